//! Adversarial scenes and rays: where acceleration structures and packet
//! traversals fail, so that tests can check every method stays exact there
//! and `sheaf bench --stress` can measure how much slower it gets.
//!
//! Scenes ([`STRESS_SCENE_NAMES`], [`stress_scene`]), each a
//! [`BuiltinScene`] with four views (`views[0]` the main one, then a second
//! angle, one from inside the scene, one grazing a surface) and a light:
//! - `teapot-stadium`: the Newell teapot (its 32 bicubic Bezier patches as
//!   published with Haines' SPD `teapot.c`, Crow's bottom included,
//!   tessellated [`TEAPOT_SF`] x [`TEAPOT_SF`] quads per patch) on the field
//!   of a stadium of 432 triangles about 250 times its size. The field's
//!   centre vertex is the teapot's bottom cusp (both exactly the origin). A
//!   uniform grid sized for the whole stadium puts the teapot in a handful
//!   of cells ("the teapot in a stadium", Haines 1988).
//! - `huge-triangles`: a 6 x 6 x 6 lattice of small cubes (the grid's
//!   resolution follows them) cut by 24 triangles larger than the lattice
//!   (each crosses hundreds of cells, straddles every kd split and overlaps
//!   every BVH box): three axis-aligned squares (one coincident with cube
//!   faces, one through the middle of a cube layer), twelve random
//!   orientations through the centre, six parallel diagonal planes.
//! - `skinny-diagonal`: 1500 long needles (length 8 to 24, width 1e-1 down
//!   to 1e-6 of the length) along body and face diagonals, whose bounding
//!   boxes (what the grid inserts) are huge and nearly empty, over a floor
//!   and two walls.
//! - `coincident-degenerate`: a terrain whose every triangle appears four
//!   times (the same indices; rotated indices; copied vertices in reverse
//!   order), two planar panels each tessellated twice along different
//!   diagonals (coincident faces whose edges differ), shared edges
//!   everywhere, and degenerate triangles: repeated indices, distinct
//!   vertices at one point, exactly collinear vertices (zero area: skipped
//!   and counted by every build as `excluded_zero_area`), near-collinear
//!   slivers (non-zero area: traced) lying in a panel, and six triangles
//!   with a NaN or infinite vertex (`excluded_non_finite`). Its
//!   [`Mesh::bounds`] is therefore infinite; use [`finite_bounds`].
//! - `closed-box`: the inside faces of a subdivided box with five boxes
//!   inside (two coincident with a wall or the floor), every view inside:
//!   every ray from the camera hits something.
//!
//! Ray classes ([`RayClass`], [`stress_rays`]) are built for a scene and a
//! view. See [`stress_rays`] for the order of the rays (the order packet
//! methods consume them) and [`RayClass`] for what each class contains.
#![forbid(unsafe_code)]

use glam::{DVec3, Vec3};
use sheaf::geom::{Ray, Scene};
use sheaf::render::{Camera, PrimaryRays};
use sheaf::scenes::{BuiltinScene, Mesh, View};

/// The adversarial scenes, each a [`BuiltinScene`] (name, mesh, views
/// (`views[0]` the main one), light).
pub const STRESS_SCENE_NAMES: &[&str] = &[
    "teapot-stadium",
    "huge-triangles",
    "skinny-diagonal",
    "coincident-degenerate",
    "closed-box",
];

/// Quads per patch side of the stadium's teapot: 64 sf^2 - 8 sf = 3080
/// triangles (SPD drops the 8 sf degenerate ones at the lid and bottom cusps).
pub const TEAPOT_SF: u32 = 7;

/// The stress scene called `name` (see [`STRESS_SCENE_NAMES`]), or `None`.
pub fn stress_scene(name: &str) -> Option<BuiltinScene> {
    let s = match name {
        "teapot-stadium" => teapot_stadium(),
        "huge-triangles" => huge_triangles(),
        "skinny-diagonal" => skinny_diagonal(),
        "coincident-degenerate" => coincident_degenerate(),
        "closed-box" => closed_box(),
        _ => return None,
    };
    Some(s)
}

/// Bounds `(min, max)` of the finite vertices (`(0, 0)` if there is none):
/// [`Mesh::bounds`] with NaN and infinite vertices left out.
pub fn finite_bounds(m: &Mesh) -> (Vec3, Vec3) {
    let mut lo = Vec3::INFINITY;
    let mut hi = Vec3::NEG_INFINITY;
    for p in m.vertices.chunks_exact(3) {
        let p = Vec3::from_slice(p);
        if p.is_finite() {
            lo = lo.min(p);
            hi = hi.max(p);
        }
    }
    if lo.x > hi.x {
        return (Vec3::ZERO, Vec3::ZERO);
    }
    (lo, hi)
}

// ---------------------------------------------------------------- random

/// SplitMix64 (Steele, Lea, Flood 2014): small, seedable, good enough.
struct Rng(u64);

impl Rng {
    fn new(seed: u64) -> Rng {
        Rng(seed ^ 0x5851_f42d_4c95_7f2d)
    }
    fn next(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9e37_79b9_7f4a_7c15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
        z ^ (z >> 31)
    }
    /// Uniform in `[0, n)` (`n > 0`).
    fn below(&mut self, n: usize) -> usize {
        (self.next() % n as u64) as usize
    }
    /// Uniform in `[0, 1)`.
    fn unit(&mut self) -> f64 {
        (self.next() >> 11) as f64 / (1u64 << 53) as f64
    }
    fn range(&mut self, lo: f64, hi: f64) -> f64 {
        lo + (hi - lo) * self.unit()
    }
    /// Uniform on the unit sphere.
    fn sphere(&mut self) -> DVec3 {
        let z = self.range(-1.0, 1.0);
        let a = self.range(0.0, std::f64::consts::TAU);
        let r = (1.0 - z * z).max(0.0).sqrt();
        DVec3::new(r * a.cos(), r * a.sin(), z)
    }
    /// Uniform in the box `[lo, hi]`.
    fn in_box(&mut self, lo: Vec3, hi: Vec3) -> Vec3 {
        let t = Vec3::new(self.unit() as f32, self.unit() as f32, self.unit() as f32);
        lo + (hi - lo) * t
    }
}

// ---------------------------------------------------------------- teapot
/// Control-point indices of the 32 bicubic patches (rim 4, body 8, handle 4,
/// spout 4, lid 8, Crow's bottom 4), row by row, as published in SPD's
/// `teapot.c` (Crow, IEEE CG&A 7(1), 1987, with the bottom).
const TEAPOT_PATCHES: [[u16; 16]; 32] = [
    // rim
    [0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11, 12, 13, 14, 15],
    [3, 16, 17, 18, 7, 19, 20, 21, 11, 22, 23, 24, 15, 25, 26, 27],
    [
        18, 28, 29, 30, 21, 31, 32, 33, 24, 34, 35, 36, 27, 37, 38, 39,
    ],
    [30, 40, 41, 0, 33, 42, 43, 4, 36, 44, 45, 8, 39, 46, 47, 12],
    // body
    [
        12, 13, 14, 15, 48, 49, 50, 51, 52, 53, 54, 55, 56, 57, 58, 59,
    ],
    [
        15, 25, 26, 27, 51, 60, 61, 62, 55, 63, 64, 65, 59, 66, 67, 68,
    ],
    [
        27, 37, 38, 39, 62, 69, 70, 71, 65, 72, 73, 74, 68, 75, 76, 77,
    ],
    [
        39, 46, 47, 12, 71, 78, 79, 48, 74, 80, 81, 52, 77, 82, 83, 56,
    ],
    [
        56, 57, 58, 59, 84, 85, 86, 87, 88, 89, 90, 91, 92, 93, 94, 95,
    ],
    [
        59, 66, 67, 68, 87, 96, 97, 98, 91, 99, 100, 101, 95, 102, 103, 104,
    ],
    [
        68, 75, 76, 77, 98, 105, 106, 107, 101, 108, 109, 110, 104, 111, 112, 113,
    ],
    [
        77, 82, 83, 56, 107, 114, 115, 84, 110, 116, 117, 88, 113, 118, 119, 92,
    ],
    // handle
    [
        120, 121, 122, 123, 124, 125, 126, 127, 128, 129, 130, 131, 132, 133, 134, 135,
    ],
    [
        123, 136, 137, 120, 127, 138, 139, 124, 131, 140, 141, 128, 135, 142, 143, 132,
    ],
    [
        132, 133, 134, 135, 144, 145, 146, 147, 148, 149, 150, 151, 68, 152, 153, 154,
    ],
    [
        135, 142, 143, 132, 147, 155, 156, 144, 151, 157, 158, 148, 154, 159, 160, 68,
    ],
    // spout
    [
        161, 162, 163, 164, 165, 166, 167, 168, 169, 170, 171, 172, 173, 174, 175, 176,
    ],
    [
        164, 177, 178, 161, 168, 179, 180, 165, 172, 181, 182, 169, 176, 183, 184, 173,
    ],
    [
        173, 174, 175, 176, 185, 186, 187, 188, 189, 190, 191, 192, 193, 194, 195, 196,
    ],
    [
        176, 183, 184, 173, 188, 197, 198, 185, 192, 199, 200, 189, 196, 201, 202, 193,
    ],
    // lid
    [
        203, 203, 203, 203, 204, 205, 206, 207, 208, 208, 208, 208, 209, 210, 211, 212,
    ],
    [
        203, 203, 203, 203, 207, 213, 214, 215, 208, 208, 208, 208, 212, 216, 217, 218,
    ],
    [
        203, 203, 203, 203, 215, 219, 220, 221, 208, 208, 208, 208, 218, 222, 223, 224,
    ],
    [
        203, 203, 203, 203, 221, 225, 226, 204, 208, 208, 208, 208, 224, 227, 228, 209,
    ],
    [
        209, 210, 211, 212, 229, 230, 231, 232, 233, 234, 235, 236, 237, 238, 239, 240,
    ],
    [
        212, 216, 217, 218, 232, 241, 242, 243, 236, 244, 245, 246, 240, 247, 248, 249,
    ],
    [
        218, 222, 223, 224, 243, 250, 251, 252, 246, 253, 254, 255, 249, 256, 257, 258,
    ],
    [
        224, 227, 228, 209, 252, 259, 260, 229, 255, 261, 262, 233, 258, 263, 264, 237,
    ],
    // bottom
    [
        265, 265, 265, 265, 266, 267, 268, 269, 270, 271, 272, 273, 92, 119, 118, 113,
    ],
    [
        265, 265, 265, 265, 269, 274, 275, 276, 273, 277, 278, 279, 113, 112, 111, 104,
    ],
    [
        265, 265, 265, 265, 276, 280, 281, 282, 279, 283, 284, 285, 104, 103, 102, 95,
    ],
    [
        265, 265, 265, 265, 282, 286, 287, 266, 285, 288, 289, 270, 95, 94, 93, 92,
    ],
];

