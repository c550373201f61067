//! Bounding frusta of large ray packets (Overbeck, Ramamoorthi, Mark 2008,
//! section 4), for culling boxes and triangles a whole packet misses. The
//! BVH packets cull with them; the kd-tree packets and the entry-point
//! searches (MLRTA, AEPSA) use them as the "ray proxy frustum".
//!
//! A frustum is four side planes `(n_i, b_i)`; a point `p` lies outside
//! plane `i` when `H_i = n_i . p - b_i > 0` (Eq. 1), and a box or triangle
//! with all its vertices outside one plane is culled. The planes come from
//! four corner rays (Eq. 2 and 3):
//!
//! - `from_primary` (4.1): the packet's own corner rays, for the n x n
//!   camera packets the renderer packs (quads in Morton order, see
//!   `render::demorton`).
//! - `from_common_origin` (4.2, point-light shadow rays traced from the
//!   light): dominant axis `k` of the direction sum, the extents of
//!   `(u, v) = (d_u / d_k, d_v / d_k)`, corner rays from the shared origin.
//! - `from_general` (4.3, reflection and refraction rays): a near plane at
//!   the origins' box and a far plane at the scene's box along `k`, the
//!   rays' `(u, v)` extents on both, corner rays from the near rectangle to
//!   the far one.
//!
//! Frusta with a common apex also cull triangles by the corner-ray test:
//! all four corner rays outside the same edge plane of the triangle (the
//! plane through the apex and the edge) means every ray of the packet
//! misses it (Dmitriev et al. 2004; Reshetov 2007).
//!
//! # Exactness
//! Culling must never reject a box or triangle that some ray's f32 test
//! hits, or packet results would differ from single rays. A plane culls
//! only what lies beyond it by more than `margin`, `CULL_EPS` times the
//! magnitude of the scene's and the origins' coordinates: that covers the
//! rounding of the f32 ray-triangle tests (which may report a hit for a
//! line passing a few ulps of the coordinates beside a triangle). The
//! `(u, v)` extents are computed 4-wide in f32 and then widened by a bound
//! on their rounding, so every ray lies inside the planes; planes, corner
//! rays and the corner-ray test are f64; the plane tests run 4-wide in f32
//! against the margin plus a bound on their own rounding. The boxes a
//! traversal tests contain their triangles, so a box culled by a plane has
//! all its triangles culled by it too. The corner-ray test needs an angular
//! separation that, at the triangle's distance from the apex, exceeds twice
//! the margin (see `cull_by_corners`).
//!
//! # Deviations
//! - The side planes of the common-origin and general frusta are built
//!   directly from the `(u, v)` extents and their change per unit of `k`
//!   (Eq. 2 simplified: adjacent corner rays share an extreme, so
//!   `d_i x d_(i+1)` is a multiple of `(-1, 0, slope)` in `(u, v, k)`
//!   coordinates), which stays well defined for parallel rays, where
//!   Eq. 2 degenerates to a zero normal.
//! - `from_primary` checks that every active ray lies inside its corner
//!   frustum (to a tolerance far below the margin, which absorbs the
//!   rounding of camera rays) and that all share the origin; otherwise the
//!   packet is not a pinhole packet and gets the `Auto` frustum.
//! - The general frustum's near and far planes are moved out by the margin
//!   (hits within rounding of a ray's origin or of the scene box stay inside).
//! - `RayKind::Shadow` packets whose rays do not share an origin get the
//!   general frustum (as `Auto`), not none.
//! - Boxes are culled by the planes only (not by the corner rays' slab
//!   test of Reshetov et al. 2005); the corner-ray triangle test is used
//!   only where the rays share an apex, as section 4.2's frusta.
//! - The dominant axis is that of the largest `|d^s|` component (the paper
//!   writes `max(d^s_x, d^s_y, d^s_z)`; the sign gives the `+-1`).

// `!(x > 0.0)` and the like are deliberate: NaN must fail the test.
#![allow(clippy::neg_cmp_op_on_partial_ord)]

