//! Pre-splitting for the fast build (`BuildQuality::Low`): large, thin
//! triangles split into several references before the Morton sort
//! (Karras and Aila 2013, "Fast Parallel Construction of High-Quality
//! Bounding Volume Hierarchies", section 5, "Triangle splitting"; the
//! splitting grid as in Embree's pre-split build). A triangle whose box is
//! much larger than the triangle itself (a diagonal wall, a long beam)
//! makes every LBVH node above it large; its parts' boxes are tight.
//!
//! 1. Each traceable triangle gets a priority: the half area its box has
//!    beyond the triangle's projections (`excess`, 0 for a triangle in an
//!    axis plane), relative to the scene's, weighted by how coarse the
//!    grid plane that crosses the box is (`WEIGHT` per Morton bit), to the
//!    power 1/4 (Embree's damping). Priorities are fixed point, so their
//!    sum, and every count below, is the same for any number of workers.
//! 2. The reserve of references (`Limits::max_bvh_refs` above
//!    `max_triangles`) is dealt out in proportion: a triangle of priority
//!    p gets `floor(reserve * p / sum)` extra references (at most
//!    `MAX_PIECES - 1`), so the planned extras never exceed the reserve.
//! 3. A triangle with extras is split recursively at the coarsest plane of
//!    a 1024-cell grid over the scene's cube that crosses its box (the
//!    plane a Morton code would separate first), the remaining count
//!    halved between the two sides; each side is the box of the triangle
//!    clipped to it (`build_spatial::clip`). The first part replaces the
//!    triangle's reference; the others go after the triangles, in
//!    triangle order, where slots a triangle could not use (a box no grid
//!    plane crosses) are marked excluded.
//!
//! # Exactness
//! As with spatial splits (`build_spatial.rs`): leaves store whole
//! triangles and each part's box holds its part of the triangle but for
//! the clip points' rounding, which the leaf boxes' padding covers, so a
//! ray reaches every hit through a leaf box holding the hit point, and a
//! triangle named by several leaves gives the same t in each.
//!
//! # Deviations
//! - Embree rounds each triangle's count up to a power of two and trims
//!   the lowest priorities by a sort when over budget; here counts are
//!   floors of the triangle's share (no sort), halved unevenly when odd.
//! - The parts of one triangle in one binary leaf are merged into one
//!   reference (`build_morton`), but a 4-wide merged leaf (`wide.rs`) may
//!   hold one triangle twice; it is tested twice and gives the same t.

use super::PrimRef;
use super::build_spatial::clip;
use super::refs::Box3;
use crate::geom::{Scene, TriVerts};
use crate::mem::par::{MAX_WORKERS, Par, Parts, share};
use glam::Vec3A;

/// Most references one triangle becomes (Embree's 32).
pub(super) const MAX_PIECES: u32 = 32;

/// Cells per axis of the splitting grid (one per Morton code cell).
const GRID: f32 = 1024.0;

/// A coarser plane counts this much more per Morton bit (Embree's
/// `PRIORITY_SPLIT_POS_WEIGHT`).
const WEIGHT: f32 = 1.5;

/// `WEIGHT` to the power of each Morton bit (30 of them).
const WEIGHTS: [f32; 30] = {
    let mut w = [1.0f32; 30];
    let mut i = 1;
    while i < 30 {
        w[i] = w[i - 1] * WEIGHT;
        i += 1;
    }
    w
};

/// Fixed-point scale of the priorities (at most about 19 before scaling:
/// `(1 * 1.5^29)^(1/4)`, so they fit 25 bits).
const ONE: f32 = (1u32 << 20) as f32;

/// `_pad` of a reference that names no triangle to store (an excluded
/// triangle's, an unused part slot).
pub(super) const EXCLUDED: u32 = u32::MAX;

/// The grid whose planes split triangles: `GRID` cells along the longest
/// side of the scene's box, on every axis.
#[derive(Clone, Copy)]
pub(super) struct SplitGrid {
    base: Vec3A,
    scale: f32,
    cell: f32,
}

