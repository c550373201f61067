//! `sheaf_bvh_params`, `sheaf_build_quality` and `sheaf_ray_kind`: the
//! tunables of the BVH and the frustum its large packets get.

use super::grid::sheaf_tri_test;
use super::sized::{self, versioned};
use super::{flag, raw};
use crate::error::{Error, Result};
use crate::{BuildQuality, BvhParams, RayKind};
use crate::{RefitInfo, RefitParams};

/// Which BVH build (the crate's `BuildQuality`), numbered as Embree's
/// `RTCBuildQuality`. Every traversal is exact on every tree; the shape
/// decides speed only.
#[repr(u32)]
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum sheaf_build_quality {
    /// Morton codes and a radix sort (LBVH): fastest build, slower
    /// traversal. For geometry rebuilt every frame.
    Low = 0,
    /// Binned SAH (the BVH paper's build; the default).
    Medium = 1,
    /// Binned SAH with 64 bins and full sweeps over small nodes.
    High = 2,
}

impl sheaf_build_quality {
    pub const fn of(q: BuildQuality) -> sheaf_build_quality {
        match q {
            BuildQuality::Low => sheaf_build_quality::Low,
            BuildQuality::Medium => sheaf_build_quality::Medium,
            BuildQuality::High => sheaf_build_quality::High,
        }
    }
    pub fn to_core(raw: raw::sheaf_build_quality) -> Result<BuildQuality> {
        [BuildQuality::Low, BuildQuality::Medium, BuildQuality::High]
            .into_iter()
            .find(|&q| sheaf_build_quality::of(q) as u32 == raw)
            .ok_or(Error::InvalidArgument("unknown sheaf_build_quality"))
    }
}

/// Tunables of the BVH (Overbeck, Ramamoorthi, Mark 2008, section 5.1: a
/// binned SAH build). Start from `sheaf_bvh_params_default`.
#[repr(C)]
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct sheaf_bvh_params {
    /// `sizeof` the caller's struct, set by `sheaf_bvh_params_default`
    /// (docs/c-api.md, "Upgrading").
    pub size: u32,
    /// Most triangles in a leaf before the build must split (1..=64, default 4).
    pub leaf_size: u32,
    /// SAH bins per axis (2..=64, default 16).
    pub bins: u32,
    /// SAH cost of a traversal step relative to a triangle test (> 0, default 1).
    pub traversal_cost: f32,
    /// Ray-triangle test of every traversal of this BVH (a `sheaf_tri_test`).
    pub test: raw::sheaf_tri_test,
    /// Which build (a `sheaf_build_quality`; default MEDIUM, binned SAH).
    /// LOW ignores `bins` and uses `traversal_cost` only for the reported
    /// SAH cost.
    pub quality: raw::sheaf_build_quality,
    /// Children per node of the tree single rays walk: 4 (default; 0 also
    /// means 4, for zero-filled structs) also builds the 4-wide tree
    /// (`SHEAF_METHOD_BVH_WIDE`, `_WIDE_RANGED`, and the packets'
    /// single-ray fallback) after every build; 2 keeps the binary tree
    /// alone (a cheaper build for binary packets only).
    pub width: u32,
    /// 1: the LOW build pre-splits large, thin triangles into the
    /// reference reserve `sheaf_limits.max_bvh_refs` sizes (none without
    /// one); 0 (default): it does not. It pays only where a build is traced
    /// by many rays (docs/studies.md, "Pre-splitting the fast build").
    pub presplit: u32,
}

impl sheaf_bvh_params {
    pub fn of(p: &BvhParams) -> sheaf_bvh_params {
        sheaf_bvh_params {
            size: core::mem::size_of::<sheaf_bvh_params>() as u32,
            leaf_size: p.leaf_size,
            bins: p.bins,
            traversal_cost: p.traversal_cost,
            test: sheaf_tri_test::of(p.test) as u32,
            quality: sheaf_build_quality::of(p.quality) as u32,
            width: p.width,
            presplit: p.presplit.into(),
        }
    }
    /// The checked crate value.
    pub fn to_core(&self) -> Result<BvhParams> {
        let p = BvhParams {
            leaf_size: self.leaf_size,
            bins: self.bins,
            traversal_cost: self.traversal_cost,
            test: sheaf_tri_test::to_core(self.test)?,
            quality: sheaf_build_quality::to_core(self.quality)?,
            width: if self.width == 0 { 4 } else { self.width },
            presplit: flag(self.presplit, "sheaf_bvh_params.presplit must be 0 or 1")?,
        };
        p.validate()?;
        Ok(p)
    }
}

/// Which frustum a BVH packet gets (BVH paper section 4; the crate's `RayKind`).
#[repr(u32)]
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum sheaf_ray_kind {
    /// Common-origin frustum when all rays share their origin, else the
    /// near/far-plane frustum.
    Auto = 0,
    /// Camera rays of an n x n pixel packet in the renderer's quad order:
    /// the corner rays' frustum (4.1).
    Primary = 1,
    /// Rays from one point light (4.2).
    Shadow = 2,
    /// Reflection or refraction rays (4.3).
    Secondary = 3,
}

impl sheaf_ray_kind {
    pub const fn of(k: RayKind) -> sheaf_ray_kind {
        match k {
            RayKind::Auto => sheaf_ray_kind::Auto,
            RayKind::Primary => sheaf_ray_kind::Primary,
            RayKind::Shadow => sheaf_ray_kind::Shadow,
            RayKind::Secondary => sheaf_ray_kind::Secondary,
        }
    }
    pub fn to_core(raw: u32) -> Result<RayKind> {
        [
            RayKind::Auto,
            RayKind::Primary,
            RayKind::Shadow,
            RayKind::Secondary,
        ]
        .into_iter()
        .find(|&k| sheaf_ray_kind::of(k) as u32 == raw)
        .ok_or(Error::InvalidArgument("unknown sheaf_ray_kind"))
    }
}

