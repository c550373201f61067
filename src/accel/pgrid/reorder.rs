//! Shadow ray reordering and load balancing (sections 4.2 and 4.3,
//! Algorithm 1).
//!
//! Input: one (light tile, primary ray) pair per shadow ray, made by the
//! caller with `LightFrame::tile_of` (the map step). Then:
//! 1. sort the pairs by light tile (radix sort, stable: rays of a tile stay
//!    in pixel order);
//! 2. mark tile boundaries (hard boundaries) and count each tile's rays (the
//!    segmented scan);
//! 3. split a tile of R > r rays into ceil(R / r) chunks of at most r rays
//!    (soft boundaries);
//! 4. keep one chunk record per chunk: empty tiles never make one (the
//!    stream compaction).
//!
//! On one CPU thread steps 2 to 4 are one pass over the sorted keys. Each
//! chunk is a contiguous range of the sorted rays, so chunks write their
//! shadow bits to disjoint ranges without synchronisation.

use crate::mem::sort::{bits_for, radix_sort};
use bytemuck::{Pod, Zeroable};

/// A work item of shadow tracing: `count` rays of light tile `tile`, at
/// positions `start..start + count` of the sorted ray list.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Pod, Zeroable)]
pub struct Chunk {
    pub tile: u32,
    pub start: u32,
    pub count: u32,
}

/// What the reordering produced.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct ReorderInfo {
    /// Shadow rays sorted.
    pub rays: u32,
    /// Light tiles with at least one ray.
    pub tiles_used: u32,
    /// Chunks made (at least `tiles_used`).
    pub chunks: u32,
    /// Rays of the most crowded light tile.
    pub max_tile_rays: u32,
}

/// Sort `tiles` (light tile per ray, all below `tile_count`) with `ids`
/// (ray ids), then fill `chunks` with chunks of at most `r` rays. `chunks`
/// must hold `rays / r + min(rays, tile_count)` records (one per tile plus
/// one per full r).
pub fn reorder(
    tiles: &mut [u32],
    ids: &mut [u32],
    tmp_keys: &mut [u32],
    tmp_vals: &mut [u32],
    tile_count: u32,
    r: u32,
    chunks: &mut [Chunk],
) -> ReorderInfo {
    let n = tiles.len();
    radix_sort(tiles, ids, tmp_keys, tmp_vals, bits_for(tile_count));
    let mut info = ReorderInfo {
        rays: n as u32,
        ..ReorderInfo::default()
    };
    let mut c = 0usize;
    let mut i = 0usize;
    while i < n {
        // Hard boundary at i: the segment of tile tiles[i].
        let tile = tiles[i];
        let mut j = i + 1;
        while j < n && tiles[j] == tile {
            j += 1;
        }
        let count = (j - i) as u32;
        info.tiles_used += 1;
        info.max_tile_rays = info.max_tile_rays.max(count);
        // Soft boundaries every r rays.
        let mut s = i as u32;
        while s < j as u32 {
            let k = r.min(j as u32 - s);
            chunks[c] = Chunk {
                tile,
                start: s,
                count: k,
            };
            c += 1;
            s += k;
        }
        i = j;
    }
    info.chunks = c as u32;
    info
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn one_tile_with_all_rays_splits_into_full_chunks() {
        let mut tiles = [7u32; 1000];
        let mut ids: [u32; 1000] = core::array::from_fn(|i| i as u32);
        let (mut tk, mut tv) = ([0u32; 1000], [0u32; 1000]);
        let mut chunks = [Chunk::default(); 1000 / 16 + 16];
        let info = reorder(&mut tiles, &mut ids, &mut tk, &mut tv, 16, 64, &mut chunks);
        assert_eq!(info.tiles_used, 1);
        assert_eq!(info.chunks, 16); // 15 x 64 + 40
        assert_eq!(info.max_tile_rays, 1000);
        let mut next = 0;
        for (k, ch) in chunks[..16].iter().enumerate() {
            assert_eq!(ch.tile, 7);
            assert_eq!(ch.start, next);
            assert_eq!(ch.count, if k < 15 { 64 } else { 40 });
            next += ch.count;
        }
        // Stable: ids still in order.
        assert!(ids.iter().enumerate().all(|(i, &v)| v == i as u32));
    }

    #[test]
    fn chunks_cover_every_ray_once_and_skip_empty_tiles() {
        let n = 777;
        let mut tiles: [u32; 777] = core::array::from_fn(|i| ((i * 37) % 50) as u32 * 2);
        let mut ids: [u32; 777] = core::array::from_fn(|i| i as u32);
        let orig = tiles;
        let (mut tk, mut tv) = ([0u32; 777], [0u32; 777]);
        let mut chunks = [Chunk::default(); 777 / 16 + 100];
        let info = reorder(&mut tiles, &mut ids, &mut tk, &mut tv, 100, 16, &mut chunks);
        assert_eq!(info.tiles_used, 50);
        let mut seen = [false; 777];
        let mut next = 0;
        for ch in &chunks[..info.chunks as usize] {
            assert!(ch.count >= 1 && ch.count <= 16);
            assert_eq!(ch.start, next);
            next += ch.count;
            for p in ch.start..ch.start + ch.count {
                let id = ids[p as usize] as usize;
                assert_eq!(orig[id], ch.tile);
                assert!(!seen[id]);
                seen[id] = true;
            }
        }
        assert_eq!(next as usize, n);
        assert!(seen.iter().all(|&s| s));
    }
}