use crate::geom::{Aabb, F4, M4, Ray4, TriVerts};

/// Which frustum a packet gets (section 4). `Auto` picks the common-origin
/// frustum (4.2) when all active rays share their origin, else the
/// near/far-plane frustum (4.3).
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum RayKind {
    #[default]
    Auto = 0,
    /// Camera rays of an n x n pixel packet (lanes as the renderer packs
    /// them): the frustum of the 4 corner rays (4.1). Full packets only;
    /// others fall back to `Auto`.
    Primary = 1,
    /// Rays from one point light (4.2).
    Shadow = 2,
    /// Reflection or refraction rays (4.3).
    Secondary = 3,
}

use crate::math;

/// Relative culling margin: a plane culls only what lies beyond it by more
/// than `CULL_EPS` times the largest coordinate magnitude of the scene box
/// and the ray origins. f32 triangle tests err by a few ulps (6e-8) of
/// that magnitude; the margin is ~1000 times larger, and at packet widths
/// of a pixel or more it costs no measurable culling.
pub const CULL_EPS: f64 = 1e-4;

/// Relative rounding allowance of the f32 parts (extents, plane tests):
/// ~16 ulps.
const F32_ERR: f64 = 1e-6;

type V3 = [f64; 3];

#[inline(always)]
fn dot(a: V3, b: V3) -> f64 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}
#[inline(always)]
fn cross(a: V3, b: V3) -> V3 {
    [
        a[1] * b[2] - a[2] * b[1],
        a[2] * b[0] - a[0] * b[2],
        a[0] * b[1] - a[1] * b[0],
    ]
}
#[inline(always)]
fn sub(a: V3, b: V3) -> V3 {
    [a[0] - b[0], a[1] - b[1], a[2] - b[2]]
}
#[inline(always)]
fn norm(a: V3) -> f64 {
    math::sqrt64(dot(a, a))
}
#[inline(always)]
fn unit(a: V3) -> Option<V3> {
    let l = norm(a);
    (l > 0.0 && l.is_finite()).then(|| [a[0] / l, a[1] / l, a[2] / l])
}
#[inline(always)]
fn v3(p: [f32; 3]) -> V3 {
    [p[0] as f64, p[1] as f64, p[2] as f64]
}

/// Which construction produced a frustum.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum FrustumKind {
    /// Section 4.1: the packet's corner rays.
    Primary,
    /// Section 4.2: `(u, v)` extents from a shared origin.
    CommonOrigin,
    /// Section 4.3: near and far planes.
    General,
}

/// Apex data of a frustum whose rays share one origin (corner-ray test).
#[derive(Clone, Copy, Debug)]
struct Apex {
    o: V3,
    /// Unit corner directions.
    c: [V3; 4],
    /// How far (as the sine of an angle) a ray may lie outside the corner
    /// cone (rounding of camera rays; 0 for `CommonOrigin`).
    slack: f64,
}

/// Four side planes around a packet (see the module docs).
#[derive(Clone, Copy, Debug)]
pub struct Frustum {
    pub kind: FrustumKind,
    /// Outward unit normals `n_i` (Eq. 2, normalised).
    pub n: [V3; 4],
    /// Offsets `b_i` (Eq. 3, normalised with `n_i`).
    pub b: [f64; 4],
    /// `H_i` beyond which a point counts as outside (see Exactness).
    pub margin: f64,
    /// `CULL_EPS` times the scene's coordinate magnitude (the margin of a
    /// frustum whose rays lie exactly inside it).
    pub eps: f64,
    /// The planes 4-wide (lane i = plane i) in f32, for Eq. 1.
    nx: F4,
    ny: F4,
    nz: F4,
    b4: F4,
    /// Planes whose normal is positive on x, y, z: their n-vertex (the box
    /// corner with the least `H`) takes the box's min there, else its max.
    pos: [M4; 3],
    /// `margin` plus the rounding bound of the f32 plane test.
    margin4: F4,
    apex: Option<Apex>,
}

