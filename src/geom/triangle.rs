//! Ray-triangle tests, written once over `Lane` so the single ray (`f32`)
//! and the 2x2 SIMD ray (`F4`) run the same arithmetic:
//!
//! - Moller and Trumbore 1997, "Fast, minimum storage ray-triangle
//!   intersection" (no per-triangle precomputation; determinant compared to
//!   exactly zero, no absolute epsilon).
//! - Woop, Benthin and Wald 2013, "Watertight ray/triangle intersection"
//!   (JCGT 2(1)): shear to ray space, 2D edge functions, f64 recomputation of
//!   edge functions that come out exactly zero (section 4 of the paper). A ray
//!   through a shared edge or vertex of a closed mesh hits at least one of the
//!   triangles.
//! - Wald 2004 ("Realtime Ray Tracing and Interactive Global Illumination",
//!   section 7.1), the precomputed projection test the CGT paper uses
//!   (section 3): per triangle, the plane as `k + n_u u + n_v v = n_d` along
//!   the normal's dominant axis k and the two barycentric coordinates as
//!   linear functions of the projected hit point; rebuilt with the grid.
//!
//! All three tests are two-sided and report `t` in `[tmin, tmax)` and the
//! barycentric weights `u` (second vertex) and `v` (third vertex).

use crate::geom::lane::{F4, Lane};
use crate::geom::wide::Wide;
use bytemuck::{Pod, Zeroable};

/// A triangle's three vertices, copied out of the caller's buffers at build.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Pod, Zeroable)]
pub struct TriVerts {
    pub v0: [f32; 3],
    pub v1: [f32; 3],
    pub v2: [f32; 3],
}

impl TriVerts {
    /// Geometric normal `(v1 - v0) x (v2 - v0)` (not normalised).
    #[inline]
    pub fn normal(&self) -> glam::Vec3 {
        let a = glam::Vec3::from(self.v0);
        (glam::Vec3::from(self.v1) - a).cross(glam::Vec3::from(self.v2) - a)
    }
}

/// Which ray-triangle test a structure uses (a build parameter).
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum TriTest {
    /// Moller-Trumbore: fastest setup, can leak through shared edges.
    #[default]
    MollerTrumbore = 0,
    /// Woop-Benthin-Wald watertight test.
    Watertight = 1,
    /// Wald 2004 precomputed projection test (48 bytes per triangle, filled
    /// at build; needs `Limits::projection_test`).
    Projection = 2,
}

/// `$body` with `$T` the triangle-test type `$test` (a `TriTest`) names
/// (`Mt`, `Wt`, `Pt`): the one match on the triangle test between a call
/// and a traversal, so each traversal is compiled once per test and picked
/// once per call (culling is a run-time value: `Cull::apply`).
macro_rules! with_test {
    ($test:expr, |$T:ident| $body:expr) => {
        match $test {
            $crate::geom::TriTest::MollerTrumbore => {
                type $T = $crate::geom::Mt;
                $body
            }
            $crate::geom::TriTest::Watertight => {
                type $T = $crate::geom::Wt;
                $body
            }
            $crate::geom::TriTest::Projection => {
                type $T = $crate::geom::Pt;
                $body
            }
        }
    };
}
pub(crate) use with_test;

/// Per-triangle data of the projection test (48 bytes, filled at build).
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Pod, Zeroable)]
pub struct ProjTri {
    /// Plane `p[k] + n_u p[u] + n_v p[v] = n_d`, `u = (k+1)%3`, `v = (k+2)%3`.
    pub n_u: f32,
    pub n_v: f32,
    pub n_d: f32,
    pub k: u32,
    /// Weight of the second vertex: `b_nu hu + b_nv hv + b_d`.
    pub b_nu: f32,
    pub b_nv: f32,
    pub b_d: f32,
    /// Weight of the third vertex: `c_nu hu + c_nv hv + c_d`.
    pub c_nu: f32,
    pub c_nv: f32,
    pub c_d: f32,
    /// 1 when the normal's `k` component is negative: the plane equation
    /// above is divided by it, so the winding's side is this sign times
    /// the equation's (`TriangleTest::facing`).
    pub neg_k: u32,
    pub pad: u32,
}

