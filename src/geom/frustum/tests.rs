//! Frustum tests, checked against BVH traversals (test-only use of a structure).

use super::*;
use crate::accel::bvh::BvhView;
use crate::accel::bvh::build::testutil::Store;
use crate::accel::bvh::packet::QuadBox;
use crate::accel::bvh::traverse_masked::tests::{RaySet, built, lattice, packets, ray_sets};
use crate::geom::{Mt, RayLanes, TriangleTest, Wt};
use glam::Vec3;

/// Origin and direction of each live lane.
fn lanes<'a>(rays: &'a [Ray4], live: &'a [M4]) -> impl Iterator<Item = (V3, V3)> + 'a {
    rays.iter().zip(live).flat_map(|(r, m)| {
        let m = *m;
        (0..4).filter(move |&i| m.test(i)).map(move |i| {
            (
                [r.org[0][i] as f64, r.org[1][i] as f64, r.org[2][i] as f64],
                [r.dir[0][i] as f64, r.dir[1][i] as f64, r.dir[2][i] as f64],
            )
        })
    })
}

/// Active lanes with valid rays.
fn live_of(quads: &[Ray4], active: &[M4]) -> Vec<M4> {
    quads
        .iter()
        .zip(active)
        .map(|(r, m)| {
            let mut l = *m;
            for i in 0..4 {
                if !r.lane(i).is_valid() {
                    l.set(i, false);
                }
            }
            l
        })
        .collect()
}

#[derive(Default, Debug)]
struct Tally {
    frusta: u64,
    tris: u64,
    tris_culled: u64,
    nodes: u64,
    nodes_culled: u64,
}

/// Every live ray inside `f` wherever it can meet geometry, and nothing
/// a live ray hits (triangle tests, slab tests) culled.
fn check(b: &BvhView<'_>, quads: &[Ray4], live: &[M4], f: &Frustum, what: &str, tally: &mut Tally) {
    let root = b.nodes[0].aabb();
    tally.frusta += 1;
    // Sample points: within the root box (and from the apex on).
    for (o, d) in lanes(quads, live) {
        let (of, df) = (
            Vec3::new(o[0] as f32, o[1] as f32, o[2] as f32),
            Vec3::new(d[0] as f32, d[1] as f32, d[2] as f32),
        );
        let Some((t0, t1)) = root.clip_ray(of, df, df.recip(), 0.0, f32::INFINITY) else {
            continue;
        };
        for s in 0..=16 {
            let t = t0 as f64 + (t1 as f64 - t0 as f64) * s as f64 / 16.0;
            let p = [o[0] + t * d[0], o[1] + t * d[1], o[2] + t * d[2]];
            for i in 0..4 {
                let h = f.h(i, p);
                assert!(
                    h <= f.margin - 0.5 * f.eps,
                    "{what}: ray {o:?} {d:?} t {t}: plane {i} H {h} margin {}",
                    f.margin
                );
            }
        }
    }
    // Triangles some live ray hits in [0, inf) are kept.
    let mut unbounded: Vec<Ray4> = quads.to_vec();
    for r in &mut unbounded {
        r.tmin = F4::ZERO;
        r.tmax = F4::INFINITY;
    }
    // Each quad's lanes and watertight precomputation, made once.
    let prepared: Vec<_> = unbounded
        .iter()
        .map(|r| {
            let l = RayLanes::from_ray4(r);
            let pre = Wt::prepare(&l);
            (l, pre)
        })
        .collect();
    for (i, t) in b.tris.iter().enumerate() {
        let culled = f.cull_triangle(t);
        tally.tris += 1;
        tally.tris_culled += culled as u64;
        if !culled {
            continue;
        }
        for (q, (l, pre)) in prepared.iter().enumerate() {
            let hm = Mt::intersect(l, &(), t).mask | Wt::intersect(l, pre, t).mask;
            assert!(
                !(hm & live[q]).any(),
                "{what}: triangle {i} {t:?} culled but hit by quad {q} {:?}",
                hm & live[q]
            );
        }
    }
    // Boxes some live ray's slab test enters are kept.
    for (i, n) in b.nodes.iter().enumerate() {
        let culled = f.cull_box(&n.min, &n.max);
        tally.nodes += 1;
        tally.nodes_culled += culled as u64;
        if !culled {
            continue;
        }
        for (q, r) in unbounded.iter().enumerate() {
            let (m, _) = QuadBox::new(r).entry(n, F4::INFINITY);
            assert!(
                !(m & live[q]).any(),
                "{what}: node {i} culled but entered by quad {q}"
            );
        }
    }
}

fn check_sets(b: &BvhView<'_>, sets: &[RaySet], sides: &[u32], name: &str) -> Tally {
    let root = b.nodes[0].aabb();
    let mut tally = Tally::default();
    for set in sets {
        for &n in sides {
            for (quads, active, _) in packets(set, n) {
                let live = live_of(&quads, &active);
                for kind in [
                    RayKind::Primary,
                    RayKind::Auto,
                    RayKind::Shadow,
                    RayKind::Secondary,
                ] {
                    if let Some(f) = Frustum::new(kind, &quads, &live, &root) {
                        check(
                            b,
                            &quads,
                            &live,
                            &f,
                            &format!("{name} {} n={n} {kind:?} -> {:?}", set.name, f.kind),
                            &mut tally,
                        );
                    }
                }
            }
        }
    }
    tally
}