#[inline(always)]
fn splat3(o: [f32; 3]) -> [F4; 3] {
    [F4::splat(o[0]), F4::splat(o[1]), F4::splat(o[2])]
}

/// The origin every live lane shares (bitwise-equal values), if any.
pub fn common_origin(rays: &[Ray4], live: &[M4]) -> Option<[f32; 3]> {
    let q = live.iter().position(|m| m.any())?;
    let i = live[q].bitmask().trailing_zeros() as usize;
    let o = [rays[q].org[0][i], rays[q].org[1][i], rays[q].org[2][i]];
    let s = splat3(o);
    let same = rays.iter().zip(live).all(|(r, m)| {
        let eq = r.org[0].cmpeq(s[0]) & r.org[1].cmpeq(s[1]) & r.org[2].cmpeq(s[2]);
        (*m & !eq).bitmask() == 0
    });
    same.then_some(o)
}

/// `scale` when every live origin is `o`.
fn scale_of(bounds: &Aabb, o: [f32; 3]) -> f64 {
    let s = bounds.min.abs().max(bounds.max.abs()).max_element();
    let a = o[0].abs().max(o[1].abs()).max(o[2].abs());
    (s.max(a) as f64).max(f32::MIN_POSITIVE as f64)
}

/// Largest coordinate magnitude of the scene box and the live origins.
fn scale(bounds: &Aabb, rays: &[Ray4], live: &[M4]) -> f64 {
    let mut s = bounds.min.abs().max(bounds.max.abs()).max_element();
    for (r, m) in rays.iter().zip(live) {
        let a = r.org[0].abs().max(r.org[1].abs()).max(r.org[2].abs());
        s = s.max(F4::select(*m, a, F4::ZERO).max_element());
    }
    // A floor keeps the margin positive for a scene at the origin's ulp scale.
    (s as f64).max(f32::MIN_POSITIVE as f64)
}

/// Dominant axis `k` of the live lanes' direction sum and its sign (`None`
/// when zero or not finite).
fn dominant_axis(rays: &[Ray4], live: &[M4]) -> Option<(usize, f32)> {
    let mut s = [F4::ZERO; 3];
    for (r, m) in rays.iter().zip(live) {
        for (sa, da) in s.iter_mut().zip(&r.dir) {
            *sa += F4::select(*m, *da, F4::ZERO);
        }
    }
    let s = [s[0].element_sum(), s[1].element_sum(), s[2].element_sum()];
    let a = [s[0].abs(), s[1].abs(), s[2].abs()];
    let k = if a[0] >= a[1] && a[0] >= a[2] {
        0
    } else if a[1] >= a[2] {
        1
    } else {
        2
    };
    if !(a[k] > 0.0 && a[k].is_finite()) {
        return None;
    }
    Some((k, if s[k] > 0.0 { 1.0 } else { -1.0 }))
}

/// Masked lane minimum and maximum of `x`, accumulated into `ext`.
#[inline(always)]
fn extend(ext: &mut [f32; 2], m: M4, x: F4) {
    ext[0] = ext[0].min(F4::select(m, x, F4::INFINITY).min_element());
    ext[1] = ext[1].max(F4::select(m, x, F4::NEG_INFINITY).max_element());
}

/// Morton index of quad (x, y) (x in the even bits, as `render::demorton`).
#[inline]
fn morton(x: usize, y: usize) -> usize {
    let mut i = 0;
    for b in 0..8 {
        i |= ((x >> b) & 1) << (2 * b) | ((y >> b) & 1) << (2 * b + 1);
    }
    i
}

