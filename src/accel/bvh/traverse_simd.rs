//! The 2x2 SIMD ray (BVH paper section 2.1; Wald, Slusallek, Benthin,
//! Wagner 2001, "Interactive Rendering with Coherent Ray Tracing"): the four
//! rays of one `Ray4` traverse the BVH together, one node at a time. A node
//! is entered when any live lane's interval `[tmin, min(tmax, best.t)]`
//! overlaps its box; every live lane is tested against every triangle of an
//! entered leaf (4-wide, the same `Lane` arithmetic as the single ray), and
//! each lane keeps its own nearest hit by the tie rule of `geom::ray`.
//!
//! This is Table 2's baseline ("2x2 SIMD ray packets"), which the large
//! packet traversals are measured against. Results equal `traverse_single`
//! lane by lane, bitwise.
//!
//! # Deviations
//! - Each quad of the input is traced on its own (a packet of one `Ray4`);
//!   larger packets are the Masked, Ranged and Partition traversals.
//! - The near child is chosen by the sign of the first live lane's
//!   direction on the node's split axis; lanes going the other way still
//!   visit both children, only in a worse order.
//! - Lanes with tiny directions (`accel::fallback::tiny`) are traced alone
//!   by `traverse_single` and replaced in the quad (`quieted`).
//! - A quad failing `accel::fallback::coherent` (its four directions over
//!   more than a 30 degree cone, or origins far apart) is traced lane by
//!   lane by `traverse_single`.

use super::packet::QuadBox;
use super::{BvhView, MAX_DEPTH, TriangleTest};
use crate::accel::fallback;
use crate::accel::group;
use crate::accel::packet::{PacketArgs, PacketSig};
use crate::counters::Counters;
use crate::geom::{F4, Hit, Hit4, INVALID_ID, M4, Ray4, RayLanes, Wide};
use crate::isa::LaneFn;

/// Nearest hits of the active lanes of `rays` into `hits` (one quad at a
/// time; `rays`, `active` and `hits` are read up to the shortest length).
/// Active lanes are written (`Hit::MISS` when nothing is hit, and for
/// invalid rays); inactive lanes are left untouched.
pub fn intersect<T: TriangleTest>(
    b: &BvhView<'_>,
    rays: &[Ray4],
    active: &[M4],
    hits: &mut [Hit4],
    fallbacks: bool,
    ctr: &mut Counters,
) {
    for ((r, m), h) in rays.iter().zip(active).zip(hits.iter_mut()) {
        quad::<T, false>(b, r, *m, h, fallbacks, ctr);
    }
}

/// Occlusion of the active lanes: `hits[q].prim[i] != INVALID_ID` marks an
/// occluded lane (t and id of some occluder in `[tmin, tmax)`, not the
/// nearest); other active lanes get `Hit::MISS`, inactive ones are untouched.
pub fn occluded<T: TriangleTest>(
    b: &BvhView<'_>,
    rays: &[Ray4],
    active: &[M4],
    hits: &mut [Hit4],
    fallbacks: bool,
    ctr: &mut Counters,
) {
    for ((r, m), h) in rays.iter().zip(active).zip(hits.iter_mut()) {
        quad::<T, true>(b, r, *m, h, fallbacks, ctr);
    }
}

/// The 2x2 SIMD ray on the packet contract (`accel::packet::PacketSig`),
/// quad by quad: its `Kernel` runs it in baseline code.
pub struct Simd<T, const ANY: bool>(core::marker::PhantomData<T>);

impl<'b, T: TriangleTest, const ANY: bool> LaneFn<PacketSig<BvhView<'b>>> for Simd<T, ANY> {
    #[inline(always)]
    fn call<W: Wide>(args: PacketArgs<'_, BvhView<'b>>) {
        let (b, p, rays, active, hits, _, ctr) = args;
        for ((r, m), h) in rays.iter().zip(active).zip(hits.iter_mut()) {
            quad::<T, ANY>(b, r, *m, h, p.fallbacks, ctr);
        }
    }
}

