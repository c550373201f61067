//! `sheaf bench --whitted`: the BVH paper's traversal study on our scenes.
//!
//! - Figure 5: time to render one frame with Masked, Ranged and Partition
//!   traversal at packet sides 4..32 (every ray class traced with that
//!   traversal and side, frustum culling on), per scene and ray recursion
//!   level: primary rays only; primary + point-light shadows; 2-deep
//!   refractions (every surface transmits); 2-bounce reflections (every
//!   surface reflects). The 2x2 SIMD ray is the baseline of each panel.
//! - Frustum culling (Figure 7): the same frames with culling off for
//!   Ranged and Partition at 16x16 and 32x32.
//! - Table 2: a full Whitted frame (shadows, 1 reflection bounce, 2 deep
//!   refractions; every surface reflects 30 % and transmits 30 %) with the
//!   paper's recommended configuration (16x16, Ranged for primary and
//!   shadow rays, Partition for reflection and refraction rays, culling
//!   on) against 2x2 SIMD rays for every class; and the culling benefit;
//!   and the frustum-first walk (`bvh-frustum` 16x16) for every class.
//! - Figure 6: ray-box and ray-triangle tests per BVH depth for Ranged and
//!   Partition at 16x16, primary and reflection levels.
//!
//! Every frame is also compared pixel for pixel with the SIMD frame of its
//! level (the images must be identical). Frame times include shading and
//! ray generation (as the paper's), on the largest `--threads` count,
//! median of `--reps` timed runs after an untimed one.
#![forbid(unsafe_code)]

use super::common::{
    FONT, Progress, check_threads, command_line, create_dir, load_or_skip, machine_line, median,
    ratio, save_chart, scene_specs, timed, tri_test, view_for, write_csv, write_text,
};
use crate::BenchArgs;
use crate::run::{self, ms};
use anyhow::{Context as _, Result};
use sheaf::render::material::{Material, Materials};
use sheaf::render::whitted::{WhittedJob, WhittedParams};
use sheaf::trace::{BvhOptions, DEPTH_BINS, RayKind};
use sheaf::{
    BvhParams, Counters, Frame, Limits, Method, OwnedContext, PointLight, Shading, TraceParams,
};
use std::fmt::Write as _;
use std::time::Instant;

/// Builds of the BVH per scene; the median is reported.
const BUILD_REPS: usize = 3;

/// A ray recursion level of Figure 5.
#[derive(Clone, Copy)]
struct Level {
    name: &'static str,
    shadows: bool,
    material: Option<Material>,
    params: WhittedParams,
}

const fn level(
    name: &'static str,
    shadows: bool,
    material: Option<Material>,
    max_reflect: u32,
    max_refract: u32,
) -> Level {
    Level {
        name,
        shadows,
        material,
        params: WhittedParams {
            max_reflect,
            max_refract,
        },
    }
}

const GREY: [f32; 3] = [0.8, 0.78, 0.72];
const LEVELS: [Level; 4] = [
    level("primary", false, None, 0, 0),
    level("primary + shadows", true, None, 0, 0),
    level(
        "2-deep refractions",
        false,
        Some(Material {
            diffuse: GREY,
            reflect: 0.0,
            transmit: 0.8,
            ior: 1.5,
        }),
        0,
        2,
    ),
    level(
        "2-bounce reflections",
        false,
        Some(Material {
            diffuse: GREY,
            reflect: 0.8,
            transmit: 0.0,
            ior: 1.0,
        }),
        2,
        0,
    ),
];
/// Table 2's frame.
const WHITTED: Level = level(
    "Whitted: shadows + 1 reflection + 2 refractions",
    true,
    Some(Material {
        diffuse: GREY,
        reflect: 0.3,
        transmit: 0.3,
        ior: 1.5,
    }),
    1,
    2,
);

const TRAVERSALS: [Method; 3] = [Method::BvhMasked, Method::BvhRanged, Method::BvhPartition];

/// One configuration: the method and packet side per ray class, and culling.
#[derive(Clone, Copy, Debug)]
struct Config {
    primary: Method,
    secondary: Method,
    packet: u32,
    culling: bool,
}

