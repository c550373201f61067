//! Fuzz the C ABI exactly as a C program calls it: raw pointers, sizes and
//! counts, enum values as plain integers, on one context per input.
//!
//! An input is a context (arbitrary `sheaf_limits`, owned or in a caller
//! buffer that may be short or misaligned) and a sequence of calls:
//! set_geometry (arbitrary vertex and index buffers, strides, counts that
//! lie within the real buffers, NULL and misaligned pointers, NaN/Inf and
//! huge vertices, out-of-range indices), in-place edits of the borrowed
//! buffers, the four builds with arbitrary parameters, trace / trace_with /
//! occluded (unaligned, overlapping, NULL arrays), render / render_with /
//! render_whitted / render_deferred (arbitrary frames, strides, lengths,
//! lights, materials), the per-pixel queries, stats and last_error.
//!
//! The contract checked after every call (a violation panics, which
//! libFuzzer reports as a crash; a panic inside sheaf aborts through
//! libFuzzer's panic hook even though sheaf's boundary would catch it):
//! - the status is one of the documented codes, never `SHEAF_STATUS_PANIC`;
//! - on an error status no output byte changed (every output buffer is
//!   filled with a sentinel first), `sheaf_stats` did not change, and
//!   `sheaf_context_last_error` describes a failure;
//! - after a failed call, the last successful trace and render (since the
//!   last successful build) give exactly the same bytes again;
//! - a successful render writes alpha 255 and never the bytes between rows
//!   or past the last row; last_error always NUL-terminates inside `len`;
//! - with finite, moderate inputs every method of a structure returns its
//!   reference method's triangle and bitwise t (and occlusion answer), as
//!   the README promises.
#![no_main]

use arbitrary::Arbitrary;
use core::ffi::c_void;
use libfuzzer_sys::fuzz_target;
use sheaf::ffi::{
    self, sheaf_bvh_params, sheaf_context, sheaf_deferred_job, sheaf_frame, sheaf_grid_params,
    sheaf_hit, sheaf_kd_params, sheaf_pgrid_params, sheaf_ray, sheaf_stats, sheaf_status,
    sheaf_trace_params,
};
use sheaf::render::material::{Material, MaterialRange};
use sheaf::{Camera, Limits, PointLight, Shading};

mod scene;

const OK: sheaf_status = sheaf_status::Ok;
/// Contexts needing more bytes than this are only asked for their size and
/// given a short caller buffer (libFuzzer reports mallocs over its limit).
const MAX_CONTEXT_BYTES: usize = 48 << 20;
/// Sentinels for output buffers.
const S_HIT: u8 = 0xA5;
const S_PIX: u8 = 0x5A;
/// `sheaf_method` values (0-12: every method, the 4-wide tree's too).
const METHODS: u32 = 13;

// ---- inputs --------------------------------------------------------------------

/// A float: mostly small values that make real scenes, sometimes any bits.
#[derive(Arbitrary, Debug, Clone, Copy)]
enum F {
    Small(i8),
    Fine(i16),
    Special(u8),
    Bits(u32),
}

impl F {
    fn get(self) -> f32 {
        match self {
            F::Small(v) => v as f32 / 8.0,
            F::Fine(v) => v as f32 / 1024.0,
            F::Special(k) => [
                f32::NAN,
                f32::INFINITY,
                f32::NEG_INFINITY,
                0.0,
                -0.0,
                f32::MAX,
                f32::MIN,
                f32::MIN_POSITIVE,
                1e-40,
                1e18,
                -1e18,
                1e30,
                1.0,
                -1.0,
                0.5,
                1e-7,
            ][k as usize % 16],
            F::Bits(b) => f32::from_bits(b),
        }
    }
}

/// A parameter: `Small` values mapped into (mostly) the valid range, `Any` raw.
fn small(n: N, f: impl Fn(u32) -> u32) -> u32 {
    match n {
        N::Small(v) => f(v as u32),
        N::Any(v) => v,
    }
}

/// A cost: `Small` values positive, others raw.
fn positive(x: F) -> f32 {
    match x {
        F::Small(v) => (v as f32).abs() / 16.0 + 0.125,
        x => x.get(),
    }
}

fn v3(a: [F; 3]) -> [f32; 3] {
    [a[0].get(), a[1].get(), a[2].get()]
}

/// A count or size: small, or any value.
#[derive(Arbitrary, Debug, Clone, Copy)]
enum N {
    Small(u8),
    Any(u32),
}

impl N {
    fn get(self) -> u32 {
        match self {
            N::Small(v) => v as u32,
            N::Any(v) => v,
        }
    }
}

#[derive(Arbitrary, Debug)]
struct LimitsIn {
    wild: bool,
    max_triangles: u32,
    max_vertices: u32,
    max_image_width: u32,
    max_image_height: u32,
    max_tile: u32,
    max_threads: u32,
    max_grid_cells: u32,
    max_grid_refs: u32,
    projection_test: bool,
    structures: u32,
    max_kd_nodes: u32,
    max_kd_refs: u32,
    max_pgrid_cells: u32,
    max_pgrid_refs: u32,
    max_geometries: u32,
    max_instances: u32,
    max_scene_triangles: u32,
    max_packet_side: u32,
    max_bounces: u32,
    renderers: u32,
}

impl LimitsIn {
    fn get(&self) -> Limits {
        if self.wild {
            return Limits {
                max_triangles: self.max_triangles,
                max_vertices: self.max_vertices,
                max_image_width: self.max_image_width,
                max_image_height: self.max_image_height,
                max_tile: self.max_tile,
                max_threads: self.max_threads,
                max_grid_cells: self.max_grid_cells,
                max_grid_refs: self.max_grid_refs,
                projection_test: self.projection_test,
                structures: self.structures,
                max_kd_nodes: self.max_kd_nodes,
                max_kd_refs: self.max_kd_refs,
                max_pgrid_cells: self.max_pgrid_cells,
                max_pgrid_refs: self.max_pgrid_refs,
                max_geometries: self.max_geometries,
                max_instances: self.max_instances,
                max_scene_triangles: self.max_scene_triangles,
                max_packet_side: self.max_packet_side,
                max_bounces: self.max_bounces,
                renderers: self.renderers,
                max_bvh_refs: bvh_refs(self.max_triangles, self.max_tile >> 3, true),
            };
        }
        // Usable limits: small pools, every structure likely.
        let max_bvh_refs = bvh_refs(self.max_triangles % 160, self.max_tile >> 3, false);
        Limits {
            max_triangles: self.max_triangles % 160,
            max_vertices: self.max_vertices % 480,
            max_image_width: 1 + self.max_image_width % 40,
            max_image_height: 1 + self.max_image_height % 40,
            max_tile: [2, 4, 8, 16, 32, 64, 3, 0][self.max_tile as usize % 8],
            max_threads: 1 + self.max_threads % 3,
            max_grid_cells: default_or(self.max_grid_cells, 3000),
            max_grid_refs: default_or(self.max_grid_refs, 4000),
            projection_test: self.projection_test,
            structures: if self.structures % 4 == 0 {
                15
            } else {
                self.structures % 17
            },
            max_kd_nodes: default_or(self.max_kd_nodes, 1000),
            max_kd_refs: default_or(self.max_kd_refs, 2000),
            max_pgrid_cells: default_or(self.max_pgrid_cells, 50000),
            max_pgrid_refs: default_or(self.max_pgrid_refs, 50000),
            max_geometries: self.max_geometries % 5,
            max_instances: self.max_instances % 9,
            max_scene_triangles: default_or(self.max_scene_triangles, 400),
            // Mostly the defaults; else smaller packets, fewer bounces or
            // renderers, whose calls must then be refused with a status.
            max_packet_side: [32, 32, 2, 4, 8, 16][self.max_packet_side as usize % 6],
            max_bounces: if self.max_bounces % 2 == 0 { 8 } else { self.max_bounces % 9 },
            renderers: if self.renderers % 2 == 0 { 7 } else { self.renderers % 8 },
            max_bvh_refs,
        }
    }
}

/// `max_bvh_refs` for `max_triangles` `t`, picked by `k` (bits of
/// `max_tile` its usable `% 8` leaves, so the corpus of earlier runs
/// decodes as before): the default 0 (one reference per triangle), a
/// reserve for the HIGH build's spatial splits, or (`wild`) fewer than
/// `t`, which creation refuses.
fn bvh_refs(t: u32, k: u32, wild: bool) -> u32 {
    match k % 4 {
        1 if wild => t / 2,
        0 | 1 => 0,
        2 => t.saturating_add(t / 4),
        _ => t.saturating_mul(2),
    }
}

/// A `sheaf_isa`: AUTO or a forced level (refused where the CPU lacks it).
fn isa(n: N) -> u32 {
    small(n, |v| [0, 0, 1, 2, 3][v as usize % 5])
}

/// A usable pool size: 0 (sheaf's default) for a third of the values, else
/// `v % below`.
fn default_or(v: u32, below: u32) -> u32 {
    if v % 3 == 0 { 0 } else { v % below }
}

#[derive(Arbitrary, Debug)]
enum Placement {
    Owned,
    /// `sheaf_context_create_in`: a buffer `short` bytes short of the need
    /// (0: exact, plus `slack`), starting `misalign` bytes past 64.
    In {
        short: u16,
        slack: u8,
        misalign: u8,
    },
}

#[derive(Arbitrary, Debug, Clone, Copy)]
enum IndexIn {
    Vertex(u8),
    Any(u32),
}

#[derive(Arbitrary, Debug)]
struct GeomIn {
    verts: Vec<[F; 3]>,
    /// Extra floats per vertex (interleaved buffer).
    pad: u8,
    /// Offset of the first vertex in floats.
    offset: u8,
    /// None: the natural stride; else any stride (bytes).
    stride: Option<u16>,
    /// None: the real vertex count; else this, clamped so the claimed span
    /// stays inside the real buffer.
    claim_vertices: Option<N>,
    tris: Vec<[IndexIn; 3]>,
    claim_triangles: Option<N>,
    /// Byte offset of the index array (non-zero: misaligned).
    index_misalign: u8,
    null_vertices: bool,
    null_indices: bool,
}

#[derive(Arbitrary, Debug)]
struct GridIn {
    lambda: F,
    macrocell: N,
    test: N,
    fit: bool,
}

#[derive(Arbitrary, Debug)]
struct BvhIn {
    leaf_size: N,
    bins: N,
    traversal_cost: F,
    test: N,
    quality: N,
    width: N,
    presplit: N,
}

#[derive(Arbitrary, Debug)]
struct KdIn {
    max_depth: N,
    traversal_cost: F,
    empty_bonus: F,
    test: N,
}

#[derive(Arbitrary, Debug)]
struct PgridIn {
    tile: N,
    group: N,
    slices: N,
    light_tiles: N,
    light_slices: N,
    chunk: u16,
    test: N,
    cull_backfaces: bool,
    isa: N,
}

impl GridIn {
    fn get(&self) -> sheaf_grid_params {
        sheaf_grid_params {
            size: core::mem::size_of::<sheaf_grid_params>() as u32,
            lambda: match self.lambda {
                F::Small(v) => (v as f32 / 8.0).abs() + 0.25,
                x => x.get(),
            },
            macrocell: small(self.macrocell, |v| v % 9),
            test: small(self.test, |v| v % 3),
            fit: self.fit.into(),
        }
    }
}

