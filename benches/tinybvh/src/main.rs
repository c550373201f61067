//! tinybvh_bench: sheaf's BVH against tinybvh (through the tinybvh-rs
//! crate) on the same triangles and the same camera rays.
//!
//!   tinybvh_bench [--reps N] [--threads 1] SCENE.scene...
//!
//! Each SCENE.scene is written by `sheaf export` (cli/src/cmd/export.rs
//! documents the format). For each scene the program
//!
//!  1. makes the camera rays of every pixel with `PrimaryRays::ray` (what
//!     `sheaf_frame_camera_ray` returns), in benches/embree's packet order:
//!     32x32 pixel tiles row by row, inside a tile 2x2 quads in Morton
//!     order, so every run of 256 rays is a 16x16 pixel packet;
//!  2. builds sheaf's BVH at `BuildQuality::Medium` and `High` (median
//!     build time, SAH cost) and traces the camera rays on one thread with
//!     `bvh-single` (the reference hits: Medium's), `bvh-wide` (single
//!     rays through the 4-wide tree) and `bvh-frustum 16x16` (packets);
//!  3. builds tinybvh's `BVH` with `Build` (binned SAH) and `BuildHQ`
//!     (SBVH: spatial splits) and, when compiled with AVX2, `BVH8_CPU`
//!     (either tree, leaves split to 4, through `MBVH<8>`), and traces the
//!     same rays one by one with their `Intersect`;
//!  4. counts the rays whose hit differs from the reference (a hit against
//!     a miss, another triangle, or t off by more than `T_REL` relative),
//!     without asserting anything;
//!  5. prints one Markdown table per scene on stdout (progress on stderr).
//!
//! Times: median of `--reps` runs after one untimed run of each build and
//! trace. tinybvh's time includes making its ray from sheaf's (normalised
//! direction, reciprocal), as sheaf's trace includes its own ray setup and
//! as benches/embree times Embree with its ray conversion.
//!
//! tinybvh-rs 0.1.0-beta.3 exposes no occlusion query (tinybvh's
//! `IsOccluded`): shadow rays are not timed, and the output says so.

use std::fmt::Display;
use std::process::ExitCode;
use std::time::Instant;

use sheaf::{
    BuildQuality, BvhParams, Camera, Hit, Limits, Method, OwnedContext, PrimaryRays, Ray, RayKind,
    Scene, TraceParams,
};
use tinybvh_rs::{Intersection, Intersector, bvh};

/// The peer and the tinybvh version it vendors (Cargo.toml pins the crate).
const PEER: &str = "tinybvh-rs 0.1.0-beta.3 (tinybvh 1.6.8)";

/// Hits whose t differ by more than this, relative to the larger, count as
/// a t mismatch (tinybvh's Moeller-Trumbore test along its normalised
/// direction rounds differently from sheaf's in the last bits).
const T_REL: f64 = 1e-4;

/// Side of the pixel tiles the rays are ordered in (benches/embree's CHUNK).
const TILE: u32 = 32;

/// tinybvh builds run on its thread pool above this many triangles
/// (`MT_BUILD_THRESHOLD` in tiny_bvh.h 1.6.8) unless NO_THREADED_BUILDS.
const MT_BUILD_THRESHOLD: u32 = 50_000;

/// `RAY_MASK_INTERSECT_ALL`: what tinybvh's `Ray` constructor puts in the
/// mask field, which tinybvh-rs calls `padding_0`.
const RAY_MASK_ALL: u32 = 0xFFFF;

fn progress(msg: impl Display) {
    eprintln!("{msg}");
}

// ---- the scene file (sheaf export) ------------------------------------------

/// A scene as `sheaf export` wrote it (the animation frames, if any, are
/// checked for size and ignored).
struct SceneFile {
    name: String,
    view: String,
    width: u32,
    height: u32,
    camera: Camera,
    /// Triangles sheaf's structures exclude (non-finite or zero area).
    excluded: u32,
    vertices: Vec<f32>,
    indices: Vec<u32>,
}

