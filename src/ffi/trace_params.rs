//! `sheaf_trace_params`: how one class of rays is traced (the crate's
//! `TraceParams`, with the method received as a raw integer and checked).

use super::method::sheaf_method;
use super::sized::{self, versioned};
use super::{flag, raw};
use crate::EntrySearch;
use crate::error::{Error, Result};
use crate::isa::Isa;
use crate::{CgtOptions, TraceParams};

/// Entry-point search before each tree packet (the crate's `EntrySearch`).
#[repr(u32)]
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum sheaf_entry_search {
    /// Packets start at the root.
    None = 0,
    /// MLRTA (Reshetov et al. 2005; AEPSA paper section 2.2).
    Mlrta = 1,
    /// AEPSA (AEPSA paper sections 3.1-3.3).
    Aepsa = 2,
}

impl sheaf_entry_search {
    pub const fn of(e: EntrySearch) -> sheaf_entry_search {
        match e {
            EntrySearch::None => sheaf_entry_search::None,
            EntrySearch::Mlrta => sheaf_entry_search::Mlrta,
            EntrySearch::Aepsa => sheaf_entry_search::Aepsa,
        }
    }
    pub fn to_core(raw: u32) -> Result<EntrySearch> {
        EntrySearch::ALL
            .iter()
            .copied()
            .find(|&e| sheaf_entry_search::of(e) as u32 == raw)
            .ok_or(Error::InvalidArgument("unknown sheaf_entry_search"))
    }
}

/// Lane width of packet traversals (the crate's `Isa`; Embree's `isa=`).
/// Results are bitwise equal at every level.
#[repr(u32)]
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum sheaf_isa {
    /// The CPU's widest level, capped by the `SHEAF_ISA` environment
    /// variable (`sse2`, `avx2` or `avx512`; read when the first context is
    /// created).
    Auto = 0,
    /// 4 lanes (one 2x2 quad per operation): SSE2 on x86-64, NEON or
    /// scalar elsewhere.
    Sse2 = 1,
    /// 8 lanes (two quads), x86 with AVX2.
    Avx2 = 2,
    /// 16 lanes (four quads), x86 with AVX-512F.
    Avx512 = 3,
}

impl sheaf_isa {
    pub const fn of(i: Isa) -> sheaf_isa {
        match i {
            Isa::Auto => sheaf_isa::Auto,
            Isa::Sse2 => sheaf_isa::Sse2,
            Isa::Avx2 => sheaf_isa::Avx2,
            Isa::Avx512 => sheaf_isa::Avx512,
        }
    }
    pub fn to_core(raw: u32) -> Result<Isa> {
        Isa::ALL
            .iter()
            .copied()
            .find(|&i| sheaf_isa::of(i) as u32 == raw)
            .ok_or(Error::InvalidArgument("unknown sheaf_isa"))
    }
}

/// Method, packet side, CGT switches and BVH frustum settings for one class
/// of rays (camera, shadow, or reflection and refraction). Start from `sheaf_trace_params_default`.
#[repr(C)]
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct sheaf_trace_params {
    /// `sizeof` the caller's struct, set by `sheaf_trace_params_default`
    /// (docs/c-api.md, "Upgrading").
    pub size: u32,
    /// A `sheaf_method` value.
    pub method: raw::sheaf_method,
    /// Packet side n (n x n rays) for packet methods: 2, 4, 8, 16 or 32.
    pub packet: u32,
    /// CGT: skip slices of empty macrocells (paper section 2.4). 0 or 1.
    pub macrocells: u32,
    /// CGT: test each triangle once per packet (section 2.3), with the
    /// thread slot's mailbox. 0 or 1.
    pub mailbox: u32,
    /// Frustum culling: CGT's SIMD corner-ray culling (CGT section 2.3) and
    /// the BVH packets' box and triangle culling (BVH paper section 4).
    /// 0 or 1.
    pub culling: u32,
    /// BVH and kd-tree packets: which frustum they get (a `sheaf_ray_kind`).
    pub ray_kind: raw::sheaf_ray_kind,
    /// Tree packets (`KD_PACKET`, `BVH_MASKED`, `BVH_RANGED`,
    /// `BVH_PARTITION`): entry-point search first (a `sheaf_entry_search`).
    pub entry: raw::sheaf_entry_search,
    /// Split shadow packets whose hit points' distances from the light
    /// differ by more than this ratio (section 4.7); 0 disables splitting.
    pub split: f32,
    /// Lane width of packet traversals (a `sheaf_isa`): `AUTO` (0, the
    /// default) or a forced level, which the CPU must support
    /// (`SHEAF_STATUS_INVALID_ARGUMENT` otherwise).
    pub isa: raw::sheaf_isa,
    /// Skip every filter (`sheaf_filter_fn`; DXR's
    /// `RAY_FLAG_FORCE_OPAQUE`): 0 (the default) or 1.
    pub force_opaque: u32,
}

