//! Camera rays through the perspective grid (section 3).
//!
//! The rays of one sorting tile visit the tile's cells front to back. Each
//! triangle of a cell is read once and tested against every 2x2 ray of the
//! tile that is still looking (the paper's shared-memory loop). After a
//! slice, rays whose nearest hit lies in that slice or before are done;
//! the tile stops at the first slice where all its rays are done.
//!
//! Indirect mapping (a tracing tile of k x k sorting tiles, each with its
//! own cells) is the caller's loop over `trace_tile`: on CPU threads the
//! tracing tile is the unit of work, the sorting tile the unit of culling.

use super::{CamView, TriangleTest};
use crate::accel::group;
use crate::accel::slot::Slot;
use crate::counters::{Counters, count};
use crate::geom::{F4, Hit4, M4, Ray4, Wide};
use crate::isa;
use crate::math;
use crate::mem::scratch::bytes;

/// Nearest hits of the camera rays of sorting tile `tile`: `rays` are its
/// `(side / 2)^2` 2x2 quads row by row (pixel quads, lanes as `Ray4`),
/// `active` lanes; `hits` start as misses or as earlier results.
pub fn trace_tile(
    g: &CamView<'_>,
    tile: u32,
    rays: &[Ray4],
    active: &[M4],
    hits: &mut [Hit4],
    slot: &mut Slot<'_>,
    ctr: &mut Counters,
) {
    crate::geom::with_test!(g.test, |T| tile_at::<T>(
        g, tile, rays, active, hits, slot, ctr
    ))
}

/// `walk` at the lane width of `g.isa` (`isa::run_fn`).
fn tile_at<T: TriangleTest>(
    g: &CamView<'_>,
    tile: u32,
    rays: &[Ray4],
    active: &[M4],
    hits: &mut [Hit4],
    slot: &mut Slot<'_>,
    ctr: &mut Counters,
) {
    isa::run_fn::<Walk<T>, Walk<T>>(g.isa, (g, tile, rays, active, hits, slot.reborrow(), ctr))
}

/// `walk` as an `isa::LaneFn` (its own signature).
struct Walk<T>(core::marker::PhantomData<T>);

impl<T: TriangleTest> isa::Sig for Walk<T> {
    type Args<'a> = (
        &'a CamView<'a>,
        u32,
        &'a [Ray4],
        &'a [M4],
        &'a mut [Hit4],
        Slot<'a>,
        &'a mut Counters,
    );
    type Out = ();
}

impl<T: TriangleTest> isa::LaneFn<Walk<T>> for Walk<T> {
    #[inline(always)]
    fn call<L: Wide>((g, tile, rays, active, hits, mut slot, ctr): <Self as isa::Sig>::Args<'_>) {
        walk::<L, T>(g, tile, rays, active, hits, &mut slot, ctr)
    }
}

/// Most quads traced as one packet (32 x 32 rays), for every family.
pub use crate::accel::packet::MAX_QUADS;

/// Slot scratch a sorting tile of up to `q` quads takes: per quad the
/// live lanes and the depth per unit t, and the quads' lane groups with
/// the triangle test's precomputation (`accel::group`, the largest kind
/// and width).
pub const fn scratch(q: usize) -> usize {
    bytes::<M4>(q) + bytes::<F4>(q) + group::max_bytes(q)
}

