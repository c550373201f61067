//! Per-frame grid build (CGT paper section 3; macrocells section 2.4).
//!
//! 1. Read the triangles: bounds of the traceable ones, counts of excluded ones.
//! 2. Resolution `N_a = d_a * cbrt(lambda N / V)` (section 3), rounded, at least 1.
//! 3. Count the references every triangle's (slightly widened) bounding box
//!    adds; fail with a capacity error before writing anything.
//! 4. Counting sort: per-cell counts, prefix sum, fill. No per-cell allocation:
//!    one `cell_start` array and one `refs` array, both preallocated.
//! 5. Macrocell flags: one bit per M x M x M block of cells.

use super::{Grid, GridInfo, GridParams};
use crate::error::{Error, Pool, Result};
use crate::geom::{Aabb, Excluded, Scene, TriVerts};
use crate::math;
use glam::Vec3;

/// Widening of every triangle box at insertion, in cells (see `mod.rs`,
/// Deviations). Cell stepping errors are ~1e-6 cells; this is 1000x that.
pub const INSERT_EPS: f32 = 1e-3;

/// Longest axis is at least this many times any other (flat scenes, such as
/// a single ground quad, get a thin but non-zero slab).
const MIN_EXTENT_RATIO: f32 = 1e-3;

/// Largest resolution along one axis (keeps cell coordinates exact in f32).
const MAX_RES: u32 = 1 << 16;

#[inline]
fn tri_bounds(t: &TriVerts) -> Aabb {
    let mut b = Aabb::EMPTY;
    b.grow(Vec3::from(t.v0));
    b.grow(Vec3::from(t.v1));
    b.grow(Vec3::from(t.v2));
    b
}

/// Inclusive cell range covered by box `b` widened by `INSERT_EPS` cells.
#[inline]
fn cell_range(info: &GridInfo, b: &Aabb) -> ([u32; 3], [u32; 3]) {
    let lo = (b.min - info.bounds.min) * info.inv_cell - Vec3::splat(INSERT_EPS);
    let hi = (b.max - info.bounds.min) * info.inv_cell + Vec3::splat(INSERT_EPS);
    let mut a = [0u32; 3];
    let mut z = [0u32; 3];
    for k in 0..3 {
        let top = (info.res[k] - 1) as f32;
        a[k] = math::floor(lo[k]).clamp(0.0, top) as u32;
        z[k] = math::floor(hi[k]).clamp(0.0, top) as u32;
    }
    (a, z)
}

/// Resolution for `n` triangles in `bounds` at `lambda` (section 3):
/// `N_a = d_a * cbrt(lambda N / V)`. An axis that would get less than one
/// cell gets exactly one, and the others are solved again without it
/// (`k = (lambda N / prod d_a)^(1/m)` over the m remaining axes), so flat
/// scenes get about lambda x N cells instead of far more.
fn resolution(bounds: &Aabb, n: u32, lambda: f32) -> [u32; 3] {
    let d = bounds.diagonal();
    let target = lambda * n as f32;
    let mut free = [true; 3];
    let mut k = math::cbrt(target / (d.x * d.y * d.z));
    for _ in 0..3 {
        let m = free.iter().filter(|f| **f).count();
        let prod: f32 = (0..3).filter(|&a| free[a]).map(|a| d[a]).product();
        k = if m == 3 {
            math::cbrt(target / prod)
        } else {
            math::powf(target / prod, 1.0 / m as f32)
        };
        let mut changed = false;
        for a in 0..3 {
            if free[a] && d[a] * k < 1.0 && m > 1 {
                free[a] = false;
                changed = true;
            }
        }
        if !changed {
            break;
        }
    }
    let mut r = [1u32; 3];
    for a in 0..3 {
        if free[a] {
            r[a] = (math::round(d[a] * k) as u32).clamp(1, MAX_RES);
        }
    }
    r
}

fn product(r: [u32; 3]) -> u64 {
    r[0] as u64 * r[1] as u64 * r[2] as u64
}

