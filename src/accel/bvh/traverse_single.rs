//! Single-ray BVH traversal: the reference every BVH packet method must
//! match bit for bit (same triangle test, same tie rule).
//!
//! Iterative, with a fixed stack of `MAX_DEPTH + 1` entries (the build never
//! goes deeper). At an inner node both children's boxes are tested; the near
//! child (by the sign of the ray direction on the node's split axis) is
//! visited first and the far one pushed with its entry t, so a popped node
//! whose entry lies strictly beyond the nearest hit so far is dropped without
//! another box test.
//!
//! Exactness (see `mod.rs`): a box is skipped only when the ray's interval
//! `[tmin, min(tmax, best.t)]` (inclusive) misses it, so a triangle at
//! exactly `best.t` with a lower id is still found.

use super::{BvhNode, BvhView, LeafAt, MAX_DEPTH, TriangleTest};
use crate::counters::Counters;
use crate::geom::closer;
use crate::geom::{Hit, Ray, RayLanes};

/// Per-ray data of the slab test (Kay and Kajiya 1986; the near plane chosen
/// by the sign of the direction, as in Williams et al. 2005, "An efficient
/// and robust ray-box intersection algorithm").
#[derive(Clone, Copy, Debug)]
pub(crate) struct RayBox {
    org: [f32; 3],
    rcp: [f32; 3],
    /// Index of the near (and far) plane of each axis in the node read as
    /// `[f32; 8]` (min at 0..3, max at 4..7).
    near: [usize; 3],
    far: [usize; 3],
    tmin: f32,
}

impl RayBox {
    #[inline(always)]
    pub(crate) fn new(ray: &Ray) -> RayBox {
        let mut b = RayBox {
            org: ray.org,
            rcp: [0.0; 3],
            near: [0; 3],
            far: [0; 3],
            tmin: ray.tmin,
        };
        for a in 0..3 {
            b.rcp[a] = 1.0 / ray.dir[a];
            // The sign bit, not a comparison: -0 has its near plane at max.
            let neg = ray.dir[a].is_sign_negative();
            b.near[a] = if neg { a + 4 } else { a };
            b.far[a] = if neg { a } else { a + 4 };
        }
        b
    }

    /// Entry t of the ray into `n`'s box within `[tmin, tmax]`, or `None`.
    ///
    /// Same answer as `Aabb::clip_ray`: for a zero direction component the
    /// slab terms are +-inf (origin outside: rejected) or NaN (origin on a
    /// plane), and NaN never replaces the running interval, so that axis
    /// constrains nothing.
    #[inline(always)]
    pub(crate) fn entry(&self, n: &BvhNode, tmax: f32) -> Option<f32> {
        let f: &[f32; 8] = bytemuck::cast_ref(n);
        let mut t0 = self.tmin;
        let mut t1 = tmax;
        for a in 0..3 {
            let near = (f[self.near[a] & 7] - self.org[a]) * self.rcp[a];
            let far = (f[self.far[a] & 7] - self.org[a]) * self.rcp[a];
            t0 = if near > t0 { near } else { t0 };
            t1 = if far < t1 { far } else { t1 };
        }
        if t0 <= t1 { Some(t0) } else { None }
    }
}

/// Nearest hit of `ray` (a miss for invalid rays: see `Ray::is_valid`).
#[inline]
pub fn intersect<T: TriangleTest>(b: &BvhView<'_>, ray: &Ray, ctr: &mut Counters) -> Hit {
    walk::<T, false>(b, ray, ctr)
}

/// Whether anything lies on `ray` in `[tmin, tmax)`.
#[inline]
pub fn occluded<T: TriangleTest>(b: &BvhView<'_>, ray: &Ray, ctr: &mut Counters) -> bool {
    walk::<T, true>(b, ray, ctr).is_hit()
}

/// Some hit on `ray` in `[tmin, tmax)` (the first found, not the nearest),
/// or a miss: occlusion that also names an occluder.
#[inline]
pub fn any_hit<T: TriangleTest>(b: &BvhView<'_>, ray: &Ray, ctr: &mut Counters) -> Hit {
    walk::<T, true>(b, ray, ctr)
}

