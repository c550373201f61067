//! The two-level scene through the C ABI (`accel::twolevel`, the crate's
//! `Context::set_geometry` and friends): geometries that borrow their
//! buffers only during the call that builds or updates them, instances
//! placing them with 3x4 transforms, a commit, and rays traced through it.
//! Needs `sheaf_limits.max_geometries` > 0.

use super::bvh::{sheaf_bvh_params, sheaf_refit_info, sheaf_refit_params};
use super::context::{Geometry, Handle, build_scene, sheaf_context, with_mut, with_ref};
use super::grid::sheaf_grid_params;
use super::kd::sheaf_kd_params;
use super::pgrid::sheaf_pgrid_params;
use super::ray::{sheaf_hit, sheaf_ray};
use super::sized::{self, versioned};
use super::trace_params::sheaf_trace_params;
use super::{check_non_null, check_rays_out, read_in, write_out, write_wanted};
use crate::SceneHit;
use crate::error::{Error, Result};
use crate::{Affine, Cull, Ray};
use crate::{GeometryParams, RayControls, TwoLevelInfo, UpdateMode};
use core::ffi::c_void;

/// A mesh as the caller holds it: `vertex_count` vertices of three floats
/// (x, y, z), `vertex_stride_bytes` apart (>= 12, a multiple of 4), and
/// `3 * triangle_count` vertex indices (4-byte aligned). A pointer may be
/// NULL only when its count is 0. Read only during the call it is passed
/// to (the geometry's BVH keeps its own copy of the triangles).
#[repr(C)]
#[derive(Clone, Copy, Debug)]
pub struct sheaf_mesh {
    pub vertices: *const f32,
    pub vertex_stride_bytes: usize,
    pub vertex_count: u32,
    pub indices: *const u32,
    pub triangle_count: u32,
}

impl sheaf_mesh {
    fn geometry(&self) -> Result<Geometry> {
        Geometry::new(
            self.vertices,
            self.vertex_stride_bytes,
            self.vertex_count,
            self.indices,
            self.triangle_count,
        )
    }
}

/// What `sheaf_context_update_scene_geometry` does with a geometry.
#[repr(u32)]
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum sheaf_update_mode {
    /// Built once; updates are refused (set it again).
    Static = 0,
    /// The vertices move, the index buffer stays: an update refits its
    /// BVH (rebuilding past `refit.rebuild_above`).
    Refit = 1,
    /// The topology changes: an update rebuilds (up to `max_triangles`).
    Rebuild = 2,
}

/// How a geometry is built and updated (the crate's `GeometryParams`).
/// Start from `sheaf_geometry_params_default`. Its BVH and refit
/// parameters are pointed to (each struct grows on its own; see
/// docs/c-api.md, "Upgrading") and read during the call only.
#[repr(C)]
#[derive(Clone, Copy, Debug)]
pub struct sheaf_geometry_params {
    /// `sizeof` the caller's struct, set by `sheaf_geometry_params_default`.
    pub size: u32,
    pub mode: super::raw::sheaf_update_mode,
    /// Its BVH (NULL, the default: `sheaf_bvh_params_default`; every
    /// geometry of a scene uses the first one's test).
    pub bvh: *const sheaf_bvh_params,
    /// When a refit becomes a rebuild (REFIT geometries; NULL, the
    /// default: never).
    pub refit: *const sheaf_refit_params,
    /// Its any-hit filter (NULL, the default: none), called with
    /// `filter_user`; see `sheaf_filter_fn` and
    /// `sheaf_context_set_scene_geometry_filter`.
    pub filter: super::filter::sheaf_filter_fn,
    pub filter_user: *mut c_void,
    /// Triangles reserved in the scene's budget (0: the mesh's count). A
    /// REBUILD geometry may grow to it.
    pub max_triangles: u32,
    /// Rays whose mask shares no bit with it skip every instance of the
    /// geometry (default all bits).
    pub mask: u32,
    /// Skip its filter (DXR's opaque geometry flag): 0 (the default) or 1.
    pub opaque: u32,
    /// Reserved for a future field: 0 (it keeps the struct free of padding).
    pub reserved: u32,
}

