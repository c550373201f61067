//! The single ray through the 4-wide tree (`wide.rs`, `Method::BvhWide`):
//! one 4-wide SIMD slab test per node gives the entry t of all four
//! children; the children hit are visited nearest first and the others
//! pushed with their entry t (Dammertz, Hanika, Keller 2008, section 3;
//! Wald, Benthin, Boulos 2008, section 3.2). It is also the single ray the
//! packet traversals fall back to (`Accel::fastest`): incoherent packets
//! and tiny directions are traced lane by lane through it.
//!
//! # Exactness
//! Each lane of the slab test is `traverse_single::RayBox::entry`'s
//! arithmetic on the same box (same near plane by the direction's sign
//! bit, same NaN handling), and the leaf test is the binary walk's
//! (`traverse_single::leaf`, the tie rule of `geom::closer`). A child is
//! skipped or a popped entry dropped only when its entry lies strictly
//! beyond the nearest hit so far, so the nearest triangle is always tested
//! (module docs of `bvh`): the same triangle and bitwise the same t, u, v
//! as `traverse_single`.
//!
//! # Deviations
//! - No root box test: the root's four children are tested at once, and a
//!   ray missing the root misses them all.
//! - Without a wide tree (`BvhInfo::wide_nodes` 0) the binary walk runs,
//!   and so it does for rays whose direction is tiny (largest component
//!   below `fallback::TINY_DIR`): their slab terms overflow to infinity
//!   where the true entry is beyond f32, so box tests are no longer
//!   conservative, and the triangle test finds hits at rounding-noise t in
//!   boxes the binary walk rejects but a merged wide leaf exposes (measured:
//!   700 lanes on the stress suite's skinny-diagonal scene). The binary
//!   walk's answer is the reference for them (`cli/stress/tests/stress.rs`).
//! - A ray that would overflow the stack restarts on the binary walk; its
//!   box and triangle tests so far stay in the counters.
//! - Counters count wide levels as depth, and 4 box tests per wide node.

use super::traverse_single::{leaf4, walk as binary_walk};
use super::wide::{WIDTH, insert_by};
use super::{BvhView, LeafAt, TriangleTest};
use crate::accel::packet::{PacketArgs, PacketSig};
use crate::counters::Counters;
use crate::geom::{Hit, Ray, RayLanes, Wide};
use crate::isa::LaneFn;
use glam::Vec4;

/// Stack entries. Up to `WIDTH - 1` may be pushed per wide level, so a
/// stack for the deepest tree (`(WIDTH - 1) * MAX_DEPTH`) would be 145
/// entries, and zeroing it cost a fifth of a missing camera ray's time
/// (perf, bunny). A balanced wide tree of 13 levels (4^13 leaves) needs
/// at most 39; a ray that would push beyond `STACK` in a deeper or
/// lopsided tree is traced again by the binary walk, which gives the same
/// answer.
const STACK: usize = 40;
const _: () = assert!(STACK >= WIDTH);

/// A stack entry: `child` in the low 32 bits, `count` in the high ones.
#[inline(always)]
fn pack(child: u32, count: u32) -> u64 {
    child as u64 | (count as u64) << 32
}

/// Nearest hit of `ray` (a miss for invalid rays).
#[inline]
pub fn intersect<T: TriangleTest>(b: &BvhView<'_>, ray: &Ray, ctr: &mut Counters) -> Hit {
    walk::<T, false>(b, ray, ctr)
}

/// Some hit of `ray` in `[tmin, tmax)` (the first found), or a miss.
#[inline]
pub fn any_hit<T: TriangleTest>(b: &BvhView<'_>, ray: &Ray, ctr: &mut Counters) -> Hit {
    walk::<T, true>(b, ray, ctr)
}

/// `Method::BvhWide` on the packet contract (`accel::packet::PacketSig`):
/// the 4-wide single ray lane by lane, in baseline code.
pub struct ByLane<T, const ANY: bool>(core::marker::PhantomData<T>);

impl<'b, T: TriangleTest, const ANY: bool> LaneFn<PacketSig<BvhView<'b>>> for ByLane<T, ANY> {
    #[inline(always)]
    fn call<W: Wide>(args: PacketArgs<'_, BvhView<'b>>) {
        let (b, _, rays, active, hits, _, ctr) = args;
        let wide = |r: &Ray, c: &mut Counters| walk::<T, ANY>(b, r, c);
        crate::accel::packet::lane_by_lane(rays, active, hits, wide, ctr);
    }
}

