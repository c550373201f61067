//! What the studies share, written once: the scenes they run (built-in,
//! stress and the OBJ scenes of ../shared/scenes) and each scene's view,
//! timing (medians of timed runs), the parallel f64 oracle, the machine and
//! command lines of their reports, CSV tables and charts (an embedded font,
//! SVG and PNG). They report through `Progress` (crate::progress).

use crate::load::{self, Loaded};
pub use crate::progress::Progress;
use crate::view::{self, INSIDE_FOV, OUTSIDE_FOV};
use crate::{BenchArgs, TestArg};
use anyhow::{Context as _, Result, anyhow, bail};
use glam::Vec3;
use plotters::coord::Shift;
use plotters::prelude::{BitMapBackend, DrawingArea, IntoDrawingArea, SVGBackend};
use plotters::style::FontStyle;
use rayon::prelude::*;
use sheaf::Ray;
use sheaf::context::SceneTracer as GridTracer;
use sheaf::geom::{Hit4, M4, Ray4};
use sheaf::render::demorton;
use std::fmt::Write as _;
use std::path::{Path, PathBuf};
use std::time::Instant;

/// A measurement stops repeating once its runs took this long (slow
/// configurations get fewer runs; their runs are long enough to be stable).
pub const MEASURE_NS: u64 = 300_000_000;

/// The OBJ scenes of ../shared/scenes: bench name and file.
pub const OBJ_SCENES: &[(&str, &str)] = &[
    ("legocar", "legocar/legocar.obj"),
    ("bunny", "bunny/bunny_tinybvh.obj"),
    ("sibenik", "sibenik/sibenik.obj"),
    ("sponza", "crytek_sponza/crytek_sponza.obj"),
    ("conference", "conference/conference.obj"),
];
/// `--quick` without `--scenes`.
pub const QUICK_SCENES: &[&str] = &["tetra", "gears", "legocar"];

/// The triangle test of a study that runs one (the first of `--tests`).
pub fn tri_test(a: &BenchArgs) -> sheaf::TriTest {
    a.tests
        .first()
        .map_or(sheaf::TriTest::MollerTrumbore, |t| t.tri_test())
}

/// `--threads` of the studies: each in 1..=64.
pub fn check_threads(threads: &[u32]) -> Result<()> {
    if threads.iter().any(|&t| !(1..=64).contains(&t)) {
        bail!("--threads: each must be in 1..=64");
    }
    Ok(())
}

/// `test` as its command-line name (`mt`, `watertight`, `projection`).
pub fn test_name(t: TestArg) -> String {
    use clap::ValueEnum as _;
    t.to_possible_value()
        .map_or_else(|| format!("{t:?}"), |v| v.get_name().to_string())
}

/// Median of `v` (0 when empty).
pub fn median(mut v: Vec<u64>) -> u64 {
    v.sort_unstable();
    v.get(v.len() / 2).copied().unwrap_or(0)
}

/// `a / b`, 0 when `b` is 0.
pub fn ratio(a: u64, b: u64) -> f64 {
    if b == 0 { 0.0 } else { a as f64 / b as f64 }
}

/// Time `f`: the median of up to `reps` runs, fewer once they took
/// `MEASURE_NS` together (at least one).
pub fn timed(reps: u32, mut f: impl FnMut()) -> u64 {
    let mut runs = Vec::new();
    let mut total = 0;
    while runs.len() < reps.max(1) as usize && (runs.is_empty() || total < MEASURE_NS) {
        let t = Instant::now();
        f();
        let ns = t.elapsed().as_nanos() as u64;
        runs.push(ns);
        total += ns;
    }
    median(runs)
}

/// Run `f` over `items` on every core (rayon's global pool), keeping order.
pub fn par_map<T: Sync, R: Send>(items: &[T], f: impl Fn(&T) -> R + Sync + Send) -> Vec<R> {
    items.par_iter().map(f).collect()
}

// ---------------------------------------------------------------------------
// Packed primary rays

