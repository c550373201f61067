//! Single-ray kd-tree traversal: the reference every kd packet method, with
//! and without entry points, must match bit for bit (same triangle test,
//! same tie rule).
//!
//! Front to back with a fixed stack of `MAX_DEPTH + 1` entries (the build
//! never goes deeper): at an inner node the near child (by the direction's
//! sign on the split axis) is visited with `[t0, min(t1, t_s)]`, the far
//! child pushed with `[max(t0, t_s), t1]`; empty intervals are skipped. The
//! ray stops after the leaf whose interval ends at or beyond its nearest
//! hit (the classic early termination; Havran 2000, TA_B^rec).

use super::{KdView, MAX_DEPTH, TriangleTest, clip, split_interval};
use crate::counters::Counters;
use crate::geom::closer;
use crate::geom::{Hit, Ray, RayLanes};

/// Nearest hit of `ray` (a miss for invalid rays: see `Ray::is_valid`).
#[inline]
pub fn intersect<T: TriangleTest>(k: &KdView<'_>, ray: &Ray, ctr: &mut Counters) -> Hit {
    walk::<T, false>(k, ray, ctr)
}

/// Whether anything lies on `ray` in `[tmin, tmax)`.
#[inline]
pub fn occluded<T: TriangleTest>(k: &KdView<'_>, ray: &Ray, ctr: &mut Counters) -> bool {
    walk::<T, true>(k, ray, ctr).is_hit()
}

/// Some hit on `ray` in `[tmin, tmax)` (the first found), or a miss.
#[inline]
pub fn any_hit<T: TriangleTest>(k: &KdView<'_>, ray: &Ray, ctr: &mut Counters) -> Hit {
    walk::<T, true>(k, ray, ctr)
}

/// One ray's traversal constants.
#[derive(Clone, Copy, Debug)]
pub(crate) struct KdRay {
    pub org: [f32; 3],
    pub rcp: [f32; 3],
    pub neg: [bool; 3],
}

impl KdRay {
    #[inline(always)]
    pub(crate) fn new(ray: &Ray) -> KdRay {
        let mut r = KdRay {
            org: ray.org,
            rcp: [0.0; 3],
            neg: [false; 3],
        };
        for a in 0..3 {
            r.rcp[a] = 1.0 / ray.dir[a];
            // The sign bit: -0 travels towards the left child's side last.
            r.neg[a] = ray.dir[a].is_sign_negative();
        }
        r
    }
}

fn walk<T: TriangleTest, const ANY: bool>(k: &KdView<'_>, ray: &Ray, ctr: &mut Counters) -> Hit {
    ctr.rays += 1;
    let mut best = Hit::MISS;
    if !ray.is_valid() || k.nodes.is_empty() || k.info.triangles == 0 {
        return best;
    }
    let kr = KdRay::new(ray);
    let root = &k.info.root;
    let (t0, t1) = clip(
        &root.min.to_array(),
        &root.max.to_array(),
        &kr.org,
        &kr.rcp,
        &kr.neg,
        ray.tmin,
        ray.tmax,
    );
    // A NaN bound misses as an empty interval does.
    if t0 <= t1 {
        let at = Visit {
            node: 0,
            depth: 0,
            t0,
            t1,
        };
        from_node::<T, ANY>(k, ray, &kr, at, &mut best, ctr);
    }
    best
}

/// Where a ray's walk starts: a node, its depth (root 0), and the ray's
/// interval `[t0, t1]` in it.
#[derive(Clone, Copy, Debug)]
pub(crate) struct Visit {
    pub node: usize,
    pub depth: usize,
    pub t0: f32,
    pub t1: f32,
}