/// The walk: a child reference is (`child`, `count`) as in `WideNode`
/// (`count` 0: wide node `child`; else a leaf).
pub(crate) fn walk<T: TriangleTest, const ANY: bool>(
    b: &BvhView<'_>,
    ray: &Ray,
    ctr: &mut Counters,
) -> Hit {
    let wide = b.wide;
    let d = ray.dir.map(f32::abs);
    let tiny = d[0].max(d[1]).max(d[2]) < crate::accel::fallback::TINY_DIR;
    if wide.is_empty() || tiny {
        return binary_walk::<T, ANY>(b, ray, ctr);
    }
    ctr.rays += 1;
    let mut best = Hit::MISS;
    if !ray.is_valid() {
        return best;
    }
    let r = WideRay::<T>::new(ray);
    let mut st = Stack::<STACK>::new();
    match walk_from::<T, ANY, STACK>(b, &r, (0, 0, 0), &mut best, &mut st, ctr) {
        Some(_) => best,
        None => {
            // The binary walk counts this ray again (its box and triangle
            // tests so far stay counted).
            ctr.rays -= 1;
            binary_walk::<T, ANY>(b, ray, ctr)
        }
    }
}

/// A valid ray (`Ray::is_valid`) prepared for the wide walk: its lanes
/// for the leaf test and its slab-test terms splatted over the children.
pub(crate) struct WideRay<T: TriangleTest> {
    lanes: RayLanes<crate::geom::F4>,
    pre: T::Pre<crate::geom::F4>,
    org: [Vec4; 3],
    rcp: [Vec4; 3],
    neg: [bool; 3],
    tmin: Vec4,
    tmax: f32,
}

impl<T: TriangleTest> WideRay<T> {
    #[inline(always)]
    pub(crate) fn new(ray: &Ray) -> Self {
        let lanes = RayLanes::splat(&RayLanes::from_ray(ray));
        WideRay {
            pre: T::prepare(&lanes),
            lanes,
            org: ray.org.map(Vec4::splat),
            rcp: ray.dir.map(|d| Vec4::splat(1.0 / d)),
            // The sign bit, not a comparison: -0 has its near plane at max.
            neg: ray.dir.map(f32::is_sign_negative),
            tmin: Vec4::splat(ray.tmin),
            tmax: ray.tmax,
        }
    }
}

/// The walk's stack of `N` entries: child reference (`pack`), entry t,
/// depth.
pub(crate) struct Stack<const N: usize> {
    e: [u64; N],
    t: [f32; N],
    depth: [u8; N],
}

impl<const N: usize> Stack<N> {
    #[inline(always)]
    pub(crate) fn new() -> Self {
        Stack {
            e: [0; N],
            t: [0.0; N],
            depth: [0; N],
        }
    }
}