impl sheaf_geometry_params {
    /// `p` with its BVH and refit parameters left to their defaults (NULL):
    /// the C struct cannot point at values that do not outlive the call.
    pub fn of(p: &GeometryParams) -> Self {
        sheaf_geometry_params {
            size: core::mem::size_of::<sheaf_geometry_params>() as u32,
            mode: p.mode as u32,
            bvh: core::ptr::null(),
            refit: core::ptr::null(),
            filter: p.filter.map(|f| f.func),
            filter_user: p.filter.map_or(core::ptr::null_mut(), |f| f.user()),
            max_triangles: p.max_triangles,
            mask: p.mask,
            opaque: p.opaque.into(),
            reserved: 0,
        }
    }
    pub fn to_core(&self) -> Result<GeometryParams> {
        let mode = [UpdateMode::Static, UpdateMode::Refit, UpdateMode::Rebuild]
            .into_iter()
            .find(|&m| m as u32 == self.mode)
            .ok_or(Error::InvalidArgument("unknown sheaf_update_mode"))?;
        if self.reserved != 0 {
            return Err(Error::InvalidArgument(
                "sheaf_geometry_params.reserved must be 0",
            ));
        }
        Ok(GeometryParams {
            mode,
            max_triangles: self.max_triangles,
            bvh: sized::or_default(self.bvh)?,
            refit: sized::or_default(self.refit)?,
            mask: self.mask,
            filter: super::filter::filter_of(self.filter, self.filter_user)?,
            opaque: super::flag(self.opaque, "sheaf_geometry_params.opaque must be 0 or 1")?,
        })
    }
}

versioned!(
    sheaf_geometry_params => GeometryParams,
    [
        mode,
        bvh,
        refit,
        filter,
        filter_user,
        max_triangles,
        mask,
        opaque,
        reserved
    ],
    sheaf_geometry_params::of(&GeometryParams::default())
);

/// Nearest hit in a two-level scene (24 bytes): the triangle's index in
/// its geometry's index buffer, the geometry and the instance. A miss has
/// `prim == geometry == instance == SHEAF_INVALID_ID` and `t == INFINITY`.
/// Of two hits at the same `t` the lower instance, then triangle, wins.
#[repr(C)]
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct sheaf_scene_hit {
    pub t: f32,
    pub u: f32,
    pub v: f32,
    pub prim: u32,
    pub geometry: u32,
    pub instance: u32,
}

impl From<SceneHit> for sheaf_scene_hit {
    fn from(h: SceneHit) -> Self {
        sheaf_scene_hit {
            t: h.t,
            u: h.u,
            v: h.v,
            prim: h.prim,
            geometry: h.geometry,
            instance: h.instance,
        }
    }
}

const _: () = assert!(core::mem::size_of::<sheaf_scene_hit>() == 24);

/// What a commit built (the crate's `TwoLevelInfo`).
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct sheaf_scene_info {
    /// Triangles of every live instance (each instance counts its
    /// geometry's triangles).
    pub instanced_triangles: u64,
    pub geometries: u32,
    /// Live instances whose geometry has triangles.
    pub instances: u32,
    /// Top-level nodes and depth.
    pub nodes: u32,
    pub depth: u32,
    /// World bounds of the instances.
    pub bounds_min: [f32; 3],
    pub bounds_max: [f32; 3],
    /// The triangle budget (`max_scene_triangles`) left free, and its
    /// longest free run: a geometry set needing more than the run but no
    /// more than the free triangles first slides the runs together.
    pub free_triangles: u32,
    pub largest_free_run: u32,
    /// Such compactions since the context was made, and the triangles they
    /// moved (140 bytes of pool entries each). Difference two commits'
    /// values for the cost per commit. The no_std core measures no time;
    /// docs/studies.md times the moves.
    pub compactions: u32,
    pub compacted_triangles: u64,
}