impl BvhIn {
    fn get(&self) -> sheaf_bvh_params {
        sheaf_bvh_params {
            size: core::mem::size_of::<sheaf_bvh_params>() as u32,
            leaf_size: small(self.leaf_size, |v| 1 + v % 8),
            bins: small(self.bins, |v| 2 + v % 31),
            traversal_cost: positive(self.traversal_cost),
            test: small(self.test, |v| v % 3),
            quality: small(self.quality, |v| v % 3),
            width: small(self.width, |v| [0, 4, 2][v as usize % 3]),
            presplit: small(self.presplit, |v| v % 2),
        }
    }
}

impl KdIn {
    fn get(&self) -> sheaf_kd_params {
        sheaf_kd_params {
            size: core::mem::size_of::<sheaf_kd_params>() as u32,
            max_depth: small(self.max_depth, |v| v % 49),
            traversal_cost: positive(self.traversal_cost),
            empty_bonus: match self.empty_bonus {
                F::Small(v) => (v as f32).abs() / 130.0,
                x => x.get(),
            },
            test: small(self.test, |v| v % 3),
            // The binned build's knobs: the test's byte picks them too
            // (the corpus of earlier runs decodes as before).
            quality: small(self.test, |v| (v / 3) % 3),
            bins: small(self.test, |v| [0, 2, 16, 64, 65][(v / 9) as usize % 5]),
        }
    }
}

impl PgridIn {
    fn get(&self) -> sheaf_pgrid_params {
        sheaf_pgrid_params {
            size: core::mem::size_of::<sheaf_pgrid_params>() as u32,
            tile: small(self.tile, |v| [2, 4, 8, 16, 32][v as usize % 5]),
            group: small(self.group, |v| [1, 2, 4][v as usize % 3]),
            slices: small(self.slices, |v| 1 + v),
            light_tiles: small(self.light_tiles, |v| 1 + v),
            light_slices: small(self.light_slices, |v| 1 + v),
            chunk: self.chunk as u32,
            test: small(self.test, |v| v % 3),
            cull_backfaces: self.cull_backfaces.into(),
            isa: isa(self.isa),
        }
    }
}

#[derive(Arbitrary, Debug, Clone, Copy)]
struct TraceIn {
    method: N,
    packet: N,
    macrocells: bool,
    mailbox: bool,
    culling: bool,
    ray_kind: N,
    entry: N,
    split: F,
    isa: N,
}

impl TraceIn {
    fn get(&self) -> sheaf_trace_params {
        sheaf_trace_params {
            size: core::mem::size_of::<sheaf_trace_params>() as u32,
            method: match self.method {
                N::Small(v) => v as u32 % METHODS,
                N::Any(v) => v,
            },
            packet: match self.packet {
                N::Small(v) => [2, 4, 8, 16, 32, 0, 3, 64][v as usize % 8],
                N::Any(v) => v,
            },
            macrocells: self.macrocells.into(),
            mailbox: self.mailbox.into(),
            culling: self.culling.into(),
            ray_kind: self.ray_kind.get() % 5,
            entry: self.entry.get() % 4,
            split: match self.split {
                F::Small(v) => (v as f32 / 8.0).abs().max(1.0),
                s => s.get(),
            },
            isa: isa(self.isa),
            force_opaque: 0,
        }
    }
}

#[derive(Arbitrary, Debug, Clone, Copy)]
struct RayIn {
    org: [F; 3],
    tmin: F,
    dir: [F; 3],
    tmax: F,
}

#[derive(Arbitrary, Debug)]
enum RayTmax {
    Inf,
    Given,
}

#[derive(Arbitrary, Debug)]
struct RaysIn {
    rays: Vec<RayIn>,
    /// Rays from one origin towards a grid of directions (packet-like).
    fan: Option<([F; 3], [F; 3], u8)>,
    tmax: RayTmax,
    /// Claimed count: None the real one, else at most the real one.
    claim: Option<u16>,
    /// Byte offsets of the ray and hit arrays (any alignment is allowed).
    ray_offset: u8,
    hit_offset: u8,
    /// Results written over the rays themselves (an overlap error).
    overlap: bool,
    null_rays: bool,
    null_hits: bool,
}

#[derive(Arbitrary, Debug, Clone, Copy)]
struct LightIn {
    position: [F; 3],
    color: [F; 3],
    spot_direction: [F; 3],
    spot_angle_deg: F,
    spot_soft_deg: F,
    /// Use the fields above as they are; else a plausible light chosen by
    /// `view`: a point light above the scene, or a spot aimed at the origin.
    raw: bool,
    view: u8,
}

impl LightIn {
    fn get(&self) -> PointLight {
        if !self.raw {
            let k = self.view;
            let a = k as f32 * 0.9;
            let position = [5.0 * a.cos(), 5.0 * a.sin(), 3.0 + (k % 7) as f32];
            return PointLight {
                position,
                color: [1.0, 0.9, 0.8],
                spot_direction: position.map(|x| -x),
                spot_angle_deg: if k % 2 == 0 {
                    0.0
                } else {
                    10.0 + (k % 70) as f32
                },
                spot_soft_deg: (k % 5) as f32,
            };
        }
        PointLight {
            position: v3(self.position),
            color: v3(self.color),
            spot_direction: v3(self.spot_direction),
            spot_angle_deg: self.spot_angle_deg.get(),
            spot_soft_deg: self.spot_soft_deg.get(),
        }
    }
}

#[derive(Arbitrary, Debug, Clone, Copy)]
struct FrameIn {
    eye: [F; 3],
    look_at: [F; 3],
    up: [F; 3],
    fov: F,
    light: LightIn,
    albedo: [F; 3],
    ambient: F,
    background: [F; 3],
    shadows: bool,
    width: N,
    height: N,
    /// Use the camera and shading above as they are; else a plausible
    /// camera chosen by `view` (looking at the origin from outside).
    raw_camera: bool,
    view: u8,
}

impl FrameIn {
    fn get(&self) -> sheaf_frame {
        let mut f = sheaf_frame {
            camera: Camera {
                eye: v3(self.eye),
                look_at: v3(self.look_at),
                up: v3(self.up),
                fov_y_deg: self.fov.get(),
            },
            light: self.light.get(),
            shading: ffi::sheaf_shading {
                albedo: v3(self.albedo),
                ambient: self.ambient.get(),
                background: v3(self.background),
                shadows: self.shadows.into(),
            },
            width: match self.width {
                N::Small(v) => 1 + v as u32 % 32,
                N::Any(v) => v,
            },
            height: match self.height {
                N::Small(v) => 1 + v as u32 % 32,
                N::Any(v) => v,
            },
        };
        if !self.raw_camera {
            let k = self.view;
            let a = k as f32 * 0.7;
            f.camera = Camera {
                eye: [4.0 * a.cos(), 4.0 * a.sin(), 2.0 + (k % 5) as f32],
                look_at: [0.0, 0.0, 0.0],
                up: [0.0, 0.0, 1.0],
                fov_y_deg: 30.0 + (k % 60) as f32,
            };
            f.shading = ffi::sheaf_shading::of(&Shading::default());
            f.shading.shadows = self.shadows.into();
            if self.light.raw {
                f.light = PointLight {
                    position: [4.0, -3.0, 8.0],
                    color: [1.0; 3],
                    ..PointLight::default()
                };
            }
        }
        f
    }
}

#[derive(Arbitrary, Debug)]
struct FbIn {
    /// Extra bytes per row (unless `any_stride`).
    row_pad: u8,
    any_stride: Option<u64>,
    /// Length: exactly the need plus `slack`, or `short` bytes less.
    short: u16,
    slack: u8,
    null: bool,
}

#[derive(Arbitrary, Debug)]
struct MaterialIn {
    diffuse: [F; 3],
    reflect: F,
    transmit: F,
    ior: F,
}

#[derive(Arbitrary, Debug)]
struct WhittedIn {
    primary: TraceIn,
    shadow: TraceIn,
    secondary: TraceIn,
    bounces: Option<(u8, u8)>,
    lights: Vec<LightIn>,
    materials: Vec<MaterialIn>,
    ranges: Vec<(u16, u16)>,
    misalign_lights: bool,
}

#[derive(Arbitrary, Debug)]
struct DeferredIn {
    lights: Vec<LightIn>,
    primary_pgrid: bool,
    shadow_light_grid: bool,
    primary: TraceIn,
    shadow: TraceIn,
    null_lights: bool,
}

#[derive(Arbitrary, Debug)]
enum Op {
    SetGeometry(GeomIn),
    /// A ground quad and a box (18 triangles), moved and scaled.
    Canned(u8, [F; 3]),
    /// A shortcut to deep states: the canned scene, every build with
    /// default parameters, then a render, a deferred frame and a trace of
    /// camera rays with methods chosen by the byte (later ops go on from
    /// there).
    Warmup(u8),
    PokeIndex(u16, IndexIn),
    PokeVertex(u16, F),
    BuildGrid(Option<GridIn>),
    BuildBvh(Option<BvhIn>),
    BuildKd(Option<KdIn>),
    BuildPgrid(Option<PgridIn>),
    Trace(N, RaysIn),
    TraceWith(TraceIn, RaysIn),
    Occluded(N, RaysIn),
    Render(N, FrameIn, FbIn),
    RenderWith(TraceIn, TraceIn, FrameIn, FbIn),
    Whitted(WhittedIn, FrameIn, FbIn),
    Deferred(DeferredIn, FrameIn, FbIn),
    DeferredPixel(u8, u8),
    DeferredShadowRay(u8, u8, LightIn),
    CameraRay(FrameIn, u8, u8),
    Stats,
    LastError(u16),
    StatusString(u32),
    /// trace_slot / occluded_slot on any slot (bit 0 of the flag: occluded).
    TraceSlot(u8, u8, TraceIn, RaysIn),
    /// render_rows on any slot and row band.
    RenderRows(u8, u8, u8, TraceIn, FrameIn, FbIn),
    /// clear_geometry, then the borrowed buffers are freed.
    ClearGeometry,
    /// One bad argument in one call: NULL pointer, a count at the overflow
    /// boundary, or outputs partly over inputs.
    BadArg(u8, u8, u8),
    /// Two threads on the context at once: traces on slot 0 against
    /// another call (trace on slot 1, render_rows, a build, set_geometry,
    /// a render); compared with the serial results.
    Concurrent(u8, TraceIn, RaysIn),
    /// The two-level scene's calls (`scene.rs`).
    Scene(scene::SceneOp),
    /// Camera packets made in the kernel: sheaf_context_trace_camera (bit 0
    /// of the flags: the scene call, bit 1: its params NULL) on a rectangle
    /// of the frame's image picked by the bytes (bit 2: one column past
    /// the image; bit 3: rows narrower than the rectangle), rows `extra`
    /// hits wider than it. Bit 4: the params as drawn; else sheaf's
    /// defaults with the drawn method and a packet of 2 to 16, which the
    /// call accepts (every drawn camera call was refused before).
    TraceCamera(TraceIn, FrameIn, [u8; 4], u8, u8),
    /// A joined build (kind % 4: BVH LOW, BVH MEDIUM, kd-tree, grid) led
    /// by thread (0, n) (n = 1 + count % 4) beside up to 4 drawn helpers
    /// (index % 5, count % 5): duplicates, other counts, index 0 or past
    /// the count among them.
    Joined(u8, u8, Vec<(u8, u8)>),
}

#[derive(Arbitrary, Debug)]
struct Input {
    limits: LimitsIn,
    placement: Placement,
    ops: Vec<Op>,
    destroy_twice: bool,
}

// ---- buffers the context borrows -----------------------------------------------

/// Vertex and index buffers handed to a successful set_geometry: they must
/// stay alive (and may be edited in place) until the next one succeeds.
struct Geometry {
    vertices: Vec<f32>,
    /// Where vertex `i`'s x is, in floats (for in-place edits).
    vertex_at: Vec<usize>,
    /// One u32 more than the indices, so a misaligned view stays inside.
    index_words: Vec<u32>,
    index_count: usize,
    vertex_count: u32,
}

