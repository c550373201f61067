//! `sheaf demo` (alias `sheaf engine`), the main job: an engine's frame
//! loop on a two-level scene (`sheaf::accel::twolevel`). A static
//! environment (crytek sponza or conference from ../shared/scenes when
//! present, else the built-in gears) is built once; an animated mesh is
//! refit every frame and placed four times, a mesh whose triangle count
//! changes is rebuilt every frame and placed twice, and a static
//! tetrahedron is placed 16 times in a turning ring; two perforated panels
//! (an alpha-tested mesh: its holes are an any-hit filter's cut-out of
//! each triangle's (u, v), `geom::filter`) stand among them and cast
//! perforated shadows. Every frame updates
//! what moved, commits the top level and traces camera and shadow rays as
//! packets on all threads; one table line per frame, PNG frames and an
//! animated PNG.
//!
//! `--family bvh` (the default, the fastest here) traces through the
//! instances with frustum-first packets (`bvh-frustum`), and compares each frame with the
//! flattened alternative: every instance's world triangles in one mesh,
//! its BVH rebuilt (LOW) and the same rays traced. `--family grid` and
//! `--family kd` rebuild the grid (CGT packets) or the kd-tree (its packet
//! traversal) every frame over the scene flattened into world triangles
//! (`Context::build_grid_scene`, the grid paper's rebuild-everything
//! model), and trace the same rays.

use super::mib;
use crate::progress::Progress;
use crate::run::{self, mrays, ms};
use anyhow::{Context as _, Result, bail};
use clap::Args;
use glam::{Mat3, Vec3};
use rayon::prelude::*;
use sheaf::accel::bvh::{BuildQuality, BvhParams};
use sheaf::render::{PointLight, PrimaryRays, SHADOW_OFFSET, demorton};
use sheaf::scenes::animated::Animated;
use sheaf::{
    Affine, Candidate, Filter, GeometryParams, Limits, Method, OwnedContext, Ray, Scene, SceneHit,
    TraceParams, UpdateMode, required_bytes,
};
use std::path::PathBuf;
use std::time::Instant;

#[derive(Args)]
pub struct EngineArgs {
    /// Number of frames.
    #[arg(long, default_value_t = 24, value_parser = clap::value_parser!(u32).range(1..=10_000))]
    pub frames: u32,
    /// Image size, WIDTHxHEIGHT.
    #[arg(long, default_value = "640x384", value_parser = crate::parse_size)]
    pub size: (u32, u32),
    /// Directory for frame_000.png, ... and engine.png (the animated PNG).
    #[arg(long, default_value = "out/demo")]
    pub out_dir: PathBuf,
    /// The structure that traces the scene: the two-level BVH, or the grid or kd-tree
    /// rebuilt every frame over the flattened scene.
    #[arg(long, value_enum, default_value_t = Family::Bvh)]
    pub family: Family,
    /// Threads (default: available cores, at most 8).
    #[arg(long)]
    pub threads: Option<u32>,
    /// Seconds between frames.
    #[arg(long, default_value_t = 0.25)]
    pub dt: f32,
    /// The environment: an OBJ file, builtin:NAME, or `auto` (crytek sponza, else
    /// conference, from ../shared/scenes, else builtin:gears).
    #[arg(long, default_value = "auto")]
    pub env: String,
    /// Packet side of the camera and shadow rays (BVH frustum-first packets).
    #[arg(long, default_value_t = 8, value_parser = clap::value_parser!(u32).range(2..=32))]
    pub packet: u32,
    /// Skip the flattened comparison (one BVH over every instance's triangles).
    #[arg(long)]
    pub no_flat: bool,
}

/// Which family traces the frames.
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum Family {
    /// The two-level BVH (frustum-first packets through the instances).
    Bvh,
    /// The uniform grid rebuilt over the flattened scene (CGT packets).
    Grid,
    /// The kd-tree rebuilt over the flattened scene (its packet traversal).
    Kd,
}

/// Cells per side of the perforated panel (two triangles each).
const PANEL_CELLS: u32 = 12;

