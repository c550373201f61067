//! kd-tree rebuilt from scratch every frame, traversed by single rays, 2x2
//! SIMD rays and n x n packets, from the root or from an entry point
//! (`accel::entry`: MLRTA, AEPSA).
//!
//! Source: "Accelerated Entry Point Search Algorithm for Real-Time
//! Ray-Tracing" (AEPSA), on Reshetov, Soupikov, Hurley 2005 (MLRTA).
//!
//! | file | implements |
//! |---|---|
//! | `build.rs` | the build: `KdParams::quality` chooses between the two below |
//! | `build_binned.rs` | the fast build (Shevtsov, Soupikov, Kapustin 2007): binned SAH, the top level by level and the subtrees depth first, on the caller's threads |
//! | `build_sweep.rs` | section 5.1: the O(N log N) SAH compiler (Wald and Havran 2006: split events sorted once, kept sorted by stable partition), biased towards cutting off empty space, SAH termination, a depth limit |
//! | `store.rs` | what both builds share: the triangles classified and stored (their first pass), the SAH's area |
//! | `traverse_single.rs` | the single-ray reference: front-to-back stack traversal with early termination |
//! | `traverse_simd.rs` | the 2x2 SIMD ray (`Ray4`) traversal (Wald 2004) |
//! | `traverse_packet.rs` | n x n packets driven by the packet's frustum, from the root or from an entry point and its AABB |
//!
//! MLRTA (section 2.2) and AEPSA (sections 3.1-3.3) live in `accel/entry/`:
//! they search this tree and the BVH alike.
//!
//! # Node layout
//! 8-byte nodes (`KdNode`), children of a node adjacent (left, and right
//! = left + 1). Node 0 is the root; its box is `KdInfo::root`, every other
//! node's box follows from the splits above it. Leaves hold a range of `refs`
//! (stored triangle slots; a triangle may sit in several leaves).
//!
//! # Exactness
//! Every traversal computes a ray's interval in a node the same way: the
//! root box's slab test (`clip`), then at each split `t_s = (s - o) * rcp`
//! narrows the near child to `[t0, min(t1, t_s)]` and the far child to
//! `[max(t0, t_s), t1]` (`split_interval`; a NaN `t_s`, the origin on the
//! plane with a zero direction, constrains neither). Rounding is monotone,
//! so a node's interval equals the slab test of that node's box with the
//! same formula: a packet entering at an entry point with the entry's AABB
//! sees, lane by lane, the very leaves and intervals the single ray sees
//! below that node. A lane stops after the leaf whose interval ends at or
//! beyond its nearest hit; hits tie on the lower triangle id. Packet and
//! single-ray traversals thus return the same triangle and bitwise the same
//! t; an entry point is exact because every triangle a ray of the packet
//! can hit is overlapped by the packet's frustum, so all leaves holding it
//! lie below the entry point.

pub mod build;
pub mod build_binned;
pub mod build_sweep;
mod entry;
pub mod store;
pub mod traverse_packet;
pub mod traverse_simd;
pub mod traverse_single;

use crate::accel::bvh::BuildQuality;
use crate::counters::Counters;
use crate::error::Result;
use crate::geom::{Aabb, Hit, Hook, M4, ProjTri, Ray, TriTest, TriVerts, TriangleTest};
use crate::mem::{Carve, Limits, entries, when};
use bytemuck::{Pod, Zeroable};

/// Slot scratch this module's packet code takes (`accel::slot`) for
/// packets of up to `q` quads: the occlusion masks of a packet and the
/// packet traversal's scratch.
pub const fn scratch(q: usize) -> usize {
    let walk = crate::mem::scratch::bytes::<M4>(q) + traverse_packet::scratch(q);
    // `packet::start` runs first and gives its scratch back.
    crate::accel::slot::max(walk, crate::accel::packet::start_scratch(q))
}

/// Deepest level a build creates (root = depth 0); every traversal stack of
/// `MAX_DEPTH + 1` entries suffices.
pub const MAX_DEPTH: usize = 48;
const _: () = assert!(MAX_DEPTH <= crate::accel::entry::MAX_ENTRY_DEPTH);

/// Relative padding of the root box (as the BVH's `BOX_PAD`): rays grazing
/// the scene's bounds still enter the tree.
pub const ROOT_PAD: f32 = 1e-5;