/// The 290 control points (x, y, z; +Z up, the teapot standing on z = 0).
#[rustfmt::skip]
const TEAPOT_POINTS: [[f64; 3]; 290] = [
    // 0..48: rim
    [1.4, 0.0, 2.4], [1.4, -0.784, 2.4], [0.784, -1.4, 2.4], [0.0, -1.4, 2.4],
    [1.3375, 0.0, 2.53125], [1.3375, -0.749, 2.53125], [0.749, -1.3375, 2.53125], [0.0, -1.3375, 2.53125],
    [1.4375, 0.0, 2.53125], [1.4375, -0.805, 2.53125], [0.805, -1.4375, 2.53125], [0.0, -1.4375, 2.53125],
    [1.5, 0.0, 2.4], [1.5, -0.84, 2.4], [0.84, -1.5, 2.4], [0.0, -1.5, 2.4],
    [-0.784, -1.4, 2.4], [-1.4, -0.784, 2.4], [-1.4, 0.0, 2.4],
    [-0.749, -1.3375, 2.53125], [-1.3375, -0.749, 2.53125], [-1.3375, 0.0, 2.53125],
    [-0.805, -1.4375, 2.53125], [-1.4375, -0.805, 2.53125], [-1.4375, 0.0, 2.53125],
    [-0.84, -1.5, 2.4], [-1.5, -0.84, 2.4], [-1.5, 0.0, 2.4],
    [-1.4, 0.784, 2.4], [-0.784, 1.4, 2.4], [0.0, 1.4, 2.4],
    [-1.3375, 0.749, 2.53125], [-0.749, 1.3375, 2.53125], [0.0, 1.3375, 2.53125],
    [-1.4375, 0.805, 2.53125], [-0.805, 1.4375, 2.53125], [0.0, 1.4375, 2.53125],
    [-1.5, 0.84, 2.4], [-0.84, 1.5, 2.4], [0.0, 1.5, 2.4],
    [0.784, 1.4, 2.4], [1.4, 0.784, 2.4],
    [0.749, 1.3375, 2.53125], [1.3375, 0.749, 2.53125],
    [0.805, 1.4375, 2.53125], [1.4375, 0.805, 2.53125],
    [0.84, 1.5, 2.4], [1.5, 0.84, 2.4],
    // 48..120: body
    [1.75, 0.0, 1.875], [1.75, -0.98, 1.875], [0.98, -1.75, 1.875], [0.0, -1.75, 1.875],
    [2.0, 0.0, 1.35], [2.0, -1.12, 1.35], [1.12, -2.0, 1.35], [0.0, -2.0, 1.35],
    [2.0, 0.0, 0.9], [2.0, -1.12, 0.9], [1.12, -2.0, 0.9], [0.0, -2.0, 0.9],
    [-0.98, -1.75, 1.875], [-1.75, -0.98, 1.875], [-1.75, 0.0, 1.875],
    [-1.12, -2.0, 1.35], [-2.0, -1.12, 1.35], [-2.0, 0.0, 1.35],
    [-1.12, -2.0, 0.9], [-2.0, -1.12, 0.9], [-2.0, 0.0, 0.9],
    [-1.75, 0.98, 1.875], [-0.98, 1.75, 1.875], [0.0, 1.75, 1.875],
    [-2.0, 1.12, 1.35], [-1.12, 2.0, 1.35], [0.0, 2.0, 1.35],
    [-2.0, 1.12, 0.9], [-1.12, 2.0, 0.9], [0.0, 2.0, 0.9],
    [0.98, 1.75, 1.875], [1.75, 0.98, 1.875],
    [1.12, 2.0, 1.35], [2.0, 1.12, 1.35],
    [1.12, 2.0, 0.9], [2.0, 1.12, 0.9],
    [2.0, 0.0, 0.45], [2.0, -1.12, 0.45], [1.12, -2.0, 0.45], [0.0, -2.0, 0.45],
    [1.5, 0.0, 0.225], [1.5, -0.84, 0.225], [0.84, -1.5, 0.225], [0.0, -1.5, 0.225],
    [1.5, 0.0, 0.15], [1.5, -0.84, 0.15], [0.84, -1.5, 0.15], [0.0, -1.5, 0.15],
    [-1.12, -2.0, 0.45], [-2.0, -1.12, 0.45], [-2.0, 0.0, 0.45],
    [-0.84, -1.5, 0.225], [-1.5, -0.84, 0.225], [-1.5, 0.0, 0.225],
    [-0.84, -1.5, 0.15], [-1.5, -0.84, 0.15], [-1.5, 0.0, 0.15],
    [-2.0, 1.12, 0.45], [-1.12, 2.0, 0.45], [0.0, 2.0, 0.45],
    [-1.5, 0.84, 0.225], [-0.84, 1.5, 0.225], [0.0, 1.5, 0.225],
    [-1.5, 0.84, 0.15], [-0.84, 1.5, 0.15], [0.0, 1.5, 0.15],
    [1.12, 2.0, 0.45], [2.0, 1.12, 0.45],
    [0.84, 1.5, 0.225], [1.5, 0.84, 0.225],
    [0.84, 1.5, 0.15], [1.5, 0.84, 0.15],
    // 120..161: handle
    [-1.6, 0.0, 2.025], [-1.6, -0.3, 2.025], [-1.5, -0.3, 2.25], [-1.5, 0.0, 2.25],
    [-2.3, 0.0, 2.025], [-2.3, -0.3, 2.025], [-2.5, -0.3, 2.25], [-2.5, 0.0, 2.25],
    [-2.7, 0.0, 2.025], [-2.7, -0.3, 2.025], [-3.0, -0.3, 2.25], [-3.0, 0.0, 2.25],
    [-2.7, 0.0, 1.8], [-2.7, -0.3, 1.8], [-3.0, -0.3, 1.8], [-3.0, 0.0, 1.8],
    [-1.5, 0.3, 2.25], [-1.6, 0.3, 2.025],
    [-2.5, 0.3, 2.25], [-2.3, 0.3, 2.025],
    [-3.0, 0.3, 2.25], [-2.7, 0.3, 2.025],
    [-3.0, 0.3, 1.8], [-2.7, 0.3, 1.8],
    [-2.7, 0.0, 1.575], [-2.7, -0.3, 1.575], [-3.0, -0.3, 1.35], [-3.0, 0.0, 1.35],
    [-2.5, 0.0, 1.125], [-2.5, -0.3, 1.125], [-2.65, -0.3, 0.9375], [-2.65, 0.0, 0.9375],
    [-2.0, -0.3, 0.9], [-1.9, -0.3, 0.6], [-1.9, 0.0, 0.6],
    [-3.0, 0.3, 1.35], [-2.7, 0.3, 1.575],
    [-2.65, 0.3, 0.9375], [-2.5, 0.3, 1.125],
    [-1.9, 0.3, 0.6], [-2.0, 0.3, 0.9],
    // 161..203: spout
    [1.7, 0.0, 1.425], [1.7, -0.66, 1.425], [1.7, -0.66, 0.6], [1.7, 0.0, 0.6],
    [2.6, 0.0, 1.425], [2.6, -0.66, 1.425], [3.1, -0.66, 0.825], [3.1, 0.0, 0.825],
    [2.3, 0.0, 2.1], [2.3, -0.25, 2.1], [2.4, -0.25, 2.025], [2.4, 0.0, 2.025],
    [2.7, 0.0, 2.4], [2.7, -0.25, 2.4], [3.3, -0.25, 2.4], [3.3, 0.0, 2.4],
    [1.7, 0.66, 0.6], [1.7, 0.66, 1.425],
    [3.1, 0.66, 0.825], [2.6, 0.66, 1.425],
    [2.4, 0.25, 2.025], [2.3, 0.25, 2.1],
    [3.3, 0.25, 2.4], [2.7, 0.25, 2.4],
    [2.8, 0.0, 2.475], [2.8, -0.25, 2.475], [3.525, -0.25, 2.49375], [3.525, 0.0, 2.49375],
    [2.9, 0.0, 2.475], [2.9, -0.15, 2.475], [3.45, -0.15, 2.5125], [3.45, 0.0, 2.5125],
    [2.8, 0.0, 2.4], [2.8, -0.15, 2.4], [3.2, -0.15, 2.4], [3.2, 0.0, 2.4],
    [3.525, 0.25, 2.49375], [2.8, 0.25, 2.475],
    [3.45, 0.15, 2.5125], [2.9, 0.15, 2.475],
    [3.2, 0.15, 2.4], [2.8, 0.15, 2.4],
    // 203..265: lid
    [0.0, 0.0, 3.15], [0.8, 0.0, 3.15], [0.8, -0.45, 3.15], [0.45, -0.8, 3.15], [0.0, -0.8, 3.15],
    [0.0, 0.0, 2.85],
    [0.2, 0.0, 2.7], [0.2, -0.112, 2.7], [0.112, -0.2, 2.7], [0.0, -0.2, 2.7],
    [-0.45, -0.8, 3.15], [-0.8, -0.45, 3.15], [-0.8, 0.0, 3.15],
    [-0.112, -0.2, 2.7], [-0.2, -0.112, 2.7], [-0.2, 0.0, 2.7],
    [-0.8, 0.45, 3.15], [-0.45, 0.8, 3.15], [0.0, 0.8, 3.15],
    [-0.2, 0.112, 2.7], [-0.112, 0.2, 2.7], [0.0, 0.2, 2.7],
    [0.45, 0.8, 3.15], [0.8, 0.45, 3.15],
    [0.112, 0.2, 2.7], [0.2, 0.112, 2.7],
    [0.4, 0.0, 2.55], [0.4, -0.224, 2.55], [0.224, -0.4, 2.55], [0.0, -0.4, 2.55],
    [1.3, 0.0, 2.55], [1.3, -0.728, 2.55], [0.728, -1.3, 2.55], [0.0, -1.3, 2.55],
    [1.3, 0.0, 2.4], [1.3, -0.728, 2.4], [0.728, -1.3, 2.4], [0.0, -1.3, 2.4],
    [-0.224, -0.4, 2.55], [-0.4, -0.224, 2.55], [-0.4, 0.0, 2.55],
    [-0.728, -1.3, 2.55], [-1.3, -0.728, 2.55], [-1.3, 0.0, 2.55],
    [-0.728, -1.3, 2.4], [-1.3, -0.728, 2.4], [-1.3, 0.0, 2.4],
    [-0.4, 0.224, 2.55], [-0.224, 0.4, 2.55], [0.0, 0.4, 2.55],
    [-1.3, 0.728, 2.55], [-0.728, 1.3, 2.55], [0.0, 1.3, 2.55],
    [-1.3, 0.728, 2.4], [-0.728, 1.3, 2.4], [0.0, 1.3, 2.4],
    [0.224, 0.4, 2.55], [0.4, 0.224, 2.55],
    [0.728, 1.3, 2.55], [1.3, 0.728, 2.55],
    [0.728, 1.3, 2.4], [1.3, 0.728, 2.4],
    // 265..290: bottom
    [0.0, 0.0, 0.0],
    [1.425, 0.0, 0.0], [1.425, 0.798, 0.0], [0.798, 1.425, 0.0], [0.0, 1.425, 0.0],
    [1.5, 0.0, 0.075], [1.5, 0.84, 0.075], [0.84, 1.5, 0.075], [0.0, 1.5, 0.075],
    [-0.798, 1.425, 0.0], [-1.425, 0.798, 0.0], [-1.425, 0.0, 0.0],
    [-0.84, 1.5, 0.075], [-1.5, 0.84, 0.075], [-1.5, 0.0, 0.075],
    [-1.425, -0.798, 0.0], [-0.798, -1.425, 0.0], [0.0, -1.425, 0.0],
    [-1.5, -0.84, 0.075], [-0.84, -1.5, 0.075], [0.0, -1.5, 0.075],
    [0.798, -1.425, 0.0], [1.425, -0.798, 0.0],
    [0.84, -1.5, 0.075], [1.5, -0.84, 0.075],
];

