//! `sheaf_context`: the opaque handle and every call on it.
//!
//! The handle is a `Handle` struct placed at the start of the context's
//! memory, followed (at `HEADER_BYTES`, a multiple of 64) by the arena the
//! core `Context` carves its pools from. `sheaf_context_create_in` puts both
//! in the caller's buffer; `sheaf_context_create` makes one aligned
//! allocation of the same size and layout and frees it in
//! `sheaf_context_destroy`.

use super::bvh::{sheaf_bvh_params, sheaf_refit_info, sheaf_refit_params};
use super::limits::sheaf_limits;
use super::sized;
use super::sized::Versioned;
use super::trace_params::sheaf_trace_params;
use super::{
    SHEAF_CONTEXT_ALIGN, SHEAF_ERROR_MESSAGE_MAX, array_bytes, check_non_null, check_rays_out,
    guard_free, overlaps, raw, read_in, sheaf_frame, sheaf_grid_params, sheaf_method, sheaf_stats,
    sheaf_status, write_out, write_wanted,
};
use super::{sheaf_hit, sheaf_ray};
use crate::Band;
use crate::Limits;
use crate::TraceParams;
use crate::context::{Context, required_bytes};
use crate::error::{Error, Result};
use crate::{CallGate, Locked, Par};
use crate::{Ray, Scene};
use core::cell::UnsafeCell;
use core::ffi::{c_char, c_void};
use core::fmt::Write as _;
use core::ptr;
use core::sync::atomic::{AtomicU64, Ordering};

/// A sheaf context (opaque): fixed memory, the borrowed geometry, the
/// current acceleration structure, the last error.
///
/// Made by `sheaf_context_create` or `sheaf_context_create_in`, released by
/// `sheaf_context_destroy`.
///
/// Thread safety: the calls taking a `const sheaf_context *` are shared
/// calls (`sheaf_context_trace`, `_trace_with`, `_occluded`,
/// `_occluded_with`, `_stats`, `_deferred_pixel`, `_deferred_shadow_ray`,
/// and `_trace_slot`, `_occluded_slot`, `_render_rows`, each thread with
/// its own slot, `0 <= slot < sheaf_limits.max_threads`, which holds the
/// thread's mailbox): any number may run at once on one context. Every
/// other call on a context (set_geometry, clear_geometry, the builds,
/// render, render_with, render_whitted, render_deferred, destroy) is
/// exclusive: no other call on the same context may run at the same time.
/// `sheaf_context_last_error` may run at any time. Different contexts are
/// independent.
///
/// Misuse is detected, not raced: each context has a state word that
/// every call updates once on entry and once on exit (one atomic
/// operation each, not per ray). An exclusive call made while any other
/// call is inside, and any call made while an exclusive call runs, returns
/// `SHEAF_STATUS_CONTEXT_BUSY` at once and changes nothing; destroy
/// refuses new calls (as on a destroyed context) and waits for the ones
/// inside. What
/// cannot be detected: a call on a context whose memory was already freed
/// by `sheaf_context_destroy` (join threads before destroying), and caller
/// buffers (geometry, rays, framebuffers) freed or written by other
/// threads during a call.
///
/// After a caught panic (`SHEAF_STATUS_PANIC`, a bug in sheaf) the context
/// is poisoned: every later call but `sheaf_context_last_error` and
/// `sheaf_context_destroy` returns `SHEAF_STATUS_POISONED`.
pub struct sheaf_context {
    _private: [u8; 0],
}

const MAGIC: u64 = u64::from_le_bytes(*b"sheafctx");

/// The caller's geometry buffers as given to `sheaf_context_set_geometry`.
pub(super) struct Geometry {
    vertices: *const u8,
    vertices_len: usize,
    stride: usize,
    vertex_count: u32,
    indices: *const u32,
    index_count: usize,
}

impl Geometry {
    /// The caller's buffers, checked as `sheaf_context_set_geometry`
    /// documents (pointers, stride, sizes, alignment) before any slice is
    /// formed over them; the indices are checked by `scene`.
    pub(super) fn new(
        vertices: *const f32,
        vertex_stride_bytes: usize,
        vertex_count: u32,
        indices: *const u32,
        triangle_count: u32,
    ) -> Result<Geometry> {
        if vertex_count > 0 {
            check_non_null!(vertices);
        }
        if triangle_count > 0 {
            check_non_null!(indices);
        }
        // The stride is checked before any slice is formed over the buffer.
        if vertex_stride_bytes < 12 || !vertex_stride_bytes.is_multiple_of(4) {
            return Err(Error::InvalidArgument(
                "vertex stride must be >= 12 and a multiple of 4",
            ));
        }
        let vertices_len = if vertex_count == 0 {
            0
        } else {
            (vertex_count as usize - 1)
                .checked_mul(vertex_stride_bytes)
                .and_then(|b| b.checked_add(12))
                .filter(|&b| b <= isize::MAX as usize)
                .ok_or(Error::InvalidArgument("vertex buffer size overflows"))?
        };
        let index_count = (triangle_count as usize)
            .checked_mul(3)
            .ok_or(Error::InvalidArgument("too many triangles"))?;
        array_bytes::<u32>(index_count, "index buffer size overflows")?;
        if triangle_count > 0 && !indices.is_aligned() {
            return Err(Error::Misaligned {
                required: core::mem::align_of::<u32>() as u32,
            });
        }
        Ok(Geometry {
            vertices: vertices.cast(),
            vertices_len,
            stride: vertex_stride_bytes,
            vertex_count,
            indices,
            index_count,
        })
    }

    /// The borrowed scene, validated again (indices may have been changed
    /// in place since `set_geometry`).
    pub(super) fn scene(&self) -> Result<Scene<'_>> {
        let vertices: &[u8] = if self.vertices_len == 0 {
            &[]
        } else {
            // SAFETY: non-NULL and checked to span `vertices_len` bytes
            // (<= isize::MAX) in set_geometry; the C contract of
            // set_geometry keeps the buffer alive and unwritten during
            // calls that read it, until the next set_geometry or destroy.
            unsafe { core::slice::from_raw_parts(self.vertices, self.vertices_len) }
        };
        let indices: &[u32] = if self.index_count == 0 {
            &[]
        } else {
            // SAFETY: non-NULL, 4-byte aligned and size-checked in
            // set_geometry; alive and unwritten during this call by the same
            // contract as the vertices.
            unsafe { core::slice::from_raw_parts(self.indices, self.index_count) }
        };
        Scene::new(vertices, self.stride, self.vertex_count, indices)
    }
}

/// What a `sheaf_context *` points to: the words calls from any thread
/// read (magic, state, last error) and, in an `UnsafeCell`, the part only
/// a registered call touches (`Handle`), shared or exclusive as the state
/// word says.
struct Header {
    /// `MAGIC` from creation on (catches pointers that never were a
    /// context); destroy marks the state word instead, which also catches
    /// calls on a destroyed `create_in` context, whose memory stays valid.
    magic: AtomicU64,
    /// Shared calls inside, an exclusive call, poisoned, destroyed (`CallGate`).
    state: CallGate,
    /// The last failure of a call on this context (never cleared by a
    /// success; busy refusals are not recorded).
    last_error: Locked<Option<Error>>,
    /// Size of the allocation made by `sheaf_context_create` (None: the
    /// caller's buffer).
    alloc_bytes: Option<usize>,
    /// Where the caller's threads join a build (`sheaf_context_build_bvh_joined`).
    join: crate::Join,
    handle: UnsafeCell<Handle>,
}

/// The context proper: the core `Context` and the borrowed geometry.
pub(super) struct Handle {
    pub(super) ctx: Context<'static>,
    pub(super) geometry: Option<Geometry>,
}

/// Bytes of the handle header in front of the arena (a multiple of 64).
pub const HEADER_BYTES: usize =
    core::mem::size_of::<Header>().next_multiple_of(SHEAF_CONTEXT_ALIGN);