pub(crate) fn walk<T: TriangleTest, const ANY: bool>(
    b: &BvhView<'_>,
    ray: &Ray,
    ctr: &mut Counters,
) -> Hit {
    ctr.rays += 1;
    let mut best = Hit::MISS;
    let nodes = b.nodes;
    if !ray.is_valid() || nodes.is_empty() {
        return best;
    }
    let rb = RayBox::new(ray);
    ctr.aabb_at(0, 1);
    if rb.entry(&nodes[0], ray.tmax).is_none() {
        return best;
    }
    let lanes = RayLanes::from_ray(ray);
    let pre = T::prepare(&lanes);
    let neg = [
        ray.dir[0].is_sign_negative(),
        ray.dir[1].is_sign_negative(),
        ray.dir[2].is_sign_negative(),
    ];

    let mut st_node = [0u32; MAX_DEPTH + 1];
    let mut st_t = [0.0f32; MAX_DEPTH + 1];
    let mut st_depth = [0u8; MAX_DEPTH + 1];
    let mut sp = 0usize;
    let mut node = 0usize;
    let mut depth = 0usize;
    loop {
        let n = &nodes[node];
        if !n.is_leaf() {
            let l = n.first as usize;
            let (near, far) = if neg[n.axis()] {
                (l + 1, l)
            } else {
                (l, l + 1)
            };
            let tmax = if best.t < ray.tmax { best.t } else { ray.tmax };
            ctr.aabb_at(depth + 1, 2);
            let tn = rb.entry(&nodes[near], tmax);
            let tf = rb.entry(&nodes[far], tmax);
            depth += 1;
            match (tn, tf) {
                (Some(_), Some(t)) => {
                    st_node[sp] = far as u32;
                    st_t[sp] = t;
                    st_depth[sp] = depth as u8;
                    sp += 1;
                    node = near;
                    continue;
                }
                (Some(_), None) => {
                    node = near;
                    continue;
                }
                (None, Some(_)) => {
                    node = far;
                    continue;
                }
                (None, None) => {}
            }
        } else if leaf::<T, ANY>(b, &lanes, &pre, n.leaf_at(depth), &mut best, ctr) {
            return best;
        }
        // Pop the next node whose entry is not beyond the nearest hit.
        loop {
            if sp == 0 {
                return best;
            }
            sp -= 1;
            if st_t[sp] <= best.t {
                node = st_node[sp] as usize;
                depth = st_depth[sp] as usize;
                break;
            }
        }
    }
}

/// Test the stored triangles of leaf `at` against the ray, keeping the
/// nearest hit in `best` (the tie rule of `geom::closer`); with `ANY`,
/// true as soon as one is hit (the walk may stop). The leaf test of both
/// single-ray walks, binary and wide.
#[inline(always)]
pub(crate) fn leaf<T: TriangleTest, const ANY: bool>(
    b: &BvhView<'_>,
    lanes: &RayLanes<f32>,
    pre: &T::Pre<f32>,
    at: LeafAt,
    best: &mut Hit,
    ctr: &mut Counters,
) -> bool {
    let (first, depth) = (at.first as usize, at.depth);
    for i in first..first + at.count as usize {
        ctr.tri_at(depth, 1);
        let tri = T::prim(b.store(), i);
        let mut h = T::intersect(lanes, pre, tri);
        b.cull.apply::<T, f32>(&lanes.dir, tri, &mut h);
        if h.mask
            && take(
                b,
                || (lanes.org, lanes.dir),
                best,
                (h.t, h.u, h.v),
                b.tri_ids[i],
            )
            && ANY
        {
            return true;
        }
    }
    false
}

/// A hit on triangle `id` at `(t, u, v)` replaces `best` when `closer`
/// and the view's filter accepts it; whether it did. The one update of
/// both leaf tests.
#[inline(always)]
fn take(
    b: &BvhView<'_>,
    ray: impl Fn() -> ([f32; 3], [f32; 3]),
    best: &mut Hit,
    hit: (f32, f32, f32),
    id: u32,
) -> bool {
    let (t, u, v) = hit;
    let c = closer(t, id, best) && {
        let (org, dir) = ray();
        b.filter.accepts(org, dir, t, u, v, id)
    };
    if c {
        *best = Hit { t, prim: id, u, v };
    }
    c
}

