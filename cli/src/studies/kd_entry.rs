//! `sheaf bench --entry`: section 5 of the AEPSA paper ("Accelerated Entry
//! Point Search Algorithm for Real-Time Ray-Tracing") on our scenes.
//!
//! Per scene (the built-in scenes and the OBJ scenes of `--scenes-dir`),
//! the scene's reference view (`bench::view_for`) at 512x512 with one point
//! light at the eye, as the paper's section 5.1:
//! - Table 1: triangles, leaves, % empty leaves, average leaf depth (and
//!   nodes, references per triangle, build ms: median of `BUILD_REPS`).
//! - Figure 5: the average depth of the entry points MLRTA and AEPSA find
//!   for the primary packets' ray proxy frusta (a search that finds no leaf
//!   counts at the tree's average leaf depth, as the paper does), and
//!   AEPSA's extra depth in per cent.
//! - Search time per packet of both full searches (phase 1 + phase 2) and
//!   Figure 6's phase-2 comparison: MLRTA's phase 1 once per packet, then
//!   MLRTA's phase 2 against AEPSA's (`traverse_aepsa::phase2_with`) on the
//!   same candidates with MLRTA's leaf test, so both return the same entry
//!   point (checked); also AEPSA's phase 2 with its own triangle test.
//!   Nodes visited per search.
//! - Nodes visited from the entry point: split-plane steps (`aabb_tests`,
//!   one per 2x2 quad and node) and triangle tests (per lane) of the kd
//!   packet traversal after the search, per packet, for no search, MLRTA
//!   and AEPSA; every hit is checked against the single-ray kd traversal.
//! - Frames per second of the whole frame (ray generation, traversal,
//!   shadow rays to the light at the eye, shading) on 1 thread and on the
//!   machine's hardware threads, median of `--reps` (default 11, 5 with
//!   `--quick`) runs after an untimed one, in rounds of one frame per
//!   configuration: kd packets without search, with MLRTA, with AEPSA;
//!   the kd 2x2 SIMD ray and single ray; the BVH's Ranged 16x16 packets
//!   without search and with AEPSA. Every frame is compared pixel for
//!   pixel with the kd single-ray frame.
//!
//! Packet sides 8x8 and 16x16 (`--packets` to change); the headline (the
//! summary ratios and the chart) is 16x16, the side of the BVH row.
//!
//! Search and phase times are measured over every packet of the frame in
//! a loop (one frustum per packet built beforehand, so frustum building is
//! not in them), repeated until a sample takes `SAMPLE_NS`, MLRTA and AEPSA
//! samples interleaved, the fastest of `SAMPLES` (the machine may be
//! shared: preemption only adds time; the medians go to the CSV); single
//! thread.
#![forbid(unsafe_code)]

use super::common::{
    FONT, NO_PIXEL, Progress, SceneSpec, Tiling, check_threads, command_line, create_dir,
    load_or_skip, machine_line, median, save_chart, scene_specs, tri_test, view_for, write_csv,
    write_text,
};
use crate::BenchArgs;
use crate::run::{self, ms};
use anyhow::{Context as _, Result, anyhow, bail};
use glam::Vec3;
use sheaf::BuildQuality;
use sheaf::Slot;
use sheaf::accel::entry::{CandidateQueue, EntryResult, LeafGoal, dir_signs, live_mask};
use sheaf::accel::entry::{aepsa as traverse_aepsa, mlrta as traverse_mlrta};
use sheaf::accel::kd::{KdInfo, KdParams, KdView};
use sheaf::geom::frustum::Frustum;
use sheaf::geom::{Hit4, M4, Ray4};
use sheaf::render::{PrimaryRays, Tracer};
use sheaf::trace::{BvhOptions, EntrySearch, RayKind};
use sheaf::{
    BvhParams, Counters, Frame, Hit, Limits, Method, OwnedContext, PointLight, Ray, Shading,
    TraceParams,
};
use std::fmt::Write as _;
use std::hint::black_box;
use std::time::Instant;

/// kd-tree builds per scene; the median is reported.
const BUILD_REPS: usize = 5;
/// Timed samples of each search measurement (the median is reported).
const SAMPLES: usize = 21;
/// A search sample repeats its pass over every packet until it took this long.
const SAMPLE_NS: u64 = 2_000_000;
const QUICK_SAMPLE_NS: u64 = 1_000_000;
/// The packet side of the summary ratios and the chart (when measured).
const HEADLINE: u32 = 16;
/// The BVH rows: Ranged traversal at this side.
const BVH_SIDE: u32 = 16;

const SEARCHES: [EntrySearch; 3] = [EntrySearch::None, EntrySearch::Mlrta, EntrySearch::Aepsa];
/// The kd-trees each scene is studied on (its rows are named
/// `scene-binned` and `scene-exact`): the default binned SAH build and the
/// exact O(N log N) sweep of the paper's section 5.1.
const TREES: [(BuildQuality, &str); 2] =
    [(BuildQuality::Low, "binned"), (BuildQuality::High, "exact")];

/// The primary rays of a frame as n x n packets: `q` quads each, quads in
/// Morton order within a tile (as `render::render_tiles` packs them), tiles
/// row by row (`common::Tiling`).
struct Packets {
    q: usize,
    quads: Vec<Ray4>,
    active: Vec<M4>,
    /// Pixel of lane `4 * quad + lane`, or `NO_PIXEL`.
    pix: Vec<u32>,
}

impl Packets {
    fn new(rays: &PrimaryRays, w: u32, h: u32, side: u32, pad: Ray) -> Packets {
        let t = Tiling::new(w, h, side);
        let row_major: Vec<Ray> = (0..h)
            .flat_map(|y| (0..w).map(move |x| (x, y)))
            .map(|(x, y)| rays.ray(x, y))
            .collect();
        let (quads, active) = t.pack(&row_major, |_| true, pad);
        Packets {
            q: t.q,
            quads,
            active,
            pix: t.pix,
        }
    }
    fn count(&self) -> usize {
        self.quads.len() / self.q
    }
    /// Packet `i`: its quads and active masks.
    fn packet(&self, i: usize) -> (&[Ray4], &[M4]) {
        let r = i * self.q..(i + 1) * self.q;
        (&self.quads[r.clone()], &self.active[r])
    }
}

/// A packet's ray proxy frustum and direction signs, as the kd packets
/// build them (`RayKind::Primary`, the tree's root box).
struct Proxy {
    f: Frustum,
    neg: [bool; 3],
    /// Index of the packet.
    packet: usize,
}

fn proxies(p: &Packets, root: &sheaf::geom::Aabb) -> (Vec<Proxy>, u64) {
    let mut out = Vec::with_capacity(p.count());
    let mut none = 0;
    for i in 0..p.count() {
        let (quads, active) = p.packet(i);
        let live: Vec<M4> = quads
            .iter()
            .zip(active)
            .map(|(r, m)| live_mask(r, *m))
            .collect();
        match Frustum::new(RayKind::Primary, quads, &live, root) {
            Some(f) => out.push(Proxy {
                f,
                neg: dir_signs(quads, &live),
                packet: i,
            }),
            None => none += 1,
        }
    }
    (out, none)
}

/// One search's results summed over the packets.
#[derive(Clone, Copy, Debug, Default)]
struct SearchStats {
    /// Entry depths, misses at the tree's (unrounded) average leaf depth.
    depth_sum: f64,
    /// Entry depths of the searches that found an entry point.
    found_depth_sum: u64,
    found: u64,
    misses: u64,
    phase1_nodes: u64,
    phase2_nodes: u64,
    candidates: u64,
    tested: u64,
}

impl SearchStats {
    fn add(&mut self, r: &EntryResult, miss_depth: f64) {
        match &r.entry {
            Some(e) => {
                self.depth_sum += e.depth as f64;
                self.found_depth_sum += e.depth as u64;
                self.found += 1;
            }
            None => {
                self.depth_sum += miss_depth;
                self.misses += 1;
            }
        }
        self.phase1_nodes += r.phase1_nodes as u64;
        self.phase2_nodes += r.phase2_nodes as u64;
        self.candidates += r.candidates as u64;
        self.tested += r.tested as u64;
    }
    fn searches(&self) -> u64 {
        self.found + self.misses
    }
    fn avg_depth(&self) -> f64 {
        ratio_f(self.depth_sum, self.searches() as f64)
    }
    fn avg_found_depth(&self) -> f64 {
        ratio_f(self.found_depth_sum as f64, self.found as f64)
    }
    fn nodes(&self) -> u64 {
        self.phase1_nodes + self.phase2_nodes
    }
}

/// The kd packet traversal of every primary packet with one search.
#[derive(Clone, Copy, Debug, Default)]
struct Traversal {
    ctr: Counters,
    /// Single thread, primary rays only, median of `reps`.
    ns: u64,
    /// Lanes whose hit (triangle or t) differs from the kd single ray's.
    diff: u64,
}

/// Everything measured on one scene at one packet side.
#[derive(Clone, Debug, Default)]
struct EntryRow {
    scene: String,
    obj: bool,
    side: u32,
    packets: u64,
    /// Packets without a frustum (no valid lane): never searched.
    no_frustum: u64,
    miss_depth: f64,
    m: SearchStats,
    a: SearchStats,
    /// Packets whose AEPSA entry point is deeper / as deep / shallower
    /// (misses at the average leaf depth).
    deeper: u64,
    same: u64,
    shallower: u64,
    /// Full searches and phase 1 alone, ns per packet.
    m_search_ns: f64,
    a_search_ns: f64,
    m_phase1_ns: f64,
    a_phase1_ns: f64,
    /// Figure 6, on MLRTA's phase-1 candidates of the packets with a leaf.
    fig6_packets: u64,
    m_p2_ns: f64,
    a_p2_ns: f64,
    a_p2_tri_ns: f64,
    m_p2_nodes: u64,
    a_p2_nodes: u64,
    a_p2_tri_nodes: u64,
    m_p2_tested: u64,
    a_p2_tested: u64,
    /// Packets where `phase2_with(.., Occupied)` returned another entry
    /// point than MLRTA's phase 2 (must be 0).
    fig6_entry_diff: u64,
    /// Median samples of the MLRTA and AEPSA full searches and of
    /// Figure 6's two phase 2s (the fields above are the fastest).
    medians: [f64; 4],
    /// Per `SEARCHES`.
    trav: [Traversal; 3],
    /// Per packet (None: no frustum): the MLRTA and AEPSA entry depths
    /// (None: a miss), for the nesting check.
    depths: Vec<Option<[Option<u32>; 2]>>,
}