/// Rows per band of the single-ray method (packet methods: whole tile rows
/// covering at least this many rows), as in `run::render_frame`.
pub const BAND_ROWS: usize = 8;

/// Pixel of a lane that is not in the image.
pub const NO_PIXEL: u32 = u32::MAX;

/// The image in n x n tiles of 2x2 quads (lane order of `Ray4`), quads in
/// Morton order within a tile, tiles row by row: the pixel of every lane.
pub struct Tiling {
    /// Quads per packet, `(n / 2)^2`.
    pub q: usize,
    /// Quads per band of whole tile rows.
    pub band: usize,
    /// Pixel (`y * w + x`) of lane `4 * quad + lane`, or `NO_PIXEL`.
    pub pix: Vec<u32>,
}

impl Tiling {
    pub fn new(w: u32, h: u32, n: u32) -> Tiling {
        let q = (n as usize / 2).pow(2);
        let (tiles_x, tiles_y) = (w.div_ceil(n), h.div_ceil(n));
        let band = BAND_ROWS.div_ceil(n as usize) * tiles_x as usize * q;
        let mut pix = Vec::with_capacity((tiles_x * tiles_y) as usize * q * 4);
        for ty in 0..tiles_y {
            for tx in 0..tiles_x {
                for k in 0..q {
                    let (qx, qy) = demorton(k);
                    for (dx, dy) in [(0, 0), (1, 0), (0, 1), (1, 1)] {
                        let (x, y) = (tx * n + 2 * qx + dx, ty * n + 2 * qy + dy);
                        pix.push(if x < w && y < h { y * w + x } else { NO_PIXEL });
                    }
                }
            }
        }
        Tiling { q, band, pix }
    }

    /// Pack per-pixel `rays` (lanes whose pixel is not `active` get `pad`,
    /// inactive) into quads and masks.
    pub fn pack(
        &self,
        rays: &[Ray],
        active: impl Fn(usize) -> bool,
        pad: Ray,
    ) -> (Vec<Ray4>, Vec<M4>) {
        self.pix
            .chunks_exact(4)
            .map(|p| {
                let p = [p[0], p[1], p[2], p[3]];
                let on = p.map(|i| i != NO_PIXEL && active(i as usize));
                let lanes = [0, 1, 2, 3].map(|k| if on[k] { rays[p[k] as usize] } else { pad });
                (Ray4::from_rays(&lanes), M4::new(on[0], on[1], on[2], on[3]))
            })
            .unzip()
    }

    /// Scatter packet results back to pixels.
    pub fn unpack<T: Copy>(&self, out: &mut [T], lanes: &[Hit4], f: impl Fn(&Hit4, usize) -> T) {
        for (k, &p) in self.pix.iter().enumerate() {
            if p != NO_PIXEL {
                out[p as usize] = f(&lanes[k / 4], k % 4);
            }
        }
    }
}

// ---------------------------------------------------------------------------
// Scenes

/// A scene to run: its bench name and what `load::load` takes.
pub struct SceneSpec {
    pub name: String,
    pub load: String,
}

pub fn scenes_dir(a: &BenchArgs) -> PathBuf {
    if let Some(d) = &a.scenes_dir {
        return d.clone();
    }
    let here = PathBuf::from("../shared/scenes");
    if here.is_dir() {
        return here;
    }
    // Beside the workspace (this crate is its cli/ folder).
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../../shared/scenes")
}

/// The scenes asked for (`--scenes`, else the quick set or the built-in
/// and OBJ scenes), absent OBJ files skipped with a message.
pub fn scene_specs(a: &BenchArgs) -> Result<Vec<SceneSpec>> {
    let names: Vec<String> = if !a.scenes.is_empty() {
        a.scenes.clone()
    } else if a.quick {
        QUICK_SCENES.iter().map(|s| s.to_string()).collect()
    } else {
        sheaf::scenes::BUILTIN_NAMES
            .iter()
            .chain(OBJ_SCENES.iter().map(|(n, _)| n))
            .map(|s| s.to_string())
            .collect()
    };
    specs_of(&names, &scenes_dir(a))
}

