//! The exactness harness of `bvh_exact.rs` and `kd_exact.rs`: a view's rays
//! as n x n packets in the renderer's layout, ray classes (primary, shadow,
//! reflection, refraction), and the check that every packet method of a
//! list returns the single ray's triangle and bitwise t, lane by lane.

use glam::Vec3;
use sheaf::accel::slot::SlotBuf;
use sheaf::geom::{Aabb, Hit4, M4, Ray4};
use sheaf::render::{Tracer, demorton};
use sheaf::trace::{BvhOptions, EntrySearch, RayKind};
use sheaf::{Counters, Hit, Isa, Method, Ray, TraceParams};

pub const RES: usize = 64;

/// Row-major rays of a `RES x RES` image as n x n packets of 2x2 quads, quads
/// in Morton order (the renderer's layout, which the primary frustum reads):
/// (quads, ray index of every lane).
pub fn packets(rays: &[Ray], n: usize) -> Vec<(Vec<Ray4>, Vec<usize>)> {
    let mut out = Vec::new();
    for ty in (0..RES).step_by(n) {
        for tx in (0..RES).step_by(n) {
            let (mut quads, mut idx) = (Vec::new(), Vec::new());
            for q in 0..(n / 2) * (n / 2) {
                let (qx, qy) = demorton(q);
                let (x, y) = (tx + 2 * qx as usize, ty + 2 * qy as usize);
                let ids = [
                    y * RES + x,
                    y * RES + x + 1,
                    (y + 1) * RES + x,
                    (y + 1) * RES + x + 1,
                ];
                quads.push(Ray4::from_rays(&ids.map(|i| rays[i])));
                idx.extend(ids);
            }
            out.push((quads, idx));
        }
    }
    out
}

/// Rays of one class with the kind their frustum is built for and the
/// active lanes (inactive rays are not compared).
pub struct Class {
    pub name: &'static str,
    pub rays: Vec<Ray>,
    pub active: Vec<bool>,
    pub kind: RayKind,
    pub any: bool,
}

pub fn reference(tr: &impl Tracer, c: &Class) -> Vec<Hit> {
    let mut ctr = Counters::default();
    c.rays
        .iter()
        .map(|r| {
            if c.any {
                if tr.occluded(r, &mut ctr) {
                    Hit {
                        t: 0.0,
                        prim: 0,
                        u: 0.0,
                        v: 0.0,
                    }
                } else {
                    Hit::MISS
                }
            } else {
                tr.intersect(r, &mut ctr)
            }
        })
        .collect()
}

/// Every method x packet side x culling x kind against the single ray.
pub fn check_class(
    tr: &impl Tracer,
    cases: &[(Method, usize, EntrySearch)],
    what: &str,
    c: &Class,
) -> Counters {
    let want = reference(tr, c);
    let mut own = SlotBuf::new(0);
    let mut slot = own.slot();
    let mut total = Counters::default();
    // Every lane width (`sheaf::isa`): the CPU's own with every option,
    // the others (run in baseline code where the CPU lacks them) with the
    // class's frustum.
    sheaf::isa::set_emulation(true);
    let mut combos = Vec::new();
    for culling in [true, false] {
        for kind in [c.kind, RayKind::Auto] {
            combos.push((culling, kind, Isa::Auto));
        }
    }
    for isa in [Isa::Sse2, Isa::Avx2, Isa::Avx512] {
        if isa != sheaf::isa::effective(Isa::Auto) {
            combos.push((true, c.kind, isa));
        }
    }
    for &(method, n, entry) in cases {
        // The large packets run wide lanes (the 2x2 SIMD rays and single
        // rays are 4-wide or scalar at every level).
        let wide = matches!(
            method,
            Method::BvhMasked
                | Method::BvhRanged
                | Method::BvhPartition
                | Method::BvhWideRanged
                | Method::BvhFrustum
                | Method::KdPacket
        );
        for &(culling, kind, isa) in &combos {
            // Lane widths are checked from the root (entry points start
            // the same walks: kd_exact.rs covers them at the CPU's width).
            if isa != Isa::Auto && (!wide || entry != EntrySearch::None) {
                continue;
            }
            {
                let p = TraceParams {
                    method,
                    packet: n as u32,
                    bvh: BvhOptions { culling, kind },
                    entry,
                    isa,
                    ..TraceParams::default()
                };
                // One choice for the whole class, as a renderer makes it.
                let traced = tr.packets(&p, c.any);
                for (quads, idx) in packets(&c.rays, n) {
                    let active: Vec<M4> = idx
                        .chunks(4)
                        .map(|k| {
                            M4::new(
                                c.active[k[0]],
                                c.active[k[1]],
                                c.active[k[2]],
                                c.active[k[3]],
                            )
                        })
                        .collect();
                    let mut hits = vec![Hit4::MISS; quads.len()];
                    traced.run(&p, &quads, &active, &mut hits, &mut slot, &mut total);
                    for (k, &ri) in idx.iter().enumerate() {
                        if !c.active[ri] {
                            continue;
                        }
                        let got = hits[k / 4].lane(k % 4);
                        let exp = want[ri];
                        let ok = if c.any {
                            got.is_hit() == exp.is_hit()
                        } else {
                            got.prim == exp.prim && got.t.to_bits() == exp.t.to_bits()
                        };
                        assert!(
                            ok,
                            "{what} {}: {} {n}x{n} {entry:?} culling {culling} {kind:?} {isa:?}: ray {ri} {:?}\n  packet {got:?}\n  single {exp:?}",
                            c.name,
                            method.name(),
                            c.rays[ri]
                        );
                    }
                }
            }
        }
    }
    total
}

