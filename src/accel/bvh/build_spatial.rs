//! Spatial splits for the `High` build: the SBVH of Stich, Friedrich and
//! Dietrich 2009 ("Spatial splits in bounding volume hierarchies"),
//! sections 3-4, inside `build::binned_sah`.
//!
//! Where the best object split's children overlap (section 4.3; here by
//! more than `OVERLAP` of the node's area, as Embree), the node is also
//! binned in space:
//! `SPATIAL_BINS` equal slabs of its box along each axis, a reference
//! counted as entering the slab of its box's minimum and leaving the slab
//! of its maximum, its triangle clipped to each slab it spans
//! (section 4.1: the clipped polygon's box within the reference's box).
//! The cheapest slab plane (SAH, `A_L N_L + A_R N_R` with straddling
//! references counted on both sides) replaces the object split when it
//! costs less than `GAIN` of it and its duplicated references fit the node's share of the
//! reserve (`Limits::max_bvh_refs`); the straddling references are then
//! split in two, one per child.
//!
//! A node's references name distinct triangles (the two parts of a split
//! reference go to different children), so every leaf, and every merged
//! leaf of the 4-wide tree, tests a triangle at most once.
//!
//! # Exactness
//! Leaves still hold whole triangles: a triangle named by several leaves
//! is tested in each with the same arithmetic, so it gives the same t and
//! the same tie rule decides. A clipped box holds its part of the triangle
//! but for the clip points' rounding (a few ulps of the coordinates),
//! which the stored boxes' padding (`BOX_PAD`, 1e-5 of the scene's
//! coordinates and diagonal) covers; the union of a triangle's parts
//! covers the triangle, so a ray reaches each of its hits through a leaf
//! box that holds the hit point.
//!
//! # Deviations
//! - Embree's thresholds (`OVERLAP`, `MIN_AREA`, `GAIN`) instead of the
//!   paper's alpha of the root area, and none in nodes of fewer than
//!   `MIN_COUNT` references.
//! - No reference unsplitting (section 4.4): a straddling reference is
//!   always split.
//! - The reserve is shared between children by their reference counts
//!   (as Embree's `heuristic_spatial_array.h`), not spent first come,
//!   first served, so a subtree's references depend on it alone.

use super::PrimRef;
use super::refs::Box3;
use crate::geom::{Scene, TriVerts};
use glam::Vec3A;

/// Slabs per axis of the spatial binning (Embree's 16).
pub(super) const SPATIAL_BINS: usize = 16;

/// Spatial splits are tried where the object split's children overlap by
/// more than this fraction of the node's half area (Embree's
/// `SPATIAL_ASPLIT_OVERLAP_THRESHOLD`; Stich et al.'s alpha, relative to
/// the root, tries them in nearly every node, at ten times the build time
/// of a build without them for the same trace speed)...
pub(super) const OVERLAP: f32 = 0.1;

/// ... in nodes of at least this fraction of the root's half area
/// (Embree's `SPATIAL_ASPLIT_AREA_THRESHOLD`)...
pub(super) const MIN_AREA: f32 = 5e-6;

/// ... of at least this many references: below it the clipping (a
/// reference spans many of a small node's slabs) took most of the build's
/// time and the trees' SAH did not change (crytek sponza 65.5 with this
/// bound and without it, sibenik 43.7 against 43.6, bunny, conference and
/// legocar alike)...
pub(super) const MIN_COUNT: usize = 128;

/// ... and are taken where they cost less than this fraction of the best
/// object split (Embree's `SPATIAL_ASPLIT_SAH_THRESHOLD`): a duplicate
/// must buy a real gain.
pub(super) const GAIN: f32 = 0.99;

/// The spatial bins of one node (in the build scratch).
#[derive(Clone, Copy)]
pub(super) struct SpatialBins {
    boxes: [[Box3; SPATIAL_BINS]; 3],
    enter: [[u32; SPATIAL_BINS]; 3],
    exit: [[u32; SPATIAL_BINS]; 3],
}

