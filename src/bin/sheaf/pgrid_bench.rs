//! `sheaf bench --pgrid`: the perspective/light grid paper's section 5 on
//! our scenes (papers/perspective-and-light-grids.txt), as deferred frames
//! (`render::deferred`) whose work items run on `run::Threads`.
//!
//! Per scene (the built-in scenes and the OBJ scenes of `--scenes-dir`),
//! the scene's reference view (`bench::view_for`) at 1024x1024 (the paper's
//! resolution) with its default light, default `PgridParams` (or the
//! `--pgrid-tile`, `--chunk`, ... given):
//! - Figure 10: ms per phase of a frame with perspective-grid camera rays
//!   and light-grid shadows (primary build, primary traversal, data
//!   rearrangement, shadow build, shadow traversal, shade), each phase the
//!   median over `--reps` frames; Mrays/s of camera plus shadow rays.
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
//!   packets on prebuilt structures (their build times listed apart).
//! - Figure 11: shadow time (rearrange + shadow build + shadow traversal)
//!   against the light's distance from the model's centre, 0.25 to 8 scene
//!   diagonals in 8 geometric steps, along a fixed direction (mostly up),
//!   for chunk sizes r = 32, 64, 256, 1024, 4096, on conference and sponza
//!   (or the two largest scenes run).
//!
//! Frames are timed in rounds, one frame per configuration per round after
//! an untimed round, so load spells on a shared machine hit all alike;
//! every configuration's first image is compared pixel for pixel with the
//! pgrid + light-grid frame's.
#![forbid(unsafe_code)]

