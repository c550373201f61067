//! Packets through a two-level scene: the top level walked once per
//! packet by the packet's interval frustum (as the frustum walk of a
//! geometry, `bvh::traverse_frustum`: Wald, Boulos, Shirley 2007, section
//! 4.3), and at each instance the lanes that enter its box mapped into the
//! instance's space, four at a time (the single ray's operations,
//! `traverse_single::object_ray`), and traced through its geometry's BVH
//! by the packet method asked for (the paper's three, the frustum walk,
//! the 2x2 SIMD ray) through the geometries' kernel the call chose once
//! (`trace::scene::Tracing`: tiny lanes and lane-by-lane fallbacks
//! included), whose one setup pass makes the mapped packet's frustum
//! (Wald, Benthin, Slusallek 2003, section 3: rays enter an object in its
//! own space).
//!
//! The frustum is made once per packet from its live lanes' bounds
//! (`LaneBounds`), in the one setup pass over the quads that also makes
//! their slab data, live lanes and far ends, and tested against both children of a top-level node
//! at once; the nearer child (by the frustum's near distance) is visited
//! first, and a node whose near distance lies beyond every live lane's
//! far end (its nearest hit so far, or `tmax`) is dropped. At an instance each quad's lanes get the
//! single ray's own box test (`QuadBox::entry`, lanes of `RayBox::entry`),
//! and only the lanes that enter are mapped and traced.
//!
//! # Exactness
//! A lane's object-space ray is its single ray's, bit for bit
//! (`Affine::point4` and `vector4` are `point` and `vector` lane by lane,
//! the same f32 operations in the same order), with the same `tmax` rule
//! (the nearest hit so far, one ulp up), and the geometry's packet
//! traversal answers as its single ray does. The frustum is conservative
//! (`traverse_frustum`'s exactness; its bounds use the same monotone
//! operations for zero and tiny directions, whose reciprocals are
//! infinite or huge), so an inner node is dropped only when
//! no live lane enters it by its nearest hit, and at an instance a lane is
//! traced when its single ray's test enters the instance's box by that
//! hit: every instance that may hold a lane's nearest hit, the lane
//! visits. Extra visits find nothing nearer. Hits merge by (t, instance,
//! triangle), so each lane gets its single ray's answer whatever the
//! order of visits. For a tiny direction, whose slab terms overflow
//! (`traverse_wide`'s deviations), "nothing nearer" rests on the geometry
//! walk as it does for the single ray; the edge packets of
//! `tests/exact/twolevel_exact.rs` (tiny, zero-component and invalid lanes,
//! `tmin > 0`, short `tmax`) check it.
//!
//! # Deviations
//! - The frustum of an instance visit is built from the mapped rays, not
//!   by mapping the world frustum's planes, and the instance's packet is
//!   always of `RayKind::Auto` (a mirroring transform turns the corner
//!   rays' winding).
//! - Inner top-level nodes get the frustum test only (no lane test): the
//!   top level is small, and the lanes are tested at its leaves.
//! - Occlusion packets keep their world frustum's bounds when lanes become
//!   occluded (only its far end shrinks).
//! - Counters: one box test for the root, two per inner node (both
//!   children at once), and one per quad at an instance, not per lane.

use super::build::MAX_TOP_DEPTH;
use super::traverse_single::SceneHit;
use super::{RayControls, TwoLevelView};
use crate::accel::bvh::BvhNode;
use crate::accel::bvh::BvhView;
use crate::accel::bvh::packet::{LaneBounds, QuadBox};
use crate::accel::bvh::traverse_frustum::Frustum;
use crate::accel::method::TraceParams;
use crate::accel::packet::MAX_QUADS;
use crate::accel::slot::Slot;
use crate::counters::Counters;
use crate::geom::frustum::RayKind;
use crate::geom::{F4, Hit4, M4, Ray4};
use crate::mem::scratch::bytes;

