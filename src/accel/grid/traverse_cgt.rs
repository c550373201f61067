//! Coherent grid traversal: packets of n x n rays marched through the grid
//! slice by slice (Wald, Ize, Kensler, Knoll, Parker 2006, sections 2.2-2.4).
//!
//! - Section 2.2: rays in canonical grid space; the major axis K is the
//!   dominant axis of the first ray; every ray must move the same way along K
//!   (lanes that do not are traced singly by the 3DDDA, so results stay
//!   exact). The frustum bounds the rays' u and v slopes along K; per slice
//!   the overlap box B is one 4-wide multiply-add of the slice number and one
//!   truncation gives the u, v cell range. Traversal stops early once every
//!   ray has a hit before the next slice.
//! - Section 2.3: mailboxing per packet (one stamp per triangle, per thread)
//!   and SIMD frustum culling (Dmitriev et al. 2004 shaft culling: if the four
//!   corner rays of the frustum miss the same edge of a triangle, every ray
//!   of the packet misses it).
//! - Section 2.4: a slice of macrocells all empty skips M fine slices.
//!
//! Exactness: every ray is tested against every triangle of every cell it
//! passes through before its own termination point, with the same triangle
//! test and tie rule as `traverse_single`, so packets return the same
//! triangle and bitwise the same t as the 3DDDA.
//!
//! # Memory
//! Per quad, the live lanes, the slice coordinates and the triangle test's
//! precomputation come from the thread slot's scratch (`SCRATCH` bytes for
//! the largest packet, `MAX_QUADS` quads), not the caller's stack.
//!
//! # Deviations
//! - `B(s)` is computed as `B(s0) + (s - s0) * dB` rather than accumulated,
//!   so rounding does not grow with the number of slices, and the box and the
//!   culling cone are widened by a relative epsilon (`SLOPE_EPS`): culling or
//!   skipping a triangle a ray's f32 test would hit is never allowed.
//! - The first and last slices come from the rays' own `[tmin, tmax)` and the
//!   grid's extent along K; slices where the frustum lies outside the grid
//!   in u or v cost one comparison each.
//! - Frustum culling needs a common origin (primary rays, shadow rays traced
//!   from the light); other packets skip culling (counted).
//!
//! # Fallbacks (`trace::fallback`)
//! Section 2.2 asks every ray of a packet to move the same way along K, and
//! section 4.7 notes that a wide frustum "breaks down" (it intersects every
//! triangle inside it) and splits shadow packets by hit distance. Beyond
//! the stray lanes above, three checks keep CGT within about twice the
//! 3DDDA:
//! - lanes with tiny directions (`fallback::tiny`) never reach CGT: the
//!   trace call (`trace::scene::Tracing`, `accel::packet::quieted`) sends
//!   them to the 3DDDA and the packet
//!   here on quads where they are replaced (their subnormal arithmetic
//!   would slow every quad holding one);
//! - after the stray lanes leave, a packet failing `fallback::coherent`
//!   (directions spread over more than a 30 degree cone, or origins over a
//!   quarter of the scene) is traced lane by lane by the 3DDDA;
//! - the budget (`fallback::CGT_BUDGET`): after each slice, the work the
//!   packet did there (quad-triangle tests, triangles met first, cells) is
//!   added to what it spent, and what the 3DDDA would have done for its
//!   live lanes (each crosses `1 + |du| + |dv|` cells of the slice, slopes
//!   capped at the grid's size, each cell a step plus the slice's mean
//!   references per cell) to what it may spend; a packet over budget hands
//!   its live lanes to the 3DDDA (`alone`). Lanes no longer live have their
//!   exact hits.

use super::{GridView, TriangleTest};
use crate::accel::fallback;
use crate::accel::group;
use crate::accel::method::TraceParams;
use crate::accel::packet::{PacketArgs, PacketSig};
use crate::accel::slot::Slot;
use crate::counters::{Counters, count};
use crate::geom::{F4, Hit, Hit4, M4, Ray4, TriVerts, Wide};
use crate::isa;
use crate::mem::scratch::bytes;
use glam::Vec3;

