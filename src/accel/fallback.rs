//! Fallbacks for incoherent packets: where a packet's rays diverge (its
//! frustum gets wide), it falls back to Partition traversal, smaller
//! packets or its single rays, so that no packet method is more than 2x
//! slower than its structure's single-ray baseline.
//!
//! Packet methods pay per packet what single rays pay per ray: when the
//! rays of a packet go different ways, a packet visits the union of their
//! cells or nodes and tests every ray at each. Each traversal therefore
//! checks its packets and falls back where they are incoherent:
//!
//! - Grid, CGT (`accel::grid::traverse_cgt`): Wald et al. 2006, section 2.2,
//!   requires every ray to move the same way along the major axis (lanes
//!   that do not are traced by the 3DDDA) and section 4.7 splits shadow
//!   packets whose frustum gets wide. After those stray lanes, packets
//!   failing the coherence test below go lane by lane to the 3DDDA, and the
//!   others keep a budget: the work they do per slice against what the
//!   3DDDA would do for their live lanes (`CGT_BUDGET`). Once over it, the
//!   remaining live lanes are traced by the 3DDDA.
//! - BVH (`accel::bvh`): Overbeck et al. 2008, section 5.2.1: Masked and
//!   Ranged traversal lose when the quads after the first alive one are not
//!   truly alive; Partition traversal "is robust to degrading coherence".
//!   Masked traversal counts the quads it tests that are dead and switches
//!   to Partition for the rest of the packet once that share is too high
//!   (`MAX_DEAD_PER_ALIVE`; the same switch for Ranged traversal slowed
//!   coherent camera packets up to 2x and is left out); packets (and 2x2
//!   SIMD rays) of every method that fail the coherence test below are
//!   traced lane by lane with the single ray (what every method degrades
//!   to).
//! - kd-tree (`accel::kd`): Wald 2004 packets need one direction sign per
//!   axis; lanes with other signs already go alone. A packet (or 2x2 SIMD
//!   ray) whose remaining lanes fail the coherence test below goes alone
//!   lane by lane too.
//!
//! - Every packet method, and the 2x2 SIMD rays: lanes with tiny
//!   directions (`TINY_DIR`, valid but subnormal in the arithmetic, which
//!   x86 cores run hundreds of times slower) are traced alone, and the
//!   rest of the packet on quads where those lanes are replaced
//!   (`quieted`): masked lanes are computed all the same. For the n x n
//!   methods the trace call does this once per packet
//!   (`trace::scene::Tracing`, `accel::packet::quieted`); the 2x2
//!   SIMD rays do it quad by quad.
//!
//! Every fallback traces a lane with its structure's single-ray traversal
//! or with a packet traversal that is itself exact, so results stay the
//! single ray's triangle and bitwise t.
//!
//! # The coherence test
//! `coherent` reads the packet's live lanes once: the angle between each
//! direction and the first live lane's (a cone), and the box of the
//! origins against the scene's diagonal. A packet is incoherent when some
//! direction is more than `MAX_CONE_DEG` from the first, or the origins
//! spread over more than `MAX_ORIGIN_SPREAD` of the scene's diagonal.
//! Camera packets pass unless one spans more than 30 degrees of the view
//! (a 32 x 32 packet of a 256-pixel-wide image with a 45 degree field of
//! view spans about 8 degrees corner to corner), and so do shadow packets
//! traced from a point light to nearby hit points; uniformly random
//! directions, mixed signs and parallel rays scattered over the scene do
//! not. Section 2.1 of the CGT paper explains why the fallback is whole
//! lanes rather than smaller packets: split packets "quickly deteriorate
//! to single-ray traversal".
//!
//! # Switch
//! `TraceParams::fallbacks` (on by default) turns every fallback off for
//! one call, so benches and tests can compare (`sheaf bench --stress`,
//! cli/stress/tests/fallback.rs); the callers of `coherent`, `tiny` and `Waste` pass
//! it on. It is not part of the C ABI; the fallbacks are always on there.
//!
//! # Counters
//! With the `counters` feature, `stats` gives the packets that fell back
//! and the lanes traced singly by a fallback since the process started
//! (all threads; relaxed atomics, touched only by packets that fall back).
//! They live here, not in `Counters`, whose layout is the C ABI's.

use crate::geom::{F4, Lane, M4, Ray4};
// usize counters: every target with atomics has them (not all have 64-bit
// atomics); they are statistics, a wrap on 32-bit targets is harmless.
use core::sync::atomic::{AtomicUsize, Ordering};

/// Largest angle between a live direction and the first live lane's.
pub const MAX_CONE_DEG: f32 = 30.0;
/// `cos(MAX_CONE_DEG)` (checked against the degrees in a test).
const MIN_COS: f32 = 0.866_025_4;
/// Largest diagonal of the live origins' box, relative to the scene's.
pub const MAX_ORIGIN_SPREAD: f32 = 0.25;

