//! Scenes, views and ray orders shared by the criterion benches (grid, bvh):
//! the built-in `animated` and `balls`, and bunny, crytek_sponza and
//! conference from `../shared/scenes` (skipped with a message when absent),
//! each with one fixed view.
#![allow(dead_code)]

use glam::Vec3;
use sheaf::scenes::{self, View};
use sheaf::{Limits, Ray, Scene};

/// Shared with the tests: OBJ loading (tobj) and the scenes folder.
#[path = "../tests/common/mod.rs"]
mod common;
pub use common::view_rays;
use common::{load_obj, scenes_dir};

/// Image side of the traced view (rays per iteration: `SIDE * SIDE`).
pub const SIDE: u32 = 256;

/// A scene with its fixed view.
pub struct BenchScene {
    pub name: &'static str,
    pub vertices: Vec<f32>,
    pub indices: Vec<u32>,
    pub view: View,
}

impl BenchScene {
    pub fn scene(&self) -> Scene<'_> {
        Scene::from_f32(&self.vertices, &self.indices).expect("valid bench scene")
    }
    pub fn triangles(&self) -> u32 {
        (self.indices.len() / 3) as u32
    }
}

/// OBJ scenes: file under `../shared/scenes`, name, fixed view (+Y up).
/// bunny: outside, framing the bounding sphere from (0.6, 0.45, 1.0) like
/// `sheaf render`'s automatic view; sponza: down the atrium from its west
/// end under the first arch; conference: from a corner above the chairs
/// towards the table.
fn obj_specs() -> [(&'static str, &'static str, View); 3] {
    let y_up = |eye: [f32; 3], look_at: [f32; 3], fov_y_deg: f32| View {
        eye: Vec3::from(eye),
        look_at: Vec3::from(look_at),
        up: Vec3::Y,
        fov_y_deg,
    };
    [
        (
            "bunny/bunny_tinybvh.obj",
            "bunny",
            y_up([9.0, 11.42, 16.70], [-1.08, 3.86, -0.10], 45.0),
        ),
        (
            "crytek_sponza/crytek_sponza.obj",
            "sponza",
            y_up([-120.0, 20.0, -4.0], [100.0, 45.0, -4.0], 60.0),
        ),
        (
            "conference/conference.obj",
            "conference",
            y_up([-500.0, 400.0, 300.0], [333.0, 80.0, -194.0], 60.0),
        ),
    ]
}

pub fn bench_scenes() -> Vec<BenchScene> {
    let mut out = Vec::new();
    for name in ["animated", "balls"] {
        let s = scenes::builtin(name).expect("builtin scene");
        out.push(BenchScene {
            name: s.name,
            vertices: s.mesh.vertices,
            indices: s.mesh.indices,
            view: s.views[0],
        });
    }
    if let Some(dir) = scenes_dir() {
        for (file, name, view) in obj_specs() {
            let path = dir.join(file);
            if !path.is_file() {
                eprintln!("note: {} not found: {name} skipped", path.display());
                continue;
            }
            if let Some((vertices, indices)) = load_obj(&path) {
                out.push(BenchScene {
                    name,
                    vertices,
                    indices,
                    view,
                });
            }
        }
    }
    out
}

/// Limits for `s`, as an embedder would size them: `for_triangles(n)` with
/// the scene's vertex count, one thread.
pub fn limits(s: &BenchScene) -> Limits {
    let mut l = Limits::for_triangles(s.triangles());
    l.max_vertices = s.scene().vertex_count();
    l.max_threads = 1;
    l
}

pub fn primary_rays(view: &View) -> Vec<Ray> {
    view_rays(view, SIDE, SIDE)
}

/// Row-major rays reordered for `Context::trace_with`'s packet layout:
/// consecutive n x n tiles, each as 2x2 quads in row-major quad order.
pub fn packet_order(rays: &[Ray], side: usize, n: usize) -> Vec<Ray> {
    let mut out = Vec::with_capacity(rays.len());
    for ty in (0..side).step_by(n) {
        for tx in (0..side).step_by(n) {
            for qy in (ty..ty + n).step_by(2) {
                for qx in (tx..tx + n).step_by(2) {
                    for (dx, dy) in [(0, 0), (1, 0), (0, 1), (1, 1)] {
                        out.push(rays[(qy + dy) * side + qx + dx]);
                    }
                }
            }
        }
    }
    out
}
