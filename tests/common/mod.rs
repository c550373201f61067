//! Shared test (and bench) scaffolding: the built-in scenes and the OBJ
//! scenes of ../shared/scenes with fixed views, and primary rays for a view.
#![allow(dead_code)]

pub mod exact;
pub mod filter;
pub mod oracle;
pub mod ray_stream;

use glam::Vec3;
use sheaf::scenes::{self, View};
use std::path::PathBuf;

/// A scene under test: owned buffers plus named views.
pub struct TestScene {
    pub name: String,
    pub vertices: Vec<f32>,
    pub indices: Vec<u32>,
    pub views: Vec<(String, View)>,
    pub light: Vec3,
}

impl TestScene {
    pub fn scene(&self) -> sheaf::Scene<'_> {
        sheaf::Scene::from_f32(&self.vertices, &self.indices).expect("valid test scene")
    }
    pub fn triangles(&self) -> u32 {
        (self.indices.len() / 3) as u32
    }
}

/// ../shared/scenes, or None (with a message) when absent.
pub fn scenes_dir() -> Option<PathBuf> {
    let dir = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../shared/scenes");
    if dir.is_dir() {
        Some(dir)
    } else {
        eprintln!("note: {} not found: OBJ scenes skipped", dir.display());
        None
    }
}

/// Load an OBJ (all models merged) with tobj.
pub fn load_obj(path: &std::path::Path) -> Option<(Vec<f32>, Vec<u32>)> {
    let opts = tobj::LoadOptions {
        triangulate: true,
        single_index: false,
        ..Default::default()
    };
    let (models, _) = match tobj::load_obj(path, &opts) {
        Ok(x) => x,
        Err(e) => {
            eprintln!("note: cannot load {}: {e}: skipped", path.display());
            return None;
        }
    };
    let (mut v, mut ix) = (Vec::new(), Vec::new());
    for m in models {
        let base = (v.len() / 3) as u32;
        v.extend_from_slice(&m.mesh.positions);
        ix.extend(m.mesh.indices.iter().map(|i| i + base));
    }
    Some((v, ix))
}

fn bounds(v: &[f32]) -> (Vec3, Vec3) {
    let mut lo = Vec3::splat(f32::INFINITY);
    let mut hi = Vec3::splat(f32::NEG_INFINITY);
    for p in v.chunks_exact(3) {
        let p = Vec3::new(p[0], p[1], p[2]);
        lo = lo.min(p);
        hi = hi.max(p);
    }
    (lo, hi)
}

/// Views derived from the bounds of a y-up model: outside (framing the
/// bounding sphere), inside (from the centre towards a corner), grazing
/// (just above the floor, looking horizontally across it).
pub fn auto_views(v: &[f32]) -> Vec<(String, View)> {
    let (lo, hi) = bounds(v);
    let c = 0.5 * (lo + hi);
    let r = 0.5 * (hi - lo).length();
    let up = Vec3::Y;
    let dir = Vec3::new(0.6, 0.45, 1.0).normalize();
    let fov = 45.0f32;
    let dist = r / (fov.to_radians() * 0.5).sin();
    vec![
        (
            "outside".into(),
            View {
                eye: c + dir * dist,
                look_at: c,
                up,
                fov_y_deg: fov,
            },
        ),
        (
            "inside".into(),
            View {
                eye: c + Vec3::new(0.07, 0.03, -0.05) * (hi - lo),
                look_at: hi * 0.8 + lo * 0.2,
                up,
                fov_y_deg: 70.0,
            },
        ),
        (
            "grazing".into(),
            View {
                eye: Vec3::new(lo.x + 0.1 * (hi.x - lo.x), lo.y + 0.01 * (hi.y - lo.y), c.z),
                look_at: Vec3::new(
                    hi.x,
                    lo.y + 0.012 * (hi.y - lo.y),
                    c.z + 0.1 * (hi.z - lo.z),
                ),
                up,
                fov_y_deg: 50.0,
            },
        ),
    ]
}

/// The built-in scenes (no files).
pub fn builtin_scenes() -> Vec<TestScene> {
    scenes::BUILTIN_NAMES
        .iter()
        .map(|&name| {
            let s = scenes::builtin(name).expect("builtin exists");
            let views = s
                .views
                .iter()
                .enumerate()
                .map(|(i, v)| (format!("view{i}"), *v))
                .collect();
            TestScene {
                name: name.into(),
                vertices: s.mesh.vertices,
                indices: s.mesh.indices,
                views,
                light: s.light,
            }
        })
        .collect()
}

/// OBJ scenes present in ../shared/scenes (file name, scene name).
pub const OBJ_SCENES: &[(&str, &str)] = &[
    ("legocar/legocar.obj", "legocar"),
    ("bunny/bunny_tinybvh.obj", "bunny"),
    ("sibenik/sibenik.obj", "sibenik"),
    ("crytek_sponza/crytek_sponza.obj", "sponza"),
    ("conference/conference.obj", "conference"),
];

pub fn obj_scene(file: &str, name: &str) -> Option<TestScene> {
    let dir = scenes_dir()?;
    let (vertices, indices) = load_obj(&dir.join(file))?;
    let views = auto_views(&vertices);
    let (lo, hi) = bounds(&vertices);
    let light = 0.5 * (lo + hi) + Vec3::new(0.1, 0.45, 0.2) * (hi - lo);
    Some(TestScene {
        name: name.into(),
        vertices,
        indices,
        views,
        light,
    })
}

pub fn obj_scenes() -> Vec<TestScene> {
    OBJ_SCENES
        .iter()
        .filter_map(|(f, n)| obj_scene(f, n))
        .collect()
}

/// Run `f` over `items` on all cores, keeping order: each thread takes
/// the next item when it is done (items of very different cost, such as
/// scenes, then end together instead of one thread finishing its fixed
/// share alone).
pub fn par_map<T: Sync, R: Send>(items: &[T], f: impl Fn(&T) -> R + Sync) -> Vec<R> {
    use std::sync::atomic::{AtomicUsize, Ordering};
    let n = std::thread::available_parallelism()
        .map_or(1, |n| n.get())
        .clamp(1, items.len().max(1));
    let next = AtomicUsize::new(0);
    let mut done: Vec<(usize, R)> = std::thread::scope(|s| {
        let hs: Vec<_> = (0..n)
            .map(|_| {
                s.spawn(|| {
                    let mut out = Vec::new();
                    loop {
                        let i = next.fetch_add(1, Ordering::Relaxed);
                        let Some(item) = items.get(i) else { break out };
                        out.push((i, f(item)));
                    }
                })
            })
            .collect();
        hs.into_iter().flat_map(|h| h.join().unwrap()).collect()
    });
    done.sort_by_key(|(i, _)| *i);
    done.into_iter().map(|(_, r)| r).collect()
}
