//! `sheaf bench --stress`: stability where methods fail: whether every
//! method stays exact on adversarial input, and how much slower it gets.
//!
//! Scenes: the adversarial scenes of `sheaf_stress` (teapot in a
//! stadium, huge triangles, long skinny diagonal needles, coincident and
//! degenerate triangles, a closed box seen from inside), then the built-in
//! scenes and the OBJ scenes of `--scenes-dir` (skipped with a note when
//! absent). Ray classes: the view's camera rays (coherent) and the
//! adversarial classes of `sheaf_stress::RayClass` (every class on the
//! stress scenes; random-in-packet and mixed-signs on the others), `RAYS`
//! rays each, in the order `stress_rays` documents (every n x n packet an
//! image tile).
//!
//! Every structure (grid, BVH, kd-tree) is built once per scene and every
//! method traces every class: the single-ray baseline of the structure,
//! its 2x2 SIMD ray (BVH, kd) and its n x n packet methods at sides 4, 8
//! and 16 (CGT; Masked, Ranged, Partition; kd packets from the root, from
//! MLRTA's and from AEPSA's entry point), each with the incoherence
//! fallbacks of `sheaf::trace::fallback` off and on. Per method and class:
//! - time per call: the calls of one class are timed in rounds, one sample
//!   per configuration per round (a sample repeats the call until it took
//!   `MIN_SAMPLE_NS`), up to `--reps` rounds (default 3), fewer for
//!   configurations whose samples already took `CAP_NS`; the median sample
//!   is reported, and the ratio to the baseline's median in the same
//!   rounds;
//! - exactness: rays whose triangle or t (bitwise) differ from the
//!   baseline's (must be 0);
//! - the baseline against the f64 oracle (`sheaf::reference`) on a sample
//!   of the rays (at most `ORACLE_BUDGET` ray-triangle tests per class):
//!   disagreements within the named tolerances `TIE_REL` (the oracle's two
//!   nearest hits are a tie) and `EDGE_BARY` (the ray passes that close to
//!   an edge), and outside them;
//! - crashes (a panic in a call is caught, reported and the configuration
//!   skipped) and the slowest call.
//!
//! The environment variable `SHEAF_STRESS_CLASSES` (comma-separated class
//! names, `camera` for the camera rays) restricts the run to those classes.
//!
//! Output: README.md (tables), stress.csv, stress.svg and stress.png (the
//! slowdown of every packet configuration against its baseline, fallbacks
//! off and on, with the 2x line) in `--out-dir` (default docs/bench-stress).
#![forbid(unsafe_code)]

use super::common::{
    FONT, OBJ_SCENES, Progress, SceneSpec, command_line, create_dir, load_or_skip, machine_line,
    median, par_map, save_chart, scenes_dir, specs_of, tri_test, view_for, write_csv, write_text,
};
use crate::BenchArgs;
use crate::load::Loaded;
use crate::run::{self, ms};
use anyhow::{Context as _, Result, bail};
use sheaf::reference::{self, RefHit};
use sheaf::render::PrimaryRays;
use sheaf::scenes::{Mesh, View};
use sheaf::trace::{EntrySearch, Structure, fallback};
use sheaf::{GridParams, Hit, Limits, Method, OwnedContext, Ray, Scene, TraceParams};
use sheaf_stress::{self as stress, RayClass};
use std::fmt::Write as _;
use std::time::Instant;

/// Rays per adversarial class (8 blocks of 32 x 32: every packet full) on
/// the stress scenes, and on the others (built-in and OBJ scenes, where
/// CGT without its fallbacks takes seconds per call).
const RAYS: usize = 8 * 1024;
const OTHER_RAYS: usize = 4 * 1024;
const QUICK_RAYS: usize = 4 * 1024;
/// Camera rays (256 x 256 pixels; `--size` sets both).
const CAMERA_RAYS: usize = 64 * 1024;
const QUICK_CAMERA_RAYS: usize = 16 * 1024;
/// A timing sample repeats its call until it took this long.
const MIN_SAMPLE_NS: u64 = 10_000_000;
/// A configuration gets no more rounds once its samples took this long.
const CAP_NS: u64 = 200_000_000;
/// Ray-triangle tests the f64 oracle may spend per scene and class.
const ORACLE_BUDGET: f64 = 4e7;
const QUICK_ORACLE_BUDGET: f64 = 2e7;
/// Named tolerances (those of tests/exact/reference_equivalence.rs and `sheaf
/// bench`): relative t gap of a tie, barycentric distance to an edge.
const TIE_REL: f64 = 1e-5;
const EDGE_BARY: f64 = 1e-5;
/// The slowdown over the single-ray baseline the fallbacks must stay under.
const LIMIT: f64 = 2.0;

const QUICK_SCENES: &[&str] = &["closed-box", "huge-triangles", "tetra"];
/// Classes of the scenes that are not stress scenes.
const OTHER_CLASSES: &[RayClass] = &[RayClass::RandomInPacket, RayClass::MixedSigns];
const QUICK_CLASSES: &[RayClass] = &[
    RayClass::RandomInPacket,
    RayClass::AxisParallel,
    RayClass::Grazing,
];

/// One traced configuration.
#[derive(Clone, Copy, Debug, PartialEq)]
struct Cfg {
    method: Method,
    packet: u32,
    entry: EntrySearch,
    fallback: bool,
}

impl Cfg {
    fn params(&self) -> TraceParams {
        TraceParams {
            entry: self.entry,
            fallbacks: self.fallback || self.is_baseline(),
            ..TraceParams::bvh(self.method, self.packet.max(2))
        }
    }
    fn is_baseline(&self) -> bool {
        self.method == self.method.single()
    }
    /// The method without the fallback switch: `cgt 8`, `kd-packet 16 aepsa`.
    fn name(&self) -> String {
        let mut s = match self.method {
            Method::GridCgt => "cgt".to_string(),
            Method::BvhMasked => "masked".into(),
            Method::BvhRanged => "ranged".into(),
            Method::BvhPartition => "partition".into(),
            Method::BvhSimd | Method::KdSimd => "simd".into(),
            Method::KdPacket => "packet".into(),
            m => m.name().into(),
        };
        if self.method.is_packet() {
            let _ = write!(s, " {}", self.packet);
        }
        match self.entry {
            EntrySearch::None => {}
            EntrySearch::Mlrta => s += " mlrta",
            EntrySearch::Aepsa => s += " aepsa",
        }
        s
    }
    /// `name` with its structure: `grid cgt 8`.
    fn long_name(&self) -> String {
        format!(
            "{} {}",
            structure_name(self.method.structure()),
            self.name()
        )
    }
}

