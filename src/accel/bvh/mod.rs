//! Bounding volume hierarchy rebuilt from scratch every frame, traversed by
//! single rays, 2x2 SIMD rays and large n x n packets.
//!
//! Source: Overbeck, Ramamoorthi, Mark 2008, "Large Ray Packets for
//! Real-time Whitted Ray Tracing".
//!
//! | file | implements |
//! |---|---|
//! | `build.rs` | section 5.1: single-threaded binned SAH build (Wald 2007), an explicit work stack, into preallocated pools (`BuildQuality::Medium` and `High`) |
//! | `build_spatial.rs` | the `High` build's spatial splits (Stich, Friedrich, Dietrich 2009, SBVH, sections 3-4): slabs binned with clipped triangles, references split where object splits overlap, within the reserve `Limits::max_bvh_refs` sizes |
//! | `build_morton.rs` | the fast build (`BuildQuality::Low`): centroids' Morton codes, a radix sort, the tree emitted top-down at the codes' highest differing bit (Lauterbach et al. 2009, LBVH), every phase on the caller's workers (`mem::par`) |
//! | `presplit.rs` | the fast build's pre-splitting (Karras, Aila 2013, section 5): large, thin triangles split at a Morton grid's coarsest planes into several references before the sort, within the reserve `Limits::max_bvh_refs` sizes |
//! | `traverse_single.rs` | the single-ray reference: stack traversal, near child first |
//! | `traverse_simd.rs` | section 2.1: the 2x2 SIMD ray (`Ray4`) traversal, the "2x2 SIMD ray packets" of Table 2 |
//! | `geom::frustum` (not in this folder) | section 4: frusta for primary (4.1), point-light shadow (4.2), reflection and refraction (4.3) packets; plane test (Eq. 1-3) and corner-ray test; shared with the kd-tree packets and the entry-point searches |
//! | `packet.rs` | what the large-packet traversals share: the prepared packet (`Packet`, `QuadBox`), the `Walk` each implements (the paper's three and the two on the 4-wide tree), the lane-by-lane coherence fallback (section 5.2.1; `accel::fallback`) |
//! | `traverse_masked.rs` | section 3.1, Figure 2: Masked traversal, and its switch to Partition when too many box tests find quads dead; the exactness argument and tests of the paper's three traversals |
//! | `traverse_ranged.rs` | section 3.2, Appendix A.1: Ranged traversal (first alive ray `i_a` on the stack, `getFirstHit`/`getLastHit`) |
//! | `traverse_partition.rs` | section 3.3, Appendix A.2: Partition traversal (index list `I` partitioned in place by `partRays`) |
//! | `wide.rs` | the 4-wide tree (`WideNode`): every built binary tree collapsed (and refit in place) into nodes of four children with their boxes side by side (Dammertz et al. 2008; Wald et al. 2008), in the reference pool |
//! | `traverse_wide.rs` | the single ray through the 4-wide tree (`Method::BvhWide`): four boxes per SIMD test; the single-ray fallback of every packet traversal |
//! | `traverse_wide_ranged.rs` | section 3.2's Ranged traversal of n x n packets through the 4-wide tree (`Method::BvhWideRanged`): every child of a node tested per quad, children front to back |
//! | `traverse_frustum.rs` | n x n packets through the 4-wide tree, frustum first (`Method::BvhFrustum`; Wald, Boulos, Shirley 2007, section 4.3; Fuetterling et al. 2015, section 4): a node visit costs a constant number of wide operations, not a scan of the quads: the packet's interval frustum, then its first live ray, against all four children at once, children visited in the frustum's near order, lane groups scanned only where the two disagree; at a leaf only the lane groups whose slab test enters it (picked by per-group frusta in large packets) test its triangles; the packet set up lane group by lane group, hits kept per group as lanes; an incoherent packet retried as its four Morton quarters; an occlusion packet left with few live lanes finished by the wide single ray (Benthin et al. 2012) |
//! | `refs.rs` | what the builds share about references: their boxes in SIMD registers (`Box3`) and how many a build may write (`reference_capacity`) |
//! | `refit.rs` | refit: the built tree's boxes recomputed bottom-up for moved vertices (Embree's REFIT quality; the paper rebuilds every frame) |
//! | `entry.rs` | the BVH as an `accel::entry::EntryTree`: MLRTA/AEPSA entry points (AEPSA paper, section 8), where the three packet traversals can start |
//!
//! # Node layout
//! 32-byte nodes (`BvhNode`), two per cache line: the box, then for an inner
//! node the index of its left child (the right child follows it) and the
//! split axis; for a leaf the first stored triangle and the count. Node 0 is
//! the root. Triangles are stored in leaf order.
//!
//! # Exactness
//! Every stored box is padded by `BOX_PAD` times (the scene's largest
//! coordinate magnitude + its bounds' diagonal), so the point a triangle test reports lies inside
//! every box on the way to that triangle despite rounding. A box is skipped
//! only when its entry lies strictly beyond the ray's current nearest hit, so
//! the set of triangles tested always contains the nearest one, whatever the
//! visiting order: all traversals return the same triangle and bitwise the
//! same t (the tie rule of `geom::ray`).

