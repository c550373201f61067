//! Built-in triangle scenes that need no files: for the demo, tests and benches.
//!
//! Three are Eric Haines' Standard Procedural Databases (SPD), tessellated to
//! triangles ([`spd`]): `tetra`, `balls` (sphereflake) and `gears`, built as
//! in erich666/StandardProceduralDatabases (`tetra.c`, `balls.c`, `gears.c`)
//! and Haines, "A Proposal for Standard Graphics Environments", IEEE CG&A
//! 7(11), 1987. The fourth, `animated` ([`animated`]), is ours: a deforming
//! blob and rigidly moving tori and boxes over a ground grid, so every frame
//! needs a full rebuild.
//!
//! All scenes keep SPD's convention: +Z is up. Each [`BuiltinScene`] carries
//! several [`View`]s: the SPD view, a close-up, one with the eye inside the
//! scene bounds and one grazing the ground (or, for tetra, the base face).
//!
//! # Deviations
//! - SPD spheres are curved primitives; here they are cube-projected meshes
//!   (see [`spd::balls`]), so balls' eye-ray hit counts only approximate the
//!   SPD Readme's reference numbers. Tetra and gears are polygonal in SPD and
//!   are triangulated exactly, so their reference counts should carry over.
//! - Only the first SPD light is kept ([`BuiltinScene::light`]).
#![forbid(unsafe_code)]

pub mod animated;
pub mod spd;

use glam::Vec3;

/// A camera view: pinhole at `eye` looking at `look_at`, `up` vector, vertical field of view in degrees.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct View {
    pub eye: Vec3,
    pub look_at: Vec3,
    pub up: Vec3,
    pub fov_y_deg: f32,
}

impl View {
    /// SPD's field of view (every SPD database uses 45 degrees).
    pub const SPD_FOV_Y_DEG: f32 = 45.0;

    /// A view with +Z up and SPD's 45 degree field of view.
    pub const fn z_up(eye: Vec3, look_at: Vec3) -> Self {
        Self {
            eye,
            look_at,
            up: Vec3::Z,
            fov_y_deg: Self::SPD_FOV_Y_DEG,
        }
    }

    /// The renderer's camera for this view.
    pub fn camera(&self) -> crate::render::Camera {
        crate::render::Camera {
            eye: self.eye.to_array(),
            look_at: self.look_at.to_array(),
            up: self.up.to_array(),
            fov_y_deg: self.fov_y_deg,
        }
    }

    /// The camera rays of a `w` x `h` image of this view, row by row.
    pub fn rays(&self, w: u32, h: u32) -> std::vec::Vec<crate::Ray> {
        let primary = crate::render::PrimaryRays::new(&self.camera(), w, h).expect("valid view");
        (0..h)
            .flat_map(|y| (0..w).map(move |x| (x, y)))
            .map(|(x, y)| primary.ray(x, y))
            .collect()
    }
}

/// Triangle mesh in the layout sheaf's scene input borrows: packed xyz f32 vertices (stride 12 bytes), u32 index triples.
#[derive(Clone, Debug, Default)]
pub struct Mesh {
    pub vertices: Vec<f32>,
    pub indices: Vec<u32>,
}

impl Mesh {
    /// An empty mesh with room for `vertices` vertices and `triangles` triangles.
    pub fn with_capacity(vertices: usize, triangles: usize) -> Self {
        Self {
            vertices: Vec::with_capacity(3 * vertices),
            indices: Vec::with_capacity(3 * triangles),
        }
    }

    pub fn triangle_count(&self) -> usize {
        self.indices.len() / 3
    }

    pub fn vertex_count(&self) -> usize {
        self.vertices.len() / 3
    }

