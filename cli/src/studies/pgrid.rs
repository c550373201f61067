//! `sheaf bench --pgrid`: the perspective/light grid paper's section 5
//! ("Fast ray tracing of dynamic scenes with primary and shadow rays on
//! grids", 2010) on our scenes, as deferred frames (`render::deferred`)
//! whose work items run on `run::Threads`.
//!
//! Per scene (the built-in scenes and the OBJ scenes of `--scenes-dir`),
//! the scene's reference view (`bench::view_for`) at 1024x1024 (the paper's
//! resolution) with its default light, default `PgridParams` (or the
//! `--pgrid-tile`, `--chunk`, ... given):
//! - Figure 10: ms per phase of a frame with perspective-grid camera rays
//!   and light-grid shadows (primary build, primary traversal, data
//!   rearrangement, shadow build, shadow traversal, shade), each phase the
//!   median over the rounds; Mrays/s of camera plus shadow rays.
//! - Light-grid shadows against shadow packets on the same frames (same
//!   perspective-grid camera pass, same light): CGT and the BVH's Ranged
//!   and Partition packets (`ShadowPass::Traced`, packets of the tracing
//!   tile's side, 16 with the defaults). The shadow phase is rearrange +
//!   shadow build + shadow traversal (packets: the shadow-ray making,
//!   counted as rearrangement, and the traversal).
//! - Load balance of the light-grid pass: the slowest chunk (work item)
//!   over the mean chunk time, from `run::Threads`' item timing, with the
//!   chunk count and the most rays in a light tile, at the default r and
//!   at r = 4096 (little splitting), and the threads' busy share of the
//!   pass.
//! - The camera pass: perspective-grid traversal (and its per-frame build)
//!   against the BVH's Ranged and Partition 16x16 packets and CGT 16x16
//!   packets on prebuilt structures (their build times listed apart), in
//!   frames without shadows; nearest triangles compared per pixel.
//! - Figure 11: shadow time (rearrange + shadow build + shadow traversal)
//!   against the light's distance from the model's centre, 0.25 to 8 scene
//!   diagonals in 8 geometric steps, along a fixed direction (mostly up),
//!   for chunk sizes r = 32, 64, 256, 1024, 4096, on conference and sponza
//!   (or the two largest scenes run), at half the image size with the
//!   BVH's camera pass (same hits, same shadow rays): 48 frames per scene.
//!
//! Frames are timed in rounds, one frame per configuration per round after
//! an untimed frame, so load spells on a shared machine hit all alike; up
//! to `--reps` rounds (default 3), fewer once a scene's rounds took
//! `SCENE_CAP_S`. Every configuration's first image is compared pixel for
//! pixel with the pgrid + light-grid frame's.
#![forbid(unsafe_code)]

use super::common::{
    FONT, Progress, SceneSpec, check_threads, command_line, create_dir, load_or_skip, machine_line,
    ratio, scene_specs, tri_test, view_for, write_csv, write_text,
};
use crate::BenchArgs;
use crate::cmd::{primary_label, shadow_label};
use crate::run::{self, DeferredSetup, ItemTimes, Threads, ms};
use anyhow::{Context as _, Result, bail};
use glam::Vec3;
use sheaf::render::deferred::{PhaseTimes, tile_side};
use sheaf::trace::RayKind;
use sheaf::{
    DeferredInfo, DeferredJob, Frame, GridParams, Method, OwnedContext, PgridParams, PointLight,
    PrimaryPass, Shading, ShadowPass, TraceParams,
};
use std::fmt::Write as _;
use std::path::Path;
use std::time::Instant;

/// Scenes of the Figure 11 sweep (when run).
const FIG11_SCENES: [&str; 2] = ["conference", "sponza"];
/// Chunk sizes r of the Figure 11 sweep.
const FIG11_R: [u32; 5] = [32, 64, 256, 1024, 4096];
/// Light distances of the Figure 11 sweep, in scene diagonals: 0.25 to 8 in
/// 8 geometric steps.
const FIG11_STEPS: usize = 8;
const FIG11_NEAR: f64 = 0.25;
const FIG11_FAR: f64 = 8.0;
/// Rounds per Figure 11 point: 2 more than `--reps` (short frames, noisy).
fn fig11_reps(reps: u32) -> u32 {
    reps + 2
}

/// Rounds of a scene stop once they took this long (at least one round).
const SCENE_CAP_S: f64 = 30.0;

/// Figure 11's image size for `--size` (half of it: its 40 frames per
/// distance step would take minutes at 1024x1024).
fn fig11_size((w, h): (u32, u32)) -> (u32, u32) {
    ((w / 2).max(16), (h / 2).max(16))
}

/// The chunk size with little splitting, for the load-balance comparison.
const WIDE_R: u32 = 4096;
/// Packet side of the traced camera passes.
const PACKET: u32 = 16;

fn fig11_distances() -> Vec<f64> {
    (0..FIG11_STEPS)
        .map(|i| FIG11_NEAR * (FIG11_FAR / FIG11_NEAR).powf(i as f64 / (FIG11_STEPS - 1) as f64))
        .collect()
}

/// What a configuration is for.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Role {
    /// pgrid + light grid at the chosen r: Figure 10, the baseline.
    Main,
    /// pgrid + light grid at r = 4096.
    Wide,
    /// pgrid + shadow packets.
    Packets,
    /// A traced camera pass (+ light-grid shadows).
    Camera,
}

#[derive(Clone, Copy, Debug)]
struct Config {
    role: Role,
    primary: PrimaryPass,
    shadow: ShadowPass,
    chunk: u32,
    /// Shadow rays traced (off for the camera-pass comparison).
    shadows: bool,
}

impl Config {
    fn label(&self) -> String {
        if !self.shadows {
            return format!("{} / no shadows", primary_label(&self.primary));
        }
        let mut s = format!(
            "{} / {}",
            primary_label(&self.primary),
            shadow_label(&self.shadow)
        );
        if self.shadow == ShadowPass::LightGrid {
            let _ = write!(s, " r={}", self.chunk);
        }
        s
    }
}

/// One frame.
#[derive(Clone, Debug, Default)]
struct Sample {
    info: DeferredInfo,
    /// Item times of the shadow pass (its chunks with the light grid).
    chunks: ItemTimes,
    /// Each chunk's time, in chunk order (light-grid frames).
    items: Vec<u64>,
}

impl Sample {
    fn shadow_ns(&self) -> u64 {
        let t = &self.info.times;
        t.rearrange + t.shadow_build + t.shadow_trace
    }
}

/// A configuration's frames on one scene, summarised by medians.
#[derive(Clone, Debug)]
struct CfgResult {
    cfg: Config,
    /// Median of each phase.
    times: PhaseTimes,
    /// Median of the whole frame and of the shadow phases' sum.
    frame_ns: u64,
    shadow_ns: u64,
    shadow_rays: u64,
    hits: u64,
    info: DeferredInfo,
    /// Load balance of the shadow pass (medians).
    chunk_count: u64,
    chunk_max_ns: u64,
    chunk_mean_ns: f64,
    imbalance: f64,
    /// The 99th-percentile chunk over the mean chunk (median).
    tail: f64,
    /// Each chunk's fastest time over the rounds (the same chunks every
    /// round): its slowest over its mean, free of most preemptions.
    steady_max_ns: u64,
    steady_mean_ns: f64,
    steady_imbalance: f64,
    efficiency: f64,
    /// Pixels that differ from the pgrid + light-grid frame's (camera
    /// configurations: pixels whose nearest triangle differs).
    diff: u64,
    /// Frames timed.
    frames: usize,
}

/// Median (the mean of the middle two for an even count; 0 when empty).
fn median(mut v: Vec<u64>) -> u64 {
    v.sort_unstable();
    let n = v.len();
    match n {
        0 => 0,
        _ if n % 2 == 1 => v[n / 2],
        _ => (v[n / 2 - 1] + v[n / 2]) / 2,
    }
}

fn med_f(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    let n = v.len();
    match n {
        0 => 0.0,
        _ if n % 2 == 1 => v[n / 2],
        _ => 0.5 * (v[n / 2 - 1] + v[n / 2]),
    }
}

impl CfgResult {
    fn new(cfg: Config, s: &[Sample], diff: u64) -> CfgResult {
        let m = |f: &dyn Fn(&Sample) -> u64| median(s.iter().map(f).collect());
        let times = PhaseTimes {
            primary_build: m(&|x| x.info.times.primary_build),
            primary_trace: m(&|x| x.info.times.primary_trace),
            rearrange: m(&|x| x.info.times.rearrange),
            shadow_build: m(&|x| x.info.times.shadow_build),
            shadow_trace: m(&|x| x.info.times.shadow_trace),
            shade: m(&|x| x.info.times.shade),
        };
        let last = s.last().cloned().unwrap_or_default();
        // Per chunk, the fastest of the rounds.
        let n = s.first().map_or(0, |x| x.items.len());
        let steady: Vec<u64> = if n > 0 && s.iter().all(|x| x.items.len() == n) {
            (0..n)
                .map(|i| s.iter().map(|x| x.items[i]).min().unwrap_or(0))
                .collect()
        } else {
            Vec::new()
        };
        let steady_max_ns = steady.iter().copied().max().unwrap_or(0);
        let steady_mean = steady.iter().sum::<u64>() as f64 / steady.len().max(1) as f64;
        CfgResult {
            cfg,
            times,
            frame_ns: m(&|x| x.info.times.total()),
            shadow_ns: m(&|x| x.shadow_ns()),
            shadow_rays: last.info.shadow_rays,
            hits: last.info.hits,
            info: last.info,
            chunk_count: m(&|x| x.chunks.count),
            chunk_max_ns: m(&|x| x.chunks.max_ns),
            chunk_mean_ns: med_f(s.iter().map(|x| x.chunks.mean_ns()).collect()),
            imbalance: med_f(s.iter().map(|x| x.chunks.imbalance()).collect()),
            tail: med_f(s.iter().map(|x| x.chunks.tail()).collect()),
            steady_max_ns,
            steady_mean_ns: steady_mean,
            steady_imbalance: if steady_mean > 0.0 {
                steady_max_ns as f64 / steady_mean
            } else {
                0.0
            },
            efficiency: med_f(s.iter().map(|x| x.chunks.efficiency()).collect()),
            diff,
            frames: s.len(),
        }
    }
}

