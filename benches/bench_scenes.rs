//! Scenes, views and ray orders shared by the criterion benches (grid, bvh,
//! kd, pgrid, ffi): the built-in `animated` and `balls`, and bunny,
//! crytek_sponza and conference from `../shared/scenes` (skipped with a
//! message when absent), each with one fixed view and one point light.
#![allow(dead_code)]

use glam::Vec3;
use sheaf::scenes::{self, View};
use sheaf::{Hit, Limits, Ray, Scene};

/// Shared with the tests: OBJ loading (tobj) and the scenes folder.
#[path = "../tests/common/mod.rs"]
mod common;
use common::{load_obj, scenes_dir};

/// Image side of the traced view (rays per iteration: `SIDE * SIDE`).
pub const SIDE: u32 = 256;

/// A scene with its fixed view and light.
pub struct BenchScene {
    pub name: &'static str,
    pub vertices: Vec<f32>,
    pub indices: Vec<u32>,
    pub view: View,
    /// Point light of the shadow-ray benches: the built-in scene's own, or
    /// for OBJ scenes the tests' rule (`tests/common`): above and beside the
    /// centre of the bounds, inside them.
    pub light: Vec3,
}

impl BenchScene {
    pub fn scene(&self) -> Scene<'_> {
        Scene::from_f32(&self.vertices, &self.indices).expect("valid bench scene")
    }
    pub fn triangles(&self) -> u32 {
        (self.indices.len() / 3) as u32
    }

    /// Shadow rays for camera rays `rays` and their nearest hits `hits`, in
    /// the same order: from the light to the hit point moved
    /// `SHADOW_OFFSET` scene diagonals along the normal facing the camera
    /// ray, `tmax = 1` (the shadow rays of `render`, cast whether or not the
    /// surface faces the light). A camera ray that missed gets an empty ray
    /// (`tmax = 0`) from the light towards where the camera ray went, so the
    /// packets keep every lane and their shape.
    pub fn shadow_rays(&self, rays: &[Ray], hits: &[Hit]) -> Vec<Ray> {
        let (lo, hi) = bounds(&self.vertices);
        let diag = (hi - lo).length();
        let eps = sheaf::render::SHADOW_OFFSET * diag;
        let vertex = |i: u32| {
            let i = 3 * i as usize;
            Vec3::new(self.vertices[i], self.vertices[i + 1], self.vertices[i + 2])
        };
        rays.iter()
            .zip(hits)
            .map(|(r, h)| {
                let (org, dir) = (Vec3::from(r.org), Vec3::from(r.dir));
                if !h.is_hit() {
                    let far = org + dir.normalize_or_zero() * diag;
                    return Ray::new(self.light, far - self.light, 0.0, 0.0);
                }
                let t = &self.indices[3 * h.prim as usize..3 * h.prim as usize + 3];
                let (a, b, c) = (vertex(t[0]), vertex(t[1]), vertex(t[2]));
                let mut n = (b - a).cross(c - a).normalize_or_zero();
                if n.dot(dir) > 0.0 {
                    n = -n;
                }
                let end = org + dir * h.t + n * eps;
                Ray::new(self.light, end - self.light, 0.0, 1.0)
            })
            .collect()
    }
}

/// Bounds of packed xyz vertices.
fn bounds(v: &[f32]) -> (Vec3, Vec3) {
    v.chunks_exact(3).map(|p| Vec3::new(p[0], p[1], p[2])).fold(
        (Vec3::splat(f32::INFINITY), Vec3::splat(f32::NEG_INFINITY)),
        |(lo, hi), p| (lo.min(p), hi.max(p)),
    )
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

/// The built-in scene `name` (see `sheaf::scenes::BUILTIN_NAMES`) with its
/// first view and its light.
pub fn builtin(name: &str) -> BenchScene {
    let s = scenes::builtin(name).expect("builtin scene");
    BenchScene {
        name: s.name,
        vertices: s.mesh.vertices,
        indices: s.mesh.indices,
        view: s.views[0],
        light: s.light,
    }
}

pub fn bench_scenes() -> Vec<BenchScene> {
    let mut out = vec![builtin("animated"), builtin("balls")];
    if let Some(dir) = scenes_dir() {
        for (file, name, view) in obj_specs() {
            let path = dir.join(file);
            if !path.is_file() {
                eprintln!("note: {} not found: {name} skipped", path.display());
                continue;
            }
            if let Some((vertices, indices)) = load_obj(&path) {
                let (lo, hi) = bounds(&vertices);
                let light = 0.5 * (lo + hi) + Vec3::new(0.1, 0.45, 0.2) * (hi - lo);
                out.push(BenchScene {
                    name,
                    vertices,
                    indices,
                    view,
                    light,
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
    view.rays(SIDE, SIDE)
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