impl ProjTri {
    /// Precompute from the vertices (the triangle must have non-zero area).
    pub fn new(t: &TriVerts) -> ProjTri {
        let (a, b1, c1) = (t.v0, t.v1, t.v2);
        let e1 = [b1[0] - a[0], b1[1] - a[1], b1[2] - a[2]];
        let e2 = [c1[0] - a[0], c1[1] - a[1], c1[2] - a[2]];
        let n = cross3::<f32>(e1, e2);
        let an = [n[0].abs(), n[1].abs(), n[2].abs()];
        let k = if an[0] >= an[1] && an[0] >= an[2] {
            0
        } else if an[1] >= an[2] {
            1
        } else {
            2
        };
        let (u, v) = ((k + 1) % 3, (k + 2) % 3);
        // In the (u, v) projection: H - A = beta e1 + gamma e2.
        let det = e1[u] * e2[v] - e1[v] * e2[u];
        ProjTri {
            n_u: n[u] / n[k],
            n_v: n[v] / n[k],
            n_d: dot3::<f32>(n, a) / n[k],
            k: k as u32,
            b_nu: e2[v] / det,
            b_nv: -e2[u] / det,
            b_d: (e2[u] * a[v] - e2[v] * a[u]) / det,
            c_nu: -e1[v] / det,
            c_nv: e1[u] / det,
            c_d: (e1[v] * a[u] - e1[u] * a[v]) / det,
            neg_k: u32::from(n[k] < 0.0),
            pad: 0,
        }
    }
}

const _: () = assert!(core::mem::size_of::<ProjTri>() == 48);

/// Per-ray shear for the watertight test (WBW 2013, section 3, Fig. 1):
/// `kz` is the dominant axis of the direction, `kx`, `ky` the others (swapped
/// when `dir[kz] < 0` to keep the winding), `s = (dx/dz, dy/dz, 1/dz)`.
#[derive(Clone, Copy, Debug)]
pub struct Shear<L: Lane> {
    pub kx: L::Axis,
    pub ky: L::Axis,
    pub kz: L::Axis,
    pub s: [L; 3],
}

impl<L: Lane> Shear<L> {
    #[inline]
    pub fn new(d: [L; 3]) -> Self {
        let (k, s) = L::shear_axes(d);
        Shear {
            kx: k[0],
            ky: k[1],
            kz: k[2],
            s,
        }
    }
}

/// One ray or four, as the triangle tests read them.
#[derive(Clone, Copy, Debug)]
pub struct RayLanes<L: Lane> {
    pub org: [L; 3],
    pub dir: [L; 3],
    pub tmin: L,
    pub tmax: L,
}

/// Result of a test: which lanes hit inside `[tmin, tmax)`, and where.
#[derive(Clone, Copy, Debug)]
pub struct TriHit<L: Lane> {
    pub mask: L::Mask,
    pub t: L,
    pub u: L,
    pub v: L,
}

#[inline(always)]
fn sub3<L: Lane>(a: [L; 3], b: [L; 3]) -> [L; 3] {
    [a[0] - b[0], a[1] - b[1], a[2] - b[2]]
}
#[inline(always)]
fn cross3<L: Lane>(a: [L; 3], b: [L; 3]) -> [L; 3] {
    [
        a[1] * b[2] - a[2] * b[1],
        a[2] * b[0] - a[0] * b[2],
        a[0] * b[1] - a[1] * b[0],
    ]
}
#[inline(always)]
fn dot3<L: Lane>(a: [L; 3], b: [L; 3]) -> L {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}
#[inline(always)]
fn splat3<L: Lane>(v: [f32; 3]) -> [L; 3] {
    [L::splat(v[0]), L::splat(v[1]), L::splat(v[2])]
}