fn bernstein(t: f64) -> [f64; 4] {
    let s = 1.0 - t;
    [s * s * s, 3.0 * t * s * s, 3.0 * t * t * s, t * t * t]
}

/// The Newell teapot (SPD `teapot.c`): each of the 32 patches evaluated in
/// f64 on an `(sf + 1)^2` lattice (row parameter s, column parameter t as in
/// SPD) and split into `2 sf^2` triangles, corners (s, t), (s, t+1),
/// (s+1, t+1) and (s+1, t+1), (s+1, t), (s, t). Triangles with two corners
/// on the Z axis (the lid and bottom cusps) are dropped as SPD does, leaving
/// `64 sf^2 - 8 sf` triangles (`sf >= 2`). Vertices are shared inside a
/// patch, not across patches. Must be traced double-sided.
pub fn teapot(sf: u32) -> Mesh {
    let sf = sf.max(2);
    let n = sf as usize + 1;
    let mut m = Mesh::with_capacity(32 * n * n, 64 * (sf * sf) as usize);
    for patch in &TEAPOT_PATCHES {
        let base = m.vertex_count() as u32;
        let mut on_axis = Vec::with_capacity(n * n);
        for i in 0..n {
            let bs = bernstein(i as f64 / sf as f64);
            for j in 0..n {
                let bt = bernstein(j as f64 / sf as f64);
                let mut p = DVec3::ZERO;
                for r in 0..4 {
                    for c in 0..4 {
                        let cp = TEAPOT_POINTS[patch[4 * r + c] as usize];
                        p += DVec3::from_array(cp) * (bs[r] * bt[c]);
                    }
                }
                on_axis.push(p.x.abs() < 1e-4 && p.y.abs() < 1e-4);
                m.push_vertex(p.as_vec3());
            }
        }
        let id = |i: usize, j: usize| i * n + j;
        for i in 0..sf as usize {
            for j in 0..sf as usize {
                let corners = [id(i, j), id(i, j + 1), id(i + 1, j + 1), id(i + 1, j)];
                for tri in [[0, 1, 2], [2, 3, 0]] {
                    let v = tri.map(|k| corners[k]);
                    if v.iter().filter(|&&k| on_axis[k]).count() > 1 {
                        continue;
                    }
                    m.push_triangle(base + v[0] as u32, base + v[1] as u32, base + v[2] as u32);
                }
            }
        }
    }
    m
}

/// A stadium around the origin: a field (a fan of 48 triangles from the
/// origin, radius 800 along x, 560 along y) and four tiers of stands rising
/// to radius 1400 (980) and height 540, 48 segments each: 432 triangles.
fn stadium(m: &mut Mesh) {
    const SEG: u32 = 48;
    const RINGS: [(f32, f32); 5] = [
        (800.0, 0.0),
        (950.0, 120.0),
        (1100.0, 250.0),
        (1250.0, 390.0),
        (1400.0, 540.0),
    ];
    let centre = m.push_vertex(Vec3::ZERO);
    let first = m.vertex_count() as u32;
    for &(r, z) in &RINGS {
        for s in 0..SEG {
            let a = std::f32::consts::TAU * s as f32 / SEG as f32;
            m.push_vertex(Vec3::new(r * a.cos(), 0.7 * r * a.sin(), z));
        }
    }
    let at = |ring: u32, s: u32| first + ring * SEG + s % SEG;
    for s in 0..SEG {
        m.push_triangle(centre, at(0, s), at(0, s + 1));
    }
    for ring in 0..RINGS.len() as u32 - 1 {
        for s in 0..SEG {
            m.push_quad(
                at(ring, s),
                at(ring, s + 1),
                at(ring + 1, s + 1),
                at(ring + 1, s),
            );
        }
    }
}

/// `teapot-stadium`: views close to the teapot (SPD's direction), a
/// telephoto from the stands, low on the field near the teapot, and
/// grazing the field.
fn teapot_stadium() -> BuiltinScene {
    let mut mesh = teapot(TEAPOT_SF);
    stadium(&mut mesh);
    let spd = View::z_up(Vec3::new(4.86, 7.2, 5.4) * 1.6, Vec3::new(0.0, 0.0, 1.2));
    let stands = View {
        fov_y_deg: 2.0,
        ..View::z_up(Vec3::new(60.0, -900.0, 470.0), Vec3::new(0.0, 0.0, 1.5))
    };
    let low = View::z_up(Vec3::new(-7.0, 3.0, 0.6), Vec3::new(0.5, -0.3, 1.4));
    let grazing = View::z_up(Vec3::new(2.0, -60.0, 0.05), Vec3::new(0.0, 0.0, 0.3));
    BuiltinScene {
        name: "teapot-stadium",
        mesh,
        views: vec![spd, stands, low, grazing],
        light: Vec3::new(200.0, -300.0, 450.0),
    }
}

// ---------------------------------------------------------------- huge triangles