impl Config {
    fn params(&self, m: Method) -> TraceParams {
        TraceParams {
            method: m,
            packet: self.packet.max(2),
            bvh: BvhOptions {
                culling: self.culling,
                kind: RayKind::Auto,
            },
            ..TraceParams::default()
        }
    }
    fn label(&self) -> String {
        let name = |m: Method| m.name().trim_start_matches("bvh-").to_string();
        let mut s = if self.primary == Method::BvhSimd || self.primary == Method::BvhSingle {
            name(self.primary)
        } else if self.primary == self.secondary {
            format!("{} {}x{}", name(self.primary), self.packet, self.packet)
        } else {
            format!(
                "{}/{} {}x{}",
                name(self.primary),
                name(self.secondary),
                self.packet,
                self.packet
            )
        };
        if !self.culling {
            s.push_str(" no-culling");
        }
        s
    }
}

/// One frame measured.
struct Row {
    scene: String,
    level: &'static str,
    cfg: Config,
    ns: u64,
    ctr: Counters,
    /// Pixels that differ from the level's SIMD frame.
    diff: usize,
}

struct Setup<'a> {
    frame: Frame,
    threads: u32,
    reps: u32,
    ctx: &'a mut OwnedContext,
}

impl Setup<'_> {
    /// Render `level` with `cfg`: untimed run (counters, image), then the timed median.
    fn frame(
        &mut self,
        level: &Level,
        cfg: &Config,
        pixels: &mut Vec<u8>,
    ) -> Result<(u64, Counters)> {
        let frame = Frame {
            shading: Shading {
                shadows: level.shadows,
                ..self.frame.shading
            },
            ..self.frame
        };
        let material = level
            .material
            .unwrap_or(Material::diffuse(frame.shading.albedo));
        let materials = if level.material.is_some() {
            Materials::uniform(&material)
        } else {
            Materials {
                materials: &[],
                ranges: &[],
            }
        };
        let job = WhittedJob {
            frame: &frame,
            lights: &[],
            materials,
            params: level.params,
            primary: cfg.params(cfg.primary).with_kind(RayKind::Primary),
            shadow: cfg.params(cfg.primary).with_kind(RayKind::Shadow),
            secondary: cfg.params(cfg.secondary).with_kind(RayKind::Secondary),
        };
        pixels.resize(frame.width as usize * frame.height as usize * 4, 0);
        let ctr = run::render_whitted_frame(self.ctx, &job, pixels, self.threads)?;
        let mut err = None;
        let ns = timed(self.reps, || {
            if let Err(e) = run::render_whitted_frame(self.ctx, &job, pixels, self.threads) {
                err = Some(e);
            }
        });
        match err {
            Some(e) => Err(e),
            None => Ok((ns, ctr)),
        }
    }
}