versioned!(
    sheaf_bvh_params => BvhParams,
    [
        leaf_size,
        bins,
        traversal_cost,
        test,
        quality,
        width,
        presplit
    ],
    sheaf_bvh_params::of(&BvhParams::default())
);

/// Write the default BVH parameters (leaves of up to 4 triangles, 16 bins,
/// traversal cost 1, Moller-Trumbore) to `*out`, a struct of `size` bytes
/// (sheaf.h's macro passes `sizeof *out`; see `sheaf_limits_default`).
///
/// `out` must not be NULL. Errors: `SHEAF_STATUS_INVALID_ARGUMENT` when
/// `size` is no size of this struct. Thread-safe.
#[unsafe(no_mangle)]
pub extern "C" fn sheaf_bvh_params_default(
    out: *mut sheaf_bvh_params,
    size: usize,
) -> super::sheaf_status {
    sized::write_defaults(out, size)
}

/// When a BVH refit becomes a rebuild (`sheaf_context_refit_bvh`), the
/// crate's `RefitParams`. Start from `sheaf_refit_params_default`.
#[repr(C)]
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct sheaf_refit_params {
    /// `sizeof` the caller's struct, set by `sheaf_refit_params_default`.
    pub size: u32,
    /// Rebuild (with the last build's `sheaf_bvh_params`) instead once the
    /// tree's SAH cost has grown past this ratio; 0 (default) never
    /// rebuilds. 0 or a finite value of at least 1.
    pub rebuild_above: f32,
}

impl sheaf_refit_params {
    pub fn of(p: &RefitParams) -> sheaf_refit_params {
        sheaf_refit_params {
            size: core::mem::size_of::<sheaf_refit_params>() as u32,
            rebuild_above: p.rebuild_above,
        }
    }
    pub fn to_core(&self) -> Result<RefitParams> {
        let p = RefitParams {
            rebuild_above: self.rebuild_above,
        };
        p.validate()?;
        Ok(p)
    }
}

/// What a BVH refit did, the crate's `RefitInfo`.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct sheaf_refit_info {
    /// Wall time of the call, refit and any rebuild, in nanoseconds.
    pub ns: u64,
    /// The tree's SAH cost before and after (after a rebuild: the new
    /// tree's).
    pub sah_before: f32,
    pub sah_after: f32,
    /// Triangles the build left out (non-finite or zero area then) that a
    /// rebuild would now store: a refit keeps them out.
    pub newly_traceable: u32,
    /// 1 when the SAH growth passed `rebuild_above` and the tree was
    /// rebuilt instead, else 0.
    pub rebuilt: u8,
}

impl sheaf_refit_info {
    pub fn of(r: &RefitInfo) -> sheaf_refit_info {
        sheaf_refit_info {
            ns: r.ns,
            sah_before: r.sah_before,
            sah_after: r.sah_after,
            newly_traceable: r.newly_traceable,
            rebuilt: r.rebuilt.into(),
        }
    }
}

versioned!(
    sheaf_refit_params => RefitParams,
    [rebuild_above],
    sheaf_refit_params::of(&RefitParams::default())
);

/// Write the default refit parameters (never rebuild) to `*out`, a struct
/// of `size` bytes (sheaf.h's macro passes `sizeof *out`).
///
/// `out` must not be NULL. Errors: `SHEAF_STATUS_INVALID_ARGUMENT` when
/// `size` is no size of this struct. Thread-safe.
#[unsafe(no_mangle)]
pub extern "C" fn sheaf_refit_params_default(
    out: *mut sheaf_refit_params,
    size: usize,
) -> super::sheaf_status {
    sized::write_defaults(out, size)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::TriTest;

    #[test]
    fn params_round_trip() {
        let p = BvhParams {
            leaf_size: 8,
            bins: 32,
            traversal_cost: 0.5,
            test: TriTest::Watertight,
            quality: BuildQuality::Low,
            width: 2,
            presplit: true,
        };
        assert_eq!(sheaf_bvh_params::of(&p).to_core(), Ok(p));
        assert!(
            sheaf_bvh_params {
                presplit: 2,
                ..sheaf_bvh_params::of(&p)
            }
            .to_core()
            .is_err()
        );
        let zero_width = sheaf_bvh_params {
            width: 0,
            ..sheaf_bvh_params::of(&p)
        };
        assert_eq!(zero_width.to_core().map(|c| c.width), Ok(4));
        assert!(
            sheaf_bvh_params {
                width: 3,
                ..sheaf_bvh_params::of(&p)
            }
            .to_core()
            .is_err()
        );
        assert!(
            sheaf_bvh_params {
                quality: 3,
                ..sheaf_bvh_params::of(&p)
            }
            .to_core()
            .is_err()
        );
        assert!(
            sheaf_bvh_params {
                test: 9,
                ..sheaf_bvh_params::of(&p)
            }
            .to_core()
            .is_err()
        );
        assert!(
            sheaf_bvh_params {
                leaf_size: 0,
                ..sheaf_bvh_params::of(&p)
            }
            .to_core()
            .is_err()
        );
        assert!(
            sheaf_bvh_params {
                bins: 1,
                ..sheaf_bvh_params::of(&p)
            }
            .to_core()
            .is_err()
        );
        for k in 0..4 {
            assert_eq!(
                sheaf_ray_kind::of(sheaf_ray_kind::to_core(k).unwrap()) as u32,
                k
            );
        }
        assert!(sheaf_ray_kind::to_core(4).is_err());
    }
}
