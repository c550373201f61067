//! The kd-tree build, by `KdParams::quality`: the exact O(N log N) sweep
//! (`build_sweep`, `High`: the AEPSA paper's section 5.1) or the binned
//! build (`build_binned`, `Low` and `Medium`), both from the same stored
//! triangles (`store`) into the preallocated pools. The tests of both
//! builds live here.

use super::{KdInfo, KdParams, KdTree, build_binned, build_sweep};
use crate::accel::bvh::BuildQuality;
use crate::error::Result;
use crate::geom::Scene;
use crate::mem::par::{Par, Serial, workers_of};

/// Rebuild `kd` from `scene` on the calling thread. On error the previous
/// build stays valid.
pub fn build(kd: &mut KdTree<'_>, scene: &Scene<'_>, p: &KdParams) -> Result<KdInfo> {
    build_with(kd, scene, p, &Serial)
}

/// Rebuild `kd` from `scene` by `p.quality`'s build, the binned ones on
/// `par`'s workers (the tree is the same for any worker count; `High`
/// runs on the calling thread). On error the previous build stays valid.
pub fn build_with(
    kd: &mut KdTree<'_>,
    scene: &Scene<'_>,
    p: &KdParams,
    par: &dyn Par,
) -> Result<KdInfo> {
    p.validate()?;
    let workers = workers_of(par)?;
    let info = if p.quality == BuildQuality::High {
        build_sweep::sweep(kd.pools_mut(), scene, p)?
    } else {
        build_binned::build(kd.pools_mut(), scene, p, par, workers)?
    };
    kd.set_info(Some(info));
    Ok(info)
}

#[cfg(test)]
pub(crate) mod testutil {
    //! Owned pools for tests.
    use super::super::{KdNode, KdPools, KdTree};
    use crate::geom::{ProjTri, TriVerts};

    pub struct Store {
        pub nodes: Vec<KdNode>,
        pub refs: Vec<u32>,
        pub tris: Vec<TriVerts>,
        pub proj: Vec<ProjTri>,
        pub ids: Vec<u32>,
        pub slot: Vec<u32>,
        pub events: Vec<u64>,
        pub side: Vec<u8>,
    }

    impl Store {
        /// Pools for `n` triangles with the default sizing rules of `Limits`
        /// (nodes `4n + 1024`, references `12n + 1024`, events `16n + 1024`).
        pub fn new(n: usize, proj: bool) -> Store {
            Store {
                nodes: vec![KdNode::default(); 4 * n + 1024],
                refs: vec![0; 12 * n + 1024],
                tris: vec![TriVerts::default(); n],
                proj: vec![ProjTri::default(); if proj { n } else { 0 }],
                ids: vec![0; n],
                slot: vec![0; n],
                events: vec![0; 16 * n + 1024],
                side: vec![0; n],
            }
        }
        pub fn kd(&mut self) -> KdTree<'_> {
            KdTree::new(KdPools {
                nodes: &mut self.nodes,
                refs: &mut self.refs,
                tris: &mut self.tris,
                proj: &mut self.proj,
                tri_ids: &mut self.ids,
                slot_of: &mut self.slot,
                events: &mut self.events,
                side: &mut self.side,
            })
        }
    }
}

#[cfg(test)]
mod tests {
    use super::testutil::Store;
    use super::*;
    use crate::accel::kd::build_sweep::EVENTS_PER_TRI;
    use crate::accel::kd::{KdNode, KdView};
    use glam::Vec3;