/// Rebuild `grid` from `scene`. On error nothing in `grid` changes.
pub fn build(
    grid: &mut Grid<'_>,
    scene: &Scene<'_>,
    p: &GridParams,
    max_cells: u64,
    max_refs: u64,
) -> Result<GridInfo> {
    if !(p.lambda.is_finite() && p.lambda > 0.0 && p.lambda <= 1024.0) {
        return Err(Error::InvalidArgument("lambda must be in (0, 1024]"));
    }
    if p.macrocell > 64 {
        return Err(Error::InvalidArgument("macrocell side must be <= 64"));
    }
    let n_in = scene.triangle_count();
    if n_in as usize > grid.pools_mut().tris.len() {
        return Err(Error::Capacity {
            pool: Pool::Triangles,
            needed: n_in as u64,
            available: grid.pools_mut().tris.len() as u64,
        });
    }

    // 1. Bounds and exclusions (read only).
    let mut bounds = Aabb::EMPTY;
    let (mut n, mut bad_nf, mut bad_za) = (0u32, 0u32, 0u32);
    for t in 0..n_in {
        let tri = scene.triangle(t);
        match Scene::classify(&tri) {
            None => {
                n += 1;
                bounds = bounds.union(&tri_bounds(&tri));
            }
            Some(Excluded::NonFinite) => bad_nf += 1,
            Some(Excluded::ZeroArea) => bad_za += 1,
        }
    }

    // 2. Resolution.
    let mut info = GridInfo {
        triangles_in: n_in,
        triangles: n,
        excluded_non_finite: bad_nf,
        excluded_zero_area: bad_za,
        test: p.test,
        ..GridInfo::default()
    };
    info.scene_bounds = bounds;
    if n == 0 {
        bounds = Aabb {
            min: Vec3::ZERO,
            max: Vec3::ONE,
        };
        info.res = [1, 1, 1];
    } else {
        let d = bounds.diagonal();
        let min_ext = d.max_element() * MIN_EXTENT_RATIO;
        for a in 0..3 {
            if d[a] < min_ext {
                let pad = 0.5 * (min_ext - d[a]);
                bounds.min[a] -= pad;
                bounds.max[a] += pad;
            }
        }
        let mut lambda = p.lambda;
        info.res = resolution(&bounds, n, lambda);
        if product(info.res) > max_cells {
            if !p.fit {
                return Err(Error::Capacity {
                    pool: Pool::GridCells,
                    needed: product(info.res),
                    available: max_cells,
                });
            }
            // Fit mode: lower lambda until the cells fit (rounding may need a few steps).
            while product(info.res) > max_cells {
                lambda *= 0.98 * (max_cells as f32 / product(info.res) as f32);
                info.res = resolution(&bounds, n, lambda);
                if info.res == [1, 1, 1] {
                    break;
                }
            }
            if product(info.res) > max_cells {
                return Err(Error::Capacity {
                    pool: Pool::GridCells,
                    needed: product(info.res),
                    available: max_cells,
                });
            }
        }
    }
    let cells = product(info.res);
    info.lambda = if n > 0 { cells as f32 / n as f32 } else { 0.0 };
    info.bounds = bounds;
    let res_f = Vec3::new(info.res[0] as f32, info.res[1] as f32, info.res[2] as f32);
    info.cell_size = bounds.diagonal() / res_f;
    info.inv_cell = res_f / bounds.diagonal();
    info.macrocell = p.macrocell.max(1);
    for a in 0..3 {
        info.macro_res[a] = info.res[a].div_ceil(info.macrocell);
    }

    // 3. Count references (read only) and check capacity.
    let mut refs = 0u64;
    if n > 0 {
        for t in 0..n_in {
            let tri = scene.triangle(t);
            if Scene::classify(&tri).is_none() {
                let (a, z) = cell_range(&info, &tri_bounds(&tri));
                refs +=
                    (z[0] - a[0] + 1) as u64 * (z[1] - a[1] + 1) as u64 * (z[2] - a[2] + 1) as u64;
            }
        }
    }
    let pools = grid.pools_mut();
    if p.test == crate::geom::TriTest::Projection && pools.proj.len() < n_in as usize {
        return Err(Error::InvalidArgument(
            "the projection test needs Limits::projection_test",
        ));
    }
    if refs > max_refs.min(pools.refs.len() as u64) {
        return Err(Error::Capacity {
            pool: Pool::GridRefs,
            needed: refs,
            available: max_refs.min(pools.refs.len() as u64),
        });
    }
    if cells + 1 > pools.cell_start.len() as u64 {
        return Err(Error::Capacity {
            pool: Pool::GridCells,
            needed: cells,
            available: pools.cell_start.len() as u64 - 1,
        });
    }
    info.refs = refs as u32;

    // 4. Commit: store triangles, count per cell, prefix sum, fill.
    let cells = cells as usize;
    let (rx, ry) = (info.res[0] as usize, info.res[1] as usize);
    let cell_start = &mut pools.cell_start[..cells + 1];
    cell_start.fill(0);
    crate::fault_point!(GridBuild);
    let mut c = 0usize;
    for t in 0..n_in {
        let tri = scene.triangle(t);
        if Scene::classify(&tri).is_some() {
            continue;
        }
        pools.tris[c] = tri;
        if p.test == crate::geom::TriTest::Projection {
            // Wald 2004 data, rebuilt with the grid (CGT paper section 3).
            pools.proj[c] = crate::geom::ProjTri::new(&tri);
        }
        pools.tri_ids[c] = t;
        c += 1;
        let (a, z) = cell_range(&info, &tri_bounds(&tri));
        for k in a[2]..=z[2] {
            for j in a[1]..=z[1] {
                let row = rx * (j as usize + ry * k as usize);
                for i in a[0]..=z[0] {
                    cell_start[row + i as usize + 1] += 1;
                }
            }
        }
    }
    for i in 0..cells {
        cell_start[i + 1] += cell_start[i];
    }
    // Fill: cell_start[c] is the write cursor of cell c; afterwards it holds
    // the end of cell c, and one shift restores the starts.
    for ci in 0..c {
        let (a, z) = cell_range(&info, &tri_bounds(&pools.tris[ci]));
        for k in a[2]..=z[2] {
            for j in a[1]..=z[1] {
                let row = rx * (j as usize + ry * k as usize);
                for i in a[0]..=z[0] {
                    let cur = &mut cell_start[row + i as usize];
                    pools.refs[*cur as usize] = ci as u32;
                    *cur += 1;
                }
            }
        }
    }
    cell_start.copy_within(0..cells, 1);
    cell_start[0] = 0;

    // 5. Macrocell occupancy.
    let m = info.macrocell as usize;
    let mr = info.macro_res;
    let words = (product(mr) as usize).div_ceil(32);
    let bits = &mut pools.macro_bits[..words];
    bits.fill(0);
    let rz = info.res[2] as usize;
    for k in 0..rz {
        for j in 0..ry {
            let row = rx * (j + ry * k);
            let mrow = mr[0] as usize * (j / m + mr[1] as usize * (k / m));
            for i in 0..rx {
                if cell_start[row + i + 1] != cell_start[row + i] {
                    let mi = mrow + i / m;
                    bits[mi >> 5] |= 1 << (mi & 31);
                }
            }
        }
    }

    grid.set_info(info);
    Ok(info)
}