fn quad<T: TriangleTest, const ANY: bool>(
    b: &BvhView<'_>,
    r: &Ray4,
    active: M4,
    out: &mut Hit4,
    fallbacks: bool,
    ctr: &mut Counters,
) {
    ctr.packets += 1;
    // Active but invalid lanes are misses and take no part (Ray::is_valid).
    let mut live = active;
    for i in 0..4 {
        if active.test(i) && !r.lane(i).is_valid() {
            live.set(i, false);
        }
    }
    ctr.rays += live.bitmask().count_ones() as u64;
    let mut best = Hit4::MISS;
    let quiet;
    let mut r = r;
    if live.any() && !b.nodes.is_empty() {
        // Lanes with tiny directions alone (`accel::fallback::tiny`), and
        // out of the quad's arithmetic.
        let tiny = fallback::tiny(fallbacks, r, live);
        if tiny.any() {
            crate::accel::packet::alone::<BvhView, T, ANY>(
                b,
                core::slice::from_ref(r),
                &[tiny],
                core::slice::from_mut(&mut best),
                ctr,
            );
            live &= !tiny;
            quiet = fallback::quieted(r, tiny);
            r = &quiet;
        }
    }
    if live.any() && !b.nodes.is_empty() {
        if fallback::coherent(
            fallbacks,
            core::slice::from_ref(r),
            &[live],
            b.info.bounds.diagonal().length(),
        ) {
            walk::<T, ANY>(b, r, live, &mut best, ctr);
        } else {
            crate::accel::packet::alone::<BvhView, T, ANY>(
                b,
                core::slice::from_ref(r),
                &[live],
                core::slice::from_mut(&mut best),
                ctr,
            );
        }
    }
    for i in 0..4 {
        if active.test(i) {
            out.set_lane(
                i,
                if best.prim[i] == INVALID_ID {
                    Hit::MISS
                } else {
                    best.lane(i)
                },
            );
        }
    }
}

