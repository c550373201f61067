//! The 2x2 SIMD ray through the kd-tree (Wald 2004, "Realtime Ray Tracing
//! and Interactive Global Illumination", the SIMD packet traversal of
//! kd-trees; Wald, Slusallek, Benthin, Wagner 2001): the four rays of one
//! `Ray4` walk the tree together, each lane with its own interval `[t0,
//! t1]`.
//!
//! The lanes share their direction signs, so they share the near and far
//! child of every split. At an inner node every lane narrows its interval
//! by `split_interval` exactly as the single ray does (see `mod.rs`,
//! Exactness); the packet goes to the near child if some live lane's near
//! interval is non-empty, to the far child if some live lane's far interval
//! is, and pushes the far child with the four far intervals when both are
//! needed. At a leaf the lanes whose interval there is non-empty test its
//! triangles (4-wide, the same `Lane` arithmetic as the single ray) and a
//! lane is done once its nearest hit lies at or before the end of its leaf
//! interval. Every lane therefore visits the very leaves the single ray
//! visits, in the same order, and stops after the same one: results equal
//! `traverse_single` lane by lane, bitwise.
//!
//! # Deviations
//! - Lanes whose direction sign bits differ from the first live lane's on
//!   some axis ("stray lanes", `Counters::stray_lanes`) are traced one by
//!   one with the single-ray traversal; Wald's packets assume equal signs.
//! - Before them, lanes with tiny directions (`accel::fallback::tiny`) are
//!   traced alone the same way and replaced in the quad (`quieted`).
//! - After them, a quad failing `accel::fallback::coherent` (directions
//!   over more than a 30 degree cone, or origins far apart) is traced lane
//!   by lane the same way.
//!
//! # Counters
//! `rays` (valid active lanes), `packets` (one per call), `stray_lanes`,
//! `aabb_at` one per split step of the 2x2 ray, `tri_at` the lanes of each
//! 4-wide triangle test.

use super::traverse_single::{KdRay, Visit, from_node};
use super::{KdView, MAX_DEPTH, TriangleTest};
use crate::accel::fallback;
use crate::accel::group;
use crate::accel::packet::{PacketArgs, PacketSig};
use crate::counters::Counters;
use crate::geom::{Aabb, F4, Hit, Hit4, M4, Ray4, RayLanes, Wide};
use crate::isa::LaneFn;

/// `Method::KdSimd` on the packet contract (`accel::packet::PacketSig`),
/// quad by quad: its `Kernel` runs it in baseline code.
pub struct Simd<T, const ANY: bool>(core::marker::PhantomData<T>);

impl<'k, T: TriangleTest, const ANY: bool> LaneFn<PacketSig<KdView<'k>>> for Simd<T, ANY> {
    #[inline(always)]
    fn call<W: Wide>(args: PacketArgs<'_, KdView<'k>>) {
        let (k, p, rays, active, hits, _, ctr) = args;
        for ((r, m), h) in rays.iter().zip(active).zip(hits.iter_mut()) {
            if ANY {
                let o = occluded::<T>(k, r, *m, p.fallbacks, ctr);
                let (m, h) = (core::slice::from_ref(m), core::slice::from_mut(h));
                crate::accel::packet::mark_occluded(&[o], m, h);
            } else {
                let got = intersect::<T>(k, r, *m, p.fallbacks, ctr);
                for i in (0..4).filter(|&i| m.test(i)) {
                    h.set_lane(i, got.lane(i));
                }
            }
        }
    }
}

/// Nearest hits of the active lanes of `r` (inactive and invalid lanes,
/// see `Ray::is_valid`: `Hit::MISS`).
#[inline]
pub fn intersect<T: TriangleTest>(
    k: &KdView<'_>,
    r: &Ray4,
    active: M4,
    fallbacks: bool,
    ctr: &mut Counters,
) -> Hit4 {
    let mut best = Hit4::MISS;
    quad::<T, false>(k, r, active, &mut best, fallbacks, ctr);
    best
}