impl Frustum {
    /// The frustum `kind` asks for, or `None` when none can be built (the
    /// packet is then traced without culling). `live` marks the lanes to
    /// bound (active and valid: `Ray::is_valid`); `bounds` is the scene's
    /// (root) box.
    pub fn new(kind: RayKind, rays: &[Ray4], live: &[M4], bounds: &Aabb) -> Option<Frustum> {
        let n = rays.len().min(live.len());
        let (rays, live) = (&rays[..n], &live[..n]);
        if bounds.is_empty() || !live.iter().any(|m| m.any()) {
            return None;
        }
        match kind {
            RayKind::Primary => {
                Self::from_primary(rays, live, bounds).or_else(|| Self::auto(rays, live, bounds))
            }
            // Point-light shadow rays share the light as origin; when they
            // do not, Auto picks the general frustum.
            RayKind::Auto | RayKind::Shadow => Self::auto(rays, live, bounds),
            RayKind::Secondary => Self::from_general(rays, live, bounds),
        }
    }

    /// `Auto`: the common-origin frustum when every live ray starts at the
    /// same point, else the general one.
    pub fn auto(rays: &[Ray4], live: &[M4], bounds: &Aabb) -> Option<Frustum> {
        match common_origin(rays, live) {
            Some(o) => Self::common(o, rays, live, bounds),
            None => Self::from_general(rays, live, bounds),
        }
    }

    /// Section 4.1: the corner rays of an n x n camera packet of
    /// `rays.len()` = 1, 4, 16, 64 or 256 quads in Morton order (lanes as in
    /// `Ray4`). `None` unless the four corner lanes are live, every live ray
    /// shares their origin and lies inside their frustum.
    pub fn from_primary(rays: &[Ray4], live: &[M4], bounds: &Aabb) -> Option<Frustum> {
        let nq = rays.len().min(live.len());
        let side = nq.isqrt();
        if nq == 0 || side * side != nq || !side.is_power_of_two() {
            return None;
        }
        let s = side - 1;
        // Cyclic order TL, TR, BR, BL: (quad, lane).
        let corners = [
            (0, 0),
            (morton(s, 0), 1),
            (morton(s, s), 3),
            (morton(0, s), 2),
        ];
        if corners.iter().any(|&(q, i)| !live[q].test(i)) {
            return None;
        }
        let o32 = common_origin(&rays[..nq], &live[..nq])?;
        let o = v3(o32);
        let mut c = [[0.0; 3]; 4];
        for (j, &(q, i)) in corners.iter().enumerate() {
            c[j] = unit([
                rays[q].dir[0][i] as f64,
                rays[q].dir[1][i] as f64,
                rays[q].dir[2][i] as f64,
            ])?;
        }
        let inside = [
            c[0][0] + c[1][0] + c[2][0] + c[3][0],
            c[0][1] + c[1][1] + c[2][1] + c[3][1],
            c[0][2] + c[1][2] + c[2][2] + c[3][2],
        ];
        let mut n = [[0.0; 3]; 4];
        let mut b = [0.0; 4];
        for i in 0..4 {
            // Eq. 2: n_i = d_i x d_(i+1); Eq. 3: b_i = o_i . n_i.
            let mut ni = unit(cross(c[i], c[(i + 1) % 4]))?;
            // Outward: the cone's axis lies inside.
            let h = dot(ni, inside);
            if h > 0.0 {
                ni = [-ni[0], -ni[1], -ni[2]];
            } else if !(h < 0.0) {
                return None;
            }
            // A convex cone: the two corners off the plane lie strictly inside.
            if !(dot(ni, c[(i + 2) % 4]) < 0.0 && dot(ni, c[(i + 3) % 4]) < 0.0) {
                return None;
            }
            n[i] = ni;
            b[i] = dot(o, ni);
        }
        // `scale` of the live origins, which all equal `o32`.
        let sc = scale_of(bounds, o32);
        let eps = CULL_EPS * sc;
        // Farthest scene point from the apex: rays may stray outside the
        // cone by an angle `slack` only as far as that costs less than a
        // tenth of the margin there.
        let mut far2 = 0.0f64;
        for (a, oa) in o.iter().enumerate() {
            let g = (bounds.min[a] as f64 - oa)
                .abs()
                .max((bounds.max[a] as f64 - oa).abs());
            far2 += g * g;
        }
        let far = math::sqrt64(far2);
        let tol = 0.1 * eps / far.max(eps);
        // Every live ray inside, 4-wide in f32: x = max_i n_i . d / |d|, the
        // sine of the largest angle by which a ray leaves a plane (squared
        // here, its root taken once). With unit n_i the f32 value errs by
        // less than F32_ERR (~10 ulps: the rounding of n_i, the dot product,
        // the norm and the quotient), so `x + F32_ERR` bounds the true
        // angle; rays beyond `tol`, and norms that overflow or vanish, give
        // no frustum.
        let nf = n.map(|ni| ni.map(|x| F4::splat(x as f32)));
        let tol2 = F4::splat((tol * tol) as f32);
        let mut worst2 = F4::ZERO;
        for (r, m) in rays[..nq].iter().zip(&live[..nq]) {
            let d = &r.dir;
            let dot = |ni: &[F4; 3]| d[0] * ni[0] + d[1] * ni[1] + d[2] * ni[2];
            let x = dot(&nf[0])
                .max(dot(&nf[1]))
                .max(dot(&nf[2]).max(dot(&nf[3])));
            let out = (x.cmpgt(F4::ZERO) | x.is_nan_mask()) & *m;
            if out.any() {
                let len2 = d[0] * d[0] + d[1] * d[1] + d[2] * d[2];
                let xs2 = x * x / len2;
                let ok = xs2.cmple(tol2) & len2.cmplt(F4::INFINITY) & len2.cmpgt(F4::ZERO);
                if (out & !ok).any() {
                    return None;
                }
                worst2 = F4::select(out, worst2.max(xs2), worst2);
            }
        }
        // One F32_ERR for the f32 angle, one for the f32 plane tests.
        let slack = math::sqrt64(worst2.max_element() as f64) + 2.0 * F32_ERR;
        // Rays outside the planes by at most `slack` lie within about
        // `4 slack` of the corner cone (its corners are far from flat).
        Some(Self::finish(
            FrustumKind::Primary,
            n,
            b,
            sc,
            eps + slack * far,
            Some(Apex {
                o,
                c,
                slack: 4.0 * slack,
            }),
        ))
    }