const _: () = assert!(core::mem::align_of::<Header>() <= SHEAF_CONTEXT_ALIGN);

/// Total bytes of a context: header plus the core's pools.
fn total_bytes(limits: &Limits) -> Result<usize> {
    required_bytes(limits)?
        .checked_add(HEADER_BYTES)
        .filter(|&b| b <= isize::MAX as usize - SHEAF_CONTEXT_ALIGN)
        .ok_or(Error::InvalidArgument(
            "limits need more memory than can be addressed",
        ))
}

/// Check a handle pointer: non-NULL, aligned, alive.
fn header<'h>(ctx: *const sheaf_context) -> Result<&'h Header> {
    check_non_null!(ctx);
    if crate::geom::filter::inside() {
        return Err(Error::Reentrant);
    }
    let h = ctx.cast::<Header>();
    if !h.is_aligned() {
        return Err(Error::InvalidArgument("not a sheaf_context"));
    }
    // SAFETY: a non-NULL handle comes from sheaf_context_create(_in) (C
    // contract), so the header is readable; only the atomic magic word is
    // read before it is known to be alive.
    let magic = unsafe { &(*h).magic }.load(Ordering::Acquire);
    if magic != MAGIC {
        return Err(Error::InvalidArgument(
            "not a live sheaf_context (destroyed?)",
        ));
    }
    // SAFETY: alive; every field other calls may touch concurrently is an
    // atomic, the last-error lock, or behind the UnsafeCell.
    Ok(unsafe { &*h })
}

/// Finish a registered call: a failure becomes the last error (a panic
/// also poisons the context), recorded while the call is still registered
/// so a concurrent destroy cannot free the header under it.
fn settle(hd: &Header, r: Result<()>) -> Result<()> {
    if let Err(e) = r {
        if e == Error::Panic {
            hd.state.poison();
        }
        hd.last_error.set(Some(e));
    }
    r
}

/// Run `f` on a shared handle (calls that may run concurrently), behind
/// the panic boundary, recording a failure in the handle. Refused with
/// `Error::ContextBusy` (not recorded) while an exclusive call runs.
pub(super) fn with_ref(
    ctx: *const sheaf_context,
    f: impl FnOnce(&Handle) -> Result<()>,
) -> sheaf_status {
    guard_free(|| {
        let hd = header(ctx)?;
        let _in = hd.state.enter_shared()?;
        // SAFETY: registered as a shared call: no exclusive call (the only
        // ones making a `&mut Handle`) can start until `_in` drops.
        let r = super::catch(|| f(unsafe { &*hd.handle.get() }));
        settle(hd, r)
    })
}

/// Run `f` on the exclusively borrowed handle (calls that need exclusive
/// access), behind the panic boundary, recording a failure in the handle.
/// Refused with `Error::ContextBusy` (not recorded) while any other call
/// is inside.
pub(super) fn with_mut(
    ctx: *mut sheaf_context,
    f: impl FnOnce(&mut Handle) -> Result<()>,
) -> sheaf_status {
    guard_free(|| {
        let hd = header(ctx)?;
        let _in = hd.state.enter_exclusive()?;
        // SAFETY: the state word gives this call the context alone until
        // `_in` drops: no other reference to the Handle exists.
        let r = super::catch(|| f(unsafe { &mut *hd.handle.get() }));
        settle(hd, r)
    })
}

/// Build a context in `base[..need]`.
///
/// # Safety
/// `base` is `SHEAF_CONTEXT_ALIGN`-aligned, valid for reads and writes of
/// `need = total_bytes(limits)` bytes, and used by nothing else until
/// `sheaf_context_destroy`.
unsafe fn place(
    base: *mut u8,
    need: usize,
    limits: &Limits,
    alloc_bytes: Option<usize>,
) -> Result<*mut sheaf_context> {
    // SAFETY: in bounds by the contract; initialises every byte so the
    // slice below covers initialised memory.
    unsafe { ptr::write_bytes(base, 0, need) };
    // SAFETY: [HEADER_BYTES, need) is in bounds, initialised, and used only
    // by the context (the header lies before it); 'static stands for "until
    // destroy", which the handle enforces by owning the context.
    let arena: &'static mut [u8] =
        unsafe { core::slice::from_raw_parts_mut(base.add(HEADER_BYTES), need - HEADER_BYTES) };
    let ctx = Context::new_in(arena, limits)?;
    let h = base.cast::<Header>();
    // SAFETY: aligned (64 >= align_of::<Header>()), in bounds (HEADER_BYTES
    // >= size_of::<Header>()), disjoint from the arena.
    unsafe {
        h.write(Header {
            magic: AtomicU64::new(MAGIC),
            state: CallGate::new(),
            last_error: Locked::new(None),
            alloc_bytes,
            join: crate::Join::new(),
            handle: UnsafeCell::new(Handle {
                ctx,
                geometry: None,
            }),
        });
    }
    Ok(h.cast())
}

/// Bytes `sheaf_context_create_in` needs for `*limits`, written to `*out`.
///
/// Exact, and includes everything: the handle itself and every pool
/// (triangles, grid cells and references, per-thread slots). The buffer
/// must also start on a `SHEAF_CONTEXT_ALIGN` (64) byte boundary.
///
/// Errors: `SHEAF_STATUS_NULL_POINTER`; `SHEAF_STATUS_INVALID_ARGUMENT` when
/// a limit is outside its domain (see `sheaf_limits`).
///
/// Thread-safe.
#[unsafe(no_mangle)]
pub extern "C" fn sheaf_required_bytes(
    limits: *const sheaf_limits,
    out: *mut usize,
) -> sheaf_status {
    guard_free(|| {
        let limits = sized::to_core(limits)?;
        check_non_null!(out);
        let need = total_bytes(&limits)?;
        write_out(out, need);
        Ok(())
    })
}

/// Create a context inside the caller's memory; never allocates.
///
/// `buf` must start on a `SHEAF_CONTEXT_ALIGN` (64) byte boundary and hold
/// at least `sheaf_required_bytes(limits)` bytes (`len`); the context (its
/// handle included) uses exactly that many bytes from `buf` and nothing
/// else. The caller keeps ownership of `buf`: it must stay valid and must
/// not be touched until `sheaf_context_destroy(*out)`, after which it may
/// be freed or reused. `*limits` is copied.
///
/// On success `*out` is the new context; on failure `*out` is unchanged.
/// Errors: `SHEAF_STATUS_NULL_POINTER`, `SHEAF_STATUS_INVALID_ARGUMENT`
/// (limits, or `out` inside the buffer's first `sheaf_required_bytes`
/// bytes), `SHEAF_STATUS_MISALIGNED`, `SHEAF_STATUS_BUFFER_TOO_SMALL`.
///
/// Thread-safe (for distinct buffers).
#[unsafe(no_mangle)]
pub extern "C" fn sheaf_context_create_in(
    buf: *mut c_void,
    len: usize,
    limits: *const sheaf_limits,
    out: *mut *mut sheaf_context,
) -> sheaf_status {
    guard_free(|| {
        check_non_null!(buf);
        let limits = sized::to_core(limits)?;
        check_non_null!(out);
        let need = total_bytes(&limits)?;
        if !(buf as usize).is_multiple_of(SHEAF_CONTEXT_ALIGN) {
            return Err(Error::Misaligned {
                required: SHEAF_CONTEXT_ALIGN as u32,
            });
        }
        if len < need {
            return Err(Error::BufferTooSmall {
                needed: need as u64,
                available: len as u64,
            });
        }
        // `*out` is written after the context is placed: inside the buffer
        // it would overwrite the new context's header.
        if overlaps(
            out.cast_const().cast(),
            core::mem::size_of::<*mut sheaf_context>(),
            buf.cast_const().cast(),
            need,
        ) {
            return Err(Error::InvalidArgument("out points into the context buffer"));
        }
        // SAFETY: aligned and at least `need` bytes (checked above); the C
        // contract hands the buffer to the context until destroy.
        let h = unsafe { place(buf.cast(), need, &limits, None)? };
        write_out(out, h);
        Ok(())
    })
}

