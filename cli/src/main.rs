//! `sheaf`: render, animate, inspect and export scenes with the sheaf
//! kernel, and measure it against its papers.
//!
//! ```text
//! sheaf demo   [--frames 24] [--size 640x384] [--family bvh|grid|kd] [--out-dir out/demo] ...
//! sheaf grid-demo [--frames 8] [--size 640x480] [--out-dir out/grid-demo] ...
//! sheaf render <scene.obj | builtin:NAME> --out image.png [--size 800x600] ...
//! sheaf render <scene> --out image.png --primary pgrid --shadows light-grid [--chunk 256] ...
//! sheaf info   <scene.obj | builtin:NAME>
//! sheaf export <scene> --out scene.bin [--size 1024x1024]
//! sheaf bench  [--whitted | --entry | --pgrid | --stress] [--quick] ...
//! ```
//!
//! This file holds the command line (clap); `cmd/` the commands, one file
//! each; `studies/` the paper studies of `sheaf bench`; `load` the scenes
//! (OBJ files, built-in and stress scenes), `view` the automatic views and
//! lights, `run` contexts sized for a scene and frames on threads.
//!
//! Every sheaf call goes through one `OwnedContext` per command, created once
//! (one allocation) with `Limits` sized for the scene; building, tracing and
//! rendering then allocate nothing inside sheaf. Frames are rendered in row
//! bands by `render::render_rows` on a rayon pool sharing `ctx.tracer()`, one
//! thread per mailbox slot of the context; with `--primary` or `--shadows`
//! they are deferred frames (`render::deferred`: perspective grid, light
//! grids) whose work items run on the same pools (`run::Threads`).
//!
//! Errors print one line (`error: what failed: why`, sheaf's `Display` where
//! sheaf failed) and exit with status 1; bad command-line arguments exit
//! with clap's 2.
// Unsafe code only in `studies::embree` (Embree's C API), which allows it.
#![deny(unsafe_code)]

mod cmd;
mod load;
mod progress;
mod run;
mod studies;
mod view;

use clap::{Args, Parser, Subcommand, ValueEnum};
use std::path::PathBuf;
use std::process::ExitCode;

#[derive(Parser)]
#[command(
    name = "sheaf",
    version,
    about = "Ray-trace triangle scenes with sheaf's per-frame acceleration structures (uniform grid, BVH, kd-tree)"
)]
struct Cli {
    #[command(subcommand)]
    cmd: Cmd,
}

#[derive(Subcommand)]
enum Cmd {
    /// The main job: an engine's frame loop on a two-level scene (a static environment, meshes
    /// refit and rebuilt every frame, many instances, the top level committed per frame), traced
    /// by the BVH through instances or by the grid or kd-tree rebuilt over the flattened scene;
    /// a table per frame, PNG frames and an animated PNG.
    #[command(alias = "engine")]
    Demo(cmd::engine::EngineArgs),
    /// Animate the built-in scene: rebuild the grid and render every frame, print a table.
    GridDemo(DemoArgs),
    /// Render one image of an OBJ file or a built-in scene.
    Render(RenderArgs),
    /// Print a scene's size, bounds and the memory a context for it needs.
    Info(InfoArgs),
    /// Benchmark every scene x method x packet size x triangle test: build and trace speed,
    /// counters, accuracy against the f64 reference; CSV, Markdown and a speed-vs-accuracy chart.
    Bench(BenchArgs),
    /// Write a scene, a named view and its light to a binary file for C programs (the Embree
    /// comparison in benches/embree reads it, so both libraries trace the same triangles and rays).
    Export(cmd::export::ExportArgs),
}

/// Ray-triangle test of the grid.
#[derive(Clone, Copy, Debug, ValueEnum)]
pub enum TestArg {
    /// Moller-Trumbore.
    Mt,
    /// Woop-Benthin-Wald watertight test.
    Watertight,
    /// Wald 2004 precomputed projection test.
    Projection,
}

/// Grid build parameters (`GridParams`).
#[derive(Args, Clone, Copy, Debug)]
pub struct GridOpts {
    /// Ray-triangle test.
    #[arg(long, value_enum, default_value = "mt")]
    pub test: TestArg,
    /// Grid cells per triangle (CGT paper, section 3: 5).
    #[arg(long, default_value_t = 5.0)]
    pub lambda: f32,
    /// Macrocell side in cells (CGT paper, section 2.4: 6); 0 or 1 disables macrocells.
    #[arg(long, default_value_t = 6)]
    pub macrocell: u32,
}