/// Little-endian reads from the file's bytes, each checked for length.
struct Reader<'a> {
    path: &'a str,
    buf: &'a [u8],
    off: usize,
}

impl Reader<'_> {
    fn bytes(&mut self, n: usize) -> Result<&[u8], String> {
        let end = self.off.checked_add(n).filter(|&e| e <= self.buf.len());
        let end = end.ok_or_else(|| format!("{}: truncated", self.path))?;
        let b = &self.buf[self.off..end];
        self.off = end;
        Ok(b)
    }
    fn u32(&mut self) -> Result<u32, String> {
        let b = self.bytes(4)?;
        Ok(u32::from_le_bytes([b[0], b[1], b[2], b[3]]))
    }
    fn f32(&mut self) -> Result<f32, String> {
        self.u32().map(f32::from_bits)
    }
    fn vec3(&mut self) -> Result<[f32; 3], String> {
        Ok([self.f32()?, self.f32()?, self.f32()?])
    }
    fn string(&mut self) -> Result<String, String> {
        let n = self.u32()? as usize;
        Ok(String::from_utf8_lossy(self.bytes(n)?).into_owned())
    }
}

/// The scene's short name, as benches/embree's `short_name`: the label's
/// file name without `builtin:` or `.obj`.
fn short_name(label: &str) -> String {
    let base = label.rsplit('/').next().unwrap_or(label);
    let base = base.strip_prefix("builtin:").unwrap_or(base);
    base.strip_suffix(".obj").unwrap_or(base).to_string()
}

fn read_scene(path: &str) -> Result<SceneFile, String> {
    let buf = std::fs::read(path).map_err(|e| format!("cannot read {path}: {e}"))?;
    let mut r = Reader {
        path,
        buf: &buf,
        off: 0,
    };
    if r.bytes(8)? != b"SHEAFSC1" || r.u32()? != 1 {
        return Err(format!(
            "{path}: not a version 1 sheaf export (run `sheaf export`)"
        ));
    }
    let (nv, nt) = (r.u32()?, r.u32()?);
    let (width, height) = (r.u32()?, r.u32()?);
    let camera = Camera {
        eye: r.vec3()?,
        look_at: r.vec3()?,
        up: r.vec3()?,
        fov_y_deg: r.f32()?,
    };
    let _light = r.vec3()?;
    let _shadow_eps = r.f32()?;
    let excluded = r.u32()?;
    let label = r.string()?;
    let view = r.string()?;
    let vertices = (0..3 * nv as usize)
        .map(|_| r.f32())
        .collect::<Result<Vec<f32>, String>>()?;
    let indices = (0..3 * nt as usize)
        .map(|_| r.u32())
        .collect::<Result<Vec<u32>, String>>()?;
    if let Some(&i) = indices.iter().find(|&&i| i >= nv) {
        return Err(format!("{path}: index {i} out of range"));
    }
    if r.off != buf.len() {
        // The optional animation: u32 F, then F frames of 3 V floats.
        let frames = r.u32()? as usize;
        let expected = r.off + 12 * nv as usize * frames;
        if buf.len() != expected {
            return Err(format!(
                "{path}: {} bytes, expected {expected} for {frames} frames",
                buf.len()
            ));
        }
    }
    Ok(SceneFile {
        name: short_name(&label),
        view,
        width,
        height,
        camera,
        excluded,
        vertices,
        indices,
    })
}

// ---- rays ---------------------------------------------------------------------

/// Quad (x, y) of Morton index i (x in the even bits), as sheaf's renderer.
fn demorton(i: u32) -> (u32, u32) {
    let (mut x, mut y) = (0, 0);
    for b in 0..5 {
        x |= ((i >> (2 * b)) & 1) << b;
        y |= ((i >> (2 * b + 1)) & 1) << b;
    }
    (x, y)
}