/// Create a context with exactly one allocation of
/// `sheaf_required_bytes(limits)` bytes (the same layout as
/// `sheaf_context_create_in`); no call on the context allocates afterwards.
///
/// On success `*out` is the new context, owned by the caller, released
/// with `sheaf_context_destroy`; on failure `*out` is unchanged. `*limits`
/// is copied.
/// Errors: `SHEAF_STATUS_NULL_POINTER`, `SHEAF_STATUS_INVALID_ARGUMENT`
/// (limits), `SHEAF_STATUS_OUT_OF_MEMORY`.
///
/// Thread-safe.
///
/// Only in builds with the `std` feature (the no_std library has no
/// allocator: use `sheaf_context_create_in`).
#[cfg(feature = "std")]
#[unsafe(no_mangle)]
pub extern "C" fn sheaf_context_create(
    limits: *const sheaf_limits,
    out: *mut *mut sheaf_context,
) -> sheaf_status {
    let mut oom = false;
    let s = guard_free(|| {
        let limits = sized::to_core(limits)?;
        check_non_null!(out);
        let need = total_bytes(&limits)?;
        let layout = std::alloc::Layout::from_size_align(need, SHEAF_CONTEXT_ALIGN)
            .map_err(|_| Error::InvalidArgument("limits need more memory than can be addressed"))?;
        // SAFETY: `need >= HEADER_BYTES > 0`, so the layout is not zero-sized.
        let base = unsafe { std::alloc::alloc(layout) };
        if base.is_null() {
            // The crate's Error has no allocation failure (the core never
            // allocates): flag it and report SHEAF_STATUS_OUT_OF_MEMORY.
            oom = true;
            return Ok(());
        }
        // SAFETY: a fresh allocation of `need` bytes aligned to 64, owned by
        // the context until destroy frees it with the same layout.
        match unsafe { place(base, need, &limits, Some(need)) } {
            Ok(h) => {
                write_out(out, h);
                Ok(())
            }
            Err(e) => {
                // SAFETY: allocated above with `layout`, not handed out.
                unsafe { std::alloc::dealloc(base, layout) };
                Err(e)
            }
        }
    });
    if oom { sheaf_status::OutOfMemory } else { s }
}

/// Destroy a context. Accepts NULL (does nothing).
///
/// After `sheaf_context_create` this frees its one allocation; after
/// `sheaf_context_create_in` the caller's buffer may be freed or reused
/// afterwards. The borrowed geometry buffers are not touched. `ctx` must
/// not be used again. A poisoned context (`SHEAF_STATUS_POISONED`) can be
/// destroyed.
///
/// Not thread-safe, but guarded: from the moment destroy starts, every call
/// on `ctx` is refused (`SHEAF_STATUS_INVALID_ARGUMENT`, not a live
/// context), and destroy waits
/// for the calls already inside to return before it frees anything, so it
/// never frees memory a running call uses. What cannot be detected: a call
/// *starting* after destroy freed a `sheaf_context_create` context reads
/// freed memory (join the threads first). A second destroy of a
/// `create_in` context (whose memory stays valid) does nothing.
#[unsafe(no_mangle)]
pub extern "C" fn sheaf_context_destroy(ctx: *mut sheaf_context) {
    if ctx.is_null() {
        return;
    }
    let _ = guard_free(|| {
        let hd = header(ctx)?;
        if !hd.state.enter_destroy() {
            return Ok(()); // another destroy is doing it
        }
        let alloc_bytes = hd.alloc_bytes;
        let h = ctx.cast::<Header>();
        // SAFETY: a live header taken for destroy (no call inside, none can
        // enter: the dying bit stays set). The header is
        // dropped in place (the context before the memory it lives in),
        // then the allocation, if any, is freed with the layout it was made
        // with.
        unsafe {
            ptr::drop_in_place(h);
            #[cfg(feature = "std")]
            if let Some(bytes) = alloc_bytes {
                std::alloc::dealloc(
                    h.cast(),
                    std::alloc::Layout::from_size_align_unchecked(bytes, SHEAF_CONTEXT_ALIGN),
                );
            }
        }
        #[cfg(not(feature = "std"))]
        let _ = alloc_bytes; // always None: no_std has no sheaf_context_create
        Ok(())
    });
}

/// Drop the borrowed geometry: from the successful return on, sheaf never
/// reads the buffers of the last successful `sheaf_context_set_geometry`
/// again, so they may be freed. Built structures keep their own copy of
/// the triangles and still trace and render; builds return
/// `SHEAF_STATUS_NO_GEOMETRY` until the next successful
/// `sheaf_context_set_geometry`. Clearing a context without geometry is
/// not an error.
///
/// Not thread-safe: needs exclusive access to `ctx`
/// (`SHEAF_STATUS_CONTEXT_BUSY` while another call runs on it).
///
/// Errors: `SHEAF_STATUS_NULL_POINTER`, `SHEAF_STATUS_INVALID_ARGUMENT`
/// (not a live context), `SHEAF_STATUS_CONTEXT_BUSY`,
/// `SHEAF_STATUS_POISONED`.
#[unsafe(no_mangle)]
pub extern "C" fn sheaf_context_clear_geometry(ctx: *mut sheaf_context) -> sheaf_status {
    with_mut(ctx, |h| {
        h.geometry = None;
        Ok(())
    })
}

/// Set the scene's triangles, borrowing the caller's buffers (zero copy).
///
/// `vertex_count` vertices of three floats (x, y, z) start at `vertices`,
/// `vertex_stride_bytes` apart (>= 12, a multiple of 4; extra per-vertex
/// data in between is ignored), so an interleaved engine buffer can be
/// passed as it is. `indices` holds `3 * triangle_count` vertex indices
/// (4-byte aligned). A pointer may be NULL only when its count is 0.
///
/// Validates every index and the counts against the limits. Triangles with
/// NaN/infinite vertices or zero area are not errors: builds skip them and
/// count them in `sheaf_stats`. On error nothing changes: the previous
/// geometry stays set (and borrowed) and the built structure stays valid.
///
/// Lifetime: the buffers are borrowed, not copied. They must stay alive
/// and unchanged until the next *successful* `sheaf_context_set_geometry`,
/// `sheaf_context_clear_geometry` or `sheaf_context_destroy` (a failed
/// call keeps the previous buffers borrowed: free them only after
/// clear_geometry), except that the caller may update them in place
/// between calls (to animate: write new positions, then call
/// `sheaf_context_build_grid` again; every build re-reads them and
/// re-validates the indices). They must not be written while a build runs.
/// Trace, occluded and render never read them (they use the copy made by
/// the last build).
///
/// Errors: `SHEAF_STATUS_NULL_POINTER`, `SHEAF_STATUS_INVALID_ARGUMENT`
/// (stride below 12 or not a multiple of 4, sizes), `SHEAF_STATUS_MISALIGNED`
/// (indices), `SHEAF_STATUS_INDEX_OUT_OF_RANGE`,
/// `SHEAF_STATUS_CAPACITY_TRIANGLES`, `SHEAF_STATUS_CAPACITY_VERTICES`,
/// `SHEAF_STATUS_CONTEXT_BUSY`, `SHEAF_STATUS_POISONED`.
///
/// Not thread-safe: needs exclusive access to `ctx`.
#[unsafe(no_mangle)]
pub extern "C" fn sheaf_context_set_geometry(
    ctx: *mut sheaf_context,
    vertices: *const f32,
    vertex_stride_bytes: usize,
    vertex_count: u32,
    indices: *const u32,
    triangle_count: u32,
) -> sheaf_status {
    with_mut(ctx, |h| {
        let g = Geometry::new(
            vertices,
            vertex_stride_bytes,
            vertex_count,
            indices,
            triangle_count,
        )?;
        h.ctx.check_scene(&g.scene()?)?;
        crate::fault_point!(SetGeometry);
        h.geometry = Some(g);
        Ok(())
    })
}