pub(super) const EMPTY_SPATIAL: SpatialBins = SpatialBins {
    boxes: [[Box3::EMPTY; SPATIAL_BINS]; 3],
    enter: [[0; SPATIAL_BINS]; 3],
    exit: [[0; SPATIAL_BINS]; 3],
};

/// The slab planes of a node's box: plane `i` of `axis` at
/// `lo + i * width`, slab `floor((x - lo) / width)` clamped.
#[derive(Clone, Copy, Debug)]
pub(super) struct Slabs {
    lo: Vec3A,
    width: Vec3A,
    inv: Vec3A,
}

impl Slabs {
    pub(super) fn new(b: &Box3) -> Slabs {
        let width = (b.max - b.min) / SPATIAL_BINS as f32;
        let ok = width.cmpgt(Vec3A::ZERO) & width.is_finite_mask();
        Slabs {
            lo: b.min,
            width: Vec3A::select(ok, width, Vec3A::ZERO),
            inv: Vec3A::select(ok, Vec3A::ONE / width, Vec3A::ZERO),
        }
    }
    /// The slab holding `x` on `axis` (out of range: the nearest; NaN: 0).
    #[inline(always)]
    fn slab(&self, x: f32, axis: usize) -> usize {
        let y = ((x - self.lo[axis]) * self.inv[axis]).max(0.0);
        (y as usize).min(SPATIAL_BINS - 1)
    }
    /// The position of plane `i` on `axis`.
    #[inline(always)]
    pub(super) fn plane(&self, i: usize, axis: usize) -> f32 {
        self.lo[axis] + i as f32 * self.width[axis]
    }
}

/// Whether a box holds anything (`min <= max` on every axis).
#[inline(always)]
fn valid(b: &Box3) -> bool {
    b.min.cmple(b.max).all()
}

/// The parts of triangle `t` on either side of the plane `x[axis] = at`
/// (`<= at`, `>= at`), each within `within`: the boxes of the clipped
/// polygons (section 4.1). An empty side comes back with `min > max`.
#[inline]
pub(super) fn clip(t: &TriVerts, axis: usize, at: f32, within: &Box3) -> (Box3, Box3) {
    let v = [Vec3A::from(t.v0), Vec3A::from(t.v1), Vec3A::from(t.v2)];
    let (mut l, mut r) = (Box3::EMPTY, Box3::EMPTY);
    for i in 0..3 {
        let (p, q) = (v[i], v[(i + 1) % 3]);
        let (pa, qa) = (p[axis], q[axis]);
        if pa <= at {
            l.grow_point(p);
        }
        if pa >= at {
            r.grow_point(p);
        }
        if (pa < at && qa > at) || (pa > at && qa < at) {
            // The edge crosses the plane: its crossing point on both sides,
            // exactly on the plane along `axis`.
            let mut x = p + (q - p) * ((at - pa) / (qa - pa));
            x[axis] = at;
            l.grow_point(x);
            r.grow_point(x);
        }
    }
    let (mut lmax, mut rmin) = (within.max, within.min);
    lmax[axis] = lmax[axis].min(at);
    rmin[axis] = rmin[axis].max(at);
    let l = Box3 {
        min: l.min.max(within.min),
        max: l.max.min(lmax),
    };
    let r = Box3 {
        min: r.min.max(rmin),
        max: r.max.min(within.max),
    };
    (l, r)
}

/// The best slab plane of a node.
#[derive(Clone, Copy, Debug)]
pub(super) struct SpatialSplit {
    pub axis: usize,
    /// Plane index, `1..SPATIAL_BINS`: slabs below it go left.
    pub pos: usize,
    /// `A_L N_L + A_R N_R` (half areas).
    pub cost: f32,
    /// References on each side (straddling ones on both).
    pub left_n: usize,
    pub right_n: usize,
}