/// Tunables of the kd-tree build (C: `sheaf_kd_params`).
#[repr(C)]
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct KdParams {
    /// Depth limit (1..=48); 0: `8 + 1.3 log2 N` (pbrt's rule), capped at 48.
    pub max_depth: u32,
    /// SAH cost of one traversal step relative to one triangle test.
    /// Default 2: lower values deepen the tree and multiply the references
    /// a triangle has (bunny: 9.7 per triangle at 1, 4.4 at 2).
    pub traversal_cost: f32,
    /// Cost discount of a split with an empty side, in [0, 1): the bias
    /// towards cutting off empty space (Hurley et al. 2002). Default 0.2.
    pub empty_bonus: f32,
    /// Ray-triangle test used by every traversal of this tree.
    pub test: TriTest,
    /// Which build (named as the BVH's): `Low` (the default, for trees
    /// rebuilt every frame) and `Medium` are the binned SAH build on the
    /// caller's threads (`build_binned.rs`), `Low` with the straddling
    /// triangles' boxes clipped to each child, `Medium` with the triangles
    /// clipped (perfect splits: a 5-10% lower SAH cost, a 20-25% longer
    /// build); `High` is the exact O(N log N) sweep with perfect splits
    /// (`build_sweep.rs`, single-threaded, 6-7x the `Low` build's time).
    /// Every traversal is exact on every tree; the shape decides speed
    /// only.
    pub quality: BuildQuality,
    /// SAH bins per axis of the binned builds (2..=64, default 32).
    pub bins: u32,
}

impl Default for KdParams {
    fn default() -> Self {
        KdParams {
            max_depth: 0,
            traversal_cost: 2.0,
            empty_bonus: 0.2,
            test: TriTest::MollerTrumbore,
            quality: BuildQuality::Low,
            bins: 32,
        }
    }
}

impl KdParams {
    pub fn validate(&self) -> crate::Result<()> {
        if self.max_depth as usize > MAX_DEPTH {
            return Err(crate::Error::InvalidArgument(
                "kd max_depth must be in 0..=48",
            ));
        }
        if !(self.traversal_cost.is_finite() && self.traversal_cost > 0.0) {
            return Err(crate::Error::InvalidArgument(
                "kd traversal_cost must be finite and > 0",
            ));
        }
        if !(self.empty_bonus >= 0.0 && self.empty_bonus < 1.0) {
            return Err(crate::Error::InvalidArgument(
                "kd empty_bonus must be in [0, 1)",
            ));
        }
        if !(2..=crate::accel::bvh::MAX_BINS).contains(&self.bins) {
            return Err(crate::Error::InvalidArgument("kd bins must be in 2..=64"));
        }
        Ok(())
    }
    /// The depth limit for `n` triangles.
    pub fn depth_for(&self, n: u32) -> u32 {
        if self.max_depth != 0 {
            return self.max_depth;
        }
        let log2 = 32 - n.max(1).leading_zeros(); // ceil-ish log2, integer only (no_std)
        (8 + (13 * log2).div_ceil(10)).min(MAX_DEPTH as u32)
    }
}

/// What the last build produced: the AEPSA paper's Table 1 and more.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct KdInfo {
    /// Bounds of the stored triangles (unpadded).
    pub bounds: Aabb,
    /// The root's box (bounds padded by `ROOT_PAD`).
    pub root: Aabb,
    pub nodes: u32,
    pub leaves: u32,
    pub empty_leaves: u32,
    /// Triangle references in leaves (a triangle may be in several).
    pub refs: u32,
    /// Deepest leaf (root = 0) and the mean depth of all leaves.
    pub depth: u32,
    pub avg_leaf_depth: f32,
    /// Depth limit the build used.
    pub max_depth: u32,
    /// Leaves made because a pool (nodes, refs, events) was full, though
    /// the SAH wanted a split: the tree is valid, only slower.
    pub forced_leaves: u32,
    /// Most split events the build held at once (size `Limits` from it).
    pub events_peak: u32,
    /// Triangles in the scene, stored, and excluded (non-finite / zero area).
    pub triangles_in: u32,
    pub triangles: u32,
    pub excluded_non_finite: u32,
    pub excluded_zero_area: u32,
    /// SAH cost (traversal_cost per inner node and 1 per reference, by
    /// surface area relative to the root).
    pub sah_cost: f32,
    pub test: TriTest,
    /// The build that made the tree, and its bins (0 for `High`).
    pub quality: BuildQuality,
    pub bins: u32,
}

/// One node (8 bytes). `b`: low 2 bits the split axis (0..2) or 3 for a
/// leaf; the rest the left child (inner) or the reference count (leaf).
/// `a`: the split position's bits (inner) or the first reference (leaf).
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Pod, Zeroable)]
pub struct KdNode {
    pub a: u32,
    pub b: u32,
}

const _: () = assert!(core::mem::size_of::<KdNode>() == 8);