/// Moller-Trumbore, two-sided. Misses where the determinant is exactly zero
/// (ray parallel to the plane) or any quantity is NaN.
///
/// NOTE(perf): the barycentric bounds are checked on the numerators against
/// the determinant, before any division, and the test returns as soon as no
/// lane can hit (up to 4 lanes: `exits_early`): most tests in a grid cell reject at `u` (`cargo bench
/// --bench grid`, 3DDDA: sponza 1.52x, bunny 1.32x the rays/s of dividing first).
#[inline(always)]
pub fn moller_trumbore<L: Lane>(r: &RayLanes<L>, tri: &TriVerts) -> TriHit<L> {
    moller_trumbore_lanes(r, [splat3(tri.v0), splat3(tri.v1), splat3(tri.v2)])
}

/// Whether the triangle tests leave as soon as no lane can hit: for a
/// ray, a quad and 4-wide lanes. Eight and sixteen lanes compute on:
/// their early exits mispredict often enough to cost more than the
/// operations they skip (sponza, 16x16 frustum packets, AVX-512: camera
/// +2.6 %, shadow +3.5 %). The answers do not change: lanes outside the
/// mask are never read.
#[inline(always)]
const fn exits_early<L: Lane>() -> bool {
    L::WIDTH <= 4
}

/// `moller_trumbore` on vertices given lane by lane: one triangle per lane
/// against one ray splatted into every lane (`Tri4`), or one triangle
/// splatted against four rays. The same operations either way, so each
/// lane's result is bitwise the scalar test's.
#[inline(always)]
pub fn moller_trumbore_lanes<L: Lane>(r: &RayLanes<L>, tri: [[L; 3]; 3]) -> TriHit<L> {
    let zero = L::splat(0.0);
    let v0 = tri[0];
    let e1 = sub3(tri[1], v0);
    let e2 = sub3(tri[2], v0);
    let p = cross3(r.dir, e2);
    let det = dot3(e1, p);
    let s = sub3(r.org, v0);
    let un = dot3(s, p);
    // u = un / det in [0, 1], by the sign of det. NaN fails every comparison.
    let pos = zero.lt(det);
    let neg = det.lt(zero);
    let ok_u = (pos & zero.le(un) & un.le(det)) | (neg & det.le(un) & un.le(zero));
    if exits_early::<L>() && !L::any(ok_u) {
        return TriHit {
            mask: ok_u,
            t: zero,
            u: zero,
            v: zero,
        };
    }
    let q = cross3(s, e1);
    let vn = dot3(r.dir, q);
    let uvn = un + vn;
    let ok = ok_u & ((pos & zero.le(vn) & uvn.le(det)) | (neg & vn.le(zero) & det.le(uvn)));
    if exits_early::<L>() && !L::any(ok) {
        return TriHit {
            mask: ok,
            t: zero,
            u: zero,
            v: zero,
        };
    }
    let inv = L::splat(1.0) / det;
    let t = dot3(e2, q) * inv;
    let mask = ok & r.tmin.le(t) & t.lt(r.tmax);
    TriHit {
        mask,
        t,
        u: un * inv,
        v: vn * inv,
    }
}

/// Woop-Benthin-Wald watertight test, two-sided, with the ray's shear.
#[inline(always)]
pub fn watertight<L: Lane>(r: &RayLanes<L>, sh: &Shear<L>, tri: &TriVerts) -> TriHit<L> {
    watertight_lanes(r, sh, [splat3(tri.v0), splat3(tri.v1), splat3(tri.v2)])
}