/// Lanes of `r` that are active and hit something in `[tmin, tmax)`.
#[inline]
pub fn occluded<T: TriangleTest>(
    k: &KdView<'_>,
    r: &Ray4,
    active: M4,
    fallbacks: bool,
    ctr: &mut Counters,
) -> M4 {
    let mut best = Hit4::MISS;
    quad::<T, true>(k, r, active, &mut best, fallbacks, ctr);
    best.hit_mask() & active
}

/// `Ray::is_valid`, 4-wide: finite origin and direction, a non-zero
/// direction, `0 <= tmin <= tmax` (NaN fails every part).
#[inline(always)]
pub(crate) fn valid4(r: &Ray4) -> M4 {
    let fin = |x: F4| x.abs().cmplt(F4::INFINITY);
    fin(r.org[0])
        & fin(r.org[1])
        & fin(r.org[2])
        & fin(r.dir[0])
        & fin(r.dir[1])
        & fin(r.dir[2])
        & (r.dir[0].cmpne(F4::ZERO) | r.dir[1].cmpne(F4::ZERO) | r.dir[2].cmpne(F4::ZERO))
        & r.tmin.cmpge(F4::ZERO)
        & r.tmin.cmple(r.tmax)
}

/// Sign bits of lane `i`'s direction (the near side of every split).
#[inline(always)]
pub(crate) fn lane_signs(r: &Ray4, i: usize) -> [bool; 3] {
    [
        r.dir[0][i].is_sign_negative(),
        r.dir[1][i].is_sign_negative(),
        r.dir[2][i].is_sign_negative(),
    ]
}

/// Lanes (bits) whose direction sign bits differ from `neg` on some axis.
#[inline(always)]
pub(crate) fn stray_bits(r: &Ray4, neg: [bool; 3]) -> u32 {
    let mut s = 0;
    for (d, n) in r.dir.iter().zip(neg) {
        s |= d.is_negative_bitmask() ^ if n { 15 } else { 0 };
    }
    s
}

/// `clip` 4-wide for lanes whose direction signs are `neg`: the interval
/// `[t0, t1]` inside the box `min..max` (same operations in the same
/// order, so each lane gets `clip`'s bits).
#[inline(always)]
pub(crate) fn clip4(
    min: &[f32; 3],
    max: &[f32; 3],
    org: &[F4; 3],
    rcp: &[F4; 3],
    neg: [bool; 3],
    mut t0: F4,
    mut t1: F4,
) -> (F4, F4) {
    for a in 0..3 {
        let lo = (F4::splat(min[a]) - org[a]) * rcp[a];
        let hi = (F4::splat(max[a]) - org[a]) * rcp[a];
        let (near, far) = if neg[a] { (hi, lo) } else { (lo, hi) };
        t0 = F4::select(near.cmpgt(t0), near, t0);
        t1 = F4::select(far.cmplt(t1), far, t1);
    }
    (t0, t1)
}

/// Lane `i` of `r` traced alone with the single-ray traversal from `node`
/// (at `depth`, box `bx`): its interval is the slab test of `bx`, which is
/// the interval the single ray has there (see `mod.rs`, Exactness).
#[inline(never)]
pub(crate) fn lane_from<T: TriangleTest, const ANY: bool>(
    k: &KdView<'_>,
    r: &Ray4,
    i: usize,
    node: usize,
    depth: usize,
    bx: &Aabb,
    ctr: &mut Counters,
) -> Hit {
    let ray = r.lane(i);
    let kr = KdRay::new(&ray);
    let (t0, t1) = super::clip(
        &bx.min.to_array(),
        &bx.max.to_array(),
        &kr.org,
        &kr.rcp,
        &kr.neg,
        ray.tmin,
        ray.tmax,
    );
    let mut best = Hit::MISS;
    if t0 <= t1 {
        let at = Visit {
            node,
            depth,
            t0,
            t1,
        };
        from_node::<T, ANY>(k, &ray, &kr, at, &mut best, ctr);
    }
    best
}