/// A successful trace to repeat after failures.
struct TraceRecord {
    params: sheaf_trace_params,
    occluded: bool,
    rays: Vec<sheaf_ray>,
    out: Vec<u8>,
}

/// A successful render to repeat after failures.
struct RenderRecord {
    primary: sheaf_trace_params,
    shadow: sheaf_trace_params,
    frame: sheaf_frame,
    stride: usize,
    image: Vec<u8>,
}

struct State {
    ctx: *mut sheaf_context,
    limits: Limits,
    geometry: Option<Geometry>,
    trace: Option<TraceRecord>,
    render: Option<RenderRecord>,
    /// Any vertex or ray field outside +-1e4 or non-finite since the last
    /// successful builds: the exactness comparisons are skipped.
    wild_scene: bool,
    /// The two-level scene as the calls made it.
    scene: scene::SceneModel,
}

// ---- contract helpers ----------------------------------------------------------

fn valid_status(s: sheaf_status, what: &str) {
    if std::env::var_os("SHEAF_FUZZ_LOG").is_some() {
        eprintln!("@call {what} {s:?}");
    }
    let raw = s as u32;
    assert!(
        sheaf_status::from_raw(raw).is_some(),
        "{what}: undocumented status {raw}"
    );
    assert_ne!(
        s,
        sheaf_status::Panic,
        "{what}: panic caught at the boundary"
    );
}

fn stats_of(ctx: *const sheaf_context) -> String {
    let mut st = sheaf_stats::default();
    assert_eq!(ffi::sheaf_context_stats(ctx, &mut st), OK);
    // Debug text: NaN-safe equality of every field.
    format!("{st:?}")
}

fn last_error(ctx: *const sheaf_context) -> String {
    let mut buf = [0x7f as core::ffi::c_char; ffi::SHEAF_ERROR_MESSAGE_MAX];
    let mut written = usize::MAX;
    assert_eq!(
        ffi::sheaf_context_last_error(ctx, buf.as_mut_ptr(), buf.len(), &mut written),
        OK
    );
    assert!(
        written < buf.len() && buf[written] == 0,
        "last_error not terminated"
    );
    let bytes: Vec<u8> = buf[..written].iter().map(|&c| c as u8).collect();
    String::from_utf8(bytes).expect("last_error is not UTF-8")
}

impl State {
    /// The checks after an exclusive call that returned `s`: on failure the
    /// stats are unchanged, the last error is set, and earlier results are
    /// reproduced.
    fn after(&mut self, s: sheaf_status, stats_before: &str, what: &str) {
        valid_status(s, what);
        if s == OK {
            return;
        }
        if std::env::var_os("SHEAF_FUZZ_LOG").is_some() {
            eprintln!("@error {what} {}", last_error(self.ctx));
        }
        assert_eq!(
            stats_of(self.ctx),
            stats_before,
            "{what} failed with {s:?} but changed sheaf_stats"
        );
        let msg = last_error(self.ctx);
        assert!(
            !msg.is_empty() && msg != "no error",
            "{what} failed with {s:?}, last_error is {msg:?}"
        );
        self.recheck(what, s);
    }

    /// Repeat the last successful trace and render: the same bytes.
    fn recheck(&mut self, what: &str, s: sheaf_status) {
        if let Some(t) = &self.trace {
            let out = run_trace(self.ctx, &t.params, t.occluded, &t.rays);
            assert_eq!(
                out.as_ref(),
                Some(&t.out),
                "after {what} failed with {s:?}: the previous trace ({:?}) changed",
                t.params
            );
        }
        if let Some(r) = &self.render {
            let mut img = vec![S_PIX; r.image.len()];
            let st = ffi::context::sheaf_context_render_with(
                self.ctx,
                &r.primary,
                &r.shadow,
                &r.frame,
                img.as_mut_ptr(),
                r.stride,
                img.len(),
            );
            assert_eq!(
                st, OK,
                "after {what} failed with {s:?}: the previous render fails"
            );
            assert!(
                img == r.image,
                "after {what} failed with {s:?}: the previous render ({:?}) changed",
                r.primary
            );
        }
    }
}

/// Trace (or occluded) `rays` with `p` into fresh memory; None on error.
fn run_trace(
    ctx: *const sheaf_context,
    p: &sheaf_trace_params,
    occluded: bool,
    rays: &[sheaf_ray],
) -> Option<Vec<u8>> {
    if occluded {
        // With `p` whole: the method's default packet may be past the
        // limits' `max_packet_side` where `p`'s is not.
        let mut o = vec![S_HIT; rays.len()];
        let s = ffi::sheaf_context_occluded_with(ctx, p, rays.as_ptr(), o.as_mut_ptr(), rays.len());
        (s == OK).then_some(o)
    } else {
        let mut h = vec![
            sheaf_hit {
                t: 0.0,
                prim: 0,
                u: 0.0,
                v: 0.0
            };
            rays.len()
        ];
        let s = ffi::context::sheaf_context_trace_with(
            ctx,
            p,
            rays.as_ptr(),
            h.as_mut_ptr(),
            rays.len(),
        );
        (s == OK).then(|| hit_bytes(&h))
    }
}

fn hit_bytes(h: &[sheaf_hit]) -> Vec<u8> {
    let mut b = Vec::with_capacity(h.len() * 16);
    for x in h {
        b.extend_from_slice(&x.t.to_bits().to_le_bytes());
        b.extend_from_slice(&x.prim.to_le_bytes());
        b.extend_from_slice(&x.u.to_bits().to_le_bytes());
        b.extend_from_slice(&x.v.to_bits().to_le_bytes());
    }
    b
}

fn moderate(x: f32) -> bool {
    x.is_finite() && x.abs() <= 1e4
}

/// The reference method of `method`'s structure.
fn reference_of(method: u32) -> Option<u32> {
    match method {
        0 | 1 => Some(0),
        2..=6 | 10..=12 => Some(2),
        7..=9 => Some(7),
        _ => None,
    }
}

// ---- calls ---------------------------------------------------------------------

fn make_rays(r: &RaysIn) -> Vec<sheaf_ray> {
    let tmax = |x: F| match r.tmax {
        RayTmax::Inf => f32::INFINITY,
        RayTmax::Given => x.get(),
    };
    let mut rays: Vec<sheaf_ray> = r
        .rays
        .iter()
        .take(96)
        .map(|x| sheaf_ray {
            org: v3(x.org),
            tmin: x.tmin.get(),
            dir: v3(x.dir),
            tmax: tmax(x.tmax),
        })
        .collect();
    if let Some((org, at, n)) = r.fan {
        let n = 1 + n as usize % 16;
        let (o, c) = (v3(org), v3(at));
        for y in 0..n {
            for x in 0..n {
                let d = [
                    c[0] - o[0] + (x as f32 - n as f32 / 2.0) * 0.1,
                    c[1] - o[1] + (y as f32 - n as f32 / 2.0) * 0.1,
                    c[2] - o[2],
                ];
                rays.push(sheaf_ray {
                    org: o,
                    tmin: 0.0,
                    dir: d,
                    tmax: f32::INFINITY,
                });
            }
        }
    }
    rays
}

/// trace / trace_with / occluded / occluded_with through raw, possibly
/// unaligned memory.
/// `Op::TraceCamera`: a refused call writes nothing; an accepted one gives
/// every pixel of the rectangle the hit the ray-array call gives
/// `sheaf_frame_camera_ray`'s ray for it, bit for bit, and leaves the gaps
/// between rows alone.
fn trace_camera(
    st: &mut State,
    params: &sheaf_trace_params,
    f: &FrameIn,
    r: &[u8; 4],
    extra: u8,
    flags: u8,
) {
    let mut frame = f.get();
    let pick = |b: u8, n: u32| (u64::from(b) * (u64::from(n) + 1) / 256) as u32;
    // Bit 5: the image reaches the u32 edge in x (bit 6: in y, bit 7:
    // both) and the rectangle lies at its far side, up to 40 pixels from
    // it, so packets overhang past 2^32.
    let edge = flags & 32 != 0;
    if edge {
        let (ex, ey) = match flags >> 6 {
            0 => (true, false),
            1 => (false, true),
            _ => (true, true),
        };
        if ex {
            frame.width = u32::MAX - u32::from(r[2] % 3);
        }
        if ey {
            frame.height = u32::MAX - u32::from(r[3] % 3);
        }
    }
    let (w, h) = (frame.width, frame.height);
    let near = |b0: u8, b1: u8, n: u32, far: bool| {
        if far {
            let x1 = n - u32::from(b1 % 4);
            (x1 - 1 - u32::from(b0 % 40).min(x1 - 1), x1)
        } else {
            (pick(b0, n), pick(b1, n))
        }
    };
    let (x0, x1) = near(r[0], r[2], w, edge && w > 1 << 31);
    let (y0, y1) = near(r[1], r[3], h, edge && h > 1 << 31);
    let mut rect = sheaf::PixelRect { x0, y0, x1, y1 };
    if flags & 4 != 0 {
        rect.x1 = rect.x1.saturating_add(1);
    }
    let inside = rect.x0 < rect.x1 && rect.y0 < rect.y1 && rect.x1 <= w && rect.y1 <= h;
    let rw = rect.x1.saturating_sub(rect.x0) as usize;
    let rh = rect.y1.saturating_sub(rect.y0) as usize;
    let row = if flags & 8 != 0 {
        rw.saturating_sub(1)
    } else {
        rw + extra as usize % 5
    };
    let len = rh.saturating_sub(1) * row + rw;
    if rw * rh > 1 << 14 || len > 1 << 16 {
        return; // bounded work per op
    }
    let scene = flags & 1 != 0;
    let plausible = plausible_params(params);
    let params = if flags & 16 != 0 { params } else { &plausible };
    let pp: *const sheaf_trace_params = if scene && flags & 2 != 0 {
        core::ptr::null()
    } else {
        params
    };
    let size = if scene { 24 } else { 16 };
    let mut buf = vec![S_HIT; size * len.max(1)];
    let s = if scene {
        let out = buf.as_mut_ptr().cast();
        ffi::sheaf_context_trace_scene_camera(
            st.ctx,
            pp,
            &frame.camera,
            w,
            h,
            &rect,
            out,
            row,
            !0,
            0,
        )
    } else {
        let out = buf.as_mut_ptr().cast();
        ffi::sheaf_context_trace_camera(st.ctx, pp, &frame.camera, w, h, &rect, out, row)
    };
    valid_status(s, "trace_camera");
    if !inside || row < rw {
        assert_ne!(
            s, OK,
            "camera rectangle {rect:?} with rows {row} apart accepted"
        );
    }
    if s != OK {
        assert!(
            buf.iter().all(|&b| b == S_HIT),
            "a failed camera trace wrote"
        );
        return;
    }
    // The same pixels' rays from sheaf_frame_camera_ray, as a ray array.
    let mut rays = Vec::with_capacity(rw * rh);
    for y in rect.y0..rect.y1 {
        for x in rect.x0..rect.x1 {
            let mut ray = sheaf_ray {
                org: [0.0; 3],
                tmin: 0.0,
                dir: [0.0; 3],
                tmax: 0.0,
            };
            assert_eq!(ffi::sheaf_frame_camera_ray(&frame, x, y, &mut ray), OK);
            rays.push(ray);
        }
    }
    let mut want = vec![0u8; size * rays.len()];
    let ws = if scene {
        let out = want.as_mut_ptr().cast();
        ffi::sheaf_context_trace_scene(st.ctx, pp, rays.as_ptr(), out, rays.len(), !0, 0)
    } else {
        let out = want.as_mut_ptr().cast();
        ffi::context::sheaf_context_trace_with(st.ctx, pp, rays.as_ptr(), out, rays.len())
    };
    assert_eq!(
        ws, OK,
        "the ray-array call refused what the camera call took"
    );
    for (k, want) in want.chunks(size).enumerate() {
        let at = (k / rw) * row + k % rw;
        assert_eq!(
            &buf[size * at..size * (at + 1)],
            want,
            "camera pixel {k} of {rect:?} differs from its ray's hit"
        );
    }
    for y in 0..rh.saturating_sub(1) {
        let gap = &buf[size * (y * row + rw)..size * (y + 1) * row];
        assert!(
            gap.iter().all(|&b| b == S_HIT),
            "a camera trace wrote between rows"
        );
    }
}