    /// Section 4.2: live rays from one origin, bounded by their `(u, v)`
    /// extents along the dominant axis `k` of their direction sum. `None`
    /// without a common origin, or when some ray's `d_k` is zero or points
    /// against the sum.
    pub fn from_common_origin(rays: &[Ray4], live: &[M4], bounds: &Aabb) -> Option<Frustum> {
        Self::common(common_origin(rays, live)?, rays, live, bounds)
    }

    fn common(o32: [f32; 3], rays: &[Ray4], live: &[M4], bounds: &Aabb) -> Option<Frustum> {
        let o = v3(o32);
        let (k, sg) = dominant_axis(rays, live)?;
        let (u, v) = ((k + 1) % 3, (k + 2) % 3);
        // Slopes per unit of travel along k: (d_u, d_v) / |d_k|.
        let (mut eu, mut ev) = (
            [f32::INFINITY, f32::NEG_INFINITY],
            [f32::INFINITY, f32::NEG_INFINITY],
        );
        for (r, m) in rays.iter().zip(live) {
            if !m.any() {
                continue;
            }
            let dk = r.dir[k] * F4::splat(sg);
            if (*m & !dk.cmpgt(F4::ZERO)).any() {
                return None;
            }
            extend(&mut eu, *m, r.dir[u] / dk);
            extend(&mut ev, *m, r.dir[v] / dk);
        }
        // A correctly rounded quotient errs by half an ulp: widen.
        let w = |x: f32, s: f64| x as f64 + s * F32_ERR * (1.0 + (x as f64).abs());
        let ext = [w(eu[0], -1.0), w(eu[1], 1.0), w(ev[0], -1.0), w(ev[1], 1.0)];
        if !ext.iter().all(|x| x.is_finite()) {
            return None;
        }
        let sg = sg as f64;
        let (n, b) = side_planes(k, sg, o[k], [o[u], o[u], o[v], o[v]], ext);
        // Corner directions (u, v, k) = (slope_u, slope_v, +-1), cyclic.
        let corner = |su: f64, sv: f64| {
            let mut c = [0.0; 3];
            c[k] = sg;
            c[u] = su;
            c[v] = sv;
            unit(c)
        };
        let c = [
            corner(ext[0], ext[2])?,
            corner(ext[1], ext[2])?,
            corner(ext[1], ext[3])?,
            corner(ext[0], ext[3])?,
        ];
        let sc = scale_of(bounds, o32);
        Some(Self::finish(
            FrustumKind::CommonOrigin,
            n,
            b,
            sc,
            CULL_EPS * sc,
            Some(Apex { o, c, slack: 0.0 }),
        ))
    }