fn quad<T: TriangleTest, const ANY: bool>(
    k: &KdView<'_>,
    r: &Ray4,
    active: M4,
    best: &mut Hit4,
    fallbacks: bool,
    ctr: &mut Counters,
) {
    ctr.packets += 1;
    let mut live = active & valid4(r);
    ctr.rays += live.bitmask().count_ones() as u64;
    if !live.any() || k.nodes.is_empty() || k.info.triangles == 0 {
        return;
    }
    let root = &k.info.root;
    // Lanes with tiny directions alone (`accel::fallback::tiny`), and out
    // of the quad's arithmetic.
    let tiny = fallback::tiny(fallbacks, r, live);
    let quiet;
    let r = if tiny.any() {
        fallback::each_lane(&[tiny], |_, i| {
            best.set_lane(i, lane_from::<T, ANY>(k, r, i, 0, 0, root, ctr));
        });
        live &= !tiny;
        if !live.any() {
            return;
        }
        quiet = fallback::quieted(r, tiny);
        &quiet
    } else {
        r
    };
    let neg = lane_signs(r, live.bitmask().trailing_zeros() as usize);
    let stray = stray_bits(r, neg) & live.bitmask();
    if stray != 0 {
        ctr.stray_lanes += stray.count_ones() as u64;
        for i in 0..4 {
            if stray & (1 << i) != 0 {
                let h = lane_from::<T, ANY>(k, r, i, 0, 0, root, ctr);
                best.set_lane(i, h);
            }
        }
        live &= !crate::geom::lane::mask_from_bits(stray);
        if !live.any() {
            return;
        }
    }
    // An incoherent quad (`trace::fallback`): every lane still live
    // (all with the first lane's direction signs) alone.
    if !fallback::coherent(
        fallbacks,
        core::slice::from_ref(r),
        &[live],
        k.info.bounds.diagonal().length(),
    ) {
        fallback::each_lane(&[live], |_, i| {
            best.set_lane(i, lane_from::<T, ANY>(k, r, i, 0, 0, root, ctr));
        });
        return;
    }
    walk::<T, ANY>(k, r, live, neg, best, ctr);
}

#[inline(always)]
fn walk<T: TriangleTest, const ANY: bool>(
    k: &KdView<'_>,
    r: &Ray4,
    mut live: M4,
    neg: [bool; 3],
    best: &mut Hit4,
    ctr: &mut Counters,
) {
    let one = F4::ONE;
    let org = r.org;
    let rcp = [one / r.dir[0], one / r.dir[1], one / r.dir[2]];
    let root = &k.info.root;
    let (mut t0, mut t1) = clip4(
        &root.min.to_array(),
        &root.max.to_array(),
        &org,
        &rcp,
        neg,
        r.tmin,
        r.tmax,
    );
    if !(live & t0.cmple(t1)).any() {
        return;
    }
    let lanes = RayLanes::from_ray4(r);
    let pre = T::prepare(&lanes);
    let nodes = k.nodes;
    // (node, depth) and the four far intervals of pushed far children.
    let mut st_node = [(0u32, 0u32); MAX_DEPTH + 1];
    let mut st_t = [(F4::ZERO, F4::ZERO); MAX_DEPTH + 1];
    let mut sp = 0usize;
    let mut node = 0usize;
    let mut depth = 0usize;
    loop {
        let n = &nodes[node];
        if !n.is_leaf() {
            let a = n.axis();
            ctr.aabb_at(depth, 1);
            // Eq. of `split_interval`, lane by lane (NaN t_s: no change).
            let ts = (F4::splat(n.split()) - org[a]) * rcp[a];
            let near_hi = F4::select(ts.cmplt(t1), ts, t1);
            let far_lo = F4::select(ts.cmpgt(t0), ts, t0);
            let l = n.left();
            let (near, far) = if neg[a] { (l + 1, l) } else { (l, l + 1) };
            depth += 1;
            let go_near = (live & t0.cmple(near_hi)).any();
            let go_far = (live & far_lo.cmple(t1)).any();
            if go_near {
                if go_far {
                    st_node[sp] = (far as u32, depth as u32);
                    st_t[sp] = (far_lo, t1);
                    sp += 1;
                }
                node = near;
                t1 = near_hi;
                continue;
            }
            if go_far {
                node = far;
                t0 = far_lo;
                continue;
            }
        } else {
            // The lanes inside this leaf; the others never visit it.
            let inside = live & t0.cmple(t1);
            let mut m = inside;
            for &s in k.leaf_refs(n) {
                ctr.tri_at(depth, m.bitmask().count_ones() as u64);
                let s = s as usize;
                let h = T::intersect(&lanes, &pre, T::prim(k.store(), s));
                let hm = h.mask & m;
                if hm.any() {
                    let id = k.tri_ids[s];
                    let ray = || (lanes.org, lanes.dir);
                    let take = group::take::<ANY>(best, hm, (h.t, h.u, h.v), id, &k.filter, ray);
                    if ANY && take.any() {
                        // Occlusion: a lane with a hit is done.
                        m &= !take;
                        live &= !take;
                        if !m.any() {
                            break;
                        }
                    }
                }
            }
            // Early termination, per lane: nothing beyond this leaf can be
            // nearer (the single ray's rule, a miss's t = inf included).
            live &= !(inside & best.t.cmple(t1));
            if !live.any() {
                return;
            }
        }
        // Pop the next far child some live lane still enters.
        loop {
            if sp == 0 {
                return;
            }
            sp -= 1;
            let (a0, a1) = st_t[sp];
            if (live & a0.cmple(a1)).any() {
                (node, depth) = (st_node[sp].0 as usize, st_node[sp].1 as usize);
                (t0, t1) = (a0, a1);
                break;
            }
        }
    }
}