pub fn run(a: &BenchArgs) -> Result<()> {
    let start = Instant::now();
    let (w, h) = a
        .size
        .unwrap_or(if a.quick { (256, 256) } else { (1024, 1024) });
    let threads = *a.threads.iter().max().unwrap_or(&2);
    let out_dir = a.out_dir();
    check_threads(&[threads])?;
    let reps = a.reps.unwrap_or(if a.quick { 1 } else { 3 }).max(1);
    let mut packets: Vec<u32> = if a.packets.is_empty() {
        vec![4, 8, 16, 32]
    } else {
        a.packets.iter().copied().filter(|&n| n >= 4).collect()
    };
    packets.sort_unstable();
    packets.dedup();
    for &n in &packets {
        TraceParams::bvh(Method::BvhRanged, n)
            .validate()
            .with_context(|| format!("--packets {n}"))?;
    }
    let test = tri_test(a);
    let specs = scene_specs(a)?;
    create_dir(&out_dir)?;
    let machine = machine_line();
    let mut cfgs = vec![Config {
        primary: Method::BvhSimd,
        secondary: Method::BvhSimd,
        packet: 2,
        culling: true,
    }];
    for m in TRAVERSALS {
        cfgs.extend(packets.iter().map(|&n| Config {
            primary: m,
            secondary: m,
            packet: n,
            culling: true,
        }));
    }
    for m in [Method::BvhRanged, Method::BvhPartition] {
        cfgs.extend(packets.iter().filter(|&&n| n >= 16).map(|&n| Config {
            primary: m,
            secondary: m,
            packet: n,
            culling: false,
        }));
    }
    let recommended = Config {
        primary: Method::BvhRanged,
        secondary: Method::BvhPartition,
        packet: 16,
        culling: true,
    };
    let table2 = [
        Config {
            primary: Method::BvhSingle,
            secondary: Method::BvhSingle,
            packet: 0,
            culling: true,
        },
        Config {
            primary: Method::BvhSimd,
            secondary: Method::BvhSimd,
            packet: 2,
            culling: true,
        },
        recommended,
        Config {
            culling: false,
            ..recommended
        },
        Config {
            primary: Method::BvhRanged,
            secondary: Method::BvhRanged,
            packet: 16,
            culling: true,
        },
        Config {
            primary: Method::BvhPartition,
            secondary: Method::BvhPartition,
            packet: 16,
            culling: true,
        },
        // The frustum-first walk for every ray class (its interval frustum
        // replaces the plane frustum, so culling is moot).
        Config {
            primary: Method::BvhFrustum,
            secondary: Method::BvhFrustum,
            packet: 16,
            culling: true,
        },
    ];
    // One step per frame measured.
    let per_scene = (LEVELS.len() * cfgs.len() + table2.len()) as u64;
    let prog = Progress::new("sheaf bench --whitted", specs.len() as u64 * per_scene);
    prog.say(format_args!(
        "sheaf bench --whitted: {} scenes x {} levels x {} configurations (+ Table 2: {}), {w}x{h}, {threads} threads, {:?}, median of up to {reps} timed runs, machine: {machine}",
        specs.len(),
        LEVELS.len(),
        cfgs.len(),
        table2.len(),
        test
    ));
    let mut rows: Vec<Row> = Vec::new();
    let mut t2: Vec<Row> = Vec::new();
    let mut notes: Vec<String> = Vec::new();
    let mut pixels = Vec::new();
    let mut base = Vec::new();
    for spec in &specs {
        prog.doing(spec.name.clone());
        let Some(loaded) = load_or_skip(spec, &prog) else {
            prog.inc(per_scene);
            continue;
        };
        let scene = loaded.scene()?;
        let mut limits: Limits = run::limits(&scene, (w, h), threads);
        limits.structures = Limits::BVH;
        limits.projection_test = test == sheaf::TriTest::Projection;
        let mut ctx = OwnedContext::new(&limits).context("creating the context")?;
        let bp = BvhParams {
            test,
            ..BvhParams::default()
        };
        let mut builds = Vec::new();
        let mut info = None;
        for _ in 0..BUILD_REPS {
            info = Some(
                ctx.build_bvh(&scene, &bp)
                    .with_context(|| format!("{}: building the BVH", spec.name))?,
            );
            builds.push(ctx.stats().bvh_build_ns);
        }
        let info = info.expect("BUILD_REPS > 0");
        if info.triangles == 0 {
            prog.say(format_args!(
                "note: {}: every triangle is degenerate or non-finite, skipped",
                spec.name
            ));
            prog.inc(per_scene);
            continue;
        }
        let build_ns = median(builds);
        let (v, light, how) = view_for(&loaded, &ctx.tracer()?, &info.bounds, w, h);
        let frame = Frame {
            camera: crate::view::camera(&v),
            light: PointLight {
                position: light.to_array(),
                color: [1.0; 3],
                ..Default::default()
            },
            shading: Shading::default(),
            width: w,
            height: h,
        };
        let note = format!(
            "{}: {} triangles, BVH {} nodes, {} leaves, depth {}, SAH cost {:.1}, build {:.1} ms ({:.2} M triangles/s, median of {BUILD_REPS}); view {how}",
            spec.name,
            info.triangles,
            info.nodes,
            info.leaves,
            info.depth,
            info.sah_cost,
            ms(build_ns),
            info.triangles as f64 / (build_ns.max(1) as f64 * 1e-3)
        );
        prog.say(format_args!("[{}] {note}", spec.name));
        notes.push(note);
        let mut setup = Setup {
            frame,
            threads,
            reps,
            ctx: &mut ctx,
        };
        for lv in LEVELS.iter().chain([&WHITTED]) {
            let list: &[Config] = if lv.name == WHITTED.name {
                &table2
            } else {
                &cfgs
            };
            for (k, cfg) in list.iter().enumerate() {
                let (ns, ctr) = setup.frame(lv, cfg, &mut pixels)?;
                if k == 0 {
                    std::mem::swap(&mut base, &mut pixels);
                }
                let src = if k == 0 { &base } else { &pixels };
                let diff = src
                    .chunks_exact(4)
                    .zip(base.chunks_exact(4))
                    .filter(|(a, b)| a != b)
                    .count();
                let row = Row {
                    scene: spec.name.clone(),
                    level: lv.name,
                    cfg: *cfg,
                    ns,
                    ctr,
                    diff,
                };
                prog.say(format_args!(
                    "[{}] {:<46} {:<32} {:>9.1} ms {:>7.2} Mrays/s {:>6.1} box {:>6.1} tri tests/ray{}",
                    spec.name,
                    lv.name,
                    cfg.label(),
                    ms(ns),
                    run::mrays(ctr.rays, ns),
                    ctr.aabb_tests as f64 / ctr.rays.max(1) as f64,
                    ctr.tri_tests as f64 / ctr.rays.max(1) as f64,
                    if diff > 0 {
                        format!("  IMAGE DIFFERS: {diff} pixels")
                    } else {
                        String::new()
                    }
                ));
                prog.step();
                if lv.name == WHITTED.name {
                    if k == 2 {
                        let png = out_dir.join(format!("whitted_{}.png", spec.name));
                        run::write_png(&png, &pixels, w, h)?;
                    }
                    t2.push(row);
                } else {
                    rows.push(row);
                }
            }
        }
    }
    let header = Header {
        notes: &notes,
        machine: &machine,
        size: (w, h),
        threads,
        reps,
        secs: start.elapsed().as_secs_f64(),
    };
    let md = markdown(&rows, &t2, &header);
    let md_path = out_dir.join("whitted.md");
    write_text(&md_path, &md)?;
    let csv_path = out_dir.join("whitted.csv");
    let (head, records) = csv(&rows, &t2);
    write_csv(&csv_path, &head, records)?;
    let (svg, png) = (out_dir.join("figure5.svg"), out_dir.join("figure5.png"));
    figure5::write(&rows, &packets, &svg, &png)?;
    prog.say(format_args!("\n{md}"));
    let differ: usize = rows.iter().chain(&t2).map(|r| r.diff).sum();
    if differ > 0 {
        prog.say(format_args!(
            "warning: some frames differ from their level's SIMD frame (see the diff column)"
        ));
    }
    prog.say(format_args!(
        "wrote {}, {}, {}, {}",
        md_path.display(),
        csv_path.display(),
        svg.display(),
        png.display()
    ));
    Ok(())
}