/// The perforated panel: a unit square of cells, upright once placed (in
/// the built-in meshes' z-up frame: x across, z up), `x` in [-0.5, 0.5].
fn panel() -> Mesh {
    let n = PANEL_CELLS;
    let mut vertices = Vec::new();
    for k in 0..=n {
        for i in 0..=n {
            vertices.extend([i as f32 / n as f32 - 0.5, 0.0, k as f32 / n as f32]);
        }
    }
    let at = |i: u32, k: u32| k * (n + 1) + i;
    let mut indices = Vec::new();
    for k in 0..n {
        for i in 0..n {
            let (a, b, c, d) = (at(i, k), at(i + 1, k), at(i + 1, k + 1), at(i, k + 1));
            indices.extend([a, b, c, a, c, d]);
        }
    }
    Mesh { vertices, indices }
}

/// The panel's cut-out: a round hole in every triangle, around its
/// centroid (u = v = 1/3): a pure function of the candidate.
fn perforated(u: f32, v: f32) -> bool {
    let (du, dv) = (u - 1.0 / 3.0, v - 1.0 / 3.0);
    du * du + dv * dv + du * dv > 0.018
}

/// The panel's filter (geometry 4 of the two-level scene).
extern "C" fn panel_filter(_: *mut std::ffi::c_void, c: &Candidate) -> bool {
    perforated(c.u, c.v)
}

/// The panel's filter on the flattened alternative's one mesh, whose
/// triangles from `from` on are the panels' (they come last): `from` is
/// the user pointer's value, never dereferenced.
extern "C" fn flat_filter(from: *mut std::ffi::c_void, c: &Candidate) -> bool {
    (c.prim as usize) < from as usize || perforated(c.u, c.v)
}

/// Triangles of the animated scene's ground grid at detail 1 (first).
const ANIMATED_GROUND: usize = 512;

/// A mesh the loop owns, as `Scene::from_f32` borrows it.
struct Mesh {
    vertices: Vec<f32>,
    indices: Vec<u32>,
}

impl Mesh {
    fn scene(&self) -> Result<Scene<'_>> {
        Ok(Scene::from_f32(&self.vertices, &self.indices)?)
    }
    fn bounds(&self) -> (Vec3, Vec3) {
        self.indices
            .iter()
            .fold((Vec3::INFINITY, Vec3::NEG_INFINITY), |(lo, hi), &i| {
                let p = Vec3::from_slice(&self.vertices[3 * i as usize..3 * i as usize + 3]);
                (lo.min(p), hi.max(p))
            })
    }
    fn triangles(&self) -> u32 {
        (self.indices.len() / 3) as u32
    }
}

/// An affine transform: the built-in meshes' z-up turned y-up, a uniform
/// scale, a rotation about y by `turn` radians, then a translation.
fn place(turn: f32, scale: f32, at: Vec3) -> Affine {
    let up = Mat3::from_rotation_x(-std::f32::consts::FRAC_PI_2);
    Affine::from_mat3(Mat3::from_rotation_y(turn) * up * scale, at)
}

/// The environment mesh and its name.
fn environment(spec: &str) -> Result<(String, Mesh)> {
    let pick = |s: &str| -> Result<(String, Mesh)> {
        let l = crate::load::load(s)?;
        Ok((
            l.label.clone(),
            Mesh {
                vertices: l.vertices,
                indices: l.indices,
            },
        ))
    };
    if spec != "auto" {
        return pick(spec);
    }
    let dirs = [
        PathBuf::from("../shared/scenes"),
        PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../shared/scenes"),
    ];
    for file in [
        "crytek_sponza/crytek_sponza.obj",
        "conference/conference.obj",
    ] {
        if let Some(p) = dirs.iter().map(|d| d.join(file)).find(|p| p.is_file()) {
            return pick(&p.to_string_lossy());
        }
    }
    pick("builtin:gears")
}

/// The image a frame renders: its camera rays, its size and the side of
/// its tiles (n x n pixels, each a packet).
struct Image<'a> {
    pr: &'a PrimaryRays,
    w: u32,
    h: u32,
    n: u32,
}

/// A scene as `render` traces and colours it: the trace, a hit's world
/// triangle and its colour.
struct TracedScene<'a> {
    trace: TraceFn<'a>,
    tri: &'a (dyn Fn(&SceneHit) -> sheaf::geom::TriVerts + Sync),
    palette: &'a (dyn Fn(&SceneHit) -> Vec3 + Sync),
}

