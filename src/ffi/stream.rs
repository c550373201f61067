//! `sheaf_ray_stream`, `sheaf_hit_stream`: rays and hits as structures of
//! arrays (Embree's `RTCRayHitNp` layout, with a stride), and the four
//! stream calls: nearest hits and occlusion, for the context's single mesh
//! and for its two-level scene. Packet methods load a packed stream's
//! quads directly (`trace::stream`), without the 32-byte `sheaf_ray`
//! transpose; other strides are read element by element.

use super::context::{Handle, sheaf_context, with_ref};
use super::scene::controls;
use super::sized;
use super::trace_params::sheaf_trace_params;
use super::{overlaps, read_in};
use crate::error::{Error, Result};
use crate::geom::{M4, Ray, Ray4};
use crate::trace::{RaySource, RayStream};

/// Rays as structures of arrays: ray `i` is `org_x[i]`, `org_y[i]`, ...,
/// `tmax[i]`, with the semantics of `sheaf_ray`.
///
/// `stride` is the distance in bytes from one ray's element to the next
/// in every array: `sizeof(float)` (4) for packed arrays, larger for
/// arrays interleaved with other data; a multiple of 4. Every pointer is
/// aligned to 4 bytes and may be NULL only when the call's count is 0.
/// Packed arrays (stride 4) are the fast layout: packets load their 2x2
/// quads from them directly.
#[repr(C)]
#[derive(Clone, Copy, Debug)]
pub struct sheaf_ray_stream {
    pub org_x: *const f32,
    pub org_y: *const f32,
    pub org_z: *const f32,
    pub dir_x: *const f32,
    pub dir_y: *const f32,
    pub dir_z: *const f32,
    pub tmin: *const f32,
    pub tmax: *const f32,
    /// Bytes between consecutive rays' elements (4: packed).
    pub stride: usize,
}

/// Nearest hits as structures of arrays: hit `i` is `t[i]`, `u[i]`,
/// `v[i]`, `prim[i]` (the fields of `sheaf_hit`), and for two-level
/// scenes `geometry[i]`, `instance[i]` (those of `sheaf_scene_hit`).
///
/// `stride` and the pointers' rules are those of `sheaf_ray_stream`;
/// `geometry` and `instance` may be NULL in a scene call (not written)
/// and must be NULL in a single-mesh call. No output array may share an
/// element with another or with an input array; arrays of different
/// strides may not overlap at all (a conservative rule).
#[repr(C)]
#[derive(Clone, Copy, Debug)]
pub struct sheaf_hit_stream {
    pub t: *mut f32,
    pub u: *mut f32,
    pub v: *mut f32,
    pub prim: *mut u32,
    pub geometry: *mut u32,
    pub instance: *mut u32,
    /// Bytes between consecutive hits' elements (4: packed).
    pub stride: usize,
}

/// The bytes one array of `n` elements `stride` apart spans from `p`
/// (no bytes for an empty stream or an array not given), checked:
/// non-NULL, 4-byte aligned, in the address space. Every field is always
/// written (no `Option`), so the checks below never read an unset
/// payload, which valgrind reports in optimised code.
#[derive(Clone, Copy)]
struct Span {
    at: usize,
    bytes: usize,
    stride: usize,
}

impl Span {
    const NONE: Span = Span {
        at: 0,
        bytes: 0,
        stride: 4,
    };
}

fn check_stride(stride: usize) -> Result<()> {
    if stride < 4 || !stride.is_multiple_of(4) {
        return Err(Error::InvalidArgument(
            "stream stride: a multiple of 4 bytes, at least 4",
        ));
    }
    Ok(())
}

