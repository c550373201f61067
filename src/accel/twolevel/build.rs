//! The top level: a binary BVH over the live instances' world boxes,
//! rebuilt by every commit (Wald, Benthin, Slusallek 2003, section 3.2:
//! the top level is rebuilt every frame because it is small).
//!
//! Each instance's box is its geometry's root box mapped by its transform
//! (`Affine::bounds`: f64 corners, rounded outward) and padded by
//! `bvh::BOX_PAD` times the transform's condition number, so a ray whose
//! object-space image hits a triangle also hits the box in world space
//! (module docs of `twolevel`). Nodes split at the median instance along
//! the widest axis of their centroids, one instance per leaf; ties in the
//! centroid order go to the smaller instance id, so a commit of the same
//! instances gives the same tree.
//!
//! # Exactness
//! The tree's shape decides speed only: a box is skipped only when the
//! ray misses it or enters beyond the nearest hit.
//!
//! # Deviations
//! - Median splits, not the SAH (the top level is small and rebuilt every
//!   frame); depth at most `ceil(log2(max_instances)) + 1`.

use super::{TwoLevel, TwoLevelInfo};
use crate::accel::bvh::{BvhNode, box_pad};
use crate::geom::{Aabb, TriTest};
use glam::{Vec3, Vec3A};

/// Deepest top level: median splits of at most `u32::MAX` instances.
pub const MAX_TOP_DEPTH: usize = 33;

/// Build the top level of `s` over its live instances.
pub(super) fn build(s: &mut TwoLevel<'_>) -> TwoLevelInfo {
    let mut info = TwoLevelInfo {
        geometries: s.live_geometries(),
        test: s.test.unwrap_or(TriTest::MollerTrumbore),
        ..TwoLevelInfo::default()
    };
    // 1. World boxes of the live instances whose geometry has triangles.
    let mut n = 0usize;
    let mut bounds = Aabb::EMPTY;
    for (id, inst) in s.insts.iter_mut().enumerate() {
        if inst.live == 0 {
            continue;
        }
        let g = &s.geoms[inst.geometry as usize];
        let Some(gi) = g.bvh.info().filter(|i| i.triangles > 0) else {
            continue;
        };
        // The geometry's root box as its BVH stores it (padded).
        let root = s.blas.nodes[2 * g.run.start as usize].aabb();
        let w = inst.transform.bounds(&root);
        let pad = box_pad(Vec3A::from(w.min), Vec3A::from(w.max)) * inst.cond;
        let (lo, hi) = (w.min - Vec3::from(pad), w.max + Vec3::from(pad));
        inst.min = lo.to_array();
        inst.max = hi.to_array();
        bounds = bounds.union(&Aabb { min: lo, max: hi });
        s.order[n] = id as u32;
        n += 1;
        info.instanced_triangles += gi.triangles as u64;
    }
    info.instances = n as u32;
    info.bounds = bounds;
    if n == 0 {
        return info;
    }
    let insts = &*s.insts;
    let ibox = |id: u32| {
        let i = &insts[id as usize];
        Aabb {
            min: Vec3::from(i.min),
            max: Vec3::from(i.max),
        }
    };
    let centroid = |id: u32| {
        let b = ibox(id);
        (b.min + b.max) * 0.5
    };
    // 2. Top-down median splits; a node's children at `next`, `next + 1`.
    let order = &mut s.order[..n];
    let nodes = &mut *s.tlas;
    let mut stack = [(0u32, 0u32, 0u32, 0u32); MAX_TOP_DEPTH + 1];
    stack[0] = (0, 0, n as u32, 0);
    let mut sp = 1;
    let mut next = 1u32;
    while sp > 0 {
        sp -= 1;
        let (node, begin, end, depth) = stack[sp];
        info.depth = info.depth.max(depth);
        let part = &mut order[begin as usize..end as usize];
        let b = part.iter().fold(Aabb::EMPTY, |b, &id| b.union(&ibox(id)));
        if part.len() == 1 {
            nodes[node as usize] = BvhNode::leaf(&b, begin, 1);
            continue;
        }
        let c = part.iter().fold(Aabb::EMPTY, |mut c, &id| {
            c.grow(centroid(id));
            c
        });
        let d = c.diagonal();
        let axis = if d.x >= d.y && d.x >= d.z {
            0
        } else if d.y >= d.z {
            1
        } else {
            2
        };
        let mid = part.len() / 2;
        part.select_nth_unstable_by(mid, |&a, &b| {
            centroid(a)[axis]
                .total_cmp(&centroid(b)[axis])
                .then(a.cmp(&b))
        });
        nodes[node as usize] = BvhNode::inner(&b, next, axis);
        let m = begin + mid as u32;
        stack[sp] = (next + 1, m, end, depth + 1);
        stack[sp + 1] = (next, begin, m, depth + 1);
        sp += 2;
        next += 2;
    }
    info.nodes = next;
    info
}
