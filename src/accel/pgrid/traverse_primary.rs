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

use super::{CamView, PgTest};
use crate::geom::{F4, Hit4, M4, Mt, Pt, RayLanes, Ray4, TriTest, Wt};
use crate::trace::{Counters, count};

/// Nearest hits of the camera rays of sorting tile `tile` (`rays`, `active`
/// lanes; `hits` start as misses or as earlier results).
pub fn trace_tile(
    g: &CamView<'_>,
    tile: u32,
    rays: &[Ray4],
    active: &[M4],
    hits: &mut [Hit4],
    ctr: &mut Counters,
) {
    match g.test {
        TriTest::MollerTrumbore => walk::<Mt>(g, tile, rays, active, hits, ctr),
        TriTest::Watertight => walk::<Wt>(g, tile, rays, active, hits, ctr),
        TriTest::Projection => walk::<Pt>(g, tile, rays, active, hits, ctr),
    }
}

/// Most 2x2 rays of one sorting tile (32 x 32 pixels).
pub const MAX_QUADS: usize = 256;

fn walk<T: PgTest>(
    g: &CamView<'_>,
    tile: u32,
    rays: &[Ray4],
    active: &[M4],
    hits: &mut [Hit4],
    ctr: &mut Counters,
) {
    let nq = rays.len().min(MAX_QUADS);
    let d = g.cells.info.depth;
    let fwd = g.pinhole.fwd;
    let mut live = [M4::FALSE; MAX_QUADS];
    let mut depth_of = [F4::ZERO; MAX_QUADS];
    let mut pre = [T::prepare(&RayLanes::from_ray4(&rays[0])); MAX_QUADS];
    ctr.packets += 1;
    for q in 0..nq {
        live[q] = active[q];
        ctr.rays += live[q].bitmask().count_ones() as u64;
        let r = &rays[q];
        // Depth along the view axis per unit t.
        depth_of[q] = r.dir[0] * F4::splat(fwd.x) + r.dir[1] * F4::splat(fwd.y) + r.dir[2] * F4::splat(fwd.z);
        pre[q] = T::prepare(&RayLanes::from_ray4(r));
    }
    for s in 0..d.count {
        let cell = g.cells.cell(tile, s);
        count!(ctr.cells += 1);
        for &tri in cell {
            let prim = T::prim(&g.tris, tri as usize);
            for q in 0..nq {
                let lm = live[q];
                if !lm.any() {
                    continue;
                }
                count!(ctr.tri_tests += lm.bitmask().count_ones() as u64);
                let h = T::intersect(&RayLanes::from_ray4(&rays[q]), &pre[q], prim);
                let hm = h.mask & lm;
                if !hm.any() {
                    continue;
                }
                let take = hm & hits[q].closer(h.t, tri);
                if take.any() {
                    let hq = &mut hits[q];
                    hq.t = F4::select(take, h.t, hq.t);
                    hq.u = F4::select(take, h.u, hq.u);
                    hq.v = F4::select(take, h.v, hq.v);
                    for i in 0..4 {
                        if take.test(i) {
                            hq.prim[i] = tri;
                        }
                    }
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