/// The camera rays of every pixel in benches/embree's packet order (32x32
/// tiles row by row, 2x2 quads in Morton order, lanes (x, y), (x + 1, y),
/// (x, y + 1), (x + 1, y + 1)).
fn camera_rays(s: &SceneFile) -> Result<Vec<Ray>, String> {
    let (w, h) = (s.width, s.height);
    if w == 0 || h == 0 || w % TILE != 0 || h % TILE != 0 {
        return Err(format!(
            "{}: image {w}x{h}: width and height must be multiples of {TILE}",
            s.name
        ));
    }
    let pr = PrimaryRays::new(&s.camera, w, h).map_err(|e| format!("{}: camera: {e}", s.name))?;
    let mut rays = Vec::with_capacity(w as usize * h as usize);
    for ty in (0..h).step_by(TILE as usize) {
        for tx in (0..w).step_by(TILE as usize) {
            for q in 0..(TILE / 2) * (TILE / 2) {
                let (qx, qy) = demorton(q);
                for l in 0..4 {
                    rays.push(pr.ray(tx + 2 * qx + (l & 1), ty + 2 * qy + (l >> 1)));
                }
            }
        }
    }
    Ok(rays)
}

// ---- results and their agreement ------------------------------------------------

/// One ray's answer: `t` in units of the ray's own direction (sheaf's), the
/// triangle, or `None` for a miss.
#[derive(Clone, Copy)]
struct Found {
    t: f64,
    prim: Option<u32>,
}

impl From<&Hit> for Found {
    fn from(h: &Hit) -> Found {
        Found {
            t: h.t as f64,
            prim: h.is_hit().then_some(h.prim),
        }
    }
}

/// Rays that disagree with the reference.
#[derive(Default)]
struct Mismatches {
    /// One hit, the other missed.
    hit_miss: usize,
    /// Both hit, different triangles.
    prim: usize,
    /// Of those, the ones whose t agree within `T_REL` (a tie: the ray
    /// through a shared edge, or coplanar triangles).
    prim_same_t: usize,
    /// Both hit, t off by more than `T_REL` relative.
    t: usize,
}

impl Display for Mismatches {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        if self.hit_miss + self.prim + self.t == 0 {
            return write!(f, "0");
        }
        write!(
            f,
            "{} hit/miss, {} prim ({} at the same t), {} t",
            self.hit_miss, self.prim, self.prim_same_t, self.t
        )
    }
}

fn compare(reference: &[Found], got: &[Found]) -> Mismatches {
    let mut m = Mismatches::default();
    for (r, g) in reference.iter().zip(got) {
        match (r.prim, g.prim) {
            (None, None) => {}
            (Some(a), Some(b)) => {
                let t_off = (r.t - g.t).abs() > T_REL * r.t.abs().max(g.t.abs());
                m.prim += usize::from(a != b);
                m.prim_same_t += usize::from(a != b && !t_off);
                m.t += usize::from(t_off);
            }
            _ => m.hit_miss += 1,
        }
    }
    m
}

/// One line of a scene's table.
struct Row {
    library: &'static str,
    build: String,
    build_ms: Option<f64>,
    sah: Option<f32>,
    trace: String,
    mrays: f64,
    mismatches: String,
}

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    let n = v.len();
    if n % 2 == 1 {
        v[n / 2]
    } else {
        0.5 * (v[n / 2 - 1] + v[n / 2])
    }
}

/// `f` once untimed, then `reps` timed runs: the median in ms and the last
/// result (the ones before it are dropped outside the timing).
fn time_builds<T, E: Display>(
    reps: usize,
    mut f: impl FnMut() -> Result<T, E>,
) -> Result<(f64, T), String> {
    let mut last = f().map_err(|e| e.to_string())?;
    let mut ms = Vec::with_capacity(reps);
    for _ in 0..reps {
        let t0 = Instant::now();
        let built = f().map_err(|e| e.to_string())?;
        ms.push(t0.elapsed().as_secs_f64() * 1e3);
        last = built;
    }
    Ok((median(ms), last))
}

