//! `sheaf_kd_params` and `sheaf_context_build_kd`:
//! the kd-tree (AEPSA paper section 5.1) and the entry-point searches its
//! and the BVH's packets may run first.

use super::bvh::sheaf_build_quality;
use super::context::{build, build_joined, build_scene_joined, sheaf_context};
use super::grid::sheaf_tri_test;
use super::sized::{self, versioned};
use super::{raw, sheaf_status};
use crate::KdParams;
use crate::error::Result;

/// Tunables of the kd-tree (an O(N log N) SAH build with perfect splits).
/// Start from `sheaf_kd_params_default`.
#[repr(C)]
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct sheaf_kd_params {
    /// `sizeof` the caller's struct, set by `sheaf_kd_params_default`
    /// (docs/c-api.md, "Upgrading").
    pub size: u32,
    /// Depth limit (1..=48); 0: `8 + 1.3 log2 N` capped at 48.
    pub max_depth: u32,
    /// SAH cost of a traversal step relative to a triangle test (> 0, default 2).
    pub traversal_cost: f32,
    /// Cost discount of splits with an empty side, in [0, 1) (default 0.2).
    pub empty_bonus: f32,
    /// Ray-triangle test of every traversal of this tree (a `sheaf_tri_test`).
    pub test: raw::sheaf_tri_test,
    /// Which build (a `sheaf_build_quality`): LOW (the default) the binned
    /// SAH build with clipped boxes, MEDIUM the same with perfect splits,
    /// both joined by `sheaf_context_build_kd_joined`'s threads; HIGH the
    /// exact O(N log N) sweep on one thread.
    pub quality: raw::sheaf_build_quality,
    /// SAH bins per axis of LOW and MEDIUM (2..=64, default 32).
    pub bins: u32,
}

impl sheaf_kd_params {
    pub fn of(p: &KdParams) -> sheaf_kd_params {
        sheaf_kd_params {
            size: core::mem::size_of::<sheaf_kd_params>() as u32,
            max_depth: p.max_depth,
            traversal_cost: p.traversal_cost,
            empty_bonus: p.empty_bonus,
            test: sheaf_tri_test::of(p.test) as u32,
            quality: sheaf_build_quality::of(p.quality) as u32,
            bins: p.bins,
        }
    }
    /// The checked crate value.
    pub fn to_core(&self) -> Result<KdParams> {
        let p = KdParams {
            max_depth: self.max_depth,
            traversal_cost: self.traversal_cost,
            empty_bonus: self.empty_bonus,
            test: sheaf_tri_test::to_core(self.test)?,
            quality: sheaf_build_quality::to_core(self.quality)?,
            bins: self.bins,
        };
        p.validate()?;
        Ok(p)
    }
}

versioned!(
    sheaf_kd_params => KdParams,
    [max_depth, traversal_cost, empty_bonus, test, quality, bins],
    sheaf_kd_params::of(&KdParams::default())
);

/// Write the default kd-tree parameters (automatic depth limit, traversal
/// cost 2, empty bonus 0.2, Moller-Trumbore, the LOW binned build with 32
/// bins) to `*out`.
///
/// `*out` is a struct of `size` bytes (sheaf.h's macro passes `sizeof
/// *out`; see `sheaf_limits_default`).
///
/// `out` must not be NULL. Errors: `SHEAF_STATUS_INVALID_ARGUMENT` when
/// `size` is no size of this struct. Thread-safe.
#[unsafe(no_mangle)]
pub extern "C" fn sheaf_kd_params_default(out: *mut sheaf_kd_params, size: usize) -> sheaf_status {
    sized::write_defaults(out, size)
}