/// The nesting check of one scene: a small packet's frustum lies inside
/// the frustum of the large packet containing it, so the common ancestor
/// of the leaves it reaches should lie at or below the large packet's
/// entry point. Counts of small packets whose entry point is shallower
/// than their large packet's (or found where the large packet misses).
#[derive(Clone, Debug)]
struct Nesting {
    scene: String,
    small: u32,
    large: u32,
    /// Small packets compared (both have frusta).
    compared: u64,
    /// MLRTA and AEPSA.
    shallower: [u64; 2],
    /// Sum over those packets of (large depth - small depth).
    levels: [u64; 2],
}

fn nesting(small: &EntryRow, large: &EntryRow, w: u32) -> Nesting {
    let (s, l) = (small.side, large.side);
    let (sx, lx) = (w.div_ceil(s) as usize, w.div_ceil(l) as usize);
    let k = (l / s) as usize;
    let mut n = Nesting {
        scene: small.scene.clone(),
        small: s,
        large: l,
        compared: 0,
        shallower: [0; 2],
        levels: [0; 2],
    };
    for (i, d) in small.depths.iter().enumerate() {
        let (tx, ty) = (i % sx, i / sx);
        let parent = (ty / k) * lx + tx / k;
        let (Some(d), Some(Some(pd))) = (d, large.depths.get(parent)) else {
            continue;
        };
        n.compared += 1;
        for a in 0..2 {
            match (d[a], pd[a]) {
                (Some(c), Some(p)) if c < p => {
                    n.shallower[a] += 1;
                    n.levels[a] += (p - c) as u64;
                }
                (Some(_), None) => n.shallower[a] += 1,
                _ => {}
            }
        }
    }
    n
}

impl EntryRow {
    fn extra_depth_pct(&self) -> f64 {
        let (m, a) = (self.m.avg_depth(), self.a.avg_depth());
        if m > 0.0 { (a - m) / m * 100.0 } else { 0.0 }
    }
    fn search_speedup(&self) -> f64 {
        ratio_f(self.m_search_ns, self.a_search_ns)
    }
    fn phase2_speedup(&self) -> f64 {
        ratio_f(self.m_p2_ns, self.a_p2_ns)
    }
    /// Traversal steps + triangle tests per packet after the search.
    fn visited(&self, s: usize) -> f64 {
        let c = &self.trav[s].ctr;
        ratio_f((c.aabb_tests + c.tri_tests) as f64, self.packets as f64)
    }
}

/// One end-to-end configuration.
#[derive(Clone, Copy, Debug)]
struct FpsConfig {
    method: Method,
    side: u32,
    entry: EntrySearch,
}

impl FpsConfig {
    fn label(&self) -> String {
        match self.method {
            Method::KdSingle | Method::KdSimd => self.method.name().to_string(),
            _ => format!(
                "{} {}x{} {}",
                self.method.name(),
                self.side,
                self.side,
                self.entry.name()
            ),
        }
    }
    fn params(&self) -> TraceParams {
        TraceParams {
            method: self.method,
            packet: self.side.max(2),
            bvh: BvhOptions {
                culling: true,
                kind: RayKind::Auto,
            },
            entry: self.entry,
            ..TraceParams::default()
        }
    }
}

/// One frame rate measured.
#[derive(Clone, Debug)]
struct FpsRow {
    scene: String,
    obj: bool,
    cfg: FpsConfig,
    threads: u32,
    /// Median and fastest of the timed runs.
    ns: u64,
    min_ns: u64,
    /// Every timed run, by round (the configurations of a round ran one
    /// after the other).
    samples: Vec<u64>,
    /// Counters of the untimed run (all threads).
    ctr: Counters,
    /// Pixels differing from the kd single-ray frame.
    diff: usize,
}

impl FpsRow {
    fn fps(&self) -> f64 {
        ratio_f(1e9, self.ns as f64)
    }
    fn fps_best(&self) -> f64 {
        ratio_f(1e9, self.min_ns as f64)
    }
}

struct Table1Row {
    scene: String,
    info: KdInfo,
    build_ns: u64,
    bvh_build_ns: u64,
    view: String,
}

fn ratio_f(a: f64, b: f64) -> f64 {
    if b == 0.0 { 0.0 } else { a / b }
}

/// ns per work item of each pass in `passes` (each does `n` items):
/// calibrated so a sample takes about `sample_ns`, samples of the passes
/// interleaved; the fastest and the median of `SAMPLES`.
fn time_passes(n: usize, sample_ns: u64, passes: &mut [&mut dyn FnMut()]) -> Vec<Timed> {
    if n == 0 {
        return vec![Timed::default(); passes.len()];
    }
    let reps: Vec<u64> = passes
        .iter_mut()
        .map(|f| {
            let t = Instant::now();
            f();
            let ns = (t.elapsed().as_nanos() as u64).max(1);
            sample_ns.div_ceil(ns).max(1)
        })
        .collect();
    let mut samples = vec![Vec::with_capacity(SAMPLES); passes.len()];
    for _ in 0..SAMPLES {
        for (k, f) in passes.iter_mut().enumerate() {
            let t = Instant::now();
            for _ in 0..reps[k] {
                f();
            }
            samples[k].push(t.elapsed().as_nanos() as u64);
        }
    }
    samples
        .into_iter()
        .zip(&reps)
        .map(|(s, &r)| {
            let per = r as f64 * n as f64;
            Timed {
                best: s.iter().copied().min().unwrap_or(0) as f64 / per,
                median: median(s) as f64 / per,
            }
        })
        .collect()
}

/// A search time, ns per packet: the fastest sample and the median.
#[derive(Clone, Copy, Debug, Default)]
struct Timed {
    best: f64,
    median: f64,
}

/// The entry-point measurements of one packet side (Figure 5, search
/// times, Figure 6), over the frusta of `pk`.
fn searches(row: &mut EntryRow, kv: &KdView<'_>, px: &[Proxy], sample_ns: u64) {
    let miss_depth = kv.info.avg_leaf_depth as f64;
    row.miss_depth = miss_depth;
    row.depths = vec![None; row.packets as usize];
    for p in px {
        let m = traverse_mlrta::search(kv, &p.f, p.neg);
        let a = traverse_aepsa::search(kv, &p.f, p.neg);
        row.m.add(&m, miss_depth);
        row.a.add(&a, miss_depth);
        row.depths[p.packet] = Some([m, a].map(|r| r.entry.map(|e| e.depth)));
        let depth = |r: &EntryResult| r.entry.map_or(miss_depth, |e| e.depth as f64);
        let (dm, da) = (depth(&m), depth(&a));
        if da > dm {
            row.deeper += 1;
        } else if da < dm {
            row.shallower += 1;
        } else {
            row.same += 1;
        }
    }
    // Full searches and phase 1.
    let n = px.len();
    let t = time_passes(
        n,
        sample_ns,
        &mut [
            &mut || {
                for p in px {
                    black_box(traverse_mlrta::search(black_box(kv), &p.f, p.neg));
                }
            },
            &mut || {
                for p in px {
                    black_box(traverse_aepsa::search(black_box(kv), &p.f, p.neg));
                }
            },
            &mut || {
                for p in px {
                    black_box(traverse_mlrta::phase1(black_box(kv), &p.f, p.neg));
                }
            },
            &mut || {
                for p in px {
                    black_box(traverse_aepsa::phase1(black_box(kv), &p.f, p.neg));
                }
            },
        ],
    );
    (
        row.m_search_ns,
        row.a_search_ns,
        row.m_phase1_ns,
        row.a_phase1_ns,
    ) = (t[0].best, t[1].best, t[2].best, t[3].best);
    row.medians[..2].copy_from_slice(&[t[0].median, t[1].median]);
    // Figure 6: MLRTA's phase 1 once, then both phase 2s on its candidates.
    let fig: Vec<(&Proxy, CandidateQueue)> = px
        .iter()
        .map(|p| (p, traverse_mlrta::phase1(kv, &p.f, p.neg)))
        .filter(|(_, q)| !q.is_empty())
        .collect();
    row.fig6_packets = fig.len() as u64;
    for (p, q) in &fig {
        let (Some(m), Some(a), Some(at)) = (
            traverse_mlrta::phase2(kv, &p.f, p.neg, q),
            traverse_aepsa::phase2_with(kv, &p.f, p.neg, q, LeafGoal::Occupied),
            traverse_aepsa::phase2_with(kv, &p.f, p.neg, q, LeafGoal::Overlapped),
        ) else {
            continue;
        };
        row.m_p2_nodes += m.visited as u64;
        row.a_p2_nodes += a.visited as u64;
        row.a_p2_tri_nodes += at.visited as u64;
        row.m_p2_tested += m.tested as u64;
        row.a_p2_tested += a.tested as u64;
        row.fig6_entry_diff += (m.entry.node != a.entry.node) as u64;
    }
    let t = time_passes(
        fig.len(),
        sample_ns,
        &mut [
            &mut || {
                for (p, q) in &fig {
                    black_box(traverse_mlrta::phase2(black_box(kv), &p.f, p.neg, q));
                }
            },
            &mut || {
                for (p, q) in &fig {
                    black_box(traverse_aepsa::phase2_with(
                        black_box(kv),
                        &p.f,
                        p.neg,
                        q,
                        LeafGoal::Occupied,
                    ));
                }
            },
            &mut || {
                for (p, q) in &fig {
                    black_box(traverse_aepsa::phase2_with(
                        black_box(kv),
                        &p.f,
                        p.neg,
                        q,
                        LeafGoal::Overlapped,
                    ));
                }
            },
        ],
    );
    (row.m_p2_ns, row.a_p2_ns, row.a_p2_tri_ns) = (t[0].best, t[1].best, t[2].best);
    row.medians[2..].copy_from_slice(&[t[0].median, t[1].median]);
}