pub mod build;
pub mod build_morton;
pub mod build_spatial;
pub mod entry;
pub mod packet;
pub mod presplit;
pub mod refit;
pub mod refs;
pub mod traverse_frustum;
pub mod traverse_masked;
pub mod traverse_partition;
pub mod traverse_ranged;
pub mod traverse_simd;
pub mod traverse_single;
pub mod traverse_wide;
pub mod traverse_wide_ranged;
pub mod wide;

pub use crate::accel::method::BvhOptions;
use crate::counters::Counters;
use crate::error::Result;
/// The packet frusta (section 4) live in `geom` because the kd-tree
/// packets use them too.
pub use crate::geom::frustum;
pub use crate::geom::frustum::RayKind;
use crate::geom::{Aabb, Cull, Hit, Hook, ProjTri, Ray, TriTest, TriVerts, TriangleTest};
use crate::mem::{Carve, TOO_BIG, when};
use bytemuck::{Pod, Zeroable};

/// Slot scratch this module's packet code takes (`accel::slot`) for
/// packets of up to `q` quads: the entry search's live lanes
/// (`accel::packet::start`), then, given back, one packet in the larger
/// of the two kinds of walk: the generic walks (`packet::scratch`) or the
/// frustum walk (its lane groups' boxes, hits and frusta, and the lane
/// groups: `traverse_frustum::bytes`); the 2x2 SIMD ray takes none.
pub const fn scratch(q: usize) -> usize {
    use crate::accel::slot::max;
    let frustum = traverse_frustum::bytes(q) + crate::accel::group::max_bytes(q);
    max(
        max(packet::scratch(q), frustum),
        crate::accel::packet::start_scratch(q),
    )
}

/// A leaf's stored triangles (`first .. first + count`) and its depth (for
/// the per-depth counters): what every leaf test reads of the node.
#[derive(Clone, Copy, Debug)]
pub(crate) struct LeafAt {
    pub first: u32,
    pub count: u32,
    pub depth: usize,
}

/// Deepest level a build creates (root = depth 0). Nodes at this depth
/// become leaves whatever their size, so every traversal stack of
/// `MAX_DEPTH + 1` entries suffices.
pub const MAX_DEPTH: usize = 48;
const _: () = assert!(MAX_DEPTH <= crate::accel::entry::MAX_ENTRY_DEPTH);

/// Relative padding of stored boxes (see the module docs, Exactness).
pub const BOX_PAD: f32 = 1e-5;

/// The padding of every stored box of a tree over the bounds `lo..hi`:
/// `BOX_PAD` times (the largest coordinate magnitude + the diagonal). The
/// builds and refit pad alike through this one function.
pub(crate) fn box_pad(lo: glam::Vec3A, hi: glam::Vec3A) -> glam::Vec3A {
    let m = lo.abs().max(hi.abs()).max_element();
    let diag = hi - lo;
    glam::Vec3A::splat(BOX_PAD * (m + crate::math::sqrt(diag.dot(diag))))
}