fn span(p: *const u8, n: usize, stride: usize) -> Result<Span> {
    if n == 0 {
        return Ok(Span::NONE);
    }
    if p.is_null() {
        return Err(Error::NullPointer);
    }
    if !(p as usize).is_multiple_of(4) {
        return Err(Error::Misaligned { required: 4 });
    }
    let bytes = (n - 1)
        .checked_mul(stride)
        .and_then(|b| b.checked_add(4))
        .filter(|&b| b <= isize::MAX as usize && (p as usize).checked_add(b).is_some())
        .ok_or(Error::InvalidArgument("ray count too large"))?;
    Ok(Span {
        at: p as usize,
        bytes,
        stride,
    })
}

/// Whether two checked arrays share an element: their spans overlap and,
/// with one stride, their starts differ by a multiple of it (4-byte
/// elements at 4-byte aligned addresses either coincide or are apart).
fn alias(a: Span, b: Span) -> bool {
    overlaps(a.at as *const u8, a.bytes, b.at as *const u8, b.bytes)
        && (a.stride != b.stride || a.at.abs_diff(b.at).is_multiple_of(a.stride))
}

/// A checked ray stream from C.
#[derive(Clone, Copy)]
struct CRays {
    p: [*const f32; 8],
    stride: usize,
    n: usize,
}

impl CRays {
    /// Read and check `*rays` for `n` rays; the spans of its arrays.
    fn new(rays: *const sheaf_ray_stream, n: usize) -> Result<(CRays, [Span; 8])> {
        let r = read_in(rays)?;
        check_stride(r.stride)?;
        let p = [
            r.org_x, r.org_y, r.org_z, r.dir_x, r.dir_y, r.dir_z, r.tmin, r.tmax,
        ];
        let mut spans = [Span::NONE; 8];
        for (s, &q) in spans.iter_mut().zip(&p) {
            *s = span(q.cast(), n, r.stride)?;
        }
        Ok((
            CRays {
                p,
                stride: r.stride,
                n,
            },
            spans,
        ))
    }

    /// Array `k`'s element `i`.
    #[inline(always)]
    fn at(&self, k: usize, i: usize) -> f32 {
        debug_assert!(i < self.n);
        // SAFETY: i < n, and `new` checked the array spans n elements
        // `stride` apart from a non-NULL, 4-byte aligned pointer (C
        // contract: readable for the call).
        unsafe { self.p[k].byte_add(i * self.stride).read() }
    }

    /// The packed arrays as slices (stride 4), for `RayStream`'s loads.
    #[inline(always)]
    fn packed(&self) -> Option<RayStream<'_>> {
        if self.stride != 4 || self.n == 0 {
            return None;
        }
        // SAFETY: `new` checked every pointer non-NULL and 4-byte aligned,
        // n * 4 bytes within isize::MAX; the C contract makes them
        // readable for the call, and the overlap checks (`CHits::new`,
        // `check_occluded`) keep every write of the call out of them.
        let s = |k: usize| unsafe { core::slice::from_raw_parts(self.p[k], self.n) };
        Some(RayStream {
            org: [s(0), s(1), s(2)],
            dir: [s(3), s(4), s(5)],
            tmin: s(6),
            tmax: s(7),
        })
    }
}

impl RaySource for CRays {
    #[inline(always)]
    fn ray(&self, i: usize) -> Ray {
        Ray {
            org: [self.at(0, i), self.at(1, i), self.at(2, i)],
            tmin: self.at(6, i),
            dir: [self.at(3, i), self.at(4, i), self.at(5, i)],
            tmax: self.at(7, i),
        }
    }

    #[inline(always)]
    fn pack(&self, start: usize, n: usize, quads: &mut [Ray4], active: &mut [M4]) -> usize {
        match self.packed() {
            Some(s) => s.pack(start, n, quads, active),
            None => crate::trace::pack_quads(n, |k| self.ray(start + k), quads, active),
        }
    }
}

/// A checked hit stream from C (`new`'s `scene`: whether `geometry` and
/// `instance` may be given, else they must be NULL).
#[derive(Clone, Copy)]
struct CHits {
    h: sheaf_hit_stream,
}