/// Rebuild the uniform grid from the current geometry (from scratch; the
/// per-frame call of an animation). `params` may be NULL for the defaults
/// (`sheaf_grid_params_default`); `*params` is copied.
///
/// Reads the geometry buffers (see `sheaf_context_set_geometry`); never
/// allocates. On error the previous grid stays valid and traces exactly
/// as before.
///
/// Errors: `SHEAF_STATUS_NO_GEOMETRY`, `SHEAF_STATUS_INVALID_ARGUMENT`
/// (lambda, macrocell, test), `SHEAF_STATUS_INDEX_OUT_OF_RANGE` (indices
/// changed in place), `SHEAF_STATUS_CAPACITY_GRID_CELLS`,
/// `SHEAF_STATUS_CAPACITY_GRID_REFS`, `SHEAF_STATUS_CAPACITY_TRIANGLES`.
///
/// Not thread-safe: needs exclusive access to `ctx`.
#[unsafe(no_mangle)]
pub extern "C" fn sheaf_context_build_grid(
    ctx: *mut sheaf_context,
    params: *const sheaf_grid_params,
) -> sheaf_status {
    build(ctx, params, |c, scene, p| c.build_grid(scene, p))
}

/// `sheaf_context_build_grid` on `thread_count` of the caller's threads,
/// joined as `sheaf_context_build_bvh_joined` joins them (same protocol,
/// same misuse notes): thread 0 leads and passes `params` (the helpers'
/// are not read), the others run their share of every step but the
/// resolution and return the leader's status. The grid is the same for
/// any `thread_count`.
///
/// Errors: as `sheaf_context_build_grid`; `SHEAF_STATUS_INVALID_ARGUMENT`
/// for `thread_count` 0 or above 16 or `thread_index >= thread_count`.
#[unsafe(no_mangle)]
pub extern "C" fn sheaf_context_build_grid_joined(
    ctx: *mut sheaf_context,
    params: *const sheaf_grid_params,
    thread_index: u32,
    thread_count: u32,
) -> sheaf_status {
    build_joined(
        ctx,
        params,
        thread_index,
        thread_count,
        |c, scene, p, par| c.build_grid_with(scene, p, par),
    )
}

/// Rebuild the BVH from the geometry with `*params` (copied; NULL: the
/// defaults of `sheaf_bvh_params_default`): a binned SAH build from scratch
/// (BVH paper section 5.1). The grid, if built, is untouched: a context may
/// hold both and trace each with its methods.
///
/// Reads the geometry buffers (see `sheaf_context_set_geometry`); never
/// allocates. On error the previous BVH stays valid and traces exactly as
/// before.
///
/// Errors: `SHEAF_STATUS_NO_GEOMETRY`, `SHEAF_STATUS_INVALID_ARGUMENT`
/// (params, or no BVH pools in `sheaf_limits.structures`),
/// `SHEAF_STATUS_INDEX_OUT_OF_RANGE`, `SHEAF_STATUS_CAPACITY_TRIANGLES`.
///
/// Not thread-safe: needs exclusive access to `ctx`.
#[unsafe(no_mangle)]
pub extern "C" fn sheaf_context_build_bvh(
    ctx: *mut sheaf_context,
    params: *const sheaf_bvh_params,
) -> sheaf_status {
    build(ctx, params, |c, scene, p| c.build_bvh(scene, p))
}

/// Build the BVH on `thread_count` of the caller's threads, which join
/// one build (as Embree's `rtcJoinCommitScene`; sheaf starts no thread):
/// every one of them calls this at about the same time with the same
/// `ctx`, `params` and `thread_count` and its own `thread_index` in
/// `0..thread_count`. Thread 0 leads (it takes the context as
/// `sheaf_context_build_bvh` does and runs the build's serial steps); the
/// others run their share of each parallel step and return when the build
/// ends, with the leader's status. The LOW build (`sheaf_build_quality`)
/// runs every step on all threads; MEDIUM and HIGH split the top of the
/// tree on the leader and the subtrees below it on all threads. Every
/// quality gives the same tree for any `thread_count`.
///
/// `thread_count` 1 is `sheaf_context_build_bvh`. At most 16 threads.
///
/// The leader returns only after every helper has left the build, so the
/// context may be destroyed once thread 0 returned. A helper joins the
/// build open when it calls, or the next one to open: it gets
/// `SHEAF_STATUS_INVALID_ARGUMENT` at once, and the build goes on without
/// it, when its `thread_count` is not the leader's or another helper
/// already took its `thread_index` (a helper waiting when a build opens
/// is always looked at by that build, never kept for a later one).
/// Misuse that cannot be detected: a thread of `0..thread_count` that
/// never calls leaves the others waiting forever (so does a duplicate
/// index that arrives after the build it duplicates ended: it waits for
/// the next one); destroying the context while helpers wait for a leader
/// that has not called yet; two groups of threads joining builds on one
/// context at once (a second leader waits for the first; a helper of one
/// group may serve or be refused by the other group's build, whose
/// leader then waits for it). A panic in any thread's part poisons the
/// context (`SHEAF_STATUS_PANIC` on the leader).
///
/// Errors: as `sheaf_context_build_bvh`; `SHEAF_STATUS_INVALID_ARGUMENT`
/// for `thread_count` 0 or above 16 or `thread_index >= thread_count`
/// (returned at once by every thread, none waits).
#[unsafe(no_mangle)]
pub extern "C" fn sheaf_context_build_bvh_joined(
    ctx: *mut sheaf_context,
    params: *const sheaf_bvh_params,
    thread_index: u32,
    thread_count: u32,
) -> sheaf_status {
    build_joined(
        ctx,
        params,
        thread_index,
        thread_count,
        |c, scene, p, par| c.build_bvh_with(scene, p, par),
    )
}

/// `sheaf_context_refit_bvh` on `thread_count` of the caller's threads,
/// joined as `sheaf_context_build_bvh_joined` joins them (same protocol,
/// same misuse notes): thread 0 leads and passes `params` and `out` (the
/// helpers' are not read), the others run their share of the refit's
/// triangle passes and leaf boxes and return the leader's status. The
/// refit tree, its boxes and `out` are the same for any `thread_count`.
/// A rebuild past `params->rebuild_above` runs on the joined threads too.
///
/// Errors: as `sheaf_context_refit_bvh`; `SHEAF_STATUS_INVALID_ARGUMENT`
/// for `thread_count` 0 or above 16 or `thread_index >= thread_count`.
#[unsafe(no_mangle)]
pub extern "C" fn sheaf_context_refit_bvh_joined(
    ctx: *mut sheaf_context,
    params: *const sheaf_refit_params,
    out: *mut sheaf_refit_info,
    thread_index: u32,
    thread_count: u32,
) -> sheaf_status {
    build_joined(
        ctx,
        params,
        thread_index,
        thread_count,
        |c, scene, p, par| {
            let r = c.refit_bvh_with(scene, p, par)?;
            write_wanted(out, sheaf_refit_info::of(&r));
            Ok(())
        },
    )
}