impl SplitGrid {
    pub(super) fn new(bounds: &Box3) -> SplitGrid {
        let extent = (bounds.max - bounds.min).max_element();
        let ok = extent > 0.0 && extent.is_finite();
        SplitGrid {
            base: bounds.min,
            scale: if ok { GRID / extent } else { 0.0 },
            cell: if ok { extent / GRID } else { 0.0 },
        }
    }

    /// The coarsest grid plane strictly inside `b`: its axis, position
    /// and Morton bit (`3 * level + 2 - axis`, x highest), or `None`.
    /// The box is shrunk by a fifth of a cell first, so a plane touching
    /// its side does not count.
    #[inline]
    fn plane(&self, b: &Box3) -> Option<(usize, f32, u32)> {
        if self.scale == 0.0 {
            return None;
        }
        let lo = ((b.min - self.base) * self.scale + Vec3A::splat(0.2)).max(Vec3A::ZERO);
        let hi = ((b.max - self.base) * self.scale - Vec3A::splat(0.2)).max(Vec3A::ZERO);
        let top = GRID - 1.0;
        let mut best: Option<(usize, u32, u32)> = None;
        for a in 0..3 {
            let (l, h) = (lo[a].min(top) as u32, hi[a].min(top) as u32);
            if h <= l {
                continue;
            }
            let level = 31 - (l ^ h).leading_zeros();
            let bit = 3 * level + 2 - a as u32;
            if best.is_none_or(|(_, _, b)| bit > b) {
                // The multiple of 2^level above `l`: a plane in `(l, h]`.
                best = Some((a, h & !((1u32 << level) - 1), bit));
            }
        }
        best.map(|(a, cell, bit)| (a, self.base[a] + cell as f32 * self.cell, bit))
    }
}

/// The half area of a triangle's box beyond the triangle (the priority's
/// measure before weighting), 0 for a triangle in an axis plane: twice the
/// triangle's area projected on each axis plane sums to the box's half
/// area for a triangle filling half of an axis face.
#[inline]
pub(super) fn excess(t: &TriVerts, b: &Box3) -> f32 {
    let (v0, v1, v2) = (Vec3A::from(t.v0), Vec3A::from(t.v1), Vec3A::from(t.v2));
    let proj = (v1 - v0).cross(v2 - v0).abs().element_sum();
    (b.half_area() - proj).max(0.0)
}

/// The fixed-point priority of a triangle with box `b` and
/// `excess` in a scene of half area `root_area`.
#[inline]
fn priority(grid: &SplitGrid, excess: f32, b: &Box3, root_area: f32) -> u32 {
    let Some((_, _, bit)) = grid.plane(b) else {
        return 0;
    };
    let e = excess / root_area;
    let p = crate::math::sqrt(crate::math::sqrt(e * WEIGHTS[bit as usize]));
    if p.is_finite() { (p * ONE) as u32 } else { 0 }
}

/// Triangle `t` (box `b`) split into at most `pieces` parts, each
/// handed to `out` in order (left side first).
#[inline]
fn split(grid: &SplitGrid, t: &TriVerts, b: Box3, pieces: u32, out: &mut impl FnMut(Box3)) {
    // (box, parts it becomes); depth at most log2(MAX_PIECES) + 1.
    let mut stack = [(Box3::EMPTY, 0u32); 8];
    stack[0] = (b, pieces);
    let mut sp = 1usize;
    while sp > 0 {
        sp -= 1;
        let (b, k) = stack[sp];
        let cut = if k > 1 { grid.plane(&b) } else { None };
        let halves = cut.map(|(axis, at, _)| clip(t, axis, at, &b));
        match halves {
            Some((l, r)) if l.min.cmple(l.max).all() && r.min.cmple(r.max).all() => {
                // Right pushed first: the left side comes out first.
                stack[sp] = (r, k - k / 2);
                stack[sp + 1] = (l, k / 2);
                sp += 2;
            }
            _ => out(b),
        }
    }
}

