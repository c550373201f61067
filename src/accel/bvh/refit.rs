//! Refit: when only vertex positions moved (the same triangles from the
//! same index buffer), the built tree keeps its shape and every box is
//! recomputed bottom-up in place: a check pass and a copy pass over the
//! stored triangles, the leaf boxes, then one reverse pass over the inner
//! nodes. Embree's equivalent is a geometry committed with
//! `RTC_BUILD_QUALITY_REFIT`; the BVH paper rebuilds every frame (section
//! 5.1).
//!
//! Children are stored after their parent (the build allocates them later),
//! so visiting the nodes in reverse order meets every child before its
//! parent: no stack, no recursion. The triangle passes and the leaf boxes
//! split among the caller's workers (`refit_with`); the inner pass (one
//! union per node) stays on one.
//!
//! # Exactness
//! Leaf boxes are padded exactly as the build pads them (`BOX_PAD` times
//! the new bounds' largest coordinate magnitude plus diagonal); an inner
//! box is the union of its children's padded boxes, which contains the
//! padded union of their triangles. Every traversal's guarantee holds on
//! the refit tree as on a fresh one: the single ray returns the triangle
//! and bitwise t of a brute-force search over the stored triangles, and
//! every packet returns the single ray's. The shape decides speed only.
//!
//! # Deviations
//! - The SAH growth compares the padded boxes before and after, each
//!   relative to its root (the build reports the unpadded ones);
//!   `BvhInfo::sah_cost` is scaled by it.
//! - Triangles the build left out (non-finite or zero area then) stay
//!   out; `RefitInfo::newly_traceable` counts those that a rebuild would
//!   now store.
#![forbid(unsafe_code)]

use super::{Bvh, BvhNode};
use crate::error::{Error, Result};
use crate::geom::{INVALID_ID, ProjTri, Scene, TriTest, TriVerts};
use crate::mem::par::{MAX_WORKERS, Par, Parts, Serial, atomic_u32, share};
use core::sync::atomic::{AtomicU32, Ordering};
use glam::Vec3A;

/// When a refit becomes a rebuild (C: `sheaf_refit_params`).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct RefitParams {
    /// Rebuild (with the last build's parameters) instead, once the SAH
    /// cost has grown past this ratio of the pre-refit tree's; 0 never
    /// rebuilds. 0 or at least 1 (default 0).
    pub rebuild_above: f32,
}

impl Default for RefitParams {
    fn default() -> Self {
        RefitParams { rebuild_above: 0.0 }
    }
}

impl RefitParams {
    pub fn validate(&self) -> Result<()> {
        let r = self.rebuild_above;
        if !(r == 0.0 || (r.is_finite() && r >= 1.0)) {
            return Err(Error::InvalidArgument(
                "refit rebuild_above must be 0 or a finite ratio of at least 1",
            ));
        }
        Ok(())
    }
}

/// What a refit did (C: `sheaf_refit_info`).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct RefitInfo {
    /// SAH cost of the tree before and after (`BvhInfo::sah_cost`).
    pub sah_before: f32,
    pub sah_after: f32,
    /// Triangles the build left out that a rebuild would now store.
    pub newly_traceable: u32,
    /// The refit grew the SAH cost past `RefitParams::rebuild_above`: the
    /// tree was rebuilt instead (`sah_after` is the new tree's).
    pub rebuilt: bool,
    /// Wall time of the call, refit and any rebuild (0 without `std`).
    pub ns: u64,
}

impl RefitInfo {
    /// `sah_after / sah_before` (1 for an empty tree).
    pub fn growth(&self) -> f32 {
        if self.sah_before > 0.0 {
            self.sah_after / self.sah_before
        } else {
            1.0
        }
    }
}

// The word counts pass 2 stores per slot.
const _: () =
    assert!(core::mem::size_of::<TriVerts>() == 36 && core::mem::size_of::<ProjTri>() == 48);

/// Write the words of `bytes` (a whole number of them) into `to`.
#[inline(always)]
fn store(to: &[AtomicU32], bytes: &[u8]) {
    for (w, x) in to.iter().zip(bytes.chunks_exact(4)) {
        w.store(
            u32::from_ne_bytes([x[0], x[1], x[2], x[3]]),
            Ordering::Relaxed,
        );
    }
}