/// An axis-aligned box `[lo, hi]` (12 triangles; `inward` flips the winding).
fn cuboid(m: &mut Mesh, lo: Vec3, hi: Vec3, inward: bool) {
    let b = m.vertex_count() as u32;
    for k in 0..8u32 {
        let pick = |bit: u32, l: f32, h: f32| if k & bit != 0 { h } else { l };
        m.push_vertex(Vec3::new(
            pick(1, lo.x, hi.x),
            pick(2, lo.y, hi.y),
            pick(4, lo.z, hi.z),
        ));
    }
    // Faces, counter-clockwise seen from outside.
    const FACES: [[u32; 4]; 6] = [
        [0, 2, 3, 1],
        [4, 5, 7, 6],
        [0, 1, 5, 4],
        [2, 6, 7, 3],
        [0, 4, 6, 2],
        [1, 3, 7, 5],
    ];
    for f in FACES {
        if inward {
            m.push_quad(b + f[3], b + f[2], b + f[1], b + f[0]);
        } else {
            m.push_quad(b + f[0], b + f[1], b + f[2], b + f[3]);
        }
    }
}

/// `huge-triangles`: 2592 small cube triangles and 24 huge ones.
fn huge_triangles() -> BuiltinScene {
    let mut m = Mesh::default();
    for i in 0..6 {
        for j in 0..6 {
            for k in 0..6 {
                let lo = Vec3::new(i as f32, j as f32, k as f32) * 1.5;
                cuboid(&mut m, lo, lo + Vec3::splat(0.5), false);
            }
        }
    }
    let c = Vec3::splat(4.0);
    let s = 16.0;
    // x = 4.5 holds the -x faces of the cubes with i = 3; y = 5.0 the +y faces
    // of j = 3; z = 3.25 cuts the k = 2 layer through the middle.
    for (axis, at) in [(0usize, 4.5f32), (1, 5.0), (2, 3.25)] {
        let (u, v) = ((axis + 1) % 3, (axis + 2) % 3);
        let corner = |a: f32, b: f32| {
            let mut p = c;
            p[axis] = at;
            p[u] += a;
            p[v] += b;
            p
        };
        let q =
            [corner(-s, -s), corner(s, -s), corner(s, s), corner(-s, s)].map(|p| m.push_vertex(p));
        m.push_quad(q[0], q[1], q[2], q[3]);
    }
    let mut rng = Rng::new(0x4855_4745);
    for _ in 0..12 {
        let v = [0; 3].map(|_| m.push_vertex(c + (rng.sphere() * 18.0).as_vec3()));
        m.push_triangle(v[0], v[1], v[2]);
    }
    // Planes x + y + z = d, as the triangle of their points on three lines.
    for d in [9.0f32, 10.5, 12.0, 13.5, 15.0, 16.5] {
        let v = [
            Vec3::new(d + 20.0, -10.0, -10.0),
            Vec3::new(-10.0, d + 20.0, -10.0),
            Vec3::new(-10.0, -10.0, d + 20.0),
        ]
        .map(|p| m.push_vertex(p));
        m.push_triangle(v[0], v[1], v[2]);
    }
    let main = View::z_up(c + Vec3::new(15.0, -20.0, 12.0), c);
    let close = View::z_up(c + Vec3::new(2.2, -3.1, 1.6), c + Vec3::new(0.5, 0.2, 0.0));
    // In the gaps between cubes on every axis, on none of the huge planes.
    let inside = View::z_up(Vec3::new(3.75, 3.85, 3.95), Vec3::new(7.9, 6.1, 5.2));
    let grazing = View::z_up(Vec3::new(-6.0, -5.0, 3.251), Vec3::new(8.0, 9.0, 3.252));
    BuiltinScene {
        name: "huge-triangles",
        mesh: m,
        views: vec![main, close, inside, grazing],
        light: c + Vec3::new(9.0, -14.0, 20.0),
    }
}

// ---------------------------------------------------------------- skinny diagonal

/// `skinny-diagonal`: 1500 needles and 6 floor and wall triangles.
fn skinny_diagonal() -> BuiltinScene {
    let mut m = Mesh::default();
    let dirs = [
        DVec3::new(1.0, 1.0, 1.0),
        DVec3::new(-1.0, 1.0, 1.0),
        DVec3::new(1.0, -1.0, 1.0),
        DVec3::new(-1.0, -1.0, 1.0),
        DVec3::new(1.0, 1.0, 0.0),
        DVec3::new(1.0, -1.0, 0.0),
        DVec3::new(1.0, 0.0, 1.0),
        DVec3::new(1.0, 0.0, -1.0),
        DVec3::new(0.0, 1.0, 1.0),
        DVec3::new(0.0, 1.0, -1.0),
    ];
    let mut rng = Rng::new(0x534b_494e);
    for i in 0..1500 {
        let d = dirs[i % dirs.len()].normalize();
        let len = rng.range(8.0, 24.0);
        let p = DVec3::new(
            rng.range(0.0, 20.0),
            rng.range(0.0, 20.0),
            rng.range(0.0, 20.0),
        ) - d * (0.5 * len);
        let q = p + d * len;
        let width = if i % 50 == 0 {
            1e-6 * len
        } else {
            len * 10f64.powf(rng.range(-4.0, -1.0))
        };
        let perp = d.cross(rng.sphere()).normalize();
        // Half the needles are widest at an end, half in the middle.
        let r = if i % 2 == 0 { p } else { 0.5 * (p + q) } + perp * width;
        let v = [p, q, r].map(|x| m.push_vertex(x.as_vec3()));
        m.push_triangle(v[0], v[1], v[2]);
    }
    let floor = [(-20.0, -20.0), (45.0, -20.0), (45.0, 45.0), (-20.0, 45.0)]
        .map(|(x, y)| m.push_vertex(Vec3::new(x, y, -12.0)));
    m.push_quad(floor[0], floor[1], floor[2], floor[3]);
    let wall_x = [(-20.0, -12.0), (45.0, -12.0), (45.0, 40.0), (-20.0, 40.0)]
        .map(|(y, z)| m.push_vertex(Vec3::new(-20.0, y, z)));
    m.push_quad(wall_x[0], wall_x[1], wall_x[2], wall_x[3]);
    let wall_y = [(-20.0, -12.0), (45.0, -12.0), (45.0, 40.0), (-20.0, 40.0)]
        .map(|(x, z)| m.push_vertex(Vec3::new(x, 45.0, z)));
    m.push_quad(wall_y[0], wall_y[1], wall_y[2], wall_y[3]);
    let main = View::z_up(Vec3::new(45.0, -35.0, 38.0), Vec3::new(10.0, 10.0, 10.0));
    // Looking along (1, 1, 1), the direction of a quarter of the needles.
    let along = View::z_up(Vec3::new(-10.0, -10.0, -8.0), Vec3::new(20.0, 20.0, 22.0));
    let inside = View::z_up(Vec3::new(10.1, 9.7, 10.3), Vec3::new(25.0, 2.0, 4.0));
    let grazing = View::z_up(Vec3::new(-18.0, 12.0, -11.99), Vec3::new(30.0, 13.0, -11.9));
    BuiltinScene {
        name: "skinny-diagonal",
        mesh: m,
        views: vec![main, along, inside, grazing],
        light: Vec3::new(40.0, -30.0, 60.0),
    }
}

// ---------------------------------------------------------------- coincident and degenerate

/// A planar panel of `nx x ny` quads, corners `o + i a + j b`, tessellated
/// twice: along one diagonal and along the other (the two share vertices).
fn double_panel(m: &mut Mesh, o: Vec3, a: Vec3, b: Vec3, nx: u32, ny: u32) {
    let base = m.vertex_count() as u32;
    for j in 0..=ny {
        for i in 0..=nx {
            m.push_vertex(o + a * i as f32 + b * j as f32);
        }
    }
    let at = |i: u32, j: u32| base + j * (nx + 1) + i;
    for j in 0..ny {
        for i in 0..nx {
            let (p, q, r, s) = (at(i, j), at(i + 1, j), at(i + 1, j + 1), at(i, j + 1));
            m.push_triangle(p, q, r);
            m.push_triangle(p, r, s);
            m.push_triangle(p, q, s);
            m.push_triangle(q, r, s);
        }
    }
}