use super::traverse_single;

/// Largest packet side (32 x 32 rays = 256 `Ray4` quads).
pub const MAX_SIDE: usize = 32;

/// Relative widening of slopes and boxes (see Deviations).
const SLOPE_EPS: f32 = 1e-4;
/// Absolute widening of the overlap box, in cells.
const BOX_EPS: f32 = 1e-3;

pub use crate::accel::mailbox::Mailbox;
pub use crate::accel::method::CgtOptions;

/// Slot scratch a packet of up to `q` quads takes: per quad the live
/// lanes and six slice coordinates, and the quads' lane groups with the
/// triangle test's precomputation (`accel::group`, the largest kind and
/// width).
pub const fn scratch(q: usize) -> usize {
    bytes::<M4>(q) + 6 * bytes::<F4>(q) + group::max_bytes(q)
}

/// Nearest hits of the active lanes of `rays` (a packet of `rays.len()`
/// quads; longer inputs are consecutive packets of `MAX_QUADS`) into
/// `hits` at the lane width of `opt.isa`; inactive lanes are left
/// untouched. The slot lends the mailbox and the per-quad scratch
/// (`scratch`). For tests and studies: a trace call runs `Cgt` through
/// its `Kernel`.
pub fn intersect<T: TriangleTest>(
    g: &GridView<'_>,
    rays: &[Ray4],
    active: &[M4],
    hits: &mut [Hit4],
    opt: &TraceParams,
    slot: &mut Slot<'_>,
    ctr: &mut Counters,
) {
    let args = (g, opt, rays, active, hits, slot.reborrow(), ctr);
    isa::run_fn::<PacketSig<GridView>, Cgt<T, false>>(opt.isa, args)
}

/// Occlusion of the active lanes: `hits[q].prim[i] != INVALID_ID` marks an
/// occluded lane (t and the id of some occluder, not the nearest).
pub fn occluded<T: TriangleTest>(
    g: &GridView<'_>,
    rays: &[Ray4],
    active: &[M4],
    hits: &mut [Hit4],
    opt: &TraceParams,
    slot: &mut Slot<'_>,
    ctr: &mut Counters,
) {
    let args = (g, opt, rays, active, hits, slot.reborrow(), ctr);
    isa::run_fn::<PacketSig<GridView>, Cgt<T, true>>(opt.isa, args)
}

/// CGT on the packet contract (`accel::packet::PacketSig`) at a lane
/// width: packets of up to `MAX_QUADS` quads, each traced by `packet`.
/// Per-quad scratch comes from the slot, `nq` values per packet, so no
/// size classes are needed.
pub struct Cgt<T, const ANY: bool>(core::marker::PhantomData<T>);

impl<'g, T: TriangleTest, const ANY: bool> isa::LaneFn<PacketSig<GridView<'g>>> for Cgt<T, ANY> {
    #[inline(always)]
    fn call<L: Wide>(args: PacketArgs<'_, GridView<'g>>) {
        let (g, opt, rays, active, hits, mut slot, ctr) = args;
        let n = rays.len().min(active.len()).min(hits.len());
        for r in crate::accel::packet::packet_ranges(n) {
            let (rays, active) = (&rays[r.clone()], &active[r.clone()]);
            packet::<L, T, ANY>(g, rays, active, &mut hits[r], opt, &mut slot, ctr)
        }
    }
}

#[inline(always)]
fn lane_mask(m: M4) -> u32 {
    m.bitmask()
}