/// One joined call of `kind` as thread `(index, count)`.
fn joined_call(ctx: *mut sheaf_context, kind: u8, index: u32, count: u32) -> sheaf_status {
    // SAFETY: plain integers and floats; filled by the defaults call.
    let mut low: sheaf_bvh_params = unsafe { core::mem::zeroed() };
    assert_eq!(
        ffi::sheaf_bvh_params_default(&mut low, core::mem::size_of_val(&low)),
        OK
    );
    low.quality = 0; // SHEAF_BUILD_QUALITY_LOW
    match kind {
        0 => ffi::context::sheaf_context_build_bvh_joined(ctx, &low, index, count),
        1 => ffi::context::sheaf_context_build_bvh_joined(ctx, core::ptr::null(), index, count),
        2 => ffi::sheaf_context_build_kd_joined(ctx, core::ptr::null(), index, count),
        _ => ffi::context::sheaf_context_build_grid_joined(ctx, core::ptr::null(), index, count),
    }
}

/// `Op::Joined`: the leader `(0, n)` and the drawn helpers, each on its
/// own thread. A helper that is refused (a count other than the open
/// build's, an index taken or out of range) returns
/// `INVALID_ARGUMENT` at once; one that joins returns the leader's
/// status; none may crash, hang the leader or panic. A helper that
/// arrived after the build it would have joined waits for the next one
/// (the documented contract), so the harness leads rescue builds for the
/// helpers still waiting until all have returned. Every build gets a
/// fresh helper for each index no waiting helper of its count holds, so
/// the fresh ones never compete (a fresh one that lost its index to a
/// waiting one would itself be left waiting, round after round). A
/// helper counts as waiting once no helper has returned for 100 ms.
/// Returns the first leader's status.
fn joined(ctx: *mut sheaf_context, kind: u8, n: u32, helpers: &[(u32, u32)]) -> sheaf_status {
    use std::time::{Duration, Instant};
    let addr = ctx as usize;
    let call = move |i: u32, c: u32| joined_call(addr as *mut sheaf_context, kind, i, c);
    let bad = |i: u32, c: u32| c == 0 || i == 0 || i >= c || c as usize > 16;
    std::thread::scope(|sc| {
        let mut pending: Vec<_> = helpers
            .iter()
            .map(|&(i, c)| (i, c, sc.spawn(move || call(i, c))))
            .collect();
        // A build of `c`: fresh helpers for the indices no pending helper
        // of that count holds.
        let session = |c: u32, held: &[u32]| {
            let fresh: Vec<_> = (1..c)
                .filter(|i| !held.contains(i))
                .map(|i| sc.spawn(move || call(i, c)))
                .collect();
            let s = call(0, c);
            valid_status(s, "joined build (leader)");
            for f in fresh {
                let h = f.join().expect("a helper thread panicked");
                valid_status(h, "joined build (helper)");
                assert_eq!(h, s, "a fresh helper's status is its leader's");
            }
            s
        };
        // The first build: the drawn helpers of its count hold their
        // indices (they are running, and the build waits for them).
        let held: Vec<u32> = pending
            .iter()
            .filter(|d| d.1 == n && !bad(d.0, d.1))
            .map(|d| d.0)
            .collect();
        let first = session(n, &held);
        for _round in 0..64 {
            // Collect the helpers that return, until none has for 100 ms.
            let mut quiet = Instant::now();
            loop {
                let (done, rest): (Vec<_>, Vec<_>) =
                    pending.into_iter().partition(|d| d.2.is_finished());
                pending = rest;
                if !done.is_empty() {
                    quiet = Instant::now();
                }
                for (i, c, t) in done {
                    let h = t.join().expect("a helper thread panicked");
                    valid_status(h, "joined build (drawn helper)");
                    if bad(i, c) {
                        assert_eq!(h, sheaf_status::InvalidArgument, "helper ({i}, {c})");
                    }
                }
                if pending.is_empty() {
                    return first;
                }
                if quiet.elapsed() > Duration::from_millis(100) {
                    break;
                }
                std::thread::sleep(Duration::from_millis(1));
            }
            // The rest wait for a build of their count: lead one.
            let c = pending[0].1;
            let held: Vec<u32> = pending.iter().filter(|d| d.1 == c).map(|d| d.0).collect();
            session(c, &held);
        }
        panic!("joined helpers still waiting after 64 rescue builds");
    })
}

/// sheaf's default params with `p`'s method (any of them) and a packet of
/// 2 to 32 rays a side: params a camera call accepts whenever the
/// method's structure is built (32: where `max_packet_side` allows it).
fn plausible_params(p: &sheaf_trace_params) -> sheaf_trace_params {
    let mut d = *p;
    assert_eq!(
        ffi::sheaf_trace_params_default(&mut d, core::mem::size_of_val(&d)),
        OK
    );
    d.method = p.method % METHODS;
    d.packet = 2 << (p.packet % 5);
    d
}

fn trace_call(
    st: &mut State,
    params: Option<sheaf_trace_params>,
    method: u32,
    occ: bool,
    r: &RaysIn,
) {
    let rays = make_rays(r);
    let real = rays.len();
    let count = r.claim.map_or(real, |c| (c as usize).min(real));
    let rsz = core::mem::size_of::<sheaf_ray>();
    let out_sz = if occ {
        1
    } else {
        core::mem::size_of::<sheaf_hit>()
    };
    // Rays copied byte-wise at an offset; results in their own buffer.
    let roff = r.ray_offset as usize % 8;
    let mut rbuf = vec![0u8; roff + real * rsz];
    for (i, ray) in rays.iter().enumerate() {
        // SAFETY: in bounds; unaligned write of a plain struct.
        unsafe {
            rbuf.as_mut_ptr()
                .add(roff + i * rsz)
                .cast::<sheaf_ray>()
                .write_unaligned(*ray)
        };
    }
    let hoff = r.hit_offset as usize % 8;
    let mut hbuf = vec![S_HIT; hoff + real * out_sz];
    let rays_before = rbuf.clone();
    let rp: *const sheaf_ray = if r.null_rays {
        core::ptr::null()
    } else {
        // SAFETY: in bounds.
        unsafe { rbuf.as_ptr().add(roff).cast() }
    };
    let overlap = r.overlap && !r.null_rays;
    let hp: *mut u8 = if r.null_hits {
        core::ptr::null_mut()
    } else if overlap {
        // Results over the rays themselves (count * out_sz <= count * 32).
        // SAFETY: in bounds.
        unsafe { rbuf.as_mut_ptr().add(roff) }
    } else {
        // SAFETY: in bounds.
        unsafe { hbuf.as_mut_ptr().add(hoff) }
    };
    let p = params.unwrap_or(sheaf_trace_params {
        method,
        ..default_trace()
    });
    let s = if occ {
        match params {
            Some(p) => ffi::sheaf_context_occluded_with(st.ctx, &p, rp, hp, count),
            None => ffi::sheaf_context_occluded(st.ctx, method, rp, hp, count),
        }
    } else if let Some(p) = params {
        ffi::context::sheaf_context_trace_with(st.ctx, &p, rp, hp.cast(), count)
    } else {
        ffi::sheaf_context_trace(st.ctx, method, rp, hp.cast(), count)
    };
    valid_status(s, "trace");
    if count > 0 && (r.null_rays || r.null_hits) {
        assert_ne!(s, OK, "NULL array with count {count} accepted");
    }
    if s == OK && overlap && count > 0 {
        panic!("results over their own rays accepted");
    }
    if s != OK {
        assert!(rbuf == rays_before, "a failed trace wrote over its rays");
        assert!(
            hbuf.iter().all(|&b| b == S_HIT),
            "a failed trace ({s:?}) wrote results"
        );
        let msg = last_error(st.ctx);
        assert!(msg != "no error", "trace failed with {s:?}, no last error");
        // A failed trace changes nothing: the previous results stand.
        st.recheck("trace", s);
        return;
    }
    assert!(rbuf == rays_before, "a trace wrote over its rays");
    if count == 0 {
        return;
    }
    let out = hbuf[hoff..hoff + count * out_sz].to_vec();
    assert!(
        hbuf[hoff + count * out_sz..].iter().all(|&b| b == S_HIT),
        "wrote past count"
    );
    assert!(
        hbuf[..hoff].iter().all(|&b| b == S_HIT),
        "wrote before the results"
    );
    if occ {
        assert!(out.iter().all(|&b| b <= 1), "occluded wrote {out:?}");
    } else {
        for k in 0..count {
            let h = &out[k * 16..k * 16 + 16];
            let t = f32::from_bits(u32::from_le_bytes(h[0..4].try_into().unwrap()));
            let prim = u32::from_le_bytes(h[4..8].try_into().unwrap());
            if prim == ffi::SHEAF_INVALID_ID {
                assert!(t == f32::INFINITY, "a miss with t = {t}");
            } else {
                let ray = rays[k];
                assert!(
                    t >= ray.tmin && t < ray.tmax,
                    "hit t = {t} outside [{}, {}) of ray {k}",
                    ray.tmin,
                    ray.tmax
                );
            }
        }
    }
    // Same results again, and through the structure's reference method.
    let sane = !st.wild_scene
        && rays[..count]
            .iter()
            .all(|r| r.org.iter().chain(&r.dir).all(|&x| moderate(x)) && moderate(r.tmin));
    let rays = rays[..count].to_vec();
    let again = run_trace(st.ctx, &p, occ, &rays).expect("the same trace fails the second time");
    assert!(again == out, "the same trace gave other results");
    if sane {
        if let Some(m) = reference_of(p.method) {
            let rp = sheaf_trace_params {
                method: m,
                ..default_trace()
            };
            if let Some(want) = run_trace(st.ctx, &rp, occ, &rays) {
                compare(&rays, &out, &want, occ, &p);
            }
        }
    }
    st.trace = Some(TraceRecord {
        params: p,
        occluded: occ,
        rays,
        out,
    });
}

fn compare(rays: &[sheaf_ray], got: &[u8], want: &[u8], occ: bool, p: &sheaf_trace_params) {
    if occ {
        for (k, (a, b)) in got.iter().zip(want).enumerate() {
            assert_eq!(
                a, b,
                "occluded ray {k} {:?}: method {p:?} vs its reference",
                rays[k]
            );
        }
        return;
    }
    for k in 0..rays.len() {
        let (a, b) = (&got[k * 16..k * 16 + 8], &want[k * 16..k * 16 + 8]);
        assert!(
            a == b,
            "ray {k} {:?}: method {p:?} gives (t, prim) {:?}, its reference {:?}",
            rays[k],
            decode(a),
            decode(b)
        );
    }
}