/// whitted.csv: the header, then one record per frame (Figure 5's, then Table 2's).
fn csv(rows: &[Row], t2: &[Row]) -> (Vec<String>, Vec<Vec<String>>) {
    let mut head: Vec<String> = "table,scene,level,config,primary,secondary,packet,culling,frame_ms,rays,aabb_tests,tri_tests,culled_nodes,culled_tris,pixels_differing"
        .split(',')
        .map(String::from)
        .collect();
    head.extend((0..DEPTH_BINS).map(|d| format!("aabb_d{d}")));
    head.extend((0..DEPTH_BINS).map(|d| format!("tri_d{d}")));
    let records = rows
        .iter()
        .map(|r| ("figure5", r))
        .chain(t2.iter().map(|r| ("table2", r)))
        .map(|(table, r)| {
            let c = &r.ctr;
            let mut f = vec![
                table.to_string(),
                r.scene.clone(),
                r.level.to_string(),
                r.cfg.label(),
                r.cfg.primary.name().to_string(),
                r.cfg.secondary.name().to_string(),
                r.cfg.packet.to_string(),
                r.cfg.culling.to_string(),
                format!("{:.3}", ms(r.ns)),
                c.rays.to_string(),
                c.aabb_tests.to_string(),
                c.tri_tests.to_string(),
                c.culled_nodes.to_string(),
                c.culled.to_string(),
                r.diff.to_string(),
            ];
            f.extend(
                c.aabb_by_depth
                    .iter()
                    .chain(&c.tri_by_depth)
                    .map(|x| x.to_string()),
            );
            f
        })
        .collect();
    (head, records)
}