impl KdNode {
    #[inline(always)]
    pub fn inner(axis: usize, split: f32, left: u32) -> KdNode {
        KdNode {
            a: split.to_bits(),
            b: (left << 2) | axis as u32,
        }
    }
    #[inline(always)]
    pub fn leaf(first: u32, count: u32) -> KdNode {
        KdNode {
            a: first,
            b: (count << 2) | 3,
        }
    }
    #[inline(always)]
    pub fn is_leaf(&self) -> bool {
        self.b & 3 == 3
    }
    /// Split axis of an inner node.
    #[inline(always)]
    pub fn axis(&self) -> usize {
        (self.b & 3) as usize
    }
    #[inline(always)]
    pub fn split(&self) -> f32 {
        f32::from_bits(self.a)
    }
    /// Left child of an inner node (the right one is `left + 1`).
    #[inline(always)]
    pub fn left(&self) -> usize {
        (self.b >> 2) as usize
    }
    /// First reference of a leaf.
    #[inline(always)]
    pub fn first(&self) -> usize {
        self.a as usize
    }
    /// References in a leaf.
    #[inline(always)]
    pub fn count(&self) -> usize {
        (self.b >> 2) as usize
    }
    /// Most references a leaf can name (30 bits).
    pub const MAX_COUNT: u32 = (1 << 30) - 1;
}

/// The pools a kd-tree lives in (carved once from the arena).
pub struct KdPools<'a> {
    pub nodes: &'a mut [KdNode],
    /// Stored triangle slot of each leaf reference, in leaf order.
    pub refs: &'a mut [u32],
    /// Stored triangles (traceable ones, in caller order).
    pub tris: &'a mut [TriVerts],
    /// Projection-test data (empty unless `Limits::projection_test`).
    pub proj: &'a mut [ProjTri],
    /// Caller's triangle id of each stored triangle.
    pub tri_ids: &'a mut [u32],
    /// Stored slot of each caller triangle id (`INVALID_ID`: excluded).
    pub slot_of: &'a mut [u32],
    /// Build scratch (see `build_sweep.rs` and `build_binned.rs`).
    pub events: &'a mut [u64],
    /// Build scratch: one side flag per stored triangle.
    pub side: &'a mut [u8],
}

impl<'a> KdPools<'a> {
    /// The kd-tree's pools under `l` (empty without `Limits::KD`): the
    /// `kd_nodes`, `kd_refs` and `kd_events` rules and the triangles.
    #[deny(clippy::arithmetic_side_effects)]
    pub fn carve(a: &mut impl Carve<'a>, l: &Limits) -> Result<Self> {
        let on = l.has(Limits::KD);
        let n = when(on, l.max_triangles as usize);
        let rule = |v: u64| if on { entries(v) } else { Ok(0) };
        Ok(KdPools {
            nodes: a.take(rule(l.kd_nodes())?)?,
            refs: a.take(rule(l.kd_refs())?)?,
            tris: a.take(n)?,
            proj: a.take(when(l.projection_test, n))?,
            tri_ids: a.take(n)?,
            slot_of: a.take(n)?,
            events: a.take(rule(l.kd_events())?)?,
            side: a.take(n)?,
        })
    }
}

/// A per-frame kd-tree: pools plus what the last successful build wrote.
pub struct KdTree<'a> {
    pools: KdPools<'a>,
    info: Option<KdInfo>,
}

/// Read-only view of a built kd-tree; `Sync`, shared by all tracing threads.
#[derive(Clone, Copy)]
pub struct KdView<'r> {
    pub info: &'r KdInfo,
    pub nodes: &'r [KdNode],
    pub refs: &'r [u32],
    pub tris: &'r [TriVerts],
    pub proj: &'r [ProjTri],
    pub tri_ids: &'r [u32],
    pub slot_of: &'r [u32],
    /// Who decides on each candidate hit (`geom::filter`).
    pub filter: Hook<'r>,
}

impl<'r> KdView<'r> {
    /// This view with candidate hits decided by `filter`.
    #[inline(always)]
    pub fn filtered(self, filter: Hook<'r>) -> Self {
        KdView { filter, ..self }
    }

    /// This view, without its filter when a call forces opacity
    /// (`TraceParams::opaque`).
    #[inline(always)]
    pub fn opaque_if(&self, opaque: bool) -> Self {
        if opaque {
            self.filtered(Hook::None)
        } else {
            *self
        }
    }
}