/// Every leaf box of `nodes` padded by `pad` (`leaf_box`'s padding of the
/// same bounds), split among `par`'s workers.
fn pad_leaves(nodes: &mut [BvhNode], pad: Vec3A, par: &dyn Par) {
    let workers = par.workers();
    let ns = Parts::even(nodes, workers);
    par.run(&|w| {
        for nd in ns.get(w).iter_mut().filter(|nd| nd.is_leaf()) {
            (nd.min, nd.max) = (
                (Vec3A::from(nd.min) - pad).into(),
                (Vec3A::from(nd.max) + pad).into(),
            );
        }
    });
}

/// Half area of a node's stored (padded) box.
pub(super) fn half_area(n: &BvhNode) -> f64 {
    let d = Vec3A::from(n.max) - Vec3A::from(n.min);
    (d.x * d.y + d.y * d.z + d.z * d.x) as f64
}

/// The SAH of the stored (padded) boxes before the division by the
/// root's half area: traversal cost per inner node, one per triangle,
/// weighted by half area (sums of parts add).
pub(super) fn sah_sum(nodes: &[BvhNode], traversal_cost: f32) -> f64 {
    nodes
        .iter()
        .map(|n| {
            let per = if n.is_leaf() {
                n.count() as f64
            } else {
                traversal_cost as f64
            };
            half_area(n) * per
        })
        .sum()
}

/// The box of the triangles `tris` padded by `pad`: every leaf box of the
/// binary and the wide tree (the wide tree's boxes equal the binary ones
/// bitwise because both are computed here). An inner box is the union of
/// its children's; the union of padded boxes equals the padded union
/// bitwise (`x - pad` rounds monotonically), so a refit tree has the boxes
/// the binned build would have written.
#[inline(always)]
pub(super) fn leaf_box(tris: &[TriVerts], pad: Vec3A) -> (Vec3A, Vec3A) {
    let (mut a, mut b) = (Vec3A::splat(f32::INFINITY), Vec3A::splat(f32::NEG_INFINITY));
    for t in tris {
        for v in [t.v0, t.v1, t.v2] {
            let v = Vec3A::from(v);
            (a, b) = (a.min(v), b.max(v));
        }
    }
    (a - pad, b + pad)
}

/// Every box of the first `upto` nodes of `part` recomputed bottom-up
/// (children follow their parent, so one reverse pass meets them first).
/// `part` holds the nodes `base..base + part.len()` of a tree, and the
/// children of those nodes lie in `part` (the fast build fits each
/// worker's region and then its top this way).
pub(super) fn fit(part: &mut [BvhNode], base: usize, upto: usize, tris: &[TriVerts], pad: Vec3A) {
    for i in (0..upto).rev() {
        let nd = part[i];
        let first = nd.first as usize;
        let (bmin, bmax) = if nd.is_leaf() {
            leaf_box(&tris[first..first + nd.count() as usize], pad)
        } else {
            let (l, r) = (&part[first - base], &part[first - base + 1]);
            (
                Vec3A::from(l.min).min(Vec3A::from(r.min)),
                Vec3A::from(l.max).max(Vec3A::from(r.max)),
            )
        };
        part[i].min = bmin.into();
        part[i].max = bmax.into();
    }
}

/// Refit the built tree of `bvh` to `scene`'s current vertex positions,
/// on the calling thread (`refit_with` on `Serial`).
pub fn refit(bvh: &mut Bvh<'_>, scene: &Scene<'_>) -> Result<RefitInfo> {
    refit_with(bvh, scene, &Serial)
}

/// The padded SAH of the tree `nodes`, summed in reverse node order, each
/// leaf with its parent; with `fit`, every inner box is first refitted as
/// the union of its children's (whose boxes are final), the refit's last
/// pass. Both ways sum in the same order, whatever the number of workers
/// fitted the leaves, so a refit to unchanged vertices reports the same
/// cost.
fn inner_pass(nodes: &mut [BvhNode], traversal_cost: f32, fit: bool) -> f64 {
    let leaf = |n: &BvhNode| half_area(n) * n.count() as f64;
    if nodes[0].is_leaf() {
        return leaf(&nodes[0]) / half_area(&nodes[0]).max(f64::MIN_POSITIVE);
    }
    let mut sum = 0.0f64;
    for i in (0..nodes.len()).rev() {
        let nd = nodes[i];
        if nd.is_leaf() {
            continue;
        }
        let first = nd.first as usize;
        let (l, r) = (nodes[first], nodes[first + 1]);
        let (a, b) = if fit {
            let a = Vec3A::from(l.min).min(Vec3A::from(r.min));
            let b = Vec3A::from(l.max).max(Vec3A::from(r.max));
            (nodes[i].min, nodes[i].max) = (a.into(), b.into());
            (a, b)
        } else {
            (Vec3A::from(nd.min), Vec3A::from(nd.max))
        };
        for c in [&l, &r] {
            if c.is_leaf() {
                sum += leaf(c);
            }
        }
        // From the box in registers: reading the node just written back
        // would stall on store forwarding.
        let d = b - a;
        sum += (d.x * d.y + d.y * d.z + d.z * d.x) as f64 * traversal_cost as f64;
    }
    sum / half_area(&nodes[0]).max(f64::MIN_POSITIVE)
}

