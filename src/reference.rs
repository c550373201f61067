//! The reference oracle for tests and accuracy reports: brute force over
//! every traceable triangle, in f64.
//!
//! Besides the nearest hit it reports how close the decision was, so a
//! comparison can tell a real error from a legitimate disagreement:
//! `gap` (relative t distance to the second-nearest hit: a tie when tiny) and
//! `edge` (the smallest barycentric coordinate of the hit, and of any near
//! miss: the ray passes within that distance of an edge).
#![forbid(unsafe_code)]

use crate::geom::{INVALID_ID, Ray, Scene, TriVerts};

/// The oracle's answer for one ray.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct RefHit {
    /// Nearest triangle (`INVALID_ID`: miss) and its t.
    pub prim: u32,
    pub t: f64,
    /// Relative distance `(t2 - t) / t` to the second-nearest hit (inf if none).
    pub gap: f64,
    /// Smallest |barycentric| over the nearest hit and every near miss whose
    /// t is within the nearest hit's t (how near the ray passes an edge).
    pub edge: f64,
}

/// f64 Moller-Trumbore without rejection: (t, b0, b1, b2) or None if parallel.
fn mt64(o: [f64; 3], d: [f64; 3], tri: &TriVerts) -> Option<(f64, f64, f64, f64)> {
    let v = |p: [f32; 3]| [p[0] as f64, p[1] as f64, p[2] as f64];
    let (a, b, c) = (v(tri.v0), v(tri.v1), v(tri.v2));
    let sub = |x: [f64; 3], y: [f64; 3]| [x[0] - y[0], x[1] - y[1], x[2] - y[2]];
    let cross = |x: [f64; 3], y: [f64; 3]| {
        [
            x[1] * y[2] - x[2] * y[1],
            x[2] * y[0] - x[0] * y[2],
            x[0] * y[1] - x[1] * y[0],
        ]
    };
    let dot = |x: [f64; 3], y: [f64; 3]| x[0] * y[0] + x[1] * y[1] + x[2] * y[2];
    let e1 = sub(b, a);
    let e2 = sub(c, a);
    let p = cross(d, e2);
    let det = dot(e1, p);
    if det == 0.0 {
        return None;
    }
    let s = sub(o, a);
    let u = dot(s, p) / det;
    let q = cross(s, e1);
    let w = dot(d, q) / det;
    let t = dot(e2, q) / det;
    Some((t, 1.0 - u - w, u, w))
}

fn for_each_crossing(scene: &Scene<'_>, ray: &Ray, f: &mut dyn FnMut(u32, f64, f64)) {
    let o = [ray.org[0] as f64, ray.org[1] as f64, ray.org[2] as f64];
    let d = [ray.dir[0] as f64, ray.dir[1] as f64, ray.dir[2] as f64];
    for i in 0..scene.triangle_count() {
        let tri = scene.triangle(i);
        if Scene::classify(&tri).is_some() {
            continue;
        }
        if let Some((t, b0, b1, b2)) = mt64(o, d, &tri) {
            f(i, t, b0.min(b1).min(b2));
        }
    }
}

/// Brute-force nearest hit of `ray` in f64 over the traceable triangles of
/// `scene` (the same ones every structure stores). `edge` covers the hit
/// only; call `edge_distance` for the near misses in front of it (a second
/// pass, needed only when a method disagrees).
pub fn nearest(scene: &Scene<'_>, ray: &Ray) -> RefHit {
    let mut best = RefHit {
        prim: INVALID_ID,
        t: f64::INFINITY,
        gap: f64::INFINITY,
        edge: f64::INFINITY,
    };
    if !ray.is_valid() {
        return best;
    }
    let (tmin, tmax) = (ray.tmin as f64, ray.tmax as f64);
    let mut second = f64::INFINITY;
    for_each_crossing(scene, ray, &mut |i, t, minb| {
        if minb >= 0.0 && t >= tmin && t < tmax {
            if t < best.t || (t == best.t && i < best.prim) {
                second = second.min(best.t);
                best.prim = i;
                best.t = t;
                best.edge = minb;
            } else {
                second = second.min(t);
            }
        }
    });
    if best.prim != INVALID_ID {
        best.gap = if second.is_finite() {
            (second - best.t) / best.t.abs().max(1e-30)
        } else {
            f64::INFINITY
        };
    }
    best
}

/// `hit` with `edge` lowered to the smallest barycentric distance by which
/// `ray` misses any triangle in front of the hit (anywhere in `[tmin, tmax)`
/// for a miss): how near an f32 test is to deciding otherwise.
pub fn with_edge_distance(scene: &Scene<'_>, ray: &Ray, mut hit: RefHit) -> RefHit {
    if !ray.is_valid() {
        return hit;
    }
    let tmin = ray.tmin as f64;
    let limit = if hit.prim == INVALID_ID {
        ray.tmax as f64
    } else {
        hit.t
    };
    let mut edge = hit.edge;
    for_each_crossing(scene, ray, &mut |_, t, minb| {
        if minb < 0.0 && t >= tmin * (1.0 - 1e-6) && t <= limit * (1.0 + 1e-6) {
            edge = edge.min(-minb);
        }
    });
    hit.edge = edge;
    hit
}

// The oracle's named tolerances: each explains a disagreement between an
// f32 method and the f64 oracle (`judge`).