fn structure_name(s: Structure) -> &'static str {
    match s {
        Structure::Grid => "grid",
        Structure::Bvh => "bvh",
        Structure::Kd => "kd",
    }
}

/// The configurations: per structure its baseline first, then every other
/// method with the fallbacks off and on.
fn configs(sides: &[u32]) -> Vec<Cfg> {
    let c = |method, packet, entry| Cfg {
        method,
        packet,
        entry,
        fallback: true,
    };
    let none = EntrySearch::None;
    let mut methods = vec![c(Method::GridDda, 0, none)];
    methods.extend(sides.iter().map(|&n| c(Method::GridCgt, n, none)));
    methods.push(c(Method::BvhSingle, 0, none));
    methods.push(c(Method::BvhSimd, 0, none));
    for m in [Method::BvhMasked, Method::BvhRanged, Method::BvhPartition] {
        methods.extend(sides.iter().map(|&n| c(m, n, none)));
    }
    methods.push(c(Method::KdSingle, 0, none));
    methods.push(c(Method::KdSimd, 0, none));
    for e in [EntrySearch::None, EntrySearch::Mlrta, EntrySearch::Aepsa] {
        methods.extend(sides.iter().map(|&n| c(Method::KdPacket, n, e)));
    }
    let mut v = Vec::new();
    for m in methods {
        if !m.is_baseline() {
            v.push(Cfg {
                fallback: false,
                ..m
            });
        }
        v.push(m);
    }
    v
}

/// A scene to run.
struct SceneIn {
    name: String,
    loaded: Loaded,
    stress: bool,
}

/// The scenes asked for (`--scenes`: stress, built-in or OBJ names, or OBJ
/// paths; by default the stress scenes, then the built-in and OBJ scenes),
/// absent OBJ files skipped with a note.
fn scene_list(a: &BenchArgs) -> Result<Vec<SceneSpec>> {
    let names: Vec<String> = if !a.scenes.is_empty() {
        a.scenes.clone()
    } else if a.quick {
        QUICK_SCENES.iter().map(|s| s.to_string()).collect()
    } else {
        stress::STRESS_SCENE_NAMES
            .iter()
            .chain(sheaf::scenes::BUILTIN_NAMES)
            .chain(OBJ_SCENES.iter().map(|(n, _)| n))
            .map(|s| s.to_string())
            .collect()
    };
    specs_of(&names, &scenes_dir(a))
}

/// One configuration on one class.
#[derive(Clone, Debug)]
struct Cell {
    cfg: Cfg,
    /// Median sample, ns per call; None after a panic.
    ns: Option<u64>,
    /// Its ratio to the structure's baseline (same class, same rounds).
    ratio: Option<f64>,
    /// Fastest sample, and its ratio to the baseline's fastest (the least
    /// disturbed by other load on the machine).
    min_ns: Option<u64>,
    ratio_min: Option<f64>,
    samples: usize,
    /// Rays whose hit differs from the baseline's (triangle or t bits).
    diff: u64,
    /// First differing ray (index, this hit, the baseline's).
    first_diff: Option<(usize, Hit, Hit)>,
    /// Packets that fell back and lanes they traced alone (one call).
    fb_packets: u64,
    fb_lanes: u64,
    panicked: bool,
    /// Slowest single call, ns.
    slowest: u64,
}

/// The baseline of one structure against the f64 oracle.
#[derive(Clone, Copy, Debug, Default)]
struct Oracle {
    checked: u64,
    mismatch: u64,
    tie: u64,
    edge: u64,
    outside: u64,
}

struct ClassResult {
    scene: String,
    class: String,
    rays: usize,
    cells: Vec<Cell>,
    /// Per structure (grid, bvh, kd).
    oracle: [Oracle; 3],
    /// Rays the oracle looked at (every `step`-th).
    oracle_step: usize,
    /// First oracle disagreements outside the tolerances.
    outside: Vec<String>,
}

struct SceneInfo {
    name: String,
    triangles: u32,
    view: String,
    build: String,
}

fn structure_index(s: Structure) -> usize {
    match s {
        Structure::Grid => 0,
        Structure::Bvh => 1,
        Structure::Kd => 2,
    }
}

/// Trace `rays` with `cfg` (its fallbacks on or off: `TraceParams::fallbacks`);
/// None on a panic.
fn trace(ctx: &mut OwnedContext, cfg: &Cfg, rays: &[Ray], hits: &mut [Hit]) -> Option<u64> {
    let p = cfg.params();
    let t = Instant::now();
    let r = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| {
        ctx.trace_with(&p, rays, hits)
    }));
    let ns = t.elapsed().as_nanos() as u64;
    match r {
        Ok(Ok(_)) => Some(ns),
        _ => None,
    }
}

pub fn run(a: &BenchArgs) -> Result<()> {
    let start = Instant::now();
    let (nrays, ncam) = match a.size {
        Some((w, h)) => {
            let n = (w as usize * h as usize).div_ceil(1024) * 1024;
            (n, n)
        }
        None if a.quick => (QUICK_RAYS, QUICK_CAMERA_RAYS),
        None => (RAYS, CAMERA_RAYS),
    };
    let reps = a.reps.unwrap_or(if a.quick { 1 } else { 3 }).max(1) as usize;
    let sides: Vec<u32> = if !a.packets.is_empty() {
        a.packets.clone()
    } else if a.quick {
        vec![8]
    } else {
        vec![4, 8, 16]
    };
    if let Some(&n) = sides.iter().find(|n| !matches!(n, 2 | 4 | 8 | 16 | 32)) {
        bail!("--packets: {n} is not 2, 4, 8, 16 or 32");
    }
    let test = tri_test(a);
    let budget = if a.quick {
        QUICK_ORACLE_BUDGET
    } else {
        ORACLE_BUDGET
    };
    let cfgs = configs(&sides);
    let list = scene_list(a)?;
    let out_dir = a.out_dir();
    create_dir(&out_dir)?;
    let machine = machine_line();
    // One step per scene and ray class; progress on stderr, as the report lines.
    let steps = list
        .iter()
        .map(|s| classes_of(a.quick, s.load.starts_with("stress:")).len() as u64)
        .sum();
    let prog = Progress::new("sheaf bench --stress", steps).on_stderr();
    prog.say(format_args!(
        "sheaf bench --stress: {} scenes, {ncam} camera rays and {nrays} rays per adversarial class, {} configurations, median of up to {reps} rounds, {test:?}, machine: {machine}",
        list.len(),
        cfgs.len()
    ));
    let mut results: Vec<ClassResult> = Vec::new();
    let mut infos: Vec<SceneInfo> = Vec::new();
    for spec in &list {
        prog.doing(spec.name.clone());
        let stress = spec.load.starts_with("stress:");
        let Some(loaded) = load_or_skip(spec, &prog) else {
            prog.inc(classes_of(a.quick, stress).len() as u64);
            continue;
        };
        let s = SceneIn {
            name: spec.name.clone(),
            loaded,
            stress,
        };
        let plan = Plan {
            test,
            nrays,
            ncam,
            reps,
            cfgs: &cfgs,
            budget,
        };
        let found = scene(&s, a, &plan, &prog)?;
        if let Some((info, mut r)) = found {
            infos.push(info);
            results.append(&mut r);
        }
    }
    if results.is_empty() {
        bail!("no scene ran");
    }
    let total_s = start.elapsed().as_secs_f64();
    let setup = Setup {
        nrays,
        ncam,
        reps,
        sides: &sides,
        test,
        machine_start: machine,
        machine_end: machine_line(),
        total_s,
        quick: a.quick,
    };
    let md_path = out_dir.join("README.md");
    write_text(&md_path, &markdown(&results, &infos, &setup))?;
    let (head, records) = csv(&results);
    write_csv(&out_dir.join("stress.csv"), &head, records)?;
    chart::slowdown(
        &results,
        &setup,
        &out_dir.join("stress.svg"),
        &out_dir.join("stress.png"),
    )?;
    prog.say(format_args!(
        "wrote {}, stress.csv, stress.svg, stress.png in {} ({total_s:.0} s)",
        md_path.display(),
        out_dir.display()
    ));
    Ok(())
}