static PACKETS: AtomicUsize = AtomicUsize::new(0);
static LANES: AtomicUsize = AtomicUsize::new(0);

/// What fell back since the process started (zeros without the `counters`
/// feature).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct FallbackStats {
    /// Packets (or quads, for the 2x2 SIMD ray) that fell back, wholly or
    /// for the rest of their traversal.
    pub packets: u64,
    /// Of their lanes, those traced singly by the fallback.
    pub lanes: u64,
}

pub fn stats() -> FallbackStats {
    FallbackStats {
        packets: PACKETS.load(Ordering::Relaxed) as u64,
        lanes: LANES.load(Ordering::Relaxed) as u64,
    }
}

/// Calls `alone(quad, lane)` for every lane set in `lanes` (quad by quad),
/// and records them as one packet that fell back: every fallback that
/// traces lanes alone goes through here. Returns how many lanes.
#[inline]
pub(crate) fn each_lane(lanes: &[M4], mut alone: impl FnMut(usize, usize)) -> u64 {
    let mut n = 0u64;
    for (q, m) in lanes.iter().enumerate() {
        for i in 0..4 {
            if m.test(i) {
                alone(q, i);
                n += 1;
            }
        }
    }
    if n > 0 {
        record(n);
    }
    n
}

/// Record one packet that fell back, `lanes` of whose lanes went alone.
#[inline(never)]
pub(crate) fn record(lanes: u64) {
    let _ = lanes;
    #[cfg(feature = "counters")]
    {
        PACKETS.fetch_add(1, Ordering::Relaxed);
        LANES.fetch_add(lanes as usize, Ordering::Relaxed);
    }
}

/// The coherence test (module docs): true when the live lanes of `rays`
/// are coherent enough to trace as a packet. `scene_diag`: the diagonal of
/// the structure's bounds. Lanes whose squared direction length is zero,
/// infinite or NaN in f32 (zero, tiny or huge directions) are left out of
/// the cone, and non-finite origins out of the box; they are still traced.
/// Always true with the fallbacks off (`on == false`).
pub fn coherent(on: bool, rays: &[Ray4], live: &[M4], scene_diag: f32) -> bool {
    if !on {
        return true;
    }
    let mut c = Coherence::new();
    for (r, m) in rays.iter().zip(live) {
        if !c.add(r, *m) {
            return false;
        }
    }
    c.close(scene_diag)
}

/// `coherent` quad by quad, inside a setup pass that reads the quads
/// anyway: `add` each quad's live lanes in order, then `close`.
pub(crate) struct Coherence {
    cone: Option<Cone<F4>>,
    wide: bool,
    lo: [F4; 3],
    hi: [F4; 3],
}

impl Coherence {
    pub(crate) fn new() -> Self {
        Coherence {
            cone: None,
            wide: false,
            lo: [F4::INFINITY; 3],
            hi: [F4::NEG_INFINITY; 3],
        }
    }

    /// Add the lanes `m` of quad `r`; false once a lane left the cone
    /// around the first usable direction (the quads before it had no
    /// usable direction, which the cone ignores, so finding it late
    /// changes nothing).
    #[inline(always)]
    pub(crate) fn add(&mut self, r: &Ray4, m: M4) -> bool {
        if !m.any() {
            return !self.wide;
        }
        if self.cone.is_none() {
            let lanes = (0..4).filter(|&i| m.test(i)).map(|i| lane_dir(r, i));
            self.cone = Cone::first(lanes);
        }
        if let Some(c) = &self.cone {
            self.wide |= c.leaves(&r.dir, m);
        }
        for a in 0..3 {
            let o = r.org[a];
            let ok = m & o.abs().cmplt(F4::INFINITY);
            self.lo[a] = F4::select(ok, self.lo[a].min(o), self.lo[a]);
            self.hi[a] = F4::select(ok, self.hi[a].max(o), self.hi[a]);
        }
        !self.wide
    }

    /// Whether the lanes added are coherent (`coherent`).
    pub(crate) fn close(&self, scene_diag: f32) -> bool {
        if self.wide {
            return false;
        }
        if self.cone.is_none() {
            return true;
        }
        let (lo, hi) = (&self.lo, &self.hi);
        let lo = glam::Vec3::new(
            lo[0].min_element(),
            lo[1].min_element(),
            lo[2].min_element(),
        );
        let hi = glam::Vec3::new(
            hi[0].max_element(),
            hi[1].max_element(),
            hi[2].max_element(),
        );
        origins_close(lo, hi, scene_diag)
    }
}