/// `names` as scenes to load: stress and built-in scene names, OBJ scene
/// names (in `dir`) and OBJ paths; absent OBJ files skipped with a message.
pub fn specs_of(names: &[String], dir: &Path) -> Result<Vec<SceneSpec>> {
    use sheaf_stress::STRESS_SCENE_NAMES;
    let mut out = Vec::new();
    for name in names.iter().map(|s| s.trim()).filter(|s| !s.is_empty()) {
        let name = name.to_string();
        let (label, path) = if STRESS_SCENE_NAMES.contains(&name.as_str()) {
            out.push(SceneSpec {
                load: format!("stress:{name}"),
                name,
            });
            continue;
        } else if sheaf::scenes::BUILTIN_NAMES.contains(&name.as_str()) {
            out.push(SceneSpec {
                load: format!("builtin:{name}"),
                name,
            });
            continue;
        } else if let Some((n, f)) = OBJ_SCENES
            .iter()
            .find(|(n, f)| *n == name || f.starts_with(&format!("{name}/")))
        {
            (n.to_string(), dir.join(f))
        } else if name.ends_with(".obj") {
            let p = PathBuf::from(&name);
            (
                p.file_stem()
                    .map_or(name.clone(), |s| s.to_string_lossy().into_owned()),
                p,
            )
        } else {
            let known: Vec<&str> = STRESS_SCENE_NAMES
                .iter()
                .chain(sheaf::scenes::BUILTIN_NAMES)
                .copied()
                .chain(OBJ_SCENES.iter().map(|(n, _)| *n))
                .collect();
            bail!(
                "--scenes: unknown scene '{name}' (known: {}, or a path ending in .obj)",
                known.join(", ")
            );
        };
        if path.is_file() {
            out.push(SceneSpec {
                name: label,
                load: path.to_string_lossy().into_owned(),
            });
        } else {
            println!("note: {label}: {} not found, skipped", path.display());
        }
    }
    Ok(out)
}

/// The scene's view and light: a builtin's first view and light, or for an
/// OBJ file what `sheaf render` picks by default (inside when the scene
/// encloses the inside view's eye, else outside; the light placed for it).
pub fn view_for(
    loaded: &Loaded,
    tr: &GridTracer<'_>,
    bounds: &sheaf::geom::Aabb,
    w: u32,
    h: u32,
) -> (sheaf::scenes::View, Vec3, String) {
    if let Some((views, light)) = &loaded.builtin {
        return (views[0], *light, "builtin view 0".into());
    }
    let (lo, hi) = (bounds.min, bounds.max);
    let inside = view::inside(tr, lo, hi, Vec3::Y, INSIDE_FOV);
    let interior = view::is_interior(tr, inside.eye);
    let v = if interior {
        inside
    } else {
        view::outside(lo, hi, Vec3::Y, OUTSIDE_FOV, w as f32 / h as f32)
    };
    let light = view::light_for(tr, &v, interior, (hi - lo).length());
    (
        v,
        Vec3::from(light.position),
        if interior {
            "inside (auto)"
        } else {
            "outside (auto)"
        }
        .into(),
    )
}

/// Load `spec`'s scene; None, with a note, when it cannot be loaded or has
/// no triangles.
pub fn load_or_skip(spec: &SceneSpec, prog: &Progress) -> Option<Loaded> {
    match load::load(&spec.load) {
        Ok(l) if !l.indices.is_empty() => Some(l),
        Ok(_) => {
            prog.say(format_args!("note: {}: no triangles, skipped", spec.name));
            None
        }
        Err(e) => {
            prog.say(format_args!("note: {}: {e:#}, skipped", spec.name));
            None
        }
    }
}

// ---------------------------------------------------------------------------
// Reports