/// The rays of `class` (None: the camera's) for `mesh` seen from `view`.
fn rays_of(class: Option<RayClass>, mesh: &Mesh, view: &View, n: usize) -> Result<Vec<Ray>> {
    match class {
        Some(c) => Ok(stress::stress_rays(c, mesh, view, n, 0x5eaf_0007)),
        None => {
            let (w, h) = stress::stress_image_size(n);
            let pr = PrimaryRays::new(&crate::view::camera(view), w, h).context("the camera")?;
            Ok((0..n)
                .map(|k| {
                    let (x, y) = stress::stress_pixel(k, n);
                    pr.ray(x, y)
                })
                .collect())
        }
    }
}

/// The ray classes of a scene (None: the camera's rays): every
/// adversarial class on the stress scenes, `OTHER_CLASSES` on the others,
/// `QUICK_CLASSES` with `--quick`. `SHEAF_STRESS_CLASSES=camera,grazing`:
/// only these (for studies, e.g. the camera rays alone at --size 512x512).
fn classes_of(quick: bool, stress: bool) -> Vec<Option<RayClass>> {
    let classes: Vec<Option<RayClass>> = std::iter::once(None)
        .chain(
            if quick {
                QUICK_CLASSES
            } else if stress {
                &RayClass::ALL[..]
            } else {
                OTHER_CLASSES
            }
            .iter()
            .copied()
            .map(Some),
        )
        .collect();
    let only: Vec<String> = std::env::var("SHEAF_STRESS_CLASSES")
        .map(|v| v.split(',').map(|s| s.trim().to_string()).collect())
        .unwrap_or_default();
    classes
        .into_iter()
        .filter(|c| only.is_empty() || only.iter().any(|o| o == c.map_or("camera", |c| c.name())))
        .collect()
}

/// How every scene and class runs, as the command line sets it: the
/// triangle test, the rays per adversarial class and camera rays, the
/// rounds, the configurations and the f64 oracle's budget.
struct Plan<'a> {
    test: sheaf::TriTest,
    nrays: usize,
    ncam: usize,
    reps: usize,
    cfgs: &'a [Cfg],
    budget: f64,
}

/// One scene: its structures built, then every ray class of it run
/// (`class_run`). None: skipped (with a note).
fn scene(
    s: &SceneIn,
    a: &BenchArgs,
    plan: &Plan<'_>,
    prog: &Progress,
) -> Result<Option<(SceneInfo, Vec<ClassResult>)>> {
    let Plan {
        test, nrays, ncam, ..
    } = *plan;
    let t0 = Instant::now();
    let classes = classes_of(a.quick, s.stress);
    let scene = s.loaded.scene()?;
    let mut limits = run::limits(&scene, (64, 64), 1);
    limits.structures = Limits::GRID | Limits::BVH | Limits::KD;
    limits.projection_test = test == sheaf::TriTest::Projection;
    let kp = sheaf::accel::kd::KdParams {
        test,
        ..Default::default()
    };
    let (limits, _) = run::kd_limits(&scene, limits, &kp)?;
    let gp = GridParams {
        lambda: a.lambda,
        macrocell: a.macrocell,
        test,
        fit: false,
    };
    let (mut ctx, ginfo) = run::context_for(&scene, limits, &gp, 1.0)?;
    let binfo = ctx
        .build_bvh(
            &scene,
            &sheaf::accel::bvh::BvhParams {
                test,
                ..Default::default()
            },
        )
        .with_context(|| format!("{}: building the BVH", s.name))?;
    let kinfo = ctx
        .build_kd(&scene, &kp)
        .with_context(|| format!("{}: building the kd-tree", s.name))?;
    if ginfo.triangles == 0 {
        prog.say(format_args!(
            "note: {}: every triangle excluded, skipped",
            s.name
        ));
        return Ok(None);
    }
    let (view, _, how) = view_for(&s.loaded, &ctx.tracer()?, &ginfo.scene_bounds, 512, 512);
    let mesh = Mesh {
        vertices: s.loaded.vertices.clone(),
        indices: s.loaded.indices.clone(),
    };
    let info = SceneInfo {
        name: s.name.clone(),
        triangles: ginfo.triangles,
        view: how,
        build: format!(
            "grid {}x{}x{}, BVH {} nodes (depth {}), kd-tree {} nodes",
            ginfo.res[0], ginfo.res[1], ginfo.res[2], binfo.nodes, binfo.depth, kinfo.nodes
        ),
    };
    prog.say(format_args!(
        "[{}] {} triangles ({} excluded), {}; view {}; built in {:.1} s",
        s.name,
        ginfo.triangles,
        ginfo.excluded_non_finite + ginfo.excluded_zero_area,
        info.build,
        info.view,
        t0.elapsed().as_secs_f64()
    ));
    let mut out = Vec::new();
    for class in classes {
        let cname = class.map_or("camera", |c| c.name()).to_string();
        let n = match class {
            None => ncam,
            Some(_) if s.stress || a.size.is_some() => nrays,
            Some(_) => nrays.min(OTHER_RAYS),
        };
        let rays = rays_of(class, &mesh, &view, n)?;
        let r = class_run(&mut ctx, &scene, &s.name, &cname, &rays, plan);
        prog.say(progress(&r));
        prog.step();
        out.push(r);
    }
    Ok(Some((info, out)))
}