pub fn run(a: &BenchArgs) -> Result<()> {
    let start = Instant::now();
    let (w, h) = a
        .size
        .unwrap_or(if a.quick { (256, 256) } else { (512, 512) });
    let hw = std::thread::available_parallelism().map_or(1, |n| n.get() as u32);
    let mut threads = if a.threads.is_empty() {
        vec![1, hw]
    } else {
        a.threads.clone()
    };
    threads.sort_unstable();
    threads.dedup();
    check_threads(&threads)?;
    let max_threads = *threads.last().unwrap_or(&1);
    let reps = a.reps.unwrap_or(if a.quick { 5 } else { 11 }).max(1);
    let sample_ns = if a.quick { QUICK_SAMPLE_NS } else { SAMPLE_NS };
    let mut sides: Vec<u32> = if a.packets.is_empty() {
        vec![8, 16]
    } else {
        a.packets.clone()
    };
    sides.sort_unstable();
    sides.dedup();
    for &n in &sides {
        if !matches!(n, 4 | 8 | 16 | 32) {
            bail!("--packets {n}: must be 4, 8, 16 or 32");
        }
    }
    let headline = if sides.contains(&HEADLINE) {
        HEADLINE
    } else {
        *sides.last().unwrap_or(&8)
    };
    let test = tri_test(a);
    let specs: Vec<SceneSpec> = if a.quick && a.scenes.is_empty() {
        sheaf::scenes::BUILTIN_NAMES
            .iter()
            .map(|n| SceneSpec {
                name: n.to_string(),
                load: format!("builtin:{n}"),
            })
            .collect()
    } else {
        scene_specs(a)?
    };
    let specs: Vec<(SceneSpec, BuildQuality)> = specs
        .iter()
        .flat_map(|s| {
            TREES.map(|(q, tag)| {
                let name = format!("{}-{tag}", s.name);
                (
                    SceneSpec {
                        name,
                        load: s.load.clone(),
                    },
                    q,
                )
            })
        })
        .collect();
    let out_dir = a.out_dir();
    create_dir(&out_dir)?;
    let machine = machine_line();
    let mut fps_cfgs = vec![
        FpsConfig {
            method: Method::KdSingle,
            side: 0,
            entry: EntrySearch::None,
        },
        FpsConfig {
            method: Method::KdSimd,
            side: 2,
            entry: EntrySearch::None,
        },
    ];
    for &n in &sides {
        for e in SEARCHES {
            fps_cfgs.push(FpsConfig {
                method: Method::KdPacket,
                side: n,
                entry: e,
            });
        }
    }
    for e in [EntrySearch::None, EntrySearch::Aepsa] {
        fps_cfgs.push(FpsConfig {
            method: Method::BvhRanged,
            side: BVH_SIDE,
            entry: e,
        });
    }
    // Steps per scene: the searches of each packet side, the frames of each thread count.
    let per_scene = (sides.len() + threads.len()) as u64;
    let prog = Progress::new("sheaf bench --entry", specs.len() as u64 * per_scene);
    prog.say(format_args!(
        "sheaf bench --entry: {} scenes, {w}x{h}, packets {:?} (headline {headline}x{headline}), threads {threads:?}, {} frame configurations, median of {reps} frames, {test:?}, machine: {machine}",
        specs.len(),
        sides,
        fps_cfgs.len()
    ));

    let mut table1: Vec<Table1Row> = Vec::new();
    let mut rows: Vec<EntryRow> = Vec::new();
    let mut nests: Vec<Nesting> = Vec::new();
    let mut fps: Vec<FpsRow> = Vec::new();
    for (spec, quality) in &specs {
        prog.doing(spec.name.clone());
        let obj = !spec.load.starts_with("builtin:");
        let Some(loaded) = load_or_skip(spec, &prog) else {
            prog.inc(per_scene);
            continue;
        };
        let scene = loaded.scene()?;
        let mut limits: Limits = run::limits(&scene, (w, h), max_threads);
        limits.structures = Limits::KD | Limits::BVH;
        limits.projection_test = test == sheaf::TriTest::Projection;
        let kp = KdParams {
            test,
            quality: *quality,
            ..KdParams::default()
        };
        // kd pools large enough that no leaf is forced (gears needs more
        // references than the default rule gives).
        let (limits, probe) = run::kd_limits(&scene, limits, &kp)?;
        if limits.max_kd_refs != 0 {
            prog.say(format_args!(
                "[{}] kd pools grown to {} nodes, {} references so the build forces no leaf{}",
                spec.name,
                limits.kd_nodes(),
                limits.kd_refs(),
                if probe.forced_leaves > 0 {
                    format!(" (still {} forced: event scratch)", probe.forced_leaves)
                } else {
                    String::new()
                }
            ));
        }
        let mut ctx = OwnedContext::new(&limits).context("creating the context")?;

        // Table 1.
        let mut builds = Vec::new();
        let mut info = KdInfo::default();
        for _ in 0..BUILD_REPS {
            info = ctx
                .build_kd(&scene, &kp)
                .with_context(|| format!("{}: building the kd-tree", spec.name))?;
            builds.push(ctx.stats().kd_build_ns);
        }
        if info.triangles == 0 {
            prog.say(format_args!(
                "note: {}: every triangle is degenerate or non-finite, skipped",
                spec.name
            ));
            prog.inc(per_scene);
            continue;
        }
        let build_ns = median(builds);
        ctx.build_bvh(
            &scene,
            &BvhParams {
                test,
                ..BvhParams::default()
            },
        )
        .with_context(|| format!("{}: building the BVH", spec.name))?;
        let bvh_build_ns = ctx.stats().bvh_build_ns;
        let (v, _, how) = view_for(&loaded, &ctx.tracer()?, &info.bounds, w, h);
        prog.say(format_args!(
            "[{}] kd-tree {} (median of {BUILD_REPS}); BVH build {:.1} ms; view {how}",
            spec.name,
            crate::cmd::kd_line(&info, build_ns),
            ms(bvh_build_ns)
        ));
        table1.push(Table1Row {
            scene: spec.name.clone(),
            info,
            build_ns,
            bvh_build_ns,
            view: how,
        });
        let cam = crate::view::camera(&v);
        let frame = Frame {
            camera: cam,
            // The paper's setup: one light at the eye point.
            light: PointLight {
                position: cam.eye,
                color: [1.0; 3],
                ..Default::default()
            },
            shading: Shading {
                shadows: true,
                ..Shading::default()
            },
            width: w,
            height: h,
        };
        let prim = PrimaryRays::new(&cam, w, h)?;
        let pad = Ray::new(v.eye, Vec3::X, 0.0, 0.0);

        // Entry points, search times, traversal from the entry point.
        {
            let (tr, mut mbs) = ctx.parts()?;
            let mut slot = mbs.next().ok_or_else(|| anyhow!("no thread slot"))?;
            let kt = tr.kd().ok_or_else(|| anyhow!("kd-tree not built"))?;
            let kv = kt;
            // Reference: the kd single ray per pixel.
            let mut c0 = Counters::default();
            let reference: Vec<Hit> = (0..h)
                .flat_map(|y| (0..w).map(move |x| (x, y)))
                .map(|(x, y)| kt.intersect(&prim.ray(x, y), &mut c0))
                .collect();
            for &side in &sides {
                let pk = Packets::new(&prim, w, h, side, pad);
                let (px, no_frustum) = proxies(&pk, &info.root);
                let mut row = EntryRow {
                    scene: spec.name.clone(),
                    obj,
                    side,
                    packets: pk.count() as u64,
                    no_frustum,
                    ..EntryRow::default()
                };
                searches(&mut row, &kv, &px, sample_ns);
                prog.say(format_args!(
                    "[{}] {side}x{side}: {} packets; entry depth MLRTA {:.2} AEPSA {:.2} ({:+.2} %), misses {} / {}; search {:.0} / {:.0} ns per packet ({:.2}x), nodes {:.1} / {:.1}; Figure 6 phase 2 {:.0} / {:.0} ns ({:.2}x), nodes {:.1} / {:.1}",
                    spec.name,
                    row.packets,
                    row.m.avg_depth(),
                    row.a.avg_depth(),
                    row.extra_depth_pct(),
                    row.m.misses,
                    row.a.misses,
                    row.m_search_ns,
                    row.a_search_ns,
                    row.search_speedup(),
                    ratio_f(row.m.nodes() as f64, row.m.searches() as f64),
                    ratio_f(row.a.nodes() as f64, row.a.searches() as f64),
                    row.m_p2_ns,
                    row.a_p2_ns,
                    row.phase2_speedup(),
                    ratio_f(row.m_p2_nodes as f64, row.fig6_packets as f64),
                    ratio_f(row.a_p2_nodes as f64, row.fig6_packets as f64),
                ));
                if row.fig6_entry_diff > 0 {
                    prog.say(format_args!(
                        "[{}] WARNING: Figure 6: AEPSA's phase 2 with MLRTA's leaf test returned another entry point than MLRTA's on {} packets",
                        spec.name, row.fig6_entry_diff
                    ));
                }
                // Each search's packets once untimed (counters, hits
                // checked), then `reps` rounds timing each in turn.
                let mut hits = vec![Hit4::MISS; pk.quads.len()];
                let ps = SEARCHES.map(|e| {
                    TraceParams {
                        method: Method::KdPacket,
                        packet: side,
                        entry: e,
                        ..TraceParams::default()
                    }
                    .with_kind(RayKind::Primary)
                });
                let pass = |p: &TraceParams,
                            slot: &mut Slot<'_>,
                            ctr: &mut Counters,
                            hits: &mut [Hit4]| {
                    let traced = kt.packets(p, false);
                    for i in 0..pk.count() {
                        let (r, m) = pk.packet(i);
                        let hq = &mut hits[i * pk.q..(i + 1) * pk.q];
                        hq.fill(Hit4::MISS);
                        traced.run(p, r, m, hq, slot, ctr);
                    }
                };
                for (k, p) in ps.iter().enumerate() {
                    let mut ctr = Counters::default();
                    pass(p, &mut slot, &mut ctr, &mut hits);
                    let diff = pk
                        .pix
                        .iter()
                        .enumerate()
                        .filter(|&(_, &px)| px != NO_PIXEL)
                        .filter(|&(l, &px)| {
                            let (got, want) = (hits[l / 4].lane(l % 4), reference[px as usize]);
                            got.prim != want.prim || got.t.to_bits() != want.t.to_bits()
                        })
                        .count() as u64;
                    row.trav[k] = Traversal { ctr, ns: 0, diff };
                }
                let mut times = [(); 3].map(|_| Vec::with_capacity(reps as usize));
                let mut scratch = Counters::default();
                for _ in 0..reps {
                    for (k, p) in ps.iter().enumerate() {
                        let t0 = Instant::now();
                        pass(p, &mut slot, &mut scratch, &mut hits);
                        times[k].push(t0.elapsed().as_nanos() as u64);
                    }
                }
                for (k, ts) in times.into_iter().enumerate() {
                    let tr = &mut row.trav[k];
                    tr.ns = median(ts);
                    let ctr = tr.ctr;
                    prog.say(format_args!(
                        "[{}] {side}x{side} kd-packet {:<5}: {:>7.1} node steps + {:>7.1} triangle tests per packet after the search, {} searches, primary rays {:.2} ms (1 thread){}",
                        spec.name,
                        SEARCHES[k].name(),
                        ratio_f(ctr.aabb_tests as f64, row.packets as f64),
                        ratio_f(ctr.tri_tests as f64, row.packets as f64),
                        ctr.entry_searches,
                        ms(tr.ns),
                        if tr.diff > 0 {
                            format!("  DIFFERS FROM kd-single on {} rays", tr.diff)
                        } else {
                            String::new()
                        }
                    ));
                }
                rows.push(row);
                prog.step();
            }
        }
        {
            let here: Vec<&EntryRow> = rows.iter().filter(|r| r.scene == spec.name).collect();
            for sm in &here {
                for lg in here
                    .iter()
                    .filter(|l| l.side > sm.side && l.side % sm.side == 0)
                {
                    let n = nesting(sm, lg, w);
                    prog.say(format_args!(
                        "[{}] nesting check: of {} {}x{} packets, {} (MLRTA) and {} (AEPSA) get an entry point shallower than the {}x{} packet containing them",
                        spec.name,
                        n.compared,
                        n.small,
                        n.small,
                        n.shallower[0],
                        n.shallower[1],
                        n.large,
                        n.large
                    ));
                    nests.push(n);
                }
            }
        }

        // Frames per second.
        // Per thread count: an untimed frame of every configuration
        // (counters, image check), then `reps` rounds timing one frame of
        // each configuration in turn, so a busy spell of the machine falls
        // on every configuration alike.
        let mut pixels = vec![0u8; w as usize * h as usize * 4];
        let mut base: Vec<u8> = Vec::new();
        let params: Vec<(TraceParams, TraceParams)> = fps_cfgs
            .iter()
            .map(|c| {
                let p = c.params();
                (p.with_kind(RayKind::Primary), p.with_kind(RayKind::Shadow))
            })
            .collect();
        for &t in &threads {
            let mut first = Vec::new();
            for (pp, ps) in &params {
                let ctr = run::render_frame(&mut ctx, pp, ps, &frame, &mut pixels, t)?;
                if base.is_empty() {
                    base = pixels.clone();
                }
                let diff = pixels
                    .chunks_exact(4)
                    .zip(base.chunks_exact(4))
                    .filter(|(x, y)| x != y)
                    .count();
                first.push((ctr, diff));
            }
            prog.say(format_args!(
                "[{}] frames on {t} thread(s): {} configurations once untimed, then {reps} timed rounds of one frame each",
                spec.name,
                params.len()
            ));
            let mut times = vec![Vec::with_capacity(reps as usize); params.len()];
            for _ in 0..reps {
                for (k, (pp, ps)) in params.iter().enumerate() {
                    let t0 = Instant::now();
                    run::render_frame(&mut ctx, pp, ps, &frame, &mut pixels, t)?;
                    times[k].push(t0.elapsed().as_nanos() as u64);
                }
            }
            for ((cfg, (ctr, diff)), ts) in fps_cfgs.iter().zip(first).zip(times) {
                let r = FpsRow {
                    scene: spec.name.clone(),
                    obj,
                    cfg: *cfg,
                    threads: t,
                    min_ns: ts.iter().copied().min().unwrap_or(0),
                    ns: median(ts.clone()),
                    samples: ts,
                    ctr,
                    diff,
                };
                prog.say(format_args!(
                    "[{}] frame {:<26} {t} thread(s): {:>8.2} ms = {:>7.2} fps (fastest run {:.2} ms){}",
                    spec.name,
                    cfg.label(),
                    ms(r.ns),
                    r.fps(),
                    ms(r.min_ns),
                    if diff > 0 {
                        format!("  IMAGE DIFFERS from kd-single: {diff} pixels")
                    } else {
                        String::new()
                    }
                ));
                fps.push(r);
            }
            prog.step();
        }
        {
            // One frame to look at (AEPSA, headline side).
            let cfg = FpsConfig {
                method: Method::KdPacket,
                side: headline,
                entry: EntrySearch::Aepsa,
            };
            let p = cfg.params();
            run::render_frame(
                &mut ctx,
                &p.with_kind(RayKind::Primary),
                &p.with_kind(RayKind::Shadow),
                &frame,
                &mut pixels,
                max_threads,
            )?;
            run::write_png(
                &out_dir.join(format!("entry_{}.png", spec.name)),
                &pixels,
                w,
                h,
            )?;
        }
    }

    let secs = start.elapsed().as_secs_f64();
    let s = Summary::new(&rows, &fps, headline, max_threads);
    let md = markdown(
        &table1,
        &rows,
        &nests,
        &fps,
        &s,
        &Setup {
            w,
            h,
            threads: &threads,
            reps,
            sides: &sides,
            headline,
            test,
            machine: &machine,
            secs,
            sample_ns,
        },
    );
    let md_path = out_dir.join("entry.md");
    write_text(&md_path, &md)?;
    let paths = [
        out_dir.join("entry_table1.csv"),
        out_dir.join("entry_search.csv"),
        out_dir.join("entry_fps.csv"),
    ];
    for (p, (head, records)) in
        paths
            .iter()
            .zip([csv_table1(&table1), csv_search(&rows), csv_fps(&fps)])
    {
        write_csv(p, &head, records)?;
    }
    let (svg, png) = (out_dir.join("entry.svg"), out_dir.join("entry.png"));
    figure::write(&rows, &fps, headline, max_threads, &svg, &png)?;
    prog.say(format_args!("\n{md}"));
    let bad_rays: u64 = rows
        .iter()
        .flat_map(|r| r.trav.iter())
        .map(|t| t.diff)
        .sum();
    let bad_px: usize = fps
        .iter()
        .filter(|r| r.cfg.method != Method::BvhRanged)
        .map(|r| r.diff)
        .sum();
    if bad_rays > 0 || bad_px > 0 {
        prog.say(format_args!(
            "warning: kd packets differ from the kd single ray ({bad_rays} rays, {bad_px} pixels of frames): see the diff columns"
        ));
    }
    prog.say(format_args!(
        "wrote {}, {}, {}, {}, {}, {}",
        md_path.display(),
        paths[0].display(),
        paths[1].display(),
        paths[2].display(),
        svg.display(),
        png.display()
    ));
    Ok(())
}