/// One packet of `rays.len() <= MAX_QUADS` quads, its triangle tests on
/// `L`-wide lanes (`accel::group`).
#[inline(always)]
fn packet<L: Wide, T: TriangleTest, const ANY: bool>(
    g: &GridView<'_>,
    rays: &[Ray4],
    active: &[M4],
    hits: &mut [Hit4],
    opt: &TraceParams,
    slot: &mut Slot<'_>,
    ctr: &mut Counters,
) {
    let info = g.info;
    let nq = rays.len();
    ctr.packets += 1;
    let (live, mut slot) = slot.split(nq, M4::FALSE);
    let mut any_live = false;
    for q in 0..nq {
        // Invalid rays are misses (Ray::is_valid), as in the 3DDDA.
        let mut m = active[q];
        for i in 0..4 {
            if m.test(i) && !rays[q].lane(i).is_valid() {
                // An active but invalid ray is a miss (written, like any
                // active lane's result), and takes no part in the packet.
                m.set(i, false);
                hits[q].set_lane(i, Hit::MISS);
            }
        }
        live[q] = m;
        any_live |= m.any();
    }
    // Rays: every valid active lane once (stray lanes are counted by the
    // 3DDDA that traces them, so they are subtracted below).
    let lanes_in = live
        .iter()
        .map(|m| lane_mask(*m).count_ones() as u64)
        .sum::<u64>();
    ctr.rays += lanes_in;
    if !any_live || info.triangles == 0 {
        return;
    }
    let gmin = info.bounds.min;
    let inv = info.inv_cell;
    let res = [info.res[0] as i32, info.res[1] as i32, info.res[2] as i32];

    // Major axis K: the dominant grid-space axis of the first live ray.
    let (q0, i0) = first_lane(live);
    let d0 = Vec3::new(
        rays[q0].dir[0][i0] * inv.x,
        rays[q0].dir[1][i0] * inv.y,
        rays[q0].dir[2][i0] * inv.z,
    );
    let a0 = d0.abs();
    let k = if a0.x >= a0.y && a0.x >= a0.z {
        0
    } else if a0.y >= a0.z {
        1
    } else {
        2
    };
    let (u, v) = ((k + 1) % 3, (k + 2) % 3);
    let flip = d0[k] < 0.0;
    let nk = res[k] as f32;

    // Per quad: position along K in the travel frame (K flipped so that
    // travel is +K), 1 / dK, and u, v slopes.
    let zero = F4::ZERO;
    let (ok, mut slot) = slot.split(nq, zero);
    let (rk, mut slot) = slot.split(nq, zero);
    let (du, mut slot) = slot.split(nq, zero);
    let (dv, mut slot) = slot.split(nq, zero);
    let (ou, mut slot) = slot.split(nq, zero);
    let (ov, mut slot) = slot.split(nq, zero);
    let mut stray = 0u64;
    // Cells the live rays cross per slice alone, summed (the budget's unit).
    let mut cross = F4::ZERO;
    for q in 0..nq {
        let r = &rays[q];
        let dk = r.dir[k] * F4::splat(inv[k]);
        let dk = if flip { -dk } else { dk };
        let okw = (r.org[k] - F4::splat(gmin[k])) * F4::splat(inv[k]);
        ok[q] = if flip { F4::splat(nk) - okw } else { okw };
        rk[q] = F4::ONE / dk;
        du[q] = r.dir[u] * F4::splat(inv[u]) * rk[q];
        dv[q] = r.dir[v] * F4::splat(inv[v]) * rk[q];
        // Lanes not moving forward along K, or whose 1 / dK or slopes
        // overflow (subnormal direction components), leave the packet for
        // the 3DDDA: an infinite slope would make every slice's box NaN.
        let fwd = dk.cmpgt(zero)
            & rk[q].is_finite_mask()
            & du[q].is_finite_mask()
            & dv[q].is_finite_mask();
        let strays = live[q] & !fwd;
        if strays.any() {
            for i in 0..4 {
                if strays.test(i) {
                    stray += 1;
                    let ray = r.lane(i);
                    let h = if ANY {
                        traverse_single::any_hit::<T>(g, &ray, ctr)
                    } else {
                        traverse_single::intersect::<T>(g, &ray, ctr)
                    };
                    hits[q].set_lane(i, h);
                }
            }
            live[q] &= fwd;
        }
        ou[q] = (r.org[u] - F4::splat(gmin[u])) * F4::splat(inv[u]);
        ov[q] = (r.org[v] - F4::splat(gmin[v])) * F4::splat(inv[v]);
        // A ray crosses at most res_u + res_v cells sideways in a slice.
        let k1 = F4::ONE
            + du[q].abs().min(F4::splat(res[u] as f32))
            + dv[q].abs().min(F4::splat(res[v] as f32));
        cross += F4::select(live[q] & k1.cmplt(F4::INFINITY), k1, F4::ZERO);
        for i in 0..4 {
            if live[q].test(i) {
                hits[q].set_lane(i, Hit::MISS);
            }
        }
    }
    ctr.stray_lanes += stray;
    ctr.rays -= stray;
    // Incoherent packets (`trace::fallback`): every lane still live (all
    // move forward along K) by the 3DDDA.
    if !fallback::coherent(opt.fallbacks, rays, live, info.bounds.diagonal().length()) {
        return crate::accel::packet::alone::<GridView, T, ANY>(g, rays, live, hits, ctr);
    }
    // The budget (`fallback::CGT_BUDGET`): quad-cells spent and allowed.
    let budget = opt.fallbacks;
    let mut nl = live_lanes(live);
    let per_lane = if nl > 0 {
        cross.element_sum() / nl as f32
    } else {
        1.0
    };
    let (mut spent, mut allowed) = (0.0f32, 0.0f32);

    // Slices to visit: from the earliest start to the latest end of any ray.
    let mut kin = f32::INFINITY;
    let mut kout = f32::NEG_INFINITY;
    let mut smin = [f32::INFINITY; 2];
    let mut smax = [f32::NEG_INFINITY; 2];
    for q in 0..nq {
        let m = live[q];
        if !m.any() {
            continue;
        }
        let r = &rays[q];
        let dk = F4::ONE / rk[q];
        let a = ok[q] + r.tmin * dk;
        let b = ok[q] + r.tmax * dk;
        kin = kin.min(F4::select(m, a, F4::INFINITY).min_element());
        kout = kout.max(F4::select(m, b, F4::NEG_INFINITY).max_element());
        smin[0] = smin[0].min(F4::select(m, du[q], F4::INFINITY).min_element());
        smax[0] = smax[0].max(F4::select(m, du[q], F4::NEG_INFINITY).max_element());
        smin[1] = smin[1].min(F4::select(m, dv[q], F4::INFINITY).min_element());
        smax[1] = smax[1].max(F4::select(m, dv[q], F4::NEG_INFINITY).max_element());
    }
    // Widened like the overlap box: the f32 triangle test may put a hit
    // just inside [tmin, tmax) a rounding error beyond the slice its t maps
    // to (a ray ending on the grid's face). NaN when no lane is live.
    kin -= BOX_EPS + SLOPE_EPS * kin.abs();
    kout += BOX_EPS + SLOPE_EPS * kout.abs();
    // Unless both hold (false for NaN).
    if !(kin < nk && kout > 0.0) {
        return;
    }
    let s0 = (kin.max(0.0) as i32).min(res[k] - 1);
    let s1 = if kout >= nk {
        res[k] - 1
    } else {
        (kout as i32).min(res[k] - 1)
    };
    for a in 0..2 {
        smin[a] -= SLOPE_EPS * (1.0 + smin[a].abs());
        smax[a] += SLOPE_EPS * (1.0 + smax[a].abs());
    }

    // Overlap box at the reference plane k = s0 (travel frame): the extreme
    // u, v of all rays there; then B(s) = base + (s - s0) * dB (Eq. in 2.2).
    let kr = F4::splat(s0 as f32);
    let mut lo = [f32::INFINITY; 2];
    let mut hi = [f32::NEG_INFINITY; 2];
    for q in 0..nq {
        let m = live[q];
        if !m.any() {
            continue;
        }
        let uu = ou[q] + (kr - ok[q]) * du[q];
        let vv = ov[q] + (kr - ok[q]) * dv[q];
        lo[0] = lo[0].min(F4::select(m, uu, F4::INFINITY).min_element());
        hi[0] = hi[0].max(F4::select(m, uu, F4::NEG_INFINITY).max_element());
        lo[1] = lo[1].min(F4::select(m, vv, F4::INFINITY).min_element());
        hi[1] = hi[1].max(F4::select(m, vv, F4::NEG_INFINITY).max_element());
    }
    let widen = |x: f32| BOX_EPS + SLOPE_EPS * x.abs();
    // B over slab [s, s+1]: the low edge moves by min(0, slope) within it.
    let base = F4::new(
        lo[0] + smin[0].min(0.0) - widen(lo[0]),
        hi[0] + smax[0].max(0.0) + widen(hi[0]),
        lo[1] + smin[1].min(0.0) - widen(lo[1]),
        hi[1] + smax[1].max(0.0) + widen(hi[1]),
    );
    let db = F4::new(smin[0], smax[0], smin[1], smax[1]);
    let box_at = |s: i32| base + db * F4::splat((s - s0) as f32);
    // Cell range of a box along u and v (inclusive), or None when outside.
    let range = |b: F4| -> Option<[i32; 4]> {
        if b.y < 0.0
            || b.x >= res[u] as f32
            || b.w < 0.0
            || b.z >= res[v] as f32
            || !(b.x <= b.y && b.z <= b.w)
        {
            return None;
        }
        // Truncation equals floor for the clamped, non-negative values.
        Some([
            (b.x as i32).clamp(0, res[u] - 1),
            (b.y as i32).clamp(0, res[u] - 1),
            (b.z as i32).clamp(0, res[v] - 1),
            (b.w as i32).clamp(0, res[v] - 1),
        ])
    };

    // Frustum culling needs one common origin and the four corner rays.
    let origin = Vec3::new(
        rays[q0].org[0][i0],
        rays[q0].org[1][i0],
        rays[q0].org[2][i0],
    );
    let cull = opt.cgt.culling && common_origin(rays, live, origin);
    if opt.cgt.culling && !cull {
        ctr.packets_no_cull += 1;
    }
    let corners = corner_dirs(k, u, v, flip, info.cell_size, smin, smax);

    // The quads in groups of the lane width, with the triangle test's
    // per-ray precomputation.
    let (grp, mut slot) = group::join::<L, T>(rays, &mut slot);
    let mb = &mut slot.mailbox;
    if opt.cgt.mailbox {
        mb.next_packet(info.triangles as usize);
    }

    let m = info.macrocell as i32;
    let use_macro = opt.cgt.macrocells && m > 1;
    let mut s = s0;
    let mut macro_end = i32::MIN; // last slice of the macrocell slab already checked
    while s <= s1 {
        let kc = if flip { res[k] - 1 - s } else { s };
        if use_macro && s > macro_end {
            // Slices left in this macrocell slab along the travel direction.
            let mk = kc / m;
            let left = if flip {
                kc - mk * m
            } else {
                ((mk + 1) * m).min(res[k]) - 1 - kc
            };
            let end = (s + left).min(s1);
            macro_end = end;
            let (b0, b1) = (box_at(s), box_at(end));
            let b = F4::new(
                b0.x.min(b1.x),
                b0.y.max(b1.y),
                b0.z.min(b1.z),
                b0.w.max(b1.w),
            );
            let empty = match range(b) {
                None => true,
                Some(r) => {
                    let mut occupied = false;
                    'scan: for mv in r[2] / m..=r[3] / m {
                        for mu in r[0] / m..=r[1] / m {
                            let mut mc = [0i32; 3];
                            mc[k] = mk;
                            mc[u] = mu;
                            mc[v] = mv;
                            if g.macro_occupied(mc) {
                                occupied = true;
                                break 'scan;
                            }
                        }
                    }
                    !occupied
                }
            };
            if empty {
                count!(ctr.macro_skips += 1);
                s = end + 1;
                if !ANY && !still_live(live, hits, ok, rk, rays, end + 1) {
                    return;
                }
                continue;
            }
        }
        if let Some(r) = range(box_at(s)) {
            // The budget's tally of this slice: references in its cells,
            // triangles met first (mailbox) and quad tests run.
            let (mut refs, mut work, lanes) = (0u32, 0u32, nl);
            for cv in r[2]..=r[3] {
                for cu in r[0]..=r[1] {
                    let mut c = [0i32; 3];
                    c[k] = kc;
                    c[u] = cu;
                    c[v] = cv;
                    count!(ctr.cells += 1);
                    let cell = g.cell(g.cell_index(c));
                    refs += cell.len() as u32;
                    for &tri in cell {
                        let tri = tri as usize;
                        if opt.cgt.mailbox && !mb.first_visit(tri) {
                            count!(ctr.mailbox_skips += 1);
                            continue;
                        }
                        work += 1;
                        let tv = &g.tris[tri];
                        if cull && culled(tv, origin, &corners) {
                            count!(ctr.culled += 1);
                            continue;
                        }
                        let id = g.tri_ids[tri];
                        let prim = T::prim(g.store(), tri);
                        let mut left = false;
                        for (gi, gr) in grp.iter().enumerate() {
                            let sel = group::all::<L>(gi, nq);
                            let bits = group::lane_bits::<L>(gi, sel, |q| live[q]);
                            if bits == 0 {
                                continue;
                            }
                            left = true;
                            // The budget counts quad tests, at any width.
                            work += group::quads_in(bits);
                            count!(ctr.tri_tests += bits.count_ones() as u64);
                            let (h, hb) = group::test(gr, prim, bits, crate::geom::Cull::None);
                            group::each_hit(&h, hb, |k, hm, hit| {
                                let q = gi * L::G + k;
                                let ray = || group::quad_ray(&gr.r, k);
                                let take =
                                    group::take::<ANY>(&mut hits[q], hm, hit, id, &g.filter, ray);
                                if ANY {
                                    live[q] &= !take;
                                }
                            });
                        }
                        if !left {
                            return;
                        }
                    }
                }
            }
            if budget {
                let cells = ((r[1] - r[0] + 1) * (r[3] - r[2] + 1)) as f32;
                spent += work as f32 + fallback::CGT_CELL * cells;
                allowed += fallback::CGT_BUDGET
                    * per_lane
                    * lanes as f32
                    * (fallback::CGT_STEP + refs as f32 / cells);
                if spent > allowed {
                    return crate::accel::packet::alone::<GridView, T, ANY>(
                        g, rays, live, hits, ctr,
                    );
                }
            }
        }
        // Early termination: rays with a hit before the next slice plane
        // (or whose tmax ends before it) are done.
        if !ANY && !still_live(live, hits, ok, rk, rays, s + 1) {
            return;
        }
        if ANY && !live.iter().any(|m| m.any()) {
            return;
        }
        if budget {
            nl = live_lanes(live);
        }
        s += 1;
    }
}

