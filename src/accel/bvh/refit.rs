//! Refit (issue 18, item 3): when only vertex positions moved (the same
//! triangles from the same index buffer), the built tree keeps its shape
//! and every box is recomputed bottom-up in place, in one pass over the
//! stored triangles and one over the nodes. Embree's equivalent is a
//! geometry committed with `RTC_BUILD_QUALITY_REFIT`; the BVH paper
//! rebuilds every frame (section 5.1).
//!
//! Children are stored after their parent (the build allocates them
//! later), so visiting the nodes in reverse order meets every child before
//! its parent: no stack, no recursion.
//!
//! # Exactness
//! Leaf boxes are padded exactly as the build pads them (`BOX_PAD` times
//! the new bounds' largest coordinate magnitude plus diagonal); an inner
//! box is the union of its children's padded boxes, which contains the
//! padded union of their triangles. Every traversal's guarantee holds on
//! the refit tree as on a fresh one: the single ray returns the triangle
//! and bitwise t of a brute-force search over the stored triangles, and
//! every packet returns the single ray's. The shape decides speed only.
//!
//! # Deviations
//! - The SAH growth compares the padded boxes before and after, each
//!   relative to its root (the build reports the unpadded ones);
//!   `BvhInfo::sah_cost` is scaled by it.
//! - Triangles the build left out (non-finite or zero area then) stay
//!   out; `RefitInfo::newly_traceable` counts those that a rebuild would
//!   now store.
#![forbid(unsafe_code)]

use super::{Bvh, BvhNode};
use crate::error::{Error, Result};
use crate::geom::{INVALID_ID, ProjTri, Scene, TriTest, TriVerts};
use glam::Vec3A;

/// When a refit becomes a rebuild (C: `sheaf_refit_params`).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct RefitParams {
    /// Rebuild (with the last build's parameters) instead, once the SAH
    /// cost has grown past this ratio of the pre-refit tree's; 0 never
    /// rebuilds. 0 or at least 1 (default 0).
    pub rebuild_above: f32,
}

impl Default for RefitParams {
    fn default() -> Self {
        RefitParams { rebuild_above: 0.0 }
    }
}

impl RefitParams {
    pub fn validate(&self) -> Result<()> {
        let r = self.rebuild_above;
        if !(r == 0.0 || (r.is_finite() && r >= 1.0)) {
            return Err(Error::InvalidArgument(
                "refit rebuild_above must be 0 or a finite ratio of at least 1",
            ));
        }
        Ok(())
    }
}

/// What a refit did (C: `sheaf_refit_info`).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct RefitInfo {
    /// SAH cost of the tree before and after (`BvhInfo::sah_cost`).
    pub sah_before: f32,
    pub sah_after: f32,
    /// Triangles the build left out that a rebuild would now store.
    pub newly_traceable: u32,
    /// The refit grew the SAH cost past `RefitParams::rebuild_above`: the
    /// tree was rebuilt instead (`sah_after` is the new tree's).
    pub rebuilt: bool,
    /// Wall time of the call, refit and any rebuild (0 without `std`).
    pub ns: u64,
}

impl RefitInfo {
    /// `sah_after / sah_before` (1 for an empty tree).
    pub fn growth(&self) -> f32 {
        if self.sah_before > 0.0 {
            self.sah_after / self.sah_before
        } else {
            1.0
        }
    }
}

/// Half area of a node's stored (padded) box.
pub(super) fn half_area(n: &BvhNode) -> f64 {
    let d = Vec3A::from(n.max) - Vec3A::from(n.min);
    (d.x * d.y + d.y * d.z + d.z * d.x) as f64
}

/// The SAH cost of the stored (padded) boxes: traversal cost per inner
/// node, one per triangle, weighted by half area relative to the root's.
pub(super) fn sah(nodes: &[BvhNode], traversal_cost: f32) -> f64 {
    sah_sum(nodes, traversal_cost) / half_area(&nodes[0]).max(f64::MIN_POSITIVE)
}

/// `sah` before the division by the root's half area (sums of parts add).
pub(super) fn sah_sum(nodes: &[BvhNode], traversal_cost: f32) -> f64 {
    nodes
        .iter()
        .map(|n| {
            let per = if n.is_leaf() {
                n.count() as f64
            } else {
                traversal_cost as f64
            };
            half_area(n) * per
        })
        .sum()
}

/// Every box of `nodes` recomputed bottom-up from the stored triangles
/// `tris`: a leaf's box is its triangles' box padded by `pad`, an inner
/// box the union of its children's. Children follow their parent, so one
/// reverse pass meets every child first. The union of padded boxes equals
/// the padded union bitwise (`x - pad` rounds monotonically), so a tree
/// fitted here has the boxes the binned build would have written.
pub(super) fn fit_boxes(nodes: &mut [BvhNode], tris: &[TriVerts], pad: Vec3A) {
    let len = nodes.len();
    fit(nodes, 0, len, tris, pad);
}