/// `coincident-degenerate`: 2048 terrain triangles (512 four times), 400
/// doubly tessellated panel triangles, 40 slivers, 120 zero-area and 6
/// non-finite triangles.
fn coincident_degenerate() -> BuiltinScene {
    const N: u32 = 16;
    let mut m = Mesh::default();
    let height = |x: f32, y: f32| 0.8 * (0.5 * x).sin() * (0.4 * y).cos();
    for j in 0..=N {
        for i in 0..=N {
            let (x, y) = (i as f32 - 8.0, j as f32 - 8.0);
            m.push_vertex(Vec3::new(x, y, height(x, y)));
        }
    }
    let at = |i: u32, j: u32| j * (N + 1) + i;
    let mut terrain = Vec::new();
    for j in 0..N {
        for i in 0..N {
            terrain.push([at(i, j), at(i + 1, j), at(i + 1, j + 1)]);
            terrain.push([at(i, j), at(i + 1, j + 1), at(i, j + 1)]);
        }
    }
    // The terrain, an exact duplicate, the same triangles with rotated
    // indices, and with copied vertices in reverse order.
    for &[a, b, c] in &terrain {
        m.push_triangle(a, b, c);
    }
    for &[a, b, c] in &terrain {
        m.push_triangle(a, b, c);
    }
    for &[a, b, c] in &terrain {
        m.push_triangle(b, c, a);
    }
    let copy = m.vertex_count() as u32;
    for k in 0..copy {
        let p = m.vertex(k as usize);
        m.push_vertex(p);
    }
    for &[a, b, c] in &terrain {
        m.push_triangle(copy + a, copy + c, copy + b);
    }
    // A horizontal table over the terrain and a tilted panel, each
    // tessellated twice.
    let table_z = 2.5;
    double_panel(
        &mut m,
        Vec3::new(-4.0, -4.0, table_z),
        Vec3::X,
        Vec3::Y,
        8,
        8,
    );
    double_panel(
        &mut m,
        Vec3::new(4.5, -3.0, 1.5),
        Vec3::new(0.5, 0.0, 0.25),
        Vec3::new(0.0, 1.0, 0.125),
        6,
        6,
    );
    // Slivers in the table's plane: the apex 1e-6 off the long edge's
    // midpoint (a non-zero f32 cross product, so they are traced).
    for k in 0..40 {
        let (x, y) = (-4.0 + 0.19 * k as f32, -3.7 + 0.17 * k as f32);
        let v = [
            Vec3::new(x, y, table_z),
            Vec3::new(x + 2.0, y + 1.0, table_z),
            Vec3::new(x + 1.0, y + 0.5 + 1e-6, table_z),
        ]
        .map(|p| m.push_vertex(p));
        m.push_triangle(v[0], v[1], v[2]);
    }
    // Zero area (the exact f32 cross product is zero): repeated indices...
    for k in 0..40 {
        let (a, b) = (at(k % N, k / 3), at(k % N + 1, k / 3));
        match k % 3 {
            0 => m.push_triangle(a, a, b),
            1 => m.push_triangle(a, b, a),
            _ => m.push_triangle(b, b, b),
        }
    }
    // ...distinct vertices at one point...
    for k in 0..20 {
        let p = m.vertex(at(k % N, 2 + k / 4) as usize);
        let v = [p, p, p].map(|p| m.push_vertex(p));
        m.push_triangle(v[0], v[1], v[2]);
    }
    // ...collinear on the table's grid lines (exactly representable)...
    for k in 0..40 {
        let (x, y) = (-4.0 + (k % 5) as f32, -4.0 + (k / 5) as f32);
        let v = [0.0, 1.0, 3.0].map(|s| {
            let p = if k % 2 == 0 {
                Vec3::new(x + s, y, table_z)
            } else {
                Vec3::new(y, x + s, table_z)
            };
            m.push_vertex(p)
        });
        m.push_triangle(v[0], v[1], v[2]);
    }
    // ...and on diagonal lines, p + s (0.5, 0.25, 0.125) for s = 0, 1, 2.
    for k in 0..20 {
        let p = Vec3::new(-3.0 + 0.25 * k as f32, -2.0, 0.5 + 0.125 * k as f32);
        let v = [0.0, 1.0, 2.0].map(|s| m.push_vertex(p + Vec3::new(0.5, 0.25, 0.125) * s));
        m.push_triangle(v[0], v[1], v[2]);
    }
    // Non-finite vertices (left out of every structure).
    let bad = [
        Vec3::new(f32::NAN, 0.0, 1.0),
        Vec3::new(0.0, f32::INFINITY, 1.0),
        Vec3::new(1.0, 1.0, f32::NEG_INFINITY),
    ]
    .map(|p| m.push_vertex(p));
    for (k, &b) in bad.iter().enumerate() {
        m.push_triangle(b, at(3 + k as u32, 3), at(4 + k as u32, 4));
        m.push_triangle(at(5, 5 + k as u32), b, bad[(k + 1) % 3]);
    }
    let main = View::z_up(Vec3::new(14.0, -13.0, 10.0), Vec3::new(0.0, 0.0, 0.8));
    let close = View::z_up(Vec3::new(2.0, -6.0, 6.0), Vec3::new(0.0, 0.0, table_z));
    let inside = View::z_up(Vec3::new(-2.0, -1.0, 1.6), Vec3::new(3.0, 2.0, 1.3));
    let grazing = View::z_up(
        Vec3::new(-9.0, -3.0, table_z + 1e-4),
        Vec3::new(4.0, 1.0, table_z + 2e-4),
    );
    BuiltinScene {
        name: "coincident-degenerate",
        mesh: m,
        views: vec![main, close, inside, grazing],
        light: Vec3::new(6.0, -8.0, 12.0),
    }
}

// ---------------------------------------------------------------- closed box

/// The inside faces of the box `[-h, h]`, each face `n x n` quads.
fn box_inside(m: &mut Mesh, h: Vec3, n: u32) {
    for axis in 0..3 {
        let (u, v) = ((axis + 1) % 3, (axis + 2) % 3);
        for side in [-1.0f32, 1.0] {
            let base = m.vertex_count() as u32;
            for j in 0..=n {
                for i in 0..=n {
                    let mut p = Vec3::ZERO;
                    p[axis] = side * h[axis];
                    p[u] = h[u] * (2.0 * i as f32 / n as f32 - 1.0);
                    p[v] = h[v] * (2.0 * j as f32 / n as f32 - 1.0);
                    m.push_vertex(p);
                }
            }
            let at = |i: u32, j: u32| base + j * (n + 1) + i;
            for j in 0..n {
                for i in 0..n {
                    let q = [at(i, j), at(i + 1, j), at(i + 1, j + 1), at(i, j + 1)];
                    // Normals into the box.
                    if side > 0.0 {
                        m.push_quad(q[3], q[2], q[1], q[0]);
                    } else {
                        m.push_quad(q[0], q[1], q[2], q[3]);
                    }
                }
            }
        }
    }
}

/// `closed-box`: 1728 wall triangles (the box [-10, 10] x [-7, 7] x [-5, 5],
/// 12 x 12 quads a face) and five inner boxes (60 triangles).
fn closed_box() -> BuiltinScene {
    let mut m = Mesh::default();
    let h = Vec3::new(10.0, 7.0, 5.0);
    box_inside(&mut m, h, 12);
    // On the floor, against the +x wall, free-standing, small, and thin.
    for (lo, hi) in [
        (Vec3::new(1.5, 0.5, -5.0), Vec3::new(4.5, 3.5, -2.0)),
        (Vec3::new(8.0, -1.0, -1.0), Vec3::new(10.0, 1.0, 1.0)),
        (Vec3::new(-7.0, -5.0, -1.0), Vec3::new(-5.0, -3.0, 1.0)),
        (Vec3::new(-0.5, -0.5, 1.5), Vec3::new(0.5, 0.5, 2.5)),
        (Vec3::new(-3.0, 4.0, -4.0), Vec3::new(3.0, 4.01, 3.0)),
    ] {
        cuboid(&mut m, lo, hi, false);
    }
    let main = View {
        fov_y_deg: 90.0,
        ..View::z_up(Vec3::new(-7.0, -4.5, 2.0), Vec3::new(10.0, 7.0, -5.0))
    };
    let axis = View {
        fov_y_deg: 60.0,
        ..View::z_up(Vec3::new(-2.0, 0.0, 0.0), Vec3::new(10.0, 0.0, 0.0))
    };
    let corner = View {
        fov_y_deg: 75.0,
        ..View::z_up(Vec3::new(9.99, 6.99, 4.99), Vec3::new(-10.0, -7.0, -5.0))
    };
    let grazing = View::z_up(Vec3::new(-9.5, 0.5, -4.999), Vec3::new(10.0, 0.6, -4.99));
    BuiltinScene {
        name: "closed-box",
        mesh: m,
        views: vec![main, axis, corner, grazing],
        light: Vec3::new(2.0, 1.0, 4.5),
    }
}

// ---------------------------------------------------------------- rays