/// Largest leaf size a build accepts.
pub const MAX_LEAF: u32 = 64;

/// Most SAH bins.
pub const MAX_BINS: u32 = 64;

/// How much time a build spends on the tree's quality (C:
/// `sheaf_build_quality`), named and numbered as Embree's
/// `RTCBuildQuality`. The shape decides speed only: every traversal is
/// exact on every tree.
#[repr(u32)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum BuildQuality {
    /// Morton codes and a radix sort (LBVH, `build_morton.rs`): several
    /// times faster to build, slower to trace. For geometry rebuilt every
    /// frame.
    Low = 0,
    /// Binned SAH (the BVH paper's build, section 5.1) with `bins` bins.
    #[default]
    Medium = 1,
    /// Binned SAH with `MAX_BINS` bins, the full SAH sweep over every
    /// object split in nodes of up to `build::SWEEP_HIGH` triangles, and
    /// spatial splits (`build_spatial.rs`, SBVH) into the reference
    /// reserve `Limits::max_bvh_refs` sizes (none without one).
    High = 2,
}

/// Tunables of the BVH build (C: `sheaf_bvh_params`).
#[repr(C)]
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct BvhParams {
    /// Most triangles in a leaf (1..=64) before the build must split; below
    /// it, the SAH decides. Default 4.
    pub leaf_size: u32,
    /// SAH bins per axis (2..=64). Default 16 (Wald 2007 uses 16 to 32).
    pub bins: u32,
    /// SAH cost of one traversal step relative to one triangle test. Default 1.
    pub traversal_cost: f32,
    /// Ray-triangle test used by every traversal of this BVH.
    pub test: TriTest,
    /// Which build (default `Medium`, binned SAH). `Low` ignores `bins`
    /// and uses `traversal_cost` only for the reported SAH cost (its leaves
    /// hold up to `leaf_size` triangles).
    pub quality: BuildQuality,
    /// Children per node of the tree the single rays walk: 4 (the default)
    /// collapses every built tree into the 4-wide tree (`wide.rs`,
    /// `Method::BvhWide`, `Method::BvhWideRanged`, the packets' single-ray
    /// fallback), which a refit refits in place; 2 keeps the binary tree
    /// alone, which saves the collapse (about 1.3 ms per 46k binary nodes)
    /// on trees rebuilt every frame and traced by binary packets only.
    pub width: u32,
    /// `Low` only: pre-split large, thin triangles (`presplit.rs`) into
    /// the reference reserve `Limits::max_bvh_refs` sizes (nothing without
    /// one). Off by default: on crytek sponza it cuts a camera ray's box
    /// tests by a fifth, but it doubles the build's time and leaves the
    /// other test scenes' trees alike (docs/studies/bvh-build.md, "Pre-splitting the
    /// fast build"), so it pays only where a build is traced by many rays.
    pub presplit: bool,
}

impl Default for BvhParams {
    fn default() -> Self {
        BvhParams {
            leaf_size: 4,
            bins: 16,
            traversal_cost: 1.0,
            test: TriTest::MollerTrumbore,
            quality: BuildQuality::Medium,
            width: 4,
            presplit: false,
        }
    }
}

impl BvhParams {
    pub fn validate(&self) -> crate::Result<()> {
        if !(1..=MAX_LEAF).contains(&self.leaf_size) {
            return Err(crate::Error::InvalidArgument(
                "bvh leaf_size must be in 1..=64",
            ));
        }
        if !(2..=MAX_BINS).contains(&self.bins) {
            return Err(crate::Error::InvalidArgument("bvh bins must be in 2..=64"));
        }
        if self.width != 2 && self.width != wide::WIDTH as u32 {
            return Err(crate::Error::InvalidArgument("bvh width must be 2 or 4"));
        }
        if !(self.traversal_cost.is_finite() && self.traversal_cost > 0.0) {
            return Err(crate::Error::InvalidArgument(
                "bvh traversal_cost must be finite and > 0",
            ));
        }
        Ok(())
    }
}