/// `leaf` four triangles at a time (`TriangleTest::intersect_tri4`), one
/// per lane: the last group repeats its last triangle in the unused lanes
/// (a repeat never beats itself under `closer`). Lanes are taken in order
/// and `closer` orders hits by (t, id), so the nearest is the scalar
/// loop's, and each lane's t, u, v are the scalar test's bits.
#[inline(always)]
pub(crate) fn leaf4<T: TriangleTest, const ANY: bool>(
    b: &BvhView<'_>,
    lanes4: &RayLanes<crate::geom::F4>,
    pre4: &T::Pre<crate::geom::F4>,
    at: LeafAt,
    best: &mut Hit,
    ctr: &mut Counters,
) -> bool {
    let depth = at.depth;
    let (first, end) = (at.first as usize, (at.first + at.count) as usize);
    let mut g = first;
    while g < end {
        let idx = core::array::from_fn(|k| (g + k).min(end - 1));
        ctr.tri_at(depth, (end - g).min(4) as u64);
        let mut h = T::intersect_tri4(lanes4, pre4, b.store(), idx);
        b.cull.apply4::<T>(lanes4, b.store(), idx, &mut h);
        let mut m = h.mask.bitmask();
        if m != 0 {
            let (t, u, v) = (h.t.to_array(), h.u.to_array(), h.v.to_array());
            while m != 0 {
                let k = m.trailing_zeros() as usize;
                m &= m - 1;
                let ray = || (lanes4.org.map(|x| x[0]), lanes4.dir.map(|x| x[0]));
                if take(b, ray, best, (t[k], u[k], v[k]), b.tri_ids[idx[k]]) && ANY {
                    return true;
                }
            }
        }
        g += 4;
    }
    false
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;
    use crate::accel::bvh::build::build;
    use crate::accel::bvh::build::testutil::{Store, deep_tris, soup};
    use crate::accel::bvh::{BuildQuality, BvhParams};
    pub use crate::accel::testkit::{Rng, test_rays, tris_of};
    use crate::geom::{INVALID_ID, Mt, Pt, Scene, TriTest, Wt};

    /// Nearest (or, with `any`, some) hit by testing every stored triangle.
    pub fn brute<T: TriangleTest>(b: &BvhView<'_>, ray: &Ray) -> Hit {
        let mut best = Hit::MISS;
        if !ray.is_valid() {
            return best;
        }
        let lanes = RayLanes::from_ray(ray);
        let pre = T::prepare(&lanes);
        for i in 0..b.tris.len() {
            let h = T::intersect(&lanes, &pre, T::prim(b.store(), i));
            if h.mask && closer(h.t, b.tri_ids[i], &best) {
                best = Hit {
                    t: h.t,
                    prim: b.tri_ids[i],
                    u: h.u,
                    v: h.v,
                };
            }
        }
        best
    }

    fn same(a: &Hit, b: &Hit) -> bool {
        a.prim == b.prim
            && a.t.to_bits() == b.t.to_bits()
            && a.u.to_bits() == b.u.to_bits()
            && a.v.to_bits() == b.v.to_bits()
    }

    fn check_scene<T: TriangleTest>(
        v: &[f32],
        ix: &[u32],
        views: &[crate::scenes::View],
        p: &BvhParams,
    ) {
        let scene = Scene::from_f32(v, ix).unwrap();
        let mut st = Store::new(scene.triangle_count() as usize, true);
        let mut bvh = st.bvh();
        build(&mut bvh, &scene, p).unwrap();
        let view = bvh.view().unwrap();
        let rays = test_rays(&tris_of(&scene), views, 0x9e37_79b9 ^ ix.len() as u64);
        let mut ctr = Counters::default();
        let mut hits = 0;
        for (k, ray) in rays.iter().enumerate() {
            let want = brute::<T>(&view, ray);
            let got = intersect::<T>(&view, ray, &mut ctr);
            assert!(
                same(&got, &want),
                "ray {k} {ray:?} ({:?}): bvh {got:?} brute {want:?}",
                T::KIND
            );
            assert_eq!(
                occluded::<T>(&view, ray, &mut ctr),
                want.is_hit(),
                "ray {k} {ray:?} occluded ({:?})",
                T::KIND
            );
            let any = any_hit::<T>(&view, ray, &mut ctr);
            assert_eq!(any.is_hit(), want.is_hit());
            if any.is_hit() {
                assert!(
                    any.t >= ray.tmin
                        && any.t < ray.tmax
                        && view.slot_of[any.prim as usize] != INVALID_ID
                );
            }
            hits += want.is_hit() as u32;
        }
        assert_eq!(ctr.rays, 3 * rays.len() as u64);
        if view.info.triangles > 0 {
            assert!(hits > 0, "some rays should hit");
        }
    }

    fn check_all_tests(v: &[f32], ix: &[u32], views: &[crate::scenes::View], leaf_size: u32) {
        for (test, bins, quality) in [
            (TriTest::MollerTrumbore, 16, BuildQuality::Medium),
            (TriTest::MollerTrumbore, 16, BuildQuality::Low),
            (TriTest::Watertight, 8, BuildQuality::Low),
            (TriTest::Projection, 32, BuildQuality::High),
        ] {
            let p = BvhParams {
                leaf_size,
                bins,
                traversal_cost: 1.0,
                test,
                quality,
                width: 2,
                presplit: false,
            };
            match test {
                TriTest::MollerTrumbore => check_scene::<Mt>(v, ix, views, &p),
                TriTest::Watertight => check_scene::<Wt>(v, ix, views, &p),
                TriTest::Projection => check_scene::<Pt>(v, ix, views, &p),
            }
        }
    }

    #[test]
    fn matches_brute_force_builtin() {
        for &name in crate::scenes::BUILTIN_NAMES {
            let s = crate::scenes::builtin(name).unwrap();
            check_all_tests(&s.mesh.vertices, &s.mesh.indices, &s.views, 4);
        }
    }

    #[test]
    fn matches_brute_force_small_leaves_and_ties() {
        let s = crate::scenes::builtin("tetra").unwrap();
        check_all_tests(&s.mesh.vertices, &s.mesh.indices, &s.views, 1);
        check_all_tests(&s.mesh.vertices, &s.mesh.indices, &s.views, 64);
        // Coincident copies: every hit ties; the lowest id must win.
        let t = [[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]];
        let mut tris = vec![t; 257];
        tris.push([[0.0, 0.0, 0.5], [1.0, 0.0, 0.5], [0.0, 1.0, 0.5]]);
        tris.extend(vec![
            [[0.0, 0.0, 0.5], [1.0, 0.0, 0.5], [0.0, 1.0, 0.5]];
            100
        ]);
        tris.reverse();
        let (v, ix) = soup(&tris);
        check_all_tests(&v, &ix, &[], 4);
        check_all_tests(&v, &ix, &[], 1);
    }

    #[test]
    fn matches_brute_force_at_max_depth() {
        let (v, ix) = soup(&deep_tris());
        for (test, quality) in [
            (TriTest::MollerTrumbore, BuildQuality::Medium),
            (TriTest::Watertight, BuildQuality::Low),
            (TriTest::Projection, BuildQuality::High),
        ] {
            let p = BvhParams {
                leaf_size: 1,
                bins: 2,
                traversal_cost: 1.0,
                test,
                quality,
                width: 2,
                presplit: false,
            };
            match test {
                TriTest::MollerTrumbore => check_scene::<Mt>(&v, &ix, &[], &p),
                TriTest::Watertight => check_scene::<Wt>(&v, &ix, &[], &p),
                TriTest::Projection => check_scene::<Pt>(&v, &ix, &[], &p),
            }
        }
    }

    #[test]
    fn empty_bvh_misses() {
        let (v, ix) = soup(&[[[0.0; 3], [1.0, 0.0, 0.0], [2.0, 0.0, 0.0]]]);
        check_all_tests(&v, &ix, &[], 4);
        check_all_tests(&[], &[], &[], 4);
    }
}
