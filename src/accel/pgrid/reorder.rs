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
//! On CPU threads steps 2 to 4 are two passes over the sorted keys (count
//! the chunks, then write them), each worker taking the tiles that start
//! in its share. Each chunk is a contiguous range of the sorted rays, so
//! chunks write their shadow bits to disjoint ranges without
//! synchronisation.

use crate::mem::par::{MAX_WORKERS, Par, Parts, share};
use crate::mem::sort::{SortScratch, bits_for, radix_sort_with};
use bytemuck::{Pod, Zeroable};
use core::ops::Range;

/// A work item of shadow tracing: `count` rays of light tile `tile`, at
/// positions `start..start + count` of the sorted ray list.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Pod, Zeroable)]
pub struct Chunk {
    pub tile: u32,
    pub start: u32,
    pub count: u32,
}

/// The (light tile, ray id) pairs of the shadow rays, key and value pools
/// of the sort.
pub struct Pairs<'a> {
    pub tiles: &'a mut [u32],
    pub ids: &'a mut [u32],
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

/// Sort the pairs at `parts` of `pairs` (tiles below `tile_count`; one
/// part per worker of `par`, in order) into `pairs.tiles[..rays]` and
/// `pairs.ids[..rays]`, then fill `chunks` with chunks of at most `r`
/// rays. `chunks` must hold `rays / r + min(rays, tile_count)` records
/// (one per tile plus one per full r); `scratch` is the sort's.
///
/// On several workers, each takes the tiles whose first ray lies in its
/// share of the sorted rays, counts their chunks, and writes them after the
/// chunks of the workers before it: the same chunks as one thread makes.
/// Panics unless `parts` holds one range per worker of `par` (at most
/// `MAX_WORKERS`).
pub fn reorder(
    pairs: Pairs<'_>,
    parts: &[Range<usize>],
    scratch: SortScratch<'_>,
    tile_count: u32,
    r: u32,
    chunks: &mut [Chunk],
    par: &dyn Par,
) -> ReorderInfo {
    let workers = parts.len();
    let Pairs { tiles, ids } = pairs;
    let n = radix_sort_with(
        tiles,
        ids,
        scratch.tmp_keys,
        scratch.tmp_vals,
        parts,
        bits_for(tile_count),
        scratch.counts,
        par,
    );
    let tiles = &tiles[..n];
    // Worker w's tiles: those starting in its share of the rays.
    let segments = |w: usize, f: &mut dyn FnMut(u32, usize, usize)| {
        let sh = share(n, w, workers);
        let mut i = sh.start;
        while i > 0 && i < sh.end && tiles[i] == tiles[i - 1] {
            i += 1;
        }
        while i < sh.end {
            let tile = tiles[i];
            let mut j = i + 1;
            while j < n && tiles[j] == tile {
                j += 1;
            }
            f(tile, i, j);
            i = j;
        }
    };
    let chunks_of = |len: usize| len.div_ceil(r as usize);
    let mut mine = [ReorderInfo::default(); MAX_WORKERS];
    {
        let out = Parts::even(&mut mine[..workers], workers);
        par.run(&|w| {
            let m = &mut out.get(w)[0];
            segments(w, &mut |_, i, j| {
                m.tiles_used += 1;
                m.chunks += chunks_of(j - i) as u32;
                m.max_tile_rays = m.max_tile_rays.max((j - i) as u32);
            });
        });
    }
    let mut bounds = [0usize; MAX_WORKERS + 1];
    let mut info = ReorderInfo {
        rays: n as u32,
        ..ReorderInfo::default()
    };
    for (w, m) in mine[..workers].iter().enumerate() {
        bounds[w + 1] = bounds[w] + m.chunks as usize;
        info.tiles_used += m.tiles_used;
        info.chunks += m.chunks;
        info.max_tile_rays = info.max_tile_rays.max(m.max_tile_rays);
    }
    let cs = Parts::at(&mut chunks[..info.chunks as usize], &bounds[..workers + 1]);
    par.run(&|w| {
        let mut out = cs.get(w).iter_mut();
        segments(w, &mut |tile, i, j| {
            // Soft boundaries every r rays.
            let mut s = i as u32;
            while s < j as u32 {
                let count = r.min(j as u32 - s);
                if let Some(c) = out.next() {
                    *c = Chunk {
                        tile,
                        start: s,
                        count,
                    };
                }
                s += count;
            }
        });
    });
    info
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::accel::testkit::Backwards;
    use crate::mem::sort::BUCKETS;

    /// `reorder` of all of `tiles` on `workers` workers (run backwards).
    fn sorted(
        tiles: &mut [u32],
        ids: &mut [u32],
        tile_count: u32,
        r: u32,
        chunks: &mut [Chunk],
        workers: usize,
    ) -> ReorderInfo {
        let n = tiles.len();
        let (mut tk, mut tv) = (vec![0u32; n], vec![0u32; n]);
        let mut counts = vec![0u32; workers * BUCKETS];
        let parts: Vec<_> = (0..workers).map(|w| share(n, w, workers)).collect();
        let scratch = SortScratch {
            tmp_keys: &mut tk,
            tmp_vals: &mut tv,
            counts: &mut counts,
        };
        let info = reorder(
            Pairs { tiles, ids },
            &parts,
            scratch,
            tile_count,
            r,
            chunks,
            &Backwards(workers),
        );
        assert_eq!(info.rays as usize, n);
        info
    }

    #[test]
    fn one_tile_with_all_rays_splits_into_full_chunks() {
        let mut tiles = [7u32; 1000];
        let mut ids: [u32; 1000] = core::array::from_fn(|i| i as u32);
        let mut chunks = [Chunk::default(); 1000 / 16 + 16];
        let info = sorted(&mut tiles, &mut ids, 16, 64, &mut chunks, 3);
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
        let mut chunks = [Chunk::default(); 777 / 16 + 100];
        let info = sorted(&mut tiles, &mut ids, 100, 16, &mut chunks, 1);
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

    #[test]
    fn workers_make_the_chunks_of_one_thread() {
        let n = 5000;
        // Runs of one tile longer than a share, single rays, empty tiles.
        let make = || -> (Vec<u32>, Vec<u32>) {
            let tiles = (0..n)
                .map(|i| {
                    if i < 2600 {
                        3
                    } else {
                        ((i * 7919) % 97) as u32 * 2
                    }
                })
                .collect();
            (tiles, (0..n as u32).collect())
        };
        let (mut t1, mut i1) = make();
        let mut c1 = vec![Chunk::default(); n / 8 + 200];
        let one = sorted(&mut t1, &mut i1, 200, 8, &mut c1, 1);
        for workers in [2, 3, 7, 16] {
            let (mut t, mut i) = make();
            let mut c = vec![Chunk::default(); n / 8 + 200];
            let got = sorted(&mut t, &mut i, 200, 8, &mut c, workers);
            assert_eq!(got, one, "{workers} workers");
            assert_eq!((&t, &i), (&t1, &i1), "{workers} workers");
            assert_eq!(c[..got.chunks as usize], c1[..one.chunks as usize]);
        }
    }
}