fn decode(h: &[u8]) -> (f32, u32) {
    (
        f32::from_bits(u32::from_le_bytes(h[0..4].try_into().unwrap())),
        u32::from_le_bytes(h[4..8].try_into().unwrap()),
    )
}

fn default_trace() -> sheaf_trace_params {
    let mut p = sheaf_trace_params {
        size: 0,
        method: 0,
        packet: 0,
        macrocells: 0,
        mailbox: 0,
        culling: 0,
        ray_kind: 0,
        entry: 0,
        split: 0.0,
        isa: 0,
        force_opaque: 0,
    };
    assert_eq!(
        ffi::sheaf_trace_params_default(&mut p, core::mem::size_of_val(&p)),
        OK
    );
    p
}

/// The framebuffer of `fb` for `frame`: (buffer, stride, len, need or None
/// when the need overflows).
fn framebuffer(frame: &sheaf_frame, fb: &FbIn) -> (Vec<u8>, usize, usize, Option<usize>) {
    let w = frame.width as usize;
    let h = frame.height as usize;
    let stride = match fb.any_stride {
        None => 4 * w.min(64) + fb.row_pad as usize % 24,
        Some(s) => s as usize,
    };
    let need = (h.max(1) - 1)
        .checked_mul(stride)
        .and_then(|b| b.checked_add(4 * w));
    let len = match need {
        Some(n) if n <= 1 << 20 => {
            if fb.short > 0 {
                n.saturating_sub(fb.short as usize)
            } else {
                n + fb.slack as usize
            }
        }
        _ => fb.slack as usize * 16,
    };
    (vec![S_PIX; len], stride, len, need)
}

/// Checks common to every render call; returns whether it succeeded.
fn check_render(
    st: &mut State,
    s: sheaf_status,
    frame: &sheaf_frame,
    buf: &[u8],
    stride: usize,
    null: bool,
    stats_before: &str,
    what: &str,
) -> bool {
    if null {
        assert_ne!(s, OK, "{what} into a NULL framebuffer");
    }
    if s != OK {
        assert!(
            buf.iter().all(|&b| b == S_PIX),
            "{what} failed ({s:?}) but wrote pixels"
        );
        st.after(s, stats_before, what);
        return false;
    }
    valid_status(s, what);
    let (w, h) = (frame.width as usize, frame.height as usize);
    assert!(
        w > 0
            && h > 0
            && w as u32 <= st.limits.max_image_width
            && h as u32 <= st.limits.max_image_height
    );
    let end = (h - 1) * stride + 4 * w;
    for y in 0..h {
        let row = &buf[y * stride..y * stride + 4 * w];
        assert!(
            row.chunks(4).all(|p| p[3] == 255),
            "{what}: alpha not 255 in row {y}"
        );
        if y + 1 < h {
            assert!(
                buf[y * stride + 4 * w..(y + 1) * stride]
                    .iter()
                    .all(|&b| b == S_PIX),
                "{what}: wrote between rows {y} and {}",
                y + 1
            );
        }
    }
    assert!(
        buf[end..].iter().all(|&b| b == S_PIX),
        "{what}: wrote past the last row"
    );
    true
}

/// The ground-and-box scene of tests/c_abi.rs as a `GeomIn`, scaled by
/// `k` and moved by `shift` (in 1/8 units).
fn canned(k: u8, shift: [F; 3]) -> GeomIn {
    let mut v: Vec<[f32; 3]> = vec![
        [-4.0, -4.0, 0.0],
        [4.0, -4.0, 0.0],
        [4.0, 4.0, 0.0],
        [-4.0, 4.0, 0.0],
    ];
    let mut idx = vec![[0u8, 1, 2], [0, 2, 3]];
    for i in 0..8u32 {
        let c = |bit: u32, lo: f32, hi: f32| if i & bit != 0 { hi } else { lo };
        v.push([c(1, -0.5, 0.5), c(2, -0.5, 0.5), c(4, 0.0, 1.0)]);
    }
    for t in [
        [0, 2, 3],
        [0, 3, 1],
        [4, 5, 7],
        [4, 7, 6],
        [0, 1, 5],
        [0, 5, 4],
        [2, 6, 7],
        [2, 7, 3],
        [0, 4, 6],
        [0, 6, 2],
        [1, 3, 7],
        [1, 7, 5],
    ] {
        idx.push([t[0] + 4, t[1] + 4, t[2] + 4]);
    }
    let scale = 1.0 + (k % 8) as f32;
    let sh = shift.map(|s| match s {
        F::Small(x) => x as f32 / 8.0,
        _ => 0.0,
    });
    let f = |x: f32| {
        // Exactly representable at 1/1024 steps: F::Fine.
        F::Fine((x * 1024.0).clamp(-32768.0, 32767.0) as i16)
    };
    GeomIn {
        verts: v
            .iter()
            .map(|p| {
                [
                    f(p[0] * scale + sh[0]),
                    f(p[1] * scale + sh[1]),
                    f(p[2] * scale + sh[2]),
                ]
            })
            .collect(),
        pad: k / 8,
        offset: k / 32,
        stride: None,
        claim_vertices: None,
        tris: idx
            .iter()
            .map(|t| {
                [
                    IndexIn::Vertex(t[0]),
                    IndexIn::Vertex(t[1]),
                    IndexIn::Vertex(t[2]),
                ]
            })
            .collect(),
        claim_triangles: None,
        index_misalign: 0,
        null_vertices: false,
        null_indices: false,
    }
}

/// The vertex and index buffers of `g` as a C caller would hold them (the
/// claimed counts stay inside the real buffers; pointers may be NULL or
/// misaligned as `g` says).
struct MeshBuf {
    vertices: Vec<f32>,
    vertex_at: Vec<usize>,
    index_words: Vec<u32>,
    /// First vertex (floats) and index (bytes) offsets.
    off: usize,
    mis: usize,
    stride: usize,
    nv: u32,
    nt: u32,
    vp: *const f32,
    ip: *const u32,
}

impl MeshBuf {
    fn of(g: &GeomIn) -> MeshBuf {
        let nv_real = g.verts.len().min(400);
        let per = 3 + g.pad as usize % 4;
        let off = g.offset as usize % 4;
        let mut vertices = vec![-7777.0f32; off + nv_real * per];
        let mut vertex_at = Vec::with_capacity(nv_real);
        for (i, v) in g.verts.iter().take(nv_real).enumerate() {
            let at = off + i * per;
            vertices[at..at + 3].copy_from_slice(&v3(*v));
            vertex_at.push(at);
        }
        let real_bytes = (vertices.len() - off) * 4;
        let stride = match g.stride {
            None => per * 4,
            Some(s) => s as usize,
        };
        // Claimed vertex count: its span (count - 1) * stride + 12 stays inside.
        let fits =
            |n: usize| n == 0 || (n - 1).saturating_mul(stride).saturating_add(12) <= real_bytes;
        let mut nv = match g.claim_vertices {
            None => nv_real as u32,
            Some(c) => c.get(),
        };
        if !fits(nv as usize) {
            nv = if stride == 0 {
                if real_bytes >= 12 { nv } else { 0 }
            } else if real_bytes >= 12 {
                ((real_bytes - 12) / stride + 1).min(nv as usize) as u32
            } else {
                0
            };
        }
        let nt_real = g.tris.len().min(200);
        let mut index_words = vec![0u32; 3 * nt_real + 1];
        for (t, tri) in g.tris.iter().take(nt_real).enumerate() {
            for k in 0..3 {
                index_words[3 * t + k] = match tri[k] {
                    IndexIn::Vertex(i) => i as u32 % (nv_real.max(1) as u32),
                    IndexIn::Any(i) => i,
                };
            }
        }
        let mis = g.index_misalign as usize % 4;
        let nt = match g.claim_triangles {
            None => nt_real as u32,
            // The claimed triangles stay inside the real buffer (its extra word
            // covers a misaligned start).
            Some(c) => c.get().min(nt_real as u32),
        };
        let vp: *const f32 = if g.null_vertices {
            core::ptr::null()
        } else {
            // SAFETY: in bounds (off <= len).
            unsafe { vertices.as_ptr().add(off) }
        };
        let ip: *const u32 = if g.null_indices {
            core::ptr::null()
        } else {
            // SAFETY: in bounds (the extra word).
            unsafe { index_words.as_ptr().cast::<u8>().add(mis).cast() }
        };
        MeshBuf {
            vertices,
            vertex_at,
            index_words,
            off,
            mis,
            stride,
            nv,
            nt,
            vp,
            ip,
        }
    }

    /// Whether every claimed vertex is finite and within +-1e4 and the
    /// stride is whole floats (the exactness checks apply).
    fn moderate(&self) -> bool {
        self.stride % 4 == 0
            && (0..self.nv as usize).all(|i| {
                let at = self.off + i * self.stride / 4;
                self.vertices
                    .get(at..at + 3)
                    .is_some_and(|v| v.iter().all(|&x| moderate(x)))
            })
    }
}

fn set_geometry(st: &mut State, g: &GeomIn) {
    let m = MeshBuf::of(g);
    let MeshBuf {
        mis,
        stride,
        nv,
        nt,
        vp,
        ip,
        ..
    } = m;
    let before = stats_of(st.ctx);
    let s = ffi::sheaf_context_set_geometry(st.ctx, vp, stride, nv, ip, nt);
    if nv > 0 && g.null_vertices || nt > 0 && g.null_indices {
        assert_eq!(s, sheaf_status::NullPointer);
    }
    if nt > 0 && mis != 0 && !g.null_indices && s == OK {
        panic!("misaligned indices accepted");
    }
    if s == OK {
        if nv > st.limits.max_vertices || nt > st.limits.max_triangles {
            panic!("set_geometry accepted {nv} vertices / {nt} triangles over the limits");
        }
        for i in 0..3 * nt as usize {
            // SAFETY: accepted, so aligned and inside (checked above).
            let x = unsafe { ip.add(i).read() };
            assert!(x < nv, "set_geometry accepted index {x} >= {nv}");
        }
        if !(stride >= 12 && stride % 4 == 0) && nv > 1 {
            panic!("set_geometry accepted stride {stride}");
        }
        if !m.moderate() {
            st.wild_scene = true;
        }
        let MeshBuf {
            vertices,
            vertex_at,
            index_words,
            ..
        } = m;
        // The index view is shifted when misaligned; keep both buffers alive.
        st.geometry = Some(Geometry {
            vertices,
            vertex_at,
            index_words,
            index_count: 3 * nt as usize,
            vertex_count: nv,
        });
    }
    st.after(s, &before, "set_geometry");
}

fn build(st: &mut State, what: &str, f: impl FnOnce(*mut sheaf_context) -> sheaf_status) {
    let before = stats_of(st.ctx);
    let had_geometry = st.geometry.is_some();
    let s = f(st.ctx);
    if !had_geometry {
        assert_ne!(s, OK, "{what} without geometry succeeded");
    }
    if s == OK {
        // New structure: earlier results may legitimately change.
        st.trace = None;
        st.render = None;
        st.scene.flat_rebuilt();
    }
    st.after(s, &before, what);
}