/// Slot scratch of one packet of up to `q` quads: its quads' slab data,
/// live lanes and far ends, the mapped quads, their lanes and hits; the
/// geometry's traversal gets the rest.
pub const fn scratch(q: usize) -> usize {
    bytes::<QuadBox>(q)
        + bytes::<M4>(q)
        + bytes::<F4>(q)
        + bytes::<Ray4>(q)
        + bytes::<M4>(q)
        + bytes::<Hit4>(q)
}

/// What a scene trace call fixes for all its packets: the scene, the
/// method's parameters and the ray controls.
#[derive(Clone, Copy)]
pub struct SceneCall<'c, 'v> {
    pub scene: &'c TwoLevelView<'v>,
    pub params: &'c TraceParams,
    pub ctl: RayControls,
}

/// Trace the active lanes of `rays` (at most `MAX_QUADS` quads) in
/// `call.scene` with `call.params.method` among instances whose mask shares
/// a bit with `call.ctl.mask`, without the triangle side `call.ctl.cull`:
/// hit `4 q + i` of `hits` is lane `i` of quad `q`'s nearest hit, or with
/// `ANY` some hit. Active lanes of `hits` must come in as misses. `blas`
/// traces each instance's packet in its geometry's BVH (the trace call's
/// kernel for the method with the scene's triangle test, chosen once per
/// call: `trace::scene::Tracing`; the view it gets culls `ctl.cull`).
pub fn trace<'v, const ANY: bool>(
    call: &SceneCall<'_, 'v>,
    mut blas: impl FnMut(
        &BvhView<'v>,
        &TraceParams,
        &[Ray4],
        &[M4],
        &mut [Hit4],
        &mut Slot<'_>,
        &mut Counters,
    ),
    rays: &[Ray4],
    active: &[M4],
    hits: &mut [SceneHit],
    slot: &mut Slot<'_>,
    ctr: &mut Counters,
) {
    let SceneCall {
        scene: s,
        params: p,
        ctl,
    } = *call;
    let nq = rays
        .len()
        .min(active.len())
        .min(MAX_QUADS)
        .min(hits.len() / 4);
    if s.tlas.is_empty() || nq == 0 {
        return;
    }
    // One setup pass over the quads: each quad's slab data, live lanes
    // (the single ray's validity rule: invalid lanes miss) and far ends
    // (the end of the interval a box must overlap: the nearest hit so far,
    // or `tmax`), and the frustum's lane bounds and far end.
    let (live, mut sl) = slot.split(nq, M4::FALSE);
    let (tfar, mut sl) = sl.split(nq, F4::ZERO);
    let mut bounds = LaneBounds::EMPTY;
    let (mut far, mut any_live) = (F4::NEG_INFINITY, false);
    let (qb, mut sl) = sl.split_from(nq, |q| {
        let r = &rays[q];
        let (l, t) = (active[q] & r.valid(), r.tmax.min(t4(hits, q)));
        (live[q], tfar[q]) = (l, t);
        bounds.add(r, l);
        far = far.max(F4::select(l, t, F4::NEG_INFINITY));
        any_live |= l.any();
        QuadBox::new(r)
    });
    if !any_live {
        return;
    }
    let mut fr = Frustum::from_bounds(&bounds);
    // `far_end(live, tfar)`, accumulated above.
    fr.set_tfar(far.max_element());
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
    // Nodes to visit and the frustum's near distance to each.
    let mut stack = [(0u32, 0f32); MAX_TOP_DEPTH + 2];
    let mut sp = 0;
    let (bits, t0) = pair(&fr, &nodes[0], &nodes[0]);
    ctr.aabb_at(0, 1);
    if bits & 1 != 0 {
        stack[0] = (0, t0.x);
        sp = 1;
    }
    while sp > 0 {
        sp -= 1;
        let (id, near) = stack[sp];
        // Beyond every live lane's far end (`t0` is never NaN).
        if near > fr.tfar() {
            continue;
        }
        let n = &nodes[id as usize];
        if !n.is_leaf() {
            // Both children at once, nearer (by the frustum) on top.
            let (c0, c1) = (n.first, n.first + 1);
            let (bits, t0) = pair(&fr, &nodes[c0 as usize], &nodes[c1 as usize]);
            ctr.aabb_at(1, 2);
            let (n0, n1) = (t0.x, t0.y);
            let first_near = n0 <= n1;
            for (c, t, on) in if first_near {
                [(c1, n1, bits & 2 != 0), (c0, n0, bits & 1 != 0)]
            } else {
                [(c0, n0, bits & 1 != 0), (c1, n1, bits & 2 != 0)]
            } {
                if on {
                    stack[sp] = (c, t);
                    sp += 1;
                }
            }
            continue;
        }
        let id = s.order[n.first as usize];
        let inst = &s.insts[id as usize];
        let Some(g) = s.visible(inst, id, ctl) else {
            continue;
        };
        // The lanes that enter the instance's box by their far end (the
        // single ray's test, `RayBox::entry`, lane by lane), mapped into
        // its space (`traverse_single::object_ray`, lane by lane).
        let mut any_live = false;
        for q in 0..nq {
            let m = live[q] & qb[q].entry(n, tfar[q]).0;
            ctr.aabb_at(1, 1);
            oact[q] = m;
            if !m.any() {
                continue;
            }
            any_live = true;
            let r = &rays[q];
            // `tmax` cut to just past the nearest hit so far.
            let tmax = F4::from_array(core::array::from_fn(|i| {
                let best = hits[4 * q + i].t;
                if best < r.tmax[i] {
                    best.next_up()
                } else {
                    r.tmax[i]
                }
            }));
            orays[q] = Ray4 {
                org: inst.inverse.point4(&r.org),
                dir: inst.inverse.vector4(&r.dir),
                tmin: r.tmin,
                tmax,
            };
        }
        if !any_live {
            continue;
        }
        ohits[..nq].fill(Hit4::MISS);
        blas(
            &g,
            &op,
            &orays[..nq],
            &oact[..nq],
            &mut ohits[..nq],
            &mut sl,
            ctr,
        );
        let mut changed = false;
        for q in 0..nq {
            let hit = oact[q] & ohits[q].hit_mask();
            if !hit.any() {
                continue;
            }
            for i in 0..4 {
                let h = ohits[q].lane(i);
                let best = &mut hits[4 * q + i];
                if hit.test(i) && best.closer(h.t, id, h.prim) {
                    *best = SceneHit::of(&h, inst.geometry, id);
                    changed = true;
                    if ANY {
                        // Occluded: the lane is done.
                        live[q].set(i, false);
                    }
                }
            }
            tfar[q] = rays[q].tmax.min(t4(hits, q));
        }
        if changed {
            if ANY && !live[..nq].iter().any(|l| l.any()) {
                break;
            }
            fr.set_tfar(far_end(live, tfar));
        }
    }
}

/// Quad `q`'s nearest hits' t.
#[inline(always)]
fn t4(hits: &[SceneHit], q: usize) -> F4 {
    F4::new(
        hits[4 * q].t,
        hits[4 * q + 1].t,
        hits[4 * q + 2].t,
        hits[4 * q + 3].t,
    )
}

/// The largest far end of a live lane.
#[inline(always)]
fn far_end(live: &[M4], tfar: &[F4]) -> f32 {
    let mut m = F4::NEG_INFINITY;
    for (l, t) in live.iter().zip(tfar) {
        m = m.max(F4::select(*l, *t, F4::NEG_INFINITY));
    }
    m.max_element()
}

/// Which of the boxes of `a` (bit 0) and `b` (bit 1) the frustum admits,
/// and its near distance to each (lanes x and y).
#[inline(always)]
fn pair(fr: &Frustum, a: &BvhNode, b: &BvhNode) -> (u32, F4) {
    let lanes = |x: f32, y: f32| [x, y, x, y];
    let min = core::array::from_fn(|k| lanes(a.min[k], b.min[k]));
    let max = core::array::from_fn(|k| lanes(a.max[k], b.max[k]));
    let (bits, t0) = fr.test_boxes(&min, &max);
    (bits & 3, t0)
}
