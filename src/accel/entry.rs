//! Entry points into trees (AEPSA paper section 2.1): "the common ancestor
//! node in the tree of all leaves that contain objects overlapped fully or
//! partially by the ray proxy frustum". Shared vocabulary of the searches
//! (`kd::traverse_mlrta`, `kd::traverse_aepsa`) and the trees they search
//! (the kd-tree, and the BVH as the paper's further work, section 8).

use crate::geom::Aabb;

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

/// Where the rays of a frustum enter a tree: a node, its depth (root 0) and
/// its box (for a kd-tree the box the splits above it carve out).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct EntryPoint {
    pub node: u32,
    pub depth: u32,
    pub aabb: Aabb,
}