/// What the last build produced (all counts exact).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct BvhInfo {
    /// Bounds of the stored triangles (unpadded; the root box is padded).
    pub bounds: Aabb,
    pub nodes: u32,
    pub leaves: u32,
    /// Deepest leaf (root = 0).
    pub depth: u32,
    /// Triangles in the scene, stored, and excluded (non-finite / zero area).
    pub triangles_in: u32,
    pub triangles: u32,
    /// Stored triangle references, the slots the leaves name: `triangles`
    /// unless the `High` build split references spatially, when a triangle
    /// may be named by several leaves (once per leaf).
    pub references: u32,
    pub excluded_non_finite: u32,
    pub excluded_zero_area: u32,
    /// SAH cost of the tree (traversal_cost per inner node and 1 per
    /// triangle, weighted by surface area relative to the root; the `Low`
    /// build weighs its padded boxes, see `build_morton.rs`).
    pub sah_cost: f32,
    pub leaf_size: u32,
    pub bins: u32,
    pub test: TriTest,
    pub quality: BuildQuality,
    /// Nodes of the 4-wide tree collapsed from this one (`wide.rs`; 0:
    /// `BvhParams::width` 2, or the reference pool could not hold it; the
    /// wide single ray then walks the binary tree).
    pub wide_nodes: u32,
}

/// One node (32 bytes). `meta`: for a leaf, the triangle count (> 0) in the
/// low 30 bits; for an inner node 0 there and the split axis in the top 2
/// bits. `first`: leaf: first stored triangle; inner: left child (right =
/// left + 1).
#[repr(C, align(32))]
#[derive(Clone, Copy, Debug, Default, PartialEq, Pod, Zeroable)]
pub struct BvhNode {
    pub min: [f32; 3],
    pub first: u32,
    pub max: [f32; 3],
    pub meta: u32,
}

const _: () = assert!(core::mem::size_of::<BvhNode>() == 32);
const _: () = assert!(
    BvhPools::SLOT_BYTES == 140,
    "the 140 bytes per triangle the docs give"
);

impl BvhNode {
    const COUNT_MASK: u32 = (1 << 30) - 1;
    #[inline(always)]
    pub fn is_leaf(&self) -> bool {
        self.meta & Self::COUNT_MASK != 0
    }
    /// Triangles in a leaf (0 for an inner node).
    #[inline(always)]
    pub fn count(&self) -> u32 {
        self.meta & Self::COUNT_MASK
    }
    /// A leaf's triangles, at depth `depth`.
    #[inline(always)]
    pub(crate) fn leaf_at(&self, depth: usize) -> LeafAt {
        LeafAt {
            first: self.first,
            count: self.count(),
            depth,
        }
    }
    /// Split axis of an inner node (0, 1, 2).
    #[inline(always)]
    pub fn axis(&self) -> usize {
        (self.meta >> 30) as usize
    }
    #[inline]
    pub fn leaf(b: &Aabb, first: u32, count: u32) -> BvhNode {
        debug_assert!(count > 0 && count <= Self::COUNT_MASK);
        BvhNode {
            min: b.min.to_array(),
            first,
            max: b.max.to_array(),
            meta: count,
        }
    }
    #[inline]
    pub fn inner(b: &Aabb, left: u32, axis: usize) -> BvhNode {
        BvhNode {
            min: b.min.to_array(),
            first: left,
            max: b.max.to_array(),
            meta: (axis as u32) << 30,
        }
    }
    #[inline(always)]
    pub fn aabb(&self) -> Aabb {
        Aabb {
            min: self.min.into(),
            max: self.max.into(),
        }
    }
}

/// Build scratch per triangle: its box and its index in the caller's buffer.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Pod, Zeroable)]
pub struct PrimRef {
    pub min: [f32; 3],
    pub id: u32,
    pub max: [f32; 3],
    pub _pad: u32,
}