/// Adversarial ray classes (see [`stress_rays`] for their order). Rays of
/// the view's camera are through pixel centres of the image
/// [`stress_image_size`] gives. Classes vary their pattern by "tile": the
/// 16 x 16 pixel tiles of [`stress_rays`]' order, 256 consecutive rays (ray
/// `k` is in tile `k / 256`), so 1024 rays hold every pattern.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum RayClass {
    /// Directions uniform on the sphere, independently per ray: from the
    /// view's eye (a common origin) in even tiles, from points uniform in
    /// the scene's finite bounds in odd tiles.
    RandomInPacket,
    /// The view's camera rays with direction signs flipped: in even tiles
    /// every ray flips a random subset of its components; in odd tiles the
    /// rays of a checkerboard flip the view's dominant axis (half the
    /// packet goes backwards along the axis the grid marches).
    MixedSigns,
    /// Directions along an axis or a face diagonal (one or two components
    /// exactly zero, so reciprocals are infinite). Even tiles are
    /// orthographic: one direction per tile, origins on a lattice across the
    /// bounds, every third ray aimed exactly at a vertex (its transverse
    /// coordinates are the vertex's). Odd tiles: a random such direction
    /// per ray (zeros randomly `-0.0`, magnitudes from 1e-3 to 1e3), from a
    /// point in the bounds or from behind a vertex.
    AxisParallel,
    /// Nearly parallel to surfaces. Even tiles: one grazing camera per
    /// tile, a hair (1e-4 of the triangle's size) above a large triangle's
    /// plane, looking along it (half the rays skim the plane at angles
    /// below a few degrees). Odd tiles: per ray, a random triangle, a point
    /// inside it, an in-plane direction tilted out of the plane by 0, +-1e-7,
    /// +-1e-5 or +-1e-3, the origin before the point along the ray.
    Grazing,
    /// Origins on triangle edges (the f32 rounding of a point on an edge:
    /// its midpoint or a random point), `tmin = 0`; 16 consecutive rays (a
    /// 4 x 4 tile) share an origin. Directions: random, a fan around a random
    /// direction, along the edge, in the triangle's plane into the triangle,
    /// along the normal, or at another vertex.
    EdgeOrigins,
    /// As `EdgeOrigins` with origins exactly on vertices (bitwise).
    VertexOrigins,
    /// Camera rays some of which are replaced (see [`zero_length_ray`]):
    /// zero direction (`+0.0` or `-0.0`: invalid, a miss), an empty interval
    /// `tmin == tmax` (valid, a miss), or a direction scaled by 1e-30 or
    /// 1e-39 (valid, subnormal or tiny components: t near 1e31 or past the
    /// f32 range). Which rays are replaced depends on the tile: all of
    /// them (kinds mixed inside every quad), every third, lane 0 of every
    /// quad, or whole 4 x 4 tiles.
    ZeroLength,
    /// Camera rays some of which (chosen as in `ZeroLength`) get a NaN or
    /// infinite direction component, origin, `tmin` or `tmax`, `tmin < 0`,
    /// `tmin > tmax` or `tmin = tmax = +inf` (see [`non_finite_ray`]). All of
    /// these are misses (sheaf.h, `sheaf_ray`).
    NonFinite,
}

impl RayClass {
    pub const ALL: [RayClass; 8] = [
        RayClass::RandomInPacket,
        RayClass::MixedSigns,
        RayClass::AxisParallel,
        RayClass::Grazing,
        RayClass::EdgeOrigins,
        RayClass::VertexOrigins,
        RayClass::ZeroLength,
        RayClass::NonFinite,
    ];
    pub fn name(self) -> &'static str {
        match self {
            RayClass::RandomInPacket => "random-in-packet",
            RayClass::MixedSigns => "mixed-signs",
            RayClass::AxisParallel => "axis-parallel",
            RayClass::Grazing => "grazing",
            RayClass::EdgeOrigins => "edge-origins",
            RayClass::VertexOrigins => "vertex-origins",
            RayClass::ZeroLength => "zero-length",
            RayClass::NonFinite => "non-finite",
        }
    }
    pub fn from_name(s: &str) -> Option<RayClass> {
        RayClass::ALL.into_iter().find(|c| c.name() == s)
    }
}

/// Side of the pixel blocks of [`stress_rays`] (the largest packet side).
pub const BLOCK: u32 = 32;
/// Side of the tiles whose pattern a class varies (see [`RayClass`]).
pub const TILE: u32 = 16;
const TILE_RAYS: usize = (TILE * TILE) as usize;

/// Width and height of the image whose pixels `n` stress rays cover: whole
/// 32 x 32 blocks, as square as possible.
pub fn stress_image_size(n: usize) -> (u32, u32) {
    let blocks = n.div_ceil((BLOCK * BLOCK) as usize).max(1);
    let bw = (blocks as f64).sqrt().ceil() as usize;
    let bh = blocks.div_ceil(bw);
    (BLOCK * bw as u32, BLOCK * bh as u32)
}

/// Pixel `(x, y)` of ray `k` of `n` (see [`stress_rays`]).
pub fn stress_pixel(k: usize, n: usize) -> (u32, u32) {
    let (w, _) = stress_image_size(n);
    let bw = (w / BLOCK) as usize;
    let per = (BLOCK * BLOCK) as usize;
    let (b, i) = (k / per, k % per);
    let (mut x, mut y) = (0u32, 0u32);
    for bit in 0..5 {
        x |= (((i >> (2 * bit)) & 1) as u32) << bit;
        y |= (((i >> (2 * bit + 1)) & 1) as u32) << bit;
    }
    ((b % bw) as u32 * BLOCK + x, (b / bw) as u32 * BLOCK + y)
}

/// `n` rays of `class` for `mesh` seen from `view`, deterministic from
/// `seed`.
///
/// # Order
/// Ray `k` belongs to pixel [`stress_pixel`]`(k, n)`: the image is cut
/// into 32 x 32 blocks (row-major), and inside a block the pixels are in
/// Morton order (bits of x in the even, of y in the odd positions of
/// `k % 1024`). `Context::trace_with` and `occluded_with` take every
/// `packet^2` consecutive rays as one packet and every 4 consecutive rays as
/// one 2x2 quad (`Ray4` lanes (x, y), (x+1, y), (x, y+1), (x+1, y+1)), so
/// for every packet side n in {2, 4, 8, 16, 32} each packet is an n x n pixel
/// tile with its quads in Morton order: the renderer's layout
/// (`render::demorton`), which camera-ray frusta (`RayKind::Primary`)
/// expect. With `n` a multiple of 1024 every packet is full.
pub fn stress_rays(class: RayClass, mesh: &Mesh, view: &View, n: usize, seed: u64) -> Vec<Ray> {
    let mut g = Gen::new(mesh, view, n, seed ^ ((class as u64) << 56));
    (0..n).map(|k| g.ray(class, k)).collect()
}

/// What the generators need of a scene.
struct Gen {
    rng: Rng,
    n: usize,
    lo: Vec3,
    hi: Vec3,
    /// Traceable triangles (finite, non-zero f32 area), as corner triples.
    tris: Vec<[Vec3; 3]>,
    cam: PrimaryRays,
    eye: Vec3,
    /// Dominant axis of the view direction.
    major: usize,
    /// Per-tile camera of `Grazing` (tile index, camera).
    grazing: Option<(usize, PrimaryRays)>,
    /// Shared origin of the current 16-ray group (`EdgeOrigins`, `VertexOrigins`).
    group: Option<(usize, Vec3, [Vec3; 3], Vec3)>,
}

/// A pinhole camera over the stress image, or a fallback looking at the
/// bounds when the view is unusable.
fn camera(view: &View, lo: Vec3, hi: Vec3, w: u32, h: u32) -> PrimaryRays {
    let cam = Camera {
        eye: view.eye.to_array(),
        look_at: view.look_at.to_array(),
        up: view.up.to_array(),
        fov_y_deg: view.fov_y_deg,
    };
    PrimaryRays::new(&cam, w, h).unwrap_or_else(|_| {
        let c = 0.5 * (lo + hi);
        let eye = c + (hi - lo).max(Vec3::ONE) * Vec3::new(0.7, -1.1, 0.6);
        let cam = Camera {
            eye: eye.to_array(),
            look_at: c.to_array(),
            up: [0.0, 0.0, 1.0],
            fov_y_deg: 50.0,
        };
        PrimaryRays::new(&cam, w, h).expect("fallback camera is valid")
    })
}

/// Axis directions and face diagonals: every component 0 or +-1, one or two zero.
const AXIAL: [[f32; 3]; 18] = [
    [1.0, 0.0, 0.0],
    [-1.0, 0.0, 0.0],
    [0.0, 1.0, 0.0],
    [0.0, -1.0, 0.0],
    [0.0, 0.0, 1.0],
    [0.0, 0.0, -1.0],
    [1.0, 1.0, 0.0],
    [1.0, -1.0, 0.0],
    [-1.0, 1.0, 0.0],
    [-1.0, -1.0, 0.0],
    [1.0, 0.0, 1.0],
    [1.0, 0.0, -1.0],
    [-1.0, 0.0, 1.0],
    [-1.0, 0.0, -1.0],
    [0.0, 1.0, 1.0],
    [0.0, 1.0, -1.0],
    [0.0, -1.0, 1.0],
    [0.0, -1.0, -1.0],
];

/// Replacement `kind` (0..6) of a `ZeroLength` camera ray `r`: zero
/// direction, negative zero direction, `tmin = tmax = 0`, `tmin = tmax =
/// 1`, direction x 1e-30, direction x 1e-39 (subnormal components).
pub fn zero_length_ray(r: Ray, kind: usize) -> Ray {
    let d = Vec3::from(r.dir);
    match kind % 6 {
        0 => Ray { dir: [0.0; 3], ..r },
        1 => Ray {
            dir: [-0.0, 0.0, -0.0],
            ..r
        },
        2 => Ray {
            tmin: 0.0,
            tmax: 0.0,
            ..r
        },
        3 => Ray {
            tmin: 1.0,
            tmax: 1.0,
            ..r
        },
        4 => Ray {
            dir: (d * 1e-30).to_array(),
            ..r
        },
        _ => Ray {
            dir: (d * 1e-39).to_array(),
            ..r
        },
    }
}

/// Replacement `kind` (0..12) of a `NonFinite` camera ray `r`: NaN, +inf,
/// -inf direction components, all-infinite direction, an infinite axis
/// direction, NaN and infinite origins, NaN `tmin`, NaN `tmax`, `tmin = -1`,
/// `tmin > tmax`, `tmin = tmax = +inf`.
pub fn non_finite_ray(r: Ray, kind: usize) -> Ray {
    let (nan, inf) = (f32::NAN, f32::INFINITY);
    let mut r = r;
    match kind % 12 {
        0 => r.dir[0] = nan,
        1 => r.dir[1] = inf,
        2 => r.dir[2] = -inf,
        3 => r.dir = [inf, -inf, inf],
        4 => r.dir = [inf, 0.0, 0.0],
        5 => r.org[1] = nan,
        6 => r.org[0] = -inf,
        7 => r.tmin = nan,
        8 => r.tmax = nan,
        9 => r.tmin = -1.0,
        10 => (r.tmin, r.tmax) = (2.0, 1.0),
        _ => (r.tmin, r.tmax) = (inf, inf),
    }
    r
}