fn run(input: &Input) {
    let core_limits = input.limits.get();
    let limits = ffi::sheaf_limits::of(&core_limits);
    let mut need = usize::MAX;
    let s = ffi::sheaf_required_bytes(&limits, &mut need);
    valid_status(s, "required_bytes");
    if s != OK {
        assert_eq!(need, usize::MAX, "required_bytes wrote on failure");
        // create and create_in must fail the same way, leaving *out alone.
        let mut out = 0x1234 as *mut sheaf_context;
        assert_eq!(ffi::sheaf_context_create(&limits, &mut out), s);
        assert_eq!(out as usize, 0x1234);
        let mut buf = vec![0u64; 64];
        let s2 = ffi::sheaf_context_create_in(buf.as_mut_ptr().cast(), 512, &limits, &mut out);
        assert_ne!(s2, OK);
        assert_eq!(out as usize, 0x1234);
        return;
    }
    let mut storage: Vec<u64> = Vec::new();
    let mut ctx: *mut sheaf_context = core::ptr::null_mut();
    let mut created_in = false;
    match input.placement {
        Placement::Owned if need <= MAX_CONTEXT_BYTES => {
            let s = ffi::sheaf_context_create(&limits, &mut ctx);
            valid_status(s, "create");
            assert_eq!(s, OK, "create with valid limits ({need} bytes)");
        }
        Placement::Owned => return,
        Placement::In {
            short,
            slack,
            misalign,
        } => {
            let short = short as usize;
            let have = if short > 0 {
                need.saturating_sub(short)
            } else {
                need + slack as usize
            };
            let mis = misalign as usize % 3 * 8; // 0, 8, 16 bytes past 64
            if have > MAX_CONTEXT_BYTES {
                // Too big to place here: a short buffer must be refused.
                let mut small = vec![0u64; 128];
                let base = small.as_mut_ptr().cast::<u8>();
                let a = base.align_offset(64);
                let mut out = 0x40 as *mut sheaf_context;
                // SAFETY: a..a+512 lies inside the 1024 bytes.
                let s = ffi::sheaf_context_create_in(
                    unsafe { base.add(a) }.cast(),
                    512,
                    &limits,
                    &mut out,
                );
                assert_eq!(s, sheaf_status::BufferTooSmall);
                assert_eq!(out as usize, 0x40);
                return;
            }
            storage = vec![0u64; (have + mis + 64) / 8 + 1];
            let base = storage.as_mut_ptr().cast::<u8>();
            // SAFETY: align_offset + mis + have fits in the allocation.
            let p = unsafe { base.add(base.align_offset(64) + mis) };
            let s = ffi::sheaf_context_create_in(p.cast::<c_void>(), have, &limits, &mut ctx);
            valid_status(s, "create_in");
            let want = if mis != 0 {
                sheaf_status::Misaligned
            } else if have < need {
                sheaf_status::BufferTooSmall
            } else {
                OK
            };
            assert_eq!(s, want, "create_in: {have} of {need} bytes, {mis} past 64");
            if s != OK {
                assert!(ctx.is_null(), "create_in wrote *out on failure");
                return;
            }
            created_in = true;
        }
    }
    let mut st = State {
        ctx,
        limits: core_limits,
        geometry: None,
        trace: None,
        render: None,
        wild_scene: false,
        scene: scene::SceneModel::new(&core_limits),
    };
    assert_eq!(last_error(st.ctx), "no error");
    for op in input.ops.iter().take(24) {
        step(&mut st, op);
    }
    ffi::sheaf_context_destroy(st.ctx);
    if created_in && input.destroy_twice {
        // The buffer is still ours: a second destroy and any call are refused.
        ffi::sheaf_context_destroy(st.ctx);
        let mut s0 = sheaf_stats::default();
        assert_eq!(
            ffi::sheaf_context_stats(st.ctx, &mut s0),
            sheaf_status::InvalidArgument
        );
        assert_eq!(
            ffi::sheaf_context_build_grid(st.ctx, core::ptr::null()),
            sheaf_status::InvalidArgument
        );
    }
    drop(st.geometry.take());
    drop(storage);
}

fn step(st: &mut State, op: &Op) {
    match op {
        Op::SetGeometry(g) => set_geometry(st, g),
        Op::Canned(k, shift) => set_geometry(st, &canned(*k, *shift)),
        Op::Warmup(k) => warmup(st, *k),
        Op::PokeIndex(at, v) => {
            if let Some(g) = &mut st.geometry {
                if g.index_count > 0 {
                    let i = *at as usize % g.index_count;
                    let nv = g.vertex_count.max(1);
                    // Edit the word the context reads (the view may be shifted
                    // when misaligned; then the context refused it anyway).
                    g.index_words[i] = match v {
                        IndexIn::Vertex(x) => *x as u32 % nv,
                        IndexIn::Any(x) => *x,
                    };
                }
            }
        }
        Op::PokeVertex(at, x) => {
            if let Some(g) = &mut st.geometry {
                if !g.vertex_at.is_empty() {
                    let k = *at as usize % (3 * g.vertex_at.len());
                    let i = g.vertex_at[k / 3] + k % 3;
                    g.vertices[i] = x.get();
                    if !moderate(g.vertices[i]) {
                        st.wild_scene = true;
                    }
                }
            }
        }
        Op::BuildGrid(p) => {
            let p = p.as_ref().map(GridIn::get);
            build(st, "build_grid", |c| {
                ffi::sheaf_context_build_grid(c, p.as_ref().map_or(core::ptr::null(), |p| p))
            });
        }
        Op::BuildBvh(p) => {
            let p = p.as_ref().map(BvhIn::get);
            build(st, "build_bvh", |c| {
                ffi::sheaf_context_build_bvh(c, p.as_ref().map_or(core::ptr::null(), |p| p))
            });
        }
        Op::BuildKd(p) => {
            let p = p.as_ref().map(KdIn::get);
            build(st, "build_kd", |c| {
                ffi::sheaf_context_build_kd(c, p.as_ref().map_or(core::ptr::null(), |p| p))
            });
        }
        Op::BuildPgrid(p) => {
            let p = p.as_ref().map(PgridIn::get);
            // Loads triangles for the grids only: traces and renders stand.
            let before = stats_of(st.ctx);
            let s =
                ffi::sheaf_context_build_pgrid(st.ctx, p.as_ref().map_or(core::ptr::null(), |p| p));
            st.after(s, &before, "build_pgrid");
        }
        Op::Trace(m, r) => trace_call(st, None, m.get() % METHODS, false, r),
        // Bit 3 of the hit offset (which uses bits 0-2) picks occluded_with,
        // so the corpus of earlier runs decodes as before.
        Op::TraceWith(p, r) => trace_call(st, Some(p.get()), 0, r.hit_offset & 8 != 0, r),
        Op::Occluded(m, r) => trace_call(st, None, m.get() % METHODS, true, r),
        Op::Render(m, f, fb) => {
            let p = sheaf_trace_params {
                method: m.get() % METHODS,
                ..default_trace()
            };
            render(st, p, p, None, f, fb);
        }
        Op::RenderWith(p, s, f, fb) => render(st, p.get(), s.get(), Some(()), f, fb),
        Op::Whitted(w, f, fb) => whitted(st, w, f, fb),
        Op::Deferred(d, f, fb) => deferred(st, d, f, fb),
        Op::TraceSlot(slot, flag, p, r) => trace_slot(st, *slot, flag & 1 != 0, &p.get(), r),
        Op::RenderRows(slot, y0, y1, p, f, fb) => render_rows(st, *slot, *y0, *y1, &p.get(), f, fb),
        Op::ClearGeometry => {
            let before = stats_of(st.ctx);
            let s = ffi::sheaf_context_clear_geometry(st.ctx);
            valid_status(s, "clear_geometry");
            assert_eq!(s, OK, "clear_geometry on a live context");
            assert_eq!(stats_of(st.ctx), before, "clear_geometry changed the stats");
            // The borrow has ended: free the buffers (ASan catches any later read).
            st.geometry = None;
            // Builds now need geometry; traces and renders still stand.
            assert_eq!(
                ffi::sheaf_context_build_bvh(st.ctx, core::ptr::null()),
                sheaf_status::NoGeometry
            );
            st.recheck("clear_geometry", sheaf_status::NoGeometry);
        }
        Op::BadArg(call, which, kind) => bad_arg(st, *call, *which, *kind),
        Op::Concurrent(other, p, r) => concurrent(st, *other, &p.get(), r),
        Op::Scene(op) => scene::step(st, op),
        Op::TraceCamera(p, f, r, extra, flags) => trace_camera(st, &p.get(), f, r, *extra, *flags),
        Op::Joined(kind, n, helpers) => {
            let helpers: Vec<(u32, u32)> = helpers
                .iter()
                .take(4)
                // Index 0 only with a bad count: a second leader is
                // another group (documented misuse), not a helper.
                .map(|&(i, c)| match (u32::from(i % 5), u32::from(c % 5)) {
                    (0, _) => (0, 0),
                    ic => ic,
                })
                .collect();
            let n = 1 + u32::from(*n % 4);
            build(st, "joined build", |c| joined(c, *kind % 4, n, &helpers));
        }
        Op::DeferredPixel(x, y) => {
            let mut hit = sheaf_hit {
                t: 1.5,
                prim: 77,
                u: 2.5,
                v: 3.5,
            };
            let mut bits = 0xEEu8;
            let s = ffi::sheaf_context_deferred_pixel(
                st.ctx, *x as u32, *y as u32, &mut hit, &mut bits,
            );
            valid_status(s, "deferred_pixel");
            if s != OK {
                assert!(
                    hit.prim == 77 && hit.t == 1.5 && bits == 0xEE,
                    "deferred_pixel wrote on failure"
                );
            } else if hit.prim == ffi::SHEAF_INVALID_ID {
                assert!(hit.t == f32::INFINITY);
            }
        }
        Op::DeferredShadowRay(x, y, l) => {
            let light = l.get();
            let mut ray = sheaf_ray {
                org: [9.0; 3],
                tmin: 9.0,
                dir: [9.0; 3],
                tmax: 9.0,
            };
            let mut has = true;
            let s = ffi::sheaf_context_deferred_shadow_ray(
                st.ctx, *x as u32, *y as u32, &light, &mut ray, &mut has,
            );
            valid_status(s, "deferred_shadow_ray");
            if s != OK || !has {
                assert!(
                    ray.org == [9.0; 3] && ray.tmax == 9.0,
                    "shadow ray written without one"
                );
            }
            if s != OK {
                assert!(has, "has_ray written on failure");
            }
        }
        Op::CameraRay(f, x, y) => {
            let frame = f.get();
            let mut ray = sheaf_ray {
                org: [9.0; 3],
                tmin: 9.0,
                dir: [9.0; 3],
                tmax: 9.0,
            };
            let s = ffi::sheaf_frame_camera_ray(&frame, *x as u32, *y as u32, &mut ray);
            valid_status(s, "frame_camera_ray");
            if s != OK {
                assert!(
                    ray.org == [9.0; 3] && ray.dir == [9.0; 3],
                    "camera ray written on failure"
                );
            } else {
                assert!(ray.tmin == 0.0 && ray.tmax == f32::INFINITY);
            }
        }
        Op::Stats => {
            let _ = stats_of(st.ctx);
            assert_eq!(
                ffi::sheaf_context_stats(st.ctx, core::ptr::null_mut()),
                sheaf_status::NullPointer
            );
        }
        Op::LastError(len) => {
            let len = *len as usize % 300;
            let mut buf = vec![0x7f as core::ffi::c_char; len.max(1)];
            let mut written = 12345usize;
            let s = ffi::sheaf_context_last_error(st.ctx, buf.as_mut_ptr(), len, &mut written);
            valid_status(s, "last_error");
            if len == 0 {
                assert_eq!(s, sheaf_status::InvalidArgument);
                assert!(written == 12345 && buf[0] == 0x7f);
            } else {
                assert_eq!(s, OK);
                assert!(written < len && buf[written] == 0);
                assert!(
                    buf[written + 1..].iter().all(|&c| c == 0x7f),
                    "wrote past the NUL"
                );
                let full = last_error(st.ctx);
                let got: Vec<u8> = buf[..written].iter().map(|&c| c as u8).collect();
                assert!(
                    full.as_bytes().starts_with(&got),
                    "truncated message is not a prefix"
                );
                assert!(core::str::from_utf8(&got).is_ok(), "cut inside a character");
            }
        }
        Op::StatusString(code) => {
            let p = ffi::sheaf_status_string(*code);
            assert!(!p.is_null());
            // SAFETY: documented as a static NUL-terminated string.
            let text = unsafe { core::ffi::CStr::from_ptr(p) };
            assert!(!text.to_bytes().is_empty());
        }
    }
}