/// The pools a BVH lives in (carved once from the arena).
pub struct BvhPools<'a> {
    /// `2 * max_triangles` nodes (a binary tree over N leaves-or-fewer).
    pub nodes: &'a mut [BvhNode],
    /// Stored triangles in leaf order.
    pub tris: &'a mut [TriVerts],
    /// Projection-test data (empty unless `Limits::projection_test`).
    pub proj: &'a mut [ProjTri],
    /// Caller's triangle id of each stored triangle.
    pub tri_ids: &'a mut [u32],
    /// Stored slot of each caller triangle id (`INVALID_ID`: excluded), for
    /// shading lookups by id.
    pub slot_of: &'a mut [u32],
    /// Build scratch.
    pub refs: &'a mut [PrimRef],
    /// The build's bins and work stack (`build::SCRATCH` bytes), so a build
    /// uses little of the caller's stack.
    pub scratch: &'a mut [u8],
}

impl<'a> BvhPools<'a> {
    /// Pools for a BVH of up to `tris` triangles and `refs` (at least
    /// `tris`) leaf references (none unless `on`): the triangles' slots
    /// (`slot_of`), and per reference two nodes, a stored triangle with its
    /// id, a build reference and projection data when `proj`, then the
    /// build's scratch. References beyond `tris` are the `High` build's
    /// spatial-split reserve.
    #[deny(clippy::arithmetic_side_effects)]
    pub fn carve(
        a: &mut impl Carve<'a>,
        on: bool,
        tris: usize,
        refs: usize,
        proj: bool,
    ) -> Result<Self> {
        let n = when(on, tris);
        let r = when(on, refs.max(tris));
        Ok(BvhPools {
            nodes: a.take(r.checked_mul(2).ok_or(TOO_BIG)?)?,
            tris: a.take(r)?,
            proj: a.take(when(proj, r))?,
            tri_ids: a.take(r)?,
            slot_of: a.take(n)?,
            refs: a.take(r)?,
            scratch: a.take(when(on, build::SCRATCH))?,
        })
    }
}

impl BvhPools<'_> {
    /// Bytes of pool entries per triangle slot, the ones `move_slots`
    /// moves (two nodes, the triangle, its id and slot, its reference):
    /// a two-level scene's budget per triangle and a compaction's cost per
    /// moved triangle. The projection pool, when carved, adds
    /// `size_of::<ProjTri>()` (48).
    pub const SLOT_BYTES: usize = 2 * core::mem::size_of::<BvhNode>()
        + core::mem::size_of::<TriVerts>()
        + 2 * core::mem::size_of::<u32>()
        + core::mem::size_of::<PrimRef>();

    /// Move the entries of triangle slots `from..from + len` of every pool
    /// (nodes: two per slot) to `to..` (`copy_within`, overlap allowed).
    /// A BVH built in those slots refers to them relative to their start,
    /// so it is the same tree at `to`: a two-level scene's compaction.
    /// Every pool a build writes is moved here, so a pool added to this
    /// struct is added here too.
    pub(crate) fn move_slots(&mut self, from: usize, to: usize, len: usize) {
        let (f, n) = (from, len);
        self.nodes.copy_within(2 * f..2 * (f + n), 2 * to);
        self.tris.copy_within(f..f + n, to);
        if !self.proj.is_empty() {
            self.proj.copy_within(f..f + n, to);
        }
        self.tri_ids.copy_within(f..f + n, to);
        self.slot_of.copy_within(f..f + n, to);
        // The reference pool holds the 4-wide tree.
        self.refs.copy_within(f..f + n, to);
    }
}

/// A per-frame BVH: pools plus what the last successful build wrote.
pub struct Bvh<'a> {
    pools: BvhPools<'a>,
    info: Option<BvhInfo>,
    /// The last successful build's parameters (a refit's SAH weights, its
    /// automatic rebuild).
    params: BvhParams,
    /// The padded SAH of the stored boxes as the last refit computed it
    /// (`refit::refit_with`), so the next refit need not sum it again;
    /// `None` after a build.
    refit_sah: Option<f64>,
    /// The wide tree's pool also holds, per wide child, the binary node
    /// its box is copied from (`wide::collapse`): a refit copies the
    /// binary boxes instead of fitting the wide tree again.
    wide_map: bool,
}

