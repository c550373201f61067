//! Shadow rays of one chunk through their light tile's cells (section 4.4).
//!
//! Every ray of a chunk starts at the light and lies in the chunk's light
//! tile, so the chunk reads the tile's cells front to back from the light
//! side, each triangle once for all its rays. A ray leaves when it is
//! occluded or when the slices pass its end point (`tmax = 1` at the
//! surface it shadows); the chunk stops when no ray is left.

use super::{LightView, TriangleTest};
use crate::accel::group;
use crate::accel::slot::Slot;
use crate::counters::{Counters, count};
use crate::geom::{M4, Ray4, Wide};
use crate::isa;
use crate::math;
use crate::mem::scratch::bytes;

/// Most 2x2 rays traced together (larger chunks go in batches of these).
pub const MAX_QUADS: usize = 64;

/// Slot scratch a batch takes: per quad the live lanes, each lane's last
/// slice and the (a, b) bounds, and the quads' lane groups with the
/// triangle test's precomputation (`accel::group`, the largest kind and
/// width).
pub const SCRATCH: usize = bytes::<M4>(MAX_QUADS)
    + bytes::<[u32; 4]>(MAX_QUADS)
    + bytes::<[f32; 4]>(MAX_QUADS)
    + group::max_bytes(MAX_QUADS);

/// Occlusion of the shadow rays `rays` (from the light, `tmax` at their end
/// points) in light tile `tile`: `occluded[q]` gets the lanes of `active[q]`
/// that hit a triangle in `[tmin, tmax)`.
pub fn trace_chunk(
    g: &LightView<'_>,
    tile: u32,
    rays: &[Ray4],
    active: &[M4],
    occluded: &mut [M4],
    slot: &mut Slot<'_>,
    ctr: &mut Counters,
) {
    for p in crate::accel::packet::packet_ranges(rays.len()) {
        let (r, a, o) = (&rays[p.clone()], &active[p.clone()], &mut occluded[p]);
        crate::geom::with_test!(g.test, |T| batch_at::<T>(g, tile, r, a, o, slot, ctr))
    }
}

/// `walk` at the lane width of `g.isa` (`isa::run_fn`).
fn batch_at<T: TriangleTest>(
    g: &LightView<'_>,
    tile: u32,
    rays: &[Ray4],
    active: &[M4],
    occluded: &mut [M4],
    slot: &mut Slot<'_>,
    ctr: &mut Counters,
) {
    isa::run_fn::<Walk<T>, Walk<T>>(
        g.isa,
        (g, tile, rays, active, occluded, slot.reborrow(), ctr),
    )
}

/// `walk` as an `isa::LaneFn` (its own signature).
struct Walk<T>(core::marker::PhantomData<T>);

impl<T: TriangleTest> isa::Sig for Walk<T> {
    type Args<'a> = (
        &'a LightView<'a>,
        u32,
        &'a [Ray4],
        &'a [M4],
        &'a mut [M4],
        Slot<'a>,
        &'a mut Counters,
    );
    type Out = ();
}

impl<T: TriangleTest> isa::LaneFn<Walk<T>> for Walk<T> {
    #[inline(always)]
    fn call<L: Wide>(
        (g, tile, rays, active, occluded, mut slot, ctr): <Self as isa::Sig>::Args<'_>,
    ) {
        walk::<L, T>(g, tile, rays, active, occluded, &mut slot, ctr)
    }
}

/// One batch, its triangle tests on `L`-wide lanes.
#[inline(always)]
fn walk<L: Wide, T: TriangleTest>(
    g: &LightView<'_>,
    tile: u32,
    rays: &[Ray4],
    active: &[M4],
    occluded: &mut [M4],
    slot: &mut Slot<'_>,
    ctr: &mut Counters,
) {
    let nq = rays.len();
    // Triangles spanning several slices are tested once per batch.
    let mail = slot.mailbox.covers(g.tris.tris.len());
    if mail {
        slot.mailbox.next_packet(g.tris.tris.len());
    }
    let d = g.cells.info.depth;
    // Per-quad state from the slot's scratch.
    let (live, mut slot) = slot.split(nq, M4::FALSE);
    let (last, mut slot) = slot.split(nq, [0u32; 4]);
    let mut end = 0;
    // (a, b) bounds of each quad's rays: a triangle whose (a, b) bounds
    // miss them cannot block any of them.
    let (qbox, mut slot) = slot.split(nq, [0.0f32; 4]);
    ctr.packets += 1;
    for q in 0..nq {
        let mut b = [
            f32::INFINITY,
            f32::INFINITY,
            f32::NEG_INFINITY,
            f32::NEG_INFINITY,
        ];
        for i in 0..4 {
            if active[q].test(i) {
                let r = rays[q].lane(i);
                let (a, bb) = g.frame.angles(glam::Vec3::from(r.dir));
                b = [b[0].min(a), b[1].min(bb), b[2].max(a), b[3].max(bb)];
            }
        }
        qbox[q] = b;
    }
    for q in 0..nq {
        live[q] = active[q];
        occluded[q] = M4::FALSE;
        ctr.rays += live[q].bitmask().count_ones() as u64;
        let r = &rays[q];
        // The ray covers distances [tmin |dir|, tmax |dir|) from the light.
        let len2 = r.dir[0] * r.dir[0] + r.dir[1] * r.dir[1] + r.dir[2] * r.dir[2];
        for i in 0..4 {
            if live[q].test(i) {
                last[q][i] = d.hi(math::sqrt(len2[i]) * r.tmax[i]);
                end = end.max(last[q][i]);
            }
        }
    }
    let (grp, mut slot) = group::join::<L, T>(rays, &mut slot);
    for s in 0..=end {
        let cell = g.cells.cell(tile, s);
        count!(ctr.cells += 1);
        for &tri in cell {
            if mail && !slot.mailbox.first_visit(tri as usize) {
                count!(ctr.mailbox_skips += 1);
                continue;
            }
            let prim = T::prim(g.tris, tri as usize);
            let tb = g.ab_box[tri as usize];
            let mut left = false;
            for (gi, gr) in grp.iter().enumerate() {
                // The group's live quads whose (a, b) bounds meet the
                // triangle's.
                let mut sel = 0u32;
                for k in 0..L::G {
                    let q = gi * L::G + k;
                    if q >= nq || !live[q].any() {
                        continue;
                    }
                    left = true;
                    let b = &qbox[q];
                    if tb[0] > b[2] || tb[2] < b[0] || tb[1] > b[3] || tb[3] < b[1] {
                        count!(ctr.culled += 1);
                        continue;
                    }
                    sel |= 1 << k;
                }
                if sel == 0 {
                    continue;
                }
                let bits = group::lane_bits::<L>(gi, sel, |q| live[q]);
                count!(ctr.tri_tests += bits.count_ones() as u64);
                let (h, hb) = group::test(gr, prim, bits, crate::geom::Cull::None);
                group::each_hit(&h, hb, |k, hm, hit| {
                    let q = gi * L::G + k;
                    let hm = g
                        .filter
                        .quad_with(hm, hit, tri, || group::quad_ray(&gr.r, k));
                    occluded[q] |= hm;
                    live[q] &= !hm;
                });
            }
            if !left {
                return;
            }
        }
        // Rays that end in this slice are done.
        let mut any = false;
        for q in 0..nq {
            if live[q].any() {
                let l = last[q];
                live[q] &= !M4::new(l[0] <= s, l[1] <= s, l[2] <= s, l[3] <= s);
                any |= live[q].any();
            }
        }
        if !any {
            return;
        }
    }
}