impl TestArg {
    pub fn tri_test(self) -> sheaf::TriTest {
        match self {
            TestArg::Mt => sheaf::TriTest::MollerTrumbore,
            TestArg::Watertight => sheaf::TriTest::Watertight,
            TestArg::Projection => sheaf::TriTest::Projection,
        }
    }
}

impl GridOpts {
    pub fn params(&self) -> sheaf::GridParams {
        sheaf::GridParams {
            lambda: self.lambda,
            macrocell: self.macrocell,
            test: self.test.tri_test(),
            fit: false,
        }
    }
}

/// Traversal method (`Method`).
#[derive(Clone, Copy, Debug, PartialEq, Eq, ValueEnum)]
pub enum MethodArg {
    /// Single-ray 3DDDA (the grid baseline).
    GridDda,
    /// Coherent grid traversal of n x n packets.
    GridCgt,
    /// BVH, single-ray traversal (the BVH baseline).
    BvhSingle,
    /// BVH, single rays through the 4-wide tree.
    BvhWide,
    /// BVH, 2x2 SIMD rays.
    BvhSimd,
    /// BVH, n x n packets, Masked traversal.
    BvhMasked,
    /// BVH, n x n packets, Ranged traversal.
    BvhRanged,
    /// BVH, n x n packets, Partition traversal.
    BvhPartition,
    /// BVH, n x n packets, Ranged traversal of the 4-wide tree.
    BvhWideRanged,
    /// BVH, n x n packets, frustum-first traversal of the 4-wide tree.
    BvhFrustum,
    /// kd-tree, single-ray traversal (the kd baseline).
    KdSingle,
    /// kd-tree, 2x2 SIMD rays.
    KdSimd,
    /// kd-tree, n x n packets driven by their frustum (with --entry: from an entry point).
    KdPacket,
}

impl MethodArg {
    pub fn method(self) -> sheaf::Method {
        match self {
            MethodArg::GridDda => sheaf::Method::GridDda,
            MethodArg::GridCgt => sheaf::Method::GridCgt,
            MethodArg::BvhSingle => sheaf::Method::BvhSingle,
            MethodArg::BvhWide => sheaf::Method::BvhWide,
            MethodArg::BvhSimd => sheaf::Method::BvhSimd,
            MethodArg::BvhMasked => sheaf::Method::BvhMasked,
            MethodArg::BvhRanged => sheaf::Method::BvhRanged,
            MethodArg::BvhPartition => sheaf::Method::BvhPartition,
            MethodArg::BvhWideRanged => sheaf::Method::BvhWideRanged,
            MethodArg::BvhFrustum => sheaf::Method::BvhFrustum,
            MethodArg::KdSingle => sheaf::Method::KdSingle,
            MethodArg::KdSimd => sheaf::Method::KdSimd,
            MethodArg::KdPacket => sheaf::Method::KdPacket,
        }
    }
}

/// Entry-point search before each packet of a tree method (`EntrySearch`).
#[derive(Clone, Copy, Debug, PartialEq, Eq, ValueEnum)]
pub enum EntryArg {
    /// Packets start at the root (plain packet tracing).
    None,
    /// MLRTA (Reshetov et al. 2005).
    Mlrta,
    /// AEPSA (the accelerated entry-point search).
    Aepsa,
}

impl EntryArg {
    pub fn search(self) -> sheaf::trace::EntrySearch {
        match self {
            EntryArg::None => sheaf::trace::EntrySearch::None,
            EntryArg::Mlrta => sheaf::trace::EntrySearch::Mlrta,
            EntryArg::Aepsa => sheaf::trace::EntrySearch::Aepsa,
        }
    }
}

/// Acceleration structure families.
#[derive(Clone, Copy, Debug, PartialEq, Eq, ValueEnum)]
pub enum StructureArg {
    Grid,
    Bvh,
    Kd,
}