/// `f` once untimed, then `reps` timed runs over `n` rays: Mrays/s of the
/// median run.
fn time_traces<E: Display>(
    reps: usize,
    n: usize,
    mut f: impl FnMut() -> Result<(), E>,
) -> Result<f64, String> {
    f().map_err(|e| e.to_string())?;
    let mut s = Vec::with_capacity(reps);
    for _ in 0..reps {
        let t0 = Instant::now();
        f().map_err(|e| e.to_string())?;
        s.push(t0.elapsed().as_secs_f64());
    }
    Ok(n as f64 / median(s) / 1e6)
}

// ---- sheaf ------------------------------------------------------------------------

/// sheaf's BVH at Medium and High, each traced three ways; the reference
/// hits (Medium, bvh-single) come back with the rows.
fn bench_sheaf(s: &SceneFile, rays: &[Ray], reps: usize) -> Result<(Vec<Row>, Vec<Found>), String> {
    let scene = Scene::from_f32(&s.vertices, &s.indices).map_err(|e| e.to_string())?;
    let mut limits = Limits::for_triangles(scene.triangle_count());
    limits.max_vertices = scene.vertex_count();
    limits.max_threads = 1;
    limits.structures = Limits::BVH;
    // A 50% reserve for the HIGH build's spatial splits (as the Embree
    // bench's default `--bvh-reserve 50`).
    limits.max_bvh_refs = limits.max_triangles + limits.max_triangles / 2;
    let mut rows = Vec::new();
    let mut reference: Option<Vec<Found>> = None;
    for (quality, qname) in [
        (BuildQuality::Medium, "BuildQuality::Medium"),
        (BuildQuality::High, "BuildQuality::High"),
    ] {
        let mut ctx = OwnedContext::new(&limits).map_err(|e| e.to_string())?;
        let params = BvhParams {
            quality,
            ..BvhParams::default()
        };
        let (build_ms, info) = time_builds(reps, || ctx.build_bvh(&scene, &params))?;
        progress(format_args!(
            "  sheaf {qname}: {build_ms:.1} ms, {} nodes, {} leaves, SAH {:.2}, {:.3} references per triangle",
            info.nodes, info.leaves, info.sah_cost, info.references as f64 / info.triangles.max(1) as f64
        ));
        let methods = [
            ("bvh-single", TraceParams::bvh(Method::BvhSingle, 0)),
            ("bvh-wide", TraceParams::bvh(Method::BvhWide, 0)),
            (
                "bvh-frustum 16x16",
                TraceParams::bvh(Method::BvhFrustum, 16).with_kind(RayKind::Primary),
            ),
        ];
        for (i, (mname, p)) in methods.iter().enumerate() {
            let mut hits = vec![Hit::MISS; rays.len()];
            let mrays = time_traces(reps, rays.len(), || {
                ctx.trace_with(p, rays, &mut hits).map(|_| ())
            })?;
            let found: Vec<Found> = hits.iter().map(Found::from).collect();
            let mismatches = match &reference {
                Some(r) => compare(r, &found).to_string(),
                None => {
                    reference = Some(found);
                    "reference".to_string()
                }
            };
            progress(format_args!(
                "  sheaf {mname}: {mrays:.2} Mrays/s, mismatches {mismatches}"
            ));
            rows.push(Row {
                library: "sheaf",
                build: qname.to_string(),
                build_ms: (i == 0).then_some(build_ms),
                sah: (i == 0).then_some(info.sah_cost),
                trace: mname.to_string(),
                mrays,
                mismatches,
            });
        }
    }
    let reference = reference.ok_or("no reference hits")?;
    Ok((rows, reference))
}

// ---- tinybvh ----------------------------------------------------------------------