#[test]
fn rays_inside_and_hits_never_culled_builtin() {
    for name in ["tetra", "gears", "animated"] {
        let s = crate::scenes::builtin(name).unwrap();
        let mut st = Store::new(0, false);
        let bvh = built::<Mt>(&mut st, &s.mesh.vertices, &s.mesh.indices, 4);
        let b = bvh.view().unwrap();
        let sets = ray_sets::<Mt>(&b, &s.views[0], s.light, 32, 32, 99);
        let t = check_sets(&b, &sets, &[4, 16], name);
        assert!(
            t.frusta > 100 && t.tris_culled > t.tris / 4 && t.nodes_culled > 0,
            "{name}: {t:?}"
        );
    }
}

#[test]
fn rays_inside_and_hits_never_culled_lattice() {
    let (v, ix, sets) = lattice();
    let mut st = Store::new(0, false);
    let bvh = built::<Wt>(&mut st, &v, &ix, 2);
    let b = bvh.view().unwrap();
    let t = check_sets(&b, &sets, &[2, 4, 16, 32], "lattice");
    assert!(t.tris_culled > t.tris / 2, "{t:?}");
}

#[test]
fn kinds() {
    let (v, ix, sets) = lattice();
    let mut st = Store::new(0, false);
    let bvh = built::<Wt>(&mut st, &v, &ix, 2);
    let b = bvh.view().unwrap();
    let root = b.nodes[0].aabb();
    let kind_of = |set: &RaySet, n: u32, k: RayKind| {
        let (quads, active, _) = packets(set, n).swap_remove(0);
        Frustum::new(k, &quads, &live_of(&quads, &active), &root).map(|f| f.kind)
    };
    for n in [2, 4, 8, 16, 32] {
        assert_eq!(
            kind_of(&sets[0], n, RayKind::Primary),
            Some(FrustumKind::Primary)
        );
        assert_eq!(
            kind_of(&sets[0], n, RayKind::Auto),
            Some(FrustumKind::CommonOrigin)
        );
        assert_eq!(
            kind_of(&sets[1], n, RayKind::Shadow),
            Some(FrustumKind::CommonOrigin)
        );
        assert_eq!(
            kind_of(&sets[0], n, RayKind::Secondary),
            Some(FrustumKind::General)
        );
        assert_eq!(
            kind_of(&sets[2], n, RayKind::Auto),
            Some(FrustumKind::General)
        );
        // Not a pinhole packet: Primary falls back to Auto.
        assert_eq!(
            kind_of(&sets[2], n, RayKind::Primary),
            Some(FrustumKind::General)
        );
    }
    // Camera rays of every built-in view: full packets get the corner
    // frustum (the rounding of camera rays is within its tolerance).
    for name in crate::scenes::BUILTIN_NAMES {
        let sc = crate::scenes::builtin(name).unwrap();
        let mut st2 = Store::new(0, false);
        let bvh2 = built::<Mt>(&mut st2, &sc.mesh.vertices, &sc.mesh.indices, 4);
        let b2 = bvh2.view().unwrap();
        let root2 = b2.nodes[0].aabb();
        for view in &sc.views {
            let set = &ray_sets::<Mt>(&b2, view, sc.light, 64, 64, 1)[0];
            for n in [2, 4, 8, 16, 32] {
                for (quads, active, _) in packets(set, n) {
                    let f = Frustum::new(RayKind::Primary, &quads, &active, &root2).unwrap();
                    assert_eq!(f.kind, FrustumKind::Primary, "{name} {view:?} n={n}");
                }
            }
        }
    }
    // A partial packet (corner lanes inactive) falls back too.
    let (quads, mut active, _) = packets(&sets[0], 8).swap_remove(0);
    active[0] = M4::new(false, true, true, true);
    let f = Frustum::new(RayKind::Primary, &quads, &active, &root).unwrap();
    assert_eq!(f.kind, FrustumKind::CommonOrigin);
    // Directions on both sides of every axis: no frustum.
    let r = crate::geom::Ray::new(Vec3::splat(5.0), Vec3::X, 0.0, f32::INFINITY);
    let mut rays = [r; 4];
    rays[1].dir = [-1.0, 0.0, 0.0];
    let q = [Ray4::from_rays(&rays)];
    assert!(Frustum::new(RayKind::Auto, &q, &[M4::TRUE], &root).is_none());
    assert!(Frustum::new(RayKind::Secondary, &q, &[M4::TRUE], &root).is_none());
    // A single ray: a degenerate but valid frustum around it.
    let f = Frustum::new(
        RayKind::Auto,
        &q,
        &[M4::new(true, false, false, false)],
        &root,
    )
    .unwrap();
    assert!(f.cull_box(&[6.0; 3], &[7.0; 3]));
}