impl sheaf_scene_info {
    fn of(i: &TwoLevelInfo) -> Self {
        sheaf_scene_info {
            instanced_triangles: i.instanced_triangles,
            geometries: i.geometries,
            instances: i.instances,
            nodes: i.nodes,
            depth: i.depth,
            bounds_min: i.bounds.min.to_array(),
            bounds_max: i.bounds.max.to_array(),
            free_triangles: i.free_triangles,
            largest_free_run: i.largest_free_run,
            compactions: i.compactions,
            compacted_triangles: i.compacted_triangles,
        }
    }
}

/// Write the default geometry parameters (STATIC, the mesh's triangle
/// count reserved, NULL BVH and refit parameters: their defaults, every
/// mask bit) to `*out`, a struct of `size` bytes (sheaf.h's macro passes
/// `sizeof *out`; see `sheaf_limits_default`).
///
/// `out` must not be NULL. Errors: `SHEAF_STATUS_INVALID_ARGUMENT` when
/// `size` is no size of this struct. Thread-safe.
#[unsafe(no_mangle)]
pub extern "C" fn sheaf_geometry_params_default(
    out: *mut sheaf_geometry_params,
    size: usize,
) -> super::sheaf_status {
    sized::write_defaults(out, size)
}

/// Set geometry `id` (`< max_geometries`) of the two-level scene to
/// `*mesh` (replacing it if set), building its BVH with `*params` (NULL:
/// the defaults) in a run of the scene's triangle budget. `*mesh` is read
/// during this call only. On error nothing changes (a committed scene
/// stays committed). After a success the scene must be committed
/// (`sheaf_context_commit_scene`) before it is traced again.
///
/// The budget does not fragment: when the free triangles suffice but no
/// gap between the geometries' runs holds the reservation, the runs are
/// slid together first (each BVH moves with its run, unchanged; a
/// committed scene stays committed and answers as before, and nothing is
/// allocated). A replaced geometry that does not fit its own run keeps
/// it until the new one is built, so both must fit at once.
///
/// Errors: `SHEAF_STATUS_NULL_POINTER`, `SHEAF_STATUS_INVALID_ARGUMENT`
/// (no two-level scene, id out of range, another triangle test than the
/// scene's, the projection test without `projection_test` in the limits,
/// bad params or mesh), `SHEAF_STATUS_MISALIGNED`,
/// `SHEAF_STATUS_INDEX_OUT_OF_RANGE`, `SHEAF_STATUS_CAPACITY_TRIANGLES`
/// (a mesh of more triangles than `params->max_triangles`, or fewer free
/// triangles than the reservation), `SHEAF_STATUS_CONTEXT_BUSY`,
/// `SHEAF_STATUS_POISONED`.
///
/// Not thread-safe: needs exclusive access to `ctx`.
#[unsafe(no_mangle)]
pub extern "C" fn sheaf_context_set_scene_geometry(
    ctx: *mut sheaf_context,
    id: u32,
    mesh: *const sheaf_mesh,
    params: *const sheaf_geometry_params,
) -> super::sheaf_status {
    with_mut(ctx, |h| {
        let g = read_in(mesh)?.geometry()?;
        let p = sized::or_default(params)?;
        h.ctx.set_geometry(id, &g.scene()?, &p)?;
        Ok(())
    })
}