impl CHits {
    fn new(
        hits: *const sheaf_hit_stream,
        n: usize,
        rays: &[Span; 8],
        scene: bool,
    ) -> Result<CHits> {
        let h = read_in(hits)?;
        check_stride(h.stride)?;
        let ids = !(h.geometry.is_null() && h.instance.is_null());
        if ids && !scene {
            return Err(Error::InvalidArgument(
                "geometry and instance are two-level scene hits: NULL for a single mesh",
            ));
        }
        let sp = |p: *const u8| span(p, n, h.stride);
        let mut outs = [
            sp(h.t.cast_const().cast())?,
            sp(h.u.cast_const().cast())?,
            sp(h.v.cast_const().cast())?,
            sp(h.prim.cast_const().cast())?,
            Span::NONE,
            Span::NONE,
        ];
        if !h.geometry.is_null() {
            outs[4] = sp(h.geometry.cast_const().cast())?;
        }
        if !h.instance.is_null() {
            outs[5] = sp(h.instance.cast_const().cast())?;
        }
        for (k, &o) in outs.iter().enumerate() {
            if rays.iter().any(|&r| alias(o, r)) || outs[k + 1..].iter().any(|&x| alias(o, x)) {
                return Err(Error::InvalidArgument(
                    "hit stream arrays overlap the rays or each other",
                ));
            }
        }
        Ok(CHits { h })
    }

    /// Lanes `0 .. n` of `h` as hits `i .. i + n`: a whole quad of a packed
    /// stream as one 16-byte store per field.
    #[inline(always)]
    fn put_quad(&self, i: usize, h: &crate::geom::Hit4, n: usize) {
        if n == 4 && self.h.stride == 4 {
            let o = i * 4;
            // SAFETY: i + 3 < n rays (the batch hands out whole quads
            // inside its count); `new` checked each array non-NULL, 4-byte
            // aligned, spanning n packed elements apart from every other
            // array and the rays (C contract: writable for the call);
            // unaligned 16-byte writes are allowed.
            unsafe {
                self.h
                    .t
                    .byte_add(o)
                    .cast::<[f32; 4]>()
                    .write_unaligned(h.t.to_array());
                self.h
                    .u
                    .byte_add(o)
                    .cast::<[f32; 4]>()
                    .write_unaligned(h.u.to_array());
                self.h
                    .v
                    .byte_add(o)
                    .cast::<[f32; 4]>()
                    .write_unaligned(h.v.to_array());
                self.h
                    .prim
                    .byte_add(o)
                    .cast::<[u32; 4]>()
                    .write_unaligned(h.prim);
            }
            return;
        }
        for l in 0..4 {
            if l < n {
                let x = h.lane(l);
                self.put(i + l, (x.t, x.u, x.v, x.prim), None);
            }
        }
    }

    /// Hit `i`'s fields (geometry and instance: scene calls only).
    #[inline(always)]
    fn put(&self, i: usize, (t, u, v, prim): (f32, f32, f32, u32), scene: Option<(u32, u32)>) {
        let o = i * self.h.stride;
        // SAFETY: i < n (the batch hands out indices below its count);
        // `new` checked each array non-NULL, 4-byte aligned, spanning n
        // elements `stride` apart, sharing no element with another array
        // or the rays (C contract: writable for the call).
        unsafe {
            self.h.t.byte_add(o).write(t);
            self.h.u.byte_add(o).write(u);
            self.h.v.byte_add(o).write(v);
            self.h.prim.byte_add(o).write(prim);
            if let Some((g, k)) = scene {
                if !self.h.geometry.is_null() {
                    self.h.geometry.byte_add(o).write(g);
                }
                if !self.h.instance.is_null() {
                    self.h.instance.byte_add(o).write(k);
                }
            }
        }
    }
}

