//! `sheaf export`: a scene, a named view and its light as one binary file for C programs.
//!
//! The scene comes from the loaders `sheaf render` and `sheaf bench` use
//! (`builtin:NAME`, or an OBJ file with every model merged), the view and
//! the light are the ones `sheaf render` picks for the same arguments (a
//! builtin's view `--view N` and its light; for an OBJ file view 0 =
//! outside, 1 = inside, by default inside when the scene encloses the
//! inside view's eye, the light placed by `view::light_for`), and the
//! shadow-ray offset is the renderers' (`SHADOW_OFFSET` times the scene
//! scale of the built structure). `benches/embree` reads the file, so sheaf
//! and Embree trace the same triangles with the same camera.
//!
//! # File format (`SHEAFSC1`, version 1, every number little-endian)
//!
//! | bytes | type | field |
//! |--:|---|---|
//! | 8 | `char[8]` | magic `SHEAFSC1` |
//! | 4 | `u32` | version, 1 |
//! | 4 | `u32` | vertex count V |
//! | 4 | `u32` | triangle count T |
//! | 4 | `u32` | image width the view was framed for |
//! | 4 | `u32` | image height |
//! | 12 | `f32[3]` | camera eye |
//! | 12 | `f32[3]` | camera look-at point |
//! | 12 | `f32[3]` | camera up vector |
//! | 4 | `f32` | vertical field of view, degrees |
//! | 12 | `f32[3]` | point light position |
//! | 4 | `f32` | shadow offset eps (`SHADOW_OFFSET * scene scale`, see `PointLight::at`) |
//! | 4 | `u32` | triangles the structure excluded (non-finite or zero area) |
//! | 4 + n | `u32` n, `u8[n]` | scene label (UTF-8, no NUL) |
//! | 4 + n | `u32` n, `u8[n]` | view description (UTF-8, no NUL) |
//! | 12 V | `f32[3 V]` | vertices x, y, z, packed |
//! | 12 T | `u32[3 T]` | vertex indices of each triangle |
//! | 4 + 12 V F | `u32` F, `f32[3 V]` per frame | optional (`--frames F`, `builtin:animated` only): the vertices of F frames of the animation, 1/30 s apart from time 0 (frame 0 = the vertices above) |
//!
//! The header before the strings is 88 bytes. A shadow ray of a hit point
//! `p` with facing normal `n` goes from the light to `p + n * max(eps,
//! SHADOW_OFFSET_REL * |light - p|)` with `tmin = 0`, `tmax = 1`
//! (exclusive), as `PointLight::at` makes it.

use std::io::Write as _;
use std::path::PathBuf;

use clap::Args;
use glam::Vec3;
use sheaf::render::Tracer as _;

use crate::load;
use crate::run;
use crate::view::{self, INSIDE_FOV, OUTSIDE_FOV};
use anyhow::{Context as _, Result, anyhow, bail};

/// File magic and version of the export format.
pub const MAGIC: &[u8; 8] = b"SHEAFSC1";
pub const VERSION: u32 = 1;

#[derive(Args)]
pub struct ExportArgs {
    /// An OBJ file, or builtin:NAME.
    pub scene: String,
    /// Output file.
    #[arg(short, long)]
    pub out: PathBuf,
    /// View number: a builtin's views (0..), or for OBJ files 0 = outside, 1 = inside
    /// (default as `sheaf render`: a builtin's view 0; for OBJ files inside when the scene
    /// encloses the inside view's eye, else outside).
    #[arg(long)]
    pub view: Option<usize>,
    /// Image size the view is framed for, WIDTHxHEIGHT (the outside view of an OBJ file
    /// fits the scene to the aspect ratio).
    #[arg(long, default_value = "1024x1024", value_parser = crate::parse_size)]
    pub size: (u32, u32),
    /// Append the vertices of this many animation frames, 1/30 s apart (`builtin:animated`
    /// only): `benches/embree` times a per-frame rebuild and refit over them.
    #[arg(long, default_value_t = 0)]
    pub frames: u32,
}

/// Time between the frames `--frames` writes, seconds.
const FRAME_DT: f32 = 1.0 / 30.0;

