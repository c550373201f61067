//! Ray primitives: the 2x2 SIMD triangle tests equal the single-ray ones bit
//! for bit, axis-parallel rays are exact, the watertight test does not leak.

use glam::Vec3;
use sheaf::geom::lane::F4;
use sheaf::geom::triangle::{RayLanes, TriVerts, TriangleTest};
use sheaf::geom::{Mt, ProjTri, Pt, Ray, Ray4, Wt};

/// Small deterministic generator (xorshift) so failures reproduce.
struct Rng(u64);
impl Rng {
    fn next(&mut self) -> f32 {
        self.0 ^= self.0 << 13;
        self.0 ^= self.0 >> 7;
        self.0 ^= self.0 << 17;
        (self.0 >> 40) as f32 / (1u64 << 24) as f32
    }
    fn range(&mut self, a: f32, b: f32) -> f32 {
        a + (b - a) * self.next()
    }
    fn v3(&mut self, s: f32) -> [f32; 3] {
        [self.range(-s, s), self.range(-s, s), self.range(-s, s)]
    }
}

fn check_lanes<T: TriangleTest>(name: &str, prim: impl Fn(&TriVerts) -> T::Prim) {
    let mut rng = Rng(0x9e3779b97f4a7c15);
    let mut hits = 0;
    for case in 0..20_000 {
        let tri = TriVerts {
            v0: rng.v3(1.0),
            v1: rng.v3(1.0),
            v2: rng.v3(1.0),
        };
        let tri = prim(&tri);
        let mut rays = [Ray::new(Vec3::ZERO, Vec3::ONE, 0.0, f32::INFINITY); 4];
        for r in rays.iter_mut() {
            let o = rng.v3(3.0);
            let target = rng.v3(0.8);
            let mut d = [target[0] - o[0], target[1] - o[1], target[2] - o[2]];
            // Every fourth ray gets zero components (infinite reciprocals).
            if case % 4 == 0 {
                d[case / 4 % 3] = 0.0;
            }
            *r = Ray {
                org: o,
                tmin: 0.0,
                dir: d,
                tmax: f32::INFINITY,
            };
        }
        let r4 = Ray4::from_rays(&rays);
        let l4 = RayLanes::<F4>::from_ray4(&r4);
        let h4 = T::intersect(&l4, &T::prepare(&l4), &tri);
        for (i, r) in rays.iter().enumerate() {
            let l1 = RayLanes::<f32>::from_ray(r);
            let h1 = T::intersect(&l1, &T::prepare(&l1), &tri);
            assert_eq!(
                h1.mask,
                h4.mask.test(i),
                "{name} case {case} lane {i}: hit/miss differ"
            );
            if h1.mask {
                hits += 1;
                assert_eq!(
                    h1.t.to_bits(),
                    h4.t[i].to_bits(),
                    "{name} case {case} lane {i}: t differs"
                );
                assert_eq!(
                    h1.u.to_bits(),
                    h4.u[i].to_bits(),
                    "{name} case {case} lane {i}: u differs"
                );
                assert_eq!(
                    h1.v.to_bits(),
                    h4.v[i].to_bits(),
                    "{name} case {case} lane {i}: v differs"
                );
            }
        }
    }
    assert!(
        hits > 5_000,
        "{name}: the random cases must actually hit ({hits})"
    );
}

#[test]
fn simd_moller_trumbore_is_bitwise_equal_to_single_ray() {
    check_lanes::<Mt>("MT", |t| *t);
}

#[test]
fn simd_watertight_is_bitwise_equal_to_single_ray() {
    check_lanes::<Wt>("WT", |t| *t);
}

#[test]
fn simd_projection_test_is_bitwise_equal_to_single_ray() {
    check_lanes::<Pt>("projection", ProjTri::new);
}

#[test]
fn projection_test_agrees_with_moller_trumbore_away_from_edges() {
    // Same hit/miss decision and t within float error for rays that pass
    // clearly inside or outside (barycentrics from MT away from 0 and 1).
    let mut rng = Rng(99);
    let mut checked = 0;
    for _ in 0..20_000 {
        let tri = TriVerts {
            v0: rng.v3(1.0),
            v1: rng.v3(1.0),
            v2: rng.v3(1.0),
        };
        let o = rng.v3(3.0);
        let target = rng.v3(0.8);
        let r = Ray {
            org: o,
            tmin: 0.0,
            dir: [target[0] - o[0], target[1] - o[1], target[2] - o[2]],
            tmax: f32::INFINITY,
        };
        let l = RayLanes::<f32>::from_ray(&r);
        let m = Mt::intersect(&l, &(), &tri);
        let p = Pt::intersect(&l, &(), &ProjTri::new(&tri));
        let (u, v) = (m.u, m.v);
        let clear = u > 1e-3 && v > 1e-3 && u + v < 1.0 - 1e-3 || (!m.mask && !p.mask);
        if m.mask && clear {
            assert!(p.mask, "projection misses an interior hit");
            assert!(
                (p.t - m.t).abs() <= 1e-4 * m.t.abs().max(1.0),
                "t {} vs {}",
                p.t,
                m.t
            );
            assert!((p.u - u).abs() < 1e-3 && (p.v - v).abs() < 1e-3);
            checked += 1;
        }
    }
    assert!(checked > 1000, "too few interior hits exercised: {checked}");
}