/// `watertight` on vertices given lane by lane (see `moller_trumbore_lanes`).
#[inline(always)]
pub fn watertight_lanes<L: Lane>(r: &RayLanes<L>, sh: &Shear<L>, tri: [[L; 3]; 3]) -> TriHit<L> {
    // Vertices relative to the ray origin (WBW Fig. 1, lines "A = v0 - org" ...).
    let a = sub3(tri[0], r.org);
    let b = sub3(tri[1], r.org);
    let c = sub3(tri[2], r.org);
    let (az, bz, cz) = (L::pick(a, sh.kz), L::pick(b, sh.kz), L::pick(c, sh.kz));
    // Shear and scale.
    let ax = L::pick(a, sh.kx) - sh.s[0] * az;
    let ay = L::pick(a, sh.ky) - sh.s[1] * az;
    let bx = L::pick(b, sh.kx) - sh.s[0] * bz;
    let by = L::pick(b, sh.ky) - sh.s[1] * bz;
    let cx = L::pick(c, sh.kx) - sh.s[0] * cz;
    let cy = L::pick(c, sh.ky) - sh.s[1] * cz;
    // Scaled barycentric coordinates (2D edge functions).
    let mut u = cx * by - cy * bx;
    let mut v = ax * cy - ay * cx;
    let mut w = bx * ay - by * ax;
    let zero = L::splat(0.0);
    let any_zero = u.eq(zero) | v.eq(zero) | w.eq(zero);
    if L::any(any_zero) {
        // Section 4 of the paper: recompute edge functions that are exactly
        // zero in double precision, so edges shared by two triangles are
        // decided consistently.
        for i in 0..L::WIDTH {
            if L::mask_get(any_zero, i) {
                let f = |x: L| x.get(i) as f64;
                u.set(i, (f(cx) * f(by) - f(cy) * f(bx)) as f32);
                v.set(i, (f(ax) * f(cy) - f(ay) * f(cx)) as f32);
                w.set(i, (f(bx) * f(ay) - f(by) * f(ax)) as f32);
            }
        }
    }
    let neg = u.lt(zero) | v.lt(zero) | w.lt(zero);
    let pos = zero.lt(u) | zero.lt(v) | zero.lt(w);
    let det = u + v + w;
    let inside = !(neg & pos) & !det.eq(zero);
    if !L::any(inside) {
        return TriHit {
            mask: inside,
            t: zero,
            u: zero,
            v: zero,
        };
    }
    let t_scaled = u * (sh.s[2] * az) + v * (sh.s[2] * bz) + w * (sh.s[2] * cz);
    let t = t_scaled / det;
    let mask = inside & r.tmin.le(t) & t.lt(r.tmax);
    TriHit {
        mask,
        t,
        u: v / det,
        v: w / det,
    }
}

/// Wald 2004 projection test on precomputed `ProjTri` data. NaN (a ray
/// parallel to the plane) fails every comparison and so misses.
#[inline(always)]
pub fn projection<L: Lane>(r: &RayLanes<L>, w: &ProjTri) -> TriHit<L> {
    let zero = L::splat(0.0);
    let k = w.k as usize;
    let (u, v) = ((k + 1) % 3, (k + 2) % 3);
    let (nu, nv) = (L::splat(w.n_u), L::splat(w.n_v));
    let nd = L::splat(1.0) / (r.dir[k] + nu * r.dir[u] + nv * r.dir[v]);
    let t = (L::splat(w.n_d) - r.org[k] - nu * r.org[u] - nv * r.org[v]) * nd;
    let in_t = r.tmin.le(t) & t.lt(r.tmax);
    if !L::any(in_t) {
        return TriHit {
            mask: in_t,
            t,
            u: zero,
            v: zero,
        };
    }
    let hu = r.org[u] + t * r.dir[u];
    let hv = r.org[v] + t * r.dir[v];
    let beta = hu * L::splat(w.b_nu) + hv * L::splat(w.b_nv) + L::splat(w.b_d);
    let gamma = hu * L::splat(w.c_nu) + hv * L::splat(w.c_nv) + L::splat(w.c_d);
    let mask = in_t & zero.le(beta) & zero.le(gamma) & (beta + gamma).le(L::splat(1.0));
    TriHit {
        mask,
        t,
        u: beta,
        v: gamma,
    }
}

/// The stored triangles of a built structure (every family keeps the same
/// two arrays, indexed by the same slot): vertices, and the projection
/// test's precomputed data (empty unless that test was built for).
#[derive(Clone, Copy, Debug)]
pub struct TriStore<'r> {
    pub tris: &'r [TriVerts],
    pub proj: &'r [ProjTri],
}