/// One tinybvh ray with room for tinybvh's whole `Ray`. tinybvh-rs
/// 0.1.0-beta.3 declares `Ray` as 64 bytes aligned to 16, but the C++ type
/// it stands for (tiny_bvh.h 1.6.8, `INST_IDX_BITS` 32) is 128 bytes
/// aligned to 64: its `Intersection` grew `auxData` and 56 bytes of user
/// data after `prim`. The first 64 bytes agree (the C++ `hit.inst` is
/// `padding_2`), so a ray in this slot is read and written correctly, and
/// whatever the C++ side stores past byte 64 lands in `_tail`. For the same
/// reason rays are not made with `Ray::new`: its C++ constructor copies
/// 128 bytes into a 64-byte Rust value.
#[repr(C, align(64))]
#[derive(Clone, Copy)]
struct RaySlot {
    ray: tinybvh_rs::Ray,
    _tail: [u8; 64],
}

const _: () = assert!(size_of::<RaySlot>() >= 128 && align_of::<RaySlot>() >= 64);

/// tinybvh's safe reciprocal (`tinybvh_safercp`): 1/x, or +-1e30 near 0.
fn safe_rcp(x: f32) -> f32 {
    if x.abs() > 1e-12 {
        1.0 / x
    } else if x >= 0.0 {
        tinybvh_rs::INFINITE
    } else {
        -tinybvh_rs::INFINITE
    }
}