fn hit1<T: TriangleTest<Prim = TriVerts>>(r: &Ray, tri: &TriVerts) -> Option<f32> {
    let l = RayLanes::<f32>::from_ray(r);
    let h = T::intersect(&l, &T::prepare(&l), tri);
    h.mask.then_some(h.t)
}

#[test]
fn axis_parallel_rays_hit_exactly() {
    let tri = TriVerts {
        v0: [-1.0, -1.0, 2.0],
        v1: [1.0, -1.0, 2.0],
        v2: [0.0, 1.0, 2.0],
    };
    let r = Ray {
        org: [0.0, 0.0, 0.0],
        tmin: 0.0,
        dir: [0.0, 0.0, 1.0],
        tmax: f32::INFINITY,
    };
    assert_eq!(hit1::<Mt>(&r, &tri), Some(2.0));
    assert_eq!(hit1::<Wt>(&r, &tri), Some(2.0));
    let r = Ray {
        dir: [0.0, 0.0, -1.0],
        ..r
    };
    assert_eq!(hit1::<Mt>(&r, &tri), None);
    assert_eq!(hit1::<Wt>(&r, &tri), None);
    // tmax is exclusive: a hit at exactly tmax is not reported.
    let r = Ray {
        dir: [0.0, 0.0, 1.0],
        tmax: 2.0,
        ..r
    };
    assert_eq!(hit1::<Mt>(&r, &tri), None);
    assert_eq!(hit1::<Wt>(&r, &tri), None);
}

#[test]
fn watertight_has_no_cracks_on_shared_edges_and_vertices() {
    // A fan of triangles around a shared vertex: rays aimed exactly at the
    // shared vertex and along shared edges must hit at least one triangle.
    let n = 7;
    let c = [0.25f32, -0.125, 3.0];
    let ring: Vec<[f32; 3]> = (0..n)
        .map(|k| {
            let a = k as f32 / n as f32 * std::f32::consts::TAU;
            [c[0] + a.cos(), c[1] + a.sin(), 3.0 + 0.1 * (k as f32).sin()]
        })
        .collect();
    let tris: Vec<TriVerts> = (0..n)
        .map(|k| TriVerts {
            v0: c,
            v1: ring[k],
            v2: ring[(k + 1) % n],
        })
        .collect();
    let mut targets = vec![c];
    for p in &ring {
        for s in [0.25f32, 0.5, 0.75] {
            targets.push([
                c[0] + (p[0] - c[0]) * s,
                c[1] + (p[1] - c[1]) * s,
                c[2] + (p[2] - c[2]) * s,
            ]);
        }
    }
    let mut rng = Rng(7);
    for origin in 0..50 {
        let o = [
            rng.range(-2.0, 2.0),
            rng.range(-2.0, 2.0),
            rng.range(-1.0, 0.5),
        ];
        for t in &targets {
            let r = Ray {
                org: o,
                tmin: 0.0,
                dir: [t[0] - o[0], t[1] - o[1], t[2] - o[2]],
                tmax: f32::INFINITY,
            };
            let any = tris.iter().any(|tri| hit1::<Wt>(&r, tri).is_some());
            assert!(any, "watertight leak: origin {origin} {o:?} towards {t:?}");
        }
    }
}

/// `isa::Chosen` runs a lane function at the width asked for (the library
/// as it ships: its own unit tests compile every traversal at 4 lanes).
#[test]
fn chosen_runs_the_width_asked_for() {
    use sheaf::Isa;
    use sheaf::geom::wide::Wide;
    use sheaf::isa::{Chosen, LaneFn, Sig, detected, run_fn};
    struct Width;
    impl Sig for Width {
        type Args<'a> = ();
        type Out = usize;
    }
    impl LaneFn<Width> for Width {
        #[inline(always)]
        fn call<W: Wide>(_: ()) -> usize {
            W::WIDTH
        }
    }
    assert_eq!(run_fn::<Width, Width>(Isa::Sse2, ()), 4);
    assert_eq!(run_fn::<Width, Width>(Isa::Auto, ()), Isa::Auto.lanes());
    assert_eq!(Chosen::<Width>::baseline::<Width>().call(()), 4);
    if detected() >= Isa::Avx2 {
        assert_eq!(run_fn::<Width, Width>(Isa::Avx2, ()), 8);
    }
    if detected() >= Isa::Avx512 {
        assert_eq!(run_fn::<Width, Width>(Isa::Avx512, ()), 16);
    }
}