/// Figure 11: one light distance.
#[derive(Clone, Debug)]
struct Fig11Row {
    diagonals: f64,
    distance: f32,
    /// Shadow rays, and the share occluded (at the chosen r).
    shadow_rays: u64,
    occluded: u64,
    /// Median shadow ms per r of `FIG11_R`, the chunk counts and the
    /// 99th-percentile chunk over the mean chunk.
    shadow_ns: Vec<u64>,
    chunks: Vec<u64>,
    imbalance: Vec<f64>,
}

struct SceneResult {
    name: String,
    triangles: u32,
    view: String,
    grid_build_ns: u64,
    bvh_build_ns: u64,
    cfgs: Vec<CfgResult>,
    fig11: Vec<Fig11Row>,
    /// Light direction of the Figure 11 sweep.
    fig11_dir: Vec3,
    diagonal: f32,
}

impl SceneResult {
    fn get(&self, f: impl Fn(&Config) -> bool) -> Option<&CfgResult> {
        self.cfgs.iter().find(|c| f(&c.cfg))
    }
    fn main(&self) -> Option<&CfgResult> {
        self.get(|c| c.role == Role::Main)
    }
    fn wide(&self) -> Option<&CfgResult> {
        self.get(|c| c.role == Role::Wide)
    }
    fn shadow_packets(&self, m: Method) -> Option<&CfgResult> {
        self.get(|c| matches!(c.shadow, ShadowPass::Traced(p) if p.method == m))
    }
    fn camera(&self, m: Method) -> Option<&CfgResult> {
        self.get(|c| matches!(c.primary, PrimaryPass::Traced(p) if p.method == m))
    }
    /// The fastest shadow-packet configuration.
    fn best_packets(&self) -> Option<&CfgResult> {
        self.cfgs
            .iter()
            .filter(|c| c.cfg.role == Role::Packets)
            .min_by_key(|c| c.shadow_ns)
    }
}

/// A scene's context, threads and frame buffer.
struct Bench<'s> {
    setup: DeferredSetup<'s>,
    ctx: OwnedContext,
    workers: Threads,
    pixels: Vec<u8>,
    frame: Frame,
    grown: bool,
}

impl Bench<'_> {
    fn frame(&mut self, cfg: &Config) -> Result<Sample> {
        if self.setup.pgrid.chunk != cfg.chunk {
            self.setup.pgrid.chunk = cfg.chunk;
            self.ctx
                .build_pgrid(self.setup.scene, &self.setup.pgrid)
                .context("loading the scene for the perspective grids")?;
        }
        self.frame.shading.shadows = cfg.shadows;
        let job = DeferredJob {
            frame: &self.frame,
            lights: &[],
            primary: cfg.primary,
            shadow: cfg.shadow,
        };
        let (info, grown) =
            self.setup
                .render(&mut self.ctx, &job, &mut self.pixels, &mut self.workers)?;
        self.grown |= grown;
        let pass = self
            .workers
            .shadow_pass()
            .filter(|_| self.frame.shading.shadows);
        let chunks = pass.map_or(ItemTimes::default(), |(t, _)| t);
        let items = match pass {
            Some((_, items)) if cfg.shadow == ShadowPass::LightGrid => items.to_vec(),
            _ => Vec::new(),
        };
        Ok(Sample {
            info,
            chunks,
            items,
        })
    }

    /// Nearest triangle of every pixel of the last frame.
    fn prims(&self) -> Vec<u32> {
        let (w, h) = (self.frame.width, self.frame.height);
        (0..h)
            .flat_map(|y| (0..w).map(move |x| (x, y)))
            .map(|(x, y)| {
                self.ctx
                    .deferred_pixel(x, y)
                    .map_or(u32::MAX, |(hit, _)| hit.prim)
            })
            .collect()
    }

    /// Pixels whose shadow bit is set in the last frame.
    fn occluded(&self) -> u64 {
        let (w, h) = (self.frame.width, self.frame.height);
        let mut n = 0;
        for y in 0..h {
            for x in 0..w {
                if let Some((_, bits)) = self.ctx.deferred_pixel(x, y) {
                    n += (bits & 1) as u64;
                }
            }
        }
        n
    }
}

fn diff_pixels(a: &[u8], b: &[u8]) -> u64 {
    a.chunks(4).zip(b.chunks(4)).filter(|(p, q)| p != q).count() as u64
}

/// `sheaf bench --pgrid`.
pub fn run(a: &BenchArgs) -> Result<()> {
    let start = Instant::now();
    let (w, h) = a
        .size
        .unwrap_or(if a.quick { (256, 256) } else { (1024, 1024) });
    let hw = std::thread::available_parallelism().map_or(1, |n| n.get() as u32);
    let threads = a.threads.iter().copied().max().unwrap_or(hw);
    check_threads(&[threads])?;
    let reps = a.reps.unwrap_or(if a.quick { 1 } else { 3 }).max(1);
    let test = tri_test(a);
    let grid = GridParams {
        lambda: a.lambda,
        macrocell: a.macrocell,
        test,
        fit: false,
    };
    let pp = a.pgrid_opts.params(test)?;
    let side = tile_side(&PrimaryPass::Pgrid, pp.tile, pp.group);
    let specs: Vec<SceneSpec> = scene_specs(a)?;
    let out_dir = a.out_dir();
    create_dir(&out_dir)?;
    let machine = machine_line();
    let cfgs = configs(&pp, side);
    let fig11_names: Vec<String> = {
        let present: Vec<&str> = FIG11_SCENES
            .iter()
            .copied()
            .filter(|n| specs.iter().any(|s| s.name == *n))
            .collect();
        if present.is_empty() {
            Vec::new() // chosen after loading: the two largest scenes
        } else {
            present.iter().map(|s| s.to_string()).collect()
        }
    };
    // Steps: each round of a scene's configurations, each light distance of Figure 11.
    let fig11_steps = FIG11_STEPS as u64;
    let prog = Progress::new(
        "sheaf bench --pgrid",
        specs.len() as u64 * reps as u64 + fig11_names.len() as u64 * fig11_steps,
    );
    prog.say(format_args!(
        "sheaf bench --pgrid: {} scenes, {w}x{h}, {threads} threads, {} configurations per scene, median of up to {reps} rounds (fewer after {SCENE_CAP_S:.0} s per scene), Figure 11 at {}x{} on {}, PgridParams {{ tile {}, group {}, slices {}, light tiles {}, light slices {}, chunk r {} }}, {test:?}, machine: {machine}",
        specs.len(),
        cfgs.len(),
        fig11_size((w, h)).0,
        fig11_size((w, h)).1,
        if fig11_names.is_empty() {
            "the two largest scenes".to_string()
        } else {
            fig11_names.join(", ")
        },
        pp.tile,
        pp.group,
        pp.slices,
        pp.light_tiles,
        pp.light_slices,
        pp.chunk
    ));
    let plan = Plan {
        w,
        h,
        threads,
        reps,
        grid: &grid,
        pp: &pp,
        out_dir: &out_dir,
    };
    let mut results: Vec<SceneResult> = Vec::new();
    // Scenes for Figure 11 when neither named one runs: after the others,
    // the two largest (re-run then).
    let mut deferred_fig11: Vec<(usize, SceneSpec)> = Vec::new();
    for spec in &specs {
        let fig11 = fig11_names.contains(&spec.name);
        prog.doing(spec.name.clone());
        match scene(spec, &plan, &cfgs, fig11, &prog)? {
            Some(r) => {
                if fig11_names.is_empty() {
                    deferred_fig11.push((
                        r.triangles as usize,
                        SceneSpec {
                            name: spec.name.clone(),
                            load: spec.load.clone(),
                        },
                    ));
                }
                results.push(r);
            }
            None => continue,
        }
    }
    if fig11_names.is_empty() && !deferred_fig11.is_empty() {
        deferred_fig11.sort_by_key(|(n, _)| std::cmp::Reverse(*n));
        deferred_fig11.truncate(2);
        prog.say(format_args!(
            "note: conference and sponza did not run: Figure 11 on {}",
            deferred_fig11
                .iter()
                .map(|(_, s)| s.name.as_str())
                .collect::<Vec<_>>()
                .join(", ")
        ));
        prog.add(deferred_fig11.len() as u64 * fig11_steps);
        for (_, spec) in &deferred_fig11 {
            prog.doing(format!("{}: Figure 11", spec.name));
            if let Some(r) = scene(spec, &plan, &[], true, &prog)? {
                if let Some(x) = results.iter_mut().find(|x| x.name == r.name) {
                    x.fig11 = r.fig11;
                    x.fig11_dir = r.fig11_dir;
                    x.diagonal = r.diagonal;
                }
            }
        }
    }
    if results.is_empty() {
        bail!("no scene ran");
    }
    let total_s = start.elapsed().as_secs_f64();
    let setup = Setup {
        w,
        h,
        threads,
        reps,
        pp: &pp,
        side,
        test,
        machine_start: machine,
        machine_end: machine_line(),
        total_s,
    };
    let md = markdown(&results, &setup);
    let md_path = out_dir.join("README.md");
    write_text(&md_path, &md)?;
    let (head, records) = csv(&results);
    write_csv(&out_dir.join("pgrid.csv"), &head, records)?;
    let (head, records) = csv_fig11(&results);
    write_csv(&out_dir.join("figure11.csv"), &head, records)?;
    charts::figure10(
        &results,
        &setup,
        &out_dir.join("figure10.svg"),
        &out_dir.join("figure10.png"),
    )?;
    charts::shadows(
        &results,
        &setup,
        &out_dir.join("shadows.svg"),
        &out_dir.join("shadows.png"),
    )?;
    if results.iter().any(|r| !r.fig11.is_empty()) {
        charts::figure11(
            &results,
            &setup,
            &out_dir.join("figure11.svg"),
            &out_dir.join("figure11.png"),
        )?;
    }
    prog.say(format_args!(
        "wrote {}, pgrid.csv, figure11.csv, figure10.svg/png, shadows.svg/png{} in {} ({:.0} s)",
        md_path.display(),
        if results.iter().any(|r| !r.fig11.is_empty()) {
            ", figure11.svg/png"
        } else {
            ""
        },
        out_dir.display(),
        start.elapsed().as_secs_f64()
    ));
    Ok(())
}