/// The configurations of `plan` on the rays of class `cname` of scene
/// `sname`: timed in rounds, compared with their structure's baseline,
/// the baselines checked against the f64 oracle.
fn class_run(
    ctx: &mut OwnedContext,
    scene: &Scene<'_>,
    sname: &str,
    cname: &str,
    rays: &[Ray],
    plan: &Plan<'_>,
) -> ClassResult {
    let Plan {
        cfgs, reps, budget, ..
    } = *plan;
    let n = rays.len();
    // Untimed first calls: hits, fallback counts, panics, repeat counts.
    let mut cells: Vec<Cell> = Vec::with_capacity(cfgs.len());
    let mut hits_of: Vec<Vec<Hit>> = Vec::with_capacity(cfgs.len());
    let mut repeat = vec![1u32; cfgs.len()];
    let mut samples: Vec<Vec<u64>> = vec![Vec::new(); cfgs.len()];
    let mut spent = vec![0u64; cfgs.len()];
    for (i, cfg) in cfgs.iter().enumerate() {
        let mut hits = vec![Hit::MISS; n];
        let f0 = fallback::stats();
        let ns = trace(ctx, cfg, rays, &mut hits);
        let f1 = fallback::stats();
        if let Some(ns) = ns {
            repeat[i] = (MIN_SAMPLE_NS / ns.max(1)).clamp(1, 1000) as u32;
            // A first call that took the whole cap is the only sample.
            if ns >= CAP_NS {
                samples[i].push(ns);
                spent[i] = ns;
            }
        }
        cells.push(Cell {
            cfg: *cfg,
            ns: None,
            ratio: None,
            min_ns: None,
            ratio_min: None,
            samples: 0,
            diff: 0,
            first_diff: None,
            fb_packets: f1.packets - f0.packets,
            fb_lanes: f1.lanes - f0.lanes,
            panicked: ns.is_none(),
            slowest: ns.unwrap_or(0),
        });
        hits_of.push(hits);
    }
    // Timed rounds, configurations interleaved.
    let mut scratch = vec![Hit::MISS; n];
    for _ in 0..reps {
        for (i, cfg) in cfgs.iter().enumerate() {
            if cells[i].panicked || spent[i] >= CAP_NS {
                continue;
            }
            let mut total = 0u64;
            for _ in 0..repeat[i] {
                match trace(ctx, cfg, rays, &mut scratch) {
                    Some(ns) => {
                        total += ns;
                        cells[i].slowest = cells[i].slowest.max(ns);
                    }
                    None => {
                        cells[i].panicked = true;
                        break;
                    }
                }
            }
            samples[i].push(total / repeat[i] as u64);
            spent[i] += total;
        }
    }
    // Medians, ratios, exactness against the structure's baseline.
    for i in 0..cfgs.len() {
        if !cells[i].panicked && !samples[i].is_empty() {
            cells[i].samples = samples[i].len();
            cells[i].min_ns = samples[i].iter().copied().min();
            cells[i].ns = Some(median(std::mem::take(&mut samples[i])));
        }
    }
    for i in 0..cfgs.len() {
        let b = cfgs
            .iter()
            .position(|c| c.is_baseline() && c.method == cfgs[i].method.single())
            .unwrap_or(i);
        if let (Some(x), Some(y)) = (cells[i].ns, cells[b].ns) {
            cells[i].ratio = Some(x as f64 / y.max(1) as f64);
        }
        if let (Some(x), Some(y)) = (cells[i].min_ns, cells[b].min_ns) {
            cells[i].ratio_min = Some(x as f64 / y.max(1) as f64);
        }
        if i != b && !cells[i].panicked && !cells[b].panicked {
            let (got, want) = (&hits_of[i], &hits_of[b]);
            for k in 0..n {
                if got[k].prim != want[k].prim || got[k].t.to_bits() != want[k].t.to_bits() {
                    cells[i].diff += 1;
                    if cells[i].first_diff.is_none() {
                        cells[i].first_diff = Some((k, got[k], want[k]));
                    }
                }
            }
        }
    }
    // The baselines against the f64 oracle.
    let tris = scene.triangle_count().max(1) as f64;
    let step = ((n as f64 * tris / budget).ceil() as usize).max(1);
    let sample: Vec<usize> = (0..n).step_by(step).collect();
    let oracle: Vec<RefHit> = par_map(&sample, |&k| reference::nearest(scene, &rays[k]));
    let mut res = [Oracle::default(); 3];
    let mut outside = Vec::new();
    for (i, cfg) in cfgs.iter().enumerate() {
        if !cfg.is_baseline() || cells[i].panicked {
            continue;
        }
        let o = &mut res[structure_index(cfg.method.structure())];
        for (&k, want) in sample.iter().zip(&oracle) {
            o.checked += 1;
            let got = hits_of[i][k];
            if got.prim == want.prim {
                continue;
            }
            o.mismatch += 1;
            let near = reference::with_edge_distance(scene, &rays[k], *want);
            if near.gap <= TIE_REL {
                o.tie += 1;
            } else if near.edge <= EDGE_BARY {
                o.edge += 1;
            } else {
                o.outside += 1;
                if outside.len() < 6 {
                    outside.push(format!(
                        "{} ray {k} {:?}: prim {} t {} / f64 prim {} t {} (gap {:e}, edge {:e})",
                        cfg.method.name(),
                        rays[k],
                        got.prim as i64,
                        got.t,
                        want.prim as i64,
                        want.t,
                        near.gap,
                        near.edge
                    ));
                }
            }
        }
    }
    ClassResult {
        scene: sname.to_string(),
        class: cname.to_string(),
        rays: n,
        cells,
        oracle: res,
        oracle_step: step,
        outside,
    }
}

/// One report line per class: the worst ratio per structure off and on.
fn progress(r: &ClassResult) -> String {
    let mut s = format!("  {:<18}", r.class);
    for st in [Structure::Grid, Structure::Bvh, Structure::Kd] {
        let worst = |fb: bool| {
            r.cells
                .iter()
                .filter(|c| {
                    c.cfg.method.structure() == st && !c.cfg.is_baseline() && c.cfg.fallback == fb
                })
                .filter_map(|c| c.ratio)
                .fold(0.0f64, f64::max)
        };
        let base = r
            .cells
            .iter()
            .find(|c| c.cfg.is_baseline() && c.cfg.method.structure() == st)
            .and_then(|c| c.ns);
        let _ = write!(
            s,
            " | {} {:>7.2} ms, worst {:>6.2}x -> {:>5.2}x",
            structure_name(st),
            base.map_or(f64::NAN, ms),
            worst(false),
            worst(true)
        );
    }
    let diff: u64 = r.cells.iter().map(|c| c.diff).sum();
    let panics = r.cells.iter().filter(|c| c.panicked).count();
    let _ = write!(s, " | diff {diff}");
    if panics > 0 {
        let _ = write!(s, " | {panics} PANICKED");
    }
    s
}