    /// Axis-aligned bounds `(min, max)` of all vertices (referenced or not);
    /// `(Vec3::ZERO, Vec3::ZERO)` for a mesh without vertices.
    pub fn bounds(&self) -> (Vec3, Vec3) {
        if self.vertices.len() < 3 {
            return (Vec3::ZERO, Vec3::ZERO);
        }
        let mut lo = Vec3::INFINITY;
        let mut hi = Vec3::NEG_INFINITY;
        for p in self.vertices.chunks_exact(3) {
            let p = Vec3::from_slice(p);
            lo = lo.min(p);
            hi = hi.max(p);
        }
        (lo, hi)
    }

    /// Vertex `i`. Panics if out of range.
    pub fn vertex(&self, i: usize) -> Vec3 {
        Vec3::from_slice(&self.vertices[3 * i..3 * i + 3])
    }

    /// The three corners of triangle `t`. Panics if out of range.
    pub fn triangle(&self, t: usize) -> [Vec3; 3] {
        let i = &self.indices[3 * t..3 * t + 3];
        [
            self.vertex(i[0] as usize),
            self.vertex(i[1] as usize),
            self.vertex(i[2] as usize),
        ]
    }

    /// Appends a vertex and returns its index.
    pub fn push_vertex(&mut self, p: Vec3) -> u32 {
        let i = self.vertex_count() as u32;
        self.vertices.extend_from_slice(&p.to_array());
        i
    }

    pub fn push_triangle(&mut self, a: u32, b: u32, c: u32) {
        self.indices.extend_from_slice(&[a, b, c]);
    }

    /// Quad `a b c d` (in order around its boundary) as triangles `a b c`, `a c d`.
    pub fn push_quad(&mut self, a: u32, b: u32, c: u32, d: u32) {
        self.push_triangle(a, b, c);
        self.push_triangle(a, c, d);
    }

    /// Appends `other`, offsetting its indices past this mesh's vertices.
    pub fn append(&mut self, other: &Mesh) {
        let base = self.vertex_count() as u32;
        self.vertices.extend_from_slice(&other.vertices);
        self.indices.extend(other.indices.iter().map(|&i| i + base));
    }
}

/// A named mesh with its views and one point light.
#[derive(Clone, Debug)]
pub struct BuiltinScene {
    pub name: &'static str,
    pub mesh: Mesh,
    /// `views[0]` is the scene's reference view (SPD's for the SPD scenes);
    /// see each constructor for the order of the rest.
    pub views: Vec<View>,
    pub light: Vec3,
}

/// Names accepted by `builtin`: "tetra", "balls", "gears", "animated" (frame 0 of the animated scene).
pub const BUILTIN_NAMES: &[&str] = &["tetra", "balls", "gears", "animated"];

/// Default size factors. SPD's own defaults where they fit the 5k-60k
/// triangle budget (tetra 6, gears 4, so the Readme's hit counts apply);
/// balls drops from SPD's 4 to 3 because each sphere becomes triangles.
pub const TETRA_SF: u32 = 6;
pub const BALLS_SF: u32 = 3;
/// Cube-face subdivisions per sphere: 12 * 2^2 = 48 triangles per sphere.
pub const BALLS_SPHERE_RES: u32 = 2;
pub const GEARS_SF: u32 = 4;
pub const ANIMATED_DETAIL: u32 = 1;

/// The built-in scene called `name` (see [`BUILTIN_NAMES`]) at the default
/// size, or `None` for an unknown name.
pub fn builtin(name: &str) -> Option<BuiltinScene> {
    let scene = match name {
        "tetra" => BuiltinScene {
            name: "tetra",
            mesh: spd::tetra(TETRA_SF),
            views: spd::tetra_views(),
            light: spd::TETRA_LIGHT,
        },
        "balls" => BuiltinScene {
            name: "balls",
            mesh: spd::balls(BALLS_SF, BALLS_SPHERE_RES),
            views: spd::balls_views(),
            light: spd::BALLS_LIGHT,
        },
        "gears" => BuiltinScene {
            name: "gears",
            mesh: spd::gears(GEARS_SF),
            views: spd::gears_views(GEARS_SF),
            light: spd::GEARS_LIGHT,
        },
        "animated" => {
            let a = animated::Animated::new(ANIMATED_DETAIL);
            let (views, light) = (a.views(), a.light());
            BuiltinScene {
                name: "animated",
                mesh: a.mesh,
                views,
                light,
            }
        }
        _ => return None,
    };
    Some(scene)
}