/// Update geometry `id` to `*mesh` as its mode says: REFIT (the same
/// triangles, vertices moved; `*out`, if not NULL, receives what the refit
/// did) or REBUILD (new triangles, up to the geometry's run: its
/// reservation, or the larger run of a geometry it replaced in place;
/// `*out` is zeroed). On error nothing changes (the previous BVH stays and
/// a committed scene stays committed). After a success, commit before
/// tracing.
///
/// Errors: as `sheaf_context_set_scene_geometry`, and
/// `SHEAF_STATUS_INVALID_ARGUMENT` for a STATIC geometry, an id not set,
/// or (REFIT) another triangle count than the build's;
/// `SHEAF_STATUS_CAPACITY_TRIANGLES` for a REBUILD past the run.
///
/// Not thread-safe: needs exclusive access to `ctx`.
#[unsafe(no_mangle)]
pub extern "C" fn sheaf_context_update_scene_geometry(
    ctx: *mut sheaf_context,
    id: u32,
    mesh: *const sheaf_mesh,
    out: *mut sheaf_refit_info,
) -> super::sheaf_status {
    with_mut(ctx, |h| {
        let g = read_in(mesh)?.geometry()?;
        let u = h.ctx.update_geometry(id, &g.scene()?)?;
        write_wanted(
            out,
            u.refit
                .map(|r| sheaf_refit_info::of(&r))
                .unwrap_or_default(),
        );
        Ok(())
    })
}

/// Remove geometry `id`, giving its triangles back to the budget.
///
/// Errors: `SHEAF_STATUS_INVALID_ARGUMENT` (no two-level scene, not set,
/// or still placed by an instance), `SHEAF_STATUS_CONTEXT_BUSY`,
/// `SHEAF_STATUS_POISONED`. Nothing changes on error.
///
/// Not thread-safe: needs exclusive access to `ctx`.
#[unsafe(no_mangle)]
pub extern "C" fn sheaf_context_remove_scene_geometry(
    ctx: *mut sheaf_context,
    id: u32,
) -> super::sheaf_status {
    with_mut(ctx, |h| h.ctx.remove_geometry(id))
}

/// Set instance `id` (`< max_instances`): geometry `geometry` placed by
/// `transform`, 12 floats of a row-major 3x4 object-to-world matrix (as
/// Embree's `RTC_FORMAT_FLOAT3X4_ROW_MAJOR`), seen by rays whose mask
/// shares a bit with `mask`. sheaf stores the inverse.
///
/// Errors: `SHEAF_STATUS_NULL_POINTER`, `SHEAF_STATUS_INVALID_ARGUMENT`
/// (no two-level scene, id out of range, geometry not set, a NaN or
/// infinite entry, a singular transform or one whose inverse does not
/// fit f32),
/// `SHEAF_STATUS_CONTEXT_BUSY`, `SHEAF_STATUS_POISONED`. Nothing changes
/// on error.
///
/// Not thread-safe: needs exclusive access to `ctx`.
#[unsafe(no_mangle)]
pub extern "C" fn sheaf_context_set_instance(
    ctx: *mut sheaf_context,
    id: u32,
    geometry: u32,
    transform: *const f32,
    mask: u32,
) -> super::sheaf_status {
    with_mut(ctx, |h| {
        let m = read_in(transform.cast::<[[f32; 4]; 3]>())?;
        h.ctx.set_instance(id, geometry, &Affine { m }, mask)
    })
}

/// Remove instance `id`.
///
/// Errors: `SHEAF_STATUS_INVALID_ARGUMENT` (no two-level scene, not set),
/// `SHEAF_STATUS_CONTEXT_BUSY`, `SHEAF_STATUS_POISONED`. Nothing changes
/// on error.
///
/// Not thread-safe: needs exclusive access to `ctx`.
#[unsafe(no_mangle)]
pub extern "C" fn sheaf_context_remove_instance(
    ctx: *mut sheaf_context,
    id: u32,
) -> super::sheaf_status {
    with_mut(ctx, |h| h.ctx.remove_instance(id))
}