/// A triangle test with its per-ray precomputation and its per-triangle
/// data, so traversals are monomorphised per test (no per-triangle branch on
/// the test kind).
pub trait TriangleTest: Copy + Default + Send + Sync + 'static {
    /// Per-ray data computed once before traversal.
    type Pre<L: Lane>: Copy;
    /// Per-triangle data the test reads (`TriVerts`, or precomputed data).
    type Prim: Copy;
    const KIND: TriTest;
    /// Where the test finds triangle `i`'s data in a family's store.
    fn prim<'r>(s: TriStore<'r>, i: usize) -> &'r Self::Prim;
    fn prepare<L: Lane>(r: &RayLanes<L>) -> Self::Pre<L>;
    fn intersect<L: Lane>(r: &RayLanes<L>, pre: &Self::Pre<L>, tri: &Self::Prim) -> TriHit<L>;
    /// `dir` dotted with triangle `tri`'s winding normal, up to a positive
    /// factor: negative when the ray meets its front (the side its
    /// counter-clockwise winding `(v1 - v0) x (v2 - v0)` faces), positive
    /// at its back (`Cull::apply`).
    fn facing<L: Lane>(dir: &[L; 3], tri: &Self::Prim) -> L;
    /// The precomputation of a group of quads (`Wide::join`) from each
    /// quad's: the same values, lane for lane.
    fn join_pre<W: Wide>(pre: impl Fn(usize) -> Self::Pre<F4>) -> Self::Pre<W>;
    /// Stored triangles `i[0..4]` against one ray splatted into four lanes
    /// (`r`, `pre` from `RayLanes::splat`), lane k testing triangle `i[k]`:
    /// bitwise the scalar test's results. The default tests them one by one.
    #[inline(always)]
    fn intersect_tri4(
        r: &RayLanes<F4>,
        pre: &Self::Pre<F4>,
        s: TriStore<'_>,
        i: [usize; 4],
    ) -> TriHit<F4> {
        let _ = pre;
        let l = RayLanes {
            org: r.org.map(|x| x.x),
            dir: r.dir.map(|x| x.x),
            tmin: r.tmin.x,
            tmax: r.tmax.x,
        };
        let p = Self::prepare(&l);
        let one = |k: usize| Self::intersect(&l, &p, Self::prim(s, i[k]));
        let h: [TriHit<f32>; 4] = core::array::from_fn(one);
        TriHit {
            mask: crate::geom::lane::mask_from_bits(
                h.iter()
                    .enumerate()
                    .fold(0, |m, (k, h)| m | (h.mask as u32) << k),
            ),
            t: F4::from_array(h.map(|h| h.t)),
            u: F4::from_array(h.map(|h| h.u)),
            v: F4::from_array(h.map(|h| h.v)),
        }
    }
}

/// Stored triangles `i[0..4]` one per lane.
#[inline(always)]
fn gather4(s: TriStore<'_>, i: [usize; 4]) -> [[F4; 3]; 3] {
    let t = i.map(|k| &s.tris[k]);
    let at = |v: fn(&TriVerts) -> &[f32; 3], a: usize| {
        F4::new(v(t[0])[a], v(t[1])[a], v(t[2])[a], v(t[3])[a])
    };
    let vert = |v: fn(&TriVerts) -> &[f32; 3]| [at(v, 0), at(v, 1), at(v, 2)];
    [vert(|t| &t.v0), vert(|t| &t.v1), vert(|t| &t.v2)]
}

/// Moller-Trumbore as a `TriangleTest`.
#[derive(Clone, Copy, Debug, Default)]
pub struct Mt;
/// Watertight as a `TriangleTest`.
#[derive(Clone, Copy, Debug, Default)]
pub struct Wt;
/// The projection test as a `TriangleTest`.
#[derive(Clone, Copy, Debug, Default)]
pub struct Pt;

impl TriangleTest for Mt {
    type Pre<L: Lane> = ();
    type Prim = TriVerts;
    const KIND: TriTest = TriTest::MollerTrumbore;
    #[inline(always)]
    fn prim<'r>(s: TriStore<'r>, i: usize) -> &'r TriVerts {
        &s.tris[i]
    }
    #[inline(always)]
    fn prepare<L: Lane>(_: &RayLanes<L>) {}
    #[inline(always)]
    fn intersect<L: Lane>(r: &RayLanes<L>, _: &(), tri: &TriVerts) -> TriHit<L> {
        moller_trumbore(r, tri)
    }
    #[inline(always)]
    fn facing<L: Lane>(dir: &[L; 3], tri: &TriVerts) -> L {
        winding(dir, tri)
    }
    #[inline(always)]
    fn join_pre<W: Wide>(_: impl Fn(usize)) {}
    #[inline(always)]
    fn intersect_tri4(r: &RayLanes<F4>, _: &(), s: TriStore<'_>, i: [usize; 4]) -> TriHit<F4> {
        moller_trumbore_lanes(r, gather4(s, i))
    }
}

