//! `sheaf bench`: speed and accuracy of every configuration on every scene.
//!
//! For each scene x method (3DDDA, CGT n x n) x triangle test: build ms (the
//! median of `BUILD_REPS` builds), trace ms and Mrays/s of the view's primary
//! rays and of their shadow rays on each thread count, per-ray counters, and
//! accuracy against the f64 brute-force oracle (`sheaf::reference`) on a
//! deterministic subsample of the rays. Writes `bench.csv`, `bench.md` and a
//! speed-vs-accuracy chart (`speed_accuracy.svg`, `speed_accuracy.png`).
//!
//! What is timed: traversal and intersection only. Primary rays are made and
//! packed (n x n tiles of 2x2 quads, quads in Morton order within a tile, as
//! `render::render_tiles` does) before the clock starts; shadow rays are made
//! from each configuration's own primary hits, untimed, and traced as the
//! renderer traces them: from the light towards a point just off the surface
//! (`tmax = 1`), packets with the primary tile's layout, split into quarters
//! while the hit points' distances from the light spread by more than
//! `TraceParams::split`. Threads take bands of whole tile rows in order, each
//! with its own mailbox slot of the context (as `run::render_frame` does).
//!
//! Accuracy: the oracle is brute force (rays x triangles), so it sees every
//! k-th primary ray (k coprime with the image width, so the samples do not
//! line up in columns), with k the smallest that keeps the oracle's tests
//! under `--oracle-budget`; it runs once per scene. The shadow rays it checks
//! are made from the oracle's own primary hits the way the renderer makes
//! them, so every configuration is judged on the same shadow rays. A primary
//! mismatch is a ray whose nearest triangle differs from the oracle's; it is
//! "within tolerance" when the oracle's two nearest hits are a tie
//! (`TIE_REL`) or the ray passes within `EDGE_BARY` of an edge in front of
//! its hit (the tolerances of tests/exact/reference_equivalence.rs). A shadow
//! mismatch is an occlusion answer that differs; it is within tolerance near
//! an edge or when the occluder lies within `END_REL` of the ray's end.
#![forbid(unsafe_code)]

use super::common::{
    BAND_ROWS, MEASURE_NS, NO_PIXEL, Progress, Tiling, check_threads, command_line, create_dir,
    load_or_skip, machine_line, median, par_map, ratio, scene_specs, test_name, timed, view_for,
    write_csv, write_text,
};
use crate::run::{self, ms, res};
use crate::{BenchArgs, GridOpts};
use anyhow::{Context as _, Result, bail};
use glam::Vec3;
use rayon::prelude::*;
use sheaf::Slot;
use sheaf::accel::bvh::BvhParams;
use sheaf::context::SceneTracer as GridTracer;
use sheaf::geom::{F4, Hit4, INVALID_ID, M4, Ray4};
use sheaf::reference::{self, RefHit};
use sheaf::render::{PrimaryRays, SHADOW_OFFSET, ShadowPacket, Tracer, shadow_packet};
use sheaf::trace::{BvhOptions, EntrySearch, RayKind, Structure};
use sheaf::{CgtOptions, Counters, Hit, Method, Ray, Scene, TraceParams};
use std::collections::HashMap;
use std::fmt::Write as _;
use std::time::Instant;

/// Builds per triangle test; the median is reported.
const BUILD_REPS: usize = 3;
/// Tolerances (see the module doc): relative t gap of a tie, barycentric
/// distance to an edge, relative distance of an occluder to the ray's end.
const TIE_REL: f64 = 1e-5;
const EDGE_BARY: f64 = 1e-5;
const END_REL: f64 = 1e-5;
/// Added to every mismatch rate on the chart's log axis, so zeros show.
const RATE_FLOOR: f64 = 1e-6;

/// One traversal configuration (the triangle test is the grid's).
#[derive(Clone, Copy, Debug, PartialEq)]
struct Config {
    method: Method,
    packet: u32,
    cgt: CgtOptions,
    /// Entry-point search of tree packet methods (kd-packet here).
    entry: EntrySearch,
}

impl Config {
    fn params(&self) -> TraceParams {
        let bvh = BvhOptions {
            culling: self.cgt.culling,
            ..BvhOptions::default()
        };
        TraceParams {
            method: self.method,
            packet: self.packet,
            cgt: self.cgt,
            bvh,
            entry: self.entry,
            ..TraceParams::default()
        }
    }
    fn structure(&self) -> Structure {
        self.method.structure()
    }
    /// Chart colour: the 3DDDA 0, CGT n x n by n, the ablations after them;
    /// the BVH from 10: single 10, SIMD 11, then Ranged, Partition, Masked
    /// by packet side 4..32, then the BVH without culling; the kd-tree from
    /// 25: single 25, SIMD 26, packets 27.. by side (8, 16, other) and entry
    /// search (none, MLRTA, AEPSA).
    fn colour(&self) -> usize {
        let side = (self.packet.max(4).trailing_zeros() as usize).min(5) - 2;
        match self.method {
            Method::KdSingle => return 25,
            Method::KdSimd => return 26,
            Method::KdPacket => {
                let s = match self.packet {
                    8 => 0,
                    16 => 1,
                    _ => 2,
                };
                return 27 + 3 * s + self.entry as usize;
            }
            Method::BvhSingle => return 10,
            Method::BvhSimd => return 11,
            _ if self.method.structure() == sheaf::trace::Structure::Bvh && !self.cgt.culling => {
                return 24;
            }
            Method::BvhRanged => return 12 + side,
            Method::BvhPartition => return 16 + side,
            Method::BvhMasked => return 20 + side,
            _ => {}
        }
        if !self.method.is_packet() {
            return 0;
        }
        let on = CgtOptions::default();
        match self.cgt {
            c if c == on => self.packet.trailing_zeros() as usize,
            c if c
                == (CgtOptions {
                    macrocells: false,
                    ..on
                }) =>
            {
                6
            }
            c if c
                == (CgtOptions {
                    mailbox: false,
                    ..on
                }) =>
            {
                7
            }
            c if c
                == (CgtOptions {
                    culling: false,
                    ..on
                }) =>
            {
                8
            }
            _ => 9,
        }
    }
    /// `grid-dda`, `grid-cgt 8x8`, `grid-cgt 8x8 no-mailbox`, `kd-packet 16x16 aepsa`.
    fn label(&self) -> String {
        if !self.method.is_packet() {
            return self.method.name().to_string();
        }
        let mut s = format!("{} {}x{}", self.method.name(), self.packet, self.packet);
        if self.entry != EntrySearch::None {
            let _ = write!(s, " {}", self.entry.name());
        }
        let bvh = self.structure() != Structure::Grid;
        let off: Vec<&str> = [
            (self.cgt.macrocells || bvh, "macrocells"),
            (self.cgt.mailbox || bvh, "mailbox"),
            (self.cgt.culling, "culling"),
        ]
        .iter()
        .filter(|(on, _)| !on)
        .map(|(_, n)| *n)
        .collect();
        if !off.is_empty() {
            let _ = write!(s, " no-{}", off.join("+"));
        }
        s
    }
}

/// Packet sides of the kd-tree's packet configurations.
const KD_PACKETS: [u32; 2] = [8, 16];

/// The configurations to run, the 3DDDA first (the others are compared with
/// it), then (with `bvh`) the BVH's: single ray, 2x2 SIMD ray, and the three
/// large-packet traversals at every packet side from 4; then (with `kd`)
/// the kd-tree's: single ray, 2x2 SIMD ray, and packets of `KD_PACKETS`
/// without and with AEPSA entry points; then the grid's CGT.
fn configs(packets: &[u32], ablation: bool, grid: bool, bvh: bool, kd: bool) -> Vec<Config> {
    let on = CgtOptions::default();
    let cfg = |method: Method, packet: u32, cgt: CgtOptions| Config {
        method,
        packet,
        cgt,
        entry: EntrySearch::None,
    };
    let mut v = vec![cfg(Method::GridDda, 0, on)];
    if !grid {
        v.clear();
    }
    if bvh {
        v.push(cfg(Method::BvhSingle, 0, on));
        v.push(cfg(Method::BvhSimd, 0, on));
        for m in [Method::BvhRanged, Method::BvhPartition, Method::BvhMasked] {
            v.extend(packets.iter().filter(|&&n| n >= 4).map(|&n| cfg(m, n, on)));
        }
        if ablation {
            for m in [Method::BvhRanged, Method::BvhPartition] {
                v.push(cfg(
                    m,
                    16,
                    CgtOptions {
                        culling: false,
                        ..on
                    },
                ));
            }
        }
    }
    if kd {
        v.push(cfg(Method::KdSingle, 0, on));
        v.push(cfg(Method::KdSimd, 0, on));
        for n in KD_PACKETS {
            for entry in [EntrySearch::None, EntrySearch::Aepsa] {
                v.push(Config {
                    entry,
                    ..cfg(Method::KdPacket, n, on)
                });
            }
        }
    }
    if !grid {
        return v;
    }
    v.extend(packets.iter().map(|&n| cfg(Method::GridCgt, n, on)));
    if ablation {
        for cgt in [
            CgtOptions {
                macrocells: false,
                ..on
            },
            CgtOptions {
                mailbox: false,
                ..on
            },
            CgtOptions {
                culling: false,
                ..on
            },
            CgtOptions {
                mailbox: false,
                culling: false,
                ..on
            },
        ] {
            v.push(cfg(Method::GridCgt, 8, cgt));
        }
    }
    v
}

fn mrays(rays: u64, ns: u64) -> f64 {
    run::mrays(rays, ns)
}