/// Build the top level over the instances as they are now: after any
/// change to geometries or instances, before tracing. `out` may be NULL.
///
/// Errors: `SHEAF_STATUS_INVALID_ARGUMENT` (no two-level scene),
/// `SHEAF_STATUS_CONTEXT_BUSY`, `SHEAF_STATUS_POISONED`.
///
/// Not thread-safe: needs exclusive access to `ctx`.
#[unsafe(no_mangle)]
pub extern "C" fn sheaf_context_commit_scene(
    ctx: *mut sheaf_context,
    out: *mut sheaf_scene_info,
) -> super::sheaf_status {
    with_mut(ctx, |h| {
        let info = h.ctx.commit_scene()?;
        write_wanted(out, sheaf_scene_info::of(&info));
        Ok(())
    })
}

/// Nearest hits of `count` rays in the committed two-level scene, among
/// instances whose mask shares a bit with `mask`, into `hits`. `params`
/// NULL: one single ray each (the 4-wide single ray in every geometry);
/// else `params->method` with its packet side, the rays taken in order as
/// packets as `sheaf_context_trace_with` takes them. Every BVH method
/// gives the same hits, bit for bit. A grid or kd-tree method traces the
/// flattened scene its `sheaf_context_build_scene_*` built for this
/// commit and `mask` (each bitwise its own single ray; t, u, v of the
/// world triangle). `flags`: 0, or one of `SHEAF_RAY_FLAG_CULL_*` to skip
/// back- or front-facing triangles (BVH methods and single rays; every
/// method gives the same hits with the same flags). The Rust API's
/// `Context::trace_scene_with` with `RayControls`.
///
/// Thread-safe: any number of threads may trace one committed scene at
/// once with `params` NULL (no thread slot is taken); with `params` every
/// call takes a free thread slot for its packets' scratch, as
/// `sheaf_context_trace_with` does, so at most `max_threads` at once.
///
/// Errors: `SHEAF_STATUS_NULL_POINTER`, `SHEAF_STATUS_INVALID_ARGUMENT`
/// (no two-level scene, bad params, count, overlap, a grid or kd method
/// for another mask than its build's or with culling, unknown or both
/// culling flags), `SHEAF_STATUS_NOT_BUILT` (changed
/// since the last commit; a grid or kd method without a
/// `sheaf_context_build_scene_*` of this commit),
/// `SHEAF_STATUS_CAPACITY_THREADS` (with `params`: no free slot),
/// `SHEAF_STATUS_CONTEXT_BUSY` (an exclusive call is inside),
/// `SHEAF_STATUS_POISONED`. `hits` is written only on success.
#[unsafe(no_mangle)]
pub extern "C" fn sheaf_context_trace_scene(
    ctx: *const sheaf_context,
    params: *const sheaf_trace_params,
    rays: *const sheaf_ray,
    hits: *mut sheaf_scene_hit,
    count: usize,
    mask: u32,
    flags: u32,
) -> super::sheaf_status {
    with_ref(ctx, |h| {
        let ctl = controls(mask, flags)?;
        check_rays_out(rays, hits.cast_const(), count, "rays and hits overlap")?;
        trace_scene_rays(h, params, rays, count, ctl, false, |i, hit| {
            // SAFETY: i < count; `hits` checked to span count writable
            // elements, not overlapping the rays.
            unsafe { hits.add(i).write_unaligned(hit.into()) }
        })
    })
}

/// Whether anything blocks each of `count` rays in `[tmin, tmax)`
/// (instances and `params` as in `sheaf_context_trace_scene`): 1 or 0
/// into `occluded`. Thread-safe as `sheaf_context_trace_scene`; same
/// errors.
#[unsafe(no_mangle)]
pub extern "C" fn sheaf_context_occluded_scene(
    ctx: *const sheaf_context,
    params: *const sheaf_trace_params,
    rays: *const sheaf_ray,
    occluded: *mut u8,
    count: usize,
    mask: u32,
    flags: u32,
) -> super::sheaf_status {
    with_ref(ctx, |h| {
        let ctl = controls(mask, flags)?;
        check_rays_out(
            rays,
            occluded.cast_const(),
            count,
            "rays and results overlap",
        )?;
        trace_scene_rays(h, params, rays, count, ctl, true, |i, hit| {
            // SAFETY: i < count; `occluded` checked to span count bytes.
            unsafe { occluded.add(i).write(u8::from(hit.is_hit())) }
        })
    })
}