impl TriangleTest for Wt {
    type Pre<L: Lane> = Shear<L>;
    type Prim = TriVerts;
    const KIND: TriTest = TriTest::Watertight;
    #[inline(always)]
    fn prim<'r>(s: TriStore<'r>, i: usize) -> &'r TriVerts {
        &s.tris[i]
    }
    #[inline(always)]
    fn prepare<L: Lane>(r: &RayLanes<L>) -> Shear<L> {
        Shear::new(r.dir)
    }
    #[inline(always)]
    fn intersect<L: Lane>(r: &RayLanes<L>, pre: &Shear<L>, tri: &TriVerts) -> TriHit<L> {
        watertight(r, pre, tri)
    }
    #[inline(always)]
    fn facing<L: Lane>(dir: &[L; 3], tri: &TriVerts) -> L {
        winding(dir, tri)
    }
    #[inline(always)]
    fn intersect_tri4(
        r: &RayLanes<F4>,
        pre: &Shear<F4>,
        s: TriStore<'_>,
        i: [usize; 4],
    ) -> TriHit<F4> {
        watertight_lanes(r, pre, gather4(s, i))
    }
    #[inline(always)]
    fn join_pre<W: Wide>(pre: impl Fn(usize) -> Shear<F4>) -> Shear<W> {
        Shear {
            kx: W::join_axis(|k| pre(k).kx),
            ky: W::join_axis(|k| pre(k).ky),
            kz: W::join_axis(|k| pre(k).kz),
            // Written out, not `array::from_fn` (`RayLanes::join`).
            s: [
                W::join(|k| pre(k).s[0]),
                W::join(|k| pre(k).s[1]),
                W::join(|k| pre(k).s[2]),
            ],
        }
    }
}

impl TriangleTest for Pt {
    type Pre<L: Lane> = ();
    type Prim = ProjTri;
    const KIND: TriTest = TriTest::Projection;
    #[inline(always)]
    fn prim<'r>(s: TriStore<'r>, i: usize) -> &'r ProjTri {
        &s.proj[i]
    }
    #[inline(always)]
    fn prepare<L: Lane>(_: &RayLanes<L>) {}
    #[inline(always)]
    fn intersect<L: Lane>(r: &RayLanes<L>, _: &(), tri: &ProjTri) -> TriHit<L> {
        projection(r, tri)
    }
    #[inline(always)]
    fn facing<L: Lane>(dir: &[L; 3], w: &ProjTri) -> L {
        let k = w.k as usize;
        let (u, v) = ((k + 1) % 3, (k + 2) % 3);
        let f = dir[k] + L::splat(w.n_u) * dir[u] + L::splat(w.n_v) * dir[v];
        if w.neg_k != 0 { L::splat(0.0) - f } else { f }
    }
    #[inline(always)]
    fn join_pre<W: Wide>(_: impl Fn(usize)) {}
}

/// `dir . ((v1 - v0) x (v2 - v0))`.
#[inline(always)]
fn winding<L: Lane>(dir: &[L; 3], tri: &TriVerts) -> L {
    let v0 = splat3::<L>(tri.v0);
    let n = cross3(sub3(splat3(tri.v1), v0), sub3(splat3(tri.v2), v0));
    dot3(*dir, n)
}