fn warmup(st: &mut State, k: u8) {
    set_geometry(st, &canned(k, [F::Small(0); 3]));
    use core::ptr::null;
    build(st, "build_grid", |c| {
        ffi::sheaf_context_build_grid(c, null())
    });
    build(st, "build_bvh", |c| ffi::sheaf_context_build_bvh(c, null()));
    build(st, "build_kd", |c| ffi::sheaf_context_build_kd(c, null()));
    let before = stats_of(st.ctx);
    let s = ffi::sheaf_context_build_pgrid(st.ctx, null());
    st.after(s, &before, "build_pgrid");
    let zero = F::Small(0);
    let light = LightIn {
        position: [zero; 3],
        color: [zero; 3],
        spot_direction: [zero; 3],
        spot_angle_deg: zero,
        spot_soft_deg: zero,
        raw: false,
        view: k / 3,
    };
    let frame = FrameIn {
        eye: [zero; 3],
        look_at: [zero; 3],
        up: [zero; 3],
        fov: zero,
        light,
        albedo: [zero; 3],
        ambient: zero,
        background: [zero; 3],
        shadows: k % 2 == 0,
        width: N::Small(k),
        height: N::Small(k / 2),
        raw_camera: false,
        view: k,
    };
    let fb = FbIn {
        row_pad: k,
        any_stride: None,
        short: 0,
        slack: k % 7,
        null: false,
    };
    let tp = |m: u8| TraceIn {
        method: N::Small(m),
        packet: N::Small(k / 11),
        macrocells: k % 3 == 0,
        mailbox: k % 5 == 0,
        culling: k % 7 != 0,
        ray_kind: N::Small(k % 4),
        entry: N::Small(k / 4 % 3),
        split: F::Small(k as i8),
        isa: N::Small(0),
    };
    let m = k % 13;
    render(st, tp(m).get(), tp(m / 2).get(), Some(()), &frame, &fb);
    let d = DeferredIn {
        lights: vec![light; 1 + k as usize % 3],
        primary_pgrid: k % 3 != 1,
        shadow_light_grid: k % 3 != 2,
        primary: tp(m),
        shadow: tp(12 - m),
        null_lights: false,
    };
    deferred(st, &d, &frame, &fb);
    // Camera rays of the frame, traced with the method.
    let f = frame.get();
    let mut rays = Vec::new();
    for y in 0..f.height.min(8) {
        for x in 0..f.width.min(8) {
            let mut r = sheaf_ray {
                org: [0.0; 3],
                tmin: 0.0,
                dir: [0.0; 3],
                tmax: 0.0,
            };
            if ffi::sheaf_frame_camera_ray(&f, x, y, &mut r) == OK {
                rays.push(RayIn {
                    org: r.org.map(|x| F::Bits(x.to_bits())),
                    tmin: F::Bits(r.tmin.to_bits()),
                    dir: r.dir.map(|x| F::Bits(x.to_bits())),
                    tmax: F::Bits(r.tmax.to_bits()),
                });
            }
        }
    }
    let r = RaysIn {
        rays,
        fan: None,
        tmax: RayTmax::Inf,
        claim: None,
        ray_offset: k,
        hit_offset: k / 8,
        overlap: false,
        null_rays: false,
        null_hits: false,
    };
    trace_call(st, Some(tp(m).get()), 0, false, &r);
    trace_call(st, None, m as u32, true, &r);
    trace_call(st, Some(tp(m).get()), 0, true, &r);
    // Camera packets over the whole image, then a corner, each compared
    // with the ray-array call (the single-mesh call; the scene's warm-up
    // is `scene.rs`'s).
    let whole = [0, 0, 255, 255];
    trace_camera(st, &tp(m).get(), &frame, &whole, k % 3, 0);
    trace_camera(st, &tp(k % 13).get(), &frame, &[k, k / 2, 200, 255], 0, 0);
}

fn render(
    st: &mut State,
    p: sheaf_trace_params,
    s: sheaf_trace_params,
    with: Option<()>,
    f: &FrameIn,
    fb: &FbIn,
) {
    let frame = f.get();
    let (mut buf, stride, len, _) = framebuffer(&frame, fb);
    let ptr = if fb.null {
        core::ptr::null_mut()
    } else {
        buf.as_mut_ptr()
    };
    let before = stats_of(st.ctx);
    let status = if with.is_some() {
        ffi::context::sheaf_context_render_with(st.ctx, &p, &s, &frame, ptr, stride, len)
    } else {
        ffi::sheaf_context_render(st.ctx, p.method, &frame, ptr, stride, len)
    };
    if check_render(st, status, &frame, &buf, stride, fb.null, &before, "render") {
        // Rendering is deterministic: the same bytes again.
        let mut again = vec![S_PIX; len];
        assert_eq!(
            ffi::context::sheaf_context_render_with(
                st.ctx,
                &p,
                &s,
                &frame,
                again.as_mut_ptr(),
                stride,
                len
            ),
            OK
        );
        assert!(again == buf, "the same render gave other pixels");
        st.render = Some(RenderRecord {
            primary: p,
            shadow: s,
            frame,
            stride,
            image: buf,
        });
    }
}

fn whitted(st: &mut State, w: &WhittedIn, f: &FrameIn, fb: &FbIn) {
    let frame = f.get();
    let (mut buf, stride, len, _) = framebuffer(&frame, fb);
    let ptr = if fb.null {
        core::ptr::null_mut()
    } else {
        buf.as_mut_ptr()
    };
    let lights: Vec<PointLight> = w.lights.iter().take(4).map(LightIn::get).collect();
    let mats: Vec<Material> = w
        .materials
        .iter()
        .take(4)
        .map(|m| {
            // Small values map into the valid ranges; others stay raw.
            let unit = |x: F, d: f32| match x {
                F::Small(v) => (v as f32).abs() / d,
                x => x.get(),
            };
            Material {
                diffuse: m.diffuse.map(|c| unit(c, 128.0)),
                reflect: unit(m.reflect, 256.0),
                transmit: unit(m.transmit, 256.0),
                ior: match m.ior {
                    F::Small(v) => 1.0 + (v as f32).abs() / 64.0,
                    x => x.get(),
                },
            }
        })
        .collect();
    let ranges: Vec<MaterialRange> = w
        .ranges
        .iter()
        .take(4)
        .map(|&(first, material)| MaterialRange {
            first: first as u32,
            material: if material == u16::MAX {
                u32::MAX
            } else {
                material as u32 % 6
            },
        })
        .collect();
    let params = w.bounces.map(|(r, t)| ffi::sheaf_whitted_params {
        size: core::mem::size_of::<ffi::sheaf_whitted_params>() as u32,
        max_reflect: r as u32 % 10,
        max_refract: t as u32 % 10,
    });
    // A misaligned copy of the lights (SHEAF_STATUS_MISALIGNED expected).
    let mut lbytes = vec![0u8; 4 + lights.len() * core::mem::size_of::<PointLight>()];
    for (i, l) in lights.iter().enumerate() {
        // SAFETY: in bounds; unaligned write.
        unsafe {
            lbytes
                .as_mut_ptr()
                .add(1 + i * core::mem::size_of::<PointLight>())
                .cast::<PointLight>()
                .write_unaligned(*l)
        };
    }
    let lp: *const PointLight = if w.misalign_lights && !lights.is_empty() {
        // SAFETY: in bounds.
        unsafe { lbytes.as_ptr().add(1).cast() }
    } else {
        lights.as_ptr()
    };
    let (pp, sp, xp) = (w.primary.get(), w.shadow.get(), w.secondary.get());
    let before = stats_of(st.ctx);
    let s = ffi::sheaf_context_render_whitted(
        st.ctx,
        &pp,
        &sp,
        &xp,
        params.as_ref().map_or(core::ptr::null(), |p| p),
        &frame,
        lp,
        lights.len(),
        mats.as_ptr(),
        mats.len(),
        ranges.as_ptr(),
        ranges.len(),
        ptr,
        stride,
        len,
    );
    if w.misalign_lights && !lights.is_empty() && s == OK {
        panic!("misaligned lights accepted");
    }
    check_render(
        st,
        s,
        &frame,
        &buf,
        stride,
        fb.null,
        &before,
        "render_whitted",
    );
}

fn deferred(st: &mut State, d: &DeferredIn, f: &FrameIn, fb: &FbIn) {
    let frame = f.get();
    let (mut buf, stride, len, _) = framebuffer(&frame, fb);
    let ptr = if fb.null {
        core::ptr::null_mut()
    } else {
        buf.as_mut_ptr()
    };
    let lights: Vec<PointLight> = d.lights.iter().take(10).map(LightIn::get).collect();
    // The job points to its trace params: they live through the call.
    let (primary, shadow) = (d.primary.get(), d.shadow.get());
    let job = sheaf_deferred_job {
        frame,
        lights: if d.null_lights {
            core::ptr::null()
        } else {
            lights.as_ptr()
        },
        light_count: lights.len(),
        primary_pgrid: d.primary_pgrid.into(),
        shadow_light_grid: d.shadow_light_grid.into(),
        primary: &primary,
        shadow: &shadow,
    };
    let before = stats_of(st.ctx);
    let s = ffi::sheaf_context_render_deferred(st.ctx, &job, ptr, stride, len);
    if lights.len() > 8 {
        assert_eq!(s, sheaf_status::InvalidArgument, "more than 8 lights");
    }
    if d.null_lights && !lights.is_empty() && lights.len() <= 8 && !fb.null {
        assert_ne!(s, OK, "NULL lights accepted");
    }
    if check_render(
        st,
        s,
        &frame,
        &buf,
        stride,
        fb.null,
        &before,
        "render_deferred",
    ) {
        // Every pixel of the frame answers; one past it does not.
        let mut hit = sheaf_hit {
            t: 0.0,
            prim: 0,
            u: 0.0,
            v: 0.0,
        };
        let mut bits = 0u8;
        let (w, h) = (frame.width, frame.height);
        assert_eq!(
            ffi::sheaf_context_deferred_pixel(st.ctx, w - 1, h - 1, &mut hit, &mut bits),
            OK
        );
        assert_eq!(
            ffi::sheaf_context_deferred_pixel(st.ctx, w, 0, &mut hit, &mut bits),
            sheaf_status::InvalidArgument
        );
        let n = lights.len().max(1);
        assert!(
            n == 8 || bits >> n == 0,
            "shadow bits {bits:#x} for {n} lights"
        );
    }
}

// ---- slots, bad arguments, two threads ----------------------------------------------------