/// The walk of the subtree at child reference `(child, count)` (wide node
/// 0, count 0: the whole tree) at `depth`, keeping the nearest hit in
/// `best` (any hit, with `ANY`). `Some(true)` when `ANY` found a hit,
/// `None` when the walk would overflow `st` (nothing is then known about
/// the subtree beyond what `best` holds).
// The ray, where it starts, its hit, the stack and counters.
#[inline(always)]
pub(crate) fn walk_from<T: TriangleTest, const ANY: bool, const N: usize>(
    b: &BvhView<'_>,
    r: &WideRay<T>,
    (mut child, mut count, mut depth): (u32, u32, usize),
    best: &mut Hit,
    st: &mut Stack<N>,
    ctr: &mut Counters,
) -> Option<bool> {
    let wide = b.wide;
    let mut sp = 0usize;
    loop {
        if count > 0 {
            let at = LeafAt {
                first: child,
                count,
                depth,
            };
            if leaf4::<T, ANY>(b, &r.lanes, &r.pre, at, best, ctr) {
                return Some(true);
            }
        } else {
            let n = &wide[child as usize];
            let tmax = if best.t < r.tmax { best.t } else { r.tmax };
            let (mut t0, mut t1) = (r.tmin, Vec4::splat(tmax));
            for a in 0..3 {
                let (lo, hi) = (Vec4::from_array(n.min[a]), Vec4::from_array(n.max[a]));
                let (np, fp) = if r.neg[a] { (hi, lo) } else { (lo, hi) };
                let near = (np - r.org[a]) * r.rcp[a];
                let far = (fp - r.org[a]) * r.rcp[a];
                t0 = Vec4::select(near.cmpgt(t0), near, t0);
                t1 = Vec4::select(far.cmplt(t1), far, t1);
            }
            ctr.aabb_at(depth + 1, WIDTH as u64);
            let mut hit = t0.cmple(t1).bitmask();
            depth += 1;
            if hit != 0 {
                if hit & (hit - 1) == 0 {
                    let c = hit.trailing_zeros() as usize;
                    (child, count) = (n.child[c], n.count[c]);
                    continue;
                }
                // Order the children hit by entry t (insertion, at most 4),
                // push all but the nearest farthest first.
                let ts = t0.to_array();
                let mut order = [0usize; WIDTH];
                let mut k = 0;
                while hit != 0 {
                    let c = hit.trailing_zeros() as usize;
                    hit &= hit - 1;
                    insert_by(&mut order, k, c, |&c| ts[c]);
                    k += 1;
                }
                if sp + k > N {
                    return None;
                }
                for &c in order[1..k].iter().rev() {
                    st.e[sp] = pack(n.child[c], n.count[c]);
                    st.t[sp] = ts[c];
                    st.depth[sp] = depth as u8;
                    sp += 1;
                }
                (child, count) = (n.child[order[0]], n.count[order[0]]);
                continue;
            }
        }
        // Pop the next child whose entry is not beyond the nearest hit.
        loop {
            if sp == 0 {
                return Some(false);
            }
            sp -= 1;
            if st.t[sp] <= best.t {
                let e = st.e[sp];
                (child, count) = (e as u32, (e >> 32) as u32);
                depth = st.depth[sp] as usize;
                break;
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::accel::bvh::build::build;
    use crate::accel::bvh::build::testutil::{Store, deep_tris, soup};
    use crate::accel::bvh::traverse_single::tests::{test_rays, tris_of};
    use crate::accel::bvh::{BuildQuality, BvhParams};
    use crate::geom::{Mt, Pt, Scene, TriTest, Wt};

    /// The wide walk answers as the binary walk, bitwise, ray by ray, for
    /// the nearest hit and the any-hit answer (hit or not).
    fn check<T: TriangleTest>(v: &[f32], ix: &[u32], views: &[crate::scenes::View], p: &BvhParams) {
        let scene = Scene::from_f32(v, ix).unwrap();
        let mut st = Store::new(scene.triangle_count() as usize, true);
        let mut bvh = st.bvh();
        let info = build(&mut bvh, &scene, p).unwrap();
        let view = bvh.view().unwrap();
        assert!(info.triangles == 0 || p.leaf_size == 1 || info.wide_nodes > 0);
        let rays = test_rays(&tris_of(&scene), views, 0x51ed ^ ix.len() as u64);
        let mut ctr = Counters::default();
        for (k, ray) in rays.iter().enumerate() {
            let want = binary_walk::<T, false>(&view, ray, &mut ctr);
            let got = intersect::<T>(&view, ray, &mut ctr);
            assert!(
                got.prim == want.prim
                    && got.t.to_bits() == want.t.to_bits()
                    && got.u.to_bits() == want.u.to_bits()
                    && got.v.to_bits() == want.v.to_bits(),
                "ray {k} {ray:?} ({:?} {:?}): wide {got:?} binary {want:?}",
                T::KIND,
                p.quality
            );
            assert_eq!(any_hit::<T>(&view, ray, &mut ctr).is_hit(), want.is_hit());
        }
    }

    fn check_all(v: &[f32], ix: &[u32], views: &[crate::scenes::View], leaf_size: u32) {
        for (test, quality) in [
            (TriTest::MollerTrumbore, BuildQuality::Medium),
            (TriTest::Watertight, BuildQuality::Low),
            (TriTest::Projection, BuildQuality::High),
        ] {
            let p = BvhParams {
                leaf_size,
                test,
                quality,
                ..BvhParams::default()
            };
            match test {
                TriTest::MollerTrumbore => check::<Mt>(v, ix, views, &p),
                TriTest::Watertight => check::<Wt>(v, ix, views, &p),
                TriTest::Projection => check::<Pt>(v, ix, views, &p),
            }
        }
    }

    #[test]
    fn wide_matches_binary_builtin() {
        for &name in crate::scenes::BUILTIN_NAMES {
            let s = crate::scenes::builtin(name).unwrap();
            check_all(&s.mesh.vertices, &s.mesh.indices, &s.views, 4);
        }
    }

    #[test]
    fn wide_matches_binary_ties_deep_and_small_leaves() {
        let s = crate::scenes::builtin("tetra").unwrap();
        check_all(&s.mesh.vertices, &s.mesh.indices, &s.views, 1);
        let t = [[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]];
        let mut tris = vec![t; 100];
        tris.push([[0.0, 0.0, 0.5], [1.0, 0.0, 0.5], [0.0, 1.0, 0.5]]);
        tris.reverse();
        let (v, ix) = soup(&tris);
        check_all(&v, &ix, &[], 4);
        check_all(&v, &ix, &[], 2);
        let (v, ix) = soup(&deep_tris());
        check_all(&v, &ix, &[], 1);
        check_all(&[], &[], &[], 4);
    }
}