/// How primary and shadow rays are traced (`TraceParams`).
#[derive(Args, Clone, Copy, Debug)]
pub struct TraceOpts {
    /// Method for primary rays.
    #[arg(long, value_enum, default_value = "grid-cgt")]
    pub method: MethodArg,
    /// Packet side n (n x n rays) for primary rays: 2, 4, 8, 16 or 32.
    #[arg(long, default_value_t = 8)]
    pub packet: u32,
    /// Method for shadow rays (default: as --method).
    #[arg(long, value_enum)]
    pub shadow_method: Option<MethodArg>,
    /// Packet side for shadow rays (default: as --packet).
    #[arg(long)]
    pub shadow_packet: Option<u32>,
    /// Entry-point search before each packet of kd-packet and bvh-masked/ranged/partition
    /// (primary and shadow rays); other methods ignore it.
    #[arg(long, value_enum, default_value = "none")]
    pub entry: EntryArg,
    /// Split shadow packets whose hit points' distances to the light differ by more than this
    /// ratio (CGT section 4.7); 0 disables splitting.
    #[arg(long, default_value_t = 2.0)]
    pub split: f32,
    /// Turn off macrocell skipping, mailboxing or frustum culling (for comparison runs).
    #[arg(long)]
    pub no_macrocells: bool,
    #[arg(long)]
    pub no_mailbox: bool,
    #[arg(long)]
    pub no_culling: bool,
}

impl TraceOpts {
    /// (primary, shadow) parameters, checked.
    pub fn params(&self) -> Result<(sheaf::TraceParams, sheaf::TraceParams), sheaf::Error> {
        let cgt = sheaf::CgtOptions {
            macrocells: !self.no_macrocells,
            mailbox: !self.no_mailbox,
            culling: !self.no_culling,
        };
        let bvh = sheaf::trace::BvhOptions {
            culling: !self.no_culling,
            ..Default::default()
        };
        let primary = sheaf::TraceParams {
            method: self.method.method(),
            packet: self.packet,
            cgt,
            bvh,
            entry: self.entry.search(),
            split: self.split,
            fallbacks: true,
            isa: sheaf::Isa::Auto,
            opaque: false,
        };
        let shadow = sheaf::TraceParams {
            method: self.shadow_method.unwrap_or(self.method).method(),
            packet: self.shadow_packet.unwrap_or(self.packet),
            ..primary
        };
        primary.validate()?;
        shadow.validate()?;
        Ok((primary, shadow))
    }
    /// `grid-cgt 8x8 / shadows grid-cgt 8x8`, `kd-packet 8x8 aepsa / shadows kd-packet 8x8 aepsa`.
    pub fn label(&self) -> String {
        let entry = self.entry.search();
        let name = |m: MethodArg, n: u32| {
            let m = m.method();
            let mut s = if m.is_packet() {
                format!("{} {n}x{n}", m.name())
            } else {
                m.name().to_string()
            };
            if run::uses_entry(m) && entry != sheaf::trace::EntrySearch::None {
                s.push(' ');
                s.push_str(entry.name());
            }
            s
        };
        let sp = self.shadow_packet.unwrap_or(self.packet);
        format!(
            "{} / shadows {}",
            name(self.method, self.packet),
            name(self.shadow_method.unwrap_or(self.method), sp)
        )
    }
}

/// How camera rays are traced in a deferred frame (`PrimaryPass`).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum PrimaryArg {
    /// The perspective grid, built per frame.
    Pgrid,
    /// A traversal method (as --method).
    Method(MethodArg),
}

/// How shadow rays are traced in a deferred frame (`ShadowPass`).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ShadowsArg {
    /// A spherical light grid per light, rays sorted into light tiles.
    LightGrid,
    /// A traversal method (as --shadow-method).
    Method(MethodArg),
}

/// `pgrid` or a --method name.
fn parse_primary(s: &str) -> Result<PrimaryArg, String> {
    if s.eq_ignore_ascii_case("pgrid") {
        return Ok(PrimaryArg::Pgrid);
    }
    MethodArg::from_str(s, true)
        .map(PrimaryArg::Method)
        .map_err(|_| format!("'{s}' is not pgrid or a method ({})", method_names()))
}

/// `light-grid` or a --method name.
fn parse_shadows(s: &str) -> Result<ShadowsArg, String> {
    if s.eq_ignore_ascii_case("light-grid") {
        return Ok(ShadowsArg::LightGrid);
    }
    MethodArg::from_str(s, true)
        .map(ShadowsArg::Method)
        .map_err(|_| format!("'{s}' is not light-grid or a method ({})", method_names()))
}