// ---------------------------------------------------------------------------
// Summary ratios

/// Per scene, at the headline side: the ratios the study is judged by.
struct SceneRatios {
    scene: String,
    obj: bool,
    search: f64,
    phase2: f64,
    /// The same from the median samples.
    search_med: f64,
    phase2_med: f64,
    extra_depth: f64,
    /// fps ratios on 1 thread and on `max_threads`: AEPSA / plain,
    /// MLRTA / plain, AEPSA / MLRTA, BVH AEPSA / BVH plain.
    a_plain: [f64; 2],
    m_plain: [f64; 2],
    a_m: [f64; 2],
    bvh: [f64; 2],
    /// AEPSA / plain from the fastest runs, and from the medians.
    a_plain_best: [f64; 2],
    a_plain_med: [f64; 2],
}

/// The median over rounds of `num[r] / den[r]`.
fn paired_ratio(num: &[u64], den: &[u64]) -> f64 {
    let mut v: Vec<f64> = num
        .iter()
        .zip(den)
        .map(|(&n, &d)| ratio_f(n as f64, d as f64))
        .collect();
    v.sort_by(f64::total_cmp);
    v.get(v.len() / 2).copied().unwrap_or(0.0)
}

struct Summary {
    scenes: Vec<SceneRatios>,
}

fn mean(v: impl Iterator<Item = f64>) -> f64 {
    let (mut s, mut n) = (0.0, 0);
    for x in v {
        s += x;
        n += 1;
    }
    if n == 0 { 0.0 } else { s / n as f64 }
}

fn min_of(v: impl Iterator<Item = f64>) -> f64 {
    v.fold(f64::INFINITY, f64::min)
}

impl Summary {
    fn new(rows: &[EntryRow], fps: &[FpsRow], headline: u32, max_threads: u32) -> Summary {
        let mut scenes = Vec::new();
        for r in rows.iter().filter(|r| r.side == headline) {
            let find = |m: Method, side: u32, e: EntrySearch, t: u32| {
                fps.iter().find(|x| {
                    x.scene == r.scene
                        && x.cfg.method == m
                        && x.cfg.side == side
                        && x.cfg.entry == e
                        && x.threads == t
                })
            };
            let f = |m, side, e, t| find(m, side, e, t).map_or(0.0, |x| x.fps());
            let fb = |m, side, e, t| find(m, side, e, t).map_or(0.0, |x| x.fps_best());
            let ts = [1, max_threads];
            // fps of `x` over `y`: the median over rounds of y's frame time
            // over x's in the same round.
            let paired = |m: Method, side: u32, x: EntrySearch, y: EntrySearch| {
                ts.map(|t| match (find(m, side, x, t), find(m, side, y, t)) {
                    (Some(x), Some(y)) => paired_ratio(&y.samples, &x.samples),
                    _ => 0.0,
                })
            };
            let kp = |x, y| paired(Method::KdPacket, headline, x, y);
            let (none, mlrta, aepsa) = (EntrySearch::None, EntrySearch::Mlrta, EntrySearch::Aepsa);
            let div = |x: [f64; 2], y: [f64; 2]| [ratio_f(x[0], y[0]), ratio_f(x[1], y[1])];
            let med = |e| ts.map(|t| f(Method::KdPacket, headline, e, t));
            let best = |e| ts.map(|t| fb(Method::KdPacket, headline, e, t));
            let a_plain_best = div(best(EntrySearch::Aepsa), best(EntrySearch::None));
            scenes.push(SceneRatios {
                scene: r.scene.clone(),
                obj: r.obj,
                search: r.search_speedup(),
                phase2: r.phase2_speedup(),
                search_med: ratio_f(r.medians[0], r.medians[1]),
                phase2_med: ratio_f(r.medians[2], r.medians[3]),
                extra_depth: r.extra_depth_pct(),
                a_plain: kp(aepsa, none),
                m_plain: kp(mlrta, none),
                a_m: kp(aepsa, mlrta),
                bvh: paired(Method::BvhRanged, BVH_SIDE, aepsa, none),
                a_plain_best,
                a_plain_med: div(med(aepsa), med(none)),
            });
        }
        Summary { scenes }
    }
}

// ---------------------------------------------------------------------------
// Outputs

struct Setup<'a> {
    w: u32,
    h: u32,
    threads: &'a [u32],
    reps: u32,
    sides: &'a [u32],
    headline: u32,
    test: sheaf::TriTest,
    machine: &'a str,
    secs: f64,
    sample_ns: u64,
}

fn pct(a: u64, b: u64) -> f64 {
    ratio_f(100.0 * a as f64, b as f64)
}