/// Read-only view of a built BVH; `Sync`, shared by all tracing threads.
#[derive(Clone, Copy)]
pub struct BvhView<'r> {
    pub info: &'r BvhInfo,
    pub nodes: &'r [BvhNode],
    pub tris: &'r [TriVerts],
    pub proj: &'r [ProjTri],
    pub tri_ids: &'r [u32],
    pub slot_of: &'r [u32],
    /// The 4-wide tree (empty when there is none: see `BvhInfo::wide_nodes`).
    pub wide: &'r [wide::WideNode],
    /// The side of every triangle a ray may not hit (`Cull::apply` after
    /// each triangle test): none, but for the two-level scene's geometries
    /// when the call culls (`culled`).
    pub cull: Cull,
    /// Who decides on each candidate hit (`geom::filter`): nobody, but
    /// when the call's geometry has a filter.
    pub filter: Hook<'r>,
}

/// The reference pool as wide nodes (4 references per node; both are
/// plain `f32`/`u32` arrays, so any `PrimRef` slice casts).
fn wide_pool(refs: &mut [PrimRef]) -> &mut [wide::WideNode] {
    let n = wide::capacity(core::mem::size_of_val(refs));
    bytemuck::cast_slice_mut(&mut refs[..n * 4])
}

fn wide_view(refs: &[PrimRef]) -> &[wide::WideNode] {
    let n = wide::capacity(core::mem::size_of_val(refs));
    bytemuck::cast_slice(&refs[..n * 4])
}

const _: () =
    assert!(core::mem::size_of::<wide::WideNode>() == 4 * core::mem::size_of::<PrimRef>());

/// What a `Bvh` keeps besides its pools: a two-level scene keeps one per
/// geometry (`accel::twolevel`), whose pools are runs of shared ones.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct BvhState {
    info: Option<BvhInfo>,
    params: BvhParams,
    refit_sah: Option<f64>,
    wide_map: bool,
}

impl BvhState {
    /// The last successful build, if any.
    pub fn info(&self) -> Option<&BvhInfo> {
        self.info.as_ref()
    }
}

impl<'a> Bvh<'a> {
    pub fn new(pools: BvhPools<'a>) -> Self {
        Self::with_state(pools, BvhState::default())
    }
    /// A BVH over `pools` that last built `state` (`state` of the BVH that
    /// owned these pools before).
    pub(crate) fn with_state(pools: BvhPools<'a>, state: BvhState) -> Self {
        Bvh {
            pools,
            info: state.info,
            params: state.params,
            refit_sah: state.refit_sah,
            wide_map: state.wide_map,
        }
    }
    /// What to keep to rebuild this `Bvh` over the same pools later.
    pub(crate) fn state(&self) -> BvhState {
        BvhState {
            info: self.info,
            params: self.params,
            refit_sah: self.refit_sah,
            wide_map: self.wide_map,
        }
    }
    /// The last successful build's parameters (the defaults before one).
    pub fn params(&self) -> BvhParams {
        self.params
    }
    pub(crate) fn set_params(&mut self, p: BvhParams) {
        self.params = p;
    }
    pub(crate) fn pools_mut(&mut self) -> &mut BvhPools<'a> {
        &mut self.pools
    }
    pub fn info(&self) -> Option<&BvhInfo> {
        self.info.as_ref()
    }
    /// Forget the wide tree (a build is about to overwrite its pool).
    pub(crate) fn drop_wide(&mut self) {
        if let Some(info) = self.info.as_mut() {
            info.wide_nodes = 0;
        }
    }
    /// Record a successful build: its binary tree is collapsed into the
    /// 4-wide tree (`wide.rs`) in the reference pool, free now.
    pub(crate) fn commit(&mut self, mut info: BvhInfo) -> BvhInfo {
        let nodes = &self.pools.nodes[..info.nodes as usize];
        (info.wide_nodes, self.wide_map) = if self.params.width == wide::WIDTH as u32 {
            wide::collapse_fitting(nodes, wide_pool(self.pools.refs))
        } else {
            (0, false)
        };
        self.info = Some(info);
        self.refit_sah = None;
        info
    }
    /// The padded SAH the last refit left (`None` after a build).
    pub(crate) fn refit_sah(&self) -> Option<f64> {
        self.refit_sah
    }
    /// Record a successful refit (`refit.rs`) whose stored triangles and
    /// binary boxes are written, and whose padded SAH is `sah`: the wide
    /// tree keeps its shape, and its boxes are refit too (`wide::refit`,
    /// on `par`'s workers), padded by `pad`.
    pub(crate) fn commit_refit(
        &mut self,
        info: BvhInfo,
        pad: glam::Vec3A,
        sah: f64,
        par: &dyn crate::mem::par::Par,
    ) {
        let n = info.wide_nodes as usize;
        if n > 0 && self.wide_map {
            let nodes = &self.pools.nodes[..info.nodes as usize];
            wide::refit_from_map(wide_pool(self.pools.refs), n, nodes, par);
        } else if n > 0 {
            let tris = &self.pools.tris[..info.references as usize];
            wide::refit(&mut wide_pool(self.pools.refs)[..n], tris, pad, par);
        }
        self.info = Some(info);
        self.refit_sah = Some(sah);
    }
    /// The last successful build, if any.
    pub fn view(&self) -> Option<BvhView<'_>> {
        let p = &self.pools;
        let info = self.info.as_ref()?;
        Some(BvhView::of(
            info, p.nodes, p.tris, p.proj, p.tri_ids, p.slot_of, p.refs,
        ))
    }
}