/// The two scene trace calls once their arrays are checked: `count` rays
/// read from `rays` and traced (`any`: for occlusion) with `*params` (NULL:
/// single rays) among the instances `ctl` lets through, each result handed
/// to `out`.
fn trace_scene_rays(
    h: &Handle,
    params: *const sheaf_trace_params,
    rays: *const sheaf_ray,
    count: usize,
    ctl: RayControls,
    any: bool,
    out: impl FnMut(usize, SceneHit),
) -> Result<()> {
    let p = sized::optional(params)?;
    h.ctx.scene_view()?;
    // SAFETY: i < count; the caller checked `rays` spans count readable
    // elements (C contract; unaligned reads allowed).
    let read = |i: usize| Ray::from(unsafe { rays.add(i).read_unaligned() });
    h.ctx
        .trace_scene_each(p.as_ref(), None, count, ctl, any, read, out)?;
    Ok(())
}

/// Rebuild the uniform grid over the committed scene's instances that
/// `mask` sees, flattened into world triangles (`params` NULL: the
/// defaults). `sheaf_context_trace_scene` then traces it with the grid's
/// methods for that `mask`. Needs `SHEAF_STRUCTURE_GRID` and a two-level
/// scene; the flattening takes up to `max_triangles` world triangles.
/// The structures built over the scene share one flattening: building
/// one for another mask, or after a new commit, leaves the others
/// answering `SHEAF_STATUS_NOT_BUILT` until they are rebuilt. On error
/// nothing the structures answer changes.
///
/// Errors: `SHEAF_STATUS_INVALID_ARGUMENT` (no two-level scene or grid
/// pools, params), `SHEAF_STATUS_NOT_BUILT` (changed since the last
/// commit), `SHEAF_STATUS_CAPACITY_TRIANGLES` (more world triangles than
/// `max_triangles`), the grid's capacities, `SHEAF_STATUS_CONTEXT_BUSY`,
/// `SHEAF_STATUS_POISONED`.
///
/// Not thread-safe: needs exclusive access to `ctx`.
#[unsafe(no_mangle)]
pub extern "C" fn sheaf_context_build_scene_grid(
    ctx: *mut sheaf_context,
    params: *const sheaf_grid_params,
    mask: u32,
) -> super::sheaf_status {
    build_scene(ctx, params, |c, p| c.build_grid_scene(p, mask))
}

/// Rebuild the kd-tree over the committed scene's instances that `mask`
/// sees (as `sheaf_context_build_scene_grid`; `SHEAF_STRUCTURE_KD`).
///
/// Not thread-safe: needs exclusive access to `ctx`.
#[unsafe(no_mangle)]
pub extern "C" fn sheaf_context_build_scene_kd(
    ctx: *mut sheaf_context,
    params: *const sheaf_kd_params,
    mask: u32,
) -> super::sheaf_status {
    build_scene(ctx, params, |c, p| c.build_kd_scene(p, mask))
}

/// Load the committed scene's instances that `mask` sees for the
/// perspective and light grids (as `sheaf_context_build_scene_grid`;
/// `SHEAF_STRUCTURE_PGRID`). A deferred frame's pixel hits are then world
/// triangles of the flattened scene: `sheaf_context_scene_prim` names
/// their geometry, instance and triangle.
///
/// Not thread-safe: needs exclusive access to `ctx`.
#[unsafe(no_mangle)]
pub extern "C" fn sheaf_context_build_scene_pgrid(
    ctx: *mut sheaf_context,
    params: *const sheaf_pgrid_params,
    mask: u32,
) -> super::sheaf_status {
    build_scene(ctx, params, |c, p| c.build_pgrid_scene(p, mask))
}