/// Camera rays of tile `(tx, ty)` of `img` (quads in Morton order, the
/// renderer's packet layout) and their pixels; off-image lanes repeat the
/// image's last row or column (whole quads for the packets) and have no
/// pixel.
fn tile_rays(
    img: &Image<'_>,
    tx: u32,
    ty: u32,
    rays: &mut Vec<Ray>,
    px: &mut Vec<Option<(u32, u32)>>,
) {
    let Image { pr, w, h, n } = *img;
    rays.clear();
    px.clear();
    for q in 0..(n / 2) * (n / 2) {
        let (qx, qy) = demorton(q as usize);
        for (dx, dy) in [(0, 0), (1, 0), (0, 1), (1, 1)] {
            let (x, y) = (tx * n + 2 * qx + dx, ty * n + 2 * qy + dy);
            rays.push(pr.ray(x.min(w - 1), y.min(h - 1)));
            px.push((x < w && y < h).then_some((x, y)));
        }
    }
}

/// A trace on slot `i`: nearest hits, or with `any` occlusion, of the rays.
type TraceFn<'a> = &'a (dyn Fn(usize, &[Ray], bool, &mut [SceneHit]) -> Result<()> + Sync);
/// One tile's rays traced and its pixels: (x, y, RGBA).
type TilePixels = Result<(u64, Vec<(u32, u32, [u8; 4])>)>;

/// What one frame's rays took: the camera rays of the image's pixels and
/// the shadow rays made, and the time of tracing and shading them.
struct Traced {
    rays: u64,
    ns: u64,
}

/// Camera rays, shadow rays and shading of `img` on the pool's threads
/// (thread `i` on context slot `i`), as `scene` traces and colours them.
/// `eps` is the shadow rays' offset (`SHADOW_OFFSET` times the scene's
/// size, as the renderers take it).
fn render(
    scene: &TracedScene<'_>,
    img: &Image<'_>,
    light: &PointLight,
    eps: f32,
    pixels: &mut [u8],
    threads: u32,
) -> Result<Traced> {
    let TracedScene {
        trace,
        tri,
        palette,
    } = *scene;
    let Image { w, h, n, .. } = *img;
    let (tw, th) = (w.div_ceil(n), h.div_ceil(n));
    let t0 = Instant::now();
    let rows: Vec<TilePixels> = run::pool(threads as usize).install(|| {
        (0..tw * th)
            .into_par_iter()
            .map(|t| {
                let slot = rayon::current_thread_index().unwrap_or(0);
                let (mut rays, mut px) = (Vec::new(), Vec::new());
                tile_rays(img, t % tw, t / tw, &mut rays, &mut px);
                let mut hits = vec![SceneHit::MISS; rays.len()];
                trace(slot, &rays, false, &mut hits)?;
                let mut shadow = Vec::with_capacity(rays.len());
                let mut lit_lane = Vec::with_capacity(rays.len());
                // Each hit's world triangle once, for its shadow ray and
                // its shading.
                let tris: Vec<_> = hits.iter().map(|h| h.is_hit().then(|| tri(h))).collect();
                for ((r, hit), t) in rays.iter().zip(&hits).zip(&tris) {
                    let s = t
                        .as_ref()
                        .and_then(|t| sheaf::render::deferred::shadow_ray(r, hit.t, t, light, eps));
                    lit_lane.push(s.is_some());
                    // Lanes without a shadow ray: a zero ray (invalid: a miss).
                    shadow.push(s.unwrap_or(Ray {
                        org: [0.0; 3],
                        dir: [0.0; 3],
                        tmin: 0.0,
                        tmax: 0.0,
                    }));
                }
                let mut occ = vec![SceneHit::MISS; rays.len()];
                trace(slot, &shadow, true, &mut occ)?;
                let mut out = Vec::with_capacity(rays.len());
                let mut traced = 0u64;
                for k in 0..rays.len() {
                    let Some((x, y)) = px[k] else { continue };
                    traced += 1 + lit_lane[k] as u64;
                    let hit = &hits[k];
                    let c = if let Some(t) = &tris[k] {
                        let nrm = t.normal().normalize_or_zero();
                        let p = Vec3::from(rays[k].org) + hit.t * Vec3::from(rays[k].dir);
                        let l = (Vec3::from(light.position) - p).normalize_or_zero();
                        let lit = lit_lane[k] && !occ[k].is_hit();
                        let diffuse = if lit { nrm.dot(l).abs() } else { 0.0 };
                        palette(hit) * (0.18 + 0.82 * diffuse)
                    } else {
                        Vec3::new(0.55, 0.65, 0.8)
                    };
                    let b = |x: f32| (x.clamp(0.0, 1.0) * 255.0) as u8;
                    out.push((x, y, [b(c.x), b(c.y), b(c.z), 255]));
                }
                Ok((traced, out))
            })
            .collect()
    });
    let ns = t0.elapsed().as_nanos() as u64;
    let mut n_rays = 0;
    for r in rows {
        let (k, out) = r?;
        n_rays += k;
        for (x, y, c) in out {
            let at = 4 * (y as usize * w as usize + x as usize);
            pixels[at..at + 4].copy_from_slice(&c);
        }
    }
    Ok(Traced { rays: n_rays, ns })
}