struct Setup<'a> {
    nrays: usize,
    ncam: usize,
    reps: usize,
    sides: &'a [u32],
    test: sheaf::TriTest,
    machine_start: String,
    machine_end: String,
    total_s: f64,
    quick: bool,
}

/// `a -> b` ratios of one method (fallbacks off, on) in a table cell,
/// bold when above the limit.
fn pair(off: Option<&Cell>, on: Option<&Cell>) -> String {
    let f = |c: Option<&Cell>| match c {
        None => "-".to_string(),
        Some(c) if c.panicked => "PANIC".to_string(),
        Some(c) => match c.ratio {
            Some(r) if r > LIMIT => format!("**{r:.2}**"),
            Some(r) => format!("{r:.2}"),
            None => "-".into(),
        },
    };
    format!("{} → {}", f(off), f(on))
}

/// The non-baseline method names of a structure, in configuration order.
fn method_names(results: &[ClassResult], st: Structure) -> Vec<String> {
    let mut v: Vec<String> = Vec::new();
    if let Some(r) = results.first() {
        for c in &r.cells {
            if c.cfg.method.structure() == st && !c.cfg.is_baseline() && !v.contains(&c.cfg.name())
            {
                v.push(c.cfg.name());
            }
        }
    }
    v
}

fn find<'r>(r: &'r ClassResult, st: Structure, name: &str, fb: bool) -> Option<&'r Cell> {
    r.cells.iter().find(|c| {
        c.cfg.method.structure() == st
            && !c.cfg.is_baseline()
            && c.cfg.fallback == fb
            && c.cfg.name() == name
    })
}

fn baseline(r: &ClassResult, st: Structure) -> Option<&Cell> {
    r.cells
        .iter()
        .find(|c| c.cfg.is_baseline() && c.cfg.method.structure() == st)
}