/// Traverse the subtree of `at.node` with the ray's interval there,
/// updating `best`. Used from the root and from entry points (packets
/// whose lanes fall back to single rays).
#[inline]
pub(crate) fn from_node<T: TriangleTest, const ANY: bool>(
    k: &KdView<'_>,
    ray: &Ray,
    kr: &KdRay,
    at: Visit,
    best: &mut Hit,
    ctr: &mut Counters,
) {
    let lanes = RayLanes::from_ray(ray);
    let pre = T::prepare(&lanes);
    let nodes = k.nodes;
    // (node, depth, t0, t1) of pushed far children.
    let mut st = [(0u32, 0u8, 0.0f32, 0.0f32); MAX_DEPTH + 1];
    let mut sp = 0usize;
    let Visit {
        mut node,
        mut depth,
        mut t0,
        mut t1,
    } = at;
    loop {
        let n = &nodes[node];
        if !n.is_leaf() {
            let a = n.axis();
            ctr.aabb_at(depth, 1);
            let ts = (n.split() - kr.org[a]) * kr.rcp[a];
            let (near_hi, far_lo) = split_interval(ts, t0, t1);
            let l = n.left();
            let (near, far) = if kr.neg[a] { (l + 1, l) } else { (l, l + 1) };
            depth += 1;
            let go_near = t0 <= near_hi;
            let go_far = far_lo <= t1;
            if go_near {
                if go_far {
                    st[sp] = (far as u32, depth as u8, far_lo, t1);
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
            for &s in k.leaf_refs(n) {
                ctr.tri_at(depth, 1);
                let s = s as usize;
                let h = T::intersect(&lanes, &pre, T::prim(k.store(), s));
                if h.mask {
                    let id = k.tri_ids[s];
                    if closer(h.t, id, best)
                        && k.filter.accepts(lanes.org, lanes.dir, h.t, h.u, h.v, id)
                    {
                        *best = Hit {
                            t: h.t,
                            prim: id,
                            u: h.u,
                            v: h.v,
                        };
                        if ANY {
                            return;
                        }
                    }
                }
            }
            // Early termination: nothing beyond this leaf can be nearer.
            if best.t <= t1 {
                return;
            }
        }
        if sp == 0 {
            return;
        }
        sp -= 1;
        let (n2, d2, a0, a1) = st[sp];
        node = n2 as usize;
        depth = d2 as usize;
        t0 = a0;
        t1 = a1;
    }
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;
    use crate::accel::kd::KdParams;
    use crate::accel::kd::build::build;
    use crate::accel::kd::build::testutil::Store;
    use crate::accel::testkit::{test_rays, tris_of};
    use crate::geom::{Mt, Pt, Scene, TriTest, Wt};

    /// Nearest (tie rule) hit by testing every stored triangle.
    pub fn brute<T: TriangleTest>(k: &KdView<'_>, ray: &Ray) -> Hit {
        let mut best = Hit::MISS;
        if !ray.is_valid() {
            return best;
        }
        let lanes = RayLanes::from_ray(ray);
        let pre = T::prepare(&lanes);
        for s in 0..k.tris.len() {
            let h = T::intersect(&lanes, &pre, T::prim(k.store(), s));
            if h.mask && closer(h.t, k.tri_ids[s], &best) {
                best = Hit {
                    t: h.t,
                    prim: k.tri_ids[s],
                    u: h.u,
                    v: h.v,
                };
            }
        }
        best
    }

    pub fn same(a: &Hit, b: &Hit) -> bool {
        a.prim == b.prim
            && a.t.to_bits() == b.t.to_bits()
            && a.u.to_bits() == b.u.to_bits()
            && a.v.to_bits() == b.v.to_bits()
    }

    fn check_scene<T: TriangleTest>(
        scene: &Scene<'_>,
        views: &[crate::scenes::View],
        p: &KdParams,
    ) {
        let mut st = Store::new(scene.triangle_count() as usize, true);
        let mut kd = st.kd();
        build(&mut kd, scene, p).unwrap();
        let view = kd.view().unwrap();
        let rays = test_rays(
            &tris_of(scene),
            views,
            0x51ed_270b ^ scene.triangle_count() as u64,
        );
        let mut ctr = Counters::default();
        for (i, ray) in rays.iter().enumerate() {
            let want = brute::<T>(&view, ray);
            let got = intersect::<T>(&view, ray, &mut ctr);
            assert!(
                same(&got, &want),
                "ray {i} {ray:?} ({:?}): kd {got:?} brute {want:?}",
                T::KIND
            );
            assert_eq!(
                occluded::<T>(&view, ray, &mut ctr),
                want.is_hit(),
                "ray {i} occluded"
            );
        }
    }

    #[test]
    fn single_ray_matches_brute_force_on_builtin_scenes() {
        for name in crate::scenes::BUILTIN_NAMES {
            let sc = crate::scenes::builtin(name).unwrap();
            let scene = Scene::from_f32(&sc.mesh.vertices, &sc.mesh.indices).unwrap();
            for test in [
                TriTest::MollerTrumbore,
                TriTest::Watertight,
                TriTest::Projection,
            ] {
                let p = KdParams {
                    test,
                    ..KdParams::default()
                };
                match test {
                    TriTest::MollerTrumbore => check_scene::<Mt>(&scene, &sc.views, &p),
                    TriTest::Watertight => check_scene::<Wt>(&scene, &sc.views, &p),
                    TriTest::Projection => check_scene::<Pt>(&scene, &sc.views, &p),
                }
            }
        }
    }
}
