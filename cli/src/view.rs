//! Automatic views of a scene from its bounds and a few probe rays.
//!
//! - Outside: look at the bounds centre from direction (0.6, 0.45, 1.0) (for
//!   +Y up; rotated for another up), far enough that the bounding sphere
//!   fits the narrower of the two fields of view.
//! - Inside: eye at a quarter of the height, at the most open of a few
//!   candidate points along the longest horizontal axis, looking along that
//!   axis towards the farther side.
//! - Which one by default: inside when the scene encloses that eye (most
//!   probe rays hit) and the surfaces it sees face it (a room, modelled to
//!   be seen from within; from inside a closed object, such as the bunny,
//!   the surfaces face away).

use glam::{Quat, Vec3};
use sheaf::render::Tracer;
use sheaf::scenes::View;
use sheaf::{Camera, Counters, PointLight, Ray};

/// Default vertical field of view of the outside view (degrees).
pub const OUTSIDE_FOV: f32 = 45.0;
/// Default vertical field of view of the inside view (degrees).
pub const INSIDE_FOV: f32 = 60.0;

/// Probe directions (Fibonacci sphere): even coverage, deterministic.
const PROBES: usize = 128;

fn probe_dir(i: usize) -> Vec3 {
    let golden = std::f32::consts::PI * (3.0 - 5.0f32.sqrt());
    let z = 1.0 - 2.0 * (i as f32 + 0.5) / PROBES as f32;
    let r = (1.0 - z * z).max(0.0).sqrt();
    let (s, c) = (golden * i as f32).sin_cos();
    Vec3::new(r * c, r * s, z)
}

/// Outside view of bounds `(lo, hi)` with `up`, for an image of `aspect`
/// (width / height).
pub fn outside(lo: Vec3, hi: Vec3, up: Vec3, fov_y_deg: f32, aspect: f32) -> View {
    let up = up.normalize();
    let c = 0.5 * (lo + hi);
    let r = (0.5 * (hi - lo).length()).max(f32::MIN_POSITIVE);
    let dir = Quat::from_rotation_arc(Vec3::Y, up) * Vec3::new(0.6, 0.45, 1.0).normalize();
    let half_y = (fov_y_deg.to_radians() * 0.5).clamp(1e-3, 1.5);
    let half_x = (half_y.tan() * aspect).atan();
    let dist = r / half_y.min(half_x).sin();
    View {
        eye: c + dir * dist,
        look_at: c,
        up,
        fov_y_deg,
    }
}

/// Axis closest to `up`, and the longer of the two others.
fn axes(lo: Vec3, hi: Vec3, up: Vec3) -> (usize, usize) {
    let ua = up.abs().max_position();
    let (a, b) = ((ua + 1) % 3, (ua + 2) % 3);
    let ext = hi - lo;
    (ua, if ext[a] >= ext[b] { a } else { b })
}

/// Nearest hit along `d` from `p` (infinite on a miss) and whether the
/// surface faces the ray (its winding normal points against `d`).
fn probe<T: Tracer>(t: &T, p: Vec3, d: Vec3) -> (f32, bool) {
    let mut ctr = Counters::default();
    let h = t.intersect(&Ray::new(p, d, 0.0, f32::INFINITY), &mut ctr);
    if !h.is_hit() {
        return (f32::INFINITY, false);
    }
    let facing = t
        .triangle(h.prim)
        .is_some_and(|tri| tri.normal().dot(d) < 0.0);
    (h.t, facing)
}

/// Inside view: the candidate eye on the long horizontal axis with the most
/// clearance (distance to the nearest surface over the probe directions),
/// looking along the axis the more open way.
pub fn inside<T: Tracer>(t: &T, lo: Vec3, hi: Vec3, up: Vec3, fov_y_deg: f32) -> View {
    let up = up.normalize();
    let (ua, ha) = axes(lo, hi, up);
    let ext = hi - lo;
    let mut base = 0.5 * (lo + hi);
    // A quarter of the height, above the floor as `up` sees it.
    base[ua] = if up[ua] >= 0.0 {
        lo[ua] + 0.25 * ext[ua]
    } else {
        hi[ua] - 0.25 * ext[ua]
    };
    // Candidates from the centre outwards; a farther one wins only with strictly more clearance.
    let mut best = (f32::NEG_INFINITY, base);
    for k in [0i32, -1, 1, -2, 2, -3, 3, -4, 4] {
        let mut p = base;
        p[ha] += ext[ha] * 0.09 * k as f32;
        let clearance = (0..PROBES)
            .map(|i| probe(t, p, probe_dir(i)).0)
            .fold(f32::INFINITY, f32::min);
        if clearance > best.0 {
            best = (clearance, p);
        }
    }
    let eye = best.1;
    let mut axis = Vec3::ZERO;
    axis[ha] = 1.0;
    let open = |d: Vec3| probe(t, eye, d).0.min(ext[ha]);
    let dir = if open(axis) >= open(-axis) {
        axis
    } else {
        -axis
    };
    // Look slightly down, a quarter of the way along the axis.
    let look_at = eye + dir * (0.25 * ext[ha]) - up * (0.02 * ext[ha]);
    View {
        eye,
        look_at,
        up,
        fov_y_deg,
    }
}

/// Whether `eye` is inside a room: at least 70 % of the probe rays hit and
/// at least 60 % of the surfaces hit face the eye.
pub fn is_interior<T: Tracer>(t: &T, eye: Vec3) -> bool {
    let (mut hits, mut facing) = (0usize, 0usize);
    for i in 0..PROBES {
        let (d, f) = probe(t, eye, probe_dir(i));
        if d.is_finite() {
            hits += 1;
            facing += f as usize;
        }
    }
    hits * 10 >= PROBES * 7 && facing * 10 >= hits * 6
}

/// Default light for a view. Outside: above, behind and to the right of the
/// eye by a fraction of the view distance. Inside a room: from the eye
/// towards up-right-back, 60 % of the way to the first surface (at most
/// `0.15 * scale`), so it stays within the walls and under the ceiling.
pub fn light_for<T: Tracer>(t: &T, v: &View, interior: bool, scale: f32) -> PointLight {
    let back = (v.eye - v.look_at).normalize_or_zero();
    let up = v.up.normalize_or_zero();
    let right = (-back).cross(up).normalize_or_zero();
    let position = if interior {
        let d = (up + right * 0.3 + back * 0.2).normalize_or_zero();
        v.eye + d * (0.6 * probe(t, v.eye, d).0).min(0.15 * scale)
    } else {
        let d = (v.eye - v.look_at).length();
        v.eye + (up * 0.8 + right * 0.5 + back * 0.2) * (0.6 * d)
    };
    PointLight {
        position: position.to_array(),
        color: [1.0; 3],
        ..Default::default()
    }
}

/// The kernel's `Camera` for a view.
pub fn camera(v: &View) -> Camera {
    Camera {
        eye: v.eye.to_array(),
        look_at: v.look_at.to_array(),
        up: v.up.to_array(),
        fov_y_deg: v.fov_y_deg,
    }
}