impl<'a> KdTree<'a> {
    pub fn new(pools: KdPools<'a>) -> Self {
        KdTree { pools, info: None }
    }
    pub(crate) fn pools_mut(&mut self) -> &mut KdPools<'a> {
        &mut self.pools
    }
    pub(crate) fn set_info(&mut self, info: Option<KdInfo>) {
        self.info = info;
    }
    pub fn info(&self) -> Option<&KdInfo> {
        self.info.as_ref()
    }
    /// The last successful build, if any.
    pub fn view(&self) -> Option<KdView<'_>> {
        let info = self.info.as_ref()?;
        let n = info.triangles as usize;
        Some(KdView {
            info,
            nodes: &self.pools.nodes[..info.nodes as usize],
            refs: &self.pools.refs[..info.refs as usize],
            tris: &self.pools.tris[..n],
            proj: if info.test == TriTest::Projection {
                &self.pools.proj[..n]
            } else {
                &[]
            },
            tri_ids: &self.pools.tri_ids[..n],
            slot_of: &self.pools.slot_of[..info.triangles_in as usize],
            filter: Hook::None,
        })
    }
}

impl<'r> KdView<'r> {
    /// The stored triangles, as every triangle test reads them.
    #[inline(always)]
    pub fn store(&self) -> crate::geom::TriStore<'r> {
        crate::geom::TriStore {
            tris: self.tris,
            proj: self.proj,
        }
    }
}

impl KdView<'_> {
    /// The stored triangle with caller id `prim`, if it was stored.
    #[inline]
    pub fn triangle(&self, prim: u32) -> Option<TriVerts> {
        let s = *self.slot_of.get(prim as usize)?;
        self.tris.get(s as usize).copied()
    }
    /// The triangles of leaf `n` (stored slots).
    #[inline(always)]
    pub fn leaf_refs(&self, n: &KdNode) -> &[u32] {
        &self.refs[n.first()..n.first() + n.count()]
    }
    /// The boxes of inner node `n`'s children, given `n`'s box.
    #[inline]
    pub fn child_boxes(n: &KdNode, b: &Aabb) -> (Aabb, Aabb) {
        let (a, s) = (n.axis(), n.split());
        let (mut l, mut r) = (*b, *b);
        l.max[a] = s;
        r.min[a] = s;
        (l, r)
    }
}

/// The ray interval `[t0, t1]` (start from the ray's `[tmin, tmax]`) inside
/// the box `min..max` by the slab test every kd traversal shares (see the
/// module docs, Exactness). `neg`: the sign bits of the direction. NaN slab
/// terms (a zero direction with the origin on a face) constrain nothing;
/// the caller checks `t0 <= t1`.
#[inline(always)]
pub fn clip(
    min: &[f32; 3],
    max: &[f32; 3],
    org: &[f32; 3],
    rcp: &[f32; 3],
    neg: &[bool; 3],
    mut t0: f32,
    mut t1: f32,
) -> (f32, f32) {
    for a in 0..3 {
        let lo = (min[a] - org[a]) * rcp[a];
        let hi = (max[a] - org[a]) * rcp[a];
        let (near, far) = if neg[a] { (hi, lo) } else { (lo, hi) };
        t0 = if near > t0 { near } else { t0 };
        t1 = if far < t1 { far } else { t1 };
    }
    (t0, t1)
}

/// At a split, `t_s = (s - o) * rcp`: the near child's upper end
/// `min(t1, t_s)` and the far child's lower end `max(t0, t_s)` (NaN: no
/// change). Near is left unless the direction's sign bit is set.
#[inline(always)]
pub fn split_interval(ts: f32, t0: f32, t1: f32) -> (f32, f32) {
    (if ts < t1 { ts } else { t1 }, if ts > t0 { ts } else { t0 })
}

/// The kd-tree under the family contract: the single-ray traversal, the
/// 2x2 SIMD ray (`Method::KdSimd`) and frustum-driven n x n packets
/// (`Method::KdPacket`), from an entry point when `p.entry` asks for one.
impl crate::accel::Accel for KdView<'_> {
    #[inline]
    fn test(&self) -> TriTest {
        self.info.test
    }
    #[inline]
    fn bounds(&self) -> Aabb {
        self.info.bounds
    }
    fn triangle(&self, prim: u32) -> Option<TriVerts> {
        KdView::triangle(self, prim)
    }
    #[inline]
    fn intersect<T: TriangleTest>(&self, ray: &Ray, ctr: &mut Counters) -> Hit {
        traverse_single::intersect::<T>(self, ray, ctr)
    }
    #[inline]
    fn occluded<T: TriangleTest>(&self, ray: &Ray, ctr: &mut Counters) -> bool {
        traverse_single::occluded::<T>(self, ray, ctr)
    }
    #[inline]
    fn any_hit<T: TriangleTest>(&self, ray: &Ray, ctr: &mut Counters) -> Hit {
        traverse_single::any_hit::<T>(self, ray, ctr)
    }
}