    /// Section 4.3: any live rays moving the same way along the dominant
    /// axis `k`: their `(u, v)` extents on a near plane (behind the origins'
    /// box) and a far plane (beyond the scene box). `None` when some ray's
    /// `d_k` is zero or points against the sum, or the planes coincide.
    pub fn from_general(rays: &[Ray4], live: &[M4], bounds: &Aabb) -> Option<Frustum> {
        let (k, sg) = dominant_axis(rays, live)?;
        let (u, v) = ((k + 1) % 3, (k + 2) % 3);
        let sc = scale(bounds, rays, live);
        let eps = CULL_EPS * sc;
        // Near plane: the origins' box along -k (travel frame); far plane:
        // the scene box along +k. Both moved out by the margin, and kept in
        // f32 (exactly representable) as the extents are computed in f32.
        let mut onear = f32::INFINITY;
        let mut smax = 0.0f32;
        let sgv = F4::splat(sg);
        for (r, m) in rays.iter().zip(live) {
            if !m.any() {
                continue;
            }
            if (*m & !(r.dir[k] * sgv).cmpgt(F4::ZERO)).any() {
                return None;
            }
            onear = onear.min(F4::select(*m, r.org[k] * sgv, F4::INFINITY).min_element());
            let su = (r.dir[u] / r.dir[k]).abs().max((r.dir[v] / r.dir[k]).abs());
            smax = smax.max(F4::select(*m, su, F4::ZERO).max_element());
        }
        let k_near = (sg as f64 * (onear as f64 - eps)) as f32;
        let k_far = (if sg > 0.0 {
            bounds.max[k] as f64 + eps
        } else {
            bounds.min[k] as f64 - eps
        }) as f32;
        let delta = (k_far as f64 - k_near as f64) * sg as f64;
        if !(delta > 0.0 && delta.is_finite() && smax.is_finite()) {
            return None;
        }
        // (u, v) extents on both planes.
        let (kn, kf) = (F4::splat(k_near), F4::splat(k_far));
        let mut e = [[f32::INFINITY, f32::NEG_INFINITY]; 4];
        for (r, m) in rays.iter().zip(live) {
            if !m.any() {
                continue;
            }
            let (su, sv) = (r.dir[u] / r.dir[k], r.dir[v] / r.dir[k]);
            extend(&mut e[0], *m, r.org[u] + (kn - r.org[k]) * su);
            extend(&mut e[1], *m, r.org[v] + (kn - r.org[k]) * sv);
            extend(&mut e[2], *m, r.org[u] + (kf - r.org[k]) * su);
            extend(&mut e[3], *m, r.org[v] + (kf - r.org[k]) * sv);
        }
        // Rounding of the f32 extents: a few ulps of the origins' and the
        // planes' coordinates, the distance between them times the slope.
        let span = sc + 2.0 * delta;
        let w = F32_ERR * (sc + span * (1.0 + smax as f64));
        let lo = |x: f32| x as f64 - w;
        let hi = |x: f32| x as f64 + w;
        let near = [lo(e[0][0]), hi(e[0][1]), lo(e[1][0]), hi(e[1][1])];
        let far = [lo(e[2][0]), hi(e[2][1]), lo(e[3][0]), hi(e[3][1])];
        if !near.iter().chain(far.iter()).all(|x| x.is_finite()) {
            return None;
        }
        // Corner rays run from near[j] to far[j]: slope per unit of travel.
        let slope = [
            (far[0] - near[0]) / delta,
            (far[1] - near[1]) / delta,
            (far[2] - near[2]) / delta,
            (far[3] - near[3]) / delta,
        ];
        let (n, b) = side_planes(k, sg as f64, k_near as f64, near, slope);
        Some(Self::finish(FrustumKind::General, n, b, sc, eps, None))
    }