/// The joined calls' protocol: thread 0 leads (takes the context as an
/// exclusive call does and runs `work` with the session's workers),
/// threads `1..thread_count` help and return the leader's status.
pub(super) fn joined(
    ctx: *mut sheaf_context,
    thread_index: u32,
    thread_count: u32,
    work: impl FnOnce(&mut Handle, &dyn Par) -> Result<()>,
) -> sheaf_status {
    use crate::MAX_WORKERS;
    let (me, count) = (thread_index as usize, thread_count as usize);
    if count == 0 || me >= count || count > MAX_WORKERS {
        return guard_free(|| {
            Err(Error::InvalidArgument(
                "joined call: thread_count in 1..=16 and thread_index below it",
            ))
        });
    }
    if me > 0 {
        let mut outcome = 0u32;
        let s = guard_free(|| {
            let hd = header(ctx)?;
            match hd.join.help(me, count) {
                crate::Helped::Done(x) => {
                    outcome = x;
                    Ok(())
                }
                crate::Helped::NotAWorker => Err(Error::InvalidArgument(
                    "joined call: thread_count differs from the leader's",
                )),
                crate::Helped::Taken => Err(Error::InvalidArgument(
                    "joined call: thread_index already taken by another thread of this build",
                )),
            }
        });
        return if s == sheaf_status::Ok {
            sheaf_status::from_raw(outcome).unwrap_or(sheaf_status::Panic)
        } else {
            s
        };
    }
    guard_free(|| {
        let hd = header(ctx)?;
        // The session opens whatever happens next, so the helpers return;
        // `lead` returns when they have all left (and waits while another
        // joined call on this context leads).
        hd.join.lead(count, |par| {
            let r = (|| {
                let _in = hd.state.enter_exclusive()?;
                let r = super::catch(|| {
                    // SAFETY: the state word gives this call the context
                    // alone until `_in` drops: no other reference to the
                    // Handle exists (the helpers touch only the join).
                    let h = unsafe { &mut *hd.handle.get() };
                    work(h, par)
                });
                settle(hd, r)
            })();
            let status = match &r {
                Ok(()) => sheaf_status::Ok,
                Err(e) => sheaf_status::from_error(e),
            };
            hd.join.set_outcome(status as u32);
            r
        })
    })
}

// The body every build call shares (`sheaf_context_build_*`, their joined
// forms, `sheaf_context_refit_bvh`, the kd-tree's, the perspective grid's
// and the two-level scene's): exclusive access to the context (`with_mut`,
// or `joined` on the caller's threads), the parameter struct read (NULL:
// the crate's defaults), the input found (the borrowed geometry, or the
// committed two-level scene the core flattens), then the core's build.
// Each export passes its core call.

/// The core context and the borrowed geometry's scene, borrowed apart (a
/// build writes the one while it reads the other); `NoGeometry` without a
/// geometry.
fn ctx_and_scene(h: &mut Handle) -> Result<(&mut Context<'static>, Scene<'_>)> {
    let g = h.geometry.as_ref().ok_or(Error::NoGeometry)?;
    Ok((&mut h.ctx, g.scene()?))
}

/// The body of `sheaf_context_build_*` over the borrowed geometry (and of
/// `sheaf_context_refit_bvh`): with exclusive access, `*params` read (NULL:
/// the crate's defaults) before the geometry is looked up, then
/// `core_build` on the calling thread.
pub(super) fn build<T: Versioned, R>(
    ctx: *mut sheaf_context,
    params: *const T,
    core_build: impl FnOnce(&mut Context<'static>, &Scene<'_>, &T::Core) -> Result<R>,
) -> sheaf_status
where
    T::Core: Default,
{
    with_mut(ctx, |h| {
        let p = sized::or_default(params)?;
        let (c, scene) = ctx_and_scene(h)?;
        core_build(c, &scene, &p)?;
        Ok(())
    })
}

/// [`build`] on the caller's joined threads ([`joined`]): the leader reads
/// `*params` and the geometry, `core_build` gets the session's workers.
pub(super) fn build_joined<T: Versioned, R>(
    ctx: *mut sheaf_context,
    params: *const T,
    thread_index: u32,
    thread_count: u32,
    core_build: impl FnOnce(&mut Context<'static>, &Scene<'_>, &T::Core, &dyn Par) -> Result<R>,
) -> sheaf_status
where
    T::Core: Default,
{
    joined(ctx, thread_index, thread_count, |h, par| {
        let p = sized::or_default(params)?;
        let (c, scene) = ctx_and_scene(h)?;
        core_build(c, &scene, &p, par)?;
        Ok(())
    })
}

