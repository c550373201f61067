//! Single-ray 3DDDA through the uniform grid (Amanatides and Woo 1987,
//! "A Fast Voxel Traversal Algorithm for Ray Tracing"), with the macrocell
//! skipping of CGT section 2.4 applied to one ray: a ray entering an empty
//! macrocell jumps to that macrocell's exit.
//!
//! This is the baseline every grid packet method is measured against and
//! must match bit for bit (same triangle test, same tie rule).
//!
//! Cell boundaries are recomputed from the cell index at every step
//! (`t = (gmin + i * size - o) / d`) instead of accumulated, so the error
//! does not grow along the ray; triangles are inserted with a widened box
//! (`build::INSERT_EPS`), so the remaining rounding never loses a hit.

use core::cmp::Ordering;

use super::{GridView, TriangleTest};
use crate::counters::{Counters, count};
use crate::geom::{Aabb, Hit, INVALID_ID, Ray, RayLanes, closer};
use glam::Vec3;

/// Nearest hit of `ray` (a miss for invalid rays: see `Ray::is_valid`).
#[inline]
pub fn intersect<T: TriangleTest>(g: &GridView<'_>, ray: &Ray, ctr: &mut Counters) -> Hit {
    walk::<T, false>(g, ray, ctr)
}

/// Whether anything lies on `ray` in `[tmin, tmax)`.
#[inline]
pub fn occluded<T: TriangleTest>(g: &GridView<'_>, ray: &Ray, ctr: &mut Counters) -> bool {
    walk::<T, true>(g, ray, ctr).is_hit()
}

/// Some hit on `ray` in `[tmin, tmax)` (the first found, not the nearest),
/// or a miss: occlusion that also names an occluder.
#[inline]
pub fn any_hit<T: TriangleTest>(g: &GridView<'_>, ray: &Ray, ctr: &mut Counters) -> Hit {
    walk::<T, true>(g, ray, ctr)
}

fn walk<T: TriangleTest, const ANY: bool>(g: &GridView<'_>, ray: &Ray, ctr: &mut Counters) -> Hit {
    ctr.rays += 1;
    let mut best = Hit::MISS;
    if !ray.is_valid() || g.info.triangles == 0 {
        return best;
    }
    let info = g.info;
    let o = Vec3::from(ray.org);
    let d = Vec3::from(ray.dir);
    let rcp = Vec3::ONE / d;
    // Clip to the grid widened as the triangles' cell ranges are
    // (`build::INSERT_EPS` cells): a hit the triangle test puts just inside
    // [tmin, tmax) may lie a rounding error outside the grid's faces (a ray
    // ending on a triangle in a face).
    let pad = info.cell_size * super::build::INSERT_EPS;
    let clip = Aabb {
        min: info.bounds.min - pad,
        max: info.bounds.max + pad,
    };
    let Some((t0, t1)) = clip.clip_ray(o, d, rcp, ray.tmin, ray.tmax) else {
        return best;
    };
    let gmin = info.bounds.min;
    let cs = info.cell_size;
    let res = [info.res[0] as i32, info.res[1] as i32, info.res[2] as i32];
    let step = [sign(d.x), sign(d.y), sign(d.z)];

    // Entry cell: the cell of the entry point, clamped into the grid.
    let p = o + d * t0;
    let mut c = [0i32; 3];
    for a in 0..3 {
        // Truncation equals floor here: both clamp to 0 below zero.
        c[a] = (((p[a] - gmin[a]) * info.inv_cell[a]) as i32).clamp(0, res[a] - 1);
    }

    let lanes = RayLanes::from_ray(ray);
    let pre = T::prepare(&lanes);
    let m = info.macrocell as i32;
    // x / m as a multiply and shift (exact for x < 2^16, m <= 64): the
    // macrocell lookup runs at every empty cell.
    let magic = (1u64 << 32).div_ceil(m as u64);
    let div_m = |x: i32| ((x as u64 * magic) >> 32) as i32;

    // t at which the ray leaves the slab [lo, hi) of cells along axis a.
    let boundary_t = |a: usize, lo: i32, hi: i32| -> f32 {
        match step[a] {
            1 => (gmin[a] + hi as f32 * cs[a] - o[a]) * rcp[a],
            -1 => (gmin[a] + lo as f32 * cs[a] - o[a]) * rcp[a],
            _ => f32::INFINITY,
        }
    };

    loop {
        if m > 1 {
            let mc = [div_m(c[0]), div_m(c[1]), div_m(c[2])];
            if !g.macro_occupied(mc) {
                // Jump to the exit of this empty macrocell.
                count!(ctr.macro_skips += 1);
                let mut t_exit = f32::INFINITY;
                let mut axis = 0;
                for a in 0..3 {
                    let t = boundary_t(a, mc[a] * m, ((mc[a] + 1) * m).min(res[a]));
                    if t < t_exit {
                        t_exit = t;
                        axis = a;
                    }
                }
                // Not `t_exit >= t1`: a NaN must stop the walk too.
                if t_exit.partial_cmp(&t1) != Some(Ordering::Less) {
                    break;
                }
                let next = if step[axis] > 0 {
                    ((mc[axis] + 1) * m).min(res[axis])
                } else {
                    mc[axis] * m - 1
                };
                if next < 0 || next >= res[axis] {
                    break;
                }
                for a in 0..3 {
                    if a == axis {
                        c[a] = next;
                    } else {
                        // Stay inside this macrocell's range on the other axes:
                        // the ray leaves through the `axis` face, so rounding
                        // must not move it sideways out of the block.
                        let lo = mc[a] * m;
                        let hi = ((mc[a] + 1) * m).min(res[a]) - 1;
                        let q = o[a] + d[a] * t_exit;
                        c[a] = (((q - gmin[a]) * info.inv_cell[a]) as i32).clamp(lo, hi);
                    }
                }
                continue;
            }
        }

        // Cell exit along each axis.
        let tn = [
            boundary_t(0, c[0], c[0] + 1),
            boundary_t(1, c[1], c[1] + 1),
            boundary_t(2, c[2], c[2] + 1),
        ];
        let axis = if tn[0] <= tn[1] && tn[0] <= tn[2] {
            0
        } else if tn[1] <= tn[2] {
            1
        } else {
            2
        };
        let t_exit = tn[axis];

        count!(ctr.cells += 1);
        for &r in g.cell(g.cell_index(c)) {
            count!(ctr.tri_tests += 1);
            let h = T::intersect(&lanes, &pre, T::prim(g.store(), r as usize));
            if h.mask {
                let id = g.tri_ids[r as usize];
                if closer(h.t, id, &best)
                    && g.filter.accepts(lanes.org, lanes.dir, h.t, h.u, h.v, id)
                {
                    best = Hit {
                        t: h.t,
                        prim: id,
                        u: h.u,
                        v: h.v,
                    };
                    if ANY {
                        return best;
                    }
                }
            }
        }
        // Strict: a hit exactly on the exit plane may tie with a lower id in
        // the next cell. A NaN stops the walk.
        if best.t < t_exit || t_exit.partial_cmp(&t1) != Some(Ordering::Less) {
            break;
        }
        c[axis] += step[axis];
        if c[axis] < 0 || c[axis] >= res[axis] {
            break;
        }
    }
    if best.prim == INVALID_ID {
        Hit::MISS
    } else {
        best
    }
}

#[inline(always)]
fn sign(x: f32) -> i32 {
    if x > 0.0 {
        1
    } else if x < 0.0 {
        -1
    } else {
        0
    }
}