/// `sheaf export`.
pub fn export(a: &ExportArgs) -> Result<()> {
    let (w, h) = a.size;
    let loaded = load::load(&a.scene)?;
    let scene = loaded.scene()?;
    if scene.triangle_count() == 0 {
        bail!("{}: no triangles", loaded.label);
    }
    // The grid `sheaf render` builds (one thread slot: only probes trace).
    let params = sheaf::GridParams::default();
    let (ctx, info) = run::context_for(&scene, run::limits(&scene, a.size, 1), &params, 1.0)?;
    if info.triangles == 0 {
        bail!(
            "{}: every triangle is degenerate or non-finite",
            loaded.label
        );
    }
    let tracer = ctx.tracer()?;
    let (lo, hi) = (info.bounds.min, info.bounds.max);
    let scale = (hi - lo).length();
    let (v, light, how) = match &loaded.builtin {
        Some((views, light)) => {
            let i = a.view.unwrap_or(0);
            let v = *views.get(i).ok_or_else(|| {
                anyhow!(
                    "--view {i}: {} has views 0..={}",
                    loaded.label,
                    views.len() - 1
                )
            })?;
            (v, *light, format!("builtin view {i}"))
        }
        None => {
            let inside = view::inside(&tracer, lo, hi, Vec3::Y, INSIDE_FOV);
            let interior = view::is_interior(&tracer, inside.eye);
            let i = a.view.unwrap_or(interior as usize);
            let v = match i {
                0 => view::outside(lo, hi, Vec3::Y, OUTSIDE_FOV, w as f32 / h as f32),
                1 => inside,
                _ => {
                    bail!("--view {i}: OBJ scenes have views 0 (outside) and 1 (inside)");
                }
            };
            let why = if a.view.is_some() {
                "chosen"
            } else if interior {
                "auto: the scene encloses it"
            } else {
                "auto"
            };
            let what = if i == 0 { "outside" } else { "inside" };
            // The light `sheaf render` places for this eye.
            let l = view::light_for(&tracer, &v, view::is_interior(&tracer, v.eye), scale);
            (v, Vec3::from(l.position), format!("{what} view ({why})"))
        }
    };
    let eps = sheaf::render::SHADOW_OFFSET * tracer.scene_scale();
    let excluded = info.excluded_non_finite + info.excluded_zero_area;

    let mut out: Vec<u8> =
        Vec::with_capacity(128 + 4 * (loaded.vertices.len() + loaded.indices.len()));
    out.extend_from_slice(MAGIC);
    let u = |out: &mut Vec<u8>, x: u32| out.extend_from_slice(&x.to_le_bytes());
    let f = |out: &mut Vec<u8>, x: f32| out.extend_from_slice(&x.to_le_bytes());
    u(&mut out, VERSION);
    u(&mut out, loaded.vertex_count());
    u(&mut out, (loaded.indices.len() / 3) as u32);
    u(&mut out, w);
    u(&mut out, h);
    for c in [v.eye, v.look_at, v.up] {
        for x in c.to_array() {
            f(&mut out, x);
        }
    }
    f(&mut out, v.fov_y_deg);
    for x in light.to_array() {
        f(&mut out, x);
    }
    f(&mut out, eps);
    u(&mut out, excluded);
    debug_assert_eq!(out.len(), 88);
    for s in [loaded.label.as_str(), how.as_str()] {
        u(&mut out, s.len() as u32);
        out.extend_from_slice(s.as_bytes());
    }
    for &x in &loaded.vertices {
        f(&mut out, x);
    }
    for &i in &loaded.indices {
        u(&mut out, i);
    }
    if a.frames > 0 {
        if a.scene != "builtin:animated" {
            bail!("--frames: only builtin:animated has an animation");
        }
        let mut anim = sheaf::scenes::animated::Animated::new(sheaf::scenes::ANIMATED_DETAIL);
        if anim.mesh.vertices != loaded.vertices {
            bail!("--frames: the animation's frame 0 is not the loaded scene");
        }
        u(&mut out, a.frames);
        for k in 0..a.frames {
            anim.set_time(k as f32 * FRAME_DT);
            for &x in &anim.mesh.vertices {
                f(&mut out, x);
            }
        }
    }
    if let Some(dir) = a.out.parent().filter(|d| !d.as_os_str().is_empty()) {
        std::fs::create_dir_all(dir).with_context(|| format!("cannot create {}", dir.display()))?;
    }
    std::fs::File::create(&a.out)
        .and_then(|mut file| file.write_all(&out))
        .with_context(|| format!("cannot write {}", a.out.display()))?;
    let v3 = |p: Vec3| format!("{},{},{}", p.x, p.y, p.z);
    println!(
        "{}: {} triangles ({excluded} excluded), {} vertices; {how}: eye ({}), look at ({}), up ({}), fov {}; light ({}); shadow eps {eps:e}; {} bytes to {}",
        loaded.label,
        loaded.indices.len() / 3,
        loaded.vertex_count(),
        v3(v.eye),
        v3(v.look_at),
        v3(v.up),
        v.fov_y_deg,
        v3(light),
        out.len(),
        a.out.display()
    );
    Ok(())
}