fn markdown(
    t1: &[Table1Row],
    rows: &[EntryRow],
    nests: &[Nesting],
    fps: &[FpsRow],
    s: &Summary,
    st: &Setup<'_>,
) -> String {
    let (w, h, hl) = (st.w, st.h, st.headline);
    let tmax = *st.threads.last().unwrap_or(&1);
    let mut o = String::from(
        "# sheaf bench --entry: kd-tree entry-point search, MLRTA vs AEPSA (AEPSA paper, section 5)\n\n",
    );
    let _ = writeln!(o, "- command: `{}`", command_line());
    let _ = writeln!(o, "- machine (at the start): {}", st.machine);
    let _ = writeln!(o, "- machine (at the end): {}", machine_line());
    let _ = writeln!(
        o,
        "- setup (paper section 5.1): {w}x{h} primary rays of each scene's reference view (built-in scenes: view 0; OBJ scenes: the view `sheaf render` picks), \
         one point light at the eye; frames are rendered **with shadow rays** (one per lit primary hit, traced from the light, which sits at the eye) and Lambert shading"
    );
    let _ = writeln!(
        o,
        "- kd-trees: each scene twice, `-binned` the default `KdParams` (binned SAH, 32 bins, boxes clipped at splits, `BuildQuality::Low`, on one thread) and `-exact` `BuildQuality::High` (the O(N log N) sweep of section 5.1); both SAH with traversal cost 2, empty-space bonus 0.2, depth limit 8 + 1.3 log2 N; triangle test {:?}; build = median of {BUILD_REPS}",
        st.test
    );
    let _ = writeln!(
        o,
        "- packets: {} (n x n rays, one ray proxy frustum each: the corner-ray frustum of the primary packet); **headline: {hl}x{hl}** (the summary and the chart), the side of the BVH rows (bvh-ranged {BVH_SIDE}x{BVH_SIDE})",
        st.sides
            .iter()
            .map(|n| format!("{n}x{n}"))
            .collect::<Vec<_>>()
            .join(", ")
    );
    let _ = writeln!(
        o,
        "- entry-point statistics, search times and nodes visited are over the **primary** packets of the frame; a search that finds no leaf (a miss: every ray of the packet misses) counts at the tree's average leaf depth, as the paper does"
    );
    let _ = writeln!(
        o,
        "- search times: one pass over every packet's frustum (built beforehand), repeated to {:.0} ms per sample, MLRTA and AEPSA samples interleaved, the **fastest** of {SAMPLES} samples (the machine is shared: preemption only adds time; medians in entry_search.csv), 1 thread; Figure 6: MLRTA's phase 1 once per packet, then MLRTA's phase 2 vs AEPSA's phase 2 (`phase2_with`) on the same candidates with MLRTA's leaf test (same entry point, checked), and AEPSA's phase 2 with its own triangle test as a further column",
        st.sample_ns as f64 * 1e-6
    );
    let _ = writeln!(
        o,
        "- frames per second: the whole frame (ray generation, traversal, shadow rays, shading), median of {} runs after an untimed one (rounds of one frame per configuration, so load spells hit all alike), on threads {:?}; every frame is compared pixel for pixel with the kd single-ray frame (`diff`)",
        st.reps, st.threads
    );
    let _ = writeln!(o, "- total time: {:.0} s\n", st.secs);

    // Summary first.
    o.push_str("## Summary (headline packets)\n\n");
    o.push_str("Search speedups: MLRTA time / AEPSA time (fastest samples). fps ratios: the median over the timed rounds of the two configurations' frame-time ratio within a round (paired, so load spells on the shared machine cancel).\n\n");
    let _ = writeln!(
        o,
        "| scene | AEPSA vs MLRTA search | Figure 6 phase 2 | extra depth | fps AEPSA / plain 1T | fps AEPSA / plain {tmax}T | fps MLRTA / plain 1T | fps MLRTA / plain {tmax}T | fps AEPSA / MLRTA 1T | fps AEPSA / MLRTA {tmax}T | BVH fps AEPSA / plain 1T | BVH fps AEPSA / plain {tmax}T |"
    );
    o.push_str("|---|--:|--:|--:|--:|--:|--:|--:|--:|--:|--:|--:|\n");
    for r in &s.scenes {
        let _ = writeln!(
            o,
            "| {}{} | {:.2}x | {:.2}x | {:+.2} % | {:.2}x | {:.2}x | {:.2}x | {:.2}x | {:.2}x | {:.2}x | {:.2}x | {:.2}x |",
            r.scene,
            if r.obj { "" } else { " (built-in)" },
            r.search,
            r.phase2,
            r.extra_depth,
            r.a_plain[0],
            r.a_plain[1],
            r.m_plain[0],
            r.m_plain[1],
            r.a_m[0],
            r.a_m[1],
            r.bvh[0],
            r.bvh[1]
        );
    }
    let all = || s.scenes.iter();
    let objs = || s.scenes.iter().filter(|r| r.obj);
    let search_mean = mean(all().map(|r| r.search));
    let search_min = min_of(all().map(|r| r.search));
    let _ = writeln!(
        o,
        "\n- AEPSA vs MLRTA full search time ({hl}x{hl}): mean {search_mean:.2}x, min {search_min:.2}x over {} scenes (target: mean >= 1.5x, none < 1): **{}**",
        s.scenes.len(),
        if search_mean >= 1.5 && search_min >= 1.0 {
            "met"
        } else {
            "not met"
        }
    );
    let _ = writeln!(
        o,
        "- the same from the median samples: full search mean {:.2}x, min {:.2}x; Figure 6 phase 2 mean {:.2}x, min {:.2}x",
        mean(all().map(|r| r.search_med)),
        min_of(all().map(|r| r.search_med)),
        mean(all().map(|r| r.phase2_med)),
        min_of(all().map(|r| r.phase2_med))
    );
    for &side in st.sides.iter().filter(|&&n| n != hl) {
        let rs = || rows.iter().filter(move |r| r.side == side);
        let _ = writeln!(
            o,
            "- at {side}x{side}: full search mean {:.2}x (min {:.2}x), Figure 6 phase 2 mean {:.2}x (min {:.2}x), extra depth mean {:+.2} %",
            mean(rs().map(|r| r.search_speedup())),
            min_of(rs().map(|r| r.search_speedup())),
            mean(rs().map(|r| r.phase2_speedup())),
            min_of(rs().map(|r| r.phase2_speedup())),
            mean(rs().map(|r| r.extra_depth_pct()))
        );
    }
    let p2_mean = mean(all().map(|r| r.phase2));
    let _ = writeln!(
        o,
        "- Figure 6 phase-2 speedup ({hl}x{hl}): mean {p2_mean:.2}x, min {:.2}x (paper: mean 1.58x, no slowdown)",
        min_of(all().map(|r| r.phase2))
    );
    let _ = writeln!(
        o,
        "- extra entry depth AEPSA over MLRTA (Figure 5): mean {:+.2} % (paper: mean 2.54 %, max 6.24 %)",
        mean(all().map(|r| r.extra_depth))
    );
    if objs().next().is_some() {
        for (i, t) in [1, tmax].into_iter().enumerate() {
            let m = mean(objs().map(|r| r.a_plain[i]));
            let lo = min_of(objs().map(|r| r.a_plain[i]));
            let _ = writeln!(
                o,
                "- fps AEPSA / plain kd packets on the OBJ scenes, {t} thread(s): mean {m:.2}x, min {lo:.2}x (target >= 1.2x on the OBJ scenes): **{}**; AEPSA / MLRTA mean {:.2}x (paper: up to 1.36x over plain, up to 1.18x over MLRTA)",
                if lo >= 1.2 {
                    "met on every OBJ scene"
                } else if m >= 1.2 {
                    "met on average, not on every scene"
                } else {
                    "not met"
                },
                mean(objs().map(|r| r.a_m[i]))
            );
        }
        let _ = writeln!(
            o,
            "- the same AEPSA / plain ratio as the ratio of the two medians: OBJ scenes mean {:.2}x on 1 thread, {:.2}x on {tmax}; from each configuration's fastest run: {:.2}x, {:.2}x",
            mean(objs().map(|r| r.a_plain_med[0])),
            mean(objs().map(|r| r.a_plain_med[1])),
            mean(objs().map(|r| r.a_plain_best[0])),
            mean(objs().map(|r| r.a_plain_best[1]))
        );
    } else {
        let _ = writeln!(
            o,
            "- fps AEPSA / plain kd packets (built-in scenes only): mean {:.2}x on 1 thread, {:.2}x on {tmax}",
            mean(all().map(|r| r.a_plain[0])),
            mean(all().map(|r| r.a_plain[1]))
        );
    }

    // Table 1.
    o.push_str("\n## Table 1: kd-tree statistics\n\n");
    o.push_str("| scene | tris | nodes | leaves | % empty | avg leaf depth | max depth | refs / tri | SAH cost | build ms | BVH build ms | view |\n|---|--:|--:|--:|--:|--:|--:|--:|--:|--:|--:|---|\n");
    for r in t1 {
        let k = &r.info;
        let _ = writeln!(
            o,
            "| {} | {} | {} | {} | {:.2} | {:.2} | {} | {:.2} | {:.1} | {:.1} | {:.1} | {} |",
            r.scene,
            k.triangles,
            k.nodes,
            k.leaves,
            pct(k.empty_leaves as u64, k.leaves as u64),
            k.avg_leaf_depth,
            k.depth,
            ratio_f(k.refs as f64, k.triangles as f64),
            k.sah_cost,
            ms(r.build_ns),
            ms(r.bvh_build_ns),
            r.view
        );
    }

    // Figure 5.
    o.push_str("\n## Entry points (Figure 5): average depth MLRTA vs AEPSA\n\n");
    o.push_str("Misses count at the average leaf depth; \"found\" averages only the searches that found an entry point.\n\n");
    o.push_str("| scene | packet | packets | avg leaf depth | MLRTA depth | AEPSA depth | extra depth | AEPSA deeper / same / shallower (% of packets) | misses MLRTA / AEPSA | found depth MLRTA / AEPSA |\n|---|---|--:|--:|--:|--:|--:|---|---|---|\n");
    for r in rows {
        let n = r.m.searches();
        let _ = writeln!(
            o,
            "| {} | {}x{} | {} | {:.2} | {:.2} | {:.2} | {:+.2} % | {:.1} / {:.1} / {:.1} | {} / {} | {:.2} / {:.2} |",
            r.scene,
            r.side,
            r.side,
            r.packets,
            r.miss_depth,
            r.m.avg_depth(),
            r.a.avg_depth(),
            r.extra_depth_pct(),
            pct(r.deeper, n),
            pct(r.same, n),
            pct(r.shallower, n),
            r.m.misses,
            r.a.misses,
            r.m.avg_found_depth(),
            r.a.avg_found_depth()
        );
    }

    if !nests.is_empty() {
        o.push_str("\nNesting check: a small packet's frustum lies inside the frustum of the large packet containing it, so an exact common-ancestor search gives it an entry point at or below the large packet's. Small packets whose entry point is shallower (or found where the large packet misses), and by how many levels on average:\n\n");
        o.push_str("| scene | small / large packet | compared | MLRTA shallower | AEPSA shallower | MLRTA levels | AEPSA levels |\n|---|---|--:|--:|--:|--:|--:|\n");
        for n in nests {
            let _ = writeln!(
                o,
                "| {} | {}x{} in {}x{} | {} | {} ({:.1} %) | {} ({:.1} %) | {:.2} | {:.2} |",
                n.scene,
                n.small,
                n.small,
                n.large,
                n.large,
                n.compared,
                n.shallower[0],
                pct(n.shallower[0], n.compared),
                n.shallower[1],
                pct(n.shallower[1], n.compared),
                ratio_f(n.levels[0] as f64, n.shallower[0] as f64),
                ratio_f(n.levels[1] as f64, n.shallower[1] as f64)
            );
        }
    }

    // Search times.
    o.push_str(
        "\n## Entry-point search time per packet (Figure 6) and nodes visited per search\n\n",
    );
    o.push_str("Full search = phase 1 + phase 2 of each algorithm. Figure 6 = phase 2 alone on MLRTA's phase-1 candidates (packets with a leaf). ns per packet, 1 thread.\n\n");
    o.push_str("| scene | packet | MLRTA search ns | AEPSA search ns | speedup | MLRTA nodes / search | AEPSA nodes / search | phase 1 ns MLRTA / AEPSA | Fig. 6 MLRTA phase 2 ns | Fig. 6 AEPSA phase 2 ns | Fig. 6 speedup | Fig. 6 nodes MLRTA / AEPSA | Fig. 6 candidates tested MLRTA / AEPSA | AEPSA phase 2 with triangle test ns (nodes) | entry differs |\n|---|---|--:|--:|--:|--:|--:|---|--:|--:|--:|---|---|---|--:|\n");
    for r in rows {
        let f6 = r.fig6_packets as f64;
        let _ = writeln!(
            o,
            "| {} | {}x{} | {:.0} | {:.0} | {:.2}x | {:.1} | {:.1} | {:.0} / {:.0} | {:.0} | {:.0} | {:.2}x | {:.1} / {:.1} | {:.2} / {:.2} | {:.0} ({:.1}) | {} |",
            r.scene,
            r.side,
            r.side,
            r.m_search_ns,
            r.a_search_ns,
            r.search_speedup(),
            ratio_f(r.m.nodes() as f64, r.m.searches() as f64),
            ratio_f(r.a.nodes() as f64, r.a.searches() as f64),
            r.m_phase1_ns,
            r.a_phase1_ns,
            r.m_p2_ns,
            r.a_p2_ns,
            r.phase2_speedup(),
            ratio_f(r.m_p2_nodes as f64, f6),
            ratio_f(r.a_p2_nodes as f64, f6),
            ratio_f(r.m_p2_tested as f64, f6),
            ratio_f(r.a_p2_tested as f64, f6),
            r.a_p2_tri_ns,
            ratio_f(r.a_p2_tri_nodes as f64, f6),
            r.fig6_entry_diff
        );
    }

    // Traversal from the entry point.
    o.push_str(
        "\n## Nodes visited from the entry point, per packet (primary rays, kd packets)\n\n",
    );
    o.push_str("Node steps = split-plane steps of 2x2 quads (`aabb_tests`), tests = ray-triangle tests per lane (`tri_tests`); the search's own nodes are not included. Primary ms: every primary packet traced once (search included), 1 thread. diff: rays whose hit differs from the kd single ray (must be 0).\n\n");
    o.push_str("| scene | packet | none: steps + tests | MLRTA: steps + tests | AEPSA: steps + tests | visited vs none MLRTA / AEPSA | primary ms none / MLRTA / AEPSA | diff |\n|---|---|---|---|---|---|---|--:|\n");
    for r in rows {
        let p = r.packets as f64;
        let cell = |k: usize| {
            let c = &r.trav[k].ctr;
            format!(
                "{:.1} + {:.1} = {:.1}",
                ratio_f(c.aabb_tests as f64, p),
                ratio_f(c.tri_tests as f64, p),
                r.visited(k)
            )
        };
        let _ = writeln!(
            o,
            "| {} | {}x{} | {} | {} | {} | {:+.1} % / {:+.1} % | {:.2} / {:.2} / {:.2} | {} |",
            r.scene,
            r.side,
            r.side,
            cell(0),
            cell(1),
            cell(2),
            100.0 * (ratio_f(r.visited(1), r.visited(0)) - 1.0),
            100.0 * (ratio_f(r.visited(2), r.visited(0)) - 1.0),
            ms(r.trav[0].ns),
            ms(r.trav[1].ns),
            ms(r.trav[2].ns),
            r.trav.iter().map(|t| t.diff).sum::<u64>()
        );
    }

    // Frames per second.
    o.push_str("\n## Frames per second (whole frame with shadows)\n\n");
    let labels: Vec<String> = {
        let mut v: Vec<String> = Vec::new();
        for r in fps {
            let l = r.cfg.label();
            if !v.contains(&l) {
                v.push(l);
            }
        }
        v
    };
    o.push_str("| scene | threads |");
    for l in &labels {
        let _ = write!(o, " {l} |");
    }
    o.push_str(" diff |\n|---|--:|");
    for _ in &labels {
        o.push_str("--:|");
    }
    o.push_str("--:|\n");
    let mut scenes: Vec<&str> = fps.iter().map(|r| r.scene.as_str()).collect();
    scenes.dedup();
    for sc in &scenes {
        for &t in st.threads {
            let _ = write!(o, "| {sc} | {t} |");
            let mut diff = 0;
            for l in &labels {
                match fps
                    .iter()
                    .find(|r| r.scene == *sc && r.threads == t && r.cfg.label() == *l)
                {
                    Some(r) => {
                        diff += r.diff;
                        let _ = write!(o, " {:.2} |", r.fps());
                    }
                    None => o.push_str(" |"),
                }
            }
            let _ = writeln!(o, " {diff} |");
        }
    }
    o.push_str("\ndiff: pixels differing from the kd single-ray frame, summed over the row's configurations.\n");
    o
}