    /// `sc`: the scale (see `scale`); `margin`: the plane margin.
    fn finish(
        kind: FrustumKind,
        n: [V3; 4],
        b: [f64; 4],
        sc: f64,
        margin: f64,
        apex: Option<Apex>,
    ) -> Frustum {
        let lanes =
            |f: &dyn Fn(usize) -> f64| F4::new(f(0) as f32, f(1) as f32, f(2) as f32, f(3) as f32);
        let nx = lanes(&|i| n[i][0]);
        let ny = lanes(&|i| n[i][1]);
        let nz = lanes(&|i| n[i][2]);
        // The f32 plane test: unit normals, points and offsets of magnitude
        // up to the scale plus |b|, a few roundings each.
        let bmax = b.iter().fold(0.0f64, |m, x| m.max(x.abs()));
        let err = F32_ERR * (4.0 * sc + bmax);
        Frustum {
            kind,
            n,
            b,
            margin,
            eps: CULL_EPS * sc,
            nx,
            ny,
            nz,
            b4: lanes(&|i| b[i]),
            pos: [nx.cmpgt(F4::ZERO), ny.cmpgt(F4::ZERO), nz.cmpgt(F4::ZERO)],
            margin4: F4::splat((margin + err) as f32),
            apex,
        }
    }

    /// Signed distance of `p` beyond plane `i` (Eq. 1 with unit normals).
    #[inline(always)]
    pub fn h(&self, i: usize, p: V3) -> f64 {
        dot(self.n[i], p) - self.b[i]
    }

    /// Eq. 1 for point `p` and the four planes at once (lane i = plane i).
    #[inline(always)]
    fn h4(&self, p: [F4; 3]) -> F4 {
        self.nx * p[0] + self.ny * p[1] + self.nz * p[2] - self.b4
    }

    /// Whether the box `min..max` lies entirely outside one plane (Eq. 1 at
    /// the box corner nearest the inside, the "n-vertex"), beyond the margin.
    #[inline]
    pub fn cull_box(&self, min: &[f32; 3], max: &[f32; 3]) -> bool {
        let p = [
            F4::select(self.pos[0], F4::splat(min[0]), F4::splat(max[0])),
            F4::select(self.pos[1], F4::splat(min[1]), F4::splat(max[1])),
            F4::select(self.pos[2], F4::splat(min[2]), F4::splat(max[2])),
        ];
        self.h4(p).cmpgt(self.margin4).any()
    }

    /// Whether all three vertices of `t` lie beyond one of the four planes
    /// (Eq. 1 only; the AEPSA paper's four-plane test, section 3.1).
    #[inline]
    pub fn cull_triangle_planes(&self, t: &TriVerts) -> bool {
        let m = self.margin4;
        (self.h4(splat3(t.v0)).cmpgt(m)
            & self.h4(splat3(t.v1)).cmpgt(m)
            & self.h4(splat3(t.v2)).cmpgt(m))
        .any()
    }

    /// Whether every ray of the packet misses triangle `t`: all three
    /// vertices beyond one plane (Eq. 1), or, for a common apex, all four
    /// corner rays beyond one edge plane.
    #[inline]
    pub fn cull_triangle(&self, t: &TriVerts) -> bool {
        let m = self.margin4;
        let out = self.h4(splat3(t.v0)).cmpgt(m)
            & self.h4(splat3(t.v1)).cmpgt(m)
            & self.h4(splat3(t.v2)).cmpgt(m);
        if out.any() {
            return true;
        }
        match &self.apex {
            Some(a) => self.cull_by_corners(a, &[v3(t.v0), v3(t.v1), v3(t.v2)]),
            None => false,
        }
    }