pub fn engine(a: &EngineArgs) -> Result<()> {
    let threads = run::threads(a.threads)?;
    let (w, h) = a.size;
    if !a.dt.is_finite() {
        bail!("--dt {}: must be finite", a.dt);
    }
    let (env_name, env) = environment(&a.env)?;
    let mut anim = Animated::new(1);
    let balls = sheaf::scenes::builtin("balls")
        .context("built-in balls")?
        .mesh;
    // The built-in meshes without their floors (balls: its first 2
    // triangles; animated: its first 512, the ground grid at detail 1).
    let balls = Mesh {
        vertices: balls.vertices,
        indices: balls.indices[3 * 2..].to_vec(),
    };
    let tetra = sheaf::scenes::builtin("tetra")
        .context("built-in tetra")?
        .mesh;
    let tetra = Mesh {
        vertices: tetra.vertices,
        indices: tetra.indices,
    };
    let fence = panel();
    let anim_mesh = |a: &Animated| Mesh {
        vertices: a.mesh.vertices.clone(),
        indices: a.mesh.indices[3 * ANIMATED_GROUND..].to_vec(),
    };

    // Where things go: relative to the environment's bounds.
    let (lo, hi) = env.bounds();
    let d = hi - lo;
    let size = d.x.min(d.z).max(d.y * 0.5);
    let fit = |m: &Mesh, frac: f32| {
        let (a, b) = m.bounds();
        frac * size / (b - a).max_element().max(1e-12)
    };
    let (s_anim, s_balls, s_tetra, s_fence) = (
        fit(&anim_mesh(&anim), 0.12),
        fit(&balls, 0.08),
        fit(&tetra, 0.035),
        fit(&fence, 0.1),
    );

    // Ids: geometries 0 environment, 1 animated (refit), 2 balls (rebuilt),
    // 3 tetra, 4 the perforated panel; instances 0 environment, 1-4
    // animated, 5-6 balls, 7-22 tetra, 23-24 panels.
    let (n_env, n_anim, n_balls, n_tetra, n_fence) = (
        env.triangles(),
        anim_mesh(&anim).triangles(),
        balls.triangles(),
        tetra.triangles(),
        fence.triangles(),
    );
    let budget = n_env + n_anim + n_balls + n_tetra + n_fence;
    let flat_tris = n_env + 4 * n_anim + 2 * n_balls + 16 * n_tetra + 2 * n_fence;
    // The grid or kd-tree family: pools for the flattened scene.
    let mut limits = match a.family {
        Family::Bvh => Limits::for_triangles(16),
        Family::Grid | Family::Kd => Limits::for_triangles(flat_tris),
    };
    // The two-level scene's BVH pools come with `max_geometries`; the
    // grid or kd-tree family needs its own pools only.
    limits.structures = match a.family {
        Family::Bvh => Limits::BVH,
        Family::Grid => Limits::GRID,
        Family::Kd => Limits::KD,
    };
    limits.max_threads = threads;
    limits.max_geometries = 5;
    limits.max_instances = 25;
    limits.max_scene_triangles = budget;
    let mut ctx = OwnedContext::new(&limits)?;
    let bytes = required_bytes(&limits)?;
    let low = |mode| GeometryParams {
        mode,
        bvh: BvhParams {
            quality: BuildQuality::Low,
            ..BvhParams::default()
        },
        ..GeometryParams::default()
    };
    let t = Instant::now();
    ctx.set_geometry(0, &env.scene()?, &GeometryParams::default())
        .context("environment")?;
    let env_ms = t.elapsed().as_secs_f64() * 1e3;
    ctx.set_geometry(
        1,
        &anim_mesh(&anim).scene()?,
        &GeometryParams {
            mode: UpdateMode::Refit,
            ..GeometryParams::default()
        },
    )?;
    ctx.set_geometry(
        2,
        &balls.scene()?,
        &GeometryParams {
            max_triangles: n_balls,
            ..low(UpdateMode::Rebuild)
        },
    )?;
    ctx.set_geometry(3, &tetra.scene()?, &GeometryParams::default())?;
    ctx.set_geometry(
        4,
        &fence.scene()?,
        &GeometryParams {
            filter: Some(Filter::new(panel_filter, std::ptr::null_mut())),
            ..GeometryParams::default()
        },
    )?;
    ctx.set_instance(0, 0, &Affine::IDENTITY, !0)?;

    // The flattened alternative's context: one BVH over every instance.
    let mut flat = if a.no_flat || a.family != Family::Bvh {
        None
    } else {
        let mut l = Limits::for_triangles(flat_tris);
        l.structures = Limits::BVH;
        l.max_threads = threads;
        l.max_vertices = 3 * flat_tris;
        Some(OwnedContext::new(&l)?)
    };

    std::fs::create_dir_all(&a.out_dir)
        .with_context(|| format!("cannot create {}", a.out_dir.display()))?;
    // The view: the built-in scene's own, else an inside view of the
    // environment (the most open spot, `view::inside`, probed on a BVH of
    // it); the light a little above and beside the eye.
    // One BVH of the environment alone, for the view and the floor.
    let mut l = Limits::for_triangles(n_env);
    l.structures = Limits::BVH;
    l.max_vertices = (env.vertices.len() / 3) as u32;
    let mut probe = OwnedContext::new(&l)?;
    probe.build_bvh(&env.scene()?, &BvhParams::default())?;
    let view = match sheaf::scenes::builtin(env_name.trim_start_matches("builtin:")) {
        Some(b) if env_name.starts_with("builtin:") => b.views[0],
        _ => crate::view::inside(&probe.tracer()?, lo, hi, Vec3::Y, crate::view::INSIDE_FOV),
    };
    let camera = crate::view::camera(&view);
    // The light behind and above the eye, so what faces the camera is lit.
    let fwd = (view.look_at - view.eye).normalize_or_zero();
    let light_at = view.eye - 0.04 * d.max_element() * fwd + Vec3::new(0.0, 0.15 * d.y, 0.0);
    // The moving objects: on the floor in front of the camera.
    let ahead = view.eye + fwd * 0.12 * d.max_element();
    // The floor below that point (the environment's lowest point if none).
    let down = [Ray::new(
        Vec3::new(ahead.x, view.eye.y, ahead.z),
        -Vec3::Y,
        0.0,
        f32::INFINITY,
    )];
    let mut floor = [sheaf::Hit::MISS];
    probe.trace(Method::BvhSingle, &down, &mut floor)?;
    let floor_y = if floor[0].is_hit() {
        view.eye.y - floor[0].t
    } else {
        lo.y
    };
    let centre = Vec3::new(ahead.x, floor_y + 0.004 * size, ahead.z);
    let pr = PrimaryRays::new(&camera, w, h)?;
    let light = PointLight {
        position: light_at.to_array(),
        color: [1.0; 3],
        ..Default::default()
    };
    let p = TraceParams {
        method: match a.family {
            // The fastest packets through instances (two-level Embree
            // comparison: frame 1.74x Embree's time against Ranged's 2.44x).
            Family::Bvh => Method::BvhFrustum,
            Family::Grid => Method::GridCgt,
            Family::Kd => Method::KdPacket,
        },
        packet: a.packet,
        ..TraceParams::default()
    };
    let method = p.method.name();
    let mut pixels = vec![0u8; (w * h * 4) as usize];

    let prog = Progress::new("sheaf demo", a.frames as u64);
    prog.say(format_args!(
        "sheaf demo: {env_name} ({n_env} triangles, built once in {env_ms:.1} ms) + animated ({n_anim}, refit, 4 instances) + balls (up to {n_balls}, rebuilt, 2) + tetra ({n_tetra}, static, 16) + perforated panels ({n_fence}, any-hit filter, 2); {flat_tris} instanced triangles; {w}x{h}, {method} {0}x{0} packets, {threads} threads, context {1:.1} MiB",
        a.packet,
        mib(bytes)
    ));
    prog.say(format_args!(
        "{:>5} {:>8} {:>8} {:>9} {:>8} {:>7} {:>9} {:>10} {:>9} {:>9} {:>8} {:>24}",
        "frame",
        "refit ms",
        "SAH x",
        "rebuilt",
        "LOW ms",
        "moving",
        "place+commit",
        match a.family {
            Family::Bvh => "-",
            Family::Grid => "grid ms",
            Family::Kd => "kd ms",
        },
        "trace ms",
        "frame ms",
        "Mrays/s",
        "flat ms (build + trace)"
    ));
    // The animated PNG, written frame by frame.
    let mut apng = apng_writer(&a.out_dir.join("engine.png"), a.frames, w, h, a.dt)?;
    let mut sums = (0.0f64, 0.0f64);
    for f in 0..a.frames {
        let time = f as f32 * a.dt;
        // 1. What moved: the animated mesh (refit), the balls' triangle count (rebuild).
        anim.set_time(time);
        let am = anim_mesh(&anim);
        let t = Instant::now();
        let u1 = ctx
            .update_geometry(1, &am.scene()?)
            .with_context(|| format!("frame {f}: refit"))?;
        let refit_ms = t.elapsed().as_secs_f64() * 1e3;
        let k = ((0.55 + 0.45 * (time * 1.3).sin()) * n_balls as f32).max(1.0) as usize;
        let bm = Mesh {
            vertices: balls.vertices.clone(),
            indices: balls.indices[..3 * k].to_vec(),
        };
        let t = Instant::now();
        ctx.update_geometry(2, &bm.scene()?)
            .with_context(|| format!("frame {f}: rebuild"))?;
        let rebuild_ms = t.elapsed().as_secs_f64() * 1e3;
        // 2. Instances: the animated mesh orbits, the balls bob, the ring turns.
        let mut placed = vec![(0u32, Affine::IDENTITY)];
        for i in 0..4 {
            let ang = time * 0.5 + i as f32 * std::f32::consts::FRAC_PI_2;
            let at = centre + 0.28 * size * Vec3::new(ang.cos(), 0.0, ang.sin());
            placed.push((1, place(-ang, s_anim, at)));
        }
        for i in 0..2 {
            let at = centre
                + Vec3::new(
                    (i as f32 - 0.5) * 0.2 * size,
                    0.06 * size * (1.0 + (time * 2.0 + i as f32).sin()),
                    0.0,
                );
            placed.push((2, place(0.0, s_balls, at)));
        }
        for i in 0..16 {
            let ang = time * 0.3 + i as f32 * std::f32::consts::TAU / 16.0;
            let at = centre
                + Vec3::new(
                    0.42 * size * ang.cos(),
                    0.02 * size,
                    0.42 * size * ang.sin(),
                );
            placed.push((3, place(ang * 2.0, s_tetra, at)));
        }
        // The panels stand still on either side, nearer the camera than
        // the ring and facing it, between the light and the floor.
        let flat_fwd = Vec3::new(fwd.x, 0.0, fwd.z).normalize_or_zero();
        let side = flat_fwd.cross(Vec3::Y);
        let facing = flat_fwd.x.atan2(flat_fwd.z);
        for i in 0..2 {
            let s = if i == 0 { -1.0 } else { 1.0 };
            let at = centre + flat_fwd * 0.1 * size + side * s * 0.07 * size;
            placed.push((4, place(facing + s * 0.4, s_fence, at)));
        }
        // The instances placed and the top level committed.
        let t = Instant::now();
        for (i, (g, x)) in placed.iter().enumerate().skip(1) {
            ctx.set_instance(i as u32, *g, x, !0)?;
        }
        let info = ctx.commit_scene()?;
        let commit_ms = t.elapsed().as_secs_f64() * 1e3;
        let eps = SHADOW_OFFSET * info.bounds.diagonal().length();
        // The grid or kd-tree: rebuilt over the flattened scene.
        let t = Instant::now();
        let par = run::Broadcast::of(threads);
        match a.family {
            Family::Bvh => {}
            Family::Grid => {
                ctx.build_grid_scene_with(&sheaf::GridParams::default(), !0, &par)
                    .with_context(|| format!("frame {f}: grid"))?;
            }
            Family::Kd => {
                ctx.build_kd_scene_with(&sheaf::KdParams::default(), !0, &par)
                    .with_context(|| format!("frame {f}: kd-tree"))?;
            }
        }
        let build_ms = t.elapsed().as_secs_f64() * 1e3;

        // 3. Camera and shadow rays through the two-level scene.
        let view = &ctx;
        let meshes: [&Mesh; 5] = [&env, &am, &bm, &tetra, &fence];
        let scene_trace =
            |slot: usize, rays: &[Ray], any: bool, out: &mut [SceneHit]| -> Result<()> {
                view.trace_scene_each(
                    Some(&p),
                    Some(slot as u32),
                    rays.len(),
                    !0,
                    any,
                    |i| rays[i],
                    |i, sh| out[i] = sh,
                )?;
                Ok(())
            };
        let world_tri = |hit: &SceneHit| {
            let (g, x) = placed[hit.instance as usize];
            let m = meshes[g as usize];
            let v = |k: usize| {
                let i = m.indices[3 * hit.prim as usize + k] as usize;
                x.point([
                    m.vertices[3 * i],
                    m.vertices[3 * i + 1],
                    m.vertices[3 * i + 2],
                ])
            };
            sheaf::geom::TriVerts {
                v0: v(0),
                v1: v(1),
                v2: v(2),
            }
        };
        let colour = |hit: &SceneHit| match hit.geometry {
            0 => Vec3::new(0.85, 0.8, 0.7),
            1 => Vec3::new(0.9, 0.35, 0.2),
            2 => Vec3::new(0.25, 0.55, 0.95),
            4 => Vec3::new(0.95, 0.8, 0.25),
            _ => Vec3::new(0.3, 0.85, 0.35),
        };
        let img = Image {
            pr: &pr,
            w,
            h,
            n: a.packet,
        };
        let scene = TracedScene {
            trace: &scene_trace,
            tri: &world_tri,
            palette: &colour,
        };
        let tr = render(&scene, &img, &light, eps, &mut pixels, threads)?;
        run::write_png(&a.out_dir.join(format!("frame_{f:03}.png")), &pixels, w, h)?;
        apng.write_image_data(&pixels)?;

        // 4. The flattened alternative: every instance's world triangles,
        // one BVH rebuilt (LOW, joined), the same rays.
        let flat_ms = if let Some(fc) = flat.as_mut() {
            let t = Instant::now();
            let (mut fv, mut fi) = (
                Vec::with_capacity(9 * flat_tris as usize),
                Vec::with_capacity(3 * flat_tris as usize),
            );
            for (g, x) in &placed {
                let m = meshes[*g as usize];
                for tri in m.indices.chunks_exact(3) {
                    for &i in tri {
                        let i = i as usize;
                        fi.push((fv.len() / 3) as u32);
                        fv.extend(x.point([
                            m.vertices[3 * i],
                            m.vertices[3 * i + 1],
                            m.vertices[3 * i + 2],
                        ]));
                    }
                }
            }
            let fs = Scene::from_f32(&fv, &fi)?;
            // The panels are the last instances: their triangles the last.
            let from = fi.len() / 3 - 2 * n_fence as usize;
            fc.set_filter(Some(Filter::new(
                flat_filter,
                from as *mut std::ffi::c_void,
            )));
            let bp = BvhParams {
                quality: BuildQuality::Low,
                width: 2,
                ..BvhParams::default()
            };
            fc.build_bvh_with(&fs, &bp, &run::Broadcast::of(threads))?;
            let build_ms = t.elapsed().as_secs_f64() * 1e3;
            let flat_view = &*fc;
            let flat_trace =
                |slot: usize, rays: &[Ray], any: bool, out: &mut [SceneHit]| -> Result<()> {
                    flat_view.trace_each(
                        Some(slot as u32),
                        &p,
                        rays.len(),
                        |i| rays[i],
                        |i, h4, lane| {
                            let h = h4.lane(lane);
                            out[i] = SceneHit {
                                t: h.t,
                                u: h.u,
                                v: h.v,
                                prim: h.prim,
                                geometry: 0,
                                instance: 0,
                            };
                        },
                        any,
                    )?;
                    Ok(())
                };
            let flat_tri = |hit: &SceneHit| {
                let k = 9 * hit.prim as usize;
                sheaf::geom::TriVerts {
                    v0: [fv[k], fv[k + 1], fv[k + 2]],
                    v1: [fv[k + 3], fv[k + 4], fv[k + 5]],
                    v2: [fv[k + 6], fv[k + 7], fv[k + 8]],
                }
            };
            let grey = |_: &SceneHit| Vec3::splat(0.8);
            let mut scratch = vec![0u8; pixels.len()];
            let flat_scene = TracedScene {
                trace: &flat_trace,
                tri: &flat_tri,
                palette: &grey,
            };
            let ft = render(&flat_scene, &img, &light, eps, &mut scratch, threads)?;
            Some((t.elapsed().as_secs_f64() * 1e3, build_ms, ms(ft.ns)))
        } else {
            None
        };

        let moving = 4 * n_anim + 2 * k as u32 + 16 * n_tetra;
        let frame_ms = refit_ms + rebuild_ms + commit_ms + build_ms + ms(tr.ns);
        prog.say(format_args!(
            "{f:>5} {refit_ms:>8.2} {:>8.3} {:>9} {rebuild_ms:>8.2} {:>6.1}% {commit_ms:>9.3} {:>10} {:>9.2} {frame_ms:>9.2} {:>8.2} {:>24}",
            u1.refit.map_or(1.0, |r| r.growth()),
            k,
            100.0 * moving as f64 / flat_tris as f64,
            if a.family == Family::Bvh {
                "-".to_string()
            } else {
                format!("{build_ms:.2}")
            },
            ms(tr.ns),
            mrays(tr.rays, tr.ns),
            flat_ms.map_or("-".into(), |(m, b, t)| format!("{m:.2} ({b:.1} + {t:.1})"))
        ));
        prog.step();
        sums.0 += frame_ms;
        sums.1 += flat_ms.map_or(0.0, |m| m.0);
    }
    apng.finish()?;
    let n = a.frames as f64;
    if flat.is_none() {
        prog.say(format_args!("mean frame {:.2} ms", sums.0 / n));
    } else {
        prog.say(format_args!(
            "mean frame {:.2} ms against {:.2} ms flattened (rebuild every instance's triangles + the same rays): {:.2}x",
            sums.0 / n,
            sums.1 / n,
            sums.0 / sums.1
        ));
    }
    prog.say(format_args!(
        "frames and the animated engine.png in {}",
        a.out_dir.display()
    ));
    Ok(())
}

/// An animated PNG (APNG) of `frames` RGBA frames, `dt` seconds each,
/// taking one frame per `write_image_data` (none kept in memory).
fn apng_writer(
    path: &std::path::Path,
    frames: u32,
    w: u32,
    h: u32,
    dt: f32,
) -> Result<png::Writer<std::io::BufWriter<std::fs::File>>> {
    let file =
        std::fs::File::create(path).with_context(|| format!("cannot create {}", path.display()))?;
    let mut enc = png::Encoder::new(std::io::BufWriter::new(file), w, h);
    enc.set_color(png::ColorType::Rgba);
    enc.set_depth(png::BitDepth::Eight);
    enc.set_animated(frames, 0)?;
    enc.set_frame_delay((dt * 1000.0).round().clamp(1.0, 65535.0) as u16, 1000)?;
    Ok(enc.write_header()?)
}