/// trace_slot / occluded_slot: the same bytes as trace_with / occluded_with,
/// or a refusal that writes nothing (slots past max_threads:
/// CAPACITY_THREADS).
fn trace_slot(st: &mut State, slot: u8, occ: bool, p: &sheaf_trace_params, r: &RaysIn) {
    let rays = make_rays(r);
    let n = rays.len();
    let slot = slot as u32 % (st.limits.max_threads + 2);
    let mut out = vec![S_HIT; n * if occ { 1 } else { 16 }];
    let s = if occ {
        ffi::sheaf_context_occluded_slot(st.ctx, slot, p, rays.as_ptr(), out.as_mut_ptr(), n)
    } else {
        ffi::sheaf_context_trace_slot(st.ctx, slot, p, rays.as_ptr(), out.as_mut_ptr().cast(), n)
    };
    valid_status(s, "trace_slot");
    if slot >= st.limits.max_threads {
        assert_ne!(s, OK, "slot {slot} of {} accepted", st.limits.max_threads);
    }
    if s != OK {
        assert!(
            out.iter().all(|&b| b == S_HIT),
            "a failed slot trace wrote results"
        );
        st.recheck("trace_slot", s);
        return;
    }
    let want = if occ {
        let mut o = vec![S_HIT; n];
        assert_eq!(
            ffi::sheaf_context_occluded_with(st.ctx, p, rays.as_ptr(), o.as_mut_ptr(), n),
            OK
        );
        o
    } else {
        run_trace(st.ctx, p, false, &rays).expect("trace_with fails where trace_slot succeeded")
    };
    if occ {
        assert!(out == want, "occluded_slot differs from occluded_with");
    } else {
        // Bytes 0..8 of each hit (t, prim) and u, v: all of it.
        assert!(out == want, "trace_slot differs from trace_with");
    }
}

/// render_rows: the band equals the same rows of render_with, nothing
/// outside the band is written, refusals write nothing.
fn render_rows(
    st: &mut State,
    slot: u8,
    y0: u8,
    y1: u8,
    p: &sheaf_trace_params,
    f: &FrameIn,
    fb: &FbIn,
) {
    let frame = f.get();
    let (mut buf, stride, len, _) = framebuffer(&frame, fb);
    let slot = slot as u32 % (st.limits.max_threads + 2);
    let (y0, y1) = (y0 as u32 % 40, y1 as u32 % 40);
    let off = (y0 as usize).saturating_mul(stride).min(len);
    let ptr = if fb.null {
        core::ptr::null_mut()
    } else {
        // SAFETY: off <= len.
        unsafe { buf.as_mut_ptr().add(off) }
    };
    let s =
        ffi::sheaf_context_render_rows(st.ctx, slot, p, p, &frame, y0, y1, ptr, stride, len - off);
    valid_status(s, "render_rows");
    if s != OK {
        assert!(
            buf.iter().all(|&b| b == S_PIX),
            "a failed render_rows wrote pixels"
        );
        st.recheck("render_rows", s);
        return;
    }
    assert!(slot < st.limits.max_threads && y0 < y1 && y1 <= frame.height && !fb.null);
    let mut whole = vec![S_PIX; len];
    let sw = ffi::context::sheaf_context_render_with(
        st.ctx,
        p,
        p,
        &frame,
        whole.as_mut_ptr(),
        stride,
        len,
    );
    let w4 = frame.width as usize * 4;
    for y in 0..frame.height as usize {
        let row = y * stride;
        let inside = y >= y0 as usize && y < y1 as usize;
        for x in 0..w4.min(len.saturating_sub(row)) {
            if inside {
                if sw == OK {
                    assert_eq!(
                        buf[row + x],
                        whole[row + x],
                        "render_rows pixel ({}, {y}) differs",
                        x / 4
                    );
                }
            } else {
                assert_eq!(
                    buf[row + x],
                    S_PIX,
                    "render_rows wrote row {y} outside [{y0}, {y1})"
                );
            }
        }
    }
}

/// One bad argument: `kind` 0 NULL, 1 a count at the overflow boundary, 2
/// outputs partly over the inputs; `which` picks the argument. Every such
/// call is refused and writes nothing.
fn bad_arg(st: &mut State, call: u8, which: u8, kind: u8) {
    let rays: Vec<sheaf_ray> = (0..8)
        .map(|i| sheaf_ray {
            org: [i as f32, -5.0, 1.0],
            tmin: 0.0,
            dir: [0.0, 1.0, 0.0],
            tmax: f32::INFINITY,
        })
        .collect();
    let p = default_trace();
    // A buffer holding rays then room for results, so outputs can overlap.
    let rsz = core::mem::size_of::<sheaf_ray>();
    let mut bytes = vec![S_HIT; 8 * rsz + 8 * 16 + 64];
    for (i, r) in rays.iter().enumerate() {
        // SAFETY: in bounds; unaligned write of a plain struct.
        unsafe {
            bytes
                .as_mut_ptr()
                .add(i * rsz)
                .cast::<sheaf_ray>()
                .write_unaligned(*r)
        };
    }
    let before = bytes.clone();
    let base = bytes.as_mut_ptr();
    let kind = kind % 3;
    let huge = [
        usize::MAX,
        usize::MAX / 16 + 1,
        isize::MAX as usize / 32 + 1,
        (u32::MAX as usize) + 1,
    ][which as usize % 4];
    let shift = 1 + which as usize % (8 * rsz - 1); // results start inside the rays
    let (rp, count): (*const sheaf_ray, usize) = match kind {
        0 if which % 2 == 0 => (core::ptr::null(), 8),
        1 => (base.cast_const().cast(), huge),
        _ => (base.cast_const().cast(), 8),
    };
    // SAFETY: offsets inside `bytes`.
    let out: *mut u8 = match kind {
        0 if which % 2 == 1 => core::ptr::null_mut(),
        2 => unsafe { base.add(shift) },
        _ => unsafe { base.add(8 * rsz) },
    };
    let slot = 0;
    let s = match call % 6 {
        0 => ffi::sheaf_context_trace(st.ctx, p.method, rp, out.cast(), count),
        1 => ffi::context::sheaf_context_trace_with(st.ctx, &p, rp, out.cast(), count),
        2 => ffi::sheaf_context_occluded(st.ctx, p.method, rp, out, count),
        3 => ffi::sheaf_context_occluded_with(st.ctx, &p, rp, out, count),
        4 => ffi::sheaf_context_trace_slot(st.ctx, slot, &p, rp, out.cast(), count),
        _ => ffi::sheaf_context_occluded_slot(st.ctx, slot, &p, rp, out, count),
    };
    valid_status(s, "bad_arg");
    // Results start inside the rays (kind 2), so every kind is refused:
    // NULL before anything else, then sizes and overlaps (InvalidArgument);
    // only a context that cannot trace at all may answer first.
    assert_ne!(
        s,
        OK,
        "call {} with bad argument kind {kind} ({which}) accepted",
        call % 6
    );
    let want = if kind == 0 {
        sheaf_status::NullPointer
    } else {
        sheaf_status::InvalidArgument
    };
    if s != sheaf_status::NotBuilt && s != sheaf_status::CapacityThreads {
        assert_eq!(s, want, "call {} kind {kind}", call % 6);
    }
    assert!(bytes == before, "a refused call wrote memory");
    st.recheck("bad_arg", s);
}

/// Two threads on one context: thread A traces on slot 0 (when there are
/// two slots) while thread B runs another call; every status is OK or a
/// busy refusal, and every OK trace equals the serial answer.
fn concurrent(st: &mut State, other: u8, p: &sheaf_trace_params, r: &RaysIn) {
    let rays = make_rays(r);
    let Some(want) = run_trace(st.ctx, p, false, &rays) else {
        return; // nothing traceable: no serial answer to compare with
    };
    let two = st.limits.max_threads >= 2;
    let ctx = st.ctx as usize;
    let stats_before = stats_of(st.ctx);
    let (a, b) = std::thread::scope(|sc| {
        let ta = sc.spawn(|| {
            let ctx = ctx as *mut sheaf_context;
            let mut h = vec![
                sheaf_hit {
                    t: 0.0,
                    prim: 0,
                    u: 0.0,
                    v: 0.0
                };
                rays.len()
            ];
            let s = if two {
                ffi::sheaf_context_trace_slot(ctx, 0, p, rays.as_ptr(), h.as_mut_ptr(), rays.len())
            } else {
                ffi::context::sheaf_context_trace_with(
                    ctx,
                    p,
                    rays.as_ptr(),
                    h.as_mut_ptr(),
                    rays.len(),
                )
            };
            (s, hit_bytes(&h))
        });
        let tb = sc.spawn(|| {
            let ctx = ctx as *mut sheaf_context;
            let mut h = vec![
                sheaf_hit {
                    t: 0.0,
                    prim: 0,
                    u: 0.0,
                    v: 0.0
                };
                rays.len()
            ];
            let mut img = vec![0u8; 16 * 16 * 4];
            let frame = sheaf_frame {
                camera: Camera {
                    eye: [3.0, -4.0, 2.0],
                    look_at: [0.0; 3],
                    up: [0.0, 0.0, 1.0],
                    fov_y_deg: 50.0,
                },
                light: PointLight::default(),
                shading: ffi::sheaf_shading::of(&Shading::default()),
                width: 16,
                height: 16,
            };
            let s = match other % 6 {
                0 if two => ffi::sheaf_context_trace_slot(
                    ctx,
                    1,
                    p,
                    rays.as_ptr(),
                    h.as_mut_ptr(),
                    rays.len(),
                ),
                0 | 1 => ffi::context::sheaf_context_trace_with(
                    ctx,
                    p,
                    rays.as_ptr(),
                    h.as_mut_ptr(),
                    rays.len(),
                ),
                2 => ffi::sheaf_context_render_rows(
                    ctx,
                    if two { 1 } else { 0 },
                    p,
                    p,
                    &frame,
                    0,
                    16,
                    img.as_mut_ptr(),
                    64,
                    img.len(),
                ),
                3 => ffi::sheaf_context_build_bvh(ctx, core::ptr::null()),
                4 => ffi::sheaf_context_build_grid(ctx, core::ptr::null()),
                _ => ffi::sheaf_context_render(
                    ctx,
                    p.method,
                    &frame,
                    img.as_mut_ptr(),
                    64,
                    img.len(),
                ),
            };
            let traced = matches!(other % 6, 0 | 1);
            (s, traced.then(|| hit_bytes(&h)))
        });
        (ta.join().unwrap(), tb.join().unwrap())
    });
    // With one slot (max_threads 1) both calls take the only slot: the
    // one that finds it taken gets CAPACITY_THREADS, as the header says.
    let busy = |s: sheaf_status| {
        matches!(s, sheaf_status::ContextBusy | sheaf_status::SlotBusy)
            || (!two && s == sheaf_status::CapacityThreads)
    };
    valid_status(a.0, "concurrent trace");
    valid_status(b.0, "concurrent other");
    assert!(a.0 == OK || busy(a.0), "concurrent trace: {:?}", a.0);
    if let (OK, Some(h)) = (b.0, &b.1) {
        assert!(*h == want, "a second concurrent trace gave other hits");
    }
    // A successful rebuild may change answers (buffers edited in place
    // since the last build): the racing trace then equals the answer from
    // before or after it, and earlier records are dropped, as `build` does.
    let after = run_trace(st.ctx, p, false, &rays);
    let rebuilt = matches!(other % 6, 3 | 4) && b.0 == OK;
    if a.0 == OK {
        assert!(
            a.1 == want || (rebuilt && after.as_ref() == Some(&a.1)),
            "a trace racing another call gave other hits"
        );
    }
    if rebuilt {
        st.trace = None;
        st.render = None;
    } else {
        assert!(
            after.as_ref() == Some(&want),
            "the serial answer changed after a concurrent pair"
        );
    }
    if matches!(other % 6, 0 | 1 | 2) {
        assert_eq!(
            stats_of(st.ctx),
            stats_before,
            "shared calls changed the stats"
        );
    }
    st.recheck("concurrent", b.0);
}

fuzz_target!(|input: Input| {
    run(&input);
});