/// Rebuild the kd-tree from the geometry with `*params` (copied; NULL: the
/// defaults of `sheaf_kd_params_default`: the binned SAH build). The grid
/// and the BVH, if built, are untouched.
///
/// Reads the geometry buffers (see `sheaf_context_set_geometry`); never
/// allocates. On error the previous kd-tree stays valid and traces exactly
/// as before.
///
/// Errors: `SHEAF_STATUS_NO_GEOMETRY`, `SHEAF_STATUS_INVALID_ARGUMENT`
/// (params, or no kd pools in `sheaf_limits.structures`),
/// `SHEAF_STATUS_INDEX_OUT_OF_RANGE`, `SHEAF_STATUS_CAPACITY_TRIANGLES`.
///
/// Not thread-safe: needs exclusive access to `ctx`.
#[unsafe(no_mangle)]
pub extern "C" fn sheaf_context_build_kd(
    ctx: *mut sheaf_context,
    params: *const sheaf_kd_params,
) -> sheaf_status {
    build(ctx, params, |c, scene, p| c.build_kd(scene, p))
}

/// `sheaf_context_build_kd` on `thread_count` of the caller's threads,
/// joined as `sheaf_context_build_bvh_joined` joins them (same protocol,
/// same misuse notes): thread 0 leads and passes `params` (the helpers'
/// are not read), the others run their share of every step and return
/// the leader's status. The LOW and MEDIUM builds run every step on all
/// threads and give the same tree for any `thread_count`; HIGH runs on
/// the leader alone (the helpers wait and return).
///
/// Errors: as `sheaf_context_build_kd`; `SHEAF_STATUS_INVALID_ARGUMENT`
/// for `thread_count` 0 or above 16 or `thread_index >= thread_count`
/// (returned at once by every thread, none waits).
#[unsafe(no_mangle)]
pub extern "C" fn sheaf_context_build_kd_joined(
    ctx: *mut sheaf_context,
    params: *const sheaf_kd_params,
    thread_index: u32,
    thread_count: u32,
) -> sheaf_status {
    build_joined(
        ctx,
        params,
        thread_index,
        thread_count,
        |c, scene, p, par| c.build_kd_with(scene, p, par),
    )
}

/// `sheaf_context_build_scene_kd` on `thread_count` of the caller's
/// threads, joined as `sheaf_context_build_kd_joined` joins them: the
/// flattening and the kd-tree's build run on all of them.
///
/// Errors: as `sheaf_context_build_scene_kd`;
/// `SHEAF_STATUS_INVALID_ARGUMENT` for `thread_count` 0 or above 16 or
/// `thread_index >= thread_count`.
#[unsafe(no_mangle)]
pub extern "C" fn sheaf_context_build_scene_kd_joined(
    ctx: *mut sheaf_context,
    params: *const sheaf_kd_params,
    mask: u32,
    thread_index: u32,
    thread_count: u32,
) -> sheaf_status {
    build_scene_joined(ctx, params, thread_index, thread_count, |c, p, par| {
        c.build_kd_scene_with(p, mask, par)
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::TriTest;

    #[test]
    fn params_and_entry_round_trip() {
        let p = KdParams {
            max_depth: 20,
            traversal_cost: 1.5,
            empty_bonus: 0.1,
            test: TriTest::Watertight,
            quality: crate::BuildQuality::High,
            bins: 8,
        };
        assert_eq!(sheaf_kd_params::of(&p).to_core(), Ok(p));
        assert!(
            sheaf_kd_params {
                test: 9,
                ..sheaf_kd_params::of(&p)
            }
            .to_core()
            .is_err()
        );
        assert!(
            sheaf_kd_params {
                max_depth: 49,
                ..sheaf_kd_params::of(&p)
            }
            .to_core()
            .is_err()
        );
        for bad in [
            sheaf_kd_params {
                quality: 3,
                ..sheaf_kd_params::of(&p)
            },
            sheaf_kd_params {
                bins: 1,
                ..sheaf_kd_params::of(&p)
            },
            sheaf_kd_params {
                bins: 65,
                ..sheaf_kd_params::of(&p)
            },
        ] {
            assert!(bad.to_core().is_err());
        }
        assert!(
            sheaf_kd_params {
                empty_bonus: 1.0,
                ..sheaf_kd_params::of(&p)
            }
            .to_core()
            .is_err()
        );
    }
}