/// Which side of a triangle a ray may hit: a per-call ray control of the
/// two-level scene (DXR's `RAY_FLAG_CULL_BACK_FACING_TRIANGLES` and
/// `..._FRONT_FACING_...`). The front is the side the counter-clockwise
/// winding `(v1 - v0) x (v2 - v0)` faces, in the geometry's own (object)
/// space, so a mirroring instance does not turn it inside out.
#[repr(u32)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum Cull {
    /// Both sides hit.
    #[default]
    None = 0,
    /// Back-facing triangles are skipped.
    Back = 1,
    /// Front-facing triangles are skipped.
    Front = 2,
}

impl Cull {
    /// Lanes whose facing value (`TriangleTest::facing`) is on the kept
    /// side: strictly, so a ray in the triangle's plane never hits a culled
    /// test.
    #[inline(always)]
    fn kept<L: Lane>(self, f: L) -> L::Mask {
        let zero = L::splat(0.0);
        if self == Cull::Front {
            zero.lt(f)
        } else {
            f.lt(zero)
        }
    }

    /// `h`, triangle `tri`'s test result for rays of direction `dir`,
    /// without the lanes that met the culled side. The same operations in
    /// every lane width, so packets stay bitwise their single ray. Culling
    /// is a run-time value, not a type: each traversal is compiled once per
    /// triangle test, and the check runs only when some lane hit.
    ///
    /// # Deviations
    /// The side is computed apart from the test's own determinant: where
    /// the winding normal overflows f32 (triangles of coordinates beyond
    /// about 1e19) or the facing product underflows to 0 or turns NaN, a
    /// hit is culled on both sides.
    #[inline(always)]
    pub fn apply<T: TriangleTest, L: Lane>(self, dir: &[L; 3], tri: &T::Prim, h: &mut TriHit<L>) {
        if self != Cull::None && L::any(h.mask) {
            h.mask = h.mask & self.kept(T::facing(dir, tri));
        }
    }

    /// `apply` for `TriangleTest::intersect_tri4`'s result: one ray (`r`,
    /// splatted) against stored triangles `i[0..4]`, one per lane, each
    /// lane's facing the scalar one.
    #[inline(always)]
    pub fn apply4<T: TriangleTest>(
        self,
        r: &RayLanes<F4>,
        s: TriStore<'_>,
        i: [usize; 4],
        h: &mut TriHit<F4>,
    ) {
        if self != Cull::None && F4::any(h.mask) {
            let d = r.dir.map(|x| x.x);
            let f = F4::from_array(i.map(|k| T::facing::<f32>(&d, T::prim(s, k))));
            h.mask &= self.kept(f);
        }
    }
}

impl RayLanes<f32> {
    #[inline]
    pub fn from_ray(r: &crate::geom::ray::Ray) -> Self {
        RayLanes {
            org: r.org,
            dir: r.dir,
            tmin: r.tmin,
            tmax: r.tmax,
        }
    }
}

impl RayLanes<F4> {
    /// One ray in all four lanes (for `TriangleTest::intersect_tri4`).
    #[inline(always)]
    pub fn splat(r: &RayLanes<f32>) -> Self {
        RayLanes {
            org: r.org.map(F4::splat),
            dir: r.dir.map(F4::splat),
            tmin: F4::splat(r.tmin),
            tmax: F4::splat(r.tmax),
        }
    }
    #[inline]
    pub fn from_ray4(r: &crate::geom::ray::Ray4) -> Self {
        RayLanes {
            org: r.org,
            dir: r.dir,
            tmin: r.tmin,
            tmax: r.tmax,
        }
    }
}

impl<W: Wide> RayLanes<W> {
    /// The group of quads `r(0) .. r(G - 1)` (`Wide::join`).
    #[inline(always)]
    pub fn join<'a>(r: impl Fn(usize) -> &'a crate::geom::ray::Ray4) -> Self {
        // Arrays written out, not `array::from_fn`: its closure is called
        // out of line, compiled for the baseline ISA, where a wide join's
        // intrinsics become calls.
        let org = |a: usize| W::join(|k| r(k).org[a]);
        let dir = |a: usize| W::join(|k| r(k).dir[a]);
        RayLanes {
            org: [org(0), org(1), org(2)],
            dir: [dir(0), dir(1), dir(2)],
            tmin: W::join(|k| r(k).tmin),
            tmax: W::join(|k| r(k).tmax),
        }
    }
}