/// `refs` (a node's, or a share of them) binned into `m` on the node's
/// `slabs`.
pub(super) fn fill(m: &mut SpatialBins, refs: &[PrimRef], scene: &Scene<'_>, slabs: &Slabs) {
    *m = EMPTY_SPATIAL;
    for r in refs {
        let b = Box3::of(r);
        let mut tri = None;
        for a in 0..3 {
            if slabs.width[a] == 0.0 {
                continue;
            }
            let (b0, b1) = (slabs.slab(b.min[a], a), slabs.slab(b.max[a], a));
            m.enter[a][b0] += 1;
            m.exit[a][b1] += 1;
            if b0 == b1 {
                m.boxes[a][b0].grow(&b);
                continue;
            }
            let t = *tri.get_or_insert_with(|| scene.triangle(r.id));
            let mut rest = b;
            for i in b0..b1 {
                let (l, rr) = clip(&t, a, slabs.plane(i + 1, a), &rest);
                if valid(&l) {
                    m.boxes[a][i].grow(&l);
                }
                rest = rr;
            }
            if valid(&rest) {
                m.boxes[a][b1].grow(&rest);
            }
        }
    }
}

/// `other`'s bins merged into `m` (the bins of the references of both).
pub(super) fn merge(m: &mut SpatialBins, other: &SpatialBins) {
    for a in 0..3 {
        for i in 0..SPATIAL_BINS {
            m.boxes[a][i].grow(&other.boxes[a][i]);
            m.enter[a][i] += other.enter[a][i];
            m.exit[a][i] += other.exit[a][i];
        }
    }
}

/// The cheapest slab plane of a node of `count` references binned into
/// `m` whose duplicated references number at most `room`, or `None`.
pub(super) fn best(
    m: &SpatialBins,
    slabs: Slabs,
    count: usize,
    room: usize,
) -> Option<(SpatialSplit, Slabs)> {
    let mut best: Option<SpatialSplit> = None;
    for a in 0..3 {
        if slabs.width[a] == 0.0 {
            continue;
        }
        let mut left_area = [0.0f32; SPATIAL_BINS];
        let mut left_n = [0usize; SPATIAL_BINS];
        let (mut acc, mut n) = (Box3::EMPTY, 0usize);
        for i in 0..SPATIAL_BINS - 1 {
            acc.grow(&m.boxes[a][i]);
            n += m.enter[a][i] as usize;
            left_area[i] = if n > 0 { acc.half_area() } else { 0.0 };
            left_n[i] = n;
        }
        let (mut acc, mut n) = (Box3::EMPTY, 0usize);
        for i in (1..SPATIAL_BINS).rev() {
            acc.grow(&m.boxes[a][i]);
            n += m.exit[a][i] as usize;
            let ln = left_n[i - 1];
            if n == 0 || ln == 0 || ln + n > count + room {
                continue;
            }
            let cost = left_area[i - 1] * ln as f32 + acc.half_area() * n as f32;
            if best.is_none_or(|b| cost < b.cost) {
                best = Some(SpatialSplit {
                    axis: a,
                    pos: i,
                    cost,
                    left_n: ln,
                    right_n: n,
                });
            }
        }
    }
    best.map(|s| (s, slabs))
}

/// What `partition` made of a node: the left count, the references used
/// (`refs[..used]`), and both children's boxes and centroid boxes.
pub(super) struct Parted {
    pub left: usize,
    pub used: usize,
    pub bl: Box3,
    pub br: Box3,
    pub cl: Box3,
    pub cr: Box3,
}