/// A CSV table: its header and records.
type Table = (Vec<String>, Vec<Vec<String>>);

fn header(names: &str) -> Vec<String> {
    names.split(',').map(String::from).collect()
}

fn csv_table1(t1: &[Table1Row]) -> Table {
    let head = header(
        "scene,triangles_in,triangles,nodes,leaves,empty_leaves,empty_pct,avg_leaf_depth,max_depth,depth_limit,refs,refs_per_tri,sah_cost,forced_leaves,events_peak,build_ms,bvh_build_ms,view",
    );
    let records = t1
        .iter()
        .map(|r| {
            let k = &r.info;
            vec![
                r.scene.clone(),
                k.triangles_in.to_string(),
                k.triangles.to_string(),
                k.nodes.to_string(),
                k.leaves.to_string(),
                k.empty_leaves.to_string(),
                format!("{:.3}", pct(k.empty_leaves as u64, k.leaves as u64)),
                format!("{:.3}", k.avg_leaf_depth),
                k.depth.to_string(),
                k.max_depth.to_string(),
                k.refs.to_string(),
                format!("{:.3}", ratio_f(k.refs as f64, k.triangles as f64)),
                format!("{:.2}", k.sah_cost),
                k.forced_leaves.to_string(),
                k.events_peak.to_string(),
                format!("{:.3}", ms(r.build_ns)),
                format!("{:.3}", ms(r.bvh_build_ns)),
                r.view.clone(),
            ]
        })
        .collect();
    (head, records)
}

fn csv_search(rows: &[EntryRow]) -> Table {
    let mut head = header(
        "scene,obj,packet,packets,no_frustum,avg_leaf_depth,\
         mlrta_avg_depth,aepsa_avg_depth,extra_depth_pct,mlrta_found_depth,aepsa_found_depth,mlrta_misses,aepsa_misses,aepsa_deeper,same_depth,aepsa_shallower,\
         mlrta_search_ns,aepsa_search_ns,search_speedup,mlrta_phase1_ns,aepsa_phase1_ns,\
         mlrta_nodes_per_search,aepsa_nodes_per_search,mlrta_phase1_nodes,aepsa_phase1_nodes,mlrta_phase2_nodes,aepsa_phase2_nodes,mlrta_candidates,aepsa_candidates,mlrta_tested,aepsa_tested,\
         fig6_packets,fig6_mlrta_phase2_ns,fig6_aepsa_phase2_ns,fig6_speedup,fig6_aepsa_tri_phase2_ns,fig6_mlrta_nodes,fig6_aepsa_nodes,fig6_aepsa_tri_nodes,fig6_mlrta_tested,fig6_aepsa_tested,fig6_entry_differs,\
         median_mlrta_search_ns,median_aepsa_search_ns,median_search_speedup,median_fig6_mlrta_phase2_ns,median_fig6_aepsa_phase2_ns,median_fig6_speedup",
    );
    for e in SEARCHES {
        let n = e.name();
        for c in [
            "node_steps",
            "tri_tests",
            "visited_per_packet",
            "rays",
            "packets",
            "stray_lanes",
            "culled_nodes",
            "culled_tris",
            "entry_searches",
            "entry_depth_sum",
            "entry_nodes",
            "entry_misses",
            "primary_ms",
            "diff_vs_single",
        ] {
            head.push(format!("{n}_{c}"));
        }
    }
    let records = rows
        .iter()
        .map(|r| {
            let mut f = vec![
                r.scene.clone(),
                r.obj.to_string(),
                r.side.to_string(),
                r.packets.to_string(),
                r.no_frustum.to_string(),
                format!("{:.3}", r.miss_depth),
                format!("{:.4}", r.m.avg_depth()),
                format!("{:.4}", r.a.avg_depth()),
                format!("{:.3}", r.extra_depth_pct()),
                format!("{:.4}", r.m.avg_found_depth()),
                format!("{:.4}", r.a.avg_found_depth()),
                r.m.misses.to_string(),
                r.a.misses.to_string(),
                r.deeper.to_string(),
                r.same.to_string(),
                r.shallower.to_string(),
                format!("{:.1}", r.m_search_ns),
                format!("{:.1}", r.a_search_ns),
                format!("{:.3}", r.search_speedup()),
                format!("{:.1}", r.m_phase1_ns),
                format!("{:.1}", r.a_phase1_ns),
                format!("{:.2}", ratio_f(r.m.nodes() as f64, r.m.searches() as f64)),
                format!("{:.2}", ratio_f(r.a.nodes() as f64, r.a.searches() as f64)),
                r.m.phase1_nodes.to_string(),
                r.a.phase1_nodes.to_string(),
                r.m.phase2_nodes.to_string(),
                r.a.phase2_nodes.to_string(),
                r.m.candidates.to_string(),
                r.a.candidates.to_string(),
                r.m.tested.to_string(),
                r.a.tested.to_string(),
                r.fig6_packets.to_string(),
                format!("{:.1}", r.m_p2_ns),
                format!("{:.1}", r.a_p2_ns),
                format!("{:.3}", r.phase2_speedup()),
                format!("{:.1}", r.a_p2_tri_ns),
                r.m_p2_nodes.to_string(),
                r.a_p2_nodes.to_string(),
                r.a_p2_tri_nodes.to_string(),
                r.m_p2_tested.to_string(),
                r.a_p2_tested.to_string(),
                r.fig6_entry_diff.to_string(),
            ];
            let md = &r.medians;
            f.extend([
                format!("{:.1}", md[0]),
                format!("{:.1}", md[1]),
                format!("{:.3}", ratio_f(md[0], md[1])),
                format!("{:.1}", md[2]),
                format!("{:.1}", md[3]),
                format!("{:.3}", ratio_f(md[2], md[3])),
            ]);
            for (k, t) in r.trav.iter().enumerate() {
                let c = &t.ctr;
                f.extend([
                    c.aabb_tests.to_string(),
                    c.tri_tests.to_string(),
                    format!("{:.2}", r.visited(k)),
                    c.rays.to_string(),
                    c.packets.to_string(),
                    c.stray_lanes.to_string(),
                    c.culled_nodes.to_string(),
                    c.culled.to_string(),
                    c.entry_searches.to_string(),
                    c.entry_depth_sum.to_string(),
                    c.entry_nodes.to_string(),
                    c.entry_misses.to_string(),
                    format!("{:.3}", ms(t.ns)),
                    t.diff.to_string(),
                ]);
            }
            f
        })
        .collect();
    (head, records)
}