/// What pre-splitting added: the extra references (valid ones, after the
/// triangles' own), their slots, and the centroid bounds with them.
pub(super) struct Added {
    /// Valid parts, and per worker: its slots' start (slots `n_in..`
    /// `slot_bounds[workers]` hold the parts, excluded where unused) and
    /// the valid parts in them.
    pub valid: usize,
    pub slot_bounds: [usize; MAX_WORKERS + 1],
    pub valid_per: [usize; MAX_WORKERS],
    /// Doubled centroids of every reference's box (the triangles' parts
    /// replaced in place included).
    pub cent: Box3,
}

/// Pre-split the references `refs[..n_in]` (written by the fast build's
/// first pass, in place, `_pad` `EXCLUDED` for excluded triangles, else the
/// bits of the triangle's `excess`) into at
/// most `reserve` more, after them; `bounds` is the scene's box.
/// `refs.len()` is at least `n_in + reserve`.
pub(super) fn presplit(
    refs: &mut [PrimRef],
    n_in: usize,
    reserve: usize,
    scene: &Scene<'_>,
    bounds: &Box3,
    par: &dyn Par,
    workers: usize,
) -> Added {
    let grid = SplitGrid::new(bounds);
    let root_area = bounds.half_area().max(f32::MIN_POSITIVE);
    // 1. Priorities into `_pad`, summed per worker (exact integers).
    let mut sums = [0u64; MAX_WORKERS];
    {
        let (rs, ss) = (
            Parts::even(&mut refs[..n_in], workers),
            Parts::even(&mut sums[..workers], workers),
        );
        par.run(&|w| {
            let mut s = 0u64;
            for r in rs.get(w).iter_mut().filter(|r| r._pad != EXCLUDED) {
                let p = priority(&grid, f32::from_bits(r._pad), &Box3::of(r), root_area);
                r._pad = p;
                s += p as u64;
            }
            ss.get(w)[0] = s;
        });
    }
    let total: u64 = sums[..workers].iter().sum();
    // 2. Extras per triangle, a pure function of its priority.
    // `reserve * p` fits 64 bits (the reserve is a u32 count, p 25 bits);
    // most triangles get no extra, known without a division.
    let reserve64 = reserve as u64;
    let extras = |p: u32| -> u32 {
        if p == EXCLUDED || total == 0 {
            return 0;
        }
        let share = reserve64 * p as u64;
        if share < total {
            return 0;
        }
        ((share / total) as u32).min(MAX_PIECES - 1)
    };
    let mut planned = [0usize; MAX_WORKERS];
    {
        let pl = Parts::even(&mut planned[..workers], workers);
        let refs = &refs[..n_in];
        par.run(&|w| {
            pl.get(w)[0] = refs[share(n_in, w, workers)]
                .iter()
                .map(|r| extras(r._pad) as usize)
                .sum();
        });
    }
    let mut slot_bounds = [0usize; MAX_WORKERS + 1];
    slot_bounds[0] = n_in;
    for w in 0..workers {
        slot_bounds[w + 1] = slot_bounds[w] + planned[w];
    }
    let planned_all = slot_bounds[workers] - n_in;
    debug_assert!(planned_all <= reserve && n_in + planned_all <= refs.len());

    // 3. The split, each worker its triangles and their slots.
    let mut found = [(0usize, Box3::EMPTY); MAX_WORKERS];
    {
        let (own, extra) = refs[..n_in + planned_all].split_at_mut(n_in);
        let mut eb = [0usize; MAX_WORKERS + 1];
        for w in 0..=workers {
            eb[w] = slot_bounds[w] - n_in;
        }
        let (rs, es, fs) = (
            Parts::even(own, workers),
            Parts::at(extra, &eb[..workers + 1]),
            Parts::even(&mut found[..workers], workers),
        );
        par.run(&|w| {
            let (mine, slots) = (rs.get(w), es.get(w));
            let (mut used, mut valid, mut cent) = (0usize, 0usize, Box3::EMPTY);
            for r in mine.iter_mut() {
                if r._pad == EXCLUDED {
                    continue;
                }
                let e = extras(r._pad);
                r._pad = 0;
                let b = Box3::of(r);
                if e == 0 {
                    cent.grow_point(b.min + b.max);
                    continue;
                }
                let (id, first) = (r.id, used);
                let mut k = 0usize;
                split(&grid, &scene.triangle(id), b, e + 1, &mut |p: Box3| {
                    cent.grow_point(p.min + p.max);
                    let pr = PrimRef {
                        min: p.min.into(),
                        id,
                        max: p.max.into(),
                        _pad: 0,
                    };
                    if k == 0 {
                        *r = pr;
                    } else {
                        slots[first + k - 1] = pr;
                    }
                    k += 1;
                });
                valid += k - 1;
                for s in &mut slots[first + k - 1..first + e as usize] {
                    s._pad = EXCLUDED;
                }
                used += e as usize;
            }
            fs.get(w)[0] = (valid, cent);
        });
    }
    let mut out = Added {
        valid: 0,
        slot_bounds,
        valid_per: [0; MAX_WORKERS],
        cent: Box3::EMPTY,
    };
    for (w, (v, c)) in found[..workers].iter().enumerate() {
        out.valid += v;
        out.valid_per[w] = *v;
        out.cent.grow(c);
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    fn tri(a: [f32; 3], b: [f32; 3], c: [f32; 3]) -> TriVerts {
        TriVerts {
            v0: a,
            v1: b,
            v2: c,
        }
    }

    /// The splitting grid of the cube from the origin to `side`.
    fn grid(side: f32) -> SplitGrid {
        SplitGrid::new(&Box3 {
            min: Vec3A::ZERO,
            max: Vec3A::splat(side),
        })
    }

    #[test]
    fn a_triangle_in_an_axis_plane_has_no_priority_and_a_diagonal_one_has() {
        let g = grid(8.0);
        let p = |t: &TriVerts| priority(&g, excess(t, &Box3::of_tri(t)), &Box3::of_tri(t), 192.0);
        let flat = tri([0.0, 0.0, 1.0], [8.0, 0.0, 1.0], [0.0, 8.0, 1.0]);
        assert_eq!(p(&flat), 0);
        let diag = tri([0.0, 0.0, 0.0], [8.0, 8.0, 8.0], [8.0, 8.1, 8.0]);
        assert!(p(&diag) > 0);
    }

    #[test]
    fn the_parts_cover_the_triangle_and_lie_in_its_box() {
        let g = grid(10.0);
        let t = tri([0.1, 0.2, 0.3], [9.7, 9.1, 9.9], [9.9, 8.7, 9.6]);
        let b = Box3::of_tri(&t);
        for pieces in [2u32, 3, 8, 32] {
            let mut parts = [Box3::EMPTY; MAX_PIECES as usize];
            let mut k = 0usize;
            split(&g, &t, b, pieces, &mut |p| {
                parts[k] = p;
                k += 1;
            });
            assert!(k > 1 && k <= pieces as usize, "{pieces}: {k} parts");
            let mut all = Box3::EMPTY;
            for p in &parts[..k] {
                assert!(p.min.cmpge(b.min).all() && p.max.cmple(b.max).all());
                all.grow(p);
            }
            assert_eq!((all.min, all.max), (b.min, b.max), "{pieces}");
            // Each part is much smaller than the whole.
            let sum: f32 = parts[..k].iter().map(|p| p.half_area()).sum();
            assert!(sum < b.half_area(), "{pieces}: {sum} vs {}", b.half_area());
            // Points along the triangle lie in some part.
            for i in 0..=20 {
                for j in 0..=(20 - i) {
                    let (u, v) = (i as f32 / 20.0, j as f32 / 20.0);
                    let p = Vec3A::from(t.v0) * (1.0 - u - v)
                        + Vec3A::from(t.v1) * u
                        + Vec3A::from(t.v2) * v;
                    let pad = Vec3A::splat(1e-5);
                    assert!(
                        parts[..k]
                            .iter()
                            .any(|b| (p + pad).cmpge(b.min).all() && (p - pad).cmple(b.max).all()),
                        "{pieces}: {p} in no part"
                    );
                }
            }
        }
    }
}