/// The body of `sheaf_context_build_scene_*`: [`build`] over the committed
/// two-level scene, which the core flattens, instead of the geometry.
pub(super) fn build_scene<T: Versioned, R>(
    ctx: *mut sheaf_context,
    params: *const T,
    core_build: impl FnOnce(&mut Context<'static>, &T::Core) -> Result<R>,
) -> sheaf_status
where
    T::Core: Default,
{
    with_mut(ctx, |h| {
        let p = sized::or_default(params)?;
        core_build(&mut h.ctx, &p)?;
        Ok(())
    })
}

/// [`build_scene`] on the caller's joined threads ([`joined`]).
pub(super) fn build_scene_joined<T: Versioned, R>(
    ctx: *mut sheaf_context,
    params: *const T,
    thread_index: u32,
    thread_count: u32,
    core_build: impl FnOnce(&mut Context<'static>, &T::Core, &dyn Par) -> Result<R>,
) -> sheaf_status
where
    T::Core: Default,
{
    joined(ctx, thread_index, thread_count, |h, par| {
        let p = sized::or_default(params)?;
        core_build(&mut h.ctx, &p, par)?;
        Ok(())
    })
}

/// Nearest hits of `count` rays: `hits[i]` for `rays[i]` (any count,
/// including 0; `rays` and `hits` may be NULL only when `count` is 0; no
/// alignment required; the arrays must not overlap).
///
/// A hit has `prim` = the triangle's index in the index buffer, `t` along
/// the (unnormalised) direction, `u`, `v` the barycentric weights of its
/// second and third vertex; a miss has `prim == SHEAF_INVALID_ID`,
/// `t = +infinity`. Rays with non-finite fields, a zero direction,
/// `tmin < 0` or `tmin > tmax` are misses. Results are those of the Rust
/// API (`Context::trace`), bit for bit.
///
/// The call takes the highest free thread slot for its packets' scratch and
/// mailbox (and gives it back): no call uses more than 16 KiB of the
/// caller's stack. A `_slot` call naming the slot meanwhile gets
/// `SHEAF_STATUS_SLOT_BUSY`; give threads that use `_slot` calls slots
/// from 0 up and leave the top ones to slot-less calls.
///
/// Thread-safe: up to `sheaf_limits.max_threads` threads may trace (and
/// call occluded, stats, last_error) on one built context at the same time;
/// one more finds no free slot and gets `SHEAF_STATUS_CAPACITY_THREADS`.
/// Does not update `sheaf_stats` (whose counters describe the last render).
///
/// Errors: `SHEAF_STATUS_NULL_POINTER`, `SHEAF_STATUS_INVALID_ARGUMENT`
/// (method, count, overlap), `SHEAF_STATUS_NOT_BUILT`. `hits` is written
/// only on success.
#[unsafe(no_mangle)]
pub extern "C" fn sheaf_context_trace(
    ctx: *const sheaf_context,
    method: raw::sheaf_method,
    rays: *const sheaf_ray,
    hits: *mut sheaf_hit,
    count: usize,
) -> sheaf_status {
    with_ref(ctx, |h| {
        let p = TraceParams {
            method: sheaf_method::to_core(method)?,
            ..TraceParams::default()
        };
        trace_impl(h, None, &p, rays, hits, count)
    })
}

/// Refit the built BVH to the current vertex positions of the context's
/// geometry (the same index buffer, vertices moved): every box recomputed
/// bottom-up, the tree's shape kept, so tracing stays exact and gets
/// slower as the shape loosens. With `params->rebuild_above` > 0 the BVH is
/// rebuilt instead once its SAH cost grows past that ratio. `params` may be
/// NULL (never rebuild); `out` may be NULL, else receives what was done.
///
/// `SHEAF_STATUS_NOT_BUILT` without a built BVH; `SHEAF_STATUS_INVALID_ARGUMENT`
/// for another triangle count than the build's, a stored triangle with a
/// non-finite vertex, or bad params; on every error the previous BVH is
/// kept. Not thread-safe with other calls on `ctx`.
#[unsafe(no_mangle)]
pub extern "C" fn sheaf_context_refit_bvh(
    ctx: *mut sheaf_context,
    params: *const sheaf_refit_params,
    out: *mut sheaf_refit_info,
) -> sheaf_status {
    build(ctx, params, |c, scene, p| {
        let r = c.refit_bvh(scene, p)?;
        write_wanted(out, sheaf_refit_info::of(&r));
        Ok(())
    })
}

/// `sheaf_context_trace` with the packet side and CGT switches of `*params`
/// (copied). Packet methods take the rays in order as packets of
/// `packet * packet` rays, every 4 consecutive rays one 2x2 quad (lane order
/// (x, y), (x+1, y), (x, y+1), (x+1, y+1)); results do not depend on the
/// grouping. Takes a free thread slot (its mailbox too, with
/// `params->mailbox`) as `sheaf_context_trace` does, and is thread-safe
/// like it.
///
/// Errors: those of `sheaf_context_trace`, and `SHEAF_STATUS_INVALID_ARGUMENT`
/// for a bad packet side or split ratio.
#[unsafe(no_mangle)]
pub extern "C" fn sheaf_context_trace_with(
    ctx: *const sheaf_context,
    params: *const sheaf_trace_params,
    rays: *const sheaf_ray,
    hits: *mut sheaf_hit,
    count: usize,
) -> sheaf_status {
    with_ref(ctx, |h| {
        let p = sized::to_core(params)?;
        trace_impl(h, None, &p, rays, hits, count)
    })
}

fn trace_impl(
    h: &Handle,
    slot: Option<u32>,
    p: &TraceParams,
    rays: *const sheaf_ray,
    hits: *mut sheaf_hit,
    count: usize,
) -> Result<()> {
    check_rays_out(rays, hits.cast_const(), count, "rays and hits overlap")?;
    // SAFETY: i < count for every call (trace_quads reads rays 0..count
    // only); the caller checked `rays` spans count readable elements
    // (unaligned allowed).
    let read = |i: usize| Ray::from(unsafe { rays.add(i).read_unaligned() });
    let emit = |i: usize, h4: &crate::geom::Hit4, n: usize| {
        for (l, hit) in h4.hits().into_iter().enumerate().take(n) {
            // SAFETY: i + l < count (the batch hands out quads inside its
            // count), and `hits` was checked to be non-NULL (count > 0) and
            // to span count writable elements (C contract); unaligned
            // writes are allowed and it does not overlap the rays.
            unsafe { hits.add(i + l).write_unaligned(hit.into()) }
        }
    };
    h.ctx.trace_quads(slot, p, count, read, emit, false)?;
    Ok(())
}

fn occluded_impl(
    h: &Handle,
    slot: Option<u32>,
    p: &TraceParams,
    rays: *const sheaf_ray,
    occluded: *mut u8,
    count: usize,
) -> Result<()> {
    check_rays_out(
        rays,
        occluded.cast_const(),
        count,
        "rays and results overlap",
    )?;
    trace_rays(h, slot, p, rays, count, true, |i, hit| {
        // SAFETY: i < count, `occluded` checked as `hits` in trace_impl.
        unsafe { occluded.add(i).write(u8::from(hit.is_hit())) }
    })
}

/// Trace (or, `any`, test occlusion of) `count` rays read from C, handing
/// each result to `out(i, hit)`, through the Rust API
/// (`Context::trace_each`): on thread slot `slot`, or without one on the
/// highest free slot.
fn trace_rays(
    h: &Handle,
    slot: Option<u32>,
    p: &TraceParams,
    rays: *const sheaf_ray,
    count: usize,
    any: bool,
    mut out: impl FnMut(usize, crate::Hit),
) -> Result<()> {
    // SAFETY: i < count for every call (trace_each reads rays 0..count
    // only); the caller checked `rays` spans count readable elements
    // (unaligned allowed).
    let read = |i: usize| Ray::from(unsafe { rays.add(i).read_unaligned() });
    let emit = |i: usize, h4: &crate::geom::Hit4, lane: usize| out(i, h4.lane(lane));
    h.ctx.trace_each(slot, p, count, read, emit, any)?;
    Ok(())
}

/// `sheaf_context_trace_with` on thread slot `slot` (`0 <= slot <
/// sheaf_limits.max_threads`): packet methods also use the slot's mailbox
/// (`params->mailbox`, CGT section 2.3), so CGT packets test each triangle
/// once per packet. Results equal `sheaf_context_trace_with`'s bit for bit.
///
/// Thread-safe: threads may call it concurrently on one built context, each
/// with its own slot (and alongside trace, occluded, stats and last_error).
/// A slot in use by another call gives `SHEAF_STATUS_SLOT_BUSY` and leaves
/// that call alone. Does not update `sheaf_stats`.
///
/// Errors: those of `sheaf_context_trace_with`, `SHEAF_STATUS_CAPACITY_THREADS`
/// (`slot >= max_threads`), `SHEAF_STATUS_SLOT_BUSY`. `hits` is written only
/// on success.
#[unsafe(no_mangle)]
pub extern "C" fn sheaf_context_trace_slot(
    ctx: *const sheaf_context,
    slot: u32,
    params: *const sheaf_trace_params,
    rays: *const sheaf_ray,
    hits: *mut sheaf_hit,
    count: usize,
) -> sheaf_status {
    with_ref(ctx, |h| {
        let p = sized::to_core(params)?;
        trace_impl(h, Some(slot), &p, rays, hits, count)
    })
}

/// Occlusion of `count` rays (as `sheaf_context_occluded`) with the method
/// and packet settings of `*params`, on thread slot `slot`: the same slot
/// rules and thread safety as `sheaf_context_trace_slot`.
///
/// Errors: those of `sheaf_context_trace_slot`. `occluded` is written only
/// on success.
#[unsafe(no_mangle)]
pub extern "C" fn sheaf_context_occluded_slot(
    ctx: *const sheaf_context,
    slot: u32,
    params: *const sheaf_trace_params,
    rays: *const sheaf_ray,
    occluded: *mut u8,
    count: usize,
) -> sheaf_status {
    with_ref(ctx, |h| {
        let p = sized::to_core(params)?;
        occluded_impl(h, Some(slot), &p, rays, occluded, count)
    })
}

/// Occlusion of `count` rays: `occluded[i]` = 1 when `rays[i]` hits any
/// triangle with `tmin <= t < tmax`, else 0 (shadow rays: `dir = light - p`,
/// `tmax = 1`). Same pointer rules as `sheaf_context_trace`.
///
/// Thread-safe like `sheaf_context_trace`; does not update `sheaf_stats`.
///
/// Errors: `SHEAF_STATUS_NULL_POINTER`, `SHEAF_STATUS_INVALID_ARGUMENT`,
/// `SHEAF_STATUS_NOT_BUILT`. `occluded` is written only on success.
#[unsafe(no_mangle)]
pub extern "C" fn sheaf_context_occluded(
    ctx: *const sheaf_context,
    method: raw::sheaf_method,
    rays: *const sheaf_ray,
    occluded: *mut u8,
    count: usize,
) -> sheaf_status {
    with_ref(ctx, |h| {
        let p = TraceParams {
            method: sheaf_method::to_core(method)?,
            ..TraceParams::default()
        };
        occluded_impl(h, None, &p, rays, occluded, count)
    })
}

/// `sheaf_context_occluded` with the method, packet side and CGT switches
/// of `*params` (copied; the packets as `sheaf_context_trace_with` forms
/// them, the frustum of `params->ray_kind`). Takes a free thread slot as
/// `sheaf_context_trace` does, and is thread-safe like it.
///
/// Errors: those of `sheaf_context_trace_with`. `occluded` is written only
/// on success.
#[unsafe(no_mangle)]
pub extern "C" fn sheaf_context_occluded_with(
    ctx: *const sheaf_context,
    params: *const sheaf_trace_params,
    rays: *const sheaf_ray,
    occluded: *mut u8,
    count: usize,
) -> sheaf_status {
    with_ref(ctx, |h| {
        let p = sized::to_core(params)?;
        occluded_impl(h, None, &p, rays, occluded, count)
    })
}

/// Render `*frame` into the caller's RGBA8 framebuffer (sRGB-encoded, alpha
/// 255) on the calling thread: row `y` starts at `rgba + y * stride_bytes`
/// (`stride_bytes >= 4 * width`), and the buffer holds `rgba_len >=
/// (height - 1) * stride_bytes + 4 * width` bytes. Bytes between rows are
/// not written. `*frame` is copied; the framebuffer is only written, and
/// only on success; it must not be accessed by others during the call.
///
/// Updates `sheaf_stats` (counters, trace time).
///
/// Errors: `SHEAF_STATUS_NULL_POINTER`, `SHEAF_STATUS_INVALID_ARGUMENT`
/// (method, camera, sizes, stride), `SHEAF_STATUS_CAPACITY_IMAGE`,
/// `SHEAF_STATUS_NOT_BUILT`.
///
/// Not thread-safe: needs exclusive access to `ctx` (it records stats).
#[unsafe(no_mangle)]
pub extern "C" fn sheaf_context_render(
    ctx: *mut sheaf_context,
    method: raw::sheaf_method,
    frame: *const sheaf_frame,
    rgba: *mut u8,
    stride_bytes: usize,
    rgba_len: usize,
) -> sheaf_status {
    with_mut(ctx, |h| {
        let p = TraceParams {
            method: sheaf_method::to_core(method)?,
            ..TraceParams::default()
        };
        render_impl(h, &p, &p, frame, rgba, stride_bytes, rgba_len)
    })
}

/// `sheaf_context_render` with `*primary` for camera rays and `*shadow` for
/// shadow rays (both copied): method, packet side (the tile side is the
/// primary's, or the shadow's when only shadows use packets), CGT switches,
/// shadow split ratio. The image does not depend on these choices.
///
/// Errors: those of `sheaf_context_render`. Not thread-safe.
#[unsafe(no_mangle)]
pub extern "C" fn sheaf_context_render_with(
    ctx: *mut sheaf_context,
    primary: *const sheaf_trace_params,
    shadow: *const sheaf_trace_params,
    frame: *const sheaf_frame,
    rgba: *mut u8,
    stride_bytes: usize,
    rgba_len: usize,
) -> sheaf_status {
    with_mut(ctx, |h| {
        let p = sized::to_core(primary)?;
        let s = sized::to_core(shadow)?;
        render_impl(h, &p, &s, frame, rgba, stride_bytes, rgba_len)
    })
}

/// Render rows `[y0, y1)` of `*frame` on thread slot `slot` (`0 <= slot <
/// sheaf_limits.max_threads`), with `*primary` and `*shadow` as in
/// `sheaf_context_render_with`. `rgba` points at the first pixel of row
/// `y0`; rows are `stride_bytes` apart and the band holds `rgba_len >=
/// (y1 - y0 - 1) * stride_bytes + 4 * width` bytes. Needs `0 <= y0 < y1 <=
/// height`. Threads rendering disjoint bands of one frame with distinct
/// slots produce exactly the image of `sheaf_context_render_with`.
///
/// Thread-safe: threads may call it concurrently on one built context, each
/// with its own slot and its own rows (and alongside trace, occluded, the
/// `_slot` calls, stats and last_error). A slot in use by another call gives
/// `SHEAF_STATUS_SLOT_BUSY`. Does not update `sheaf_stats`.
///
/// Errors: those of `sheaf_context_render_with` (`SHEAF_STATUS_INVALID_ARGUMENT`
/// also for bad rows), `SHEAF_STATUS_CAPACITY_THREADS`, `SHEAF_STATUS_SLOT_BUSY`.
/// The band is written only on success.
#[unsafe(no_mangle)]
pub extern "C" fn sheaf_context_render_rows(
    ctx: *const sheaf_context,
    slot: u32,
    primary: *const sheaf_trace_params,
    shadow: *const sheaf_trace_params,
    frame: *const sheaf_frame,
    y0: u32,
    y1: u32,
    rgba: *mut u8,
    stride_bytes: usize,
    rgba_len: usize,
) -> sheaf_status {
    with_ref(ctx, |h| {
        let p = sized::to_core(primary)?;
        let s = sized::to_core(shadow)?;
        let frame = read_in(frame)?.to_core()?;
        check_non_null!(rgba);
        if rgba_len > isize::MAX as usize {
            return Err(Error::InvalidArgument("framebuffer length too large"));
        }
        h.ctx.check_rows(&frame, y0, y1, rgba_len, stride_bytes)?;
        // Only the band's own bytes, (rows - 1) * stride + 4 * width (checked
        // by check_rows): threads given adjacent bands with a generous
        // `rgba_len` still borrow disjoint memory.
        let band_len = band_bytes(y1 - y0, frame.width, stride_bytes)?;
        // SAFETY: non-NULL, `band_len <= rgba_len` bytes (<= isize::MAX) of
        // writable memory that no one else accesses during the call (C
        // contract: each thread passes its own rows). The core only writes
        // through it.
        let band = unsafe { core::slice::from_raw_parts_mut(rgba, band_len) };
        h.ctx.render_rows_in_slot(
            slot,
            &p,
            &s,
            &frame,
            Band {
                y0,
                y1,
                pixels: band,
                stride: stride_bytes,
            },
        )?;
        Ok(())
    })
}

fn render_impl(
    h: &mut Handle,
    primary: &TraceParams,
    shadow: &TraceParams,
    frame: *const sheaf_frame,
    rgba: *mut u8,
    stride_bytes: usize,
    rgba_len: usize,
) -> Result<()> {
    let frame = read_in(frame)?.to_core()?;
    let pixels = framebuffer(h, &frame, rgba, stride_bytes, rgba_len)?;
    h.ctx
        .render_with(primary, shadow, &frame, pixels, stride_bytes)?;
    Ok(())
}

/// The caller's framebuffer for `frame`, checked (sizes, limits, camera, a
/// built structure) before anything is written.
pub(super) fn framebuffer<'p>(
    h: &Handle,
    frame: &crate::Frame,
    rgba: *mut u8,
    stride_bytes: usize,
    rgba_len: usize,
) -> Result<&'p mut [u8]> {
    let p = pixels(h, frame, rgba, stride_bytes, rgba_len)?;
    h.ctx.tracer()?;
    Ok(p)
}