/// `*hit`, a hit of `structure` (`SHEAF_STRUCTURE_GRID`, `_KD` or
/// `_PGRID`: a deferred frame's pixel after
/// `sheaf_context_build_scene_pgrid`) on the flattened scene, as a scene
/// hit into `*out`: the same t, u, v with its geometry, instance and the
/// geometry's own triangle id. A miss maps to a miss.
///
/// Errors: `SHEAF_STATUS_NULL_POINTER`, `SHEAF_STATUS_NOT_BUILT`
/// (`structure` does not answer for the current commit: not built over
/// it, the scene changed or was committed since, or a build for another
/// mask flattened the scene again), `SHEAF_STATUS_INVALID_ARGUMENT`
/// (another `structure`, or `hit->prim` not a world triangle of it),
/// `SHEAF_STATUS_CONTEXT_BUSY`, `SHEAF_STATUS_POISONED`.
///
/// Thread-safe: reads only.
#[unsafe(no_mangle)]
pub extern "C" fn sheaf_context_scene_prim(
    ctx: *const sheaf_context,
    structure: u32,
    hit: *const sheaf_hit,
    out: *mut sheaf_scene_hit,
) -> super::sheaf_status {
    with_ref(ctx, |h| {
        let hit = read_in(hit)?;
        check_non_null!(out);
        write_out(out, h.ctx.scene_prim(structure, &hit.into())?.into());
        Ok(())
    })
}

/// `flags` of `sheaf_context_trace_scene`: skip back-facing triangles
/// (C: `SHEAF_RAY_FLAG_CULL_BACK_FACING`).
pub const SHEAF_RAY_FLAG_CULL_BACK_FACING: u32 = 1;
/// `flags` of `sheaf_context_trace_scene`: skip front-facing triangles
/// (C: `SHEAF_RAY_FLAG_CULL_FRONT_FACING`).
pub const SHEAF_RAY_FLAG_CULL_FRONT_FACING: u32 = 2;

/// `flags` of `sheaf_context_trace_scene`: skip every filter (DXR's
/// `RAY_FLAG_FORCE_OPAQUE`; C: `SHEAF_RAY_FLAG_FORCE_OPAQUE`).
pub const SHEAF_RAY_FLAG_FORCE_OPAQUE: u32 = 4;

/// A scene trace's mask and `SHEAF_RAY_FLAG_*` bits as `RayControls`.
pub(super) fn controls(mask: u32, flags: u32) -> Result<RayControls> {
    const BOTH: u32 = SHEAF_RAY_FLAG_CULL_BACK_FACING | SHEAF_RAY_FLAG_CULL_FRONT_FACING;
    let opaque = flags & SHEAF_RAY_FLAG_FORCE_OPAQUE != 0;
    let cull = match flags & !SHEAF_RAY_FLAG_FORCE_OPAQUE {
        0 => Cull::None,
        SHEAF_RAY_FLAG_CULL_BACK_FACING => Cull::Back,
        SHEAF_RAY_FLAG_CULL_FRONT_FACING => Cull::Front,
        BOTH => {
            return Err(Error::InvalidArgument(
                "cull back-facing and front-facing triangles: at most one",
            ));
        }
        _ => return Err(Error::InvalidArgument("unknown SHEAF_RAY_FLAG_* bits")),
    };
    Ok(RayControls { mask, cull, opaque })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn params_round_trip() {
        let p = GeometryParams {
            mode: UpdateMode::Rebuild,
            max_triangles: 77,
            ..GeometryParams::default()
        };
        assert_eq!(sheaf_geometry_params::of(&p).to_core(), Ok(p));
        let bad = sheaf_geometry_params {
            mode: 3,
            ..sheaf_geometry_params::of(&p)
        };
        assert!(bad.to_core().is_err());
    }
}