    /// Every stored triangle sits in the leaves its padded box reaches,
    /// node boxes nest, and the tallies agree with the tree.
    fn check_invariants(v: &KdView<'_>) {
        let info = v.info;
        let mut stack = vec![(0usize, info.root, 0u32)];
        let (mut leaves, mut empty, mut refs, mut depth_sum) = (0u32, 0u32, 0u32, 0u64);
        let mut seen = vec![false; v.tris.len()];
        while let Some((n, b, d)) = stack.pop() {
            let node: &KdNode = &v.nodes[n];
            assert!(d <= info.max_depth);
            if node.is_leaf() {
                leaves += 1;
                empty += (node.count() == 0) as u32;
                refs += node.count() as u32;
                depth_sum += d as u64;
                // Every triangle of a leaf meets its box (padded by far
                // more than the build's padding): a leaf naming another
                // part of the reference pool fails here.
                let slack = 1e-3 * info.root.diagonal().length();
                for &s in v.leaf_refs(node) {
                    seen[s as usize] = true;
                    let t = &v.tris[s as usize];
                    let lo = Vec3::from(t.v0).min(t.v1.into()).min(t.v2.into());
                    let hi = Vec3::from(t.v0).max(t.v1.into()).max(t.v2.into());
                    assert!(
                        (lo - slack).cmple(b.max).all() && (hi + slack).cmpge(b.min).all(),
                        "leaf {n}: triangle {s} outside its box"
                    );
                }
                continue;
            }
            let (l, r) = KdView::child_boxes(node, &b);
            let s = node.split();
            assert!(
                s > b.min[node.axis()] && s < b.max[node.axis()],
                "split inside the node"
            );
            stack.push((node.left(), l, d + 1));
            stack.push((node.left() + 1, r, d + 1));
        }
        assert!(seen.iter().all(|&x| x), "every triangle in some leaf");
        assert_eq!(
            (leaves, empty, refs),
            (info.leaves, info.empty_leaves, info.refs)
        );
        assert!((depth_sum as f64 / leaves as f64 - info.avg_leaf_depth as f64).abs() < 1e-3);
        assert_eq!(info.nodes as usize, 2 * leaves as usize - 1);
    }

    #[test]
    fn builtin_scenes_invariants() {
        for name in crate::scenes::BUILTIN_NAMES {
            let sc = crate::scenes::builtin(name).unwrap();
            let scene = Scene::from_f32(&sc.mesh.vertices, &sc.mesh.indices).unwrap();
            let mut st = Store::new(scene.triangle_count() as usize, false);
            roomy(&mut st, scene.triangle_count() as usize);
            let mut kd = st.kd();
            for quality in QUALITIES {
                let p = KdParams {
                    quality,
                    ..KdParams::default()
                };
                let info = build(&mut kd, &scene, &p).unwrap();
                check_invariants(&kd.view().unwrap());
                assert!(
                    info.empty_leaves > 0 && info.forced_leaves == 0 && info.quality == quality,
                    "{name}: {info:?}"
                );
            }
        }
    }

    /// Roomy pools: gears' fan triangles need 20 references and 6 nodes
    /// each, and the `Low` build's lists as many (the default limits make
    /// forced leaves there).
    fn roomy(st: &mut Store, n: usize) {
        st.refs.resize(32 * n, 0);
        st.nodes.resize(16 * n, KdNode::default());
        st.events.resize(64 * n, 0);
    }

    const QUALITIES: [BuildQuality; 3] =
        [BuildQuality::Low, BuildQuality::Medium, BuildQuality::High];