/// The caller's framebuffer for `frame`, checked (sizes, limits, camera)
/// before anything is written; no structure needs to be built (deferred
/// frames may use only the perspective and light grids).
pub(super) fn pixels<'p>(
    h: &Handle,
    frame: &crate::Frame,
    rgba: *mut u8,
    stride_bytes: usize,
    rgba_len: usize,
) -> Result<&'p mut [u8]> {
    check_non_null!(rgba);
    if rgba_len > isize::MAX as usize {
        return Err(Error::InvalidArgument("framebuffer length too large"));
    }
    // The core checks sizes, limits, camera and light (Context::check_frame);
    // its `(height - 1) * stride + 4 * width` must not overflow first.
    if frame.width > 0 && frame.height > 0 {
        band_bytes(frame.height, frame.width, stride_bytes)?;
    }
    h.ctx.check_frame(frame, rgba_len, stride_bytes)?;
    let len = band_bytes(frame.height, frame.width, stride_bytes)?;
    // SAFETY: non-NULL, `len <= rgba_len` bytes (<= isize::MAX) of
    // writable memory not accessed by others during the call (C contract).
    // The core only writes through it.
    Ok(unsafe { core::slice::from_raw_parts_mut(rgba, len) })
}

/// Bytes of `rows` rows of `width` RGBA8 pixels, `stride` apart: `(rows -
/// 1) * stride + 4 * width`, checked (`rows >= 1`).
pub(super) fn band_bytes(rows: u32, width: u32, stride: usize) -> Result<usize> {
    (rows as usize)
        .checked_sub(1)
        .and_then(|r| r.checked_mul(stride))
        .and_then(|b| b.checked_add((width as usize).checked_mul(4)?))
        .filter(|&b| b <= isize::MAX as usize)
        .ok_or(Error::InvalidArgument("framebuffer size overflows"))
}

