//! Packets through a two-level scene: the top level walked once per
//! packet, and at each instance the packet's live rays mapped into the
//! instance's space (each lane by the single ray's operations,
//! `traverse_single::object_ray`) and traced through its geometry's BVH by
//! the packet method asked for (Masked, Ranged, Partition, Ranged on the
//! 4-wide tree, the 2x2 SIMD ray), through the generic packet driver
//! (`accel::packet::trace`: tiny lanes and lane-by-lane fallbacks
//! included). Each instance visit builds its packet's frustum from the
//! mapped rays (Wald, Benthin, Slusallek 2003, section 3: rays enter an
//! object in its own space).
//!
//! # Exactness
//! A lane's object-space ray is its single ray's, bit for bit, with the
//! same `tmax` rule (the nearest hit so far, one ulp up), and the
//! geometry's packet traversal answers as its single ray does. The top
//! level is walked while any live lane enters a node's box no later than
//! its nearest hit (`RayBox::entry`, the single ray's test), so every
//! instance a lane's single ray visits, the packet visits; extra visits
//! find nothing nearer. Hits merge by (t, instance, triangle), so each
//! lane gets its single ray's answer.
//!
//! # Deviations
//! - The frustum of an instance visit is built from the mapped rays, not
//!   by mapping the world frustum's planes, and always as `RayKind::Auto`
//!   (a mirroring transform turns the corner rays' winding).
//! - The top-level box test runs lane by lane (stopping at the first lane
//!   that enters): the top level is small.

use super::TwoLevelView;
use super::build::MAX_TOP_DEPTH;
use super::traverse_single::{SceneHit, object_ray};
use crate::accel::bvh::traverse_single::RayBox;
use crate::accel::method::TraceParams;
use crate::accel::packet::{self, MAX_QUADS};
use crate::accel::slot::Slot;
use crate::counters::Counters;
use crate::geom::frustum::RayKind;
use crate::geom::{Hit4, M4, Ray, Ray4, TriangleTest};
use crate::mem::scratch::bytes;

/// Slot scratch of one packet: its lanes' slab data, the mapped quads,
/// their live lanes and hits; the geometry's traversal gets the rest.
pub const SCRATCH: usize = bytes::<RayBox>(4 * MAX_QUADS)
    + bytes::<Ray4>(MAX_QUADS)
    + bytes::<M4>(MAX_QUADS)
    + bytes::<Hit4>(MAX_QUADS);

/// Trace the active lanes of `rays` (at most `MAX_QUADS` quads) with
/// `p.method` among instances whose mask shares a bit with `mask`: hit
/// `4 q + i` of `hits` is lane `i` of quad `q`'s nearest hit, or with
/// `ANY` some hit. Active lanes of `hits` must come in as misses.
#[allow(clippy::too_many_arguments)] // the packet contract's arguments and the mask
pub fn trace<T: TriangleTest, const ANY: bool>(
    s: &TwoLevelView<'_>,
    p: &TraceParams,
    rays: &[Ray4],
    active: &[M4],
    mask: u32,
    hits: &mut [SceneHit],
    slot: &mut Slot<'_>,
    ctr: &mut Counters,
) {
    let nq = rays.len().min(active.len()).min(MAX_QUADS);
    if s.tlas.is_empty() || nq == 0 {
        return;
    }
    let lane = |q: usize, i: usize| rays[q].lane(i);
    let live = |q: usize, i: usize| active[q].bitmask() >> i & 1 != 0;
    // The single ray's validity rule: invalid lanes miss.
    let (boxes, mut sl) = slot.split_from(4 * nq, |k| RayBox::new(&lane(k / 4, k % 4)));
    let mut valid = [0u8; MAX_QUADS];
    for (q, v) in valid.iter_mut().enumerate().take(nq) {
        for i in 0..4 {
            if live(q, i) && lane(q, i).is_valid() {
                *v |= 1 << i;
            }
        }
    }
    let (orays, mut sl) = sl.split(nq, rays[0]);
    let (oact, mut sl) = sl.split(nq, M4::FALSE);
    let (ohits, mut sl) = sl.split(nq, Hit4::MISS);
    let op = TraceParams {
        bvh: crate::accel::method::BvhOptions {
            kind: RayKind::Auto,
            ..p.bvh
        },
        ..*p
    };
    let nodes = s.tlas;
    let mut stack = [0u32; MAX_TOP_DEPTH + 2];
    let mut sp = 1usize;
    while sp > 0 {
        sp -= 1;
        let n = &nodes[stack[sp] as usize];
        // Some live lane enters the box no later than its nearest hit?
        let enters = (0..4 * nq).any(|k| {
            valid[k / 4] >> (k % 4) & 1 != 0 && {
                // The lane's fields read directly: no `Ray` per lane per node.
                let tmax = rays[k / 4].tmax[k % 4].min(hits[k].t);
                boxes[k].entry(n, tmax).is_some()
            }
        });
        ctr.aabb_at(1, 1);
        if !enters {
            continue;
        }
        if !n.is_leaf() {
            // Near child first, by the first live lane's direction sign.
            let k = (0..4 * nq)
                .find(|&k| valid[k / 4] >> (k % 4) & 1 != 0)
                .unwrap_or(0);
            let neg = rays[k / 4].dir[n.axis()][k % 4].is_sign_negative();
            let (near, far) = if neg {
                (n.first + 1, n.first)
            } else {
                (n.first, n.first + 1)
            };
            stack[sp] = far;
            stack[sp + 1] = near;
            sp += 2;
            continue;
        }
        let id = s.order[n.first as usize];
        let inst = &s.insts[id as usize];
        let Some(g) = s.visible(inst, mask) else {
            continue;
        };
        let mut any_live = false;
        for q in 0..nq {
            let quad: [Ray; 4] =
                core::array::from_fn(|i| object_ray(&inst.inverse, &lane(q, i), hits[4 * q + i].t));
            orays[q] = Ray4::from_rays(&quad);
            let m = valid[q] as u32;
            oact[q] = crate::geom::lane::mask_from_bits(m);
            any_live |= m != 0;
        }
        if !any_live {
            break;
        }
        ohits[..nq].fill(Hit4::MISS);
        packet::trace::<_, T, ANY>(
            &g,
            &op,
            &orays[..nq],
            &oact[..nq],
            &mut ohits[..nq],
            &mut sl,
            ctr,
        );
        for q in 0..nq {
            for i in 0..4 {
                let h = ohits[q].lane(i);
                let best = &mut hits[4 * q + i];
                if valid[q] >> i & 1 != 0 && h.is_hit() && best.closer(h.t, id, h.prim) {
                    *best = SceneHit::of(&h, inst.geometry, id);
                    if ANY {
                        // Occluded: the lane is done.
                        valid[q] &= !(1 << i);
                    }
                }
            }
        }
    }
}