/// Lane `i`'s direction.
#[inline(always)]
fn lane_dir(r: &Ray4, i: usize) -> glam::Vec3 {
    glam::Vec3::new(r.dir[0][i], r.dir[1][i], r.dir[2][i])
}

/// The coherence test's cone (module docs) at any lane width: around the
/// first usable direction, `MAX_CONE_DEG` wide.
#[derive(Clone, Copy)]
pub(crate) struct Cone<L: Lane> {
    d0: [L; 3],
    min_cos2: L,
}

impl<L: Lane> Cone<L> {
    /// The cone around the first of `dirs` whose length is finite and not
    /// zero (`None` when none is: nothing to compare, the lanes pass).
    #[inline(always)]
    pub(crate) fn first(dirs: impl Iterator<Item = glam::Vec3>) -> Option<Self> {
        for d in dirs {
            let l = d.length();
            if l.is_finite() && l > 0.0 {
                let d0 = d / l;
                return Some(Cone {
                    d0: [L::splat(d0.x), L::splat(d0.y), L::splat(d0.z)],
                    min_cos2: L::splat(MIN_COS * MIN_COS),
                });
            }
        }
        None
    }

    /// Whether a lane of `live` points out of the cone: cos < MIN_COS
    /// <=> dot < MIN_COS |d| <=> dot < 0 or dot^2 < MIN_COS^2 |d|^2;
    /// NaN, zero and overflowing directions are ignored.
    #[inline(always)]
    pub(crate) fn leaves(&self, dir: &[L; 3], live: L::Mask) -> bool {
        let [dx, dy, dz] = *dir;
        let [x0, y0, z0] = self.d0;
        let len2 = dx * dx + dy * dy + dz * dz;
        let dot = dx * x0 + dy * y0 + dz * z0;
        let zero = L::splat(0.0);
        let usable = zero.lt(len2) & len2.lt(L::splat(f32::INFINITY));
        let out = dot.lt(zero) | (dot * dot).lt(self.min_cos2 * len2);
        L::any(out & usable & live)
    }
}

/// The coherence test's second half: whether the box `(lo, hi)` of the
/// live lanes' finite origins spans at most `MAX_ORIGIN_SPREAD` of the
/// scene's diagonal (true when there is no finite origin: `lo > hi`
/// makes the extent negative infinity or NaN).
#[inline(always)]
pub(crate) fn origins_close(lo: glam::Vec3, hi: glam::Vec3, scene_diag: f32) -> bool {
    let limit = MAX_ORIGIN_SPREAD * scene_diag;
    (hi - lo).length().partial_cmp(&limit) != Some(core::cmp::Ordering::Greater)
}

/// Directions whose largest component is below this are "tiny": they are
/// valid (`Ray::is_valid`), but the SIMD arithmetic of a quad holding one
/// runs into subnormal numbers (products of its components, or the
/// components themselves), which x86 cores compute hundreds of times
/// slower, for all four lanes and every step of the quad's traversal.
pub const TINY_DIR: f32 = 1e-18;

/// Lanes of `r` in `live` whose direction is tiny (`TINY_DIR`, not zero);
/// none with the fallbacks off (`on == false`). Packet methods trace these lanes
/// alone and the rest of the packet on quads with those lanes replaced
/// (`quieted`), so only the tiny rays pay for their subnormal arithmetic,
/// as they do as single rays.
#[inline(always)]
pub fn tiny(on: bool, r: &Ray4, live: M4) -> M4 {
    if !on {
        return M4::FALSE;
    }
    let m = r.dir[0].abs().max(r.dir[1].abs()).max(r.dir[2].abs());
    live & m.cmpgt(F4::ZERO) & m.cmplt(F4::splat(TINY_DIR))
}

/// `r` with the lanes of `quiet` replaced by another of its lanes (or, when
/// all four are, by an empty ray along +x): a quad whose tiny lanes went
/// alone keeps its other lanes' bits, and its SIMD arithmetic no longer
/// meets the tiny lanes' subnormal numbers (masked lanes are computed all
/// the same). The replaced lanes must not be live.
pub fn quieted(r: &Ray4, quiet: M4) -> Ray4 {
    let keep = (!quiet).bitmask();
    let donor = if keep != 0 {
        r.lane(keep.trailing_zeros() as usize)
    } else {
        crate::geom::Ray::new(glam::Vec3::ZERO, glam::Vec3::X, 0.0, 0.0)
    };
    let lanes = [0, 1, 2, 3].map(|i| if quiet.test(i) { donor } else { r.lane(i) });
    Ray4::from_rays(&lanes)
}