fn markdown(results: &[ClassResult], infos: &[SceneInfo], s: &Setup<'_>) -> String {
    let mut m = String::new();
    let _ = writeln!(m, "# Stress: where methods fail\n");
    let _ = writeln!(
        m,
        "Command: `{}`, {:.0} s. {} camera rays ({}x{} pixels) and {} rays per adversarial class (stress scenes; {} on the others); every configuration timed in interleaved rounds (a sample repeats the call for at least {} ms), median of up to {} rounds (one round for configurations that took {} ms); triangle test {:?}; packet sides {}. Machine at the start: {}; at the end: {}.\n",
        command_line(),
        s.total_s,
        s.ncam,
        stress::stress_image_size(s.ncam).0,
        stress::stress_image_size(s.ncam).1,
        s.nrays,
        s.nrays.min(OTHER_RAYS),
        MIN_SAMPLE_NS / 1_000_000,
        s.reps,
        CAP_NS / 1_000_000,
        s.test,
        s.sides
            .iter()
            .map(|n| format!("{n}x{n}"))
            .collect::<Vec<_>>()
            .join(", "),
        s.machine_start,
        s.machine_end
    );
    if s.quick {
        let _ = writeln!(
            m,
            "**`--quick`**: a small subset (three scenes, three adversarial classes, 8x8 packets, one round); see the full run for the tables below at full size.\n"
        );
    }
    let _ = writeln!(
        m,
        "Ratios are time per call over the time of the same structure's single-ray baseline on the same rays in the same rounds (grid: the 3DDDA; BVH and kd-tree: their single-ray traversals), written `fallbacks off → on` (`TraceParams::fallbacks`); above {LIMIT}x in bold. What each fallback does and where it lives: see \"The fallbacks\" at the end.\n"
    );

    // Summary.
    let _ = writeln!(m, "## Summary\n");
    let _ = writeln!(
        m,
        "Per method: the worst ratio over every scene and class, the classes above {LIMIT}x, the worst ratio with the fallbacks on from the fastest samples (the configuration's over the baseline's: the machine's other load only ever adds time), and the rays that differ from the baseline (all classes; must be 0), fallbacks off and on.\n"
    );
    let _ = writeln!(
        m,
        "| method | worst off | worst on | > {LIMIT}x off | > {LIMIT}x on | where the worst (on) is | worst on, fastest samples | differing rays off / on |"
    );
    let _ = writeln!(m, "|---|--:|--:|--:|--:|---|--:|--:|");
    let total_classes = results.len();
    for st in [Structure::Grid, Structure::Bvh, Structure::Kd] {
        for name in method_names(results, st) {
            let mut worst = [0.0f64; 2];
            let mut worst_min = 0.0f64;
            let mut over = [0usize; 2];
            let mut diff = [0u64; 2];
            let mut at = String::new();
            for r in results {
                for (j, fb) in [false, true].into_iter().enumerate() {
                    if let Some(c) = find(r, st, &name, fb) {
                        diff[j] += c.diff;
                        if fb {
                            worst_min = worst_min.max(c.ratio_min.unwrap_or(0.0));
                        }
                        if let Some(x) = c.ratio {
                            if x > LIMIT {
                                over[j] += 1;
                            }
                            if x > worst[j] {
                                worst[j] = x;
                                if fb {
                                    at = format!("{} / {}", r.scene, r.class);
                                }
                            }
                        }
                    }
                }
            }
            let _ = writeln!(
                m,
                "| {} {name} | {:.2} | {} | {} of {total_classes} | {} of {total_classes} | {at} | {worst_min:.2} | {} / {} |",
                structure_name(st),
                worst[0],
                if worst[1] > LIMIT {
                    format!("**{:.2}**", worst[1])
                } else {
                    format!("{:.2}", worst[1])
                },
                over[0],
                over[1],
                diff[0],
                diff[1]
            );
        }
    }
    let panics: Vec<String> = results
        .iter()
        .flat_map(|r| {
            r.cells
                .iter()
                .filter(|c| c.panicked)
                .map(move |c| format!("{} / {}: {}", r.scene, r.class, c.cfg.long_name()))
        })
        .collect();
    let slowest = results
        .iter()
        .flat_map(|r| r.cells.iter().map(move |c| (c.slowest, r, c)))
        .max_by_key(|x| x.0);
    let _ = writeln!(
        m,
        "\nCrashes: {}. Hangs: none (every call returned; the slowest single call took {}). Allocation: none after setup (cli/stress/tests/fallback.rs counts allocations while every method traces every stress class, fallbacks on and off; tests/no_alloc.rs covers builds and renders).\n",
        if panics.is_empty() {
            "none (no call panicked)".to_string()
        } else {
            panics.join("; ")
        },
        slowest.map_or("-".into(), |(ns, r, c)| format!(
            "{:.0} ms: {} / {}, {}{}",
            ms(ns),
            r.scene,
            r.class,
            c.cfg.long_name(),
            if c.cfg.is_baseline() || c.cfg.fallback {
                ""
            } else {
                ", fallbacks off"
            }
        ))
    );

    // Camera rays: the fallbacks must not slow coherent packets.
    let cams: Vec<&ClassResult> = results.iter().filter(|r| r.class == "camera").collect();
    if !cams.is_empty() {
        let _ = writeln!(m, "## Coherent camera rays: fallbacks on against off\n");
        let _ = writeln!(
            m,
            "The time of each method on the camera rays with the fallbacks on over its time with them off (same binary, same rounds; below 1: faster with them). Camera packets pass the coherence test; what changes them is the CGT budget and the switch of Masked traversal to Partition.\n"
        );
        let _ = write!(m, "| method |");
        for r in &cams {
            let _ = write!(m, " {} |", r.scene);
        }
        let _ = writeln!(m, " geometric mean | worst |");
        let _ = write!(m, "|---|");
        for _ in &cams {
            let _ = write!(m, "--:|");
        }
        let _ = writeln!(m, "--:|--:|");
        let mut all = Vec::new();
        for st in [Structure::Grid, Structure::Bvh, Structure::Kd] {
            for name in method_names(results, st) {
                let _ = write!(m, "| {} {name} |", structure_name(st));
                let mut v = Vec::new();
                for r in &cams {
                    match (
                        find(r, st, &name, false).and_then(|c| c.ns),
                        find(r, st, &name, true).and_then(|c| c.ns),
                    ) {
                        (Some(off), Some(on)) => {
                            let x = on as f64 / off.max(1) as f64;
                            v.push(x);
                            let _ = write!(m, " {x:.2} |");
                        }
                        _ => {
                            let _ = write!(m, " - |");
                        }
                    }
                }
                let g = geo_mean(&v);
                let w = v.iter().copied().fold(0.0f64, f64::max);
                let _ = writeln!(m, " {g:.2} | {w:.2} |");
                all.extend(v);
            }
        }
        let _ = writeln!(
            m,
            "\nOver all {} method-scene pairs: geometric mean {:.3}, best {:.2}, worst {:.2} (timing noise on this machine is about 10-20 percent per pair).\n",
            all.len(),
            geo_mean(&all),
            all.iter().copied().fold(f64::INFINITY, f64::min),
            all.iter().copied().fold(0.0f64, f64::max)
        );
    }

    // Scenes.
    let _ = writeln!(m, "## Scenes\n");
    let _ = writeln!(m, "| scene | triangles stored | view | structures |");
    let _ = writeln!(m, "|---|--:|---|---|");
    for i in infos {
        let _ = writeln!(
            m,
            "| {} | {} | {} | {} |",
            i.name, i.triangles, i.view, i.build
        );
    }
    let _ = writeln!(m);

    // Per structure.
    for (st, title, base) in [
        (Structure::Grid, "Grid: CGT against the 3DDDA", "3DDDA"),
        (
            Structure::Bvh,
            "BVH: SIMD ray and Masked, Ranged, Partition packets against the single ray",
            "single",
        ),
        (
            Structure::Kd,
            "kd-tree: SIMD ray and packets (root, MLRTA, AEPSA entry) against the single ray",
            "single",
        ),
    ] {
        let names = method_names(results, st);
        let _ = writeln!(m, "## {title}\n");
        let _ = write!(m, "| scene | rays | {base} ms |");
        for n in &names {
            let _ = write!(m, " {n} |");
        }
        let _ = writeln!(m);
        let _ = write!(m, "|---|---|--:|");
        for _ in &names {
            let _ = write!(m, "--:|");
        }
        let _ = writeln!(m);
        for r in results {
            let b = baseline(r, st);
            let _ = write!(
                m,
                "| {} | {} | {} |",
                r.scene,
                r.class,
                b.and_then(|c| c.ns)
                    .map_or("-".into(), |ns| format!("{:.2}", ms(ns)))
            );
            for n in &names {
                let _ = write!(
                    m,
                    " {} |",
                    pair(find(r, st, n, false), find(r, st, n, true))
                );
            }
            let _ = writeln!(m);
        }
        let _ = writeln!(m);
    }

    // Exactness.
    let _ = writeln!(m, "## Exactness against the single-ray baseline\n");
    let _ = writeln!(
        m,
        "Rays whose triangle or t (bitwise) differ from the structure's single-ray baseline. Every configuration not listed: 0.\n"
    );
    let mut any = false;
    for r in results {
        for c in r.cells.iter().filter(|c| c.diff > 0) {
            if !any {
                let _ = writeln!(
                    m,
                    "| scene | rays | method | fallbacks | differing rays | first (ray: method / baseline) |"
                );
                let _ = writeln!(m, "|---|---|---|---|--:|---|");
                any = true;
            }
            let first = c.first_diff.map_or(String::new(), |(k, g, w)| {
                format!(
                    "{k}: prim {} t {:e} / prim {} t {:e}",
                    g.prim as i64, g.t, w.prim as i64, w.t
                )
            });
            let _ = writeln!(
                m,
                "| {} | {} | {} | {} | {} | {} |",
                r.scene,
                r.class,
                c.cfg.long_name(),
                if c.cfg.fallback { "on" } else { "off" },
                c.diff,
                first
            );
        }
    }
    if !any {
        let _ = writeln!(m, "None: every configuration returned the baseline's hits.");
    }
    let _ = writeln!(m);

    // Oracle.
    let _ = writeln!(m, "## The baselines against the f64 oracle\n");
    let _ = writeln!(
        m,
        "Every k-th ray (k chosen so the brute-force f64 oracle, `sheaf::reference`, spends at most {:.0e} ray-triangle tests per class) against each single-ray baseline: disagreements on the nearest triangle within the named tolerances (`TIE_REL` {TIE_REL:e}: the oracle's two nearest hits are that close, a tie; `EDGE_BARY` {EDGE_BARY:e}: the ray passes that close to an edge, barycentric) and outside them. The packet methods equal their baselines (previous section), so these counts are theirs too.\n\nOutside these two tolerances is not by itself wrong: these rays are built to be ill-posed. Most are rays with subnormal directions (zero-length: the f64 hit lies at t ~ 1e40, beyond f32's range, which no f32 answer can match), self-hits at t ~ 0 of origins on edges and vertices, and rays grazing a triangle or along an axis, where the f32 test's determinant is rounding noise. cli/stress/tests/stress.rs judges every ray class on the five stress scenes (1024 rays per class) with wider named tolerances that take the test's condition number and the coordinates' rounding into account (`illcond`, `origin`, `at-tmax`) and fails on any disagreement none of them explains.\n",
        if s.quick {
            QUICK_ORACLE_BUDGET
        } else {
            ORACLE_BUDGET
        }
    );
    let _ = writeln!(
        m,
        "| scene | rays | checked (every k-th) | grid: tie / edge / outside | BVH: tie / edge / outside | kd: tie / edge / outside |"
    );
    let _ = writeln!(m, "|---|---|--:|--:|--:|--:|");
    for r in results {
        let o = |x: &Oracle| {
            if x.outside > 0 {
                format!("{} / {} / **{}**", x.tie, x.edge, x.outside)
            } else {
                format!("{} / {} / 0", x.tie, x.edge)
            }
        };
        let _ = writeln!(
            m,
            "| {} | {} | {} (k = {}) | {} | {} | {} |",
            r.scene,
            r.class,
            r.oracle[0].checked,
            r.oracle_step,
            o(&r.oracle[0]),
            o(&r.oracle[1]),
            o(&r.oracle[2])
        );
    }
    let details: Vec<String> = results
        .iter()
        .flat_map(|r| {
            r.outside
                .iter()
                .map(move |d| format!("- {} / {}: {d}", r.scene, r.class))
        })
        .collect();
    if !details.is_empty() {
        let _ = writeln!(m, "\nOutside the tolerances (first few per class):\n");
        for d in details.iter().take(40) {
            let _ = writeln!(m, "{d}");
        }
    }
    let _ = writeln!(m);
    let _ = writeln!(m, "{}", FALLBACK_DOC);
    m
}