/// Exactness of the 2x2 SIMD ray against `traverse_single`, and the setup
/// the packet tests share.
#[cfg(test)]
pub(crate) mod tests {
    use super::*;
    use crate::accel::bvh::BvhView;
    use crate::accel::kd::KdParams;
    use crate::accel::kd::build::build;
    use crate::accel::kd::build::testutil::Store;
    use crate::accel::kd::traverse_single::{self, tests::same};
    use crate::accel::testkit::Store as BvhStore;
    use crate::accel::testkit::{Rng, test_rays, tris_of};
    use crate::accel::testkit::{built as bvh_built, packets, ray_sets};
    use crate::geom::TriangleTest;
    use crate::geom::lane::mask_from_bits;
    use crate::geom::{Mt, Pt, Ray, Scene, TriTest, Wt};
    use glam::Vec3;

    /// A kd-tree (depth limit `max_depth`, 0: the default rule) with test
    /// `T` over `v`, `ix`, and a BVH over the same mesh (for the ray sets
    /// of `traverse_masked::tests` and the entry-point helper).
    pub(crate) fn with_trees<T: TriangleTest + TriangleTest>(
        v: &[f32],
        ix: &[u32],
        max_depth: u32,
        f: impl FnOnce(&KdView<'_>, &BvhView<'_>),
    ) {
        let scene = Scene::from_f32(v, ix).unwrap();
        let n = scene.triangle_count() as usize;
        let mut st = Store::new(n, T::KIND == TriTest::Projection);
        let mut kd = st.kd();
        let p = KdParams {
            test: T::KIND,
            max_depth,
            ..KdParams::default()
        };
        build(&mut kd, &scene, &p).unwrap();
        let mut bst = BvhStore::new(0, false);
        let bvh = bvh_built::<T>(&mut bst, v, ix, 4);
        f(&kd.view().unwrap(), &bvh.view().unwrap());
    }