// ---------------------------------------------------------------------------
// Ray layouts (the packed primary rays: `common::Tiling`)

/// A view's primary rays: row-major (the 3DDDA's order) and packed per packet side.
struct ViewRays {
    w: u32,
    rays: Vec<Ray>,
    packed: HashMap<u32, (Tiling, Vec<Ray4>, Vec<M4>)>,
}

/// Shadow rays of a frame, one slot per pixel.
struct Shadows {
    rays: Vec<Ray>,
    active: Vec<bool>,
    /// Distance from the light to the ray's end (for packet splitting).
    dist: Vec<f32>,
    count: u64,
}

/// The shadow ray of a primary hit, as `render::surface` makes it: from the
/// light to a point `eps` off the surface on the viewer's side, `tmax = 1`;
/// None when the surface faces away from the light.
fn shadow_ray(ray: &Ray, t: f32, normal: Vec3, light: Vec3, eps: f32) -> Option<Ray> {
    let d = Vec3::from(ray.dir);
    let mut n = normal.normalize_or_zero();
    if n.dot(d) > 0.0 {
        n = -n;
    }
    let p = Vec3::from(ray.org) + d * t;
    if n.dot((light - p).normalize_or_zero()) > 0.0 {
        let end = p + n * eps;
        Some(Ray::new(light, end - light, 0.0, 1.0))
    } else {
        None
    }
}

fn shadows(tr: &GridTracer<'_>, rays: &[Ray], hits: &[Hit], light: Vec3, eps: f32) -> Shadows {
    let pad = Ray::new(light, Vec3::X, 0.0, 0.0);
    let mut s = Shadows {
        rays: vec![pad; rays.len()],
        active: vec![false; rays.len()],
        dist: vec![0.0; rays.len()],
        count: 0,
    };
    for (i, (r, h)) in rays.iter().zip(hits).enumerate() {
        let Some(tri) = h.is_hit().then(|| tr.triangle(h.prim)).flatten() else {
            continue;
        };
        if let Some(sr) = shadow_ray(r, h.t, tri.normal(), light, eps) {
            s.dist[i] = Vec3::from(sr.dir).length();
            s.rays[i] = sr;
            s.active[i] = true;
            s.count += 1;
        }
    }
    s
}

// ---------------------------------------------------------------------------
// Timed tracing on one or more threads