/// Check `occluded` (`n` bytes) against the rays.
fn check_occluded(occluded: *mut u8, n: usize, rays: &[Span; 8]) -> Result<()> {
    super::check_array(occluded.cast_const(), n, "ray count too large")?;
    let hit = |r: Span| overlaps(occluded.cast_const(), n, r.at as *const u8, r.bytes);
    if rays.iter().any(|&r| hit(r)) {
        return Err(Error::InvalidArgument("rays and results overlap"));
    }
    Ok(())
}

/// Write `occluded[i]`.
#[inline(always)]
fn put_occluded(occluded: *mut u8, i: usize, hit: bool) {
    // SAFETY: i < n; `check_occluded` checked `occluded` spans n bytes
    // apart from the rays (C contract: writable for the call).
    unsafe { occluded.add(i).write(u8::from(hit)) }
}

/// Nearest hits of `count` rays given as a stream (`sheaf_ray_stream`)
/// into a hit stream (`sheaf_hit_stream`, `geometry` and `instance`
/// NULL), with `params`' method and packets as `sheaf_context_trace_with`
/// forms them from the rays in order: its hits, bit for bit. Takes a free
/// thread slot as `sheaf_context_trace` does, and is thread-safe like it.
///
/// Errors: `SHEAF_STATUS_NULL_POINTER` (a NULL stream, or a NULL array
/// with `count` > 0), `SHEAF_STATUS_MISALIGNED` (an array not 4-byte
/// aligned), `SHEAF_STATUS_INVALID_ARGUMENT` (bad params, a stride that is
/// not a multiple of 4 or below 4, `count` past the address space, an
/// output array sharing elements with another array or overlapping one of
/// another stride, `geometry` or `instance` not NULL), `SHEAF_STATUS_NOT_BUILT`,
/// `SHEAF_STATUS_CAPACITY_THREADS`. The hits are written only on success.
#[unsafe(no_mangle)]
pub extern "C" fn sheaf_context_trace_stream(
    ctx: *const sheaf_context,
    params: *const sheaf_trace_params,
    rays: *const sheaf_ray_stream,
    hits: *const sheaf_hit_stream,
    count: usize,
) -> super::sheaf_status {
    with_ref(ctx, |h| {
        let p = sized::to_core(params)?;
        let (r, spans) = CRays::new(rays, count)?;
        let out = CHits::new(hits, count, &spans, false)?;
        let emit = |i: usize, h4: &crate::geom::Hit4, n: usize| out.put_quad(i, h4, n);
        h.ctx.trace_quads(None, &p, count, r, emit, false)?;
        Ok(())
    })
}

/// Occlusion of `count` rays given as a stream: `occluded[i]` = 1 when
/// ray `i` hits any triangle in `[tmin, tmax)`, else 0, as
/// `sheaf_context_occluded_with` answers. Same rules and errors as
/// `sheaf_context_trace_stream`; `occluded` (`count` bytes) may not
/// overlap the rays.
#[unsafe(no_mangle)]
pub extern "C" fn sheaf_context_occluded_stream(
    ctx: *const sheaf_context,
    params: *const sheaf_trace_params,
    rays: *const sheaf_ray_stream,
    occluded: *mut u8,
    count: usize,
) -> super::sheaf_status {
    with_ref(ctx, |h| {
        let p = sized::to_core(params)?;
        let (r, spans) = CRays::new(rays, count)?;
        check_occluded(occluded, count, &spans)?;
        let emit = |i: usize, h4: &crate::geom::Hit4, l: usize| {
            put_occluded(occluded, i, h4.prim[l] != crate::geom::INVALID_ID)
        };
        h.ctx.trace_each(None, &p, count, r, emit, true)?;
        Ok(())
    })
}

