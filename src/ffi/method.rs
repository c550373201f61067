//! `sheaf_method`: which traversal a trace, occluded or render call uses.

use crate::Method;
use crate::error::{Error, Result};

/// Traversal method of a trace, occluded or render call (the crate's
/// `Method`). Codes are stable; later methods get new numbers.
#[repr(u32)]
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum sheaf_method {
    /// Uniform grid, single-ray 3DDDA with macrocell skipping (the baseline;
    /// CGT paper section 2).
    GridDda = 0,
    /// Uniform grid, coherent grid traversal of packets (CGT paper sections
    /// 2.2-2.4). Trace and occluded calls form 8x8 packets from consecutive
    /// rays (every 4 rays a 2x2 quad); render uses 8x8 tiles; both use the
    /// thread slot's mailbox.
    GridCgt = 1,
    /// BVH, single-ray stack traversal (the BVH reference; BVH paper).
    BvhSingle = 2,
    /// BVH, 2x2 SIMD rays: every 4 consecutive rays one `Ray4` (Table 2's baseline).
    BvhSimd = 3,
    /// BVH, n x n packets, Masked traversal (BVH paper section 3.1).
    BvhMasked = 4,
    /// BVH, n x n packets, Ranged traversal (section 3.2).
    BvhRanged = 5,
    /// BVH, n x n packets, Partition traversal (section 3.3).
    BvhPartition = 6,
    /// kd-tree, single-ray front-to-back traversal (the kd reference; AEPSA paper).
    KdSingle = 7,
    /// kd-tree, 2x2 SIMD rays: every 4 consecutive rays one `Ray4`.
    KdSimd = 8,
    /// kd-tree, n x n packets driven by their frustum, from the root or from
    /// the entry point of `sheaf_trace_params.entry` (MLRTA, AEPSA).
    KdPacket = 9,
    /// BVH, single rays through the 4-wide tree every BVH build and refit
    /// collapses from its binary tree: four child boxes per SIMD test.
    BvhWide = 10,
    /// BVH, n x n packets, Ranged traversal of the 4-wide tree: all four
    /// children of a node tested per quad (from the root; with an entry
    /// point, or `width` 2, the binary Ranged traversal).
    BvhWideRanged = 11,
    /// BVH, n x n packets, frustum-first traversal of the 4-wide tree: the
    /// packet's interval frustum and first live ray against all four
    /// children of a node at once, per-lane tests only where they disagree
    /// and at leaves (from the root; with an entry point, or `width` 2, the
    /// binary Ranged traversal).
    BvhFrustum = 12,
}

impl sheaf_method {
    /// The C code of a crate method (exhaustive: a new `Method` must get a
    /// variant here before the crate compiles).
    pub const fn of(m: Method) -> sheaf_method {
        match m {
            Method::GridDda => sheaf_method::GridDda,
            Method::GridCgt => sheaf_method::GridCgt,
            Method::BvhSingle => sheaf_method::BvhSingle,
            Method::BvhSimd => sheaf_method::BvhSimd,
            Method::BvhMasked => sheaf_method::BvhMasked,
            Method::BvhRanged => sheaf_method::BvhRanged,
            Method::BvhPartition => sheaf_method::BvhPartition,
            Method::KdSingle => sheaf_method::KdSingle,
            Method::KdSimd => sheaf_method::KdSimd,
            Method::KdPacket => sheaf_method::KdPacket,
            Method::BvhWide => sheaf_method::BvhWide,
            Method::BvhWideRanged => sheaf_method::BvhWideRanged,
            Method::BvhFrustum => sheaf_method::BvhFrustum,
        }
    }

    /// The crate method with C code `raw`.
    pub fn to_core(raw: super::raw::sheaf_method) -> Result<Method> {
        Method::ALL
            .iter()
            .copied()
            .find(|&m| sheaf_method::of(m) as u32 == raw)
            .ok_or(Error::InvalidArgument("unknown sheaf_method"))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn codes_match_the_core() {
        for &m in Method::ALL {
            assert_eq!(sheaf_method::of(m) as u32, m as u32);
            assert_eq!(sheaf_method::to_core(m as u32), Ok(m));
        }
        assert!(sheaf_method::to_core(77).is_err());
    }
}