/// The configurations of a scene, the baseline first.
fn configs(pp: &PgridParams, side: u32) -> Vec<Config> {
    let shadow =
        |m: Method| ShadowPass::Traced(TraceParams::bvh(m, side).with_kind(RayKind::Shadow));
    let camera =
        |m: Method| PrimaryPass::Traced(TraceParams::bvh(m, PACKET).with_kind(RayKind::Primary));
    let mut v = vec![Config {
        role: Role::Main,
        primary: PrimaryPass::Pgrid,
        shadow: ShadowPass::LightGrid,
        chunk: pp.chunk,
        shadows: true,
    }];
    if pp.chunk != WIDE_R {
        v.push(Config {
            role: Role::Wide,
            chunk: WIDE_R,
            ..v[0]
        });
    }
    for m in [Method::GridCgt, Method::BvhRanged, Method::BvhPartition] {
        v.push(Config {
            role: Role::Packets,
            primary: PrimaryPass::Pgrid,
            shadow: shadow(m),
            chunk: pp.chunk,
            shadows: true,
        });
    }
    for m in [Method::BvhRanged, Method::BvhPartition, Method::GridCgt] {
        v.push(Config {
            role: Role::Camera,
            primary: camera(m),
            shadow: ShadowPass::LightGrid,
            chunk: pp.chunk,
            shadows: false,
        });
    }
    v
}

/// What every scene of the run shares, as the command line sets it: the
/// frame size, the threads, the rounds, the structures' parameters and
/// where the images go.
#[derive(Clone, Copy)]
struct Plan<'a> {
    w: u32,
    h: u32,
    threads: u32,
    reps: u32,
    grid: &'a GridParams,
    pp: &'a PgridParams,
    out_dir: &'a Path,
}