/// Statistics of the last build and the last render, written to `*out`
/// (all zero before the first build).
///
/// Thread-safe with trace, occluded, stats and last_error; not with calls
/// needing exclusive access.
///
/// Errors: `SHEAF_STATUS_NULL_POINTER`.
#[unsafe(no_mangle)]
pub extern "C" fn sheaf_context_stats(
    ctx: *const sheaf_context,
    out: *mut sheaf_stats,
) -> sheaf_status {
    with_ref(ctx, |h| {
        check_non_null!(out);
        write_out(out, sheaf_stats::of(h.ctx.stats()));
        Ok(())
    })
}

/// Scratch bytes each thread slot of a context made with `*limits` holds
/// (part of `sheaf_required_bytes`), written to `*out`: set by the largest
/// packet side, the Whitted bounces, the renderers and the structures.
///
/// Errors: `SHEAF_STATUS_NULL_POINTER`, `SHEAF_STATUS_INVALID_ARGUMENT`
/// (limits outside their domain). Thread-safe.
#[unsafe(no_mangle)]
pub extern "C" fn sheaf_slot_scratch_bytes(
    limits: *const sheaf_limits,
    out: *mut usize,
) -> sheaf_status {
    guard_free(|| {
        let limits = sized::to_core(limits)?;
        limits.validate()?;
        check_non_null!(out);
        write_out(out, crate::slot_scratch_bytes(&limits));
        Ok(())
    })
}

/// The most slot scratch any call on `ctx` has used since its creation, in
/// bytes, written to `*out` (at most `sheaf_slot_scratch_bytes` of its
/// limits): run a frame at its largest settings, then size the limits.
///
/// Needs exclusive access (`SHEAF_STATUS_CONTEXT_BUSY` while another call
/// runs). Errors: `SHEAF_STATUS_NULL_POINTER`.
#[unsafe(no_mangle)]
pub extern "C" fn sheaf_context_scratch_high_water(
    ctx: *mut sheaf_context,
    out: *mut usize,
) -> sheaf_status {
    with_mut(ctx, |h| {
        check_non_null!(out);
        write_out(out, h.ctx.scratch_high_water());
        Ok(())
    })
}

/// A fixed-size text buffer on the stack (formatting never allocates).
struct MessageBuf {
    bytes: [u8; SHEAF_ERROR_MESSAGE_MAX],
    len: usize,
    /// Set at the first character that did not fit: later ones are dropped too.
    full: bool,
}

impl core::fmt::Write for MessageBuf {
    fn write_str(&mut self, s: &str) -> core::fmt::Result {
        for ch in s.chars() {
            if self.full {
                break;
            }
            let mut tmp = [0u8; 4];
            let enc = ch.encode_utf8(&mut tmp).as_bytes();
            // Keep one byte for the NUL terminator; drop what does not fit.
            if self.len + enc.len() >= SHEAF_ERROR_MESSAGE_MAX {
                self.full = true;
                break;
            }
            self.bytes[self.len..self.len + enc.len()].copy_from_slice(enc);
            self.len += enc.len();
        }
        Ok(())
    }
}

/// The message of `e` ("no error" for None).
fn message(e: Option<Error>) -> MessageBuf {
    let mut m = MessageBuf {
        bytes: [0; SHEAF_ERROR_MESSAGE_MAX],
        len: 0,
        full: false,
    };
    let _ = match e {
        Some(e) => write!(m, "{e}"),
        None => m.write_str("no error"),
    };
    m
}

/// Text of the last failure of a call on `ctx` (it names the pool, what was
/// needed and what is available for capacity errors, the triangle and the
/// index for out-of-range indices...). "no error" before any failure; a
/// successful call does not clear it. Failures of this call itself are not
/// recorded, nor are `SHEAF_STATUS_CONTEXT_BUSY` and
/// `SHEAF_STATUS_POISONED` refusals (the failure that poisoned a context
/// stays readable here).
///
/// Writes at most `len - 1` bytes of the message plus a NUL terminator to
/// `buf` (truncating at a character boundary; `SHEAF_ERROR_MESSAGE_MAX`
/// bytes always suffice) and the number of bytes before the NUL to
/// `*written`. Never allocates.
///
/// Thread-safe, also beside exclusive calls and on a poisoned context.
///
/// Errors: `SHEAF_STATUS_NULL_POINTER`, `SHEAF_STATUS_INVALID_ARGUMENT`
/// (`len == 0`, not a live context).
#[unsafe(no_mangle)]
pub extern "C" fn sheaf_context_last_error(
    ctx: *const sheaf_context,
    buf: *mut c_char,
    len: usize,
    written: *mut usize,
) -> sheaf_status {
    guard_free(|| {
        let hd = header(ctx)?;
        if hd.state.dead() {
            return Err(Error::InvalidArgument(
                "not a live sheaf_context (destroyed?)",
            ));
        }
        check_non_null!(buf, written);
        if len == 0 {
            return Err(Error::InvalidArgument("len must be >= 1"));
        }
        let m = message(hd.last_error.get());
        let mut n = m.len.min(len - 1);
        while n > 0 && n < m.len && (m.bytes[n] & 0xC0) == 0x80 {
            n -= 1; // do not cut a UTF-8 sequence
        }
        // SAFETY: `buf` is non-NULL and writable for `len > n` bytes (C
        // contract); the source is our stack buffer, so they do not overlap.
        unsafe {
            ptr::copy_nonoverlapping(m.bytes.as_ptr(), buf.cast::<u8>(), n);
            buf.add(n).write(0);
        }
        write_out(written, n);
        Ok(())
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::error::Pool;

    #[test]
    fn header_fits_and_keeps_the_arena_aligned() {
        assert!(HEADER_BYTES >= core::mem::size_of::<Handle>());
        assert_eq!(HEADER_BYTES % SHEAF_CONTEXT_ALIGN, 0);
    }

    #[test]
    fn worst_case_messages_fit() {
        let big = u64::MAX;
        let cases = [
            Error::IndexOutOfRange {
                triangle: u32::MAX,
                index: u32::MAX,
                vertex_count: u32::MAX,
            },
            Error::Capacity {
                pool: Pool::GridCells,
                needed: big,
                available: big,
            },
            Error::BufferTooSmall {
                needed: big,
                available: big,
            },
            Error::Misaligned { required: u32::MAX },
            Error::InvalidArgument("framebuffer smaller than (height - 1) * stride + 4 * width"),
            Error::Panic,
        ];
        for e in cases {
            let m = message(Some(e));
            let full = format!("{e}");
            assert_eq!(
                &m.bytes[..m.len],
                full.as_bytes(),
                "message of {e:?} truncated"
            );
        }
    }

    #[test]
    fn long_messages_are_truncated_not_overflowed() {
        let mut m = MessageBuf {
            bytes: [0; SHEAF_ERROR_MESSAGE_MAX],
            len: 0,
            full: false,
        };
        for _ in 0..100 {
            let _ = m.write_str("abcdefé");
        }
        assert!(m.len < SHEAF_ERROR_MESSAGE_MAX && m.len + 2 >= SHEAF_ERROR_MESSAGE_MAX - 1);
        assert!(core::str::from_utf8(&m.bytes[..m.len]).is_ok());
    }
}