/// Shared checks for the scene tests (and the stress scenes', in the
/// CLI's `sheaf-stress` crate).
#[doc(hidden)]
pub mod check {
    use super::{Mesh, View};
    use glam::Vec3;

    pub fn indices_in_range(m: &Mesh) {
        assert_eq!(m.indices.len() % 3, 0);
        assert_eq!(m.vertices.len() % 3, 0);
        let n = m.vertex_count() as u32;
        assert!(m.indices.iter().all(|&i| i < n), "index out of range");
    }

    pub fn finite(m: &Mesh) {
        assert!(
            m.vertices.iter().all(|v| v.is_finite()),
            "non-finite vertex"
        );
    }

    /// Exact cross product (in f32, from the stored vertices) is non-zero.
    pub fn no_zero_area(m: &Mesh) {
        for t in 0..m.triangle_count() {
            let [a, b, c] = m.triangle(t);
            let n = (b - a).cross(c - a);
            assert!(n.length() > 0.0, "zero-area triangle {t}: {a} {b} {c}");
        }
    }

    pub fn bounds_non_degenerate(m: &Mesh) {
        let (lo, hi) = m.bounds();
        assert!((hi - lo).min_element() > 0.0, "flat bounds {lo} {hi}");
    }

    pub fn inside(p: Vec3, (lo, hi): (Vec3, Vec3)) -> bool {
        p.cmpgt(lo).all() && p.cmplt(hi).all()
    }

    pub fn views_sane(views: &[View]) {
        assert!(views.len() >= 4);
        for v in views {
            let d = v.look_at - v.eye;
            assert!(v.eye != v.look_at);
            assert!(
                d.cross(v.up).length() > 1e-3 * d.length() * v.up.length(),
                "up parallel to view: {v:?}"
            );
            assert!(v.fov_y_deg > 0.0 && v.fov_y_deg < 180.0);
        }
    }

    pub fn mesh_sane(m: &Mesh) {
        assert!(m.triangle_count() > 0);
        indices_in_range(m);
        finite(m);
        no_zero_area(m);
        bounds_non_degenerate(m);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_builtin_is_sane() {
        for &name in BUILTIN_NAMES {
            let s = builtin(name).unwrap();
            assert_eq!(s.name, name);
            check::mesh_sane(&s.mesh);
            check::views_sane(&s.views);
            assert!(s.light.is_finite());
            let n = s.mesh.triangle_count();
            assert!((4_000..=60_000).contains(&n), "{name}: {n} triangles");
            // views[2] is the inside view in every scene.
            assert!(
                check::inside(s.views[2].eye, s.mesh.bounds()),
                "{name}: inside view is outside"
            );
        }
        assert!(builtin("nope").is_none());
    }

    #[test]
    fn mesh_helpers() {
        let mut m = Mesh::default();
        assert_eq!(m.bounds(), (Vec3::ZERO, Vec3::ZERO));
        let a = m.push_vertex(Vec3::new(0.0, 0.0, 0.0));
        let b = m.push_vertex(Vec3::new(1.0, 0.0, 0.0));
        let c = m.push_vertex(Vec3::new(1.0, 1.0, 2.0));
        let d = m.push_vertex(Vec3::new(0.0, 1.0, 0.0));
        m.push_quad(a, b, c, d);
        assert_eq!((m.vertex_count(), m.triangle_count()), (4, 2));
        assert_eq!(m.bounds(), (Vec3::ZERO, Vec3::new(1.0, 1.0, 2.0)));
        let copy = m.clone();
        m.append(&copy);
        assert_eq!(m.indices[6..9], [4, 5, 6]);
        assert_eq!(
            m.triangle(3),
            [Vec3::ZERO, Vec3::new(1.0, 1.0, 2.0), Vec3::Y]
        );
    }
}