/// The oracle's two nearest hits within this relative t of each other:
/// either triangle is a right answer in f32.
pub const TIE_REL: f64 = 1e-5;
/// The oracle's hit, or a triangle in front of it, within this barycentric
/// distance of an edge: an f32 test may decide either way.
pub const EDGE_BARY: f64 = 1e-5;
/// On agreement, the f32 t within this relative distance of the f64 t.
pub const T_REL: f64 = 1e-4;
/// An f32 position's uncertainty as a fraction of the largest coordinate
/// magnitude involved (64 roundings; `cli/stress/tests/stress.rs` uses the same).
/// On agreement, the f32 t is also right within `POS_EPS` times the ray's
/// `t_scale`: a hit at the ray's origin has a t of rounding size (a
/// two-level ray moved into object space, a world triangle rounded to
/// f32), which no relative tolerance bounds (fuzz run 9: a hit at t
/// 1.1e-27 against the oracle's 0 on a triangle through the origin).
pub const POS_EPS: f64 = 64.0 * f32::EPSILON as f64;

/// The size at which an f32 test rounds the t of `ray` against `tri`: the
/// largest coordinate magnitude of the origin and the vertices (the hit
/// point lies in their box) over the direction's length.
pub fn t_scale(ray: &Ray, tri: &TriVerts) -> f64 {
    let big = |p: [f32; 3]| p.iter().fold(0.0f64, |m, &x| m.max((x as f64).abs()));
    let span = big(ray.org)
        .max(big(tri.v0))
        .max(big(tri.v1))
        .max(big(tri.v2));
    let d = ray.dir.map(|x| x as f64);
    span / libm::sqrt(d[0] * d[0] + d[1] * d[1] + d[2] * d[2])
}

/// How an f32 answer compares with the oracle's.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Verdict {
    /// The same triangle (or both miss), t within `T_REL` plus the
    /// position term `POS_EPS` (or near an edge).
    Exact,
    /// Another triangle within `TIE_REL` of the oracle's.
    Tie,
    /// Another answer, the ray within `EDGE_BARY` of an edge.
    Edge,
    /// The same triangle with t off by more than `T_REL` plus the position
    /// term, away from edges (the oracle's answer with its edge distance).
    WrongT(RefHit),
    /// Another answer that no tolerance explains.
    Wrong(RefHit),
}

/// Judge an f32 answer (`prim`, `t`) for `ray` against the oracle's `want`
/// (from `nearest` on the same `scene`), under the named tolerances.
pub fn judge(scene: &Scene<'_>, ray: &Ray, prim: u32, t: f32, want: RefHit) -> Verdict {
    // Only for a hit on the oracle's triangle.
    let t_ok = |want: &RefHit| {
        let pos = POS_EPS * t_scale(ray, &scene.triangle(want.prim));
        (t as f64 - want.t).abs() <= T_REL * want.t.abs() + pos
    };
    let mut want = want;
    if prim != want.prim || (prim != INVALID_ID && !t_ok(&want)) {
        want = with_edge_distance(scene, ray, want);
    }
    if prim == want.prim {
        if prim != INVALID_ID && !t_ok(&want) && want.edge > EDGE_BARY {
            return Verdict::WrongT(want);
        }
        Verdict::Exact
    } else if want.gap <= TIE_REL {
        Verdict::Tie
    } else if want.edge <= EDGE_BARY {
        Verdict::Edge
    } else {
        Verdict::Wrong(want)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Fuzz run 9's disagreement: a ray starting 5.6e-29 above a triangle
    /// in the plane y = 0 hits it at t 1.1e-27, which an f32 method that
    /// moved the ray (or the oracle's rounded world triangle) puts at 0.
    /// Both answers are right to rounding; a t off by far more than
    /// rounding, near the origin or not, is still wrong.
    #[test]
    fn a_hit_at_the_origin_is_judged_by_the_t_scale() {
        let verts = [-1.0, 0.0, -1.0, 1.0, 0.0, -1.0, 0.0, 0.0, 1.0];
        let scene = Scene::from_f32(&verts, &[0, 1, 2]).unwrap();
        let ray = Ray {
            org: [-0.375, 5.640_045_5e-29, 0.0],
            tmin: 0.0,
            dir: [0.325, -0.05, 0.0],
            tmax: f32::INFINITY,
        };
        let want = nearest(&scene, &ray);
        assert_eq!(want.prim, 0);
        assert!(want.t > 0.0 && want.t < 1e-26, "{want:?}");
        let scale = t_scale(&ray, &scene.triangle(0));
        assert!((3.0..3.1).contains(&scale), "{scale}");
        assert_eq!(judge(&scene, &ray, 0, want.t as f32, want), Verdict::Exact);
        assert_eq!(judge(&scene, &ray, 0, 0.0, want), Verdict::Exact);
        let at_origin = RefHit { t: 0.0, ..want };
        assert_eq!(judge(&scene, &ray, 0, 1.128e-27, at_origin), Verdict::Exact);
        // 1e-3 is about 40 times the position term at this ray's scale.
        assert!(matches!(
            judge(&scene, &ray, 0, 1e-3, want),
            Verdict::WrongT(_)
        ));
        // Far from the origin the relative tolerance still decides.
        let far = Ray {
            org: [-0.375, 5.0, 0.0],
            dir: [0.0, -1.0, 0.0],
            ..ray
        };
        let want = nearest(&scene, &far);
        assert_eq!(want.prim, 0);
        let t = want.t as f32;
        assert_eq!(judge(&scene, &far, 0, t, want), Verdict::Exact);
        assert!(matches!(
            judge(&scene, &far, 0, t * 1.001, want),
            Verdict::WrongT(_)
        ));
    }
}