fn geo_mean(v: &[f64]) -> f64 {
    if v.is_empty() {
        return f64::NAN;
    }
    (v.iter().map(|x| x.ln()).sum::<f64>() / v.len() as f64).exp()
}

const FALLBACK_DOC: &str = "## The fallbacks

`sheaf::trace::fallback` (src/trace/fallback.rs) holds the shared test and
the switch; each traversal applies it:

- **Coherence test** (every packet method, at packet start, one pass over
  the live lanes): a packet is incoherent when some live direction is more
  than `MAX_CONE_DEG` (30 degrees) from the first live lane's, or the live
  origins spread over more than `MAX_ORIGIN_SPREAD` (a quarter) of the
  scene's diagonal. An incoherent packet is traced lane by lane by its
  structure's single-ray traversal (the 3DDDA, the BVH or kd single ray):
  CGT (`traverse_cgt.rs`), Masked/Ranged/Partition (`traverse_masked.rs`,
  `packet`), kd packets (`traverse_packet.rs`), and the 2x2 SIMD rays of
  the BVH and the kd-tree (one quad is the packet).
- **CGT budget** (`traverse_cgt.rs`; CGT paper sections 2.2 and 4.7: a wide
  frustum intersects every triangle in it): after each slice, the work the
  packet did (quad-triangle tests, triangles met first, `CGT_CELL` per
  cell) is charged against `CGT_BUDGET` (1) times what the 3DDDA would do
  for the live lanes (each crosses `1 + |du| + |dv|` cells of the slice, a
  cell costing `CGT_STEP` plus the slice's mean references per cell). Once
  over budget, the live lanes are handed to the 3DDDA (a lane no longer
  live already has its exact hit).
- **Tiny directions** (every packet method and the 2x2 SIMD rays):
  valid rays whose direction's largest component is below `TINY_DIR`
  (1e-18: the stress class zero-length scales directions by 1e-30 and
  1e-39) are traced alone by the single ray, and the packet on quads where
  they are replaced by another lane: a masked lane is still computed, and
  its subnormal numbers made every SIMD operation of its quad hundreds of
  times slower (kd SIMD rays on skinny-diagonal: 6x the single ray).
- **Masked switches to Partition** (`traverse_masked.rs`; BVH paper
  section 5.2.1: Masked traversal tests every quad at every leaf and is
  superseded by the other two (section 5.4), Partition traversal is robust to degrading coherence): the
  box tests that find a quad dead are counted against those that find one
  alive; after a leaf, once there are more than `MAX_DEAD_PER_ALIVE` (2)
  dead per alive (and at least 2 tests per quad), the subtrees still on the
  stack are walked by Partition traversal. The same switch for Ranged
  traversal made coherent camera packets up to 2x slower (skinny-diagonal)
  and is left out: with the coherence test, Ranged stays within its single
  ray's time on every stress class without it.

Exactness: a lane traced alone gets its baseline's answer by definition;
Partition traversal from any node is exact (traverse_partition.rs), and the
nodes handed to it are those the packet would have visited. cli/stress/tests/fallback.rs
checks that packets which trigger each fallback return the single ray's
triangle and bitwise t, and that the fallbacks trigger (their counters).
";

/// stress.csv: the header, then one record per scene, class and configuration.
fn csv(results: &[ClassResult]) -> (Vec<String>, Vec<Vec<String>>) {
    let head = "scene,rays,count,structure,method,packet,entry,fallback,ms,ratio,min_ms,ratio_min,samples,diff_vs_baseline,fallback_packets,fallback_lanes,panicked,slowest_ms,oracle_checked,oracle_tie,oracle_edge,oracle_outside"
        .split(',')
        .map(String::from)
        .collect();
    let mut records = Vec::new();
    for r in results {
        for c in &r.cells {
            let o = r.oracle[structure_index(c.cfg.method.structure())];
            let packet = if c.cfg.method.is_packet() {
                c.cfg.packet
            } else {
                0
            };
            let entry = match c.cfg.entry {
                EntrySearch::None => "none",
                EntrySearch::Mlrta => "mlrta",
                EntrySearch::Aepsa => "aepsa",
            };
            let fallback = if c.cfg.is_baseline() {
                "-"
            } else if c.cfg.fallback {
                "on"
            } else {
                "off"
            };
            records.push(vec![
                r.scene.clone(),
                r.class.clone(),
                r.rays.to_string(),
                structure_name(c.cfg.method.structure()).to_string(),
                c.cfg.method.name().to_string(),
                packet.to_string(),
                entry.to_string(),
                fallback.to_string(),
                c.ns.map_or(String::new(), |ns| format!("{:.4}", ms(ns))),
                c.ratio.map_or(String::new(), |x| format!("{x:.4}")),
                c.min_ns
                    .map_or(String::new(), |ns| format!("{:.4}", ms(ns))),
                c.ratio_min.map_or(String::new(), |x| format!("{x:.4}")),
                c.samples.to_string(),
                c.diff.to_string(),
                c.fb_packets.to_string(),
                c.fb_lanes.to_string(),
                c.panicked.to_string(),
                format!("{:.3}", ms(c.slowest)),
                o.checked.to_string(),
                o.tie.to_string(),
                o.edge.to_string(),
                o.outside.to_string(),
            ]);
        }
    }
    (head, records)
}

mod chart {
    use super::{
        Cell, ClassResult, FONT, LIMIT, Setup, Structure, find, method_names, save_chart,
        structure_name,
    };
    use anyhow::Result;
    use plotters::coord::Shift;
    use plotters::prelude::*;
    use std::path::Path;

    const SIZE: (u32, u32) = (1600, 760);
    const OFF: RGBColor = RGBColor(214, 39, 40);
    const ON: RGBColor = RGBColor(44, 160, 44);

    /// Axis label of a method: `cgt 8`, `M8` (Masked), `R8`, `P8`, `simd`,
    /// `8`, `8 mlrta` (kd packets).
    fn short(n: &str) -> String {
        let mut w = n.split(' ');
        let head = w.next().unwrap_or("");
        let rest: Vec<&str> = w.collect();
        let rest = rest.join(" ");
        match head {
            "masked" => format!("M{rest}"),
            "ranged" => format!("R{rest}"),
            "partition" => format!("P{rest}"),
            "packet" => rest,
            _ => n.to_string(),
        }
    }

    /// Every packet configuration's ratio on every scene and class, off
    /// (red, left) and on (green, right), log scale, with the 2x line.
    pub(super) fn slowdown(
        results: &[ClassResult],
        s: &Setup<'_>,
        svg: &Path,
        png: &Path,
    ) -> Result<()> {
        save_chart(
            SIZE,
            svg,
            png,
            |root| draw(root, results, s),
            |root| draw(root, results, s),
        )
    }

    fn draw<DB: DrawingBackend>(
        root: DrawingArea<DB, Shift>,
        results: &[ClassResult],
        s: &Setup<'_>,
    ) -> Result<()>
    where
        DB::ErrorType: 'static,
    {
        root.fill(&WHITE)?;
        let mut labels: Vec<(Structure, String)> = Vec::new();
        for st in [Structure::Grid, Structure::Bvh, Structure::Kd] {
            for n in method_names(results, st) {
                labels.push((st, n));
            }
        }
        let ratios = |st: Structure, n: &str, fb: bool| -> Vec<f64> {
            results
                .iter()
                .filter_map(|r| find(r, st, n, fb).and_then(|c: &Cell| c.ratio))
                .collect()
        };
        let top = labels
            .iter()
            .flat_map(|(st, n)| ratios(*st, n, false))
            .fold(4.0f64, f64::max)
            * 1.5;
        let bottom = labels
            .iter()
            .flat_map(|(st, n)| ratios(*st, n, true))
            .chain(labels.iter().flat_map(|(st, n)| ratios(*st, n, false)))
            .fold(0.5f64, f64::min)
            * 0.8;
        let nx = labels.len() as f64;
        let caption = format!(
            "Slowdown against the structure's single-ray baseline, every scene and ray class ({} camera rays, {} of each other class{}): fallbacks off (red) and on (green)",
            s.ncam,
            s.nrays,
            if s.quick { ", --quick" } else { "" }
        );
        let mut c = ChartBuilder::on(&root)
            .caption(caption, (FONT, 17))
            .margin(14)
            .x_label_area_size(40)
            .y_label_area_size(70)
            .build_cartesian_2d(0.0..nx, (bottom..top).log_scale())?;
        c.configure_mesh()
            .disable_x_mesh()
            .x_labels(2 * labels.len() + 1)
            .x_label_formatter(&|x| {
                let i = x.floor() as usize;
                if (x - i as f64 - 0.5).abs() < 0.01 {
                    labels.get(i).map(|(_, n)| short(n)).unwrap_or_default()
                } else {
                    String::new()
                }
            })
            .x_label_style((FONT, 11))
            .y_desc("time / single-ray baseline time (log)")
            .y_label_formatter(&|y| format!("{y}"))
            .label_style((FONT, 12))
            .axis_desc_style((FONT, 13))
            .draw()?;
        // The limit.
        c.draw_series(LineSeries::new(
            [(0.0, LIMIT), (nx, LIMIT)],
            BLACK.stroke_width(2),
        ))?
        .label(format!("{LIMIT}x: the limit"))
        .legend(|(x, y)| PathElement::new([(x, y), (x + 18, y)], BLACK.stroke_width(2)));
        c.draw_series(LineSeries::new([(0.0, 1.0), (nx, 1.0)], BLACK.mix(0.3)))?;
        for (fb, colour, dx, label) in [
            (false, OFF, 0.3, "fallbacks off"),
            (true, ON, 0.7, "fallbacks on"),
        ] {
            let mut pts = Vec::new();
            let mut worst = Vec::new();
            for (i, (st, n)) in labels.iter().enumerate() {
                let v = ratios(*st, n, fb);
                for r in &v {
                    pts.push((i as f64 + dx, *r));
                }
                if let Some(w) = v.iter().copied().reduce(f64::max) {
                    worst.push((i as f64 + dx, w));
                }
            }
            c.draw_series(
                pts.iter()
                    .map(|p| Circle::new(*p, 3, colour.mix(0.45).filled())),
            )?
            .label(label)
            .legend(move |(x, y)| Circle::new((x + 9, y), 4, colour.filled()));
            c.draw_series(worst.iter().map(|p| {
                Rectangle::new(
                    [(p.0 - 0.12, p.1 / 1.04), (p.0 + 0.12, p.1 * 1.04)],
                    colour.filled(),
                )
            }))?;
        }
        // Structure names over their groups, and lines between the groups.
        let mut i0 = 0usize;
        for st in [Structure::Grid, Structure::Bvh, Structure::Kd] {
            let k = labels.iter().filter(|(s2, _)| *s2 == st).count();
            if k == 0 {
                continue;
            }
            let title = match st {
                Structure::Grid => "grid (vs 3DDDA)",
                Structure::Bvh => "BVH (vs single ray)",
                Structure::Kd => "kd-tree (vs single ray)",
            };
            c.draw_series(std::iter::once(Text::new(
                title.to_string(),
                (i0 as f64 + 0.1, top / 1.12),
                (FONT, 14).into_font(),
            )))?;
            if i0 > 0 {
                c.draw_series(LineSeries::new(
                    [(i0 as f64, bottom), (i0 as f64, top)],
                    BLACK.mix(0.5),
                ))?;
            }
            i0 += k;
        }
        let _ = structure_name;
        c.configure_series_labels()
            .position(SeriesLabelPosition::UpperRight)
            .background_style(WHITE.mix(0.85))
            .border_style(BLACK.mix(0.4))
            .label_font((FONT, 13))
            .draw()?;
        Ok(())
    }
}