/// Live lanes of a packet.
#[inline]
fn live_lanes(live: &[M4]) -> u32 {
    live.iter().map(|m| m.bitmask().count_ones()).sum()
}

/// After the slab ending at travel-frame plane `next`: drop lanes whose hit
/// lies strictly before the plane, or whose interval ends there. False when
/// no lane is left.
#[inline]
fn still_live(
    live: &mut [M4],
    hits: &[Hit4],
    ok: &[F4],
    rk: &[F4],
    rays: &[Ray4],
    next: i32,
) -> bool {
    let plane = F4::splat(next as f32);
    let mut any = false;
    for q in 0..live.len() {
        if !live[q].any() {
            continue;
        }
        let tp = (plane - ok[q]) * rk[q];
        let done = hits[q].t.cmplt(tp) | rays[q].tmax.cmple(tp);
        live[q] &= !done;
        any |= live[q].any();
    }
    any
}

fn first_lane(live: &[M4]) -> (usize, usize) {
    for (q, m) in live.iter().enumerate() {
        let b = m.bitmask();
        if b != 0 {
            return (q, b.trailing_zeros() as usize);
        }
    }
    (0, 0)
}

/// Whether every live lane starts at bitwise the same point.
fn common_origin(rays: &[Ray4], live: &[M4], o: Vec3) -> bool {
    rays.iter().zip(live).all(|(r, m)| {
        let same = r.org[0].cmpeq(F4::splat(o.x))
            & r.org[1].cmpeq(F4::splat(o.y))
            & r.org[2].cmpeq(F4::splat(o.z));
        (*m & !same).bitmask() == 0
    })
}