impl Gen {
    fn new(mesh: &Mesh, view: &View, n: usize, seed: u64) -> Gen {
        let (lo, hi) = finite_bounds(mesh);
        let mut tris = Vec::new();
        if let Ok(scene) = Scene::from_f32(&mesh.vertices, &mesh.indices) {
            for t in 0..scene.triangle_count() {
                let tri = scene.triangle(t);
                if Scene::classify(&tri).is_none() {
                    tris.push([tri.v0, tri.v1, tri.v2].map(Vec3::from));
                }
            }
        }
        if tris.is_empty() {
            // No geometry: pretend the bounds' corners form a triangle.
            tris.push([lo, Vec3::new(hi.x, lo.y, lo.z), Vec3::new(lo.x, hi.y, hi.z)]);
        }
        let (w, h) = stress_image_size(n);
        let cam = camera(view, lo, hi, w, h);
        let fwd = view.look_at - view.eye;
        let major = if fwd.is_finite() {
            fwd.abs().max_position()
        } else {
            0
        };
        Gen {
            rng: Rng::new(seed),
            n,
            lo,
            hi,
            tris,
            cam,
            eye: Vec3::from(cam.ray(0, 0).org),
            major,
            grazing: None,
            group: None,
        }
    }

    fn unit(&mut self) -> Vec3 {
        self.rng.sphere().as_vec3()
    }

    fn triangle(&mut self) -> [Vec3; 3] {
        let i = self.rng.below(self.tris.len());
        self.tris[i]
    }

    fn vertex(&mut self) -> Vec3 {
        let t = self.triangle();
        t[self.rng.below(3)]
    }

    /// Half the bounds' diagonal (at least 1).
    fn radius(&self) -> f32 {
        (0.5 * (self.hi - self.lo).length()).max(1.0)
    }

    fn camera_ray(&self, k: usize) -> Ray {
        let (x, y) = stress_pixel(k, self.n);
        self.cam.ray(x, y)
    }

    fn ray(&mut self, class: RayClass, k: usize) -> Ray {
        let tile = k / TILE_RAYS;
        let inf = f32::INFINITY;
        match class {
            RayClass::RandomInPacket => {
                let o = if tile.is_multiple_of(2) {
                    self.eye
                } else {
                    self.rng.in_box(self.lo, self.hi)
                };
                let d = self.unit();
                Ray::new(o, d, 0.0, inf)
            }
            RayClass::MixedSigns => {
                let mut r = self.camera_ray(k);
                let (x, y) = stress_pixel(k, self.n);
                let flips = if tile.is_multiple_of(2) {
                    self.rng.below(8)
                } else if (x ^ y) & 1 == 1 {
                    1 << self.major
                } else {
                    0
                };
                for a in 0..3 {
                    if flips & (1 << a) != 0 {
                        r.dir[a] = -r.dir[a];
                    }
                }
                r
            }
            RayClass::AxisParallel => self.axis_parallel(k, tile),
            RayClass::Grazing => self.grazing(k, tile),
            RayClass::EdgeOrigins => self.on_surface(k, false),
            RayClass::VertexOrigins => self.on_surface(k, true),
            RayClass::ZeroLength | RayClass::NonFinite => {
                let r = self.camera_ray(k);
                let kinds = if class == RayClass::ZeroLength { 6 } else { 12 };
                let replace = match tile % 4 {
                    0 => Some(k % kinds),
                    1 => k.is_multiple_of(3).then(|| (k / 3) % kinds),
                    2 => k.is_multiple_of(4).then(|| (k / 4) % kinds),
                    _ => (k / 16).is_multiple_of(2).then(|| (k / 32) % kinds),
                };
                match (replace, class) {
                    (None, _) => r,
                    (Some(kind), RayClass::ZeroLength) => zero_length_ray(r, kind),
                    (Some(kind), _) => non_finite_ray(r, kind),
                }
            }
        }
    }

    fn axis_parallel(&mut self, k: usize, tile: usize) -> Ray {
        let c = 0.5 * (self.lo + self.hi);
        let r = self.radius();
        if tile.is_multiple_of(2) {
            let d = Vec3::from(AXIAL[(tile / 2) % AXIAL.len()]);
            // Lattice axes across d: a zero axis of d and the rest.
            let zero = (0..3).find(|&a| d[a] == 0.0).unwrap_or(0);
            let mut u = Vec3::ZERO;
            u[zero] = 1.0;
            let v = d.cross(u).normalize();
            let (x, y) = stress_pixel(k, self.n);
            let (fx, fy) = (
                ((x % TILE) as f32 + 0.5) / TILE as f32 - 0.5,
                ((y % TILE) as f32 + 0.5) / TILE as f32 - 0.5,
            );
            let o = if self.rng.below(3) == 0 {
                self.vertex() - d * (2.0 * r)
            } else {
                c - d * (2.0 * r) + (u * fx + v * fy) * (2.2 * r)
            };
            Ray::new(o, d, 0.0, inf_f32())
        } else {
            let mut d = AXIAL[self.rng.below(AXIAL.len())];
            for x in &mut d {
                if *x == 0.0 && self.rng.below(2) == 0 {
                    *x = -0.0;
                }
            }
            let scale = 10f32.powi(self.rng.below(7) as i32 - 3);
            let d = Vec3::from(d) * scale;
            let o = if self.rng.below(2) == 0 {
                self.rng.in_box(self.lo, self.hi)
            } else {
                let back = self.rng.range(0.0, 2.0) as f32 * r / scale;
                self.vertex() - d * back
            };
            Ray::new(o, d, 0.0, inf_f32())
        }
    }

    fn grazing(&mut self, k: usize, tile: usize) -> Ray {
        if tile.is_multiple_of(2) {
            if self.grazing.map(|(b, _)| b) != Some(tile) {
                // The largest of 16 random triangles.
                let mut best = self.triangle();
                for _ in 0..15 {
                    let t = self.triangle();
                    let area = |t: &[Vec3; 3]| (t[1] - t[0]).cross(t[2] - t[0]).length();
                    if area(&t) > area(&best) {
                        best = t;
                    }
                }
                let [a, b, c] = best;
                let nrm = (b - a).cross(c - a).normalize();
                let centre = (a + b + c) / 3.0;
                let along = (b - a).normalize();
                let size = (b - a).length().max((c - a).length());
                let lift = nrm * (1e-4 * size);
                let eye = centre - along * size + lift;
                let cam = Camera {
                    eye: eye.to_array(),
                    look_at: (centre + along * size + lift).to_array(),
                    up: nrm.to_array(),
                    fov_y_deg: 10.0,
                };
                let pr = PrimaryRays::new(&cam, TILE, TILE).unwrap_or(self.cam);
                self.grazing = Some((tile, pr));
            }
            let (x, y) = stress_pixel(k, self.n);
            self.grazing.expect("set above").1.ray(x % TILE, y % TILE)
        } else {
            let [a, b, c] = self.triangle();
            let nrm = (b - a).cross(c - a).normalize();
            let (mut s, mut t) = (self.rng.unit() as f32, self.rng.unit() as f32);
            if s + t > 1.0 {
                (s, t) = (1.0 - s, 1.0 - t);
            }
            let p = a + (b - a) * s + (c - a) * t;
            let tangent = self.unit().reject_from(nrm).normalize_or(b - a);
            let tilt = [0.0, 1e-7, -1e-7, 1e-5, -1e-5, 1e-3, -1e-3][self.rng.below(7)];
            let d = tangent + nrm * tilt;
            let size = (b - a).length().max((c - a).length());
            let back = size * (0.5 + self.rng.unit() as f32);
            Ray::new(p - d * back, d, 0.0, inf_f32())
        }
    }

    fn on_surface(&mut self, k: usize, vertex: bool) -> Ray {
        let g = k / 16;
        if self.group.map(|x| x.0) != Some(g) {
            let tri = self.triangle();
            let e = self.rng.below(3);
            let o = if vertex {
                tri[e]
            } else {
                let w = if self.rng.below(2) == 0 {
                    0.5
                } else {
                    self.rng.unit() as f32
                };
                tri[e] + (tri[(e + 1) % 3] - tri[e]) * w
            };
            // Reorder so tri[0] -> tri[1] is the edge (or the vertex's edge).
            let tri = [tri[e], tri[(e + 1) % 3], tri[(e + 2) % 3]];
            let fan = self.unit();
            self.group = Some((g, o, tri, fan));
        }
        let (_, o, [a, b, c], fan) = self.group.expect("set above");
        let d = match self.rng.below(6) {
            0 => self.unit(),
            1 => fan + self.unit() * 0.15,
            2 => {
                if self.rng.below(2) == 0 {
                    b - a
                } else {
                    a - b
                }
            }
            3 => (c + (a + b) * 0.5) * 0.5 - o,
            4 => {
                let nrm = (b - a).cross(c - a);
                if self.rng.below(2) == 0 { nrm } else { -nrm }
            }
            _ => self.vertex() - o,
        };
        // Never a zero direction (a vertex at the origin itself).
        let d = if d == Vec3::ZERO { fan } else { d };
        Ray::new(o, d, 0.0, inf_f32())
    }
}