/// `refit` on the caller's workers (`mem::par::Par`): the checks, the
/// stored triangles and the leaf boxes are split among them; the inner
/// boxes (one union each) are fitted by worker 0. The tree, the boxes and
/// the reported SAH are the same for any number of workers.
/// Errors (nothing changed): no tree built, a different triangle count, a
/// stored triangle with a non-finite vertex.
pub fn refit_with(bvh: &mut Bvh<'_>, scene: &Scene<'_>, par: &dyn Par) -> Result<RefitInfo> {
    let Some(mut info) = bvh.info().copied() else {
        return Err(Error::NotBuilt);
    };
    if scene.triangle_count() != info.triangles_in {
        return Err(Error::InvalidArgument(
            "refit needs the triangles the BVH was built from (same count): rebuild instead",
        ));
    }
    let traversal_cost = bvh.params().traversal_cost;
    let cached_sah = bvh.refit_sah();
    let workers = crate::mem::par::workers_of(par)?;
    let pools = bvh.pools_mut();
    let n = info.references as usize;
    let nn = info.nodes as usize;

    // 1. Check, writing nothing: every stored triangle finite. First one
    // streaming pass over the vertex buffer; only when it holds a
    // non-finite vertex (which may belong to triangles the build left out
    // alone) are the stored triangles checked one by one.
    let mut finite = [true; MAX_WORKERS];
    {
        let (vs, fs) = (
            scene.vertex_count() as usize,
            Parts::even(&mut finite[..workers], workers),
        );
        par.run(&|w| {
            fs.get(w)[0] =
                share(vs, w, workers).all(|i| Vec3A::from(scene.vertex(i as u32)).is_finite());
        });
    }
    if !finite[..workers].iter().all(|&f| f) {
        let all = info.triangles_in as usize;
        let stored = (0..all as u32).filter(|&t| pools.slot_of[t as usize] != INVALID_ID);
        for t in stored {
            let t = scene.triangle(t);
            if ![t.v0, t.v1, t.v2]
                .iter()
                .all(|v| Vec3A::from(*v).is_finite())
            {
                return Err(Error::InvalidArgument(
                    "refit: a stored triangle has a non-finite vertex (the previous BVH is kept)",
                ));
            }
        }
    }
    // Only a build that left triangles out needs this second pass.
    let left_out = info.excluded_non_finite + info.excluded_zero_area;
    let newly_traceable = if left_out == 0 {
        0
    } else {
        (0..info.triangles_in)
            .filter(|&t| {
                pools.slot_of[t as usize] == INVALID_ID
                    && Scene::classify(&scene.triangle(t)).is_none()
            })
            .count() as u32
    };
    let mut out = RefitInfo {
        sah_before: info.sah_cost,
        sah_after: info.sah_cost,
        newly_traceable,
        rebuilt: false,
        ns: 0,
    };
    if n == 0 {
        return Ok(out);
    }
    crate::fault_point!(BvhBuild);

    // 2. Leaf by leaf on every worker: its stored triangles (each slot is
    // one leaf's, so each is written once, through word atomics: the
    // leaves of a node share are scattered over the slots) and its box,
    // unpadded (the pad needs every triangle's bounds), in one pass.
    let before =
        cached_sah.unwrap_or_else(|| inner_pass(&mut pools.nodes[..nn], traversal_cost, false));
    let proj_on = info.test == TriTest::Projection;
    let mut bounds = [(Vec3A::INFINITY, Vec3A::NEG_INFINITY); MAX_WORKERS];
    {
        let ids = &pools.tri_ids[..n];
        let tris = atomic_u32(bytemuck::cast_slice_mut(&mut pools.tris[..n]));
        let proj = atomic_u32(bytemuck::cast_slice_mut(if proj_on {
            &mut pools.proj[..n]
        } else {
            &mut []
        }));
        let ns = Parts::even(&mut pools.nodes[..nn], workers);
        let bs = Parts::even(&mut bounds[..workers], workers);
        par.run(&|w| {
            let (mut lo, mut hi) = (Vec3A::INFINITY, Vec3A::NEG_INFINITY);
            for nd in ns.get(w).iter_mut().filter(|nd| nd.is_leaf()) {
                let first = nd.first as usize;
                let (mut a, mut b) = (Vec3A::INFINITY, Vec3A::NEG_INFINITY);
                for s in first..first + nd.count() as usize {
                    scene.prefetch_ahead(ids, s);
                    let t = scene.triangle(ids[s]);
                    store(&tris[9 * s..9 * s + 9], bytemuck::bytes_of(&t));
                    if proj_on {
                        let p = ProjTri::new(&t);
                        store(&proj[12 * s..12 * s + 12], bytemuck::bytes_of(&p));
                    }
                    for v in [t.v0, t.v1, t.v2] {
                        (a, b) = (a.min(v.into()), b.max(v.into()));
                    }
                }
                (nd.min, nd.max) = (a.into(), b.into());
                (lo, hi) = (lo.min(a), hi.max(b));
            }
            bs.get(w)[0] = (lo, hi);
        });
    }
    let (lo, hi) = bounds[..workers]
        .iter()
        .fold(bounds[0], |(a, b), &(l, h)| (a.min(l), b.max(h)));

    // 3. The leaf boxes padded, then the inner boxes bottom-up.
    let pad = super::box_pad(lo, hi);
    pad_leaves(&mut pools.nodes[..nn], pad, par);
    let after = inner_pass(&mut pools.nodes[..nn], traversal_cost, true);
    if before > 0.0 {
        info.sah_cost = (info.sah_cost as f64 * after / before) as f32;
    }
    info.bounds = crate::geom::Aabb {
        min: lo.into(),
        max: hi.into(),
    };
    out.sah_after = info.sah_cost;
    bvh.commit_refit(info, pad, after, par);
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::accel::bvh::build::build;
    use crate::accel::bvh::build::testutil::Store;
    use crate::accel::bvh::{BuildQuality, BvhParams};
    use crate::accel::testkit::Backwards;

    /// A refit split among workers writes the calling-thread refit's
    /// stored triangles, binary and wide boxes, and SAH figures, bit for
    /// bit, for every worker count, on the SAH and the fast tree.
    #[test]
    fn workers_refit_as_the_calling_thread() {
        let mut a = crate::scenes::animated::Animated::new(1);
        let n = a.mesh.indices.len() / 3;
        // The HIGH tree with spatial splits in a reserve of n / 4.
        for (quality, reserve) in [
            (BuildQuality::Medium, 0),
            (BuildQuality::Low, 0),
            (BuildQuality::High, n / 4),
        ] {
            let p = BvhParams {
                quality,
                ..BvhParams::default()
            };
            let mut results = Vec::new();
            for workers in [0, 1, 2, 3, 7] {
                a.set_time(0.0);
                let mut st = Store::with_refs(n, n + reserve, false);
                let mut bvh = st.bvh();
                let scene = Scene::from_f32(&a.mesh.vertices, &a.mesh.indices).unwrap();
                build(&mut bvh, &scene, &p).unwrap();
                a.set_time(1.5);
                let scene = Scene::from_f32(&a.mesh.vertices, &a.mesh.indices).unwrap();
                // Twice: the second refit starts from the first's cached SAH.
                let mut infos = [RefitInfo::default(); 2];
                for info in &mut infos {
                    *info = if workers == 0 {
                        refit(&mut bvh, &scene).unwrap()
                    } else {
                        refit_with(&mut bvh, &scene, &Backwards(workers)).unwrap()
                    };
                    info.ns = 0;
                }
                assert!(infos[0].growth() > 1.0, "{quality:?}: the boxes moved");
                assert_eq!(
                    infos[1].growth(),
                    1.0,
                    "{quality:?}: the same vertices again"
                );
                let v = bvh.view().unwrap();
                assert!(v.info.wide_nodes > 0);
                let bits = |x: &[f32]| x.iter().map(|f| f.to_bits()).collect::<Vec<_>>();
                let nodes: Vec<f32> = v
                    .nodes
                    .iter()
                    .flat_map(|n| n.min.into_iter().chain(n.max))
                    .collect();
                let tris: Vec<f32> = v
                    .tris
                    .iter()
                    .flat_map(|t| t.v0.into_iter().chain(t.v1).chain(t.v2))
                    .collect();
                let wide: Vec<f32> = v
                    .wide
                    .iter()
                    .flat_map(|w| w.min.into_iter().chain(w.max).flatten())
                    .collect();
                results.push((infos, *v.info, bits(&nodes), bits(&tris), bits(&wide)));
            }
            for r in &results[1..] {
                assert!(
                    r == &results[0],
                    "{quality:?}: a worker count changed the refit"
                );
            }
        }
    }

    /// The checks: a non-finite vertex of a triangle the build left out
    /// does not stop a refit (the vertex pass sees it, the per-triangle
    /// check lets it by); one of a stored triangle is refused with the tree
    /// unchanged; an excluded triangle that became finite is counted.
    #[test]
    fn non_finite_vertices_of_excluded_and_stored_triangles() {
        let tris: Vec<[[f32; 3]; 3]> = (0..40)
            .map(|i| {
                let x = i as f32;
                [[x, 0.0, 0.0], [x + 1.0, 0.0, 0.0], [x, 1.0, 0.5]]
            })
            .collect();
        let (mut v, ix) = crate::accel::testkit::soup(&tris);
        v[3 * 3 * 7] = f32::NAN; // triangle 7's first vertex: left out
        let mut st = Store::new(tris.len(), false);
        let mut bvh = st.bvh();
        let built = build(
            &mut bvh,
            &Scene::from_f32(&v, &ix).unwrap(),
            &BvhParams::default(),
        )
        .unwrap();
        assert_eq!(built.excluded_non_finite, 1);
        for x in v.iter_mut().skip(1).step_by(3) {
            *x += 0.25; // every y moves (the NaN is an x)
        }
        let r = refit(&mut bvh, &Scene::from_f32(&v, &ix).unwrap()).unwrap();
        assert_eq!((r.newly_traceable, r.rebuilt), (0, false));
        let v0 = bvh.view().unwrap();
        let (nodes, tris, wide) = (v0.nodes.to_vec(), v0.tris.to_vec(), v0.wide.to_vec());
        let mut bad = v.clone();
        bad[3 * 3 * 20 + 4] = f32::INFINITY; // a stored triangle's vertex
        for par in [&Serial as &dyn Par, &Backwards(2)] {
            assert!(refit_with(&mut bvh, &Scene::from_f32(&bad, &ix).unwrap(), par).is_err());
            let v1 = bvh.view().unwrap();
            assert!(
                v1.nodes == &nodes[..] && v1.tris == &tris[..] && v1.wide == &wide[..],
                "a refused refit wrote"
            );
        }
        v[3 * 3 * 7] = 7.0;
        let r = refit(&mut bvh, &Scene::from_f32(&v, &ix).unwrap()).unwrap();
        assert_eq!(r.newly_traceable, 1);
    }

    /// A build forgets the SAH the last refit cached: a refit to the
    /// vertices a fresh tree was built from reports no growth (a stale
    /// cache, the previous tree's, would report some), and a `Par` of more
    /// than 16 workers is refused with the tree unchanged.
    #[test]
    fn a_build_clears_the_cached_sah() {
        let mut a = crate::scenes::animated::Animated::new(1);
        let n = a.mesh.indices.len() / 3;
        let mut st = Store::new(n, false);
        let mut bvh = st.bvh();
        let p = BvhParams::default();
        build(
            &mut bvh,
            &Scene::from_f32(&a.mesh.vertices, &a.mesh.indices).unwrap(),
            &p,
        )
        .unwrap();
        a.set_time(1.5);
        let scene = Scene::from_f32(&a.mesh.vertices, &a.mesh.indices).unwrap();
        assert!(refit(&mut bvh, &scene).unwrap().growth() > 1.0);
        build(&mut bvh, &scene, &p).unwrap();
        assert_eq!(refit(&mut bvh, &scene).unwrap().growth(), 1.0);
        let nodes = bvh.view().unwrap().nodes.to_vec();
        assert!(refit_with(&mut bvh, &scene, &Backwards(MAX_WORKERS + 1)).is_err());
        assert!(bvh.view().unwrap().nodes == &nodes[..]);
    }
}