/// Hardware threads, CPU model and load average (Linux), so a reader can
/// tell a busy machine's numbers.
pub fn machine_line() -> String {
    let cores = std::thread::available_parallelism().map_or(1, |n| n.get());
    let mut s = format!("{cores} hardware threads");
    let cpu = std::fs::read_to_string("/proc/cpuinfo").ok().and_then(|t| {
        t.lines()
            .find(|l| l.starts_with("model name"))
            .and_then(|l| l.split_once(':'))
            .map(|(_, v)| v.trim().to_string())
    });
    if let Some(c) = cpu {
        let _ = write!(s, " ({c})");
    }
    if let Some(l) = std::fs::read_to_string("/proc/loadavg")
        .ok()
        .map(|l| l.split_whitespace().take(3).collect::<Vec<_>>().join(" "))
    {
        let _ = write!(s, ", load average {l}");
    }
    s
}

/// The command line as typed (arguments with spaces quoted), for the reports.
pub fn command_line() -> String {
    std::env::args()
        .map(|a| {
            if a.contains(char::is_whitespace) || a.is_empty() {
                format!("'{a}'")
            } else {
                a
            }
        })
        .collect::<Vec<_>>()
        .join(" ")
}

/// Write a CSV table: `header`, then one record per row (fields formatted
/// by the caller, so every study keeps its number formats).
pub fn write_csv<I>(path: &Path, header: &[String], rows: I) -> Result<()>
where
    I: IntoIterator<Item = Vec<String>>,
{
    let write = || -> Result<()> {
        let mut w = csv::Writer::from_path(path)?;
        w.write_record(header)?;
        for r in rows {
            w.write_record(&r)?;
        }
        w.flush()?;
        Ok(())
    };
    write().with_context(|| format!("cannot write {}", path.display()))
}

/// Write `text` to `path`.
pub fn write_text(path: &Path, text: &str) -> Result<()> {
    std::fs::write(path, text).with_context(|| format!("cannot write {}", path.display()))
}

/// Create `dir` (and its parents).
pub fn create_dir(dir: &Path) -> Result<()> {
    std::fs::create_dir_all(dir).with_context(|| format!("cannot create {}", dir.display()))
}

// ---------------------------------------------------------------------------
// Charts

/// The charts' font family: DejaVu Sans, embedded (`register_font`).
pub const FONT: &str = "sans-serif";

/// Register the embedded DejaVu Sans as `FONT` (once).
pub fn register_font() -> Result<()> {
    static ONCE: std::sync::OnceLock<bool> = std::sync::OnceLock::new();
    let ok = *ONCE.get_or_init(|| {
        plotters::style::register_font(FONT, FontStyle::Normal, dejavu::sans::regular()).is_ok()
    });
    if ok {
        Ok(())
    } else {
        Err(anyhow!("chart: the embedded DejaVu Sans font did not load"))
    }
}

/// Draw a chart twice, with `draw_svg` into the SVG `svg` and with
/// `draw_png` into a pixel buffer saved as the PNG `png` (plotters'
/// backends are different types, hence two closures over the same drawing).
pub fn save_chart(
    size: (u32, u32),
    svg: &Path,
    png: &Path,
    draw_svg: impl FnOnce(DrawingArea<SVGBackend<'_>, Shift>) -> Result<()>,
    draw_png: impl FnOnce(DrawingArea<BitMapBackend<'_>, Shift>) -> Result<()>,
) -> Result<()> {
    register_font()?;
    draw_svg(SVGBackend::new(svg, size).into_drawing_area())
        .with_context(|| format!("chart {}", svg.display()))?;
    let mut buf = vec![0u8; size.0 as usize * size.1 as usize * 3];
    draw_png(BitMapBackend::with_buffer(&mut buf, size).into_drawing_area())
        .with_context(|| format!("chart {}", png.display()))?;
    image::save_buffer_with_format(
        png,
        &buf,
        size.0,
        size.1,
        image::ExtendedColorType::Rgb8,
        image::ImageFormat::Png,
    )
    .with_context(|| format!("cannot write {}", png.display()))
}