fn method_names() -> String {
    MethodArg::value_variants()
        .iter()
        .filter_map(|m| m.to_possible_value())
        .map(|v| v.get_name().to_string())
        .collect::<Vec<_>>()
        .join(", ")
}

/// Perspective/light grid parameters (`PgridParams`); unset: the defaults
/// of `PgridParams::default()`.
#[derive(Args, Clone, Copy, Debug, Default)]
pub struct PgridOpts {
    /// Side of a perspective grid sorting tile in pixels: 2, 4, 8, 16 or 32 [default: 8].
    #[arg(long)]
    pub pgrid_tile: Option<u32>,
    /// Sorting tiles per side of a tracing tile (indirect mapping; paper section 3: 2): 1, 2 or 4
    /// [default: 2].
    #[arg(long)]
    pub pgrid_group: Option<u32>,
    /// Depth slices of the perspective grid [default: 32].
    #[arg(long)]
    pub slices: Option<u32>,
    /// Light tiles per side of a light grid, at most 256 [default: 64; fewer for small frames].
    #[arg(long)]
    pub light_tiles: Option<u32>,
    /// Depth slices of a light grid [default: 32].
    #[arg(long)]
    pub light_slices: Option<u32>,
    /// Most shadow rays per chunk, r (paper section 4.3, load balance): 16..=4096 [default: 256].
    #[arg(long)]
    pub chunk: Option<u32>,
}

impl PgridOpts {
    /// The parameters with triangle test `test`, checked.
    pub fn params(&self, test: sheaf::TriTest) -> Result<sheaf::PgridParams, sheaf::Error> {
        let d = sheaf::PgridParams::default();
        let p = sheaf::PgridParams {
            tile: self.pgrid_tile.unwrap_or(d.tile),
            group: self.pgrid_group.unwrap_or(d.group),
            slices: self.slices.unwrap_or(d.slices),
            light_tiles: self.light_tiles.unwrap_or(d.light_tiles),
            light_slices: self.light_slices.unwrap_or(d.light_slices),
            chunk: self.chunk.unwrap_or(d.chunk),
            test,
            ..d
        };
        p.validate()?;
        Ok(p)
    }
    /// Whether any knob was given.
    pub fn any(&self) -> bool {
        self.pgrid_tile.is_some()
            || self.pgrid_group.is_some()
            || self.slices.is_some()
            || self.light_tiles.is_some()
            || self.light_slices.is_some()
            || self.chunk.is_some()
    }
}

#[derive(Args)]
pub struct DemoArgs {
    /// Number of frames.
    #[arg(long, default_value_t = 8, value_parser = clap::value_parser!(u32).range(1..=100_000))]
    pub frames: u32,
    /// Image size, WIDTHxHEIGHT.
    #[arg(long, default_value = "640x480", value_parser = parse_size)]
    pub size: (u32, u32),
    /// Directory for frame_000.png, frame_001.png, ...
    #[arg(long, default_value = "out/grid-demo")]
    pub out_dir: PathBuf,
    /// Seconds of animation between frames. The animation loops every 12 s; the default 0.4 s
    /// shows smooth motion and never lands the four boxes (a quarter turn apart) on each other's places.
    #[arg(long, default_value_t = 0.4, allow_hyphen_values = true)]
    pub dt: f32,
    /// Rendering threads (default: available cores, at most 8).
    #[arg(long)]
    pub threads: Option<u32>,
    /// View of the animated scene (0 overview, 1 close-up, 2 inside, 3 grazing).
    #[arg(long, default_value_t = 0)]
    pub view: usize,
    #[command(flatten)]
    pub grid: GridOpts,
    #[command(flatten)]
    pub trace: TraceOpts,
}