/// The tile's walk, its triangle tests on `L`-wide lanes.
#[inline(always)]
fn walk<L: Wide, T: TriangleTest>(
    g: &CamView<'_>,
    tile: u32,
    rays: &[Ray4],
    active: &[M4],
    hits: &mut [Hit4],
    slot: &mut Slot<'_>,
    ctr: &mut Counters,
) {
    let nq = rays.len().min(MAX_QUADS);
    // A triangle spanning several slices is tested once per tile: its
    // hits for the tile's live rays cannot change in a later slice.
    let mail = slot.mailbox.covers(g.tris.tris.len());
    if mail {
        slot.mailbox.next_packet(g.tris.tris.len());
    }
    let d = g.cells.info.depth;
    let fwd = g.pinhole.fwd;
    // Per-quad state from the slot's scratch (all written below).
    let (live, mut slot) = slot.split(nq, M4::FALSE);
    let (depth_of, mut slot) = slot.split(nq, F4::ZERO);
    ctr.packets += 1;
    for q in 0..nq {
        live[q] = active[q];
        ctr.rays += live[q].bitmask().count_ones() as u64;
        let r = &rays[q];
        // Depth along the view axis per unit t.
        depth_of[q] =
            r.dir[0] * F4::splat(fwd.x) + r.dir[1] * F4::splat(fwd.y) + r.dir[2] * F4::splat(fwd.z);
    }
    let (grp, mut slot) = group::join::<L, T>(&rays[..nq], &mut slot);
    // Quads are a half x half grid over the tile's pixels from (x0, y0).
    let half = (g.tile / 2) as i32;
    let tx = tile % g.cells.info.tiles[0];
    let (x0, y0) = (
        (tx * g.tile) as f32,
        ((tile / g.cells.info.tiles[0]) * g.tile) as f32,
    );
    let quad_range = |lo: f32, hi: f32, o: f32| -> (i32, i32) {
        // Pixel centres c + 0.5 in [lo, hi], as quad columns from o.
        let a = math::ceil(lo - 0.5 - o).max(-2.0);
        let b = math::floor(hi - 0.5 - o).min(2.0 * half as f32);
        (
            (a as i32).div_euclid(2).max(0),
            (b as i32).div_euclid(2).min(half - 1),
        )
    };
    for s in 0..d.count {
        let cell = g.cells.cell(tile, s);
        count!(ctr.cells += 1);
        for &tri in cell {
            if mail && !slot.mailbox.first_visit(tri as usize) {
                count!(ctr.mailbox_skips += 1);
                continue;
            }
            let prim = T::prim(g.tris, tri as usize);
            // Only the quads whose pixel centres the triangle's padded
            // pixel bounds cover can hit it.
            let b = g.px_box[tri as usize];
            let (qx0, qx1) = quad_range(b[0], b[2], x0);
            let (qy0, qy1) = quad_range(b[1], b[3], y0);
            // Row by row, the lane groups holding the covered quads.
            for qy in qy0..=qy1 {
                let a = (qy * half + qx0) as usize;
                let b = ((qy * half + qx1) as usize).min(nq.saturating_sub(1));
                if qx0 > qx1 || a >= nq {
                    continue;
                }
                let (g0, g1) = (a / L::G, b / L::G);
                for (gi, gr) in grp.iter().enumerate().take(g1 + 1).skip(g0) {
                    let mut sel = 0u32;
                    for k in 0..L::G {
                        sel |= u32::from((a..=b).contains(&(gi * L::G + k))) << k;
                    }
                    let bits = group::lane_bits::<L>(gi, sel, |q| live[q]);
                    if bits == 0 {
                        continue;
                    }
                    count!(ctr.tri_tests += bits.count_ones() as u64);
                    let (h, hb) = group::test(gr, prim, bits, crate::geom::Cull::None);
                    group::each_hit(&h, hb, |k, hm, hit| {
                        let ray = || group::quad_ray(&gr.r, k);
                        let q = gi * L::G + k;
                        group::take::<false>(&mut hits[q], hm, hit, tri, &g.filter, ray);
                    });
                }
            }
        }
        // Rays whose nearest hit cannot lie beyond slice s are done.
        let mut any = false;
        for q in 0..nq {
            if !live[q].any() {
                continue;
            }
            let hq = &hits[q];
            let z = hq.t * depth_of[q];
            let mut done = [false; 4];
            for i in 0..4 {
                done[i] = hq.prim[i] != crate::geom::INVALID_ID && d.hi(z[i]) <= s;
            }
            live[q] &= !M4::new(done[0], done[1], done[2], done[3]);
            any |= live[q].any();
        }
        if !any {
            break;
        }
    }
}