impl RaySlot {
    /// sheaf's ray as tinybvh's `Ray(origin, direction, t)` makes it: the
    /// direction normalised, its safe reciprocal, `hit.t` the far end along
    /// the normalised direction (1e30 for an unbounded ray). tinybvh has no
    /// tmin: it takes hits at t >= 0, as the camera rays' tmin 0.
    fn new(r: &Ray) -> RaySlot {
        let d = r.dir;
        let len = (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt();
        let rl = if len == 0.0 { 0.0 } else { 1.0 / len };
        let dir = d.map(|c| c * rl);
        let t = if r.tmax.is_finite() {
            (r.tmax * len).min(tinybvh_rs::INFINITE)
        } else {
            tinybvh_rs::INFINITE
        };
        RaySlot {
            ray: tinybvh_rs::Ray {
                origin: r.org,
                padding_0: RAY_MASK_ALL,
                dir,
                padding_1: 0,
                r_d: dir.map(safe_rcp),
                padding_2: 0,
                hit: Intersection {
                    t,
                    u: 0.0,
                    v: 0.0,
                    prim: 0,
                },
            },
            _tail: [0; 64],
        }
    }
}

/// Nearest hits of `rays` through `bvh`, one ray at a time, as raw
/// (t along the normalised direction, prim).
fn trace_tiny(bvh: &impl Intersector, rays: &[Ray], out: &mut [(f32, u32)]) {
    for (r, o) in rays.iter().zip(out.iter_mut()) {
        let mut slot = RaySlot::new(r);
        bvh.intersect(&mut slot.ray);
        *o = (slot.ray.hit.t, slot.ray.hit.prim);
    }
}

/// tinybvh's raw answers in sheaf's terms: t divided by the length of the
/// ray's direction, misses (t left at 1e30) as `None`.
fn found_tiny(rays: &[Ray], raw: &[(f32, u32)]) -> Vec<Found> {
    rays.iter()
        .zip(raw)
        .map(|(r, &(t, prim))| {
            let len = r
                .dir
                .iter()
                .map(|&c| c as f64 * c as f64)
                .sum::<f64>()
                .sqrt();
            Found {
                t: t as f64 / len,
                prim: (t < tinybvh_rs::INFINITE).then_some(prim),
            }
        })
        .collect()
}

/// The triangles as tinybvh takes them: three 4-float vertices each, in
/// index order (so its primitive ids are sheaf's triangle ids). A triangle
/// with a non-finite vertex (which sheaf excludes and tinybvh's build does
/// not expect) becomes a zero-area one at a finite vertex of the scene,
/// which no ray hits; how many is returned too.
fn tiny_positions(s: &SceneFile) -> (Vec<[f32; 4]>, usize) {
    let vertex = |i: u32| {
        let i = 3 * i as usize;
        [s.vertices[i], s.vertices[i + 1], s.vertices[i + 2], 0.0]
    };
    let finite = |v: &[f32; 4]| v.iter().all(|c| c.is_finite());
    let fill = s
        .vertices
        .chunks_exact(3)
        .find(|v| v.iter().all(|c| c.is_finite()))
        .map_or([0.0; 4], |v| [v[0], v[1], v[2], 0.0]);
    let mut replaced = 0;
    let mut out = Vec::with_capacity(s.indices.len());
    for t in s.indices.chunks_exact(3) {
        let tri = [vertex(t[0]), vertex(t[1]), vertex(t[2])];
        if tri.iter().all(finite) {
            out.extend(tri);
        } else {
            out.extend([fill; 3]);
            replaced += 1;
        }
    }
    (out, replaced)
}

/// tinybvh's `BVH8_CPU` as tinybvh-rs builds it: the binary BVH (`Build`
/// or `BuildHQ`), its leaves split to 4 triangles, converted to `MBVH<8>`,
/// then to `BVH8_CPU` (which copies the triangles into its leaves and keeps
/// no reference to the two trees).
#[cfg(target_feature = "avx2")]
fn build_bvh8(
    positions: &[[f32; 4]],
    hq: bool,
) -> Result<tinybvh_rs::bvh8_cpu::BVH, tinybvh_rs::Error> {
    let mut b = if hq {
        bvh::BVH::new_hq(positions.into())?
    } else {
        bvh::BVH::new(positions.into())?
    };
    b.split_leaves(4);
    let m = tinybvh_rs::mbvh::BVH::new(&b);
    tinybvh_rs::bvh8_cpu::BVH::new(&m)
}

/// Times the traversal of a built tinybvh structure and checks its hits.
fn tiny_row(
    rays: &[Ray],
    reference: &[Found],
    reps: usize,
    bvh: &impl Intersector,
    build: (&str, f64, Option<f32>),
    trace: &str,
) -> Result<Row, String> {
    let mut raw = vec![(0.0f32, 0u32); rays.len()];
    let mrays = time_traces(reps, rays.len(), || {
        trace_tiny(bvh, rays, &mut raw);
        Ok::<(), String>(())
    })?;
    let mismatches = compare(reference, &found_tiny(rays, &raw)).to_string();
    progress(format_args!(
        "  tinybvh {} / {trace}: {mrays:.2} Mrays/s, mismatches {mismatches}",
        build.0
    ));
    Ok(Row {
        library: "tinybvh",
        build: build.0.to_string(),
        build_ms: Some(build.1),
        sah: build.2,
        trace: trace.to_string(),
        mrays,
        mismatches,
    })
}

fn bench_tinybvh(
    s: &SceneFile,
    rays: &[Ray],
    reference: &[Found],
    reps: usize,
) -> Result<(Vec<Row>, Vec<String>), String> {
    let (positions, replaced) = tiny_positions(s);
    let mut notes = Vec::new();
    if replaced > 0 {
        notes.push(format!(
            "{replaced} triangles with a non-finite vertex given to tinybvh as zero-area triangles."
        ));
    }
    let mut rows = Vec::new();
    for (name, hq) in [
        ("BVH Build (binned SAH, 8 bins)", false),
        ("BVH BuildHQ (SBVH)", true),
    ] {
        let (ms, b) = time_builds(reps, || {
            if hq {
                bvh::BVH::new_hq(positions.as_slice().into())
            } else {
                bvh::BVH::new(positions.as_slice().into())
            }
        })?;
        let sah = b.sah_cost(0);
        progress(format_args!(
            "  tinybvh {name}: {ms:.1} ms, {} nodes, SAH {sah:.2}",
            b.nodes().len()
        ));
        rows.push(tiny_row(
            rays,
            reference,
            reps,
            &b,
            (name, ms, Some(sah)),
            "BVH::Intersect",
        )?);
    }
    #[cfg(target_feature = "avx2")]
    for (name, hq) in [
        ("BVH8_CPU from Build", false),
        ("BVH8_CPU from BuildHQ", true),
    ] {
        let (ms, b8) = time_builds(reps, || build_bvh8(&positions, hq))?;
        progress(format_args!("  tinybvh {name}: {ms:.1} ms"));
        rows.push(tiny_row(
            rays,
            reference,
            reps,
            &b8,
            (name, ms, None),
            "BVH8_CPU::Intersect",
        )?);
    }
    #[cfg(not(target_feature = "avx2"))]
    notes.push(
        "BVH8_CPU not run: tinybvh-rs implements its Intersect only when compiled with AVX2 \
         (build with RUSTFLAGS=\"-C target-cpu=native\")."
            .to_string(),
    );
    Ok((rows, notes))
}

// ---- the machine ------------------------------------------------------------------

fn cpu_model() -> String {
    std::fs::read_to_string("/proc/cpuinfo")
        .ok()
        .and_then(|s| {
            s.lines()
                .find(|l| l.starts_with("model name"))
                .and_then(|l| l.split_once(':'))
                .map(|(_, m)| m.trim().to_string())
        })
        .unwrap_or_else(|| "unknown CPU".to_string())
}

fn load_average() -> String {
    std::fs::read_to_string("/proc/loadavg")
        .map(|s| s.split_whitespace().take(3).collect::<Vec<_>>().join(" "))
        .unwrap_or_else(|_| "unknown".to_string())
}

fn cores() -> usize {
    std::thread::available_parallelism().map_or(1, |n| n.get())
}

/// Whether tinybvh was compiled single-threaded: cc (under cxx-build)
/// passes CXXFLAGS from these variables to the C++ compiler, and this crate
/// is rebuilt when they change.
fn tinybvh_single_threaded() -> bool {
    [
        option_env!("CXXFLAGS"),
        option_env!("TARGET_CXXFLAGS"),
        option_env!("CXXFLAGS_x86_64_unknown_linux_gnu"),
        option_env!("CXXFLAGS_x86_64-unknown-linux-gnu"),
    ]
    .iter()
    .flatten()
    .any(|f| f.contains("NO_THREADED_BUILDS"))
}

// ---- main -------------------------------------------------------------------------

const USAGE: &str = "usage: tinybvh_bench [--reps N] [--threads 1] SCENE.scene...
  SCENE.scene: written by `sheaf export` (benches/embree/run.sh makes them in
  target/embree-bench/scenes/). --reps: timed runs per build and trace, the
  median reported (default 5). --threads: tracing threads, 1 only.";

struct Options {
    reps: usize,
    scenes: Vec<String>,
}

fn parse_args() -> Result<Options, String> {
    let mut o = Options {
        reps: 5,
        scenes: Vec::new(),
    };
    let mut args = std::env::args().skip(1);
    while let Some(a) = args.next() {
        match a.as_str() {
            "-h" | "--help" => {
                println!("{USAGE}");
                std::process::exit(0);
            }
            "--reps" => {
                let v = args.next().ok_or("--reps needs a value")?;
                o.reps = v
                    .parse()
                    .ok()
                    .filter(|&n| n >= 1)
                    .ok_or(format!("--reps {v}: want a count >= 1"))?;
            }
            "--threads" => {
                let v = args.next().ok_or("--threads needs a value")?;
                if v != "1" {
                    return Err(format!(
                        "--threads {v}: only 1 thread is supported (tinybvh traces single rays on the caller's thread)"
                    ));
                }
            }
            _ if a.starts_with('-') => return Err(format!("unknown option {a}\n{USAGE}")),
            _ => o.scenes.push(a),
        }
    }
    if o.scenes.is_empty() {
        return Err(USAGE.to_string());
    }
    Ok(o)
}

fn bench_scene(path: &str, reps: usize) -> Result<(), String> {
    let s = read_scene(path)?;
    let load = load_average();
    let nt = s.indices.len() / 3;
    progress(format_args!(
        "== {}: {nt} triangles, {} vertices, {}x{}, {}",
        s.name,
        s.vertices.len() / 3,
        s.width,
        s.height,
        s.view
    ));
    let rays = camera_rays(&s)?;
    let (mut rows, reference) = bench_sheaf(&s, &rays, reps)?;
    let hits = reference.iter().filter(|f| f.prim.is_some()).count();
    let (tiny_rows, notes) = bench_tinybvh(&s, &rays, &reference, reps)?;
    rows.extend(tiny_rows);

    println!(
        "## {}: {nt} triangles ({} excluded by sheaf), {}x{} camera rays ({hits} hit), {}",
        s.name, s.excluded, s.width, s.height, s.view
    );
    println!();
    println!("Load average at the scene's start: {load}.");
    println!();
    println!("| library | build | build ms | SAH cost | trace | Mrays/s camera | mismatches |");
    println!("|---|---|--:|--:|---|--:|---|");
    for r in &rows {
        let ms = r.build_ms.map_or(String::new(), |v| format!("{v:.1}"));
        let sah = r.sah.map_or(String::new(), |v| format!("{v:.2}"));
        println!(
            "| {} | {} | {ms} | {sah} | {} | {:.2} | {} |",
            r.library, r.build, r.trace, r.mrays, r.mismatches
        );
    }
    println!();
    for n in &notes {
        println!("{n}");
    }
    println!(
        "Occlusion: {PEER} exposes no occlusion query (tinybvh's BVH::IsOccluded and \
         BVH8_CPU::IsOccluded are not in its bridge): shadow rays not timed."
    );
    println!();
    Ok(())
}

fn main() -> ExitCode {
    let o = match parse_args() {
        Ok(o) => o,
        Err(e) => {
            eprintln!("tinybvh_bench: {e}");
            return ExitCode::from(2);
        }
    };
    println!("# sheaf against tinybvh");
    println!();
    println!(
        "CPU: {}, {} online cores; load average at start: {}.",
        cpu_model(),
        cores(),
        load_average()
    );
    let threads = if tinybvh_single_threaded() {
        "single-threaded builds (NO_THREADED_BUILDS)".to_string()
    } else {
        format!(
            "builds on its thread pool above {MT_BUILD_THRESHOLD} triangles ({} workers; CXXFLAGS=-DNO_THREADED_BUILDS for one)",
            cores()
        )
    };
    println!("Peer: {PEER}, C++ compiled at -march=native, {threads}.");
    println!(
        "Rust code (sheaf, tinybvh-rs) compiled {}.",
        if cfg!(target_feature = "avx2") {
            "with AVX2 enabled (e.g. RUSTFLAGS=\"-C target-cpu=native\")"
        } else {
            "for baseline x86-64 (sheaf picks its SIMD width at run time)"
        }
    );
    println!(
        "Median of {} runs after one untimed run; tracing on 1 thread, camera rays one \
         per pixel in benches/embree's packet order; tinybvh's time includes making its \
         rays (normalised direction, reciprocal). Mismatches against sheaf bvh-single on \
         the Medium tree: one hit and one miss (hit/miss), both hit but another triangle \
         (prim; in parentheses those at the same t: ties at a shared edge or between \
         coplanar triangles), or both hit with t off by more than {T_REL:e} relative (tinybvh's t, along its normalised direction, \
         divided by the direction's length).",
        o.reps
    );
    println!();
    for path in &o.scenes {
        if let Err(e) = bench_scene(path, o.reps) {
            eprintln!("tinybvh_bench: {e}");
            return ExitCode::FAILURE;
        }
    }
    ExitCode::SUCCESS
}
