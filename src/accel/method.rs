//! What a trace call asks for: the method (which family, which traversal),
//! the packet side and each family's switches (C: `sheaf_method`,
//! `sheaf_trace_params`). It sits in `accel` so the families and the
//! packet traversals read it without importing from the trace layer above.
#![forbid(unsafe_code)]

use crate::geom::frustum::RayKind;

/// Traversal method (C: `sheaf_method`). Codes are stable; later methods get
/// new numbers.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum Method {
    /// Uniform grid, single-ray 3DDDA with macrocell skipping (the baseline).
    #[default]
    GridDda = 0,
    /// Uniform grid, coherent grid traversal of n x n packets (CGT).
    GridCgt = 1,
    /// BVH, single-ray stack traversal (the BVH baseline and reference).
    BvhSingle = 2,
    /// BVH, 2x2 SIMD rays traversed one `Ray4` at a time (Table 2's baseline).
    BvhSimd = 3,
    /// BVH, n x n packets, Masked traversal (section 3.1).
    BvhMasked = 4,
    /// BVH, n x n packets, Ranged traversal (section 3.2).
    BvhRanged = 5,
    /// BVH, n x n packets, Partition traversal (section 3.3).
    BvhPartition = 6,
    /// kd-tree, single-ray front-to-back traversal (the kd reference).
    KdSingle = 7,
    /// kd-tree, 2x2 SIMD rays one `Ray4` at a time (Wald 2004).
    KdSimd = 8,
    /// kd-tree, n x n packets driven by their frustum, from the root or
    /// from the entry point `TraceParams::entry` finds (MLRTA, AEPSA).
    KdPacket = 9,
    /// BVH, single rays through the 4-wide tree collapsed from the built
    /// one (`accel::bvh::traverse_wide`): four child boxes per SIMD test.
    BvhWide = 10,
    /// BVH, n x n packets, Ranged traversal of the 4-wide tree
    /// (`accel::bvh::traverse_wide_ranged`): all four children tested at
    /// each node.
    BvhWideRanged = 11,
    /// BVH, n x n packets, frustum-first traversal of the 4-wide tree
    /// (`accel::bvh::traverse_frustum`): the packet's interval frustum and
    /// its first live ray against all four children at once, lane groups
    /// scanned only where they disagree and at leaves.
    BvhFrustum = 12,
}

impl Method {
    pub const ALL: &'static [Method] = &[
        Method::GridDda,
        Method::GridCgt,
        Method::BvhSingle,
        Method::BvhSimd,
        Method::BvhMasked,
        Method::BvhRanged,
        Method::BvhPartition,
        Method::KdSingle,
        Method::KdSimd,
        Method::KdPacket,
        Method::BvhWide,
        Method::BvhWideRanged,
        Method::BvhFrustum,
    ];
    pub fn name(self) -> &'static str {
        match self {
            Method::GridDda => "grid-dda",
            Method::GridCgt => "grid-cgt",
            Method::BvhSingle => "bvh-single",
            Method::BvhSimd => "bvh-simd",
            Method::BvhMasked => "bvh-masked",
            Method::BvhRanged => "bvh-ranged",
            Method::BvhPartition => "bvh-partition",
            Method::KdSingle => "kd-single",
            Method::KdSimd => "kd-simd",
            Method::KdPacket => "kd-packet",
            Method::BvhWide => "bvh-wide",
            Method::BvhWideRanged => "bvh-wide-ranged",
            Method::BvhFrustum => "bvh-frustum",
        }
    }
    /// Whether the method traces n x n packets (and so uses `TraceParams::packet`).
    pub fn is_packet(self) -> bool {
        matches!(
            self,
            Method::GridCgt
                | Method::BvhMasked
                | Method::BvhRanged
                | Method::BvhPartition
                | Method::BvhWideRanged
                | Method::BvhFrustum
                | Method::KdPacket
        )
    }
    /// Which structure the method traverses.
    pub fn structure(self) -> Structure {
        match self {
            Method::GridDda | Method::GridCgt => Structure::Grid,
            Method::KdSingle | Method::KdSimd | Method::KdPacket => Structure::Kd,
            _ => Structure::Bvh,
        }
    }
    /// The single-ray method of the same structure (the reference).
    pub fn single(self) -> Method {
        match self.structure() {
            Structure::Grid => Method::GridDda,
            Structure::Bvh => Method::BvhSingle,
            Structure::Kd => Method::KdSingle,
        }
    }
    pub fn from_name(s: &str) -> Option<Method> {
        Method::ALL.iter().copied().find(|m| m.name() == s)
    }
}

/// Acceleration structure families of a context.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Structure {
    Grid,
    Bvh,
    Kd,
}

/// How one class of rays is traced (C: `sheaf_trace_params`).
#[repr(C)]
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct TraceParams {
    pub method: Method,
    /// Packet side n (n x n rays) for packet methods: 2, 4, 8, 16 or 32.
    pub packet: u32,
    /// CGT switches (macrocells, mailbox, frustum culling).
    pub cgt: CgtOptions,
    /// Tree packet switches (frustum culling, ray kind), for the BVH's and
    /// the kd-tree's n x n packets.
    pub bvh: BvhOptions,
    /// Entry-point search before each n x n packet of a tree method
    /// (`KdPacket`, `BvhMasked`, `BvhRanged`, `BvhPartition`); ignored by
    /// the other methods.
    pub entry: EntrySearch,
    /// Shadow packets whose farthest hit point is more than `split` times as
    /// far from the light as the nearest are split into four (CGT section
    /// 4.7); 0 disables splitting.
    pub split: f32,
    /// The packet fallbacks (`accel::fallback`: incoherent packets, tiny
    /// directions, wasted box tests) on (the default) or off, so studies
    /// can measure what they save. Results are the same either way. The C
    /// ABI keeps them on.
    pub fallbacks: bool,
    /// Lane width of the packet traversals (`crate::isa`): `Auto` (the
    /// CPU's widest, capped by `SHEAF_ISA`) or a forced level. Results are
    /// bitwise equal at every level.
    pub isa: crate::isa::Isa,
    /// Force opacity: no filter is asked (DXR's `RAY_FLAG_FORCE_OPAQUE`;
    /// `geom::filter`). Default false.
    pub opaque: bool,
}