fn csv_fps(fps: &[FpsRow]) -> Table {
    let head = header(
        "scene,obj,config,method,packet,entry,threads,frame_ms,fps,fastest_ms,rays_traced,aabb_tests,tri_tests,entry_searches,entry_depth_sum,entry_nodes,entry_misses,pixels_differing",
    );
    let records = fps
        .iter()
        .map(|r| {
            let c = &r.ctr;
            vec![
                r.scene.clone(),
                r.obj.to_string(),
                r.cfg.label(),
                r.cfg.method.name().to_string(),
                r.cfg.side.to_string(),
                r.cfg.entry.name().to_string(),
                r.threads.to_string(),
                format!("{:.3}", ms(r.ns)),
                format!("{:.3}", r.fps()),
                format!("{:.3}", ms(r.min_ns)),
                c.rays.to_string(),
                c.aabb_tests.to_string(),
                c.tri_tests.to_string(),
                c.entry_searches.to_string(),
                c.entry_depth_sum.to_string(),
                c.entry_nodes.to_string(),
                c.entry_misses.to_string(),
                r.diff.to_string(),
            ]
        })
        .collect();
    (head, records)
}

/// The chart: per scene, bars of the headline side's fps speedup over
/// plain kd packets (MLRTA, AEPSA; the BVH's AEPSA over its plain packets)
/// on the machine's threads, and of AEPSA's search-time speedup over MLRTA
/// (full search and Figure 6's phase 2).
mod figure {
    use super::{EntryRow, FONT, FpsRow, Summary, save_chart};
    use anyhow::Result;
    use plotters::prelude::*;
    use std::path::Path;

    /// Width per scene, and for the axis and the legend (about 2 scenes' room).
    const W_SCENE: u32 = 170;
    const W_EXTRA: u32 = 420;
    const PANEL_H: u32 = 380;
    const TITLE_H: u32 = 40;

    struct Series {
        label: String,
        colour: RGBColor,
        values: Vec<f64>,
    }

    fn panel<DB: DrawingBackend>(
        area: &DrawingArea<DB, plotters::coord::Shift>,
        title: &str,
        scenes: &[String],
        series: &[Series],
    ) -> Result<()>
    where
        DB::ErrorType: 'static,
    {
        let top = series
            .iter()
            .flat_map(|s| s.values.iter().copied())
            .fold(1.0f64, f64::max)
            * 1.15;
        let n = scenes.len().max(1);
        // Room on the right for the legend.
        let xmax = (n + 2) as f64;
        let mut c = ChartBuilder::on(area)
            .caption(title, (FONT, 16))
            .margin(12)
            .x_label_area_size(34)
            .y_label_area_size(52)
            .build_cartesian_2d(0.0..xmax, 0.0..top)?;
        c.configure_mesh()
            .disable_x_mesh()
            .x_labels(2 * xmax.ceil() as usize + 1)
            .x_label_formatter(&|x| {
                let i = x.floor() as usize;
                if (x - i as f64 - 0.5).abs() < 0.01 {
                    scenes.get(i).cloned().unwrap_or_default()
                } else {
                    String::new()
                }
            })
            .y_desc("speedup (x)")
            .label_style((FONT, 12))
            .axis_desc_style((FONT, 13))
            .draw()?;
        let k = series.len().max(1) as f64;
        let bw = 0.8 / k;
        for (j, s) in series.iter().enumerate() {
            c.draw_series(s.values.iter().enumerate().map(|(i, &v)| {
                let x0 = i as f64 + 0.1 + j as f64 * bw;
                Rectangle::new([(x0, 0.0), (x0 + bw * 0.92, v)], s.colour.filled())
            }))?
            .label(s.label.clone())
            .legend(move |(x, y)| Rectangle::new([(x, y - 5), (x + 14, y + 5)], s.colour.filled()));
            // The value above each bar.
            c.draw_series(s.values.iter().enumerate().map(|(i, &v)| {
                let x0 = i as f64 + 0.1 + j as f64 * bw;
                Text::new(
                    format!("{v:.2}"),
                    (x0, v + top * 0.012),
                    (FONT, 10).into_font(),
                )
            }))?;
        }
        c.draw_series(DashedLineSeries::new(
            [(0.0, 1.0), (n as f64, 1.0)],
            6,
            4,
            BLACK.mix(0.6).stroke_width(1),
        ))?;
        c.configure_series_labels()
            .position(SeriesLabelPosition::UpperRight)
            .background_style(WHITE.mix(0.85))
            .border_style(BLACK.mix(0.4))
            .label_font((FONT, 12))
            .draw()?;
        Ok(())
    }

    fn draw<DB: DrawingBackend>(
        root: DrawingArea<DB, plotters::coord::Shift>,
        s: &Summary,
        title: &str,
        tmax: u32,
    ) -> Result<()>
    where
        DB::ErrorType: 'static,
    {
        root.fill(&WHITE)?;
        let (head, body) = root.split_vertically(TITLE_H);
        head.draw(&Text::new(
            title.to_string(),
            (12, 10),
            (FONT, 18).into_font(),
        ))?;
        let (p1, p2) = body.split_vertically(PANEL_H);
        let scenes: Vec<String> = s.scenes.iter().map(|r| r.scene.clone()).collect();
        let mut fps_series = Vec::new();
        for (i, t, light) in [(0, 1, false), (1, tmax, true)] {
            if i == 1 && tmax == 1 {
                break;
            }
            let shade = |c: RGBColor| {
                if light {
                    RGBColor(c.0 / 2 + 128, c.1 / 2 + 128, c.2 / 2 + 128)
                } else {
                    c
                }
            };
            fps_series.push(Series {
                label: format!("kd MLRTA / plain, {t}T"),
                colour: shade(RGBColor(230, 85, 13)),
                values: s.scenes.iter().map(|r| r.m_plain[i]).collect(),
            });
            fps_series.push(Series {
                label: format!("kd AEPSA / plain, {t}T"),
                colour: shade(RGBColor(84, 39, 143)),
                values: s.scenes.iter().map(|r| r.a_plain[i]).collect(),
            });
        }
        fps_series.push(Series {
            label: format!("BVH Ranged 16x16 AEPSA / plain, {tmax}T"),
            colour: RGBColor(49, 130, 189),
            values: s
                .scenes
                .iter()
                .map(|r| r.bvh[if tmax > 1 { 1 } else { 0 }])
                .collect(),
        });
        panel(
            &p1,
            "frames per second over plain kd packets (whole frame with shadows)",
            &scenes,
            &fps_series,
        )?;
        panel(
            &p2,
            "entry-point search time: MLRTA / AEPSA (1 thread)",
            &scenes,
            &[
                Series {
                    label: "full search (phase 1 + 2)".into(),
                    colour: RGBColor(44, 160, 44),
                    values: s.scenes.iter().map(|r| r.search).collect(),
                },
                Series {
                    label: "Figure 6: phase 2 on MLRTA's candidates".into(),
                    colour: RGBColor(214, 39, 40),
                    values: s.scenes.iter().map(|r| r.phase2).collect(),
                },
            ],
        )?;
        Ok(root.present()?)
    }