/// One scene: load, build, the configurations in rounds, Figure 11 when
/// `fig11`. None: skipped (with a note).
fn scene(
    spec: &SceneSpec,
    plan: &Plan<'_>,
    cfgs: &[Config],
    fig11: bool,
    prog: &Progress,
) -> Result<Option<SceneResult>> {
    let Plan {
        w,
        h,
        threads,
        reps,
        grid,
        pp,
        out_dir,
    } = *plan;
    // The steps this scene stands for, done when it is skipped.
    let steps =
        if cfgs.is_empty() { 0 } else { reps as u64 } + if fig11 { FIG11_STEPS as u64 } else { 0 };
    let t_load = Instant::now();
    let Some(loaded) = load_or_skip(spec, prog) else {
        prog.inc(steps);
        return Ok(None);
    };
    let scene = loaded.scene()?;
    let load_s = t_load.elapsed().as_secs_f64();
    let setup = DeferredSetup {
        scene: &scene,
        grid: *grid,
        bvh: true,
        kd: false,
        pgrid: *pp,
    };
    let mut limits = run::limits(&scene, (w, h), threads);
    limits.structures = sheaf::Limits::GRID | sheaf::Limits::BVH | sheaf::Limits::PGRID;
    let (ctx, info) = setup.context(limits)?;
    if info.triangles == 0 {
        prog.say(format_args!(
            "note: {}: every triangle is degenerate or non-finite, skipped",
            spec.name
        ));
        prog.inc(steps);
        return Ok(None);
    }
    let grid_build_ns = ctx.stats().build_ns;
    let bvh_build_ns = ctx.stats().bvh_build_ns;
    let (v, light, how) = view_for(&loaded, &ctx.tracer()?, &info.bounds, w, h);
    let frame = Frame {
        camera: crate::view::camera(&v),
        light: PointLight {
            position: light.to_array(),
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
    prog.say(format_args!(
        "[{}] {} triangles, loaded in {load_s:.1} s; grid {} build {:.0} ms, BVH build {:.0} ms; view {how}",
        spec.name,
        info.triangles,
        run::res(&info),
        ms(grid_build_ns),
        ms(bvh_build_ns)
    ));
    let mut b = Bench {
        setup,
        ctx,
        workers: {
            let mut t = Threads::new(threads);
            t.keep_items = true;
            t
        },
        pixels: vec![0u8; w as usize * h as usize * 4],
        frame,
        grown: false,
    };
    let mut res = SceneResult {
        name: spec.name.clone(),
        triangles: info.triangles,
        view: how,
        grid_build_ns,
        bvh_build_ns,
        cfgs: Vec::new(),
        fig11: Vec::new(),
        fig11_dir: Vec3::ZERO,
        diagonal: (info.bounds.max - info.bounds.min).length(),
    };

    // The configurations: one untimed frame, then up to `reps` rounds of
    // one frame each (fewer once the scene's rounds took `SCENE_CAP`); the
    // first round's images are compared with the baseline's.
    if !cfgs.is_empty() {
        b.frame(&cfgs[0])?;
        let mut reference: Vec<u8> = Vec::new();
        let mut ref_prims: Vec<u32> = Vec::new();
        let mut diffs = vec![0u64; cfgs.len()];
        let mut samples: Vec<Vec<Sample>> = vec![Vec::new(); cfgs.len()];
        let t0 = Instant::now();
        let mut round = 0;
        while round < reps && (round == 0 || t0.elapsed().as_secs_f64() < SCENE_CAP_S) {
            let tr = Instant::now();
            for (i, c) in cfgs.iter().enumerate() {
                samples[i].push(b.frame(c)?);
                if round > 0 {
                    continue;
                }
                if i == 0 {
                    reference = b.pixels.clone();
                    ref_prims = b.prims();
                    let path = out_dir.join(format!("frame_{}.png", spec.name));
                    run::write_png(&path, &b.pixels, w, h)?;
                } else if c.shadows {
                    diffs[i] = diff_pixels(&reference, &b.pixels);
                } else {
                    diffs[i] = b
                        .prims()
                        .iter()
                        .zip(&ref_prims)
                        .filter(|(p, q)| p != q)
                        .count() as u64;
                }
            }
            round += 1;
            prog.step();
            prog.say(format_args!(
                "[{}] round {round}/{reps}: {} frames in {:.1} s",
                spec.name,
                cfgs.len(),
                tr.elapsed().as_secs_f64()
            ));
        }
        prog.inc((reps - round) as u64);
        for (i, c) in cfgs.iter().enumerate() {
            let r = CfgResult::new(*c, &samples[i], diffs[i]);
            prog.say(format_args!("[{}] {}", spec.name, progress(&r, w, h)));
            res.cfgs.push(r);
        }
    }

    // Figure 11.
    if fig11 {
        let c = 0.5 * (info.bounds.min + info.bounds.max);
        let diag = res.diagonal;
        let up = v.up.normalize_or_zero();
        let back = (v.eye - v.look_at).normalize_or_zero();
        let right = (-back).cross(up).normalize_or_zero();
        let dir = (up + right * 0.3 + back * 0.2).normalize_or(Vec3::Y);
        res.fig11_dir = dir;
        // The camera pass is the BVH's (the shadow rays, made from the
        // same hits, are the same as after the perspective grid's; this
        // only saves time), at half the size.
        let base = Config {
            role: Role::Main,
            primary: PrimaryPass::Traced(
                TraceParams::bvh(Method::BvhRanged, PACKET).with_kind(RayKind::Primary),
            ),
            shadow: ShadowPass::LightGrid,
            chunk: pp.chunk,
            shadows: true,
        };
        let (fw, fh) = fig11_size((w, h));
        b.frame.width = fw;
        b.frame.height = fh;
        b.pixels.truncate(fw as usize * fh as usize * 4);
        for k in fig11_distances() {
            let d = diag * k as f32;
            b.frame.light.position = (c + dir * d).to_array();
            // Untimed: the occlusion share at the chosen r.
            let s0 = b.frame(&base)?;
            let occluded = b.occluded();
            let mut samples: Vec<Vec<Sample>> = vec![Vec::new(); FIG11_R.len()];
            for _ in 0..fig11_reps(reps) {
                for (j, &r) in FIG11_R.iter().enumerate() {
                    samples[j].push(b.frame(&Config { chunk: r, ..base })?);
                }
            }
            let row = Fig11Row {
                diagonals: k,
                distance: d,
                shadow_rays: s0.info.shadow_rays,
                occluded,
                shadow_ns: samples
                    .iter()
                    .map(|s| median(s.iter().map(|x| x.shadow_ns()).collect()))
                    .collect(),
                chunks: samples
                    .iter()
                    .map(|s| median(s.iter().map(|x| x.info.reorder.chunks as u64).collect()))
                    .collect(),
                imbalance: samples
                    .iter()
                    .map(|s| med_f(s.iter().map(|x| x.chunks.tail()).collect()))
                    .collect(),
            };
            let mut line = format!(
                "[{}] Figure 11: light at {k:.2} diagonals ({d:.1}): {} shadow rays, {:.1} % occluded; shadow ms",
                spec.name,
                row.shadow_rays,
                100.0 * row.occluded as f64 / row.shadow_rays.max(1) as f64
            );
            for (j, r) in FIG11_R.iter().enumerate() {
                let _ = write!(line, " r={r} {:.2}", ms(row.shadow_ns[j]));
            }
            prog.say(line);
            prog.step();
            res.fig11.push(row);
        }
        b.frame.light.position = light.to_array();
        b.frame.width = w;
        b.frame.height = h;
        b.pixels.resize(w as usize * h as usize * 4, 0);
    }
    if b.grown {
        prog.say(format_args!(
            "[{}] note: a perspective or light grid outgrew the pools: grown to {} cells, {} pairs per grid",
            spec.name,
            b.ctx.limits().pgrid_cells(),
            b.ctx.limits().pgrid_refs()
        ));
    }
    Ok(Some(res))
}

fn progress(r: &CfgResult, w: u32, h: u32) -> String {
    let t = &r.times;
    let mut s = format!(
        "{:<40} frame {:7.2} ms = pbuild {:.2} + ptrace {:.2} + rearr {:.2} + sbuild {:.2} + strace {:.2} + shade {:.2}; shadow {:.2} ms; {:.1} Mrays/s",
        r.cfg.label(),
        ms(r.frame_ns),
        ms(t.primary_build),
        ms(t.primary_trace),
        ms(t.rearrange),
        ms(t.shadow_build),
        ms(t.shadow_trace),
        ms(t.shade),
        ms(r.shadow_ns),
        run::mrays(w as u64 * h as u64 + r.shadow_rays, r.frame_ns)
    );
    if r.cfg.shadows && r.cfg.shadow == ShadowPass::LightGrid {
        let _ = write!(
            s,
            "; {} chunks, slowest/mean {:.1} (raw {:.1}), p99/mean {:.1}, busy {:.0} %",
            r.chunk_count,
            r.steady_imbalance,
            r.imbalance,
            r.tail,
            100.0 * r.efficiency
        );
    }
    if r.diff > 0 {
        let _ = write!(
            s,
            "; {} pixels differ from the pgrid/light-grid frame",
            r.diff
        );
    }
    s
}

// ---------------------------------------------------------------------------
// Output

struct Setup<'a> {
    w: u32,
    h: u32,
    threads: u32,
    reps: u32,
    pp: &'a PgridParams,
    side: u32,
    test: sheaf::TriTest,
    machine_start: String,
    machine_end: String,
    total_s: f64,
}

fn f2(ns: u64) -> String {
    format!("{:.2}", ms(ns))
}

fn markdown(results: &[SceneResult], s: &Setup<'_>) -> String {
    let (w, h) = (s.w, s.h);
    let pp = s.pp;
    let mut m = String::new();
    let _ = writeln!(
        m,
        "# sheaf bench --pgrid: perspective grids and light grids (paper section 5)\n"
    );
    let _ = writeln!(m, "- command: `{}`", command_line());
    let _ = writeln!(m, "- machine (at the start): {}", s.machine_start);
    let _ = writeln!(m, "- machine (at the end): {}", s.machine_end);
    let _ = writeln!(
        m,
        "- setup: {w}x{h}, each scene's reference view (built-in scenes: view 0; OBJ scenes: the view `sheaf render` picks) and default light (one point light), Lambert shading; deferred frames (`render_deferred`) with work items on {} threads (`run::Threads`: scoped threads pulling items from a shared queue)",
        s.threads
    );
    let _ = writeln!(
        m,
        "- PgridParams: sorting tile {} px, group {} (tracing tiles {}x{} px), {} depth slices; light grids of up to {} x {} tiles, {} slices; chunk r = {}; triangle test {:?}",
        pp.tile,
        pp.group,
        s.side,
        s.side,
        pp.slices,
        pp.light_tiles,
        pp.light_tiles,
        pp.light_slices,
        pp.chunk,
        s.test
    );
    let _ = writeln!(
        m,
        "- timing: after one untimed frame, rounds of one frame per configuration (so load spells on the shared machine hit all alike), up to {} rounds, fewer once a scene's rounds took {SCENE_CAP_S:.0} s (at least one; \"frames\" in the Figure 10 table); each number is the median over the rounds (Figure 10: each phase's own median, so the stacked phases add up to about the median frame)",
        s.reps
    );
    let _ = writeln!(
        m,
        "- the perspective grid and the light grid are built in every frame (timed); the uniform grid and the BVH of the traced passes are built once per scene (their build times are listed, not in the frames)"
    );
    let _ = writeln!(
        m,
        "- on the threads: every phase. Work items (tiles, chunks) for the two traversals, the making of the shadow rays and shading; the grid builds and the rest of data rearrangement (light frustum, map, sort, chunking) as joined builds (`Workers::par`, rayon's broadcast), each thread taking a share of the triangles or rays"
    );
    let _ = writeln!(m, "- total time: {:.0} s\n", s.total_s);
    summary(&mut m, results, s);

    // Figure 10.
    let _ = writeln!(m, "## Figure 10: time per phase (ms)\n");
    let _ = writeln!(
        m,
        "Perspective-grid camera rays and light-grid shadows. Data rearrangement: making the shadow rays, the light frustum, mapping rays to light tiles, sorting, counting, chunking, compacting. Mrays/s: camera + shadow rays over the frame.\n"
    );
    let _ = writeln!(m, "![Figure 10](figure10.svg)\n");
    let _ = writeln!(
        m,
        "| scene | tris | primary build | primary traversal | data rearrangement | shadow build | shadow traversal | shade | frame | frames | shadow rays | Mrays/s | camera Mrays/s (traversal) |"
    );
    let _ = writeln!(m, "|---|--:|--:|--:|--:|--:|--:|--:|--:|--:|--:|--:|--:|");
    for r in results {
        let Some(c) = r.main() else { continue };
        let t = &c.times;
        let _ = writeln!(
            m,
            "| {} | {} | {} | {} | {} | {} | {} | {} | **{}** | {} | {} | {:.1} | {:.1} |",
            r.name,
            r.triangles,
            f2(t.primary_build),
            f2(t.primary_trace),
            f2(t.rearrange),
            f2(t.shadow_build),
            f2(t.shadow_trace),
            f2(t.shade),
            f2(c.frame_ns),
            c.frames,
            c.shadow_rays,
            run::mrays(w as u64 * h as u64 + c.shadow_rays, c.frame_ns),
            run::mrays(w as u64 * h as u64, t.primary_trace)
        );
    }
    let _ = writeln!(m);
    let _ = writeln!(m, "Grids of the frames above:\n");
    let _ = writeln!(
        m,
        "| scene | camera tiles | slices | camera pairs | pairs / mapped tri | light tiles | light pairs | light tiles used | chunks | most rays in a tile | hits |"
    );
    let _ = writeln!(m, "|---|--:|--:|--:|--:|--:|--:|--:|--:|--:|--:|");
    for r in results {
        let Some(c) = r.main() else { continue };
        let (ci, li, ro) = (&c.info.camera, &c.info.light, &c.info.reorder);
        let _ = writeln!(
            m,
            "| {} | {}x{} | {} | {} | {:.2} | {}x{} | {} | {} | {} | {} | {} |",
            r.name,
            ci.tiles[0],
            ci.tiles[1],
            ci.depth.count,
            ci.refs,
            ci.refs as f64 / ci.mapped.max(1) as f64,
            li.tiles[0],
            li.tiles[1],
            li.refs,
            ro.tiles_used,
            ro.chunks,
            ro.max_tile_rays,
            c.hits
        );
    }

    // Shadows: light grid vs packets.
    let _ = writeln!(m, "\n## Light-grid shadows vs shadow packets (ms)\n");
    let _ = writeln!(
        m,
        "Same frames: perspective-grid camera pass, same light. Shadow phase = data rearrangement + shadow build + shadow traversal; for packets (`ShadowPass::Traced`, packets from the light per {0}x{0} tracing tile, split in depth as the renderer does) the rearrangement is the making of the shadow rays and there is no build. Ratio < 1: the light grid is faster. \"differ\": pixels that differ from the light-grid image.\n",
        s.side
    );
    let _ = writeln!(m, "![shadows](shadows.svg)\n");
    let _ = writeln!(
        m,
        "| scene | light grid r={} | light grid r={WIDE_R} | CGT {1}x{1} | BVH Ranged {1}x{1} | BVH Partition {1}x{1} | best packets | light grid / best | differ (CGT / Ranged / Partition) |",
        pp.chunk, s.side
    );
    let _ = writeln!(m, "|---|--:|--:|--:|--:|--:|---|--:|---|");
    let mut ratios = Vec::new();
    for r in results {
        let Some(c) = r.main() else { continue };
        let cell = |x: Option<&CfgResult>| x.map_or("-".to_string(), |x| f2(x.shadow_ns));
        let best = r.best_packets();
        let ratio_v = best.map_or(0.0, |b| ratio(c.shadow_ns, b.shadow_ns));
        if best.is_some() {
            ratios.push(ratio_v);
        }
        let diff = |mm: Method| {
            r.shadow_packets(mm)
                .map_or("-".to_string(), |x| x.diff.to_string())
        };
        let _ = writeln!(
            m,
            "| {} | {} | {} | {} | {} | {} | {} | {:.2} | {} / {} / {} |",
            r.name,
            f2(c.shadow_ns),
            cell(r.wide()),
            cell(r.shadow_packets(Method::GridCgt)),
            cell(r.shadow_packets(Method::BvhRanged)),
            cell(r.shadow_packets(Method::BvhPartition)),
            best.map_or("-".to_string(), |b| shadow_label(&b.cfg.shadow)),
            ratio_v,
            diff(Method::GridCgt),
            diff(Method::BvhRanged),
            diff(Method::BvhPartition)
        );
    }
    if !ratios.is_empty() {
        let geo = (ratios.iter().map(|x| x.ln()).sum::<f64>() / ratios.len() as f64).exp();
        let wins = ratios.iter().filter(|&&x| x < 1.0).count();
        let _ = writeln!(
            m,
            "\nLight grid / best packets: geometric mean {geo:.2}, light grid faster on {wins} of {} scenes.",
            ratios.len()
        );
    }
    let _ = writeln!(m, "\nThe pieces (ms): rearrangement + build + traversal.\n");
    let _ = writeln!(
        m,
        "| scene | light grid r={} | light grid r={WIDE_R} | CGT | BVH Ranged | BVH Partition |",
        pp.chunk
    );
    let _ = writeln!(m, "|---|---|---|---|---|---|");
    for r in results {
        let Some(c) = r.main() else { continue };
        let p = |x: Option<&CfgResult>| {
            x.map_or("-".to_string(), |x| {
                format!(
                    "{} + {} + {}",
                    f2(x.times.rearrange),
                    f2(x.times.shadow_build),
                    f2(x.times.shadow_trace)
                )
            })
        };
        let _ = writeln!(
            m,
            "| {} | {} | {} | {} | {} | {} |",
            r.name,
            p(Some(c)),
            p(r.wide()),
            p(r.shadow_packets(Method::GridCgt)),
            p(r.shadow_packets(Method::BvhRanged)),
            p(r.shadow_packets(Method::BvhPartition))
        );
    }

    // Load balance.
    let _ = writeln!(m, "\n## Load balance of the light-grid pass\n");
    let _ = writeln!(
        m,
        "Work items of the shadow traversal are chunks of at most r rays of one light tile (paper section 4.3), timed one by one by `run::Threads`. The chunks are the same in every round, so each chunk's time here is its fastest over the rounds: a chunk preempted in one round (a scheduler slice is about 4 ms on this shared machine) is not counted slow. Slowest / mean: the slowest chunk over the mean chunk; raw: the same from single frames (median over the rounds), preemptions included; p99 / mean: the 99th-percentile chunk over the mean (median over the rounds). Busy: the threads' summed chunk time over threads x the pass's wall time (100 = no thread idle). r = {WIDE_R} barely splits tiles: a crowded tile is one long item.\n"
    );
    let _ = writeln!(
        m,
        "| scene | r | light tiles used | chunks | most rays in a tile | mean chunk ms | slowest chunk ms | slowest / mean | p99 / mean | raw slowest / mean | busy % | shadow traversal ms |"
    );
    let _ = writeln!(m, "|---|--:|--:|--:|--:|--:|--:|--:|--:|--:|--:|--:|");
    for r in results {
        for c in [r.main(), r.wide()].into_iter().flatten() {
            let _ = writeln!(
                m,
                "| {} | {} | {} | {} | {} | {:.3} | {:.3} | **{:.1}** | {:.1} | {:.1} | {:.0} | {} |",
                r.name,
                c.cfg.chunk,
                c.info.reorder.tiles_used,
                c.chunk_count,
                c.info.reorder.max_tile_rays,
                c.steady_mean_ns * 1e-6,
                ms(c.steady_max_ns),
                c.steady_imbalance,
                c.tail,
                c.imbalance,
                100.0 * c.efficiency,
                f2(c.times.shadow_trace)
            );
        }
    }

    // Camera pass.
    let _ = writeln!(m, "\n## Camera rays: perspective grid vs packets\n");
    let _ = writeln!(
        m,
        "Same camera, same rounds. Perspective grid: the baseline frames above, the grid built in every frame; traversal Mrays/s counts the traversal only, \"with build\" adds the per-frame build. The packets ({PACKET}x{PACKET}, Morton-ordered 2x2 quads, `PrimaryPass::Traced`) trace the prebuilt BVH (Ranged, Partition) and uniform grid (CGT) in frames without shadow rays (only the camera pass is compared); their builds, once per scene, are listed apart. \"differ\": pixels whose nearest triangle differs from the perspective grid's.\n"
    );
    let _ = writeln!(
        m,
        "| scene | pgrid build | pgrid traversal | Mrays/s | with build | BVH Ranged {PACKET}x{PACKET} | Mrays/s | BVH Partition {PACKET}x{PACKET} | Mrays/s | CGT {PACKET}x{PACKET} | Mrays/s | grid / BVH build (once) | differ (Ranged / Partition / CGT) |"
    );
    let _ = writeln!(m, "|---|--:|--:|--:|--:|--:|--:|--:|--:|--:|--:|---|---|");
    let px = w as u64 * h as u64;
    for r in results {
        let Some(c) = r.main() else { continue };
        let cam = |mm: Method| -> (String, String, String) {
            r.camera(mm)
                .map_or(("-".into(), "-".into(), "-".into()), |x| {
                    (
                        f2(x.times.primary_trace),
                        format!("{:.1}", run::mrays(px, x.times.primary_trace)),
                        x.diff.to_string(),
                    )
                })
        };
        let (rt, rm, rd) = cam(Method::BvhRanged);
        let (pt, pm, pd) = cam(Method::BvhPartition);
        let (ct, cm, cd) = cam(Method::GridCgt);
        let _ = writeln!(
            m,
            "| {} | {} | {} | {:.1} | {:.1} | {rt} | {rm} | {pt} | {pm} | {ct} | {cm} | {:.0} / {:.0} ms | {rd} / {pd} / {cd} |",
            r.name,
            f2(c.times.primary_build),
            f2(c.times.primary_trace),
            run::mrays(px, c.times.primary_trace),
            run::mrays(px, c.times.primary_trace + c.times.primary_build),
            ms(r.grid_build_ns),
            ms(r.bvh_build_ns)
        );
    }

    // Figure 11.
    let f11: Vec<&SceneResult> = results.iter().filter(|r| !r.fig11.is_empty()).collect();
    if !f11.is_empty() {
        let _ = writeln!(
            m,
            "\n## Figure 11: shadow time vs light distance, per chunk size r\n"
        );
        let _ = writeln!(
            m,
            "Shadow time = data rearrangement + shadow build + shadow traversal (ms, median of {} frames per point; each round runs every r in turn). {}x{} (half the size above, to keep the run short), the camera pass by BVH Ranged {PACKET}x{PACKET} packets (same hits, so the same shadow rays as after the perspective grid; it only saves time). The light moves from the model's bounding-box centre along a fixed direction (the view's up, tilted 0.3 to the right and 0.2 back), 0.25 to 8 bounding-box diagonals; \"occluded\": the share of shadow rays blocked (at r = {}). Beyond about half a diagonal the light is outside the model: for a closed room (conference) its roof then blocks every shadow ray.\n",
            fig11_reps(s.reps),
            fig11_size((w, h)).0,
            fig11_size((w, h)).1,
            pp.chunk
        );
        let _ = writeln!(m, "![Figure 11](figure11.svg)\n");
        for r in f11 {
            let _ = writeln!(
                m,
                "### {} ({} triangles, diagonal {:.1}, direction ({:.2}, {:.2}, {:.2}))\n",
                r.name, r.triangles, r.diagonal, r.fig11_dir.x, r.fig11_dir.y, r.fig11_dir.z
            );
            let mut head = "| diagonals | distance | shadow rays | occluded % |".to_string();
            let mut rule = "|--:|--:|--:|--:|".to_string();
            for rr in FIG11_R {
                let _ = write!(head, " r={rr} |");
                rule.push_str("--:|");
            }
            head.push_str(" chunks (r=32 .. 4096) | p99 / mean chunk (r=32 .. 4096) |");
            rule.push_str("---|---|");
            let _ = writeln!(m, "{head}\n{rule}");
            for row in &r.fig11 {
                let mut l = format!(
                    "| {:.2} | {:.1} | {} | {:.1} |",
                    row.diagonals,
                    row.distance,
                    row.shadow_rays,
                    100.0 * row.occluded as f64 / row.shadow_rays.max(1) as f64
                );
                let best = row.shadow_ns.iter().copied().min().unwrap_or(0);
                for &ns in &row.shadow_ns {
                    if ns == best {
                        let _ = write!(l, " **{}** |", f2(ns));
                    } else {
                        let _ = write!(l, " {} |", f2(ns));
                    }
                }
                let _ = write!(
                    l,
                    " {} | {} |",
                    row.chunks
                        .iter()
                        .map(|c| c.to_string())
                        .collect::<Vec<_>>()
                        .join(" / "),
                    row.imbalance
                        .iter()
                        .map(|c| format!("{c:.1}"))
                        .collect::<Vec<_>>()
                        .join(" / ")
                );
                let _ = writeln!(m, "{l}");
            }
            let _ = writeln!(m);
        }
    }

    // Images.
    let _ = writeln!(m, "\n## Frames\n");
    let _ = writeln!(
        m,
        "The pgrid + light-grid frame of each scene ({w}x{h}, one light, Lambert):\n"
    );
    let head = results
        .iter()
        .find(|r| r.name == "conference")
        .or_else(|| results.first());
    if let Some(r) = head {
        let _ = writeln!(m, "![{0}](frame_{0}.png)\n", r.name);
    }
    let others: Vec<String> = results
        .iter()
        .filter(|r| Some(r.name.as_str()) != head.map(|h| h.name.as_str()))
        .map(|r| format!("[{0}](frame_{0}.png)", r.name))
        .collect();
    if !others.is_empty() {
        let _ = writeln!(m, "Others: {}\n", others.join(", "));
    }
    let _ = writeln!(
        m,
        "Data: [pgrid.csv](pgrid.csv) (every configuration, medians per phase), [figure11.csv](figure11.csv); charts also as PNG: [figure10.png](figure10.png), [shadows.png](shadows.png), [figure11.png](figure11.png)."
    );
    m
}

fn geo_mean(v: &[f64]) -> f64 {
    let v: Vec<f64> = v.iter().copied().filter(|x| *x > 0.0).collect();
    if v.is_empty() {
        0.0
    } else {
        (v.iter().map(|x| x.ln()).sum::<f64>() / v.len() as f64).exp()
    }
}

/// `same` when no configuration of `role` differs from the baseline's
/// image, else the count of differing pixels and `differ`.
fn agree(results: &[SceneResult], role: Role, same: &str, differ: &str) -> String {
    let n: u64 = results
        .iter()
        .flat_map(|r| r.cfgs.iter())
        .filter(|c| c.cfg.role == role)
        .map(|c| c.diff)
        .sum();
    if n == 0 {
        same.to_string()
    } else {
        format!("{n} {differ} (summed over scenes and methods)")
    }
}

/// The headline numbers, computed from the tables below.
fn summary(m: &mut String, results: &[SceneResult], s: &Setup<'_>) {
    let mains: Vec<(&SceneResult, &CfgResult)> = results
        .iter()
        .filter_map(|r| r.main().map(|c| (r, c)))
        .collect();
    if mains.is_empty() {
        return;
    }
    let _ = writeln!(m, "## Summary\n");
    // Phase shares.
    let names = crate::cmd::phases(&PhaseTimes::default()).map(|(n, _)| n);
    let mut share = [0.0f64; 6];
    for (_, c) in &mains {
        let tot = c.times.total().max(1) as f64;
        for (k, (_, ns)) in crate::cmd::phases(&c.times).iter().enumerate() {
            share[k] += *ns as f64 / tot / mains.len() as f64;
        }
    }
    let (lo, hi) = mains.iter().fold((u64::MAX, 0), |(lo, hi), (_, c)| {
        (lo.min(c.frame_ns), hi.max(c.frame_ns))
    });
    let _ = writeln!(
        m,
        "- Figure 10: a {}x{} frame with perspective-grid camera rays and light-grid shadows takes {:.0} to {:.0} ms on {} threads; mean share of the frame: {}",
        s.w,
        s.h,
        ms(lo),
        ms(hi),
        s.threads,
        names
            .iter()
            .zip(share)
            .map(|(n, x)| format!("{n} {:.0} %", 100.0 * x))
            .collect::<Vec<_>>()
            .join(", ")
    );
    // Shadows.
    let lg: Vec<f64> = mains
        .iter()
        .filter_map(|(r, c)| r.best_packets().map(|b| ratio(c.shadow_ns, b.shadow_ns)))
        .collect();
    if !lg.is_empty() {
        let wins = lg.iter().filter(|&&x| x < 1.0).count();
        let trav: Vec<f64> = mains
            .iter()
            .filter_map(|(r, c)| {
                r.best_packets()
                    .map(|b| ratio(c.times.shadow_trace, b.times.shadow_trace))
            })
            .collect();
        let _ = writeln!(
            m,
            "- shadows: light grid (rearrangement + build + traversal) / the best shadow packets (BVH Ranged or Partition {0}x{0}): geometric mean {1:.2}, the light grid faster on {2} of {3} scenes; traversal alone: {4:.2}; {5}",
            s.side,
            geo_mean(&lg),
            wins,
            lg.len(),
            geo_mean(&trav),
            agree(
                results,
                Role::Packets,
                "every shadow-packet image equals the light-grid image",
                "pixels differ between the shadow-packet and light-grid images"
            )
        );
    }
    // Camera pass.
    let cam: Vec<(f64, f64)> = mains
        .iter()
        .filter_map(|(r, c)| {
            let best = [Method::BvhRanged, Method::BvhPartition, Method::GridCgt]
                .iter()
                .filter_map(|&mm| r.camera(mm))
                .min_by_key(|x| x.times.primary_trace)?;
            Some((
                ratio(c.times.primary_trace, best.times.primary_trace),
                ratio(
                    c.times.primary_trace + c.times.primary_build,
                    best.times.primary_trace,
                ),
            ))
        })
        .collect();
    if !cam.is_empty() {
        let a: Vec<f64> = cam.iter().map(|x| x.0).collect();
        let b: Vec<f64> = cam.iter().map(|x| x.1).collect();
        let _ = writeln!(
            m,
            "- camera rays: perspective-grid traversal / the best {PACKET}x{PACKET} packets on a prebuilt structure: geometric mean {:.2} ({:.2} with the per-frame build); {}",
            geo_mean(&a),
            geo_mean(&b),
            agree(
                results,
                Role::Camera,
                "the packets find the perspective grid's nearest triangle on every pixel",
                "pixels' nearest triangles differ between the packets and the perspective grid"
            )
        );
    }
    // Chunking.
    let pairs: Vec<(&CfgResult, &CfgResult)> = results
        .iter()
        .filter_map(|r| Some((r.main()?, r.wide()?)))
        .collect();
    if !pairs.is_empty() {
        let t: Vec<f64> = pairs
            .iter()
            .map(|(a, b)| ratio(a.times.shadow_trace, b.times.shadow_trace))
            .collect();
        let means = |f: &dyn Fn(&CfgResult) -> f64| {
            let a: Vec<f64> = pairs.iter().map(|(a, _)| f(a)).collect();
            let b: Vec<f64> = pairs.iter().map(|(_, b)| f(b)).collect();
            (geo_mean(&a), geo_mean(&b))
        };
        let (sa, sb) = means(&|c| c.steady_imbalance);
        let (pa, pb) = means(&|c| c.tail);
        let busy = |f: &dyn Fn(&(&CfgResult, &CfgResult)) -> f64| {
            pairs.iter().map(f).fold(f64::INFINITY, f64::min) * 100.0
        };
        let _ = writeln!(
            m,
            "- load balance (geometric means over the scenes): with r = {} the slowest chunk takes {:.1}x the mean chunk and the 99th-percentile chunk {:.1}x, against {:.1}x and {:.1}x with r = {WIDE_R}; shadow traversal time r = {} / r = {WIDE_R}: {:.2} on {} threads, threads busy at least {:.0} % of the pass (r = {WIDE_R}: {:.0} %)",
            s.pp.chunk,
            sa,
            pa,
            sb,
            pb,
            s.pp.chunk,
            geo_mean(&t),
            s.threads,
            busy(&|p| p.0.efficiency),
            busy(&|p| p.1.efficiency)
        );
    }
    // Figure 11.
    for r in results.iter().filter(|r| !r.fig11.is_empty()) {
        let n = FIG11_R.len();
        let small: Vec<f64> = r
            .fig11
            .iter()
            .map(|row| ratio(row.shadow_ns[0], row.shadow_ns[n - 1]))
            .collect();
        let first = r.fig11.first().map_or(0, |x| x.shadow_ns[n - 1]);
        let last = r.fig11.last().map_or(0, |x| x.shadow_ns[n - 1]);
        let _ = writeln!(
            m,
            "- Figure 11, {}: shadow time at r = {} / r = {}: geometric mean {:.2} over the {} light distances; from {:.2} to {:.2} diagonals the shadow time (r = {}) goes from {:.1} to {:.1} ms",
            r.name,
            FIG11_R[0],
            FIG11_R[n - 1],
            geo_mean(&small),
            r.fig11.len(),
            r.fig11.first().map_or(0.0, |x| x.diagonals),
            r.fig11.last().map_or(0.0, |x| x.diagonals),
            FIG11_R[n - 1],
            ms(first),
            ms(last)
        );
    }
    let _ = writeln!(m);
}

/// A CSV table: its header and records.
type Table = (Vec<String>, Vec<Vec<String>>);

/// pgrid.csv: every configuration of every scene, medians per phase.
fn csv(results: &[SceneResult]) -> Table {
    let head = "scene,triangles,view,config,primary,shadows,chunk,frames,primary_build_ms,primary_trace_ms,rearrange_ms,shadow_build_ms,shadow_trace_ms,shade_ms,frame_ms,shadow_ms,shadow_rays,hits,camera_refs,light_refs,light_tiles_used,chunks,max_tile_rays,chunk_mean_ms,chunk_max_ms,chunk_slowest_over_mean,chunk_p99_over_mean,chunk_slowest_steady_ms,chunk_slowest_over_mean_steady,threads_busy,pixels_differ"
        .split(',')
        .map(String::from)
        .collect();
    let mut records = Vec::new();
    for r in results {
        for c in &r.cfgs {
            let t = &c.times;
            records.push(vec![
                r.name.clone(),
                r.triangles.to_string(),
                r.view.clone(),
                c.cfg.label(),
                primary_label(&c.cfg.primary),
                if c.cfg.shadows {
                    shadow_label(&c.cfg.shadow)
                } else {
                    "none".into()
                },
                c.cfg.chunk.to_string(),
                c.frames.to_string(),
                format!("{:.4}", ms(t.primary_build)),
                format!("{:.4}", ms(t.primary_trace)),
                format!("{:.4}", ms(t.rearrange)),
                format!("{:.4}", ms(t.shadow_build)),
                format!("{:.4}", ms(t.shadow_trace)),
                format!("{:.4}", ms(t.shade)),
                format!("{:.4}", ms(c.frame_ns)),
                format!("{:.4}", ms(c.shadow_ns)),
                c.shadow_rays.to_string(),
                c.hits.to_string(),
                c.info.camera.refs.to_string(),
                c.info.light.refs.to_string(),
                c.info.reorder.tiles_used.to_string(),
                c.chunk_count.to_string(),
                c.info.reorder.max_tile_rays.to_string(),
                format!("{:.5}", c.chunk_mean_ns * 1e-6),
                format!("{:.5}", ms(c.chunk_max_ns)),
                format!("{:.3}", c.imbalance),
                format!("{:.3}", c.tail),
                format!("{:.5}", ms(c.steady_max_ns)),
                format!("{:.3}", c.steady_imbalance),
                format!("{:.3}", c.efficiency),
                c.diff.to_string(),
            ]);
        }
    }
    (head, records)
}

/// figure11.csv: shadow time per light distance and chunk size r.
fn csv_fig11(results: &[SceneResult]) -> Table {
    let head =
        "scene,diagonals,distance,shadow_rays,occluded,chunk,shadow_ms,chunks,chunk_p99_over_mean"
            .split(',')
            .map(String::from)
            .collect();
    let mut records = Vec::new();
    for r in results {
        for row in &r.fig11 {
            for (j, rr) in FIG11_R.iter().enumerate() {
                records.push(vec![
                    r.name.clone(),
                    format!("{:.3}", row.diagonals),
                    format!("{:.3}", row.distance),
                    row.shadow_rays.to_string(),
                    row.occluded.to_string(),
                    rr.to_string(),
                    format!("{:.4}", ms(row.shadow_ns[j])),
                    row.chunks[j].to_string(),
                    format!("{:.3}", row.imbalance[j]),
                ]);
            }
        }
    }
    (head, records)
}

// ---------------------------------------------------------------------------
// Charts

mod charts {
    use super::{FIG11_R, FONT, Method, SceneResult, Setup, WIDE_R};
    use crate::cmd::phases;
    use crate::run::ms;
    use crate::studies::common::save_chart as save;
    use anyhow::Result;
    use plotters::coord::Shift;
    use plotters::prelude::*;
    use std::path::Path;

    const TITLE_H: u32 = 40;

    fn title<DB: DrawingBackend>(
        root: &DrawingArea<DB, Shift>,
        t: &str,
    ) -> Result<DrawingArea<DB, Shift>>
    where
        DB::ErrorType: 'static,
    {
        root.fill(&WHITE)?;
        let (head, body) = root.split_vertically(TITLE_H);
        head.draw(&Text::new(t.to_string(), (12, 10), (FONT, 18).into_font()))?;
        Ok(body)
    }

    /// Phase colours, bottom to top (the paper's legend order).
    const PHASE_COLOURS: [RGBColor; 6] = [
        RGBColor(31, 119, 180),
        RGBColor(174, 199, 232),
        RGBColor(255, 127, 14),
        RGBColor(44, 160, 44),
        RGBColor(214, 39, 40),
        RGBColor(148, 103, 189),
    ];

    /// A bar chart over `scenes`: per scene a value per series in `values`,
    /// stacked when `stacked` (their sum above each bar with `totals`),
    /// else side by side; the y axis in `ylabel`.
    struct Bars<'a> {
        caption: &'a str,
        scenes: &'a [String],
        series: &'a [(String, RGBColor)],
        values: &'a [Vec<f64>],
        stacked: bool,
        ylabel: &'a str,
        totals: bool,
    }

    /// Draw `chart` on `area`.
    fn bars<DB: DrawingBackend>(area: &DrawingArea<DB, Shift>, chart: &Bars<'_>) -> Result<()>
    where
        DB::ErrorType: 'static,
    {
        let Bars {
            caption,
            scenes,
            series,
            values,
            stacked,
            ylabel,
            totals,
        } = *chart;
        let n = scenes.len().max(1);
        let top = values
            .iter()
            .map(|v| {
                if stacked {
                    v.iter().sum::<f64>()
                } else {
                    v.iter().copied().fold(0.0, f64::max)
                }
            })
            .fold(1e-3, f64::max)
            * 1.15;
        // Room on the right for the legend.
        let xmax = n as f64 + 1.3;
        let mut c = ChartBuilder::on(area)
            .caption(caption, (FONT, 15))
            .margin(12)
            .x_label_area_size(34)
            .y_label_area_size(60)
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
            .y_desc(ylabel)
            .label_style((FONT, 12))
            .axis_desc_style((FONT, 13))
            .draw()?;
        let k = series.len().max(1) as f64;
        for (j, (label, colour)) in series.iter().enumerate() {
            let colour = *colour;
            let rects: Vec<Rectangle<(f64, f64)>> = values
                .iter()
                .enumerate()
                .map(|(i, v)| {
                    let val = v.get(j).copied().unwrap_or(0.0);
                    if stacked {
                        let base: f64 = v[..j.min(v.len())].iter().sum();
                        Rectangle::new(
                            [(i as f64 + 0.2, base), (i as f64 + 0.8, base + val)],
                            colour.filled(),
                        )
                    } else {
                        let bw = 0.8 / k;
                        let x0 = i as f64 + 0.1 + j as f64 * bw;
                        Rectangle::new([(x0, 0.0), (x0 + bw * 0.92, val)], colour.filled())
                    }
                })
                .collect();
            c.draw_series(rects)?
                .label(label.clone())
                .legend(move |(x, y)| {
                    Rectangle::new([(x, y - 5), (x + 14, y + 5)], colour.filled())
                });
            if !stacked {
                let bw = 0.8 / k;
                c.draw_series(values.iter().enumerate().map(|(i, v)| {
                    let val = v.get(j).copied().unwrap_or(0.0);
                    let x0 = i as f64 + 0.1 + j as f64 * bw;
                    Text::new(
                        if val < 10.0 {
                            format!("{val:.1}")
                        } else {
                            format!("{val:.0}")
                        },
                        (x0, val + top * 0.012),
                        (FONT, 9).into_font(),
                    )
                }))?;
            }
        }
        if stacked && totals {
            c.draw_series(values.iter().enumerate().map(|(i, v)| {
                let t: f64 = v.iter().sum();
                Text::new(
                    format!("{t:.1}"),
                    (i as f64 + 0.3, t + top * 0.015),
                    (FONT, 11).into_font(),
                )
            }))?;
        }
        c.configure_series_labels()
            .position(SeriesLabelPosition::UpperRight)
            .background_style(WHITE.mix(0.85))
            .border_style(BLACK.mix(0.4))
            .label_font((FONT, 12))
            .draw()?;
        Ok(())
    }

    fn fig10_data(results: &[SceneResult]) -> (Vec<String>, Vec<Vec<f64>>) {
        let mut scenes = Vec::new();
        let mut values = Vec::new();
        for r in results {
            if let Some(c) = r.main() {
                scenes.push(r.name.clone());
                values.push(phases(&c.times).iter().map(|(_, ns)| ms(*ns)).collect());
            }
        }
        (scenes, values)
    }

    pub(super) fn figure10(
        results: &[SceneResult],
        s: &Setup<'_>,
        svg: &Path,
        png: &Path,
    ) -> Result<()> {
        let (scenes, values) = fig10_data(results);
        let series: Vec<(String, RGBColor)> = phases(&Default::default())
            .iter()
            .zip(PHASE_COLOURS)
            .map(|((n, _), c)| (n.to_string(), c))
            .collect();
        let t = format!(
            "sheaf Figure 10: time per phase, perspective grid + light grid, {}x{}, {} threads",
            s.w, s.h, s.threads
        );
        let size = (150 * scenes.len() as u32 + 420, 560);
        let chart = Bars {
            caption: "ms per frame: each phase's median, stacked (their sum above each bar)",
            scenes: &scenes,
            series: &series,
            values: &values,
            stacked: true,
            ylabel: "ms",
            totals: true,
        };
        save(
            size,
            svg,
            png,
            |root| {
                let body = title(&root, &t)?;
                bars(&body, &chart)?;
                Ok(root.present()?)
            },
            |root| {
                let body = title(&root, &t)?;
                bars(&body, &chart)?;
                Ok(root.present()?)
            },
        )
    }

    pub(super) fn shadows(
        results: &[SceneResult],
        s: &Setup<'_>,
        svg: &Path,
        png: &Path,
    ) -> Result<()> {
        let mut scenes = Vec::new();
        let mut values = Vec::new();
        for r in results {
            let Some(c) = r.main() else { continue };
            scenes.push(r.name.clone());
            let v = |x: Option<&super::CfgResult>| x.map_or(0.0, |x| ms(x.shadow_ns));
            values.push(vec![
                ms(c.shadow_ns),
                v(r.wide()),
                v(r.shadow_packets(Method::GridCgt)),
                v(r.shadow_packets(Method::BvhRanged)),
                v(r.shadow_packets(Method::BvhPartition)),
            ]);
        }
        let n = s.side;
        let series = vec![
            (
                format!("light grid r={}", s.pp.chunk),
                RGBColor(214, 39, 40),
            ),
            (format!("light grid r={WIDE_R}"), RGBColor(252, 146, 114)),
            (format!("CGT {n}x{n} packets"), RGBColor(44, 160, 44)),
            (format!("BVH Ranged {n}x{n}"), RGBColor(33, 113, 181)),
            (format!("BVH Partition {n}x{n}"), RGBColor(158, 202, 225)),
        ];
        let t = format!(
            "sheaf shadow rays: light grid vs shadow packets, {}x{}, {} threads",
            s.w, s.h, s.threads
        );
        let size = (190 * scenes.len() as u32 + 420, 560);
        let chart = Bars {
            caption: "shadow phase ms (rearrangement + build + traversal), lower is better",
            scenes: &scenes,
            series: &series,
            values: &values,
            stacked: false,
            ylabel: "ms",
            totals: false,
        };
        save(
            size,
            svg,
            png,
            |root| {
                let body = title(&root, &t)?;
                bars(&body, &chart)?;
                Ok(root.present()?)
            },
            |root| {
                let body = title(&root, &t)?;
                bars(&body, &chart)?;
                Ok(root.present()?)
            },
        )
    }

    const R_COLOURS: [RGBColor; 5] = [
        RGBColor(103, 0, 13),
        RGBColor(214, 39, 40),
        RGBColor(255, 127, 14),
        RGBColor(44, 160, 44),
        RGBColor(31, 119, 180),
    ];

    fn fig11_panel<DB: DrawingBackend>(area: &DrawingArea<DB, Shift>, r: &SceneResult) -> Result<()>
    where
        DB::ErrorType: 'static,
    {
        let top = r
            .fig11
            .iter()
            .flat_map(|row| row.shadow_ns.iter().map(|&ns| ms(ns)))
            .fold(1e-3, f64::max)
            * 1.1;
        // x: log2 of the distance, labelled in diagonals.
        let lo = r.fig11.first().map_or(0.25, |x| x.diagonals).log2() - 0.25;
        let hi = r.fig11.last().map_or(8.0, |x| x.diagonals).log2() + 0.25;
        let mut c = ChartBuilder::on(area)
            .caption(
                format!("{} ({} triangles)", r.name, r.triangles),
                (FONT, 15),
            )
            .margin(12)
            .x_label_area_size(40)
            .y_label_area_size(56)
            .build_cartesian_2d(lo..hi, 0.0..top)?;
        c.configure_mesh()
            .x_desc("light distance from the model centre (scene diagonals, log scale)")
            .y_desc("shadow ms")
            .x_labels(((hi - lo).ceil() as usize) + 1)
            .x_label_formatter(&|x| {
                let v = 2f64.powf(*x);
                if v < 1.0 {
                    format!("{v:.2}")
                } else {
                    format!("{v:.0}")
                }
            })
            .light_line_style(RGBColor(236, 236, 236))
            .label_style((FONT, 12))
            .axis_desc_style((FONT, 13))
            .draw()?;
        for (j, rr) in FIG11_R.iter().enumerate() {
            let colour = R_COLOURS[j % R_COLOURS.len()];
            let pts: Vec<(f64, f64)> = r
                .fig11
                .iter()
                .map(|row| (row.diagonals.log2(), ms(row.shadow_ns[j])))
                .collect();
            c.draw_series(LineSeries::new(pts.clone(), colour.stroke_width(2)))?
                .label(format!("r = {rr}"))
                .legend(move |(x, y)| {
                    PathElement::new(vec![(x, y), (x + 16, y)], colour.stroke_width(2))
                });
            c.draw_series(pts.iter().map(|&p| Circle::new(p, 3, colour.filled())))?;
        }
        c.configure_series_labels()
            .position(SeriesLabelPosition::UpperRight)
            .background_style(WHITE.mix(0.85))
            .border_style(BLACK.mix(0.4))
            .label_font((FONT, 12))
            .draw()?;
        Ok(())
    }

    fn fig11_draw<DB: DrawingBackend>(
        root: DrawingArea<DB, Shift>,
        rs: &[&SceneResult],
        t: &str,
    ) -> Result<()>
    where
        DB::ErrorType: 'static,
    {
        let body = title(&root, t)?;
        let panels = body.split_evenly((1, rs.len().max(1)));
        for (p, r) in panels.iter().zip(rs) {
            fig11_panel(p, r)?;
        }
        Ok(root.present()?)
    }

    pub(super) fn figure11(
        results: &[SceneResult],
        s: &Setup<'_>,
        svg: &Path,
        png: &Path,
    ) -> Result<()> {
        let rs: Vec<&SceneResult> = results.iter().filter(|r| !r.fig11.is_empty()).collect();
        let t = format!(
            "sheaf Figure 11: shadow time vs light distance per chunk size r, {}x{}, {} threads",
            super::fig11_size((s.w, s.h)).0,
            super::fig11_size((s.w, s.h)).1,
            s.threads
        );
        let size = (620 * rs.len().max(1) as u32, 520);
        save(
            size,
            svg,
            png,
            |root| fig11_draw(root, &rs, &t),
            |root| fig11_draw(root, &rs, &t),
        )
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::TestArg;

    /// A tiny run end to end: every file is written, every configuration
    /// ran on every scene, the images and hits agree with the baseline,
    /// Figure 11 falls back to the scenes run.
    #[test]
    fn tiny_run_writes_every_output() {
        let dir = std::env::temp_dir().join(format!("sheaf-pgrid-test-{}", std::process::id()));
        let a = BenchArgs {
            scenes: vec!["tetra".into(), "animated".into()],
            scenes_dir: None,
            size: Some((48, 32)),
            quick: true,
            packets: vec![],
            tests: vec![TestArg::Mt],
            threads: vec![2],
            ablation: false,
            reps: Some(1),
            oracle_budget: None,
            lambda: 5.0,
            macrocell: 6,
            out_dir: Some(dir.clone()),
            whitted: false,
            entry: false,
            pgrid: true,
            stress: false,
            pgrid_opts: Default::default(),
            structures: vec![],
        };
        crate::studies::bench(&a).unwrap();
        let csv = std::fs::read_to_string(dir.join("pgrid.csv")).unwrap();
        let lines: Vec<&str> = csv.lines().collect();
        let n = configs(&PgridParams::default(), 16).len();
        assert_eq!(
            lines.len(),
            1 + 2 * n,
            "header + 2 scenes x {n} configurations"
        );
        let differ = lines[0]
            .split(',')
            .position(|c| c == "pixels_differ")
            .unwrap();
        for l in &lines[1..] {
            assert_eq!(l.split(',').nth(differ), Some("0"), "{l}");
        }
        let f11 = std::fs::read_to_string(dir.join("figure11.csv")).unwrap();
        assert_eq!(f11.lines().count(), 1 + 2 * FIG11_STEPS * FIG11_R.len());
        for f in [
            "README.md",
            "figure10.svg",
            "figure10.png",
            "shadows.svg",
            "shadows.png",
            "figure11.svg",
            "figure11.png",
            "frame_tetra.png",
            "frame_animated.png",
        ] {
            assert!(dir.join(f).is_file(), "{f} missing");
        }
        let _ = std::fs::remove_dir_all(&dir);
    }

    #[test]
    fn distances_and_medians() {
        let d = fig11_distances();
        assert_eq!(d.len(), FIG11_STEPS);
        assert!((d[0] - FIG11_NEAR).abs() < 1e-9 && (d[FIG11_STEPS - 1] - FIG11_FAR).abs() < 1e-9);
        assert_eq!(median(vec![3, 1, 2]), 2);
        assert_eq!(median(vec![4, 1, 2, 3]), 2);
        assert_eq!(median(vec![]), 0);
        assert_eq!(med_f(vec![1.0, 3.0]), 2.0);
    }
}
