//! The context's trace calls: rays (arrays, streams, camera rays made in
//! the kernel) traced or tested for occlusion on the calling thread or on
//! a claimed thread slot, all through one batch loop (`trace::batch_on`).
#![forbid(unsafe_code)]

use super::Context;
use crate::accel::slot::Slot;
use crate::counters::{elapsed_ns, now};
use crate::error::{Error, Result};
use crate::geom::{Hit, Hit4, Ray};
use crate::render::{CameraRays, PixelRect, PrimaryRays};
use crate::trace::stream::one_per_ray;
use crate::trace::{
    Counters, HitStream, Method, RaySource, RayStream, SceneTracer, TraceParams, batch_on, per_ray,
};

impl Context<'_> {
    /// The built structures with single-ray calls going to the first built
    /// of grid, BVH, kd-tree.
    pub(super) fn scene_tracer(&self) -> Result<SceneTracer<'_>> {
        with_first_single(super::structures!(self))
    }

    /// The built structures, for tracing from several threads. Single-ray
    /// calls use the grid's 3DDDA when a grid is built, else the BVH's
    /// single-ray traversal (see `SceneTracer::with_single`).
    pub fn tracer(&self) -> Result<SceneTracer<'_>> {
        self.scene_tracer()
    }

    /// The built structures and one mailbox per thread slot, for tracing
    /// and rendering from several threads (each thread takes one mailbox).
    /// A slot's scratch holds packets up to `Limits::max_packet_side`:
    /// handing a `Tracer` larger packets with it panics (the context's own
    /// calls refuse them with a status first).
    pub fn parts(&mut self) -> Result<(SceneTracer<'_>, impl Iterator<Item = Slot<'_>>)> {
        let t = with_first_single(super::structures!(self))?;
        // One mailbox and scratch per thread slot; without grid pools (no
        // stamps) the mailboxes are empty, which only the grid's CGT uses.
        let mbs = self.slots.all().map(Slot::of);
        Ok((t, mbs))
    }

    /// Nearest hits of `rays` into `hits` (same length) with `method` and
    /// its default packet settings (`TraceParams`).
    pub fn trace(&mut self, method: Method, rays: &[Ray], hits: &mut [Hit]) -> Result<Counters> {
        self.trace_with(
            &TraceParams {
                method,
                ..TraceParams::default()
            },
            rays,
            hits,
        )
    }

    /// Nearest hits of `rays` into `hits` (same length). Packet methods take
    /// the rays in order as packets of `p.packet`^2 rays, every 4 rays one
    /// 2x2 quad in `Ray4` lane order (a last, smaller packet is padded with
    /// inactive lanes).
    pub fn trace_with(
        &mut self,
        p: &TraceParams,
        rays: &[Ray],
        hits: &mut [Hit],
    ) -> Result<Counters> {
        one_per_ray(&[hits.len()], rays.len())?;
        self.timed(|c| c.trace_quads(Some(0), p, rays.len(), |i| rays[i], into_hits(hits), false))
    }

    /// Occlusion of `rays` with `method` (default packet settings).
    pub fn occluded(
        &mut self,
        method: Method,
        rays: &[Ray],
        occluded: &mut [bool],
    ) -> Result<Counters> {
        self.occluded_with(
            &TraceParams {
                method,
                ..TraceParams::default()
            },
            rays,
            occluded,
        )
    }

    /// Occlusion of `rays` into `occluded` (same length): any hit in
    /// `[tmin, tmax)`. Packets are formed as in `trace_with`.
    pub fn occluded_with(
        &mut self,
        p: &TraceParams,
        rays: &[Ray],
        occluded: &mut [bool],
    ) -> Result<Counters> {
        one_per_ray(&[occluded.len()], rays.len())?;
        let out = into_occluded(occluded);
        self.timed(|c| c.trace_quads(Some(0), p, rays.len(), |i| rays[i], out, true))
    }

    /// `f` on this context, its counters and wall time recorded in `stats`
    /// (the calls on the calling thread, which hold the context).
    pub(super) fn timed(&mut self, f: impl FnOnce(&Self) -> Result<Counters>) -> Result<Counters> {
        let t = now();
        let ctr = f(self)?;
        self.stats.trace_ns = elapsed_ns(t);
        self.stats.counters = ctr;
        Ok(ctr)
    }

    /// `trace_with` from any thread sharing `&self`, with thread slot
    /// `slot`'s mailbox (claimed for the call: `Error::SlotBusy` while
    /// another call holds it). Does not update `stats`.
    pub fn trace_in_slot(
        &self,
        slot: u32,
        p: &TraceParams,
        rays: &[Ray],
        hits: &mut [Hit],
    ) -> Result<Counters> {
        one_per_ray(&[hits.len()], rays.len())?;
        let out = into_hits(hits);
        self.trace_quads(Some(slot), p, rays.len(), |i| rays[i], out, false)
    }

    /// `occluded_with` from any thread sharing `&self`, with thread slot
    /// `slot`'s mailbox (see `trace_in_slot`).
    pub fn occluded_in_slot(
        &self,
        slot: u32,
        p: &TraceParams,
        rays: &[Ray],
        occluded: &mut [bool],
    ) -> Result<Counters> {
        one_per_ray(&[occluded.len()], rays.len())?;
        let out = into_occluded(occluded);
        self.trace_quads(Some(slot), p, rays.len(), |i| rays[i], out, true)
    }

    /// Trace (`any`: test occlusion of) `count` rays, ray `i` being
    /// `rays.ray(i)` (a closure reading an array, or a `RayStream`), from
    /// any thread sharing `&self`, handing each result to `out(i, hits,
    /// lane)`: packets as `trace_with` forms them, on thread slot `slot`
    /// (see `with_slot`; `None` takes the highest free slot). The calls of
    /// the C ABI come here. Does not update `stats`.
    pub fn trace_each(
        &self,
        slot: Option<u32>,
        p: &TraceParams,
        count: usize,
        rays: impl RaySource,
        out: impl FnMut(usize, &Hit4, usize),
        any: bool,
    ) -> Result<Counters> {
        self.trace_quads(slot, p, count, rays, per_ray(out), any)
    }

    /// `trace_each` handing the results out quad by quad: `out(i, hits,
    /// n)` for rays `i .. i + n` (lanes `0 .. n` of `hits`, `n <= 4`), so a
    /// caller storing lanes side by side (hit streams, camera pixels)
    /// writes whole quads.
    pub fn trace_quads(
        &self,
        slot: Option<u32>,
        p: &TraceParams,
        count: usize,
        rays: impl RaySource,
        out: impl FnMut(usize, &Hit4, usize),
        any: bool,
    ) -> Result<Counters> {
        p.validate_for(&self.limits)?;
        let tr = self.scene_tracer()?.with_single(p.method)?;
        self.with_slot(slot, |slot| batch_on(&tr, slot, p, count, rays, out, any))
    }

    /// Nearest hits of a ray stream (rays and hits as structures of
    /// arrays, `trace::stream`) with `p.method`, from any thread sharing
    /// `&self`, on thread slot `slot` as `trace_each`: the packets and the
    /// hits of `trace_with` on the same rays, bit for bit, without the
    /// array-of-structs conversion. Does not update `stats`.
    pub fn trace_stream(
        &self,
        slot: Option<u32>,
        p: &TraceParams,
        rays: &RayStream<'_>,
        hits: &mut HitStream<'_>,
    ) -> Result<Counters> {
        let n = rays.count()?;
        hits.check(n)?;
        self.trace_quads(slot, p, n, *rays, |i, h, k| hits.put_quad(i, h, k), false)
    }

    /// Occlusion of a ray stream into `occluded` (one per ray), as
    /// `occluded_with` answers it, on thread slot `slot` as `trace_each`.
    /// Does not update `stats`.
    pub fn occluded_stream(
        &self,
        slot: Option<u32>,
        p: &TraceParams,
        rays: &RayStream<'_>,
        occluded: &mut [bool],
    ) -> Result<Counters> {
        let n = rays.count()?;
        crate::trace::stream::one_per_ray(&[occluded.len()], n)?;
        self.trace_quads(slot, p, n, *rays, into_occluded(occluded), true)
    }

    /// Nearest hits of the camera rays through the pixels of `rect` (inside
    /// `camera`'s image), made in the kernel as packets of `p.packet`^2
    /// pixels (`render::CameraRays`: no ray array, no conversion), pixel
    /// (x, y)'s hit into `hits[(y - rect.y0) * row + (x - rect.x0)]`;
    /// other elements are left alone. The hits of `trace_with` on the rays
    /// `camera.ray(x, y)`, bit for bit. From any thread sharing `&self`,
    /// on thread slot `slot` as `trace_each` (threads tracing disjoint
    /// tiles or row bands of one image into one buffer, each its own
    /// slot). Does not update `stats`.
    pub fn trace_camera(
        &self,
        slot: Option<u32>,
        p: &TraceParams,
        camera: &PrimaryRays,
        rect: PixelRect,
        hits: &mut [Hit],
        row: usize,
    ) -> Result<Counters> {
        let rays = CameraRays::new(camera, rect, Some(p))?;
        rect.check_results(hits.len(), row)?;
        let mut at = rays.index(row);
        let out = |i: usize, h: &Hit4, _: usize| {
            for (k, hit) in at.quad(i).into_iter().zip(h.hits()) {
                if let Some(k) = k {
                    hits[k] = hit;
                }
            }
        };
        self.trace_quads(slot, p, rays.count(), rays, out, false)
    }

    /// Run `f` with thread slot `slot` (its mailbox and scratch), claimed
    /// for the call (`Error::SlotBusy` while another call holds it;
    /// `Capacity(Threads)` when `slot >= max_threads`). `None`: the highest
    /// free slot (`Capacity(Threads)` while every slot is held), which a
    /// concurrent call naming that slot then finds busy. The slot's scratch
    /// holds packets up to `Limits::max_packet_side` (see `parts`).
    pub fn with_slot<R>(&self, slot: Option<u32>, f: impl FnOnce(&mut Slot<'_>) -> R) -> Result<R> {
        let mut guard = match slot {
            Some(s) => self.slots.claim(s)?,
            None => self.slots.claim_free()?,
        };
        Ok(f(&mut Slot::of(guard.parts())))
    }
}

/// A batch's quad consumer writing ray `i`'s nearest hit to `hits[i]`.
fn into_hits(hits: &mut [Hit]) -> impl FnMut(usize, &Hit4, usize) + '_ {
    move |i, h, n| hits[i..i + n].copy_from_slice(&h.hits()[..n])
}

/// A batch's quad consumer writing whether ray `i` is occluded to
/// `occluded[i]`.
fn into_occluded(occluded: &mut [bool]) -> impl FnMut(usize, &Hit4, usize) + '_ {
    per_ray(move |i, h: &Hit4, l| occluded[i] = h.prim[l] != crate::geom::INVALID_ID)
}

/// `t` with single-ray calls going to the first built of grid, BVH,
/// kd-tree (`NotBuilt`: none is).
fn with_first_single(t: SceneTracer<'_>) -> Result<SceneTracer<'_>> {
    let single = if t.grid.is_some() {
        Method::GridDda
    } else if t.bvh.is_some() {
        Method::BvhSingle
    } else if t.kd.is_some() {
        Method::KdSingle
    } else {
        return Err(Error::NotBuilt);
    };
    Ok(SceneTracer { single, ..t })
}