    pub(super) fn write(
        rows: &[EntryRow],
        fps: &[FpsRow],
        headline: u32,
        tmax: u32,
        svg: &Path,
        png: &Path,
    ) -> Result<()> {
        let s = Summary::new(rows, fps, headline, tmax);
        let size = (
            W_SCENE * s.scenes.len() as u32 + W_EXTRA,
            TITLE_H + 2 * PANEL_H,
        );
        let title = format!(
            "sheaf kd-tree entry-point search, {headline}x{headline} packets: AEPSA vs MLRTA vs plain packets"
        );
        save_chart(
            size,
            svg,
            png,
            |root| draw(root, &s, &title, tmax),
            |root| draw(root, &s, &title, tmax),
        )
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::TestArg;

    /// A tiny run end to end: every file is written, kd packets with every
    /// search agree with the kd single ray on every ray and pixel, and
    /// Figure 6's two phase 2s return the same entry points.
    #[test]
    fn tiny_run_writes_every_output() {
        let dir = std::env::temp_dir().join(format!("sheaf-entry-test-{}", std::process::id()));
        let a = BenchArgs {
            scenes: vec!["tetra".into(), "animated".into()],
            scenes_dir: None,
            size: Some((48, 32)),
            quick: true,
            packets: vec![8, 16],
            tests: vec![TestArg::Mt],
            threads: vec![1, 2],
            ablation: false,
            reps: Some(1),
            oracle_budget: None,
            lambda: 5.0,
            macrocell: 6,
            out_dir: Some(dir.clone()),
            whitted: false,
            entry: true,
            pgrid: false,
            stress: false,
            pgrid_opts: Default::default(),
            structures: vec![crate::StructureArg::Kd],
        };
        crate::studies::bench(&a).unwrap();
        let search = std::fs::read_to_string(dir.join("entry_search.csv")).unwrap();
        let lines: Vec<&str> = search.lines().collect();
        assert_eq!(
            lines.len(),
            1 + 2 * 2 * 2,
            "header + 2 scenes x 2 trees x 2 sides"
        );
        let head: Vec<&str> = lines[0].split(',').collect();
        let col = |n: &str| head.iter().position(|h| *h == n).unwrap();
        for l in &lines[1..] {
            let f: Vec<&str> = l.split(',').collect();
            assert_eq!(f.len(), head.len(), "{l}");
            for c in [
                "none_diff_vs_single",
                "mlrta_diff_vs_single",
                "aepsa_diff_vs_single",
                "fig6_entry_differs",
            ] {
                assert_eq!(f[col(c)], "0", "{c}: {l}");
            }
            assert!(f[col("aepsa_entry_searches")].parse::<u64>().unwrap() > 0);
        }
        let fps = std::fs::read_to_string(dir.join("entry_fps.csv")).unwrap();
        let lines: Vec<&str> = fps.lines().collect();
        assert_eq!(
            lines.len(),
            1 + 2 * 2 * 2 * (2 + 2 * 3 + 2),
            "header + scenes x trees x threads x configurations"
        );
        let head: Vec<&str> = lines[0].split(',').collect();
        let diff = head.iter().position(|h| *h == "pixels_differing").unwrap();
        let method = head.iter().position(|h| *h == "method").unwrap();
        for l in &lines[1..] {
            let f: Vec<&str> = l.split(',').collect();
            if f[method] != "bvh-ranged" {
                assert_eq!(f[diff], "0", "{l}");
            }
        }
        let md = std::fs::read_to_string(dir.join("entry.md")).unwrap();
        assert!(
            md.contains("## Table 1")
                && md.contains("| tetra-binned | 16x16 |")
                && md.contains("| tetra-exact | 16x16 |")
        );
        for f in [
            "entry_table1.csv",
            "entry.svg",
            "entry.png",
            "entry_tetra-binned.png",
            "entry_tetra-exact.png",
        ] {
            assert!(std::fs::metadata(dir.join(f)).unwrap().len() > 0, "{f}");
        }
        std::fs::remove_dir_all(&dir).ok();
    }
}

#[cfg(test)]
mod diagnose {
    use super::*;
    use crate::TestArg;
    use crate::load;
    use sheaf::geom::Aabb;

    /// Occupied leaves whose box and every ancestor's box the frustum does
    /// not cull (what the searches call reached), by brute force.
    fn reached(kv: &KdView<'_>, f: &Frustum) -> Vec<(u32, Aabb)> {
        let mut out = Vec::new();
        let mut stack = vec![(0u32, kv.info.root)];
        while let Some((n, b)) = stack.pop() {
            if f.cull_box(&b.min.to_array(), &b.max.to_array()) {
                continue;
            }
            let node = &kv.nodes[n as usize];
            if node.is_leaf() {
                if node.count() > 0 {
                    out.push((n, b));
                }
                continue;
            }
            let (l, r) = KdView::child_boxes(node, &b);
            stack.push((node.left() as u32, l));
            stack.push((node.left() as u32 + 1, r));
        }
        out
    }

    /// Why 8x8 entry points come out shallower than their 16x16 packet's on
    /// the interior scenes: occupied leaves the small frustum reaches but
    /// the large one culls, and whether they lie behind the eye.
    /// `cargo test --release --features cli --bin sheaf nesting -- --ignored --nocapture`
    #[test]
    #[ignore]
    fn nesting_violations_come_from_boxes_behind_the_eye() {
        for name in ["sibenik", "sponza", "conference"] {
            let a = BenchArgs {
                scenes: vec![name.into()],
                scenes_dir: None,
                size: None,
                quick: false,
                packets: vec![],
                tests: vec![TestArg::Mt],
                threads: vec![],
                ablation: false,
                reps: None,
                oracle_budget: None,
                lambda: 5.0,
                macrocell: 6,
                out_dir: None,
                whitted: false,
                entry: true,
                pgrid: false,
                stress: false,
                pgrid_opts: Default::default(),
                structures: vec![],
            };
            let Some(spec) = scene_specs(&a).unwrap().pop() else {
                continue;
            };
            let loaded = load::load(&spec.load).unwrap();
            let scene = loaded.scene().unwrap();
            let (w, h) = (512, 512);
            let mut limits = run::limits(&scene, (w, h), 1);
            limits.structures = Limits::KD;
            let (limits, _) = run::kd_limits(&scene, limits, &KdParams::default()).unwrap();
            let mut ctx = OwnedContext::new(&limits).unwrap();
            let info = ctx.build_kd(&scene, &KdParams::default()).unwrap();
            let tr = ctx.tracer().unwrap();
            let (v, _, _) = view_for(&loaded, &tr, &info.bounds, w, h);
            let kv = tr.kd.unwrap();
            let prim = PrimaryRays::new(&crate::view::camera(&v), w, h).unwrap();
            let pad = Ray::new(v.eye, Vec3::X, 0.0, 0.0);
            let small = Packets::new(&prim, w, h, 8, pad);
            let large = Packets::new(&prim, w, h, 16, pad);
            let (ps, _) = proxies(&small, &info.root);
            let (pl, _) = proxies(&large, &info.root);
            let fwd = (v.look_at - v.eye).normalize();
            let (sx, lx) = (w.div_ceil(8) as usize, w.div_ceil(16) as usize);
            let (mut viol, mut extra, mut behind) = (0, 0, 0);
            for p in &ps {
                let (tx, ty) = (p.packet % sx, p.packet / sx);
                let q = &pl[(ty / 2) * lx + tx / 2];
                let (ms, ml) = (
                    traverse_mlrta::search(&kv, &p.f, p.neg),
                    traverse_mlrta::search(&kv, &q.f, q.neg),
                );
                let (Some(es), Some(el)) = (ms.entry, ml.entry) else {
                    continue;
                };
                if es.depth >= el.depth {
                    continue;
                }
                viol += 1;
                let rl: std::collections::HashSet<u32> =
                    reached(&kv, &q.f).into_iter().map(|x| x.0).collect();
                for (n, b) in reached(&kv, &p.f) {
                    if rl.contains(&n) {
                        continue;
                    }
                    extra += 1;
                    let far = (0..8).map(|c| {
                        let corner = Vec3::new(
                            if c & 1 == 0 { b.min.x } else { b.max.x },
                            if c & 2 == 0 { b.min.y } else { b.max.y },
                            if c & 4 == 0 { b.min.z } else { b.max.z },
                        );
                        (corner - v.eye).dot(fwd)
                    });
                    if far.fold(f32::NEG_INFINITY, f32::max) < 0.0 {
                        behind += 1;
                    }
                }
            }
            println!(
                "{name}: {viol} of {} 8x8 packets get a shallower MLRTA entry point than their 16x16 packet; \
                 occupied leaves reached by the 8x8 frustum but culled by the 16x16 one: {extra}, of them entirely behind the eye plane: {behind}",
                ps.len()
            );
            // What a near plane at the eye would give: leaves entirely
            // behind the eye plane treated as empty.
            let front = Front {
                kv,
                eye: v.eye,
                fwd,
                behind: Default::default(),
            };
            for (side, px) in [(8, &ps), (16, &pl)] {
                let mut d = [0u64; 4];
                for p in px.iter() {
                    let r = [
                        traverse_mlrta::search(&kv, &p.f, p.neg),
                        traverse_aepsa::search(&kv, &p.f, p.neg),
                        traverse_mlrta::search(&front, &p.f, p.neg),
                        traverse_aepsa::search(&front, &p.f, p.neg),
                    ];
                    for (k, r) in r.iter().enumerate() {
                        d[k] += r
                            .entry
                            .map_or(info.avg_leaf_depth as u64, |e| e.depth as u64);
                    }
                }
                let n = px.len() as f64;
                println!(
                    "{name} {side}x{side}: avg entry depth MLRTA {:.2} AEPSA {:.2}; with the leaves behind the eye plane ignored: MLRTA {:.2} AEPSA {:.2}",
                    d[0] as f64 / n,
                    d[1] as f64 / n,
                    d[2] as f64 / n,
                    d[3] as f64 / n
                );
            }
        }
    }

    /// The kd-tree with every leaf entirely behind the eye plane empty.
    struct Front<'a> {
        kv: KdView<'a>,
        eye: Vec3,
        fwd: Vec3,
        /// Leaves seen entirely behind the eye plane.
        behind: std::cell::RefCell<std::collections::HashSet<u32>>,
    }

    impl Front<'_> {
        fn behind(&self, b: &Aabb) -> bool {
            let c = (b.min + b.max) * 0.5;
            let e = (b.max - b.min) * 0.5;
            (c - self.eye).dot(self.fwd) + e.dot(self.fwd.abs()) < 0.0
        }
    }

    impl sheaf::accel::entry::EntryTree for Front<'_> {
        fn root(&self) -> Option<(u32, Aabb)> {
            self.kv.root()
        }
        fn children(&self, node: u32, aabb: &Aabb) -> Option<[(u32, Aabb); 2]> {
            let ch = self.kv.children(node, aabb)?;
            for (n, b) in ch {
                if self.kv.nodes[n as usize].is_leaf() && self.behind(&b) {
                    self.behind.borrow_mut().insert(n);
                }
            }
            Some(ch)
        }
        fn split_axis(&self, node: u32) -> usize {
            self.kv.split_axis(node)
        }
        fn leaf_count(&self, node: u32) -> usize {
            if self.behind.borrow().contains(&node) {
                0
            } else {
                self.kv.leaf_count(node)
            }
        }
        fn leaf_overlapped(&self, node: u32, f: &Frustum) -> bool {
            !self.behind.borrow().contains(&node) && self.kv.leaf_overlapped(node, f)
        }
        fn miss_depth(&self) -> u32 {
            self.kv.miss_depth()
        }
    }
}