#[inline(always)]
fn walk<T: TriangleTest, const ANY: bool>(
    b: &BvhView<'_>,
    r: &Ray4,
    mut live: M4,
    best: &mut Hit4,
    ctr: &mut Counters,
) {
    let nodes = b.nodes;
    let qb = QuadBox::new(r);
    ctr.aabb_at(0, 1);
    let (h0, _) = qb.entry(&nodes[0], r.tmax);
    if !(h0 & live).any() {
        return;
    }
    let lanes = RayLanes::from_ray4(r);
    let pre = T::prepare(&lanes);
    // Child order from the first live lane.
    let f = live.bitmask().trailing_zeros() as usize;
    let neg = [
        r.dir[0][f].is_sign_negative(),
        r.dir[1][f].is_sign_negative(),
        r.dir[2][f].is_sign_negative(),
    ];
    let nan = F4::splat(f32::NAN);

    let mut st_node = [0u32; MAX_DEPTH + 1];
    let mut st_t = [F4::ZERO; MAX_DEPTH + 1];
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
            let tmax = F4::select(best.t.cmplt(r.tmax), best.t, r.tmax);
            ctr.aabb_at(depth + 1, 2);
            let (hn, _) = qb.entry(&nodes[near], tmax);
            let (hf, tf) = qb.entry(&nodes[far], tmax);
            let (hn, hf) = ((hn & live).any(), hf & live);
            depth += 1;
            match (hn, hf.any()) {
                (true, true) => {
                    st_node[sp] = far as u32;
                    // Lanes that miss the box get NaN: never <= best.t.
                    st_t[sp] = F4::select(hf, tf, nan);
                    st_depth[sp] = depth as u8;
                    sp += 1;
                    node = near;
                    continue;
                }
                (true, false) => {
                    node = near;
                    continue;
                }
                (false, true) => {
                    node = far;
                    continue;
                }
                (false, false) => {}
            }
        } else {
            let first = n.first as usize;
            let mut live_n = live.bitmask().count_ones() as u64;
            for i in first..first + n.count() as usize {
                ctr.tri_at(depth, live_n);
                let tri = T::prim(b.store(), i);
                let mut h = T::intersect(&lanes, &pre, tri);
                b.cull.apply::<T, F4>(&lanes.dir, tri, &mut h);
                let hm = h.mask & live;
                if hm.any() {
                    let id = b.tri_ids[i];
                    let ray = || (lanes.org, lanes.dir);
                    let take = group::take::<ANY>(best, hm, (h.t, h.u, h.v), id, &b.filter, ray);
                    if ANY && take.any() {
                        live &= !take;
                        if !live.any() {
                            return;
                        }
                        live_n = live.bitmask().count_ones() as u64;
                    }
                }
            }
        }
        // Pop the next node some live lane enters before its nearest hit.
        loop {
            if sp == 0 {
                return;
            }
            sp -= 1;
            if (st_t[sp].cmple(best.t) & live).any() {
                node = st_node[sp] as usize;
                depth = st_depth[sp] as usize;
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
    use crate::accel::bvh::traverse_single::{
        self,
        tests::{Rng, test_rays, tris_of},
    };
    use crate::accel::bvh::{BuildQuality, BvhParams};
    use crate::geom::lane::mask_from_bits;
    use crate::geom::{Mt, Pt, Ray, Scene, TriTest, Wt};

    fn same(a: &Hit, b: &Hit) -> bool {
        a.prim == b.prim
            && a.t.to_bits() == b.t.to_bits()
            && a.u.to_bits() == b.u.to_bits()
            && a.v.to_bits() == b.v.to_bits()
    }

    fn check<T: TriangleTest>(v: &[f32], ix: &[u32], views: &[crate::scenes::View], p: &BvhParams) {
        let scene = Scene::from_f32(v, ix).unwrap();
        let mut st = Store::new(scene.triangle_count() as usize, true);
        let mut bvh = st.bvh();
        build(&mut bvh, &scene, p).unwrap();
        let view = bvh.view().unwrap();
        let mut rays = test_rays(&tris_of(&scene), views, 0x51ed_270b ^ ix.len() as u64);
        while !rays.len().is_multiple_of(4) {
            rays.push(rays[rays.len() % 7]);
        }
        let quads: Vec<Ray4> = rays
            .chunks_exact(4)
            .map(|c| Ray4::from_rays(&[c[0], c[1], c[2], c[3]]))
            .collect();
        let mut rng = Rng(0x2545_f491);
        // Mixed masks: every third quad full, the others random.
        let active: Vec<M4> = (0..quads.len())
            .map(|q| {
                mask_from_bits(if q % 3 == 0 {
                    15
                } else {
                    (rng.next() % 16) as u32
                })
            })
            .collect();
        let sentinel = Hit {
            t: -7.0,
            prim: 0xdead,
            u: 3.0,
            v: 4.0,
        };
        let fill = {
            let mut h = Hit4::MISS;
            for i in 0..4 {
                h.set_lane(i, sentinel);
            }
            h
        };
        for any in [false, true] {
            let mut hits = vec![fill; quads.len()];
            let mut ctr = Counters::default();
            if any {
                occluded::<T>(&view, &quads, &active, &mut hits, true, &mut ctr);
            } else {
                intersect::<T>(&view, &quads, &active, &mut hits, true, &mut ctr);
            }
            let mut valid = 0;
            let mut c1 = Counters::default();
            for (q, (h, m)) in hits.iter().zip(&active).enumerate() {
                for i in 0..4 {
                    let ray: Ray = rays[4 * q + i];
                    assert_eq!(
                        bytemuck::bytes_of(&quads[q].lane(i)),
                        bytemuck::bytes_of(&ray)
                    );
                    let got = h.lane(i);
                    if !m.test(i) {
                        assert!(same(&got, &sentinel), "inactive lane {q}.{i} written");
                        continue;
                    }
                    valid += ray.is_valid() as u64;
                    if any {
                        let want = traverse_single::occluded::<T>(&view, &ray, &mut c1);
                        assert_eq!(
                            got.is_hit(),
                            want,
                            "quad {q} lane {i} {ray:?} occluded ({:?})",
                            T::KIND
                        );
                        if got.is_hit() {
                            assert!(got.t >= ray.tmin && got.t < ray.tmax);
                        } else {
                            assert!(same(&got, &Hit::MISS));
                        }
                    } else {
                        let want = traverse_single::intersect::<T>(&view, &ray, &mut c1);
                        assert!(
                            same(&got, &want),
                            "quad {q} lane {i} {ray:?} ({:?}): simd {got:?} single {want:?}",
                            T::KIND
                        );
                    }
                }
            }
            assert_eq!(ctr.rays, valid);
            assert_eq!(ctr.packets, quads.len() as u64);
        }
    }

    fn check_all(v: &[f32], ix: &[u32], views: &[crate::scenes::View], leaf_size: u32) {
        for (test, bins) in [
            (TriTest::MollerTrumbore, 16),
            (TriTest::Watertight, 12),
            (TriTest::Projection, 4),
        ] {
            let p = BvhParams {
                leaf_size,
                bins,
                traversal_cost: 1.0,
                test,
                // The SAH tree for the first test, the fast one after.
                quality: if test == TriTest::MollerTrumbore {
                    BuildQuality::Medium
                } else {
                    BuildQuality::Low
                },
                width: 4,
                presplit: false,
            };
            match test {
                TriTest::MollerTrumbore => check::<Mt>(v, ix, views, &p),
                TriTest::Watertight => check::<Wt>(v, ix, views, &p),
                TriTest::Projection => check::<Pt>(v, ix, views, &p),
            }
        }
    }

    #[test]
    fn simd_matches_single_builtin() {
        for &name in crate::scenes::BUILTIN_NAMES {
            let s = crate::scenes::builtin(name).unwrap();
            check_all(&s.mesh.vertices, &s.mesh.indices, &s.views, 4);
        }
    }

    #[test]
    fn simd_matches_single_ties_and_empty() {
        let t = [[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]];
        let mut tris = vec![t; 100];
        tris.extend(vec![
            [[0.0, 0.0, 0.5], [1.0, 0.0, 0.5], [0.0, 1.0, 0.5]];
            50
        ]);
        tris.reverse();
        let (v, ix) = soup(&tris);
        check_all(&v, &ix, &[], 2);
        check_all(&[], &[], &[], 4);
        let s = crate::scenes::builtin("gears").unwrap();
        check_all(&s.mesh.vertices, &s.mesh.indices, &s.views, 1);
        // A tree at MAX_DEPTH (full traversal stacks).
        let (v, ix) = soup(&deep_tris());
        check::<Mt>(
            &v,
            &ix,
            &[],
            &BvhParams {
                leaf_size: 1,
                bins: 2,
                ..Default::default()
            },
        );
    }
}