    /// The corner-ray test. With `e` an edge plane's normal pointing to the
    /// triangle's side and `m = max_j e . c_j / |e|` over the unit corner
    /// directions, every ray direction `d` in the corner cone has
    /// `e . d / (|e| |d|) <= m`, so a ray point at distance `r` from the
    /// apex lies `-m r` outside the plane, while points within the margin
    /// `eps` of the triangle lie at most `eps` outside it. A ray can then
    /// come within `eps` of the triangle only where `r <= eps / -m`, and
    /// the triangle lies at least `R` (its box's distance) from the apex:
    /// culling is safe when `(-m - slack) R > 2 eps`.
    fn cull_by_corners(&self, a: &Apex, p: &[V3; 3]) -> bool {
        let v = [sub(p[0], a.o), sub(p[1], a.o), sub(p[2], a.o)];
        // Distance from the apex to the triangle's box.
        let mut r2 = 0.0;
        for ((a, b), c) in v[0].iter().zip(&v[1]).zip(&v[2]) {
            let (lo, hi) = (a.min(*b).min(*c), a.max(*b).max(*c));
            let g = if lo > 0.0 {
                lo
            } else if hi < 0.0 {
                -hi
            } else {
                0.0
            };
            r2 += g * g;
        }
        let eps = self.eps;
        if !(r2 > 4.0 * eps * eps) {
            return false;
        }
        let e = [cross(v[0], v[1]), cross(v[1], v[2]), cross(v[2], v[0])];
        // Triple product: e[0] . v[2] = e[1] . v[0] = e[2] . v[1].
        let sigma = dot(e[1], v[0]);
        if sigma == 0.0 || !sigma.is_finite() {
            return false;
        }
        // Cull when, for one edge, -m > |e| (slack + 2 eps / R).
        let need = a.slack + 2.0 * eps / math::sqrt64(r2);
        for ei in &e {
            let mut m = f64::NEG_INFINITY;
            for c in &a.c {
                m = m.max(dot(*ei, *c) * sigma.signum());
            }
            if m < 0.0 && m * m > dot(*ei, *ei) * need * need {
                return true;
            }
        }
        false
    }
}

/// Eq. 2 and 3 for frusta bounded by `(u, v)` extents along axis `k`
/// (travel direction `sg`): at `k = k0` the extents are `near = [u_min,
/// u_max, v_min, v_max]`, and each changes by `slope[j]` per unit of travel.
/// The plane of the `u_min` side holds the corner rays `(u_min, v_min)` and
/// `(u_min, v_max)`, whose cross product (Eq. 2) is a multiple of `(-1, 0,
/// sg slope)` in `(u, v, k)` coordinates; `b` is its dot product with a
/// corner origin (Eq. 3). Normals are returned outward and unit length.
fn side_planes(k: usize, sg: f64, k0: f64, near: [f64; 4], slope: [f64; 4]) -> ([V3; 4], [f64; 4]) {
    let (u, v) = ((k + 1) % 3, (k + 2) % 3);
    let mut n = [[0.0; 3]; 4];
    let mut b = [0.0; 4];
    for j in 0..4 {
        // j = 0: u_min, 1: u_max, 2: v_min, 3: v_max; outward is -u, +u, -v, +v.
        let (axis, out) = if j < 2 {
            (u, if j == 0 { -1.0 } else { 1.0 })
        } else {
            (v, if j == 2 { -1.0 } else { 1.0 })
        };
        let mut ni = [0.0; 3];
        ni[axis] = out;
        ni[k] = -out * sg * slope[j];
        let mut o = [0.0; 3];
        o[axis] = near[j];
        o[k] = k0;
        let l = norm(ni);
        n[j] = [ni[0] / l, ni[1] / l, ni[2] / l];
        b[j] = dot(o, ni) / l;
    }
    (n, b)
}

#[cfg(test)]
mod tests;