use crate::bench::{SceneSpec, command_line, machine_line, median, scene_specs, view_for};
use crate::cmd::{phases, primary_label, shadow_label};
use crate::load;
use crate::run::{self, DeferredSetup, ItemTimes, Threads, ms};
use crate::{BenchArgs, Failure, OrFail, TestArg};
use glam::Vec3;
use sheaf::render::deferred::{PhaseTimes, tile_side};
use sheaf::trace::RayKind;
use sheaf::{
    Camera, DeferredInfo, DeferredJob, Frame, GridParams, Method, OwnedContext, PgridParams,
    PointLight, PrimaryPass, ShadowPass, Shading, TraceParams,
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
/// The chunk size with little splitting, for the load-balance comparison.
const WIDE_R: u32 = 4096;
/// Packet side of the traced camera passes.
const PACKET: u32 = 16;

fn fig11_distances() -> Vec<f64> {
    (0..FIG11_STEPS)
        .map(|i| {
            FIG11_NEAR * (FIG11_FAR / FIG11_NEAR).powf(i as f64 / (FIG11_STEPS - 1) as f64)
        })
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
}

impl Config {
    fn label(&self) -> String {
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
#[derive(Clone, Copy, Debug, Default)]
struct Sample {
    info: DeferredInfo,
    /// Item times of the shadow pass (its chunks with the light grid).
    chunks: ItemTimes,
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
    efficiency: f64,
    /// Pixels that differ from the pgrid + light-grid frame's.
    diff: u64,
}

fn med_f(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    v.get(v.len() / 2).copied().unwrap_or(0.0)
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
        let last = s.last().copied().unwrap_or_default();
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
            efficiency: med_f(s.iter().map(|x| x.chunks.efficiency()).collect()),
            diff,
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
    /// Median shadow ms per r of `FIG11_R`, and the chunk counts.
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
    fn frame(&mut self, cfg: &Config) -> Result<Sample, Failure> {
        if self.setup.pgrid.chunk != cfg.chunk {
            self.setup.pgrid.chunk = cfg.chunk;
            self.ctx
                .build_pgrid(self.setup.scene, &self.setup.pgrid)
                .or_fail(|| "loading the scene for the perspective grids".into())?;
        }
        let job = DeferredJob {
            frame: &self.frame,
            lights: &[],
            primary: cfg.primary,
            shadow: cfg.shadow,
        };
        let (info, grown) = self
            .setup
            .render(&mut self.ctx, &job, &mut self.pixels, &mut self.workers)?;
        self.grown |= grown;
        let chunks = if self.frame.shading.shadows && self.workers.runs.len() >= 2 {
            self.workers.runs.last().copied().unwrap_or_default()
        } else {
            ItemTimes::default()
        };
        Ok(Sample { info, chunks })
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
    a.chunks(4)
        .zip(b.chunks(4))
        .filter(|(p, q)| p != q)
        .count() as u64
}

/// `sheaf bench --pgrid`.
pub fn run(a: &BenchArgs) -> Result<(), Failure> {
    let start = Instant::now();
    let (w, h) = a
        .size
        .unwrap_or(if a.quick { (256, 256) } else { (1024, 1024) });
    let hw = std::thread::available_parallelism().map_or(1, |n| n.get() as u32);
    let threads = a.threads.iter().copied().max().unwrap_or(hw);
    if !(1..=64).contains(&threads) {
        return Err(Failure("--threads: each must be in 1..=64".into()));
    }
    let reps = a.reps.unwrap_or(if a.quick { 1 } else { 3 }).max(1);
    let test = match a.tests.first() {
        Some(TestArg::Watertight) => sheaf::TriTest::Watertight,
        Some(TestArg::Projection) => sheaf::TriTest::Projection,
        _ => sheaf::TriTest::MollerTrumbore,
    };
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
    std::fs::create_dir_all(&out_dir).or_fail(|| format!("cannot create {}", out_dir.display()))?;
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
    println!(
        "sheaf bench --pgrid: {} scenes, {w}x{h}, {threads} threads, {} configurations per scene, median of {reps} frames after an untimed one, PgridParams {{ tile {}, group {}, slices {}, light tiles {}, light slices {}, chunk r {} }}, {test:?}, machine: {machine}",
        specs.len(),
        cfgs.len(),
        pp.tile,
        pp.group,
        pp.slices,
        pp.light_tiles,
        pp.light_slices,
        pp.chunk
    );
    let mut results: Vec<SceneResult> = Vec::new();
    // Scenes for Figure 11 when neither named one runs: after the others,
    // the two largest (re-run then).
    let mut deferred_fig11: Vec<(usize, SceneSpec)> = Vec::new();
    for spec in &specs {
        let fig11 = fig11_names.contains(&spec.name);
        match scene(spec, (w, h), threads, reps, &grid, &pp, &cfgs, fig11, &out_dir)? {
            Some(r) => {
                if fig11_names.is_empty() {
                    deferred_fig11.push((r.triangles as usize, SceneSpec {
                        name: spec.name.clone(),
                        load: spec.load.clone(),
                    }));
                }
                results.push(r);
            }
            None => continue,
        }
    }
    if fig11_names.is_empty() && !deferred_fig11.is_empty() {
        deferred_fig11.sort_by_key(|(n, _)| std::cmp::Reverse(*n));
        deferred_fig11.truncate(2);
        println!(
            "note: conference and sponza did not run: Figure 11 on {}",
            deferred_fig11
                .iter()
                .map(|(_, s)| s.name.as_str())
                .collect::<Vec<_>>()
                .join(", ")
        );
        for (_, spec) in &deferred_fig11 {
            if let Some(r) = scene(spec, (w, h), threads, reps, &grid, &pp, &[], true, &out_dir)? {
                if let Some(x) = results.iter_mut().find(|x| x.name == r.name) {
                    x.fig11 = r.fig11;
                    x.fig11_dir = r.fig11_dir;
                    x.diagonal = r.diagonal;
                }
            }
        }
    }
    if results.is_empty() {
        return Err(Failure("no scene ran".into()));
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
    std::fs::write(&md_path, &md).or_fail(|| format!("cannot write {}", md_path.display()))?;
    let csv_path = out_dir.join("pgrid.csv");
    std::fs::write(&csv_path, csv(&results)).or_fail(|| format!("cannot write {}", csv_path.display()))?;
    let csv11 = out_dir.join("figure11.csv");
    std::fs::write(&csv11, csv_fig11(&results)).or_fail(|| format!("cannot write {}", csv11.display()))?;
    charts::figure10(&results, &setup, &out_dir.join("figure10.svg"), &out_dir.join("figure10.png"))?;
    charts::shadows(&results, &setup, &out_dir.join("shadows.svg"), &out_dir.join("shadows.png"))?;
    if results.iter().any(|r| !r.fig11.is_empty()) {
        charts::figure11(&results, &setup, &out_dir.join("figure11.svg"), &out_dir.join("figure11.png"))?;
    }
    println!(
        "wrote {}, pgrid.csv, figure11.csv, figure10.svg/png, shadows.svg/png{} in {} ({:.0} s)",
        md_path.display(),
        if results.iter().any(|r| !r.fig11.is_empty()) { ", figure11.svg/png" } else { "" },
        out_dir.display(),
        start.elapsed().as_secs_f64()
    );
    Ok(())
}

/// The configurations of a scene, the baseline first.
fn configs(pp: &PgridParams, side: u32) -> Vec<Config> {
    let shadow = |m: Method| {
        ShadowPass::Traced(TraceParams::bvh(m, side).with_kind(RayKind::Shadow))
    };
    let camera = |m: Method| {
        PrimaryPass::Traced(TraceParams::bvh(m, PACKET).with_kind(RayKind::Primary))
    };
    let mut v = vec![Config {
        role: Role::Main,
        primary: PrimaryPass::Pgrid,
        shadow: ShadowPass::LightGrid,
        chunk: pp.chunk,
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
        });
    }
    for m in [Method::BvhRanged, Method::BvhPartition, Method::GridCgt] {
        v.push(Config {
            role: Role::Camera,
            primary: camera(m),
            shadow: ShadowPass::LightGrid,
            chunk: pp.chunk,
        });
    }
    v
}

/// One scene: load, build, the configurations in rounds, Figure 11 when
/// `fig11`. None: skipped (with a note).
#[allow(clippy::too_many_arguments)]
fn scene(
    spec: &SceneSpec,
    (w, h): (u32, u32),
    threads: u32,
    reps: u32,
    grid: &GridParams,
    pp: &PgridParams,
    cfgs: &[Config],
    fig11: bool,
    out_dir: &Path,
) -> Result<Option<SceneResult>, Failure> {
    let t_load = Instant::now();
    let loaded = match load::load(&spec.load) {
        Ok(l) => l,
        Err(e) => {
            println!("note: {}: {e}, skipped", spec.name);
            return Ok(None);
        }
    };
    let scene = loaded.scene()?;
    if scene.triangle_count() == 0 {
        println!("note: {}: no triangles, skipped", spec.name);
        return Ok(None);
    }
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
        println!(
            "note: {}: every triangle is degenerate or non-finite, skipped",
            spec.name
        );
        return Ok(None);
    }
    let grid_build_ns = ctx.stats().build_ns;
    let bvh_build_ns = ctx.stats().bvh_build_ns;
    let (v, light, how) = view_for(&loaded, &ctx.tracer()?, &info.bounds, w, h);
    let frame = Frame {
        camera: Camera {
            eye: v.eye.to_array(),
            look_at: v.look_at.to_array(),
            up: v.up.to_array(),
            fov_y_deg: v.fov_y_deg,
        },
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
    println!(
        "[{}] {} triangles, loaded in {load_s:.1} s; grid {} build {:.0} ms, BVH build {:.0} ms; view {how}",
        spec.name,
        info.triangles,
        run::res(&info),
        ms(grid_build_ns),
        ms(bvh_build_ns)
    );
    let mut b = Bench {
        setup,
        ctx,
        workers: Threads::new(threads),
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

    // The configurations: an untimed round (images compared), then `reps`
    // timed rounds.
    if !cfgs.is_empty() {
        let mut reference: Vec<u8> = Vec::new();
        let mut diffs = vec![0u64; cfgs.len()];
        for (i, c) in cfgs.iter().enumerate() {
            b.frame(c)?;
            if i == 0 {
                reference = b.pixels.clone();
                let path = out_dir.join(format!("frame_{}.png", spec.name));
                run::write_png(&path, &b.pixels, w, h)?;
            } else {
                diffs[i] = diff_pixels(&reference, &b.pixels);
            }
        }
        let mut samples: Vec<Vec<Sample>> = vec![Vec::new(); cfgs.len()];
        for _ in 0..reps {
            for (i, c) in cfgs.iter().enumerate() {
                samples[i].push(b.frame(c)?);
            }
        }
        for (i, c) in cfgs.iter().enumerate() {
            let r = CfgResult::new(*c, &samples[i], diffs[i]);
            println!("[{}] {}", spec.name, progress(&r, w, h));
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
        let base = Config {
            role: Role::Main,
            primary: PrimaryPass::Pgrid,
            shadow: ShadowPass::LightGrid,
            chunk: pp.chunk,
        };
        for k in fig11_distances() {
            let d = diag * k as f32;
            b.frame.light.position = (c + dir * d).to_array();
            // Untimed: the occlusion share at the chosen r.
            let s0 = b.frame(&base)?;
            let occluded = b.occluded();
            let mut samples: Vec<Vec<Sample>> = vec![Vec::new(); FIG11_R.len()];
            for _ in 0..reps {
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
                    .map(|s| med_f(s.iter().map(|x| x.chunks.imbalance()).collect()))
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
            println!("{line}");
            res.fig11.push(row);
        }
        b.frame.light.position = light.to_array();
    }
    if b.grown {
        println!(
            "[{}] note: perspective grid pools grown to {} cells, {} pairs",
            spec.name,
            b.ctx.limits().pgrid_cells(),
            b.ctx.limits().pgrid_refs()
        );
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
    if r.cfg.shadow == ShadowPass::LightGrid {
        let _ = write!(
            s,
            "; {} chunks, slowest/mean {:.2}, busy {:.0} %",
            r.chunk_count,
            r.imbalance,
            100.0 * r.efficiency
        );
    }
    if r.diff > 0 {
        let _ = write!(s, "; {} pixels differ from the pgrid/light-grid frame", r.diff);
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

fn ratio(a: u64, b: u64) -> f64 {
    if b == 0 { 0.0 } else { a as f64 / b as f64 }
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
        pp.tile, pp.group, s.side, s.side, pp.slices, pp.light_tiles, pp.light_tiles, pp.light_slices, pp.chunk, s.test
    );
    let _ = writeln!(
        m,
        "- timing: rounds of one frame per configuration (so load spells on the shared machine hit all alike) after an untimed round; each number is the median over {} rounds (Figure 10: each phase's own median, so the stacked phases add up to about the median frame)",
        s.reps
    );
    let _ = writeln!(
        m,
        "- the perspective grid and the light grid are built in every frame (timed); the uniform grid and the BVH of the traced passes are built once per scene (their build times are listed, not in the frames)"
    );
    let _ = writeln!(
        m,
        "- single-threaded phases in this version of `render_deferred`: primary build, data rearrangement, shadow build and shade; the two traversals run on the threads"
    );
    let _ = writeln!(m, "- total time: {:.0} s\n", s.total_s);

    // Figure 10.
    let _ = writeln!(m, "## Figure 10: time per phase (ms)\n");
    let _ = writeln!(
        m,
        "Perspective-grid camera rays and light-grid shadows. Data rearrangement: making the shadow rays, the light frustum, mapping rays to light tiles, sorting, counting, chunking, compacting. Mrays/s: camera + shadow rays over the frame.\n"
    );
    let _ = writeln!(m, "![Figure 10](figure10.svg)\n");
    let _ = writeln!(
        m,
        "| scene | tris | primary build | primary traversal | data rearrangement | shadow build | shadow traversal | shade | frame | shadow rays | Mrays/s | camera Mrays/s (traversal) |"
    );
    let _ = writeln!(m, "|---|--:|--:|--:|--:|--:|--:|--:|--:|--:|--:|--:|");
    for r in results {
        let Some(c) = r.main() else { continue };
        let t = &c.times;
        let _ = writeln!(
            m,
            "| {} | {} | {} | {} | {} | {} | {} | {} | **{}** | {} | {:.1} | {:.1} |",
            r.name,
            r.triangles,
            f2(t.primary_build),
            f2(t.primary_trace),
            f2(t.rearrange),
            f2(t.shadow_build),
            f2(t.shadow_trace),
            f2(t.shade),
            f2(c.frame_ns),
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
        let diff = |mm: Method| r.shadow_packets(mm).map_or("-".to_string(), |x| x.diff.to_string());
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
        "Work items of the shadow traversal are chunks of at most r rays of one light tile (paper section 4.3). Slowest / mean: the slowest chunk's time over the mean chunk time (`run::Threads` item timing). Busy: the threads' summed chunk time over threads x the pass's wall time (1 = no thread idle). r = {WIDE_R} barely splits tiles: a crowded tile is one long item.\n"
    );
    let _ = writeln!(
        m,
        "| scene | r | light tiles used | chunks | most rays in a tile | mean chunk ms | slowest chunk ms | slowest / mean | busy % | shadow traversal ms |"
    );
    let _ = writeln!(m, "|---|--:|--:|--:|--:|--:|--:|--:|--:|--:|");
    for r in results {
        for c in [r.main(), r.wide()].into_iter().flatten() {
            let _ = writeln!(
                m,
                "| {} | {} | {} | {} | {} | {:.3} | {:.3} | {:.1} | {:.0} | {} |",
                r.name,
                c.cfg.chunk,
                c.info.reorder.tiles_used,
                c.chunk_count,
                c.info.reorder.max_tile_rays,
                c.chunk_mean_ns * 1e-6,
                ms(c.chunk_max_ns),
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
        "Same frames (light-grid shadows in all). Perspective grid: built in every frame; traversal Mrays/s counts the traversal only, \"with build\" adds the per-frame build. The packets ({PACKET}x{PACKET}, Morton-ordered 2x2 quads) trace the prebuilt BVH (Ranged, Partition) and uniform grid (CGT); their builds, once per scene, are listed apart. \"differ\": pixels that differ from the perspective-grid image.\n"
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
            r.camera(mm).map_or(("-".into(), "-".into(), "-".into()), |x| {
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
        let _ = writeln!(m, "\n## Figure 11: shadow time vs light distance, per chunk size r\n");
        let _ = writeln!(
            m,
            "Shadow time = data rearrangement + shadow build + shadow traversal (ms, median of {}). The light moves from the model's bounding-box centre along a fixed direction (the view's up, tilted 0.3 to the right and 0.2 back), 0.25 to 8 bounding-box diagonals; \"occluded\": the share of shadow rays blocked (at r = {}); the camera and its pass stay fixed. Beyond about half a diagonal the light is outside the model: for a closed room (conference) its roof then blocks every shadow ray.\n",
            s.reps, pp.chunk
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
            head.push_str(" chunks (r=32 .. 4096) | slowest / mean chunk (r=32 .. 4096) |");
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

fn csv(results: &[SceneResult]) -> String {
    let mut s = String::from(
        "scene,triangles,view,config,primary,shadows,chunk,primary_build_ms,primary_trace_ms,rearrange_ms,shadow_build_ms,shadow_trace_ms,shade_ms,frame_ms,shadow_ms,shadow_rays,hits,camera_refs,light_refs,light_tiles_used,chunks,max_tile_rays,chunk_mean_ms,chunk_max_ms,chunk_slowest_over_mean,threads_busy,pixels_differ\n",
    );
    for r in results {
        for c in &r.cfgs {
            let t = &c.times;
            let _ = writeln!(
                s,
                "{},{},{},{},{},{},{},{:.4},{:.4},{:.4},{:.4},{:.4},{:.4},{:.4},{:.4},{},{},{},{},{},{},{},{:.5},{:.5},{:.3},{:.3},{}",
                r.name,
                r.triangles,
                r.view,
                c.cfg.label(),
                primary_label(&c.cfg.primary),
                shadow_label(&c.cfg.shadow),
                c.cfg.chunk,
                ms(t.primary_build),
                ms(t.primary_trace),
                ms(t.rearrange),
                ms(t.shadow_build),
                ms(t.shadow_trace),
                ms(t.shade),
                ms(c.frame_ns),
                ms(c.shadow_ns),
                c.shadow_rays,
                c.hits,
                c.info.camera.refs,
                c.info.light.refs,
                c.info.reorder.tiles_used,
                c.chunk_count,
                c.info.reorder.max_tile_rays,
                c.chunk_mean_ns * 1e-6,
                ms(c.chunk_max_ns),
                c.imbalance,
                c.efficiency,
                c.diff
            );
        }
    }
    s
}

fn csv_fig11(results: &[SceneResult]) -> String {
    let mut s = String::from("scene,diagonals,distance,shadow_rays,occluded,chunk,shadow_ms,chunks,chunk_slowest_over_mean\n");
    for r in results {
        for row in &r.fig11 {
            for (j, rr) in FIG11_R.iter().enumerate() {
                let _ = writeln!(
                    s,
                    "{},{:.3},{:.3},{},{},{rr},{:.4},{},{:.3}",
                    r.name,
                    row.diagonals,
                    row.distance,
                    row.shadow_rays,
                    row.occluded,
                    ms(row.shadow_ns[j]),
                    row.chunks[j],
                    row.imbalance[j]
                );
            }
        }
    }
    s
}

// ---------------------------------------------------------------------------
// Charts

mod charts {
    use super::{FIG11_R, Method, SceneResult, Setup, WIDE_R};
    use crate::bench::chart;
    use crate::cmd::phases;
    use crate::run::ms;
    use crate::{Failure, OrFail};
    use plotters::coord::Shift;
    use plotters::prelude::*;
    use std::path::Path;

    const TITLE_H: u32 = 40;

    fn e(x: &dyn std::fmt::Display) -> String {
        x.to_string()
    }

    /// Draw with `draw` into an SVG and a PNG of `size`.
    fn save(
        size: (u32, u32),
        svg: &Path,
        png: &Path,
        draw_svg: impl FnOnce(DrawingArea<SVGBackend<'_>, Shift>) -> Result<(), String>,
        draw_png: impl FnOnce(DrawingArea<BitMapBackend<'_>, Shift>) -> Result<(), String>,
    ) -> Result<(), Failure> {
        chart::register_font()?;
        draw_svg(SVGBackend::new(svg, size).into_drawing_area())
            .map_err(|x| Failure(format!("chart {}: {x}", svg.display())))?;
        let mut buf = vec![0u8; size.0 as usize * size.1 as usize * 3];
        draw_png(BitMapBackend::with_buffer(&mut buf, size).into_drawing_area())
            .map_err(|x| Failure(format!("chart {}: {x}", png.display())))?;
        image::save_buffer(png, &buf, size.0, size.1, image::ExtendedColorType::Rgb8)
            .or_fail(|| format!("cannot write {}", png.display()))
    }

    fn title<DB: DrawingBackend>(
        root: &DrawingArea<DB, Shift>,
        t: &str,
    ) -> Result<DrawingArea<DB, Shift>, String>
    where
        DB::ErrorType: 'static,
    {
        root.fill(&WHITE).map_err(|x| e(&x))?;
        let (head, body) = root.split_vertically(TITLE_H);
        head.draw(&Text::new(t.to_string(), (12, 10), (chart::FONT, 18).into_font()))
            .map_err(|x| e(&x))?;
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

    /// A bar chart over scenes: `stacks` per scene of (value per series),
    /// stacked when `stacked`, else side by side.
    #[allow(clippy::too_many_arguments)]
    fn bars<DB: DrawingBackend>(
        area: &DrawingArea<DB, Shift>,
        caption: &str,
        scenes: &[String],
        series: &[(String, RGBColor)],
        values: &[Vec<f64>],
        stacked: bool,
        ylabel: &str,
        totals: bool,
    ) -> Result<(), String>
    where
        DB::ErrorType: 'static,
    {
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
        let xmax = n as f64 + 1.6;
        let mut c = ChartBuilder::on(area)
            .caption(caption, (chart::FONT, 15))
            .margin(12)
            .x_label_area_size(34)
            .y_label_area_size(60)
            .build_cartesian_2d(0.0..xmax, 0.0..top)
            .map_err(|x| e(&x))?;
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
            .label_style((chart::FONT, 12))
            .axis_desc_style((chart::FONT, 13))
            .draw()
            .map_err(|x| e(&x))?;
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
            c.draw_series(rects)
                .map_err(|x| e(&x))?
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
                        format!("{val:.0}"),
                        (x0, val + top * 0.012),
                        (chart::FONT, 9).into_font(),
                    )
                }))
                .map_err(|x| e(&x))?;
            }
        }
        if stacked && totals {
            c.draw_series(values.iter().enumerate().map(|(i, v)| {
                let t: f64 = v.iter().sum();
                Text::new(
                    format!("{t:.1}"),
                    (i as f64 + 0.3, t + top * 0.015),
                    (chart::FONT, 11).into_font(),
                )
            }))
            .map_err(|x| e(&x))?;
        }
        c.configure_series_labels()
            .position(SeriesLabelPosition::UpperRight)
            .background_style(WHITE.mix(0.85))
            .border_style(BLACK.mix(0.4))
            .label_font((chart::FONT, 12))
            .draw()
            .map_err(|x| e(&x))?;
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
    ) -> Result<(), Failure> {
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
        let cap = "ms per frame (stacked phases; frame total above each bar)";
        save(
            size,
            svg,
            png,
            |root| {
                let body = title(&root, &t)?;
                bars(&body, cap, &scenes, &series, &values, true, "ms", true)?;
                root.present().map_err(|x| e(&x))
            },
            |root| {
                let body = title(&root, &t)?;
                bars(&body, cap, &scenes, &series, &values, true, "ms", true)?;
                root.present().map_err(|x| e(&x))
            },
        )
    }

    pub(super) fn shadows(
        results: &[SceneResult],
        s: &Setup<'_>,
        svg: &Path,
        png: &Path,
    ) -> Result<(), Failure> {
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
            (format!("light grid r={}", s.pp.chunk), RGBColor(214, 39, 40)),
            (format!("light grid r={WIDE_R}"), RGBColor(252, 146, 114)),
            (format!("CGT {n}x{n} packets"), RGBColor(44, 160, 44)),
            (format!("BVH Ranged {n}x{n}"), RGBColor(33, 113, 181)),
            (format!("BVH Partition {n}x{n}"), RGBColor(158, 202, 225)),
        ];
        let t = format!(
            "sheaf shadow rays: light grid vs shadow packets, {}x{}, {} threads",
            s.w, s.h, s.threads
        );
        let cap = "shadow phase ms (rearrangement + build + traversal), lower is better";
        let size = (190 * scenes.len() as u32 + 420, 560);
        save(
            size,
            svg,
            png,
            |root| {
                let body = title(&root, &t)?;
                bars(&body, cap, &scenes, &series, &values, false, "ms", false)?;
                root.present().map_err(|x| e(&x))
            },
            |root| {
                let body = title(&root, &t)?;
                bars(&body, cap, &scenes, &series, &values, false, "ms", false)?;
                root.present().map_err(|x| e(&x))
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

    fn fig11_panel<DB: DrawingBackend>(
        area: &DrawingArea<DB, Shift>,
        r: &SceneResult,
    ) -> Result<(), String>
    where
        DB::ErrorType: 'static,
    {
        let top = r
            .fig11
            .iter()
            .flat_map(|row| row.shadow_ns.iter().map(|&ns| ms(ns)))
            .fold(1e-3, f64::max)
            * 1.1;
        let lo = r.fig11.first().map_or(0.25, |x| x.diagonals) * 0.9;
        let hi = r.fig11.last().map_or(8.0, |x| x.diagonals) * 1.1;
        let mut c = ChartBuilder::on(area)
            .caption(
                format!("{} ({} triangles)", r.name, r.triangles),
                (chart::FONT, 15),
            )
            .margin(12)
            .x_label_area_size(40)
            .y_label_area_size(56)
            .build_cartesian_2d((lo..hi).log_scale(), 0.0..top)
            .map_err(|x| e(&x))?;
        c.configure_mesh()
            .x_desc("light distance from the model centre (scene diagonals, log scale)")
            .y_desc("shadow ms")
            .x_label_formatter(&|x| format!("{x:.2}"))
            .label_style((chart::FONT, 12))
            .axis_desc_style((chart::FONT, 13))
            .draw()
            .map_err(|x| e(&x))?;
        for (j, rr) in FIG11_R.iter().enumerate() {
            let colour = R_COLOURS[j % R_COLOURS.len()];
            let pts: Vec<(f64, f64)> = r
                .fig11
                .iter()
                .map(|row| (row.diagonals, ms(row.shadow_ns[j])))
                .collect();
            c.draw_series(LineSeries::new(pts.clone(), colour.stroke_width(2)))
                .map_err(|x| e(&x))?
                .label(format!("r = {rr}"))
                .legend(move |(x, y)| {
                    PathElement::new(vec![(x, y), (x + 16, y)], colour.stroke_width(2))
                });
            c.draw_series(pts.iter().map(|&p| Circle::new(p, 3, colour.filled())))
                .map_err(|x| e(&x))?;
        }
        c.configure_series_labels()
            .position(SeriesLabelPosition::UpperRight)
            .background_style(WHITE.mix(0.85))
            .border_style(BLACK.mix(0.4))
            .label_font((chart::FONT, 12))
            .draw()
            .map_err(|x| e(&x))?;
        Ok(())
    }

    fn fig11_draw<DB: DrawingBackend>(
        root: DrawingArea<DB, Shift>,
        rs: &[&SceneResult],
        t: &str,
    ) -> Result<(), String>
    where
        DB::ErrorType: 'static,
    {
        let body = title(&root, t)?;
        let panels = body.split_evenly((1, rs.len().max(1)));
        for (p, r) in panels.iter().zip(rs) {
            fig11_panel(p, r)?;
        }
        root.present().map_err(|x| e(&x))
    }

    pub(super) fn figure11(
        results: &[SceneResult],
        s: &Setup<'_>,
        svg: &Path,
        png: &Path,
    ) -> Result<(), Failure> {
        let rs: Vec<&SceneResult> = results.iter().filter(|r| !r.fig11.is_empty()).collect();
        let t = format!(
            "sheaf Figure 11: shadow time vs light distance per chunk size r, {}x{}, {} threads",
            s.w, s.h, s.threads
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