/// Split a node's `count` references (`refs[..count]`, `refs` running to
/// its share of the reserve) at `s`: straddling references become their
/// left part in place and their right part appended after `count`; then
/// left before right. The duplicates never exceed `s`'s count of
/// straddlers, which `find` fitted in the room.
pub(super) fn partition(
    refs: &mut [PrimRef],
    count: usize,
    scene: &Scene<'_>,
    slabs: &Slabs,
    s: &SpatialSplit,
) -> Parted {
    const LEFT: u32 = 1;
    let (a, at) = (s.axis, slabs.plane(s.pos, s.axis));
    let mut end = count;
    debug_assert!(s.left_n + s.right_n - count <= refs.len() - count);
    for j in 0..count {
        let b = Box3::of(&refs[j]);
        let (b0, b1) = (slabs.slab(b.min[a], a), slabs.slab(b.max[a], a));
        if b1 < s.pos {
            refs[j]._pad = LEFT;
        } else if b0 >= s.pos {
            refs[j]._pad = 0;
        } else {
            let (l, r) = clip(&scene.triangle(refs[j].id), a, at, &b);
            let put = |r: &mut PrimRef, b: &Box3, side: u32| {
                r.min = b.min.into();
                r.max = b.max.into();
                r._pad = side;
            };
            match (valid(&l), valid(&r)) {
                (true, true) if end < refs.len() => {
                    refs[end] = refs[j];
                    put(&mut refs[end], &r, 0);
                    put(&mut refs[j], &l, LEFT);
                    end += 1;
                }
                // No room (which `find`'s count rules out): whole, left.
                (true, true) => refs[j]._pad = LEFT,
                (false, true) => put(&mut refs[j], &r, 0),
                // The left part alone, or (rounding) neither: the whole
                // reference stays left.
                (true, false) => put(&mut refs[j], &l, LEFT),
                (false, false) => refs[j]._pad = LEFT,
            }
        }
    }
    // Left first (Hoare's two scans), each side's boxes gathered on the way.
    let refs = &mut refs[..end];
    let (mut i, mut j) = (0usize, end);
    while i < j {
        if refs[i]._pad == LEFT {
            i += 1;
        } else {
            j -= 1;
            refs.swap(i, j);
        }
    }
    let mut p = Parted {
        left: i,
        used: end,
        bl: Box3::EMPTY,
        br: Box3::EMPTY,
        cl: Box3::EMPTY,
        cr: Box3::EMPTY,
    };
    for (k, r) in refs.iter_mut().enumerate() {
        r._pad = 0;
        let b = Box3::of(r);
        if k < p.left {
            p.bl.grow(&b);
            p.cl.grow_point(b.min + b.max);
        } else {
            p.br.grow(&b);
            p.cr.grow_point(b.min + b.max);
        }
    }
    p
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn clip_holds_both_parts_of_a_triangle() {
        let t = TriVerts {
            v0: [0.0, 0.0, 0.0],
            v1: [4.0, 1.0, 0.0],
            v2: [0.0, 2.0, 3.0],
        };
        let whole = Box3::of_tri(&t);
        let (l, r) = clip(&t, 0, 1.0, &whole);
        assert!(valid(&l) && valid(&r));
        assert_eq!((l.max.x, r.min.x), (1.0, 1.0));
        assert_eq!((l.min, r.max.x), (whole.min, whole.max.x));
        assert_eq!(r.max, Vec3A::new(4.0, 1.75, 2.25));
        // The right part is the corner near v1: smaller than the box's
        // right part (1..4 x 0..2 x 0..3).
        let slab = Box3 {
            min: Vec3A::new(1.0, 0.0, 0.0),
            max: whole.max,
        };
        assert!(r.half_area() < 0.8 * slab.half_area());
        // Points of the triangle on each side lie in that side's box.
        for i in 0..=20 {
            for j in 0..=20 - i {
                let (u, w) = (i as f32 / 20.0, j as f32 / 20.0);
                let p = Vec3A::from(t.v0) * (1.0 - u - w)
                    + Vec3A::from(t.v1) * u
                    + Vec3A::from(t.v2) * w;
                let b = if p.x <= 1.0 { &l } else { &r };
                let eps = 1e-6;
                assert!(
                    p.cmpge(b.min - eps).all() && p.cmple(b.max + eps).all(),
                    "{p} outside {b:?}"
                );
            }
        }
        // A plane beyond the triangle: one side empty.
        let (l, r) = clip(&t, 0, 5.0, &whole);
        assert!(valid(&l) && !valid(&r));
    }
}