/// Shadow rays from `light` to just off (`eps` along the normal, toward
/// the ray) the surfaces the primary `rays` hit (`hits`); rays that miss
/// are inactive.
pub fn shadow(tr: &impl Tracer, rays: &[Ray], hits: &[Hit], light: Vec3, eps: f32) -> Class {
    let mut shadow = Class {
        name: "shadow",
        rays: rays.to_vec(),
        active: vec![false; rays.len()],
        kind: RayKind::Shadow,
        any: true,
    };
    for (i, (r, h)) in rays.iter().zip(hits).enumerate() {
        if let Some(tri) = h.is_hit().then(|| tr.triangle(h.prim)).flatten() {
            let mut n = tri.normal().normalize_or_zero();
            if n.dot(Vec3::from(r.dir)) > 0.0 {
                n = -n;
            }
            let end = Vec3::from(r.org) + Vec3::from(r.dir) * h.t + n * eps;
            shadow.rays[i] = Ray::new(light, end - light, 0.0, 1.0);
            shadow.active[i] = true;
        }
    }
    shadow
}

/// Reflection and refraction rays of the primary hits (every hit reflects
/// and refracts with index 1.5; total internal reflection gives no ray).
pub fn secondary(tr: &impl Tracer, rays: &[Ray], hits: &[Hit], eps: f32) -> (Class, Class) {
    let pad = Ray::new(Vec3::ZERO, Vec3::X, 0.0, 0.0);
    let mut refl = Class {
        name: "reflection",
        rays: vec![pad; rays.len()],
        active: vec![false; rays.len()],
        kind: RayKind::Secondary,
        any: false,
    };
    let mut refr = Class {
        name: "refraction",
        rays: vec![pad; rays.len()],
        active: vec![false; rays.len()],
        kind: RayKind::Secondary,
        any: false,
    };
    for (i, (r, h)) in rays.iter().zip(hits).enumerate() {
        let Some(tri) = h.is_hit().then(|| tr.triangle(h.prim)).flatten() else {
            continue;
        };
        let d = Vec3::from(r.dir).normalize();
        let mut n = tri.normal().normalize_or_zero();
        let entering = n.dot(d) < 0.0;
        if !entering {
            n = -n;
        }
        let p = Vec3::from(r.org) + Vec3::from(r.dir) * h.t;
        let rd = d - 2.0 * d.dot(n) * n;
        refl.rays[i] = Ray::new(p + n * eps, rd, 0.0, f32::INFINITY);
        refl.active[i] = true;
        let eta = if entering { 1.0 / 1.5 } else { 1.5 };
        let cos_i = -d.dot(n);
        let k = 1.0 - eta * eta * (1.0 - cos_i * cos_i);
        if k > 0.0 {
            let td = eta * d + (eta * cos_i - k.sqrt()) * n;
            refr.rays[i] = Ray::new(p - n * eps, td, 0.0, f32::INFINITY);
            refr.active[i] = true;
        }
    }
    (refl, refr)
}

/// Incoherent packets: random directions (mixed signs) from one origin
/// near the center of `bounds` and from origins scattered over it, some
/// lanes inactive, some invalid (a NaN origin, a zero direction); every
/// method of `cases` against the single ray, nearest hits and occlusion.
/// `scene` names the scene in failures.
pub fn check_random_packets(
    tr: &impl Tracer,
    cases: &[(Method, usize, EntrySearch)],
    scene: &str,
    bounds: &Aabb,
) {
    let (c, r) = (bounds.min.lerp(bounds.max, 0.5), bounds.diagonal().length());
    let mut seed = 0x9e3779b9u32;
    let mut rnd = move || {
        seed ^= seed << 13;
        seed ^= seed >> 17;
        seed ^= seed << 5;
        seed as f32 / u32::MAX as f32 * 2.0 - 1.0
    };
    for common_origin in [true, false] {
        let mut rays = Vec::new();
        let mut active = Vec::new();
        for i in 0..RES * RES {
            let o = if common_origin {
                c + Vec3::new(0.1, 0.2, 0.3) * r
            } else {
                c + Vec3::new(rnd(), rnd(), rnd()) * r
            };
            let mut d = Vec3::new(rnd(), rnd(), rnd());
            if i % 97 == 0 {
                d = Vec3::ZERO;
            }
            let mut ray = Ray::new(o, d, 0.0, f32::INFINITY);
            if i % 89 == 0 {
                ray.org[1] = f32::NAN;
            }
            rays.push(ray);
            active.push(i % 7 != 0);
        }
        for any in [false, true] {
            let class = Class {
                name: if any { "random occlusion" } else { "random" },
                rays: rays.clone(),
                active: active.clone(),
                kind: RayKind::Auto,
                any,
            };
            let what = format!("{scene} common origin {common_origin}");
            check_class(tr, cases, &what, &class);
        }
    }
}