/// Run `work` on `bands` on a pool of one thread per mailbox (`run::par_mailboxes`);
/// returns the summed counters.
fn par_bands<'m, I: ParallelIterator>(
    bands: I,
    mbs: &mut [Slot<'m>],
    work: impl Fn(I::Item, &mut Slot<'m>, &mut Counters) + Sync,
) -> Counters {
    if mbs.is_empty() {
        return Counters::default();
    }
    run::par_mailboxes(mbs.iter_mut().collect(), bands, work)
}

/// Nearest hits of row-major `rays`, one ray at a time.
fn trace_single(
    tr: &GridTracer<'_>,
    rays: &[Ray],
    band: usize,
    hits: &mut [Hit],
    mbs: &mut [Slot<'_>],
) -> Counters {
    par_bands(
        rays.par_chunks(band).zip(hits.par_chunks_mut(band)),
        mbs,
        |(r, h), _, ctr| {
            for (r, h) in r.iter().zip(h) {
                *h = tr.intersect(r, ctr);
            }
        },
    )
}

/// Occlusion of the active `rays`, one ray at a time.
fn occlude_single(
    tr: &GridTracer<'_>,
    s: &Shadows,
    band: usize,
    out: &mut [bool],
    mbs: &mut [Slot<'_>],
) -> Counters {
    let bands = s
        .rays
        .par_chunks(band)
        .zip(s.active.par_chunks(band))
        .zip(out.par_chunks_mut(band));
    par_bands(bands, mbs, |((r, a), o), _, ctr| {
        for ((r, a), o) in r.iter().zip(a).zip(o) {
            *o = *a && tr.occluded(r, ctr);
        }
    })
}

/// Nearest hits of packed rays, one packet of `t.q` quads at a time.
fn trace_packets(
    tr: &GridTracer<'_>,
    p: &TraceParams,
    t: &Tiling,
    rays: &[Ray4],
    active: &[M4],
    hits: &mut [Hit4],
    mbs: &mut [Slot<'_>],
) -> Counters {
    let bands = rays
        .par_chunks(t.band)
        .zip(active.par_chunks(t.band))
        .zip(hits.par_chunks_mut(t.band));
    let traced = tr.packets(p, false);
    par_bands(bands, mbs, |((r, a), h), slot, ctr| {
        for ((r, a), h) in r.chunks(t.q).zip(a.chunks(t.q)).zip(h.chunks_mut(t.q)) {
            traced.run(p, r, a, h, slot, ctr);
        }
    })
}

/// Shadow packets with the primary tiling, split like the renderer's.
fn occlude_packets(
    tr: &GridTracer<'_>,
    p: &TraceParams,
    t: &Tiling,
    shadow: ShadowPacket<'_>,
    hits: &mut [Hit4],
    mbs: &mut [Slot<'_>],
) -> Counters {
    let ShadowPacket { rays, active, dist } = shadow;
    let shadowed = tr.packets(p, true);
    let bands = rays
        .par_chunks(t.band)
        .zip(active.par_chunks(t.band))
        .zip(dist.par_chunks(t.band))
        .zip(hits.par_chunks_mut(t.band));
    par_bands(bands, mbs, |(((r, a), d), h), slot, ctr| {
        for (((r, a), d), h) in r
            .chunks(t.q)
            .zip(a.chunks(t.q))
            .zip(d.chunks(t.q))
            .zip(h.chunks_mut(t.q))
        {
            for x in h.iter_mut() {
                *x = Hit4::MISS;
            }
            let packet = ShadowPacket {
                rays: r,
                active: a,
                dist: d,
            };
            shadow_packet(&shadowed, p, packet, h, slot, ctr);
        }
    })
}

/// Wall time of one trace on `threads` threads, for each measurement.
#[derive(Clone, Copy, Debug, Default)]
struct Timing {
    threads: u32,
    prim_ns: u64,
    shadow_ns: u64,
}

/// What one configuration did on the full frame.
struct Traced {
    /// Per pixel: nearest hit, and whether its shadow ray was blocked.
    hits: Vec<Hit>,
    occluded: Vec<bool>,
    prim_rays: u64,
    shadow_rays: u64,
    prim_ctr: Counters,
    shadow_ctr: Counters,
    timings: Vec<Timing>,
}

/// A view's frame as each configuration traces it: the primary rays, the
/// point light and the shadow rays' offset.
struct ViewFrame<'a> {
    vr: &'a ViewRays,
    light: Vec3,
    eps: f32,
}

/// The frame traced with `cfg`: untimed (hits, occlusion, counters), then
/// timed on each of `threads` thread counts (the median of `reps` runs).
fn trace_config(
    tr: &GridTracer<'_>,
    mbs: &mut [Slot<'_>],
    cfg: &Config,
    frame: &ViewFrame<'_>,
    threads: &[u32],
    reps: u32,
) -> Traced {
    let ViewFrame { vr, light, eps } = *frame;
    let n = vr.rays.len();
    let tr = &tr
        .with_single(cfg.method)
        .expect("the configuration's structure is built");
    let p = cfg.params().with_kind(RayKind::Primary);
    let ps = cfg.params().with_kind(RayKind::Shadow);
    let mut hits = vec![Hit::MISS; n];
    let mut occluded = vec![false; n];
    let mut timings = Vec::new();
    let (prim_ctr, shadow_ctr, shadow_rays);
    if p.tile_side() == 0 {
        let band = BAND_ROWS * vr.w as usize;
        // Untimed first runs (warm caches, counters, results).
        prim_ctr = trace_single(tr, &vr.rays, band, &mut hits, &mut mbs[..1]);
        let s = shadows(tr, &vr.rays, &hits, light, eps);
        shadow_ctr = occlude_single(tr, &s, band, &mut occluded, &mut mbs[..1]);
        shadow_rays = s.count;
        let (mut h2, mut o2) = (hits.clone(), occluded.clone());
        for &t in threads {
            let mbs = &mut mbs[..t as usize];
            let prim_ns = timed(reps, || {
                trace_single(tr, &vr.rays, band, &mut h2, mbs);
            });
            let shadow_ns = timed(reps, || {
                occlude_single(tr, &s, band, &mut o2, mbs);
            });
            timings.push(Timing {
                threads: t,
                prim_ns,
                shadow_ns,
            });
        }
    } else {
        let (tiling, quads, active) = &vr.packed[&p.tile_side()];
        let mut h4 = vec![Hit4::MISS; quads.len()];
        prim_ctr = trace_packets(tr, &p, tiling, quads, active, &mut h4, &mut mbs[..1]);
        tiling.unpack(&mut hits, &h4, |h, i| h.lane(i));
        let s = shadows(tr, &vr.rays, &hits, light, eps);
        let (squads, sactive) =
            tiling.pack(&s.rays, |i| s.active[i], Ray::new(light, Vec3::X, 0.0, 0.0));
        let sdist: Vec<F4> = tiling
            .pix
            .chunks_exact(4)
            .map(|p| {
                F4::from_array([p[0], p[1], p[2], p[3]].map(|i| {
                    if i == NO_PIXEL {
                        0.0
                    } else {
                        s.dist[i as usize]
                    }
                }))
            })
            .collect();
        let mut s4 = vec![Hit4::MISS; squads.len()];
        let packet = ShadowPacket {
            rays: &squads,
            active: &sactive,
            dist: &sdist,
        };
        shadow_ctr = occlude_packets(tr, &ps, tiling, packet, &mut s4, &mut mbs[..1]);
        tiling.unpack(&mut occluded, &s4, |h, i| h.prim[i] != INVALID_ID);
        for (o, a) in occluded.iter_mut().zip(&s.active) {
            *o &= *a;
        }
        shadow_rays = s.count;
        for &t in threads {
            let mbs = &mut mbs[..t as usize];
            let prim_ns = timed(reps, || {
                trace_packets(tr, &p, tiling, quads, active, &mut h4, mbs);
            });
            let shadow_ns = timed(reps, || {
                occlude_packets(tr, &ps, tiling, packet, &mut s4, mbs);
            });
            timings.push(Timing {
                threads: t,
                prim_ns,
                shadow_ns,
            });
        }
    }
    Traced {
        hits,
        occluded,
        prim_rays: n as u64,
        shadow_rays,
        prim_ctr,
        shadow_ctr,
        timings,
    }
}

// ---------------------------------------------------------------------------
// The f64 oracle

fn gcd(a: usize, b: usize) -> usize {
    if b == 0 { a } else { gcd(b, a % b) }
}

/// The oracle's answers for one scene and view, and the near-miss passes
/// already made (cached: every configuration with the same triangle test
/// disagrees on the same rays).
struct Oracle {
    /// Every `step`-th pixel is checked.
    step: usize,
    pixels: Vec<u32>,
    prim: Vec<RefHit>,
    /// Shadow rays of the oracle's hits, their answers, in `pixels` order.
    shadow_rays: Vec<Ray>,
    shadow: Vec<RefHit>,
    prim_near: HashMap<usize, RefHit>,
    shadow_tol: HashMap<usize, bool>,
    ns: u64,
}

impl Oracle {
    fn new(scene: &Scene<'_>, rays: &[Ray], w: u32, light: Vec3, eps: f32, budget: f64) -> Oracle {
        let start = Instant::now();
        let tris = scene.triangle_count().max(1) as f64;
        // Primary plus at most as many shadow rays, each against every triangle.
        let mut step = ((2.0 * rays.len() as f64 * tris / budget.max(1.0)).ceil() as usize).max(1);
        while step > 1 && gcd(step, w as usize) != 1 {
            step += 1;
        }
        let pixels: Vec<u32> = (0..rays.len()).step_by(step).map(|i| i as u32).collect();
        let prim = par_map(&pixels, |&i| reference::nearest(scene, &rays[i as usize]));
        let shadow_rays: Vec<Ray> = pixels
            .iter()
            .zip(&prim)
            .filter(|(_, h)| h.prim != INVALID_ID)
            .filter_map(|(&i, h)| {
                let tri = scene.triangle(h.prim);
                shadow_ray(&rays[i as usize], h.t as f32, tri.normal(), light, eps)
            })
            .collect();
        let shadow = par_map(&shadow_rays, |r| reference::nearest(scene, r));
        Oracle {
            step,
            pixels,
            prim,
            shadow_rays,
            shadow,
            prim_near: HashMap::new(),
            shadow_tol: HashMap::new(),
            ns: start.elapsed().as_nanos() as u64,
        }
    }
}

/// Disagreements of one configuration with the oracle.
#[derive(Clone, Copy, Debug, Default)]
struct Accuracy {
    prim_checked: u64,
    prim_mismatch: u64,
    /// Of the mismatches: ties, near an edge, neither.
    prim_tie: u64,
    prim_edge: u64,
    prim_outside: u64,
    shadow_checked: u64,
    shadow_mismatch: u64,
    shadow_outside: u64,
}

impl Accuracy {
    fn checked(&self) -> u64 {
        self.prim_checked + self.shadow_checked
    }
    fn mismatch(&self) -> u64 {
        self.prim_mismatch + self.shadow_mismatch
    }
    fn rate(&self) -> f64 {
        ratio(self.mismatch(), self.checked())
    }
    fn outside(&self) -> u64 {
        self.prim_outside + self.shadow_outside
    }
}

/// Occlusion of the oracle's shadow rays by `cfg` (packets of consecutive
/// rays for packet methods: incoherent, but the answers are what counts).
fn occlusion_of(tr: &GridTracer<'_>, cfg: &Config, rays: &[Ray], slot: &mut Slot<'_>) -> Vec<bool> {
    let mut ctr = Counters::default();
    if !cfg.method.is_packet() {
        return rays.iter().map(|r| tr.occluded(r, &mut ctr)).collect();
    }
    let p = cfg.params();
    let q = (cfg.packet as usize / 2).pow(2);
    let shadowed = tr.packets(&p, true);
    let mut out = Vec::with_capacity(rays.len());
    for chunk in rays.chunks(4 * q) {
        let (quads, active): (Vec<Ray4>, Vec<M4>) = chunk
            .chunks(4)
            .map(|c| {
                let lanes = [0, 1, 2, 3].map(|k| c.get(k).copied().unwrap_or(c[0]));
                (
                    Ray4::from_rays(&lanes),
                    M4::new(true, c.len() > 1, c.len() > 2, c.len() > 3),
                )
            })
            .unzip();
        let mut hits = vec![Hit4::MISS; quads.len()];
        shadowed.run(&p, &quads, &active, &mut hits, slot, &mut ctr);
        out.extend((0..chunk.len()).map(|k| hits[k / 4].prim[k % 4] != INVALID_ID));
    }
    out
}

/// Count the disagreements of `hits` / `occluded` with the oracle; describe
/// those outside the tolerances in `details` (one line each).
fn accuracy(
    scene: &Scene<'_>,
    o: &mut Oracle,
    w: u32,
    rays: &[Ray],
    hits: &[Hit],
    occluded: &[bool],
    details: &mut Vec<String>,
) -> Accuracy {
    let mut a = Accuracy {
        prim_checked: o.pixels.len() as u64,
        shadow_checked: o.shadow_rays.len() as u64,
        ..Accuracy::default()
    };
    for (k, (&px, want)) in o.pixels.iter().zip(&o.prim).enumerate() {
        if hits[px as usize].prim == want.prim {
            continue;
        }
        a.prim_mismatch += 1;
        let near = *o
            .prim_near
            .entry(k)
            .or_insert_with(|| reference::with_edge_distance(scene, &rays[px as usize], *want));
        if near.gap <= TIE_REL {
            a.prim_tie += 1;
        } else if near.edge <= EDGE_BARY {
            a.prim_edge += 1;
        } else {
            a.prim_outside += 1;
            let (r, h) = (&rays[px as usize], &hits[px as usize]);
            details.push(format!(
                "primary pixel ({}, {}) {r:?}: got prim {} t {} / f64 prim {} t {} (gap {:e}, edge {:e})",
                px % w,
                px / w,
                h.prim as i64,
                h.t,
                want.prim as i64,
                want.t,
                near.gap,
                near.edge
            ));
        }
    }
    for (k, (&got, want)) in occluded.iter().zip(&o.shadow).enumerate() {
        if got == (want.prim != INVALID_ID) {
            continue;
        }
        a.shadow_mismatch += 1;
        let r = o.shadow_rays[k];
        let ok = *o.shadow_tol.entry(k).or_insert_with(|| {
            let near = reference::with_edge_distance(scene, &r, *want);
            // An occluder at the ray's end either way: the oracle's just
            // before it, or one just past it that f32 may put before it.
            let at_end = if want.prim != INVALID_ID {
                want.t >= r.tmax as f64 * (1.0 - END_REL)
            } else {
                let longer = Ray {
                    tmax: (r.tmax as f64 * (1.0 + END_REL)) as f32,
                    ..r
                };
                reference::nearest(scene, &longer).prim != INVALID_ID
            };
            near.edge <= EDGE_BARY || at_end
        });
        if !ok {
            a.shadow_outside += 1;
            details.push(format!(
                "shadow ray {k} {r:?}: got occluded {got} / f64 prim {} t {} (edge {:e})",
                want.prim as i64, want.t, want.edge
            ));
        }
    }
    a
}

// ---------------------------------------------------------------------------
// Embree 3 reference points

/// Embree 3 on one scene's rays (`studies::embree`, where installed): its
/// camera-ray speed on one thread and its accuracy against the same oracle
/// (shadow answers from `rtcOccluded1`).
struct EmbreeRow {
    scene: String,
    /// 0: `rtcIntersect1`, 1: `rtcIntersect8` (the chart's marker).
    kind: usize,
    prim_rays: u64,
    prim_ns: u64,
    acc: Accuracy,
}

impl EmbreeRow {
    const LABELS: [&'static str; 2] = [
        "Embree 3 rtcIntersect1 (MEDIUM)",
        "Embree 3 rtcIntersect8, 4x2 (MEDIUM)",
    ];
    fn mrays(&self) -> f64 {
        mrays(self.prim_rays, self.prim_ns)
    }
}

/// Embree's rows for one scene: one ray at a time and 4 x 2 pixel
/// packets, timed like sheaf's configurations (one untimed run, then the
/// median of up to `reps`) on the calling thread.
#[cfg(embree)]
fn embree_rows(
    name: &str,
    scene: &Scene<'_>,
    oracle: &mut Oracle,
    vr: &ViewRays,
    h: u32,
    reps: u32,
    details: &mut Vec<String>,
) -> Vec<EmbreeRow> {
    let Some(e) = super::embree::Embree::new(scene) else {
        details.push(format!("{name}: Embree's device failed to start"));
        return Vec::new();
    };
    let (w, rays) = (vr.w, &vr.rays);
    let occl: Vec<bool> = oracle.shadow_rays.iter().map(|r| e.occluded1(r)).collect();
    let mut out = Vec::new();
    let mut hits = vec![Hit::MISS; rays.len()];
    let one = |hits: &mut [Hit]| {
        for (r, h) in rays.iter().zip(hits.iter_mut()) {
            *h = e.intersect1(r);
        }
    };
    one(&mut hits);
    let prim_ns = timed(reps, || one(&mut hits));
    let acc = accuracy(scene, oracle, w, rays, &hits, &occl, details);
    out.push(EmbreeRow {
        scene: name.to_string(),
        kind: 0,
        prim_rays: rays.len() as u64,
        prim_ns,
        acc,
    });
    // 4 x 2 pixel packets, gathered before timing (edge packets partial).
    let mut packs: Vec<(Vec<usize>, Vec<Ray>)> = Vec::new();
    for y0 in (0..h).step_by(2) {
        for x0 in (0..w).step_by(4) {
            let idx: Vec<usize> = (0..8)
                .map(|k| (x0 + k % 4, y0 + k / 4))
                .filter(|&(x, y)| x < w && y < h)
                .map(|(x, y)| (y * w + x) as usize)
                .collect();
            let rs = idx.iter().map(|&i| rays[i]).collect();
            packs.push((idx, rs));
        }
    }
    let mut out8 = vec![[Hit::MISS; 8]; packs.len()];
    let eight = |out8: &mut [[Hit; 8]]| {
        for ((_, rs), o) in packs.iter().zip(out8.iter_mut()) {
            e.intersect8(rs, o);
        }
    };
    eight(&mut out8);
    let prim_ns = timed(reps, || eight(&mut out8));
    for ((idx, _), o) in packs.iter().zip(&out8) {
        for (&i, h) in idx.iter().zip(o) {
            hits[i] = *h;
        }
    }
    let acc = accuracy(scene, oracle, w, rays, &hits, &occl, details);
    out.push(EmbreeRow {
        scene: name.to_string(),
        kind: 1,
        prim_rays: rays.len() as u64,
        prim_ns,
        acc,
    });
    out
}

// ---------------------------------------------------------------------------
// Results

/// One configuration on one scene: everything the CSV holds.
struct Row {
    scene: String,
    triangles: u32,
    view: String,
    size: (u32, u32),
    cfg: Config,
    test: String,
    build_ns: u64,
    grid: String,
    refs: u32,
    prim_rays: u64,
    shadow_rays: u64,
    timings: Vec<Timing>,
    prim_ctr: Counters,
    shadow_ctr: Counters,
    oracle_step: usize,
    acc: Accuracy,
    /// Pixels whose nearest triangle / shadow answer differ from the 3DDDA's
    /// with the same triangle test (0: CGT is exact, as it must be).
    diff_dda: (u64, u64),
}

impl Row {
    fn prim_mrays(&self, i: usize) -> f64 {
        self.timings
            .get(i)
            .map_or(0.0, |t| mrays(self.prim_rays, t.prim_ns))
    }
    fn shadow_mrays(&self, i: usize) -> f64 {
        self.timings
            .get(i)
            .map_or(0.0, |t| mrays(self.shadow_rays, t.shadow_ns))
    }
}

fn counters_csv(f: &mut Vec<String>, c: &Counters, rays: u64) {
    for x in [
        c.cells,
        c.macro_skips,
        c.tri_tests,
        c.mailbox_skips,
        c.culled,
    ] {
        f.push(format!("{:.3}", ratio(x, rays)));
    }
    for x in [c.packets, c.stray_lanes, c.packets_no_cull, c.packets_split] {
        f.push(x.to_string());
    }
}

/// bench.csv: the header, then one record per row.
fn csv(rows: &[Row], threads: &[u32]) -> (Vec<String>, Vec<Vec<String>>) {
    let mut head: Vec<String> = "scene,triangles,view,width,height,config,method,packet,macrocells,mailbox,culling,test,build_ms,grid_res,grid_refs,primary_rays,shadow_rays"
        .split(',')
        .map(String::from)
        .collect();
    for t in threads {
        for c in [
            "primary_ms",
            "primary_mrays",
            "shadow_ms",
            "shadow_mrays",
            "total_mrays",
        ] {
            head.push(format!("{c}_{t}t"));
        }
    }
    for k in ["primary", "shadow"] {
        for c in [
            "cells",
            "macro_skips",
            "tri_tests",
            "mailbox_skips",
            "culled",
        ] {
            head.push(format!("{k}_{c}_per_ray"));
        }
        for c in ["packets", "stray_lanes", "packets_no_cull", "packets_split"] {
            head.push(format!("{k}_{c}"));
        }
    }
    head.extend("oracle_step,primary_checked,primary_mismatch,primary_mismatch_tie,primary_mismatch_edge,primary_mismatch_outside_tol,shadow_checked,shadow_mismatch,shadow_mismatch_outside_tol,mismatch_rate,mismatch_outside_tol_rate,primary_diff_vs_dda,shadow_diff_vs_dda".split(',').map(String::from));
    let records = rows
        .iter()
        .map(|r| {
            let a = &r.acc;
            let mut f = vec![
                r.scene.clone(),
                r.triangles.to_string(),
                r.view.clone(),
                r.size.0.to_string(),
                r.size.1.to_string(),
                r.cfg.label(),
                r.cfg.method.name().to_string(),
                r.cfg.packet.to_string(),
                r.cfg.cgt.macrocells.to_string(),
                r.cfg.cgt.mailbox.to_string(),
                r.cfg.cgt.culling.to_string(),
                r.test.clone(),
                format!("{:.3}", ms(r.build_ns)),
                r.grid.clone(),
                r.refs.to_string(),
                r.prim_rays.to_string(),
                r.shadow_rays.to_string(),
            ];
            for (i, t) in r.timings.iter().enumerate() {
                f.extend([
                    format!("{:.3}", ms(t.prim_ns)),
                    format!("{:.3}", r.prim_mrays(i)),
                    format!("{:.3}", ms(t.shadow_ns)),
                    format!("{:.3}", r.shadow_mrays(i)),
                    format!(
                        "{:.3}",
                        mrays(r.prim_rays + r.shadow_rays, t.prim_ns + t.shadow_ns)
                    ),
                ]);
            }
            counters_csv(&mut f, &r.prim_ctr, r.prim_rays);
            counters_csv(&mut f, &r.shadow_ctr, r.shadow_rays);
            f.extend([
                r.oracle_step.to_string(),
                a.prim_checked.to_string(),
                a.prim_mismatch.to_string(),
                a.prim_tie.to_string(),
                a.prim_edge.to_string(),
                a.prim_outside.to_string(),
                a.shadow_checked.to_string(),
                a.shadow_mismatch.to_string(),
                a.shadow_outside.to_string(),
                format!("{:.3e}", a.rate()),
                format!("{:.3e}", ratio(a.outside(), a.checked())),
                r.diff_dda.0.to_string(),
                r.diff_dda.1.to_string(),
            ]);
            f
        })
        .collect();
    (head, records)
}

/// What the Markdown header says about each scene.
struct SceneNote {
    name: String,
    line: String,
}

/// The Embree reference points as a table (empty without them).
fn embree_markdown(ext: &[EmbreeRow]) -> String {
    let mut s = String::new();
    if ext.is_empty() {
        return s;
    }
    s.push_str(
        "\n### Embree 3 on the same rays (reference points)\n\n\
         Built with Embree's default quality (MEDIUM) from the scene's triangles; camera rays on 1 thread, \
         checked against the same oracle as every configuration above (shadow answers: `rtcOccluded1`). \
         benches/embree compares both libraries at every width, quality and thread count.\n\n\
         | scene | Embree call | primary Mrays/s 1T | primary mismatch (outside tol) | shadow mismatch (outside tol) | mismatch rate |\n\
         |---|---|--:|--:|--:|--:|\n",
    );
    for r in ext {
        let a = &r.acc;
        let _ = writeln!(
            s,
            "| {} | {} | {:.2} | {} ({}) | {} ({}) | {:.2e} |",
            r.scene,
            EmbreeRow::LABELS[r.kind],
            r.mrays(),
            a.prim_mismatch,
            a.prim_outside,
            a.shadow_mismatch,
            a.shadow_outside,
            a.rate()
        );
    }
    s
}

fn markdown(rows: &[Row], notes: &[SceneNote], header: &str, threads: &[u32]) -> String {
    let mut s = String::from(header);
    for note in notes {
        let _ = write!(s, "\n### {}\n\n{}\n\n", note.name, note.line);
        s.push_str("| config | test | build ms |");
        for t in threads {
            let _ = write!(s, " primary Mrays/s {t}T |");
        }
        for t in threads {
            let _ = write!(s, " shadow Mrays/s {t}T |");
        }
        s.push_str(" cells/ray | tests/ray | mailbox skips/ray | culled/ray | stray lanes | shadow splits | primary mismatch (outside tol) | shadow mismatch (outside tol) | mismatch rate |\n|---|---|--:|");
        for _ in 0..2 * threads.len() {
            s.push_str("--:|");
        }
        s.push_str("--:|--:|--:|--:|--:|--:|--:|--:|--:|\n");
        for r in rows.iter().filter(|r| r.scene == note.name) {
            let a = &r.acc;
            let c = &r.prim_ctr;
            let _ = write!(
                s,
                "| {} | {} | {:.1} |",
                r.cfg.label(),
                r.test,
                ms(r.build_ns)
            );
            for i in 0..threads.len() {
                let _ = write!(s, " {:.2} |", r.prim_mrays(i));
            }
            for i in 0..threads.len() {
                let _ = write!(s, " {:.2} |", r.shadow_mrays(i));
            }
            let _ = writeln!(
                s,
                " {:.2} | {:.2} | {:.2} | {:.2} | {} | {} | {} ({}) | {} ({}) | {:.2e} |",
                ratio(c.cells, r.prim_rays),
                ratio(c.tri_tests, r.prim_rays),
                ratio(c.mailbox_skips, r.prim_rays),
                ratio(c.culled, r.prim_rays),
                c.stray_lanes,
                r.shadow_ctr.packets_split,
                a.prim_mismatch,
                a.prim_outside,
                a.shadow_mismatch,
                a.shadow_outside,
                a.rate()
            );
        }
    }
    s
}

// ---------------------------------------------------------------------------
// The command

/// `sheaf bench` without a study flag: speed against accuracy.
pub fn run(a: &BenchArgs) -> Result<()> {
    let out_dir = a.out_dir();
    let start = Instant::now();
    let (w, h) = a
        .size
        .unwrap_or(if a.quick { (256, 256) } else { (512, 512) });
    let packets: Vec<u32> = if !a.packets.is_empty() {
        a.packets.clone()
    } else if a.quick {
        vec![4, 8, 16]
    } else {
        vec![2, 4, 8, 16, 32]
    };
    for &n in &packets {
        TraceParams::cgt(n)
            .validate()
            .with_context(|| format!("--packets {n}"))?;
    }
    let mut threads = if a.threads.is_empty() {
        vec![1, 2]
    } else {
        a.threads.clone()
    };
    threads.dedup();
    check_threads(&threads)?;
    let max_threads = *threads.iter().max().unwrap_or(&1);
    let reps = a.reps.unwrap_or(if a.quick { 1 } else { 3 }).max(1);
    let budget = a.oracle_budget.unwrap_or(if a.quick { 2e8 } else { 1e9 });
    if budget.is_nan() || budget < 1.0 {
        bail!("--oracle-budget must be >= 1");
    }
    let with = |s: crate::StructureArg| a.structures.contains(&s);
    let cfgs = configs(
        &packets,
        a.ablation,
        with(crate::StructureArg::Grid),
        with(crate::StructureArg::Bvh),
        with(crate::StructureArg::Kd),
    );
    if cfgs.is_empty() {
        bail!("--structures: name at least one of grid, bvh, kd");
    }
    let mut tests = a.tests.clone();
    tests.dedup_by_key(|t| test_name(*t));
    let specs = scene_specs(a)?;
    create_dir(&out_dir)?;
    let machine = machine_line();
    // One step per configuration, triangle test and scene.
    let per_scene = (tests.len() * cfgs.len()) as u64;
    let prog = Progress::new("sheaf bench", specs.len() as u64 * per_scene);
    prog.say(format_args!(
        "sheaf bench: {} scenes x {} configurations x {} triangle tests, {w}x{h}, threads {:?}, median of up to {reps} timed runs, machine: {machine}",
        specs.len(),
        cfgs.len(),
        tests.len(),
        threads,
    ));
    let mut rows: Vec<Row> = Vec::new();
    let mut notes: Vec<SceneNote> = Vec::new();
    // Embree's reference points (none unless the CLI was built with it).
    #[cfg_attr(not(embree), allow(unused_mut))]
    let mut ext: Vec<EmbreeRow> = Vec::new();
    let mut mismatch_log = String::from(
        "# Mismatches with the f64 oracle outside the tolerances (scene, configuration, test: ray, both answers)\n",
    );
    for spec in &specs {
        prog.doing(spec.name.clone());
        let t_load = Instant::now();
        let Some(loaded) = load_or_skip(spec, &prog) else {
            prog.inc(per_scene);
            continue;
        };
        let scene = loaded.scene()?;
        let load_ms = t_load.elapsed().as_secs_f64() * 1e3;
        let mut limits = run::limits(&scene, (w, h), max_threads);
        if cfgs.iter().any(|c| c.structure() == Structure::Kd) {
            // kd pools that force no leaf (gears needs more references
            // than the default rule gives); the tree is the same for every
            // triangle test.
            let kp = sheaf::accel::kd::KdParams::default();
            limits = run::kd_limits(&scene, limits, &kp)
                .with_context(|| spec.name.clone())?
                .0;
        }
        // Set on the first triangle test's build: view, light, rays, oracle.
        let mut prepared: Option<(ViewRays, Vec3, f32, Oracle)> = None;
        let mut scene_line = String::new();
        let mut view_how = String::new();
        for &test in &tests {
            let grid = GridOpts {
                test,
                lambda: a.lambda,
                macrocell: a.macrocell,
            };
            let params = grid.params();
            let (mut ctx, info) = run::context_for(&scene, limits, &params, 1.0)
                .with_context(|| spec.name.clone())?;
            if info.triangles == 0 {
                prog.say(format_args!(
                    "note: {}: every triangle is degenerate or non-finite, skipped",
                    spec.name
                ));
                prog.inc(per_scene - rows.iter().filter(|r| r.scene == spec.name).count() as u64);
                break;
            }
            let mut builds = vec![ctx.stats().build_ns];
            for _ in 1..BUILD_REPS {
                ctx.build_grid(&scene, &params)?;
                builds.push(ctx.stats().build_ns);
            }
            let build_ns = median(builds);
            let bvh_params = BvhParams {
                test: params.test,
                ..BvhParams::default()
            };
            let mut bvh_builds = Vec::new();
            let mut bvh_info = None;
            if cfgs
                .iter()
                .any(|c| c.method.structure() == sheaf::trace::Structure::Bvh)
            {
                for _ in 0..BUILD_REPS {
                    bvh_info = Some(ctx.build_bvh(&scene, &bvh_params)?);
                    bvh_builds.push(ctx.stats().bvh_build_ns);
                }
            }
            let bvh_build_ns = if bvh_builds.is_empty() {
                0
            } else {
                median(bvh_builds)
            };
            let kd_params = sheaf::accel::kd::KdParams {
                test: params.test,
                ..Default::default()
            };
            let mut kd_builds = Vec::new();
            let mut kd_info = None;
            if cfgs.iter().any(|c| c.structure() == Structure::Kd) {
                for _ in 0..BUILD_REPS {
                    kd_info = Some(ctx.build_kd(&scene, &kd_params)?);
                    kd_builds.push(ctx.stats().kd_build_ns);
                }
            }
            let kd_build_ns = median(kd_builds);
            if prepared.is_none() {
                let tr = ctx.tracer()?;
                let (v, light, how) = view_for(&loaded, &tr, &info.bounds, w, h);
                let pr = PrimaryRays::new(&crate::view::camera(&v), w, h)?;
                let rays: Vec<Ray> = (0..h)
                    .flat_map(|y| (0..w).map(move |x| (x, y)))
                    .map(|(x, y)| pr.ray(x, y))
                    .collect();
                let pad = Ray::new(v.eye, Vec3::X, 0.0, 0.0);
                // Every packet side a configuration uses (the ablations' 8 too).
                let mut sides: Vec<u32> = cfgs
                    .iter()
                    .map(|c| c.params().tile_side())
                    .filter(|&n| n > 0)
                    .collect();
                sides.sort_unstable();
                sides.dedup();
                let packed = sides
                    .iter()
                    .map(|&n| {
                        let t = Tiling::new(w, h, n);
                        let (q, m) = t.pack(&rays, |_| true, pad);
                        (n, (t, q, m))
                    })
                    .collect();
                let eps = SHADOW_OFFSET * info.bounds.diagonal().length();
                let oracle = Oracle::new(&scene, &rays, w, light, eps, budget);
                scene_line = format!(
                    "{} triangles ({} traceable), loaded in {load_ms:.0} ms; view: {how}, eye ({}), look at ({}), fov {}; light ({}); \
                     oracle (f64 brute force): 1 in {} primary rays ({} rays) and the shadow rays of its hits ({} rays), {:.1} s",
                    scene.triangle_count(),
                    info.triangles,
                    fmt_v(v.eye),
                    fmt_v(v.look_at),
                    v.fov_y_deg,
                    fmt_v(light),
                    oracle.step,
                    oracle.pixels.len(),
                    oracle.shadow_rays.len(),
                    oracle.ns as f64 * 1e-9
                );
                prog.say(format_args!("[{}] {scene_line}", spec.name));
                view_how = how;
                prepared = Some((ViewRays { w, rays, packed }, light, eps, oracle));
                #[cfg(embree)]
                if let Some((vr, _, _, oracle)) = prepared.as_mut() {
                    let mut found = Vec::new();
                    for r in embree_rows(&spec.name, &scene, oracle, vr, h, reps, &mut found) {
                        prog.say(format_args!(
                            "[{}] {}: {:.2} Mrays/s (1 thread), {} of {} checked rays differ from the oracle",
                            spec.name,
                            EmbreeRow::LABELS[r.kind],
                            r.mrays(),
                            r.acc.mismatch(),
                            r.acc.checked()
                        ));
                        ext.push(r);
                    }
                    for d in found {
                        let _ = writeln!(mismatch_log, "{} Embree: {d}", spec.name);
                    }
                }
            }
            let Some((vr, light, eps, oracle)) = prepared.as_mut() else {
                unreachable!()
            };
            let grid_res = res(&info);
            prog.say(format_args!(
                "[{}] {}: grid {grid_res}, {} refs, build {:.2} ms (median of {BUILD_REPS})",
                spec.name,
                test_name(test),
                info.refs,
                ms(build_ns)
            ));
            let bvh_line = bvh_info
                .map(|b| {
                    format!(
                        "bvh {} nodes {} leaves depth {}",
                        b.nodes, b.leaves, b.depth
                    )
                })
                .unwrap_or_default();
            if let Some(b) = bvh_info {
                prog.say(format_args!(
                    "[{}] {}: {bvh_line}, SAH cost {:.1}, build {:.2} ms (median of {BUILD_REPS}) = {:.2} M triangles/s",
                    spec.name,
                    test_name(test),
                    b.sah_cost,
                    ms(bvh_build_ns),
                    b.triangles as f64 / (bvh_build_ns.max(1) as f64 * 1e-3)
                ));
            }
            let kd_line = kd_info
                .map(|k| {
                    format!(
                        "kd {} nodes {} leaves {:.1}% empty avg depth {:.2}",
                        k.nodes,
                        k.leaves,
                        100.0 * k.empty_leaves as f64 / k.leaves.max(1) as f64,
                        k.avg_leaf_depth
                    )
                })
                .unwrap_or_default();
            if let Some(k) = kd_info {
                prog.say(format_args!(
                    "[{}] {}: kd-tree {} (median of {BUILD_REPS} builds)",
                    spec.name,
                    test_name(test),
                    crate::cmd::kd_line(&k, kd_build_ns)
                ));
            }
            let (tr, mbs) = ctx.parts()?;
            let mut mbs: Vec<Slot<'_>> = mbs.take(max_threads as usize).collect();
            let mut dda: Option<(Vec<u32>, Vec<bool>)> = None;
            let frame = ViewFrame {
                vr,
                light: *light,
                eps: *eps,
            };
            for cfg in &cfgs {
                let t = trace_config(&tr, &mut mbs, cfg, &frame, &threads, reps);
                let occl = occlusion_of(&tr, cfg, &oracle.shadow_rays, &mut mbs[0]);
                let mut found = Vec::new();
                let acc = accuracy(&scene, oracle, w, &vr.rays, &t.hits, &occl, &mut found);
                for d in found {
                    let _ = writeln!(
                        mismatch_log,
                        "{} {} {}: {d}",
                        spec.name,
                        cfg.label(),
                        test_name(test)
                    );
                }
                let prims: Vec<u32> = t.hits.iter().map(|h| h.prim).collect();
                let diff_dda = match &dda {
                    None => {
                        dda = Some((prims, t.occluded.clone()));
                        (0, 0)
                    }
                    Some((p, o)) => (
                        p.iter().zip(&prims).filter(|(a, b)| a != b).count() as u64,
                        o.iter().zip(&t.occluded).filter(|(a, b)| a != b).count() as u64,
                    ),
                };
                let row = Row {
                    scene: spec.name.clone(),
                    triangles: scene.triangle_count(),
                    view: view_how.clone(),
                    size: (w, h),
                    cfg: *cfg,
                    test: test_name(test),
                    build_ns: match cfg.structure() {
                        Structure::Grid => build_ns,
                        Structure::Bvh => bvh_build_ns,
                        Structure::Kd => kd_build_ns,
                    },
                    grid: match cfg.structure() {
                        Structure::Grid => grid_res.clone(),
                        Structure::Bvh => bvh_line.clone(),
                        Structure::Kd => kd_line.clone(),
                    },
                    refs: match cfg.structure() {
                        Structure::Grid => info.refs,
                        Structure::Bvh => 0,
                        Structure::Kd => kd_info.map_or(0, |k| k.refs),
                    },
                    prim_rays: t.prim_rays,
                    shadow_rays: t.shadow_rays,
                    timings: t.timings,
                    prim_ctr: t.prim_ctr,
                    shadow_ctr: t.shadow_ctr,
                    oracle_step: oracle.step,
                    acc,
                    diff_dda,
                };
                prog.say(progress(&row));
                prog.step();
                rows.push(row);
            }
        }
        if prepared.is_some() {
            notes.push(SceneNote {
                name: spec.name.clone(),
                line: scene_line,
            });
        }
    }

    let header = format!(
        "# sheaf bench\n\n\
         - command: `{}`\n\
         - machine (at the start): {}\n\
         - image: {w}x{h} primary rays per scene (one view), plus one shadow ray per lit hit, traced from the light\n\
         - timing: traversal and intersection only (rays packed beforehand), after one untimed run: median of up to {reps} runs \
         (fewer once they took {:.1} s); threads {:?}; build: median of {BUILD_REPS}\n\
         - grid: lambda {}, macrocell {}\n\
         - counters are per primary ray; stray lanes and shadow splits are totals\n\
         - accuracy: f64 brute-force oracle on a subsample (every k-th primary ray, k per scene below, plus the shadow rays of the oracle's hits); \
         mismatch = nearest triangle (primary) or occlusion (shadow) differs; in parentheses those outside the tolerances \
         (tie gap <= {TIE_REL:e} relative, edge distance <= {EDGE_BARY:e} barycentric, occluder within {END_REL:e} of the ray's end); \
         mismatch rate = all mismatches / rays checked\n\
         - total time: {:.0} s\n",
        command_line(),
        machine,
        MEASURE_NS as f64 * 1e-9,
        threads,
        a.lambda,
        a.macrocell,
        start.elapsed().as_secs_f64()
    );
    let md = markdown(&rows, &notes, &header, &threads) + &embree_markdown(&ext);
    let csv_path = out_dir.join("bench.csv");
    let md_path = out_dir.join("bench.md");
    let (head, records) = csv(&rows, &threads);
    write_csv(&csv_path, &head, records)?;
    write_text(&md_path, &md)?;
    let log_path = out_dir.join("mismatches.txt");
    write_text(&log_path, &mismatch_log)?;
    prog.say(format_args!("\n{md}"));
    let inconsistent: u64 = rows.iter().map(|r| r.diff_dda.0 + r.diff_dda.1).sum();
    if inconsistent > 0 {
        prog.say(format_args!(
            "warning: some packet configurations differ from the 3DDDA with the same triangle test (see primary_diff_vs_dda in bench.csv)"
        ));
    }
    let (svg, png) = (
        out_dir.join("speed_accuracy.svg"),
        out_dir.join("speed_accuracy.png"),
    );
    chart::write(&rows, &notes, &ext, (w, h), &svg, &png)?;
    prog.say(format_args!(
        "wrote {}, {}, {}, {}, {}",
        csv_path.display(),
        md_path.display(),
        log_path.display(),
        svg.display(),
        png.display()
    ));
    Ok(())
}

fn fmt_v(v: Vec3) -> String {
    format!("{:.3}, {:.3}, {:.3}", v.x, v.y, v.z)
}

/// One line per configuration as it completes.
fn progress(r: &Row) -> String {
    let ts: Vec<String> = r
        .timings
        .iter()
        .map(|t| format!("{}T", t.threads))
        .collect();
    let mut s = format!(
        "[{}] {:<34} {:<10} Mrays/s ({}) primary",
        r.scene,
        r.cfg.label(),
        r.test,
        ts.join("/")
    );
    for i in 0..r.timings.len() {
        let _ = write!(s, " {:>6.2}", r.prim_mrays(i));
    }
    s.push_str("  shadow");
    for i in 0..r.timings.len() {
        let _ = write!(s, " {:>6.2}", r.shadow_mrays(i));
    }
    let a = &r.acc;
    let _ = write!(
        s,
        "  tests/ray {:>6.2}  mismatch {}/{} + {}/{} shadow ({} outside tol)",
        ratio(r.prim_ctr.tri_tests, r.prim_rays),
        a.prim_mismatch,
        a.prim_checked,
        a.shadow_mismatch,
        a.shadow_checked,
        a.outside()
    );
    if r.diff_dda != (0, 0) {
        let _ = write!(
            s,
            "  DIFFERS FROM 3DDDA: {} primary, {} shadow",
            r.diff_dda.0, r.diff_dda.1
        );
    }
    s
}

// ---------------------------------------------------------------------------
// The chart

mod chart {
    use super::super::common::{FONT, save_chart};
    use super::{EmbreeRow, RATE_FLOOR, Row, SceneNote, ratio};
    use anyhow::Result;
    use plotters::coord::Shift;
    use plotters::prelude::*;
    use std::path::Path;

    const PANEL: (u32, u32) = (560, 420);
    const LEGEND_W: u32 = 260;
    const COLS: u32 = 3;
    const TITLE_H: u32 = 44;

    /// Colours per configuration label, in order of first appearance.
    const COLOURS: &[RGBColor] = &[
        RGBColor(30, 30, 30),    // grid-dda
        RGBColor(31, 119, 180),  // cgt 2
        RGBColor(44, 160, 44),   // cgt 4
        RGBColor(255, 127, 14),  // cgt 8
        RGBColor(214, 39, 40),   // cgt 16
        RGBColor(148, 103, 189), // cgt 32
        RGBColor(140, 86, 75),
        RGBColor(227, 119, 194),
        RGBColor(127, 127, 127),
        RGBColor(188, 189, 34),
        RGBColor(23, 190, 207),
        RGBColor(0, 0, 128),
        // BVH: single, SIMD; Ranged 4..32 (blues), Partition 4..32 (reds), Masked 4..32 (greens); no culling.
        RGBColor(90, 90, 90),
        RGBColor(160, 160, 160),
        RGBColor(158, 202, 225),
        RGBColor(107, 174, 214),
        RGBColor(33, 113, 181),
        RGBColor(8, 48, 107),
        RGBColor(252, 146, 114),
        RGBColor(239, 59, 44),
        RGBColor(165, 15, 21),
        RGBColor(103, 0, 13),
        RGBColor(161, 217, 155),
        RGBColor(65, 171, 93),
        RGBColor(0, 109, 44),
        RGBColor(0, 68, 27),
        RGBColor(255, 200, 0),
        // kd-tree: single, SIMD; packets 8x8 (none, MLRTA, AEPSA: purples),
        // 16x16 (browns/oranges), other sides (teals).
        RGBColor(60, 60, 110),
        RGBColor(130, 130, 190),
        RGBColor(188, 189, 220),
        RGBColor(158, 154, 200),
        RGBColor(84, 39, 143),
        RGBColor(253, 208, 162),
        RGBColor(253, 141, 60),
        RGBColor(166, 54, 3),
        RGBColor(153, 216, 201),
        RGBColor(65, 174, 118),
        RGBColor(0, 88, 36),
    ];

    pub(super) struct Point {
        pub(super) x: f64,
        pub(super) rate: f64,
        pub(super) colour: usize,
        pub(super) marker: usize,
    }

    struct Panel {
        title: String,
        points: Vec<Point>,
        /// Embree's reference points: (Mrays/s, mismatch rate, kind).
        refs: Vec<(f64, f64, usize)>,
    }

    /// Embree's points of `scene` (`None`: every scene, rays over summed
    /// time as the all-scenes panel does).
    fn refs(ext: &[EmbreeRow], scene: Option<&str>) -> Vec<(f64, f64, usize)> {
        (0..EmbreeRow::LABELS.len())
            .filter_map(|k| {
                let rs: Vec<&EmbreeRow> = ext
                    .iter()
                    .filter(|r| r.kind == k && scene.is_none_or(|s| r.scene == s))
                    .collect();
                if rs.is_empty() {
                    return None;
                }
                let rays = rs.iter().map(|r| r.prim_rays).sum();
                let ns = rs.iter().map(|r| r.prim_ns).sum();
                let mism = rs.iter().map(|r| r.acc.mismatch()).sum();
                let checked = rs.iter().map(|r| r.acc.checked()).sum();
                Some((super::mrays(rays, ns), ratio(mism, checked), k))
            })
            .collect()
    }

    /// Indices of the Pareto-optimal points (max x, min rate), by x ascending.
    pub(super) fn front(points: &[Point]) -> Vec<usize> {
        let mut idx: Vec<usize> = (0..points.len()).collect();
        idx.sort_by(|&a, &b| {
            points[b]
                .x
                .total_cmp(&points[a].x)
                .then(points[a].rate.total_cmp(&points[b].rate))
        });
        let mut best = f64::INFINITY;
        let mut out = Vec::new();
        for i in idx {
            if points[i].rate < best {
                best = points[i].rate;
                out.push(i);
            }
        }
        out.reverse();
        out
    }

    /// Panels: all scenes, then one per scene. `labels` are (colour, configuration label).
    fn panels(
        rows: &[Row],
        notes: &[SceneNote],
        ext: &[EmbreeRow],
        labels: &[(usize, String)],
        tests: &[String],
    ) -> Vec<Panel> {
        let key = |r: &Row| {
            (
                r.cfg.colour(),
                tests.iter().position(|t| *t == r.test).unwrap_or(0),
            )
        };
        let mut out = Vec::new();
        // All scenes: rays over summed time, mismatches over summed checks.
        let mut all = Panel {
            title: "all scenes (rays / total time, mismatches / checks)".into(),
            points: Vec::new(),
            refs: refs(ext, None),
        };
        for &(ci, _) in labels {
            for (ti, _) in tests.iter().enumerate() {
                let rs: Vec<&Row> = rows.iter().filter(|r| key(r) == (ci, ti)).collect();
                if rs.is_empty() {
                    continue;
                }
                let rays: u64 = rs.iter().map(|r| r.prim_rays).sum();
                let ns: u64 = rs
                    .iter()
                    .map(|r| r.timings.first().map_or(0, |t| t.prim_ns))
                    .sum();
                let mism: u64 = rs.iter().map(|r| r.acc.mismatch()).sum();
                let checked: u64 = rs.iter().map(|r| r.acc.checked()).sum();
                all.points.push(Point {
                    x: super::mrays(rays, ns),
                    rate: ratio(mism, checked),
                    colour: ci,
                    marker: ti,
                });
            }
        }
        if notes.len() > 1 {
            out.push(all);
        }
        for n in notes {
            let rs = rows.iter().filter(|r| r.scene == n.name);
            let tris = rows
                .iter()
                .find(|r| r.scene == n.name)
                .map_or(0, |r| r.triangles);
            out.push(Panel {
                title: format!("{} ({} tris)", n.name, tris),
                points: rs
                    .map(|r| {
                        let (c, m) = key(r);
                        Point {
                            x: r.prim_mrays(0),
                            rate: r.acc.rate(),
                            colour: c,
                            marker: m,
                        }
                    })
                    .collect(),
                refs: refs(ext, Some(&n.name)),
            });
        }
        out
    }

    fn marker<DB: DrawingBackend>(
        area: &DrawingArea<DB, Shift>,
        at: (i32, i32),
        marker: usize,
        c: RGBColor,
    ) -> Result<(), DrawingAreaErrorKind<DB::ErrorType>> {
        let s = c.filled();
        match marker % 3 {
            0 => area.draw(&Circle::new(at, 5, s)),
            1 => area.draw(&TriangleMarker::new(at, 7, s)),
            _ => area.draw(&Rectangle::new(
                [(at.0 - 5, at.1 - 5), (at.0 + 5, at.1 + 5)],
                s,
            )),
        }
    }

    fn draw<DB: DrawingBackend>(
        root: DrawingArea<DB, Shift>,
        panels: &[Panel],
        labels: &[(usize, String)],
        tests: &[String],
        title: &str,
    ) -> Result<()>
    where
        DB::ErrorType: 'static,
    {
        root.fill(&WHITE)?;
        let (top, body) = root.split_vertically(TITLE_H);
        top.draw(&Text::new(
            title.to_string(),
            (14, 12),
            (FONT, 20).into_font().color(&BLACK),
        ))?;
        let (grid, legend) = body.split_horizontally(COLS * PANEL.0);
        let rows = (panels.len() as u32).div_ceil(COLS);
        let cells = grid.split_evenly((rows as usize, COLS as usize));
        for (area, p) in cells.iter().zip(panels) {
            let xs = p
                .points
                .iter()
                .map(|q| q.x)
                .chain(p.refs.iter().map(|r| r.0));
            let xmax = xs.fold(0.0, f64::max).max(1e-3) * 1.12;
            let rates = p
                .points
                .iter()
                .map(|q| q.rate)
                .chain(p.refs.iter().map(|r| r.1));
            let ymax = (rates.fold(0.0, f64::max) + RATE_FLOOR).max(1e-4) * 4.0;
            let mut chart = ChartBuilder::on(area)
                .caption(&p.title, (FONT, 17))
                .margin(10)
                .x_label_area_size(38)
                .y_label_area_size(62)
                .build_cartesian_2d(0.0..xmax, (RATE_FLOOR * 0.5..ymax).log_scale())?;
            chart
                .configure_mesh()
                .x_desc("Mrays/s (primary rays, 1 thread)")
                .y_desc("mismatch rate + 1e-6 (log)")
                .label_style((FONT, 12))
                .axis_desc_style((FONT, 13))
                .y_label_formatter(&|v| format!("{v:.0e}"))
                .x_label_formatter(&|v| format!("{v:.1}"))
                .light_line_style(RGBColor(238, 238, 238))
                .draw()?;
            let f = front(&p.points);
            chart.draw_series(LineSeries::new(
                f.iter()
                    .map(|&i| (p.points[i].x, p.points[i].rate + RATE_FLOOR)),
                ShapeStyle::from(&BLACK.mix(0.55)).stroke_width(2),
            ))?;
            let at = |q: &Point| (q.x, q.rate + RATE_FLOOR);
            let col = |q: &Point| COLOURS[q.colour % COLOURS.len()].filled();
            let of = |m: usize| p.points.iter().filter(move |q| q.marker % 3 == m);
            chart.draw_series(
                of(0).map(|q| EmptyElement::at(at(q)) + Circle::new((0, 0), 5, col(q))),
            )?;
            chart.draw_series(
                of(1).map(|q| EmptyElement::at(at(q)) + TriangleMarker::new((0, 0), 7, col(q))),
            )?;
            chart.draw_series(
                of(2).map(|q| EmptyElement::at(at(q)) + Rectangle::new([(-5, -5), (5, 5)], col(q))),
            )?;
            // Embree's reference points: black crosses (1-wide) and
            // stars (8-wide), off the front (another library).
            for &(x, rate, k) in &p.refs {
                let at = (x, rate + RATE_FLOOR);
                let st = ShapeStyle::from(&BLACK).stroke_width(2);
                if k == 0 {
                    chart.draw_series(std::iter::once(Cross::new(at, 7, st)))?;
                } else {
                    chart.draw_series(std::iter::once(
                        EmptyElement::at(at)
                            + Cross::new((0, 0), 7, st)
                            + Circle::new((0, 0), 7, st),
                    ))?;
                }
            }
            // Ring the points on the front.
            chart.draw_series(f.iter().map(|&i| {
                Circle::new(
                    at(&p.points[i]),
                    10,
                    ShapeStyle::from(&BLACK.mix(0.55)).stroke_width(1),
                )
            }))?;
        }
        // Legend: colours per configuration, markers per triangle test, the front.
        let font = (FONT, 14).into_font().color(&BLACK);
        let mut y = 30;
        legend.draw(&Text::new("configuration (colour)", (10, y), font.clone()))?;
        y += 24;
        for (i, l) in labels {
            marker(&legend, (22, y + 7), 0, COLOURS[i % COLOURS.len()])?;
            legend.draw(&Text::new(l.clone(), (36, y), font.clone()))?;
            y += 22;
        }
        y += 14;
        legend.draw(&Text::new("triangle test (marker)", (10, y), font.clone()))?;
        y += 24;
        for (i, t) in tests.iter().enumerate() {
            marker(&legend, (22, y + 7), i, RGBColor(90, 90, 90))?;
            legend.draw(&Text::new(t.clone(), (36, y), font.clone()))?;
            y += 22;
        }
        y += 14;
        legend.draw(&PathElement::new(
            vec![(12, y + 7), (32, y + 7)],
            ShapeStyle::from(&BLACK.mix(0.55)).stroke_width(2),
        ))?;
        legend.draw(&Circle::new(
            (22, y + 7),
            10,
            ShapeStyle::from(&BLACK.mix(0.55)).stroke_width(1),
        ))?;
        legend.draw(&Text::new("Pareto front", (36, y), font.clone()))?;
        y += 22;
        legend.draw(&Text::new(
            "(max speed, min mismatch)",
            (36, y),
            font.clone(),
        ))?;
        if panels.iter().any(|p| !p.refs.is_empty()) {
            y += 36;
            legend.draw(&Text::new("reference (black)", (10, y), font.clone()))?;
            for (k, l) in EmbreeRow::LABELS.iter().enumerate() {
                y += 22;
                let st = ShapeStyle::from(&BLACK).stroke_width(2);
                legend.draw(&Cross::new((22, y + 7), 7, st))?;
                if k == 1 {
                    legend.draw(&Circle::new((22, y + 7), 7, st))?;
                }
                legend.draw(&Text::new(
                    l.replace("Embree 3 ", "Embree "),
                    (36, y),
                    (FONT, 12).into_font().color(&BLACK),
                ))?;
            }
        }
        y += 34;
        for line in [
            "y: mismatch rate vs the f64",
            "oracle (primary + shadow",
            "rays checked), + 1e-6 so",
            "zero shows, log scale",
        ] {
            legend.draw(&Text::new(
                line,
                (10, y),
                (FONT, 13).into_font().color(&BLACK),
            ))?;
            y += 18;
        }
        root.present()?;
        Ok(())
    }

    /// Write the chart as SVG and PNG.
    pub(super) fn write(
        rows: &[Row],
        notes: &[SceneNote],
        ext: &[EmbreeRow],
        size: (u32, u32),
        svg: &Path,
        png: &Path,
    ) -> Result<()> {
        let mut labels: Vec<(usize, String)> = Vec::new();
        let mut tests: Vec<String> = Vec::new();
        for r in rows {
            if !labels.iter().any(|(c, _)| *c == r.cfg.colour()) {
                labels.push((r.cfg.colour(), r.cfg.label()));
            }
            if !tests.contains(&r.test) {
                tests.push(r.test.clone());
            }
        }
        labels.sort();
        let ps = panels(rows, notes, ext, &labels, &tests);
        let rows_n = (ps.len() as u32).div_ceil(COLS).max(1);
        let dim = (COLS * PANEL.0 + LEGEND_W, TITLE_H + rows_n * PANEL.1);
        let title = format!(
            "sheaf bench: speed vs accuracy, {}x{} primary rays per scene",
            size.0, size.1
        );
        save_chart(
            dim,
            svg,
            png,
            |root| draw(root, &ps, &labels, &tests, &title),
            |root| draw(root, &ps, &labels, &tests, &title),
        )
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::TestArg;
    use crate::studies::bench;

    #[test]
    fn tiling_covers_every_pixel_once() {
        for (w, h, n) in [
            (10, 6, 4),
            (16, 16, 8),
            (7, 3, 2),
            (33, 17, 32),
            (64, 8, 16),
        ] {
            let t = Tiling::new(w, h, n);
            let tiles = (w.div_ceil(n) * h.div_ceil(n)) as usize;
            assert_eq!(t.pix.len(), tiles * t.q * 4, "{w}x{h} n={n}");
            let mut seen = vec![0u8; (w * h) as usize];
            for &p in t.pix.iter().filter(|&&p| p != NO_PIXEL) {
                seen[p as usize] += 1;
            }
            assert!(
                seen.iter().all(|&c| c == 1),
                "{w}x{h} n={n}: every pixel exactly once"
            );
            // Lane order of a quad: (x, y), (x+1, y), (x, y+1), (x+1, y+1).
            assert_eq!(&t.pix[..4], &[0, 1, w, w + 1]);
        }
    }

    #[test]
    fn pareto_front_keeps_the_undominated_points() {
        let p = |x: f64, rate: f64| chart::Point {
            x,
            rate,
            colour: 0,
            marker: 0,
        };
        let pts = [
            p(1.0, 0.0),
            p(2.0, 0.5),
            p(3.0, 0.1),
            p(0.5, 0.0),
            p(3.0, 0.2),
            p(2.5, 0.1),
        ];
        assert_eq!(chart::front(&pts), vec![0, 2]);
    }

    #[test]
    fn labels_and_colours() {
        let c = configs(&[2, 8, 32], true, true, false, false);
        let labels: Vec<String> = c.iter().map(Config::label).collect();
        assert_eq!(labels[0], "grid-dda");
        assert_eq!(labels[2], "grid-cgt 8x8");
        assert_eq!(labels[5], "grid-cgt 8x8 no-mailbox");
        assert_eq!(labels[7], "grid-cgt 8x8 no-mailbox+culling");
        let colours: Vec<usize> = c.iter().map(Config::colour).collect();
        assert_eq!(colours, vec![0, 1, 3, 5, 6, 7, 8, 9]);
    }

    /// A tiny run end to end: every file is written, CGT agrees with the
    /// 3DDDA on every pixel, the tetrahedra match the oracle exactly.
    #[test]
    fn tiny_run_writes_every_output() {
        let dir = std::env::temp_dir().join(format!("sheaf-bench-test-{}", std::process::id()));
        let a = BenchArgs {
            scenes: vec!["tetra".into()],
            scenes_dir: None,
            size: Some((36, 20)),
            quick: false,
            packets: vec![4, 16],
            tests: vec![TestArg::Mt, TestArg::Watertight],
            threads: vec![1, 2],
            ablation: true,
            reps: Some(1),
            oracle_budget: Some(1e7),
            lambda: 5.0,
            macrocell: 6,
            out_dir: Some(dir.clone()),
            whitted: false,
            entry: false,
            pgrid: false,
            stress: false,
            pgrid_opts: Default::default(),
            structures: vec![crate::StructureArg::Grid, crate::StructureArg::Bvh],
        };
        bench(&a).unwrap();
        let csv = std::fs::read_to_string(dir.join("bench.csv")).unwrap();
        let lines: Vec<&str> = csv.lines().collect();
        assert_eq!(
            lines.len(),
            1 + 2 * (1 + 2 + 4 + 2 + 3 * 2 + 2),
            "header + (dda + 2 CGT sizes + 4 ablations + BVH single, SIMD, 3 traversals x 2 sizes, 2 without culling) x 2 tests"
        );
        let head: Vec<&str> = lines[0].split(',').collect();
        let col = |name: &str| head.iter().position(|h| *h == name).unwrap();
        for l in &lines[1..] {
            let f: Vec<&str> = l.split(',').collect();
            assert_eq!(f.len(), head.len());
            assert_eq!(f[col("primary_diff_vs_dda")], "0", "{l}");
            assert_eq!(f[col("shadow_diff_vs_dda")], "0", "{l}");
            assert_eq!(f[col("primary_mismatch_outside_tol")], "0", "{l}");
            assert!(f[col("primary_checked")].parse::<u64>().unwrap() > 0);
        }
        let md = std::fs::read_to_string(dir.join("bench.md")).unwrap();
        assert!(md.contains("### tetra") && md.contains("| grid-cgt 16x16 | watertight |"));
        for f in ["speed_accuracy.svg", "speed_accuracy.png", "mismatches.txt"] {
            assert!(std::fs::metadata(dir.join(f)).unwrap().len() > 0, "{f}");
        }
        let svg = std::fs::read_to_string(dir.join("speed_accuracy.svg")).unwrap();
        assert!(svg.contains("Pareto front"));
        // Built with Embree: its reference points in the report and chart.
        if cfg!(embree) {
            assert!(
                md.contains("| tetra | Embree 3 rtcIntersect1 (MEDIUM) |"),
                "{md}"
            );
            assert!(svg.contains("reference (black)"));
        }
        // The Whitted study: every frame identical to its level's SIMD frame.
        let w = BenchArgs {
            whitted: true,
            size: Some((32, 32)),
            packets: vec![4, 16],
            threads: vec![2],
            out_dir: Some(dir.join("whitted")),
            ..a
        };
        bench(&w).unwrap();
        let csv = std::fs::read_to_string(dir.join("whitted/whitted.csv")).unwrap();
        let lines: Vec<&str> = csv.lines().collect();
        let head: Vec<&str> = lines[0].split(',').collect();
        let diff = head.iter().position(|h| *h == "pixels_differing").unwrap();
        assert_eq!(
            lines.len(),
            1 + 4 * (1 + 3 * 2 + 2) + 7,
            "header + 4 levels x 9 configurations + Table 2's 7"
        );
        for l in &lines[1..] {
            assert_eq!(l.split(',').nth(diff), Some("0"), "{l}");
        }
        for f in [
            "whitted.md",
            "figure5.svg",
            "figure5.png",
            "whitted_tetra.png",
        ] {
            assert!(
                std::fs::metadata(dir.join("whitted").join(f))
                    .unwrap()
                    .len()
                    > 0,
                "{f}"
            );
        }
        std::fs::remove_dir_all(&dir).ok();
    }
}