#[derive(Args)]
pub struct RenderArgs {
    /// An OBJ file, or builtin:NAME (tetra, balls, gears, animated).
    pub scene: String,
    /// Output PNG.
    #[arg(long)]
    pub out: PathBuf,
    /// Image size, WIDTHxHEIGHT.
    #[arg(long, default_value = "800x600", value_parser = parse_size)]
    pub size: (u32, u32),
    /// Camera position x,y,z (default: framed from the scene bounds, or the builtin's view).
    #[arg(long, value_parser = parse_vec3, allow_hyphen_values = true)]
    pub eye: Option<[f32; 3]>,
    /// Point the camera looks at, x,y,z.
    #[arg(long, value_parser = parse_vec3, allow_hyphen_values = true)]
    pub look_at: Option<[f32; 3]>,
    /// Camera up vector x,y,z (default: +Y for OBJ files, the view's for builtins).
    #[arg(long, value_parser = parse_vec3, allow_hyphen_values = true)]
    pub up: Option<[f32; 3]>,
    /// Vertical field of view in degrees (default 45; 60 for the automatic inside view).
    #[arg(long)]
    pub fov: Option<f32>,
    /// Point light position x,y,z (default: above and behind the camera, or the builtin's light).
    #[arg(long, value_parser = parse_vec3, allow_hyphen_values = true)]
    pub light: Option<[f32; 3]>,
    /// View number: a builtin's views (0..), or for OBJ files 0 = outside, 1 = inside
    /// (default for OBJ files: inside when the scene encloses the inside view's eye, a room; else outside).
    #[arg(long)]
    pub view: Option<usize>,
    /// Rendering threads (default: available cores, at most 8).
    #[arg(long)]
    pub threads: Option<u32>,
    /// Lambert shading without shadow rays.
    #[arg(long)]
    pub no_shadows: bool,
    /// Whitted ray tracing: most mirror reflections on a path (with --refract: at most 8 in total).
    #[arg(long, default_value_t = 0)]
    pub reflect: u32,
    /// Whitted ray tracing: most refractions on a path.
    #[arg(long, default_value_t = 0)]
    pub refract: u32,
    /// Materials: the OBJ's .mtl (default), or every surface a mirror, glass, or both.
    #[arg(long, value_enum, default_value = "scene")]
    pub materials: MaterialsArg,
    /// Method for reflection and refraction rays (default: the primary method; bvh-partition
    /// when that is bvh-masked or bvh-ranged at 16x16 or more, as the BVH paper recommends;
    /// bvh-frustum's secondary packets are faster than Partition's, docs/studies/whitted.md).
    #[arg(long, value_enum)]
    pub secondary_method: Option<MethodArg>,
    /// Camera rays of a deferred frame: pgrid (a perspective grid built per frame) or a method
    /// name (as --method). With --primary or --shadows the frame is deferred (camera rays, then
    /// all shadow rays, then shading) and its phase times are printed (paper Figure 10).
    #[arg(long, value_parser = parse_primary, conflicts_with = "method")]
    pub primary: Option<PrimaryArg>,
    /// Shadow rays of a deferred frame: light-grid (a spherical light grid per light, rays sorted
    /// into light tiles and chunks) or a method name (as --shadow-method; packets take the
    /// primary pass's tile side).
    #[arg(long, value_parser = parse_shadows, conflicts_with = "shadow_method")]
    pub shadows: Option<ShadowsArg>,
    #[command(flatten)]
    pub pgrid: PgridOpts,
    #[command(flatten)]
    pub grid: GridOpts,
    #[command(flatten)]
    pub trace: TraceOpts,
}

/// Materials of a Whitted render.
#[derive(Clone, Copy, Debug, PartialEq, Eq, ValueEnum)]
pub enum MaterialsArg {
    /// The scene's own (OBJ .mtl: Kd, Ks with illum 3/5/7, Tr or d, Ni); built-ins are diffuse.
    Scene,
    /// Every surface reflects 60 %.
    Mirror,
    /// Every surface transmits 70 % (index 1.5).
    Glass,
    /// Every surface reflects 30 % and transmits 30 % (index 1.5).
    Mixed,
}

#[derive(Args)]
pub struct InfoArgs {
    /// An OBJ file, or builtin:NAME (tetra, balls, gears, animated).
    pub scene: String,
    /// Image size the perspective/light grid pools are shown for, WIDTHxHEIGHT.
    #[arg(long, default_value = "1024x1024", value_parser = parse_size)]
    pub size: (u32, u32),
    #[command(flatten)]
    pub grid: GridOpts,
}