impl Default for TraceParams {
    fn default() -> Self {
        TraceParams {
            method: Method::GridCgt,
            packet: 8,
            cgt: CgtOptions::default(),
            bvh: BvhOptions::default(),
            entry: EntrySearch::None,
            split: 2.0,
            fallbacks: true,
            isa: crate::isa::Isa::Auto,
            opaque: false,
        }
    }
}

impl TraceParams {
    /// The defaults with the tree packet switches `bvh`.
    pub fn with_bvh(bvh: BvhOptions) -> Self {
        TraceParams {
            bvh,
            ..TraceParams::default()
        }
    }
    /// The single-ray baseline.
    pub fn dda() -> Self {
        TraceParams {
            method: Method::GridDda,
            ..TraceParams::default()
        }
    }
    pub fn cgt(packet: u32) -> Self {
        TraceParams {
            method: Method::GridCgt,
            packet,
            ..TraceParams::default()
        }
    }
    /// A BVH method with packet side `packet` (ignored by single and SIMD).
    pub fn bvh(method: Method, packet: u32) -> Self {
        TraceParams {
            method,
            packet,
            ..TraceParams::default()
        }
    }
    /// The same parameters with entry-point search `entry`.
    pub fn with_entry(&self, entry: EntrySearch) -> Self {
        TraceParams { entry, ..*self }
    }
    /// The same parameters with the BVH ray kind set (which frustum packets get).
    pub fn with_kind(&self, kind: RayKind) -> Self {
        TraceParams {
            bvh: BvhOptions { kind, ..self.bvh },
            ..*self
        }
    }
    /// Side of the square pixel tile this method traces at once: the packet
    /// side for n x n methods, 2 for the 2x2 SIMD ray, 0 for single rays.
    pub fn tile_side(&self) -> u32 {
        if self.method.is_packet() {
            self.packet
        } else if matches!(self.method, Method::BvhSimd | Method::KdSimd) {
            2
        } else {
            0
        }
    }
    /// Checks the packet side and the split ratio.
    pub fn validate(&self) -> crate::Result<()> {
        if self.method.is_packet() && !matches!(self.packet, 2 | 4 | 8 | 16 | 32) {
            return Err(crate::Error::InvalidArgument(
                "packet side must be 2, 4, 8, 16 or 32",
            ));
        }
        if !(self.split == 0.0 || (self.split.is_finite() && self.split >= 1.0)) {
            return Err(crate::Error::InvalidArgument(
                "split must be 0 or a finite ratio >= 1",
            ));
        }
        crate::isa::resolve(self.isa)?;
        Ok(())
    }

    /// `validate`, and a packet method's side within
    /// `Limits::max_packet_side` (`Capacity { pool: PacketSide }`): the
    /// check of every call that traces with these params, made once, before
    /// the call takes any slot scratch.
    pub fn validate_for(&self, l: &crate::mem::Limits) -> crate::Result<()> {
        self.validate()?;
        if self.method.is_packet() {
            l.check_packet_side(self.packet)?;
        }
        Ok(())
    }
}

/// Switches of the packet traversal (all on by default), for comparison runs.
#[repr(C)]
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct CgtOptions {
    /// Skip M slices when the frustum's macrocells are all empty (section 2.4).
    pub macrocells: bool,
    /// Test each triangle once per packet (section 2.3).
    pub mailbox: bool,
    /// SIMD frustum culling with the four corner rays (section 2.3).
    pub culling: bool,
}

impl Default for CgtOptions {
    fn default() -> Self {
        CgtOptions {
            macrocells: true,
            mailbox: true,
            culling: true,
        }
    }
}

/// Large-packet switches (C: `sheaf_bvh_options`).
#[repr(C)]
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct BvhOptions {
    /// Frustum culling of boxes and triangles (section 4); off for comparison.
    pub culling: bool,
    /// What the rays are, which decides the frustum.
    pub kind: RayKind,
}

impl Default for BvhOptions {
    fn default() -> Self {
        BvhOptions {
            culling: true,
            kind: RayKind::Auto,
        }
    }
}

/// Which entry-point search a packet method runs before traversal (C:
/// `sheaf_entry_search`).
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum EntrySearch {
    /// Packets start at the root ("plain packet tracing").
    #[default]
    None = 0,
    /// MLRTA (Reshetov et al. 2005, as the AEPSA paper's section 2.2).
    Mlrta = 1,
    /// AEPSA (the AEPSA paper's sections 3.1-3.3).
    Aepsa = 2,
}

impl EntrySearch {
    pub const ALL: &'static [EntrySearch] =
        &[EntrySearch::None, EntrySearch::Mlrta, EntrySearch::Aepsa];
    pub fn name(self) -> &'static str {
        match self {
            EntrySearch::None => "none",
            EntrySearch::Mlrta => "mlrta",
            EntrySearch::Aepsa => "aepsa",
        }
    }
    pub fn from_name(s: &str) -> Option<EntrySearch> {
        Self::ALL.iter().copied().find(|e| e.name() == s)
    }
}