fn inf_f32() -> f32 {
    f32::INFINITY
}

#[cfg(test)]
mod tests {
    use super::*;
    use sheaf::scenes::check;

    #[test]
    fn teapot_counts_and_symmetry() {
        for sf in [2, 4, TEAPOT_SF] {
            let m = teapot(sf);
            let sf = sf as usize;
            assert_eq!(m.triangle_count(), 64 * sf * sf - 8 * sf, "sf {sf}");
            check::mesh_sane(&m);
        }
        // The table is mirror symmetric in y, and rim, body, lid and
        // bottom are symmetric under a quarter turn about z: catches typos.
        let has = |p: [f64; 3]| TEAPOT_POINTS.contains(&p);
        for (i, p) in TEAPOT_POINTS.iter().enumerate() {
            let mirror = [p[0], if p[1] == 0.0 { 0.0 } else { -p[1] }, p[2]];
            assert!(has(mirror), "point {i} {p:?} has no mirror image");
            if !(120..203).contains(&i) {
                let turn = [if p[1] == 0.0 { 0.0 } else { -p[1] }, p[0], p[2]];
                assert!(has(turn), "point {i} {p:?} has no quarter-turn image");
            }
        }
        let (lo, hi) = teapot(4).bounds();
        assert!(lo.z.abs() < 1e-6 && (hi.z - 3.15).abs() < 1e-3, "{lo} {hi}");
        assert!((lo.x + 3.0).abs() < 0.01 && hi.x > 3.4, "{lo} {hi}");
    }

    #[test]
    fn every_stress_scene_is_as_documented() {
        for &name in STRESS_SCENE_NAMES {
            let s = stress_scene(name).unwrap();
            assert_eq!(s.name, name);
            check::indices_in_range(&s.mesh);
            check::views_sane(&s.views);
            assert!(s.light.is_finite());
            let n = s.mesh.triangle_count();
            assert!((1_000..=6_000).contains(&n), "{name}: {n} triangles");
            let (lo, hi) = finite_bounds(&s.mesh);
            // views[2] is inside the scene bounds; in the closed box all are.
            let inside: &[View] = if name == "closed-box" {
                &s.views
            } else {
                &s.views[2..3]
            };
            for v in inside {
                assert!(check::inside(v.eye, (lo, hi)), "{name}: eye outside {v:?}");
            }
            let scene = Scene::from_f32(&s.mesh.vertices, &s.mesh.indices).unwrap();
            let (mut zero, mut bad) = (0, 0);
            for t in 0..scene.triangle_count() {
                match Scene::classify(&scene.triangle(t)) {
                    Some(sheaf::geom::Excluded::ZeroArea) => zero += 1,
                    Some(sheaf::geom::Excluded::NonFinite) => bad += 1,
                    None => {}
                }
            }
            if name == "coincident-degenerate" {
                assert_eq!((zero, bad), (120, 6), "{name}");
            } else {
                assert_eq!((zero, bad), (0, 0), "{name}");
                check::finite(&s.mesh);
            }
        }
        assert!(stress_scene("nope").is_none());
        // The stadium is hundreds of times the teapot.
        let s = stress_scene("teapot-stadium").unwrap();
        let (lo, hi) = s.mesh.bounds();
        assert!((hi - lo).x > 250.0 * 6.5, "{lo} {hi}");
        assert_eq!(s.mesh.triangle_count(), 3080 + 432);
        // The closed box is closed: every camera ray of every view hits a
        // wall (checked on the box's faces alone in f64 by the tests).
        let b = stress_scene("closed-box").unwrap();
        assert_eq!(b.mesh.triangle_count(), 6 * 2 * 144 + 5 * 12);
    }

    #[test]
    fn pixels_follow_the_packet_layout() {
        for n in [16, 1000, 1024, 4096, 5000] {
            let (w, h) = stress_image_size(n);
            assert!(w % BLOCK == 0 && h % BLOCK == 0 && (w * h) as usize >= n);
            let mut seen = std::collections::HashSet::new();
            for k in 0..n {
                let (x, y) = stress_pixel(k, n);
                assert!(x < w && y < h && seen.insert((x, y)));
            }
        }
        // Every aligned group of side^2 rays is a side x side tile; quads
        // are in Ray4 lane order and in render::demorton order.
        for side in [2usize, 4, 8, 16, 32] {
            for p in 0..(4096 / (side * side)) {
                let k0 = p * side * side;
                let (x0, y0) = stress_pixel(k0, 4096);
                assert!((x0 as usize).is_multiple_of(side) && (y0 as usize).is_multiple_of(side));
                for k in k0..k0 + side * side {
                    let (x, y) = stress_pixel(k, 4096);
                    let q = (k - k0) / 4;
                    let (qx, qy) = sheaf::render::demorton(q);
                    let lane = (k - k0) % 4;
                    assert_eq!(
                        (x - x0, y - y0),
                        (2 * qx + (lane as u32 & 1), 2 * qy + (lane as u32 >> 1))
                    );
                }
            }
        }
    }

    #[test]
    fn rays_are_deterministic_and_of_their_class() {
        let s = stress_scene("huge-triangles").unwrap();
        let scene = Scene::from_f32(&s.mesh.vertices, &s.mesh.indices).unwrap();
        let is_vertex = |p: [f32; 3]| s.mesh.vertices.chunks_exact(3).any(|v| v == p);
        for class in RayClass::ALL {
            assert_eq!(RayClass::from_name(class.name()), Some(class));
            let a = stress_rays(class, &s.mesh, &s.views[0], 2048, 7);
            let b = stress_rays(class, &s.mesh, &s.views[0], 2048, 7);
            let c = stress_rays(class, &s.mesh, &s.views[0], 2048, 8);
            assert_eq!(a.len(), 2048);
            let bits = |r: &[Ray]| -> Vec<u32> {
                r.iter()
                    .flat_map(|r| r.org.iter().chain(&r.dir).chain([&r.tmin, &r.tmax]))
                    .map(|x| x.to_bits())
                    .collect()
            };
            assert_eq!(bits(&a), bits(&b), "{class:?} not deterministic");
            let invalid = a.iter().filter(|r| !r.is_valid()).count();
            match class {
                RayClass::ZeroLength => {
                    assert!(invalid > 100 && invalid < 2048);
                    assert!(a.iter().any(|r| r.is_valid() && r.tmin == r.tmax));
                    assert!(
                        a.iter()
                            .any(|r| r.is_valid() && r.dir[0].abs() < 1e-37 && r.dir[0] != 0.0)
                    );
                }
                RayClass::NonFinite => {
                    assert!(invalid > 100 && invalid < 2048);
                    assert!(a.iter().any(|r| r.dir.iter().any(|x| x.is_nan())));
                    assert!(a.iter().any(|r| r.dir.iter().any(|x| x.is_infinite())));
                    assert!(
                        a.iter()
                            .any(|r| r.tmin.is_infinite() && r.tmax.is_infinite())
                    );
                }
                _ => assert_eq!(invalid, 0, "{class:?}"),
            }
            match class {
                RayClass::RandomInPacket
                | RayClass::MixedSigns
                | RayClass::Grazing
                | RayClass::AxisParallel
                | RayClass::EdgeOrigins
                | RayClass::VertexOrigins => {
                    assert_ne!(bits(&a), bits(&c), "{class:?} ignores the seed")
                }
                _ => {}
            }
            match class {
                RayClass::AxisParallel => {
                    assert!(
                        a.iter()
                            .all(|r| r.dir.iter().filter(|&&x| x == 0.0).count() >= 1)
                    );
                }
                RayClass::VertexOrigins => assert!(a.iter().all(|r| is_vertex(r.org))),
                RayClass::EdgeOrigins => {
                    // Within rounding of an edge of some triangle.
                    for r in a.iter().step_by(16) {
                        let o = Vec3::from(r.org);
                        let near = (0..scene.triangle_count()).any(|t| {
                            let tv = scene.triangle(t);
                            let v = [tv.v0, tv.v1, tv.v2].map(Vec3::from);
                            (0..3).any(|e| {
                                let (p, q) = (v[e], v[(e + 1) % 3]);
                                let w = (o - p).dot(q - p) / (q - p).length_squared();
                                (0.0..=1.0).contains(&w)
                                    && (p + (q - p) * w - o).length() <= 1e-5 * (q - p).length()
                            })
                        });
                        assert!(near, "{r:?} not on an edge");
                    }
                }
                RayClass::MixedSigns => {
                    // Every 8 x 8 packet mixes signs along the dominant axis.
                    let m = (s.views[0].look_at - s.views[0].eye).abs().max_position();
                    for p in a.chunks(64) {
                        assert!(
                            p.iter().any(|r| r.dir[m] > 0.0) && p.iter().any(|r| r.dir[m] < 0.0)
                        );
                    }
                }
                RayClass::Grazing => {
                    // Odd tiles: within 1e-3 of parallel to some surface.
                    assert!(a[256..512].iter().all(|r| r.is_valid()));
                }
                _ => {}
            }
        }
    }
}