    /// Every quad through `intersect` and `occluded`, every lane compared
    /// with `traverse_single` (bitwise hits, equal occlusion; inactive
    /// lanes a miss and not occluded). Returns the SIMD counters.
    pub(crate) fn check_quads<T: TriangleTest>(
        k: &KdView<'_>,
        quads: &[Ray4],
        active: &[M4],
        what: &str,
    ) -> Counters {
        let mut ctr = Counters::default();
        let mut c1 = Counters::default();
        let mut valid = 0u64;
        for (q, (r, m)) in quads.iter().zip(active).enumerate() {
            let h = intersect::<T>(k, r, *m, true, &mut ctr);
            let o = occluded::<T>(k, r, *m, true, &mut ctr);
            for i in 0..4 {
                let ray: Ray = r.lane(i);
                if !m.test(i) {
                    assert!(same(&h.lane(i), &Hit::MISS), "{what}: inactive {q}.{i}");
                    assert!(!o.test(i), "{what}: inactive {q}.{i} occluded");
                    continue;
                }
                valid += ray.is_valid() as u64;
                let want = traverse_single::intersect::<T>(k, &ray, &mut c1);
                assert!(
                    same(&h.lane(i), &want),
                    "{what} ({:?}): quad {q} lane {i} {ray:?}: simd {:?} single {want:?}",
                    T::KIND,
                    h.lane(i)
                );
                assert_eq!(
                    o.test(i),
                    traverse_single::occluded::<T>(k, &ray, &mut c1),
                    "{what} ({:?}): quad {q} lane {i} {ray:?} occluded",
                    T::KIND
                );
            }
        }
        assert_eq!(ctr.rays, 2 * valid, "{what}");
        assert_eq!(ctr.packets, 2 * quads.len() as u64, "{what}");
        ctr
    }

    /// `test_rays` (random, axis-parallel, through vertices and edges,
    /// bounded, invalid) four by four with mixed masks, then the ray sets
    /// of `traverse_masked::tests` (primary, shadow, reflection, mixed,
    /// random, bundle) as 2x2 quads of the first view.
    fn check_scene<T: TriangleTest + TriangleTest>(
        name: &str,
        v: &[f32],
        ix: &[u32],
        views: &[crate::scenes::View],
        light: Vec3,
    ) -> Counters {
        let mut total = Counters::default();
        with_trees::<T>(v, ix, 0, |k, b| {
            let scene = Scene::from_f32(v, ix).unwrap();
            let mut rays = test_rays(&tris_of(&scene), views, 0x9e37 ^ ix.len() as u64);
            while !rays.len().is_multiple_of(4) {
                rays.push(rays[rays.len() % 7]);
            }
            let quads: Vec<Ray4> = rays
                .chunks_exact(4)
                .map(|c| Ray4::from_rays(&[c[0], c[1], c[2], c[3]]))
                .collect();
            let mut rng = Rng(0x2545_f491);
            let active: Vec<M4> = (0..quads.len())
                .map(|q| {
                    mask_from_bits(if q % 3 == 0 {
                        15
                    } else {
                        (rng.next() % 16) as u32
                    })
                })
                .collect();
            total.add(&check_quads::<T>(
                k,
                &quads,
                &active,
                &format!("{name} test_rays"),
            ));
            for view in views.iter().take(1) {
                for set in ray_sets::<T>(b, view, light, 40, 36, 0x51 ^ ix.len() as u64) {
                    let (mut quads, mut active) = (Vec::new(), Vec::new());
                    for (q, a, _) in packets(&set, 2) {
                        quads.extend(q);
                        active.extend(a);
                    }
                    let what = format!("{name} {}", set.name);
                    total.add(&check_quads::<T>(k, &quads, &active, &what));
                }
            }
        });
        total
    }

    fn check_all(name: &str, v: &[f32], ix: &[u32], views: &[crate::scenes::View], light: Vec3) {
        let c = check_scene::<Mt>(name, v, ix, views, light);
        if !ix.is_empty() {
            // Mixed-sign lanes took the single-ray path, the others SIMD.
            assert!(c.stray_lanes > 0, "{name}: {c:?}");
            if cfg!(feature = "counters") {
                assert!(c.aabb_tests > 0 && c.tri_tests > 0, "{name}: {c:?}");
            }
        }
        check_scene::<Wt>(name, v, ix, views, light);
        check_scene::<Pt>(name, v, ix, views, light);
    }