/// `sheaf_context_trace_scene` on a ray stream into a hit stream
/// (`geometry` and `instance` written where not NULL): `params` (NULL:
/// single rays), `mask` and `flags` as there, and its hits, bit for bit.
/// Thread-safe as `sheaf_context_trace_scene`. Errors: those of
/// `sheaf_context_trace_scene` and the stream checks of
/// `sheaf_context_trace_stream`.
#[unsafe(no_mangle)]
pub extern "C" fn sheaf_context_trace_scene_stream(
    ctx: *const sheaf_context,
    params: *const sheaf_trace_params,
    rays: *const sheaf_ray_stream,
    hits: *const sheaf_hit_stream,
    count: usize,
    mask: u32,
    flags: u32,
) -> super::sheaf_status {
    with_ref(ctx, |h| {
        let ctl = controls(mask, flags)?;
        let (r, spans) = CRays::new(rays, count)?;
        let out = CHits::new(hits, count, &spans, true)?;
        let p = sized::optional(params)?; // NULL: single rays
        scene_rays(h, p, r, count, ctl, false, |i, x| {
            out.put(i, (x.t, x.u, x.v, x.prim), Some((x.geometry, x.instance)))
        })
    })
}

/// `sheaf_context_occluded_scene` on a ray stream: 1 or 0 into
/// `occluded`. Rules and errors as `sheaf_context_trace_scene_stream`
/// and `sheaf_context_occluded_stream`.
#[unsafe(no_mangle)]
pub extern "C" fn sheaf_context_occluded_scene_stream(
    ctx: *const sheaf_context,
    params: *const sheaf_trace_params,
    rays: *const sheaf_ray_stream,
    occluded: *mut u8,
    count: usize,
    mask: u32,
    flags: u32,
) -> super::sheaf_status {
    with_ref(ctx, |h| {
        let ctl = controls(mask, flags)?;
        let (r, spans) = CRays::new(rays, count)?;
        check_occluded(occluded, count, &spans)?;
        let p = sized::optional(params)?; // NULL: single rays
        scene_rays(h, p, r, count, ctl, true, |i, x| {
            put_occluded(occluded, i, x.is_hit())
        })
    })
}

/// The scene stream calls' trace, after their checks.
fn scene_rays(
    h: &Handle,
    p: Option<crate::TraceParams>,
    r: CRays,
    count: usize,
    ctl: crate::RayControls,
    any: bool,
    out: impl FnMut(usize, crate::SceneHit),
) -> Result<()> {
    // `trace_scene_each` checks the scene (pools, commit) before any write.
    h.ctx
        .trace_scene_each(p.as_ref(), None, count, ctl, any, r, out)?;
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn element_aliasing() {
        let s = |at: usize, n: usize, stride: usize| Span {
            at,
            bytes: (n - 1) * stride + 4,
            stride,
        };
        // Packed arrays apart, then overlapping.
        assert!(!alias(s(0, 4, 4), s(16, 4, 4)));
        assert!(alias(s(0, 4, 4), s(12, 4, 4)));
        // Interleaved (an array of 16-byte structs): fields 4 bytes apart
        // never share an element, the same field does.
        assert!(!alias(s(0, 8, 16), s(4, 8, 16)));
        assert!(alias(s(0, 8, 16), s(32, 8, 16)));
        // Different strides over one span: refused.
        assert!(alias(s(0, 8, 16), s(4, 8, 8)));
        assert!(!alias(Span::NONE, s(0, 4, 4)));
    }

    #[test]
    fn spans_are_checked() {
        assert_eq!(span(core::ptr::null(), 0, 4).map(|s| s.bytes), Ok(0));
        assert_eq!(
            span(core::ptr::null(), 1, 4).err(),
            Some(Error::NullPointer)
        );
        let x = [0u32; 4];
        let p = x.as_ptr().cast::<u8>();
        assert_eq!(
            span(p.wrapping_add(2), 1, 4).err(),
            Some(Error::Misaligned { required: 4 })
        );
        assert!(span(p, usize::MAX, 4).is_err());
        assert!(check_stride(0).is_err() && check_stride(6).is_err() && check_stride(8).is_ok());
    }
}