impl<'r> BvhView<'r> {
    /// The view of what `info`'s build wrote into these pools.
    pub(crate) fn of(
        info: &'r BvhInfo,
        nodes: &'r [BvhNode],
        tris: &'r [TriVerts],
        proj: &'r [ProjTri],
        tri_ids: &'r [u32],
        slot_of: &'r [u32],
        refs: &'r [PrimRef],
    ) -> Self {
        let n = info.references as usize;
        BvhView {
            info,
            nodes: &nodes[..info.nodes as usize],
            tris: &tris[..n],
            proj: if info.test == TriTest::Projection {
                &proj[..n]
            } else {
                &[]
            },
            tri_ids: &tri_ids[..n],
            slot_of: &slot_of[..info.triangles_in as usize],
            wide: &wide_view(refs)[..info.wide_nodes as usize],
            cull: Cull::None,
            filter: Hook::None,
        }
    }

    /// This view with triangles' `cull` side skipped.
    #[inline(always)]
    pub fn culled(self, cull: Cull) -> Self {
        BvhView { cull, ..self }
    }

    /// This view with candidate hits decided by `filter`.
    #[inline(always)]
    pub fn filtered(self, filter: Hook<'r>) -> Self {
        BvhView { filter, ..self }
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

    /// The stored triangles, as every triangle test reads them.
    #[inline(always)]
    pub fn store(&self) -> crate::geom::TriStore<'r> {
        crate::geom::TriStore {
            tris: self.tris,
            proj: self.proj,
        }
    }
}

impl BvhView<'_> {
    /// The stored triangle with caller id `prim`, if it was stored.
    #[inline]
    pub fn triangle(&self, prim: u32) -> Option<TriVerts> {
        let s = *self.slot_of.get(prim as usize)?;
        self.tris.get(s as usize).copied()
    }
}

/// The BVH under the family contract: the single-ray stack traversal, the
/// 4-wide single ray (`Method::BvhWide`, also the packets' fallback), the
/// 2x2 SIMD ray (`Method::BvhSimd`) and the large-packet traversals
/// (Masked, Ranged, Partition, and Ranged on the 4-wide tree), those from
/// an entry point when `p.entry` asks for one.
impl crate::accel::Accel for BvhView<'_> {
    #[inline]
    fn test(&self) -> TriTest {
        self.info.test
    }
    #[inline]
    fn bounds(&self) -> Aabb {
        self.info.bounds
    }
    fn triangle(&self, prim: u32) -> Option<TriVerts> {
        BvhView::triangle(self, prim)
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
    /// The 4-wide single ray (`traverse_wide`).
    #[inline(always)]
    fn fastest<T: TriangleTest, const ANY: bool>(&self, ray: &Ray, ctr: &mut Counters) -> Hit {
        traverse_wide::walk::<T, ANY>(self, ray, ctr)
    }
}