/// The box of the triangles `tris` padded by `pad`: every leaf box of the
/// binary and the wide tree (the wide tree's boxes equal the binary ones
/// bitwise because both are computed here).
#[inline(always)]
pub(super) fn leaf_box(tris: &[TriVerts], pad: Vec3A) -> (Vec3A, Vec3A) {
    let (mut a, mut b) = (Vec3A::splat(f32::INFINITY), Vec3A::splat(f32::NEG_INFINITY));
    for t in tris {
        for v in [t.v0, t.v1, t.v2] {
            let v = Vec3A::from(v);
            (a, b) = (a.min(v), b.max(v));
        }
    }
    (a - pad, b + pad)
}

/// `fit_boxes` on the first `upto` nodes of `part`, the nodes `base..base +
/// part.len()` of a tree whose children of those nodes lie in `part` (the
/// fast build fits each worker's region and then its top this way).
pub(super) fn fit(part: &mut [BvhNode], base: usize, upto: usize, tris: &[TriVerts], pad: Vec3A) {
    for i in (0..upto).rev() {
        let nd = part[i];
        let first = nd.first as usize;
        let (bmin, bmax) = if nd.is_leaf() {
            leaf_box(&tris[first..first + nd.count() as usize], pad)
        } else {
            let (l, r) = (&part[first - base], &part[first - base + 1]);
            (
                Vec3A::from(l.min).min(Vec3A::from(r.min)),
                Vec3A::from(l.max).max(Vec3A::from(r.max)),
            )
        };
        part[i].min = bmin.into();
        part[i].max = bmax.into();
    }
}

/// Refit the built tree of `bvh` to `scene`'s current vertex positions.
/// Errors (nothing changed): no tree built, a different triangle count, a
/// stored triangle with a non-finite vertex.
pub fn refit(bvh: &mut Bvh<'_>, scene: &Scene<'_>) -> Result<RefitInfo> {
    let Some(mut info) = bvh.info().copied() else {
        return Err(Error::NotBuilt);
    };
    if scene.triangle_count() != info.triangles_in {
        return Err(Error::InvalidArgument(
            "refit needs the triangles the BVH was built from (same count): rebuild instead",
        ));
    }
    let traversal_cost = bvh.params().traversal_cost;
    let pools = bvh.pools_mut();
    let n = info.triangles as usize;
    let nn = info.nodes as usize;

    // 1. Check, writing nothing: every stored triangle finite; new bounds.
    let (mut lo, mut hi) = (Vec3A::splat(f32::INFINITY), Vec3A::splat(f32::NEG_INFINITY));
    for &id in &pools.tri_ids[..n] {
        let t = scene.triangle(id);
        let all = t.v0.iter().chain(&t.v1).chain(&t.v2);
        if !all.clone().all(|x| x.is_finite()) {
            return Err(Error::InvalidArgument(
                "refit: a stored triangle has a non-finite vertex (the previous BVH is kept)",
            ));
        }
        for v in [t.v0, t.v1, t.v2] {
            let v = Vec3A::from(v);
            (lo, hi) = (lo.min(v), hi.max(v));
        }
    }
    // Only a build that left triangles out needs this second pass.
    let left_out = info.excluded_non_finite + info.excluded_zero_area;
    let newly_traceable = if left_out == 0 {
        0
    } else {
        (0..info.triangles_in)
            .filter(|&t| {
                pools.slot_of[t as usize] == INVALID_ID
                    && Scene::classify(&scene.triangle(t)).is_none()
            })
            .count() as u32
    };
    let mut out = RefitInfo {
        sah_before: info.sah_cost,
        sah_after: info.sah_cost,
        newly_traceable,
        rebuilt: false,
        ns: 0,
    };
    if n == 0 {
        return Ok(out);
    }
    crate::fault_point!(BvhBuild);

    // 2. The stored triangles, then the boxes bottom-up.
    let before = sah(&pools.nodes[..nn], traversal_cost);
    let proj = info.test == TriTest::Projection;
    for s in 0..n {
        let t = scene.triangle(pools.tri_ids[s]);
        pools.tris[s] = t;
        if proj {
            pools.proj[s] = ProjTri::new(&t);
        }
    }
    let pad = super::box_pad(lo, hi);
    let nodes = &mut pools.nodes[..nn];
    fit_boxes(nodes, &pools.tris[..n], pad);
    let after = sah(nodes, traversal_cost);
    if before > 0.0 {
        info.sah_cost = (info.sah_cost as f64 * after / before) as f32;
    }
    info.bounds = crate::geom::Aabb {
        min: lo.into(),
        max: hi.into(),
    };
    out.sah_after = info.sah_cost;
    bvh.commit_refit(info, pad);
    Ok(out)
}