/// World-space directions of the four frustum corner rays (slope extremes,
/// already widened), as x, y, z lanes over the corners.
fn corner_dirs(
    k: usize,
    u: usize,
    v: usize,
    flip: bool,
    cell: Vec3,
    smin: [f32; 2],
    smax: [f32; 2],
) -> [F4; 3] {
    let mut d = [F4::ZERO; 3];
    d[k] = F4::splat(if flip { -cell[k] } else { cell[k] });
    d[u] = F4::new(smin[0], smax[0], smin[0], smax[0]) * F4::splat(cell[u]);
    d[v] = F4::new(smin[1], smin[1], smax[1], smax[1]) * F4::splat(cell[v]);
    d
}

/// Shaft culling (Dmitriev et al. 2004): the corner rays from `o` all miss
/// the triangle on the same edge, so every ray inside their cone does.
#[inline(always)]
fn culled(t: &TriVerts, o: Vec3, corners: &[F4; 3]) -> bool {
    let a = Vec3::from(t.v0) - o;
    let b = Vec3::from(t.v1) - o;
    let c = Vec3::from(t.v2) - o;
    let n = [a.cross(b), b.cross(c), c.cross(a)];
    // Inside the triangle all three edge functions share the sign of the
    // triple product; one edge with every corner beyond the other side
    // separates the cone from the triangle.
    // "Beyond" by a margin: an edge whose line passes within rounding of the
    // apex (a packet starting on the edge) has a plane normal of rounding
    // noise, of order eps |x| |y| for `x.cross(y)`, and the triangle tests
    // accept lines a few ulps outside an edge. `SLOPE_EPS` of |x| |y| |corner|
    // (max norms, times 3 for the Euclidean ones) covers both. Likewise the
    // triple product's sign is noise when the apex lies within rounding of
    // the triangle's plane (a packet starting on the triangle): its f32
    // error is of order eps (|a| |b| |c| + |n| (|a| + |o|)), n = a x b +
    // b x c + c x a the triangle's normal; then no culling.
    let inf = |p: Vec3| p.abs().max_element();
    let (la, lb, lc) = (inf(a), inf(b), inf(c));
    let sigma = a.dot(n[1]);
    let big = la.max(lb).max(lc) + inf(o);
    let noise = 64.0 * f32::EPSILON * (la * lb * lc + inf(n[0] + n[1] + n[2]) * big);
    if !(sigma.abs() > noise && sigma.is_finite()) {
        return false;
    }
    let cm = corners[0]
        .abs()
        .max(corners[1].abs())
        .max(corners[2].abs())
        .max_element();
    let m = 3.0 * SLOPE_EPS * cm;
    for (e, len) in n.iter().zip([la * lb, lb * lc, lc * la]) {
        let s =
            corners[0] * F4::splat(e.x) + corners[1] * F4::splat(e.y) + corners[2] * F4::splat(e.z);
        let margin = F4::splat(m * len);
        let out = if sigma > 0.0 {
            s.cmplt(-margin)
        } else {
            s.cmpgt(margin)
        };
        if out.all() {
            return true;
        }
    }
    false
}