/// What the report's head says of the run: its notes, the machine, the
/// frame size, threads and rounds, and the seconds it took.
struct Header<'a> {
    notes: &'a [String],
    machine: &'a str,
    size: (u32, u32),
    threads: u32,
    reps: u32,
    secs: f64,
}

/// whitted.md: the run's `header`, Table 2 (`t2`) and Figure 5 (`rows`).
fn markdown(rows: &[Row], t2: &[Row], header: &Header<'_>) -> String {
    let Header {
        notes,
        machine,
        size: (w, h),
        threads,
        reps,
        secs,
    } = *header;
    let mut s = String::from("# sheaf bench --whitted\n\n");
    let _ = writeln!(s, "- command: `{}`", command_line());
    let _ = writeln!(s, "- machine (at the start): {machine}");
    let _ = writeln!(
        s,
        "- {w}x{h}, {threads} threads, frame time = ray generation + traversal + shading of the whole frame, median of up to {reps} runs after an untimed one; total {secs:.0} s"
    );
    let _ = writeln!(
        s,
        "- every frame is compared pixel for pixel with its level's 2x2 SIMD frame: `diff` is the count of differing pixels (must be 0)\n"
    );
    for n in notes {
        let _ = writeln!(s, "- {n}");
    }
    let scenes: Vec<&str> = {
        let mut v: Vec<&str> = rows.iter().map(|r| r.scene.as_str()).collect();
        v.dedup();
        v
    };
    s.push_str("\n## Table 2: a Whitted frame, large packets against 2x2 SIMD rays\n\n");
    s.push_str("Shadows, 1 reflection bounce, 2-deep refractions; every surface reflects 30 % and transmits 30 % (index 1.5).\n\n");
    s.push_str("| scene | single ms | 2x2 SIMD ms | 16x16 Ranged/Partition ms | speed-up vs SIMD | culling benefit | 16x16 Ranged ms | 16x16 Partition ms | 16x16 frustum ms | frustum speed-up vs SIMD | diff |\n|---|--:|--:|--:|--:|--:|--:|--:|--:|--:|--:|\n");
    for sc in &scenes {
        let get = |i: usize| t2.iter().filter(|r| r.scene == *sc).nth(i);
        let (Some(single), Some(simd), Some(rec), Some(nocull), Some(rg), Some(pt)) =
            (get(0), get(1), get(2), get(3), get(4), get(5))
        else {
            continue;
        };
        let diff: usize = t2.iter().filter(|r| r.scene == *sc).map(|r| r.diff).sum();
        let (fr_ms, fr_x) = get(6).map_or(("-".into(), "-".into()), |f| {
            (
                format!("{:.1}", ms(f.ns)),
                format!("{:.2}x", ratio(simd.ns, f.ns)),
            )
        });
        let _ = writeln!(
            s,
            "| {sc} | {:.1} | {:.1} | {:.1} | {:.2}x | {:.2}x | {:.1} | {:.1} | {fr_ms} | {fr_x} | {diff} |",
            ms(single.ns),
            ms(simd.ns),
            ms(rec.ns),
            ratio(simd.ns, rec.ns),
            ratio(nocull.ns, rec.ns),
            ms(rg.ns),
            ms(pt.ns)
        );
    }
    s.push_str("\n## Figure 5: frame ms per traversal and packet side (culling on); SIMD = 2x2 SIMD rays\n\n");
    let sides: Vec<u32> = {
        let mut v: Vec<u32> = rows
            .iter()
            .filter(|r| r.cfg.packet >= 4)
            .map(|r| r.cfg.packet)
            .collect();
        v.sort_unstable();
        v.dedup();
        v
    };
    for sc in &scenes {
        let _ = writeln!(s, "### {sc}\n");
        s.push_str("| level | SIMD |");
        for m in TRAVERSALS {
            for n in &sides {
                let _ = write!(s, " {} {n} |", &m.name()[4..]);
            }
        }
        s.push_str(" best | culling benefit (16x16 Ranged / Partition) | diff |\n|---|--:|");
        for _ in 0..TRAVERSALS.len() * sides.len() {
            s.push_str("--:|");
        }
        s.push_str("---|---|--:|\n");
        for lv in LEVELS {
            let of = |m: Method, n: u32, cull: bool| {
                rows.iter().find(|r| {
                    r.scene == *sc
                        && r.level == lv.name
                        && r.cfg.primary == m
                        && r.cfg.packet == n
                        && r.cfg.culling == cull
                })
            };
            let Some(simd) = of(Method::BvhSimd, 2, true) else {
                continue;
            };
            let _ = write!(s, "| {} | {:.1} |", lv.name, ms(simd.ns));
            let mut best: Option<&Row> = None;
            for m in TRAVERSALS {
                for &n in &sides {
                    match of(m, n, true) {
                        Some(r) => {
                            let _ = write!(s, " {:.1} |", ms(r.ns));
                            if best.is_none_or(|b| r.ns < b.ns) {
                                best = Some(r);
                            }
                        }
                        None => s.push_str(" |"),
                    }
                }
            }
            let cull = |m: Method| match (of(m, 16, true), of(m, 16, false)) {
                (Some(on), Some(off)) => format!("{:.2}x", ratio(off.ns, on.ns)),
                _ => "-".into(),
            };
            let diff: usize = rows
                .iter()
                .filter(|r| r.scene == *sc && r.level == lv.name)
                .map(|r| r.diff)
                .sum();
            let _ = writeln!(
                s,
                " {} ({:.2}x SIMD) | {} / {} | {diff} |",
                best.map_or("-".into(), |b| b.cfg.label()),
                best.map_or(0.0, |b| ratio(simd.ns, b.ns)),
                cull(Method::BvhRanged),
                cull(Method::BvhPartition)
            );
        }
        s.push('\n');
    }
    s.push_str(
        "## Figure 6: ray-box and ray-triangle tests per BVH depth, 16x16, Ranged vs Partition\n\n",
    );
    for sc in &scenes {
        for lv in [LEVELS[0].name, LEVELS[3].name] {
            let of = |m: Method| {
                rows.iter().find(|r| {
                    r.scene == *sc
                        && r.level == lv
                        && r.cfg.primary == m
                        && r.cfg.packet == 16
                        && r.cfg.culling
                })
            };
            let (Some(rg), Some(pt)) = (of(Method::BvhRanged), of(Method::BvhPartition)) else {
                continue;
            };
            let deepest = (0..DEPTH_BINS)
                .rev()
                .find(|&d| {
                    rg.ctr.aabb_by_depth[d]
                        + pt.ctr.aabb_by_depth[d]
                        + rg.ctr.tri_by_depth[d]
                        + pt.ctr.tri_by_depth[d]
                        > 0
                })
                .unwrap_or(0);
            let _ = writeln!(
                s,
                "**{sc}, {lv}**: totals box tests Ranged {} / Partition {}, triangle tests Ranged {} / Partition {}\n",
                rg.ctr.aabb_tests, pt.ctr.aabb_tests, rg.ctr.tri_tests, pt.ctr.tri_tests
            );
            s.push_str("| depth | box Ranged | box Partition | tri Ranged | tri Partition |\n|--:|--:|--:|--:|--:|\n");
            for d in 0..=deepest {
                let _ = writeln!(
                    s,
                    "| {d}{} | {} | {} | {} | {} |",
                    if d == DEPTH_BINS - 1 { "+" } else { "" },
                    rg.ctr.aabb_by_depth[d],
                    pt.ctr.aabb_by_depth[d],
                    rg.ctr.tri_by_depth[d],
                    pt.ctr.tri_by_depth[d]
                );
            }
            s.push('\n');
        }
    }
    s
}

