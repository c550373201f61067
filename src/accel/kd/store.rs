//! What both kd builds (`build_sweep`, `build_binned`) share: the first pass, the
//! stored triangles (`store`: classify the scene's triangles, check the
//! pools, store the traceable ones), and the SAH's area measure
//! (`half_area`).

use super::{KdInfo, KdNode, KdParams, KdPools, ROOT_PAD};
use crate::accel::bvh::BuildQuality;
use crate::error::{Error, Pool, Result};
use crate::geom::{Aabb, Excluded, INVALID_ID, ProjTri, Scene, TriTest};
use crate::math;
use crate::mem::par::{MAX_WORKERS, Par, Parts};
use glam::Vec3;

/// Bits of a stored triangle's slot in the exact build's split events
/// (`build_sweep`); they bound the stored triangles of every build.
pub(super) const SLOT_BITS: u32 = 29;

/// Most stored triangles a kd-tree accepts (the slot field of an event,
/// `SLOT_BITS`).
pub const MAX_TRIS: u32 = (1 << SLOT_BITS) - 1;

/// Half the surface area of box `b` (an inverted extent counts as 0): the
/// SAH's measure in both builds.
#[inline(always)]
pub(super) fn half_area(b: &Aabb) -> f32 {
    let d = (b.max - b.min).max(Vec3::ZERO);
    d.x * d.y + d.y * d.z + d.z * d.x
}

/// What one worker found in its share of the triangles.
#[derive(Clone, Copy, Default)]
struct Found {
    valid: u32,
    non_finite: u32,
    zero_area: u32,
    bounds: Option<Aabb>,
}

/// The stored triangles (the first pass of both builds).
pub(super) struct Stored {
    /// Stored triangles.
    pub n: usize,
    /// The counts, bounds, root box and parameters filled in.
    pub info: KdInfo,
    /// The padding of every reference box (`ROOT_PAD` of the scene's scale).
    pub pad: Vec3,
}

/// The first pass of both builds on `par`'s workers: classify the triangles (flags
/// in `side`), check the pools (`fits(pools, n)` adds a build's own
/// checks), then store the traceable triangles in caller order. Nothing a
/// traversal reads is written before every check passed. With no
/// traceable triangle the tree is one empty leaf, returned as
/// `Ok(Err(info))`: the build is done.
pub(super) fn store(
    pools: &mut KdPools<'_>,
    scene: &Scene<'_>,
    p: &KdParams,
    par: &dyn Par,
    workers: usize,
    fits: impl FnOnce(&KdPools<'_>, usize) -> Result<()>,
) -> Result<core::result::Result<Stored, KdInfo>> {
    let n_in = scene.triangle_count() as usize;
    let cap = |needed: usize, available: usize| Error::Capacity {
        pool: Pool::Triangles,
        needed: needed as u64,
        available: available as u64,
    };
    let room = pools.slot_of.len().min(pools.side.len());
    if n_in > room {
        return Err(cap(n_in, room));
    }
    let mut found = [Found::default(); MAX_WORKERS];
    {
        let (fs, sd) = (
            Parts::even(&mut found[..workers], workers),
            Parts::even(&mut pools.side[..n_in], workers),
        );
        par.run(&|w| {
            let (side, first) = (sd.get(w), sd.start(w));
            let mut f = Found::default();
            for (k, flag) in side.iter_mut().enumerate() {
                let tri = scene.triangle((first + k) as u32);
                *flag = match Scene::classify(&tri) {
                    None => {
                        let b = f.bounds.get_or_insert(Aabb::EMPTY);
                        for v in [tri.v0, tri.v1, tri.v2] {
                            b.grow(Vec3::from(v));
                        }
                        f.valid += 1;
                        0
                    }
                    Some(Excluded::NonFinite) => {
                        f.non_finite += 1;
                        1
                    }
                    Some(Excluded::ZeroArea) => {
                        f.zero_area += 1;
                        2
                    }
                };
            }
            fs.get(w)[0] = f;
        });
    }
    let (mut n, mut bad_nf, mut bad_za) = (0usize, 0u32, 0u32);
    let mut bounds = Aabb::EMPTY;
    let mut start = [0usize; MAX_WORKERS + 1];
    for (w, f) in found[..workers].iter().enumerate() {
        n += f.valid as usize;
        start[w + 1] = n;
        bad_nf += f.non_finite;
        bad_za += f.zero_area;
        if let Some(b) = f.bounds {
            bounds.grow(b.min);
            bounds.grow(b.max);
        }
    }
    if n > MAX_TRIS as usize {
        return Err(cap(n, MAX_TRIS as usize));
    }
    for avail in [pools.tris.len(), pools.tri_ids.len(), pools.refs.len()] {
        if n > avail {
            return Err(cap(n, avail));
        }
    }
    if pools.nodes.is_empty() {
        return Err(cap(n, 0));
    }
    let proj = p.test == TriTest::Projection;
    if proj && pools.proj.len() < n {
        return Err(Error::InvalidArgument(
            "the projection test needs Limits::projection_test",
        ));
    }
    fits(pools, n)?;

    // From here on nothing fails.
    crate::fault_point!(KdBuild);
    let n_tris = n as u32;
    let mut info = KdInfo {
        triangles_in: n_in as u32,
        triangles: n_tris,
        excluded_non_finite: bad_nf,
        excluded_zero_area: bad_za,
        max_depth: p.depth_for(n_tris),
        test: p.test,
        quality: p.quality,
        bins: if p.quality == BuildQuality::High {
            0
        } else {
            p.bins
        },
        ..KdInfo::default()
    };
    if n == 0 {
        pools.slot_of[..n_in].fill(INVALID_ID);
        pools.nodes[0] = KdNode::leaf(0, 0);
        info.nodes = 1;
        info.leaves = 1;
        info.empty_leaves = 1;
        return Ok(Err(info));
    }
    {
        let bd = &start[..workers + 1];
        let (ts, is) = (
            Parts::at(&mut pools.tris[..n], bd),
            Parts::at(&mut pools.tri_ids[..n], bd),
        );
        let ps = Parts::at(if proj { &mut pools.proj[..n] } else { &mut [] }, {
            if proj { bd } else { &[] }
        });
        let ss = Parts::even(&mut pools.slot_of[..n_in], workers);
        let side = &pools.side[..n_in];
        par.run(&|w| {
            let (tris, ids, slots) = (ts.get(w), is.get(w), ss.get(w));
            let pj = if proj { ps.get(w) } else { &mut [] };
            let first = ss.start(w);
            let mut k = 0usize;
            for (j, slot) in slots.iter_mut().enumerate() {
                let t = first + j;
                if side[t] != 0 {
                    *slot = INVALID_ID;
                    continue;
                }
                let tri = scene.triangle(t as u32);
                tris[k] = tri;
                if let Some(x) = pj.get_mut(k) {
                    *x = ProjTri::new(&tri);
                }
                ids[k] = t as u32;
                *slot = (start[w] + k) as u32;
                k += 1;
            }
        });
    }
    info.bounds = bounds;
    let m = bounds.min.abs().max(bounds.max.abs()).max_element();
    let diag = bounds.diagonal();
    let pad = Vec3::splat(ROOT_PAD * (m + math::sqrt(diag.dot(diag))));
    info.root = Aabb {
        min: bounds.min - pad,
        max: bounds.max + pad,
    };
    Ok(Ok(Stored { n, info, pad }))
}