/// Split the quads of a packet with active lanes `active` for the
/// tiny-direction fallback (`tiny`, `quieted`) into the caller's slices
/// (slot scratch, at least `rays.len()` long): `quiet`, the quads with
/// their tiny lanes replaced; `rest`, the active lanes that are not tiny
/// (the packet traces these); `tiny`, the tiny lanes (each traced alone).
pub(crate) fn split_tiny(
    rays: &[Ray4],
    active: &[M4],
    quiet: &mut [Ray4],
    rest: &mut [M4],
    tiny_lanes: &mut [M4],
) {
    for (q, r) in rays.iter().enumerate() {
        let t = tiny(true, r, active[q]);
        tiny_lanes[q] = t;
        quiet[q] = quieted(r, t);
        rest[q] = active[q] & !t;
    }
}

/// Budget of a CGT packet (`accel::grid::traverse_cgt`), in units of one
/// triangle test: per slice, the packet's work (one per quad-triangle test,
/// one per triangle met first in the packet (the mailbox and culling
/// checks), `CGT_CELL` per cell of the overlap box) against what the 3DDDA
/// would do for the live lanes (each crossing `1 + |du| + |dv|` cells of
/// the slice, each cell `CGT_STEP` for the step plus the slice's mean
/// references per cell in tests). The packet goes on while its work so far
/// is at most `CGT_BUDGET` times the 3DDDA's. A SIMD quad test costs about
/// one single-ray test, so a packet at its budget runs at about the
/// 3DDDA's speed, and the work spent before falling back is at most what
/// the 3DDDA spends on those slices.
pub const CGT_BUDGET: f32 = 1.0;
/// Cost of a cell of the overlap box (index, reference range) in triangle
/// tests.
pub const CGT_CELL: f32 = 0.25;
/// Cost of a 3DDDA step in triangle tests.
pub const CGT_STEP: f32 = 0.5;

/// Masked traversal switches to Partition traversal once more than this
/// many of its box tests per test that finds a quad alive found it dead
/// (section 5.2.1; Masked traversal tests every quad at every leaf it
/// visits, and "is superseded by Ranged and Partition traversal").
pub const MAX_DEAD_PER_ALIVE: u32 = 2;

/// The tally behind `MAX_DEAD_PER_ALIVE` for one packet of `nq` quads: no
/// decision before `2 nq` tests.
pub(crate) struct Waste {
    alive: u32,
    dead: u32,
    min: u32,
    on: bool,
}

impl Waste {
    #[inline(always)]
    pub(crate) fn new(nq: usize, on: bool) -> Waste {
        Waste {
            alive: 0,
            dead: 0,
            min: 2 * nq as u32,
            on,
        }
    }
    /// One box test of a quad (`live`: it had live lanes, so it was tested).
    #[inline(always)]
    pub(crate) fn tested(&mut self, live: bool, alive: bool) {
        self.alive += (live & alive) as u32;
        self.dead += (live & !alive) as u32;
    }
    /// Whether to switch now.
    #[inline(always)]
    pub(crate) fn too_high(&self) -> bool {
        self.on && self.alive + self.dead >= self.min && self.dead > MAX_DEAD_PER_ALIVE * self.alive
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn split_tiny_fills_only_the_packet() {
        use crate::geom::Ray;
        use glam::Vec3;
        let ray = |d: Vec3| Ray::new(Vec3::ONE, d, 0.0, 1.0);
        let (big, small) = (Vec3::new(0.0, 0.0, -1.0), Vec3::new(1e-20, 0.0, 0.0));
        let rays = [
            Ray4::from_rays(&[ray(big), ray(small), ray(big), ray(small)]),
            Ray4::from_rays(&[ray(big); 4]),
        ];
        let active = [crate::geom::lane::mask_from_bits(0b0111), M4::TRUE];
        // One quad more than the packet: it must stay as it was.
        let mut quiet = [rays[1]; 3];
        let (mut rest, mut lanes) = ([M4::TRUE; 3], [M4::TRUE; 3]);
        split_tiny(&rays, &active, &mut quiet, &mut rest, &mut lanes);
        let bits = |m: [M4; 3]| m.map(|m| m.bitmask());
        // Lane 3 is tiny but inactive: it stays in the quad, off.
        assert_eq!(bits(lanes), [0b0010, 0, 0b1111]);
        assert_eq!(bits(rest), [0b0101, 0b1111, 0b1111]);
        assert_eq!(quiet[0].lane(1).dir, quiet[0].lane(0).dir);
        assert_eq!(quiet[0].lane(3).dir, small.to_array());
        assert_eq!(quiet[1].lane(2).dir, big.to_array());
        assert_eq!(quiet[2].lane(0).dir, rays[1].lane(0).dir);
    }

    #[test]
    fn min_cos_is_the_cone() {
        let c = libm::cosf(MAX_CONE_DEG.to_radians());
        assert!((c - MIN_COS).abs() < 1e-6, "{c}");
    }
}