    #[test]
    fn simd_matches_single_builtin() {
        for &name in crate::scenes::BUILTIN_NAMES {
            let s = crate::scenes::builtin(name).unwrap();
            check_all(name, &s.mesh.vertices, &s.mesh.indices, &s.views, s.light);
        }
    }

    /// The lattice of `traverse_masked::tests` (rays exactly through shared
    /// vertices and edges), coincident triangles (ties), an empty scene
    /// and a tree at the depth limit.
    #[test]
    fn simd_matches_single_lattice_and_edge_cases() {
        let (v, ix, sets) = crate::accel::testkit::lattice();
        for_tests(&v, &ix, 0, &|k: Check<'_>| {
            for set in &sets {
                let (mut quads, mut active) = (Vec::new(), Vec::new());
                for (q, a, _) in packets(set, 2) {
                    quads.extend(q);
                    active.extend(a);
                }
                k(&quads, &active, set.name);
            }
        });
        let view = crate::scenes::View {
            eye: Vec3::new(0.3, 0.2, 3.0),
            look_at: Vec3::new(0.3, 0.2, 0.0),
            up: Vec3::Y,
            fov_y_deg: 40.0,
        };
        let (v, ix) = ties();
        check_all("ties", &v, &ix, &[view], Vec3::new(0.2, 0.2, 4.0));
        check_all("empty", &[], &[], &[view], Vec3::ONE);
        let (v, ix) = crate::accel::testkit::soup(&crate::accel::testkit::deep_tris());
        let rays = deep_rays(32);
        for_tests(&v, &ix, MAX_DEPTH as u32, &|k: Check<'_>| {
            let quads: Vec<Ray4> = rays
                .chunks_exact(4)
                .map(|c| Ray4::from_rays(&[c[0], c[1], c[2], c[3]]))
                .collect();
            k(&quads, &vec![M4::TRUE; quads.len()], "deep");
        });
    }

    /// A quad checker: quads, active masks, what they are.
    type Check<'c> = &'c dyn Fn(&[Ray4], &[M4], &str);

    /// Run `body` with a quad checker for a kd-tree over `v`, `ix` with
    /// each of the three triangle tests.
    fn for_tests(v: &[f32], ix: &[u32], max_depth: u32, body: &dyn Fn(Check<'_>)) {
        with_trees::<Mt>(v, ix, max_depth, |k, _| {
            body(&|q, a, w| {
                check_quads::<Mt>(k, q, a, w);
            })
        });
        with_trees::<Wt>(v, ix, max_depth, |k, _| {
            body(&|q, a, w| {
                check_quads::<Wt>(k, q, a, w);
            })
        });
        with_trees::<Pt>(v, ix, max_depth, |k, _| {
            body(&|q, a, w| {
                check_quads::<Pt>(k, q, a, w);
            })
        });
    }

    /// 60 copies of one triangle and 30 of another above it, in reverse
    /// id order: every hit is a tie decided by the lowest id.
    pub(crate) fn ties() -> (Vec<f32>, Vec<u32>) {
        let t = [[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]];
        let mut tris = vec![t; 60];
        tris.extend(vec![
            [[0.0, 0.0, 0.5], [1.0, 0.0, 0.5], [0.0, 1.0, 0.5]];
            30
        ]);
        tris.reverse();
        crate::accel::testkit::soup(&tris)
    }

    /// `side` x `side` rays from the origin down the chain of `deep_tris`
    /// (row-major), the first half unbounded, the second from t = 1e3.
    pub(crate) fn deep_rays(side: u32) -> Vec<Ray> {
        let grid = |x: u32, y: u32| {
            Vec3::new(
                1.0,
                0.001 + 0.008 * x as f32 / side as f32,
                0.001 + 0.008 * y as f32 / side as f32,
            )
        };
        (0..side)
            .flat_map(|y| {
                (0..side).map(move |x| {
                    if y < side / 2 {
                        Ray::new(Vec3::ZERO, grid(x, y), 0.0, f32::INFINITY)
                    } else {
                        Ray::new(Vec3::ZERO, grid(x, y), 1e3, 1e8)
                    }
                })
            })
            .collect()
    }
}