#[derive(Args)]
pub struct BenchArgs {
    /// Scenes, comma-separated: tetra, balls, gears, animated (built in), legocar, bunny, sibenik,
    /// sponza, conference (OBJ files in --scenes-dir, skipped when absent), or paths of OBJ files
    /// [default: all; with --quick: tetra,gears,legocar].
    #[arg(long, value_delimiter = ',')]
    pub scenes: Vec<String>,
    /// Directory of the OBJ scenes [default: ../shared/scenes, else the one beside the source tree].
    #[arg(long)]
    pub scenes_dir: Option<PathBuf>,
    /// Image size, WIDTHxHEIGHT [default: 512x512; with --quick: 256x256; the CGT paper uses 1024x1024].
    #[arg(long, value_parser = parse_size)]
    pub size: Option<(u32, u32)>,
    /// A small subset for CI: three small scenes, 256x256, packets 4,8,16, one timed run each.
    #[arg(long)]
    pub quick: bool,
    /// CGT packet sides to run, comma-separated [default: 2,4,8,16,32; with --quick: 4,8,16].
    #[arg(long, value_delimiter = ',')]
    pub packets: Vec<u32>,
    /// Triangle tests, comma-separated (one grid build each).
    #[arg(
        long,
        value_enum,
        value_delimiter = ',',
        default_value = "mt,watertight"
    )]
    pub tests: Vec<TestArg>,
    /// Instead of the ray table: the Whitted study of the BVH traversals
    /// (BVH paper Figure 5, Table 2 and the culling benefit): frame times per
    /// traversal, packet side and ray recursion level, at 1024x1024 by
    /// default (256x256 with --quick).
    #[arg(long)]
    pub whitted: bool,
    /// Instead of the ray table: the entry-point study of the kd-tree (AEPSA paper
    /// section 5: Table 1, entry depths MLRTA vs AEPSA, search times, nodes visited,
    /// frames per second), 512x512 by default; with --quick the built-in scenes at 256x256.
    #[arg(long, conflicts_with = "whitted")]
    pub entry: bool,
    /// Instead of the ray table: the perspective/light grid study (its paper's section 5:
    /// Figure 10 phase times, Figure 11 shadow time vs light distance per chunk size, light-grid
    /// vs packet shadows and load balance, primary pass vs packets), 1024x1024 by default;
    /// written to docs/bench-pgrid.
    #[arg(long, conflicts_with_all = ["whitted", "entry"])]
    pub pgrid: bool,
    /// Instead of the ray table: stability where methods fail. Adversarial rays and scenes
    /// through every method, checked against the single-ray reference, with each packet
    /// method's slowdown against its structure's single-ray baseline; written to docs/bench-stress.
    #[arg(long, conflicts_with_all = ["whitted", "entry", "pgrid"])]
    pub stress: bool,
    /// Perspective/light grid parameters of `--pgrid` (the Figure 11 sweep varies --chunk).
    #[command(flatten)]
    pub pgrid_opts: PgridOpts,
    /// Structures whose methods are measured (grid, bvh, kd).
    #[arg(long, value_enum, value_delimiter = ',', default_value = "grid,bvh")]
    pub structures: Vec<StructureArg>,
    /// Thread counts to time, comma-separated [default: 1,2; with --entry: 1 and the machine's
    /// hardware threads; with --pgrid: the machine's hardware threads (the largest given is used)].
    #[arg(long, value_delimiter = ',')]
    pub threads: Vec<u32>,
    /// Also run CGT 8x8 with macrocells, mailbox, culling, and mailbox + culling switched off.
    #[arg(long)]
    pub ablation: bool,
    /// Timed runs per measurement (the median is reported) [default: 3; with --quick: 1].
    #[arg(long)]
    pub reps: Option<u32>,
    /// Most ray-triangle tests the f64 oracle may spend per scene (primary plus shadow rays):
    /// every k-th ray is checked, k chosen to fit [default: 2e9; with --quick: 2e8].
    #[arg(long)]
    pub oracle_budget: Option<f64>,
    /// Grid cells per triangle (CGT paper, section 3: 5).
    #[arg(long, default_value_t = 5.0)]
    pub lambda: f32,
    /// Macrocell side in cells (CGT paper, section 2.4: 6); 0 or 1 disables macrocells.
    #[arg(long, default_value_t = 6)]
    pub macrocell: u32,
    /// Directory for bench.csv, bench.md, speed_accuracy.svg and speed_accuracy.png (or the
    /// study's files) [default: out/bench; with --entry: docs/bench-kd; with --pgrid:
    /// docs/bench-pgrid].
    #[arg(long)]
    pub out_dir: Option<PathBuf>,
}