    /// The binned builds make the same tree on any number of workers, in
    /// any order and on real threads: the same nodes, references and
    /// stored triangles, and the same `KdInfo`.
    #[test]
    fn workers_build_the_same_tree() {
        use crate::accel::testkit::Backwards;
        use crate::mem::par::{Helped, Join};
        for &name in crate::scenes::BUILTIN_NAMES {
            let sc = crate::scenes::builtin(name).unwrap();
            let scene = Scene::from_f32(&sc.mesh.vertices, &sc.mesh.indices).unwrap();
            let n = scene.triangle_count() as usize;
            let mut big = Store::new(n, false);
            roomy(&mut big, n);
            // Pools too small for the tree the SAH wants: forced leaves,
            // in the same places for any worker count.
            let mut tight = Store::new(n, false);
            tight.refs.truncate(n + n / 2 + 8);
            tight.nodes.truncate(n / 2 + 8);
            tight.events.truncate(9 * n + 1024);
            // Few nodes, many references: most jobs outgrow their node
            // shares and are built again in the rest.
            let mut lean = Store::new(n, false);
            roomy(&mut lean, n);
            lean.nodes.truncate(n / 8 + 8);
            for (st, forced) in [(&mut big, false), (&mut tight, true), (&mut lean, true)] {
                let mut kd = st.kd();
                for quality in [BuildQuality::Low, BuildQuality::Medium] {
                    let p = KdParams {
                        quality,
                        ..KdParams::default()
                    };
                    let snap = |kd: &KdTree<'_>| {
                        let v = kd.view().unwrap();
                        (
                            *v.info,
                            v.nodes.to_vec(),
                            v.refs.to_vec(),
                            v.tri_ids.to_vec(),
                        )
                    };
                    build(&mut kd, &scene, &p).unwrap();
                    let want = snap(&kd);
                    check_invariants(&kd.view().unwrap());
                    assert!(want.0.nodes > 1, "{name}: one leaf");
                    assert_eq!(
                        want.0.forced_leaves > 0,
                        forced,
                        "{name} {quality:?}: {:?}",
                        want.0
                    );
                    for workers in [2usize, 3, 16] {
                        build_with(&mut kd, &scene, &p, &Backwards(workers)).unwrap();
                        assert!(
                            snap(&kd) == want,
                            "{name} {quality:?}: {workers} workers backwards"
                        );
                    }
                    let join = Join::new();
                    std::thread::scope(|t| {
                        let j = &join;
                        t.spawn(move || assert_eq!(j.help(1, 2), Helped::Done(0)));
                        join.lead(2, |par| build_with(&mut kd, &scene, &p, par))
                    })
                    .unwrap();
                    assert!(snap(&kd) == want, "{name} {quality:?}: 2 threads");
                }
            }
        }
    }

    #[test]
    fn empty_degenerate_and_tiny_pools() {
        // No traceable triangle: a single empty leaf.
        let v = [
            0.0f32,
            0.0,
            0.0,
            1.0,
            0.0,
            0.0,
            2.0,
            0.0,
            0.0,
            f32::NAN,
            0.0,
            0.0,
        ];
        let ix = [0u32, 1, 2, 0, 1, 3];
        let scene = Scene::from_f32(&v, &ix).unwrap();
        let mut st = Store::new(2, false);
        let mut kd = st.kd();
        let info = build(&mut kd, &scene, &KdParams::default()).unwrap();
        assert_eq!(
            (
                info.triangles,
                info.excluded_zero_area,
                info.excluded_non_finite,
                info.leaves
            ),
            (0, 1, 1, 1)
        );
        // Pools just big enough for the root: splits are refused, the tree
        // is one leaf with every triangle, counted as forced.
        let sc = crate::scenes::builtin("tetra").unwrap();
        let scene = Scene::from_f32(&sc.mesh.vertices, &sc.mesh.indices).unwrap();
        let n = scene.triangle_count() as usize;
        let mut st = Store::new(n, false);
        st.events.truncate(EVENTS_PER_TRI * n);
        let mut kd = st.kd();
        // The binned builds need their job list and two root lists: a
        // capacity error, nothing written.
        assert!(build(&mut kd, &scene, &KdParams::default()).is_err());
        assert!(kd.view().is_none());
        let high = KdParams {
            quality: BuildQuality::High,
            ..KdParams::default()
        };
        let info = build(&mut kd, &scene, &high).unwrap();
        assert_eq!(
            (info.leaves, info.forced_leaves, info.refs as usize),
            (1, 1, n)
        );
        check_invariants(&kd.view().unwrap());
        // Too few triangle slots: an error, and the previous tree stays.
        let mut st = Store::new(n, false);
        st.tris.truncate(n - 1);
        let mut kd = st.kd();
        assert!(build(&mut kd, &scene, &KdParams::default()).is_err());
        assert!(kd.view().is_none());
    }

    use crate::accel::testkit::shared_scene as obj;

    /// The binned builds against the BVH SAH build and the exact kd build,
    /// and the binned tree's camera rays against the exact tree's, in
    /// interleaved rounds (each round times every configuration once; the
    /// medians of the per-round ratios are printed). 1024x1024 camera
    /// rays from inside the scene's box looking along x, kd packets 16x16
    /// from the root, one thread. `KD_ROUNDS` rounds (default 7).
    #[test]
    #[ignore]
    fn binned_against_exact() {
        use crate::mem::par::Join;
        use crate::render::{PixelRect, PrimaryRays};
        use crate::{BvhParams, Limits, Method, OwnedContext, TraceParams};
        use std::time::Instant;
        let rounds: usize = std::env::var("KD_ROUNDS").map_or(7, |r| r.parse().unwrap());
        let load = std::fs::read_to_string("/proc/loadavg").unwrap_or_default();
        println!("load at start: {}", load.trim());
        println!(
            "| scene | tris | kd Medium / BVH SAH build | kd Low / BVH SAH | Medium 1 / 2 threads | Low 1 / 2 threads | exact / Medium build | Medium SAH / exact SAH | refs/tri Medium, exact | camera Mrays/s Medium / exact | Low / exact | hits differing |"
        );
        println!("|---|--:|--:|--:|--:|--:|--:|--:|--:|--:|--:|--:|");
        for file in [
            "bunny/bunny_tinybvh.obj",
            "conference/conference.obj",
            "crytek_sponza/crytek_sponza.obj",
            "sibenik/sibenik.obj",
        ] {
            let Some((v, ix)) = obj(file) else {
                println!("{file}: not found, skipped");
                continue;
            };
            let scene = Scene::from_f32(&v, &ix).unwrap();
            let n = scene.triangle_count();
            let mut l = Limits::for_triangles(n);
            l.max_vertices = (v.len() / 3) as u32;
            l.structures = Limits::KD | Limits::BVH;
            let new = || OwnedContext::new(&l).unwrap();
            let (mut fast, mut exact, mut coarse) = (new(), new(), new());
            let q = |quality| KdParams {
                quality,
                ..KdParams::default()
            };
            let (low, med, high) = (
                q(BuildQuality::Low),
                q(BuildQuality::Medium),
                q(BuildQuality::High),
            );
            let hi_info = exact.build_kd(&scene, &high).unwrap();
            let info = fast.build_kd(&scene, &med).unwrap();
            coarse.build_kd(&scene, &low).unwrap();
            let b = info.bounds;
            let (c, e) = ((b.min + b.max) * 0.5, b.max - b.min);
            let cam = crate::Camera {
                eye: (c - Vec3::new(0.45 * e.x, 0.0, 0.0)).to_array(),
                look_at: (c + Vec3::new(e.x, 0.0, 0.0)).to_array(),
                up: [0.0, 1.0, 0.0],
                fov_y_deg: 60.0,
            };
            let (w, h) = (1024u32, 1024u32);
            let rays = PrimaryRays::new(&cam, w, h).unwrap();
            let tp = TraceParams {
                method: Method::KdPacket,
                packet: 16,
                ..TraceParams::default()
            };
            let trace = |ctx: &OwnedContext, hits: &mut Vec<crate::Hit>| {
                let t = Instant::now();
                ctx.trace_camera(None, &tp, &rays, PixelRect::image(w, h), hits, w as usize)
                    .unwrap();
                t.elapsed().as_secs_f64()
            };
            let timed = |f: &mut dyn FnMut()| {
                let t = Instant::now();
                f();
                t.elapsed().as_secs_f64()
            };
            let joined = |ctx: &mut OwnedContext, p: &KdParams| {
                let join = Join::new();
                std::thread::scope(|t| {
                    let j = &join;
                    t.spawn(move || j.help(1, 2));
                    join.lead(2, |par| ctx.build_kd_with(&scene, p, par))
                })
                .unwrap();
            };
            let (mut hf, mut he) = (
                vec![crate::Hit::MISS; (w * h) as usize],
                vec![crate::Hit::MISS; (w * h) as usize],
            );
            let mut hl = hf.clone();
            let mut r: [Vec<f64>; 7] = Default::default();
            for _ in 0..rounds {
                let bvh = timed(&mut || {
                    exact.build_bvh(&scene, &BvhParams::default()).unwrap();
                });
                let l1 = timed(&mut || {
                    fast.build_kd(&scene, &low).unwrap();
                });
                let l2 = timed(&mut || joined(&mut fast, &low));
                let m2 = timed(&mut || joined(&mut fast, &med));
                let m1 = timed(&mut || {
                    fast.build_kd(&scene, &med).unwrap();
                });
                let hb = timed(&mut || {
                    exact.build_kd(&scene, &high).unwrap();
                });
                let (tf, te, tl) = (
                    trace(&fast, &mut hf),
                    trace(&exact, &mut he),
                    trace(&coarse, &mut hl),
                );
                for (k, x) in [
                    m1 / bvh,
                    l1 / bvh,
                    m1 / m2,
                    l1 / l2,
                    hb / m1,
                    te / tf,
                    te / tl,
                ]
                .into_iter()
                .enumerate()
                {
                    r[k].push(x);
                }
            }
            let med_of = |v: &mut Vec<f64>| {
                v.sort_by(f64::total_cmp);
                v[v.len() / 2]
            };
            let differ = hf
                .iter()
                .chain(&hl)
                .zip(he.iter().chain(&he))
                .filter(|(a, b)| a.prim != b.prim || a.t.to_bits() != b.t.to_bits())
                .count();
            let m: Vec<f64> = r.iter_mut().map(med_of).collect();
            println!(
                "| {} | {n} | {:.2} | {:.2} | {:.2} | {:.2} | {:.2} | {:.3} | {:.2}, {:.2} | {:.2} | {:.2} | {differ} |",
                file.split('/').next().unwrap(),
                m[0],
                m[1],
                m[2],
                m[3],
                m[4],
                info.sah_cost / hi_info.sah_cost,
                info.refs as f64 / info.triangles as f64,
                hi_info.refs as f64 / hi_info.triangles as f64,
                m[5],
                m[6]
            );
        }
    }

    /// Table 1 of the AEPSA paper for the OBJ scenes (skips absent files).
    #[test]
    #[ignore]
    fn table1_obj_scenes() {
        for file in [
            "legocar/legocar.obj",
            "bunny/bunny_tinybvh.obj",
            "sibenik/sibenik.obj",
            "crytek_sponza/crytek_sponza.obj",
            "conference/conference.obj",
        ] {
            if std::env::var("KD_ONLY").is_ok_and(|f| !file.contains(&f)) {
                continue;
            }
            let Some((v, ix)) = obj(file) else {
                eprintln!("{file}: not found, skipped");
                continue;
            };
            let scene = Scene::from_f32(&v, &ix).unwrap();
            let mut st = Store::new(scene.triangle_count() as usize, false);
            let mut kd = st.kd();
            let time = |f: &mut dyn FnMut()| {
                let mut t = [0.0f64; 5];
                for x in &mut t {
                    let t0 = std::time::Instant::now();
                    f();
                    *x = t0.elapsed().as_secs_f64() * 1e3;
                }
                t.sort_by(f64::total_cmp);
                t[2]
            };
            let mut bst = crate::accel::testkit::Store::new(scene.triangle_count() as usize, false);
            let mut bvh = bst.bvh();
            for q in [BuildQuality::Low, BuildQuality::Medium] {
                let bp = crate::BvhParams {
                    quality: q,
                    ..crate::BvhParams::default()
                };
                let ms = time(&mut || {
                    crate::accel::bvh::build::build(&mut bvh, &scene, &bp).unwrap();
                });
                println!("{file}: BVH {q:?} build {ms:.1} ms");
            }
            for q in [BuildQuality::Low, BuildQuality::Medium, BuildQuality::High] {
                let mut p = KdParams {
                    quality: q,
                    ..KdParams::default()
                };
                if let Ok(c) = std::env::var("KD_TRAV") {
                    p.traversal_cost = c.parse().unwrap();
                }
                if let Ok(c) = std::env::var("KD_BINS") {
                    p.bins = c.parse().unwrap();
                }
                let mut info = build(&mut kd, &scene, &p).unwrap();
                let ms = time(&mut || info = build(&mut kd, &scene, &p).unwrap());
                if q != BuildQuality::High {
                    use crate::mem::par::Join;
                    let join = Join::new();
                    let ms2 = time(&mut || {
                        std::thread::scope(|t| {
                            let j = &join;
                            t.spawn(move || j.help(1, 2));
                            join.lead(2, |par| build_with(&mut kd, &scene, &p, par))
                        })
                        .unwrap();
                    });
                    println!(
                        "{file} {q:?}: 2 joined threads {ms2:.1} ms ({:.2}x)",
                        ms / ms2
                    );
                }
                check_invariants(&kd.view().unwrap());
                println!(
                    "{file} {q:?}: tris {} leaves {} empty {:.2}% avg depth {:.2} max {} refs/tri {:.2} nodes/tri {:.2} events/tri {:.2} forced {} sah {:.1} build {:.1} ms",
                    info.triangles,
                    info.leaves,
                    100.0 * info.empty_leaves as f64 / info.leaves as f64,
                    info.avg_leaf_depth,
                    info.depth,
                    info.refs as f64 / info.triangles as f64,
                    info.nodes as f64 / info.triangles as f64,
                    info.events_peak as f64 / info.triangles as f64,
                    info.forced_leaves,
                    info.sah_cost,
                    ms
                );
            }
        }
    }
}