impl sheaf_trace_params {
    pub fn of(p: &TraceParams) -> Self {
        sheaf_trace_params {
            size: core::mem::size_of::<sheaf_trace_params>() as u32,
            method: sheaf_method::of(p.method) as u32,
            packet: p.packet,
            macrocells: p.cgt.macrocells.into(),
            mailbox: p.cgt.mailbox.into(),
            culling: p.cgt.culling.into(),
            ray_kind: super::bvh::sheaf_ray_kind::of(p.bvh.kind) as u32,
            entry: sheaf_entry_search::of(p.entry) as u32,
            split: p.split,
            isa: sheaf_isa::of(p.isa) as u32,
            force_opaque: p.opaque.into(),
        }
    }
    /// The crate value, its enums and flags checked (the values by the
    /// call that takes it: `TraceParams::validate_for`).
    pub fn to_core(&self) -> Result<TraceParams> {
        let culling = flag(self.culling, "sheaf_trace_params.culling must be 0 or 1")?;
        let p = TraceParams {
            method: sheaf_method::to_core(self.method)?,
            packet: self.packet,
            cgt: CgtOptions {
                macrocells: flag(
                    self.macrocells,
                    "sheaf_trace_params.macrocells must be 0 or 1",
                )?,
                mailbox: flag(self.mailbox, "sheaf_trace_params.mailbox must be 0 or 1")?,
                culling,
            },
            bvh: crate::BvhOptions {
                culling,
                kind: super::bvh::sheaf_ray_kind::to_core(self.ray_kind)?,
            },
            entry: sheaf_entry_search::to_core(self.entry)?,
            split: self.split,
            // Always on in C (module `accel::fallback`).
            fallbacks: true,
            isa: sheaf_isa::to_core(self.isa)?,
            opaque: flag(
                self.force_opaque,
                "sheaf_trace_params.force_opaque must be 0 or 1",
            )?,
        };
        // Every call taking the params validates them once, against its
        // context's limits, before it traces (`TraceParams::validate_for`).
        Ok(p)
    }
}

versioned!(
    sheaf_trace_params => TraceParams,
    [
        method,
        packet,
        macrocells,
        mailbox,
        culling,
        ray_kind,
        entry,
        split,
        isa,
        force_opaque
    ],
    sheaf_trace_params::of(&TraceParams::default())
);

/// Write the defaults to `*out`: coherent grid traversal, 8x8 packets,
/// macrocells, mailbox and culling on, shadow split ratio 2.
///
/// `*out` is a struct of `size` bytes (sheaf.h's macro passes `sizeof
/// *out`; see `sheaf_limits_default`).
///
/// `out` must not be NULL. Errors: `SHEAF_STATUS_INVALID_ARGUMENT` when
/// `size` is no size of this struct. Thread-safe.
#[unsafe(no_mangle)]
pub extern "C" fn sheaf_trace_params_default(
    out: *mut sheaf_trace_params,
    size: usize,
) -> super::sheaf_status {
    sized::write_defaults(out, size)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn entry_search_round_trips() {
        for &e in EntrySearch::ALL {
            assert_eq!(
                sheaf_entry_search::to_core(sheaf_entry_search::of(e) as u32),
                Ok(e)
            );
        }
        assert!(sheaf_entry_search::to_core(3).is_err());
    }
}