impl BenchArgs {
    /// `--out-dir`, or the default of the chosen study.
    pub fn out_dir(&self) -> PathBuf {
        match &self.out_dir {
            Some(d) => d.clone(),
            None if self.entry => PathBuf::from("docs/bench-kd"),
            None if self.pgrid => PathBuf::from("docs/bench-pgrid"),
            None if self.stress => PathBuf::from("docs/bench-stress"),
            None => PathBuf::from("out/bench"),
        }
    }
}

/// `WIDTHxHEIGHT`, each in 1..=16384.
fn parse_size(s: &str) -> Result<(u32, u32), String> {
    let (w, h) = s
        .split_once(['x', 'X'])
        .ok_or_else(|| format!("'{s}' is not WIDTHxHEIGHT (e.g. 800x600)"))?;
    let dim = |t: &str| -> Result<u32, String> {
        let v: u32 = t
            .trim()
            .parse()
            .map_err(|_| format!("'{t}' is not a whole number"))?;
        if (1..=16384).contains(&v) {
            Ok(v)
        } else {
            Err(format!("{v} is outside 1..=16384"))
        }
    };
    Ok((dim(w)?, dim(h)?))
}

/// `x,y,z`, three finite numbers.
fn parse_vec3(s: &str) -> Result<[f32; 3], String> {
    let parts: Vec<&str> = s.split(',').collect();
    if parts.len() != 3 {
        return Err(format!(
            "'{s}' is not x,y,z (three comma-separated numbers)"
        ));
    }
    let mut v = [0.0f32; 3];
    for (o, p) in v.iter_mut().zip(parts) {
        *o = p
            .trim()
            .parse()
            .map_err(|_| format!("'{p}' is not a number"))?;
        if !o.is_finite() {
            return Err(format!("'{p}' is not finite"));
        }
    }
    Ok(v)
}

fn main() -> ExitCode {
    let cli = Cli::parse();
    let res = match cli.cmd {
        Cmd::Demo(a) => cmd::engine::engine(&a),
        Cmd::GridDemo(a) => cmd::demo::demo(&a),
        Cmd::Render(a) => cmd::render::render(&a),
        Cmd::Info(a) => cmd::info::info(&a),
        Cmd::Bench(a) => studies::bench(&a),
        Cmd::Export(a) => cmd::export::export(&a),
    };
    match res {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            // `{:#}`: every context with its cause, `what: why`, on one line.
            eprintln!("error: {e:#}");
            ExitCode::FAILURE
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn sizes_and_vectors() {
        assert_eq!(parse_size("800x600"), Ok((800, 600)));
        assert!(parse_size("0x600").is_err());
        assert!(parse_size("800").is_err());
        assert!(parse_size("axb").is_err());
        assert_eq!(parse_vec3("1,-2.5, 3"), Ok([1.0, -2.5, 3.0]));
        assert!(parse_vec3("1,2").is_err());
        assert!(parse_vec3("1,2,nan").is_err());
        assert!(parse_vec3("1,2,x").is_err());
    }

    #[test]
    fn deferred_passes() {
        assert_eq!(parse_primary("pgrid"), Ok(PrimaryArg::Pgrid));
        assert_eq!(
            parse_primary("bvh-ranged"),
            Ok(PrimaryArg::Method(MethodArg::BvhRanged))
        );
        assert_eq!(parse_shadows("light-grid"), Ok(ShadowsArg::LightGrid));
        assert_eq!(
            parse_shadows("grid-cgt"),
            Ok(ShadowsArg::Method(MethodArg::GridCgt))
        );
        assert!(parse_primary("light-grid").is_err());
        assert!(parse_shadows("pgrid").is_err());
        let d = sheaf::PgridParams::default();
        let o = PgridOpts::default();
        assert!(!o.any());
        assert_eq!(o.params(d.test), Ok(d));
        let o = PgridOpts {
            chunk: Some(8),
            ..Default::default()
        };
        assert!(o.any() && o.params(d.test).is_err());
    }

    #[test]
    fn cli_definition_is_consistent() {
        use clap::CommandFactory;
        Cli::command().debug_assert();
    }
}