/// The Figure 5 chart: one panel per (level, scene), frame ms against packet
/// side, one line per traversal, the 2x2 SIMD ray as a dashed line.
mod figure5 {
    use super::{FONT, LEVELS, Row, TRAVERSALS, save_chart};
    use anyhow::Result;
    use plotters::prelude::*;
    use sheaf::Method;
    use std::path::Path;

    const PANEL: (u32, u32) = (360, 260);
    const TITLE_H: u32 = 52;

    fn colour(m: Method) -> RGBColor {
        match m {
            Method::BvhMasked => RGBColor(44, 160, 44),
            Method::BvhRanged => RGBColor(31, 119, 180),
            _ => RGBColor(214, 39, 40),
        }
    }

    fn draw<DB: DrawingBackend>(
        root: DrawingArea<DB, plotters::coord::Shift>,
        rows: &[Row],
        packets: &[u32],
    ) -> Result<()>
    where
        DB::ErrorType: 'static,
    {
        root.fill(&WHITE)?;
        let mut scenes: Vec<&str> = rows.iter().map(|r| r.scene.as_str()).collect();
        scenes.dedup();
        let (title, body) = root.split_vertically(TITLE_H);
        title.draw(&Text::new(
            "Frame ms vs packet side (BVH paper Figure 5)",
            (10, 8),
            (FONT, 16).into_font(),
        ))?;
        let mut x = 10;
        for (label, c) in [
            ("Masked", colour(Method::BvhMasked)),
            ("Ranged", colour(Method::BvhRanged)),
            ("Partition", colour(Method::BvhPartition)),
            ("2x2 SIMD", RGBColor(120, 120, 120)),
        ] {
            title.draw(&Rectangle::new([(x, 34), (x + 18, 40)], c.filled()))?;
            title.draw(&Text::new(label, (x + 24, 30), (FONT, 13).into_font()))?;
            x += 110;
        }
        let panels = body.split_evenly((LEVELS.len(), scenes.len().max(1)));
        for (i, p) in panels.iter().enumerate() {
            let (lv, sc) = (
                LEVELS[i / scenes.len().max(1)],
                scenes.get(i % scenes.len().max(1)).copied().unwrap_or(""),
            );
            let here: Vec<&Row> = rows
                .iter()
                .filter(|r| r.scene == sc && r.level == lv.name && r.cfg.culling)
                .collect();
            if here.is_empty() {
                continue;
            }
            let top = here.iter().map(|r| r.ns as f64 * 1e-6).fold(0.0, f64::max) * 1.1;
            let lo = packets.first().map_or(2.0, |&n| (n as f64).log2()) - 0.3;
            let hi = packets.last().map_or(5.0, |&n| (n as f64).log2()) + 0.3;
            let mut c = ChartBuilder::on(p)
                .caption(format!("{sc}: {}", lv.name), (FONT, 13))
                .margin(6)
                .x_label_area_size(22)
                .y_label_area_size(44)
                .build_cartesian_2d(lo..hi, 0.0..top.max(1e-3))?;
            c.configure_mesh()
                .x_labels(packets.len())
                .x_label_formatter(&|x| format!("{0}x{0}", 2f64.powf(x.round()) as u32))
                .y_desc("ms")
                .label_style((FONT, 11))
                .draw()?;
            if let Some(simd) = here.iter().find(|r| r.cfg.primary == Method::BvhSimd) {
                let y = simd.ns as f64 * 1e-6;
                c.draw_series(DashedLineSeries::new(
                    [(lo, y), (hi, y)],
                    6,
                    4,
                    RGBColor(120, 120, 120).stroke_width(2),
                ))?;
            }
            for m in TRAVERSALS {
                let pts: Vec<(f64, f64)> = here
                    .iter()
                    .filter(|r| r.cfg.primary == m)
                    .map(|r| ((r.cfg.packet as f64).log2(), r.ns as f64 * 1e-6))
                    .collect();
                c.draw_series(LineSeries::new(pts.clone(), colour(m).stroke_width(2)))?;
                c.draw_series(pts.iter().map(|&p| Circle::new(p, 3, colour(m).filled())))?;
            }
        }
        Ok(root.present()?)
    }

    pub(super) fn write(rows: &[Row], packets: &[u32], svg: &Path, png: &Path) -> Result<()> {
        let mut scenes: Vec<&str> = rows.iter().map(|r| r.scene.as_str()).collect();
        scenes.dedup();
        let size = (
            PANEL.0 * scenes.len().max(2) as u32,
            PANEL.1 * LEVELS.len() as u32 + TITLE_H,
        );
        save_chart(
            size,
            svg,
            png,
            |root| draw(root, rows, packets),
            |root| draw(root, rows, packets),
        )
    }
}
