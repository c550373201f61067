//! What the BVH builds share about references (`PrimRef`): their boxes in
//! SIMD registers (`Box3`), and how many references a build may write
//! (`PoolRoom`, `reference_capacity`): the binned SAH build and its
//! spatial splits (`build.rs`, `build_spatial.rs`) and the fast build with
//! its pre-splits (`build_morton.rs`, `presplit.rs`) all read them here, so
//! no build imports another's module for them.
#![forbid(unsafe_code)]

use super::{BuildQuality, BvhParams, BvhPools, PrimRef};
use crate::geom::{Aabb, F4, M4, TriTest, TriVerts};
use glam::Vec3A;

/// A box in SIMD registers (build-internal).
#[derive(Clone, Copy, Debug)]
pub(super) struct Box3 {
    pub min: Vec3A,
    pub max: Vec3A,
}

impl Box3 {
    pub(super) const EMPTY: Box3 = Box3 {
        min: Vec3A::splat(f32::INFINITY),
        max: Vec3A::splat(f32::NEG_INFINITY),
    };
    /// The box of a reference: two 16-byte loads, the fourth lanes (id and
    /// padding) cleared.
    #[inline(always)]
    pub(super) fn of(r: &PrimRef) -> Box3 {
        let f: &[f32; 8] = bytemuck::cast_ref(r);
        let xyz = M4::new(true, true, true, false);
        let lo = F4::select(xyz, F4::from_slice(&f[..4]), F4::ZERO);
        let hi = F4::select(xyz, F4::from_slice(&f[4..]), F4::ZERO);
        Box3 {
            min: Vec3A::from_vec4(lo),
            max: Vec3A::from_vec4(hi),
        }
    }
    /// The box of a triangle's three vertices.
    #[inline(always)]
    pub(super) fn of_tri(t: &TriVerts) -> Box3 {
        let (a, b, c) = (Vec3A::from(t.v0), Vec3A::from(t.v1), Vec3A::from(t.v2));
        Box3 {
            min: a.min(b).min(c),
            max: a.max(b).max(c),
        }
    }
    #[inline(always)]
    pub(super) fn grow(&mut self, o: &Box3) {
        self.min = self.min.min(o.min);
        self.max = self.max.max(o.max);
    }
    #[inline(always)]
    pub(super) fn grow_point(&mut self, p: Vec3A) {
        self.min = self.min.min(p);
        self.max = self.max.max(p);
    }
    /// Half the surface area (the SAH only uses ratios).
    #[inline(always)]
    pub(super) fn half_area(&self) -> f32 {
        let d = self.max - self.min;
        d.x * d.y + d.y * d.z + d.z * d.x
    }
    #[inline]
    pub(super) fn aabb(&self) -> Aabb {
        Aabb {
            min: self.min.into(),
            max: self.max.into(),
        }
    }
    #[inline]
    pub(super) fn padded(&self, pad: Vec3A) -> Aabb {
        Aabb {
            min: (self.min - pad).into(),
            max: (self.max + pad).into(),
        }
    }
}

/// The lengths of the pools a stored reference fills, read before a build
/// splits the pools into its own borrows.
#[derive(Clone, Copy)]
pub(super) struct PoolRoom {
    refs: usize,
    slots: usize,
    tris: usize,
    ids: usize,
    nodes: usize,
    /// The projection pool's, when the build's test uses it.
    proj: Option<usize>,
}

impl PoolRoom {
    pub(super) fn of(pools: &BvhPools<'_>, p: &BvhParams) -> PoolRoom {
        PoolRoom {
            refs: pools.refs.len(),
            slots: pools.slot_of.len(),
            tris: pools.tris.len(),
            ids: pools.tri_ids.len(),
            nodes: pools.nodes.len(),
            proj: (p.test == TriTest::Projection).then_some(pools.proj.len()),
        }
    }
    /// The reserve the limits sized: the reference pool beyond the
    /// triangle slots (a two-level scene's geometries have none).
    pub(super) fn reserve(&self) -> usize {
        self.refs.saturating_sub(self.slots)
    }
}

/// References a build of `n` traceable triangles (of `n_in`) may use: the
/// triangles' own and, where the build splits references (`High`'s
/// spatial splits, `Low`'s pre-splits when `p.presplit`), the reserve, as
/// far as every pool a reference fills holds it. The `Low` build writes
/// its references at the triangles' own indices, so its parts follow all
/// `n_in` of them.
pub(super) fn reference_capacity(r: &PoolRoom, p: &BvhParams, n: usize, n_in: usize) -> usize {
    let splits = match p.quality {
        BuildQuality::High => true,
        BuildQuality::Low => p.presplit,
        BuildQuality::Medium => false,
    };
    if !splits {
        return n;
    }
    let mut cap = (n + r.reserve())
        .min(r.refs)
        .min(r.tris)
        .min(r.ids)
        .min(r.nodes / 2)
        .min(r.proj.unwrap_or(usize::MAX));
    if p.quality == BuildQuality::Low {
        cap = cap.min(n + r.refs.saturating_sub(n_in));
    }
    cap.max(n)
}
