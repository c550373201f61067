//! Tracing front end: which method traces which rays, and the counters every
//! method fills. Structures know nothing of each other; this layer picks one.
#![forbid(unsafe_code)]

use bytemuck::{Pod, Zeroable};

/// A hot-loop counter update (`count!(ctr.cells += 1)`), compiled out
/// without the `counters` feature: the cheap switch of CGT's statistics.
macro_rules! count {
    ($($t:tt)*) => {
        #[cfg(feature = "counters")]
        {
            $($t)*;
        }
    };
}
pub(crate) use count;

/// Counters of one trace or render call (C: `sheaf_counters`). Each thread
/// fills its own and the caller adds them up.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Pod, Zeroable)]
pub struct Counters {
    /// Rays traced (primary, shadow, any kind).
    pub rays: u64,
    /// Grid cells whose triangles were tested.
    pub cells: u64,
    /// Empty macrocells skipped.
    pub macro_skips: u64,
    /// Ray-triangle tests (one per ray, or per lane of a packet test).
    pub tri_tests: u64,
    /// Packets traced (packet methods).
    pub packets: u64,
    /// Packet lanes traced singly because they do not move along the
    /// packet's major axis like its first ray (CGT section 2.2).
    pub stray_lanes: u64,
    /// Triangles skipped because the packet had already tested them (mailbox).
    pub mailbox_skips: u64,
    /// Triangles rejected by frustum culling for a whole packet.
    pub culled: u64,
    /// Packets that could not use frustum culling (no common origin).
    pub packets_no_cull: u64,
    /// Shadow packets split because their hit points spread too far in depth.
    pub packets_split: u64,
}

impl Counters {
    pub fn add(&mut self, o: &Counters) {
        self.rays += o.rays;
        self.cells += o.cells;
        self.macro_skips += o.macro_skips;
        self.tri_tests += o.tri_tests;
        self.packets += o.packets;
        self.stray_lanes += o.stray_lanes;
        self.mailbox_skips += o.mailbox_skips;
        self.culled += o.culled;
        self.packets_no_cull += o.packets_no_cull;
        self.packets_split += o.packets_split;
    }
}

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
}

impl Method {
    pub const ALL: &'static [Method] = &[Method::GridDda, Method::GridCgt];
    pub fn name(self) -> &'static str {
        match self {
            Method::GridDda => "grid-dda",
            Method::GridCgt => "grid-cgt",
        }
    }
    /// Whether the method traces packets (and so uses `TraceParams::packet`).
    pub fn is_packet(self) -> bool {
        matches!(self, Method::GridCgt)
    }
    pub fn from_name(s: &str) -> Option<Method> {
        Method::ALL.iter().copied().find(|m| m.name() == s)
    }
}

pub use crate::accel::grid::traverse_cgt::CgtOptions;

/// How one class of rays is traced (C: `sheaf_trace_params`).
#[repr(C)]
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct TraceParams {
    pub method: Method,
    /// Packet side n (n x n rays) for packet methods: 2, 4, 8, 16 or 32.
    pub packet: u32,
    /// CGT switches (macrocells, mailbox, frustum culling).
    pub cgt: CgtOptions,
    /// Shadow packets whose farthest hit point is more than `split` times as
    /// far from the light as the nearest are split into four (CGT section
    /// 4.7); 0 disables splitting.
    pub split: f32,
}

impl Default for TraceParams {
    fn default() -> Self {
        TraceParams { method: Method::GridCgt, packet: 8, cgt: CgtOptions::default(), split: 2.0 }
    }
}

impl TraceParams {
    /// The single-ray baseline.
    pub fn dda() -> Self {
        TraceParams { method: Method::GridDda, ..TraceParams::default() }
    }
    pub fn cgt(packet: u32) -> Self {
        TraceParams { method: Method::GridCgt, packet, ..TraceParams::default() }
    }
    /// Checks the packet side and the split ratio.
    pub fn validate(&self) -> crate::Result<()> {
        if self.method.is_packet() && !matches!(self.packet, 2 | 4 | 8 | 16 | 32) {
            return Err(crate::Error::InvalidArgument("packet side must be 2, 4, 8, 16 or 32"));
        }
        if !(self.split == 0.0 || (self.split.is_finite() && self.split >= 1.0)) {
            return Err(crate::Error::InvalidArgument("split must be 0 or a finite ratio >= 1"));
        }
        Ok(())
    }
}

use crate::geom::{M4, Ray, Ray4};

/// Pack `n` consecutive rays (`ray(k)` for `k < n`, at most `4 * quads.len()`)
/// into 2x2 quads in `Ray4` lane order; lanes past `n` are inactive (they
/// repeat the last ray so every lane holds finite data). Returns the quads used.
#[inline]
pub fn pack_quads(n: usize, ray: impl Fn(usize) -> Ray, quads: &mut [Ray4], active: &mut [M4]) -> usize {
    let nq = n.div_ceil(4);
    for q in 0..nq {
        let last = ray((q * 4 + 3).min(n - 1));
        let mut lanes = [last; 4];
        let mut m = [false; 4];
        for i in 0..4 {
            if q * 4 + i < n {
                lanes[i] = ray(q * 4 + i);
                m[i] = true;
            }
        }
        quads[q] = Ray4::from_rays(&lanes);
        active[q] = M4::new(m[0], m[1], m[2], m[3]);
    }
    nq
}
