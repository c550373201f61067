//! Any-hit filters: the caller's function asked about each candidate hit
//! before a traversal accepts it (an alpha-tested leaf, a fence, a grille),
//! as Embree's intersection and occlusion filter functions
//! (`rtcSetGeometryIntersectFilterFunction`) and DXR's and Vulkan's any-hit
//! shaders.
//!
//! A structure's view carries a [`Hook`]: empty (every candidate accepted,
//! one predictable branch on each candidate that is nearer than the best
//! so far) unless the call's geometry has a filter, is not opaque and the
//! call does not force opacity. A traversal asks the hook only about a
//! candidate it would take: nearer than its best so far by the tie rule
//! (`geom::closer`) for nearest hits, any hit for occlusion. A rejected
//! candidate changes nothing, so each method keeps the nearest accepted
//! candidate, or stops at the first accepted one.
//!
//! # Exactness
//! A filter that is a pure function of its [`Candidate`] makes every
//! method's answer its single ray's, bitwise: the candidate's fields are
//! bitwise the same whichever method finds it (the ray's origin and
//! direction as the structure sees them, the triangle test's t, u, v, the
//! caller's ids), the nearest accepted candidate under the tie rule is
//! unique, and a traversal prunes only by accepted hits. The candidate
//! carries no `tmin`/`tmax`: a traversal shortens its ray as it finds
//! hits, by an amount that depends on the order of its visits.
//!
//! # Deviations
//! A candidate may be asked about more than once (a triangle referenced by
//! several cells or leaves, a lane traced again by a fallback), lanes in
//! any order, from the threads of the call; the calls are not counted in
//! the stats.
#![forbid(unsafe_code)]

use crate::geom::lane::{F4, M4, mask_from_bits};
use crate::geom::ray::INVALID_ID;
use core::ffi::c_void;

/// A candidate hit, as a filter sees it (C: `sheaf_candidate`).
#[repr(C)]
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Candidate {
    /// The ray's origin and direction in the space of the triangles tested:
    /// an instance's object space for a two-level scene's BVH methods
    /// (t is the same parameter in both spaces), the world otherwise.
    pub org: [f32; 3],
    pub dir: [f32; 3],
    /// Ray parameter of the hit.
    pub t: f32,
    /// Barycentric weights of the triangle's second and third vertex.
    pub u: f32,
    pub v: f32,
    /// The triangle's index in its geometry's index buffer.
    pub prim: u32,
    /// The geometry's id (0 for a context's single mesh).
    pub geometry: u32,
    /// The instance's id (`INVALID_ID`, C `SHEAF_INVALID_ID`, for a
    /// single mesh).
    pub instance: u32,
}

/// A filter: true accepts the candidate, false rejects it (the traversal
/// goes on as if the triangle were not there for this ray). It must be a
/// pure function of its arguments, return, not unwind, and make no sheaf
/// call (refused with `Error::Reentrant` where `std` is on).
pub type FilterFn = extern "C" fn(user: *mut c_void, candidate: &Candidate) -> bool;

/// A filter function and the caller's pointer it is passed.
#[derive(Clone, Copy, Debug, Eq)]
pub struct Filter {
    pub func: FilterFn,
    /// The pointer as an address: kept, never read by sheaf.
    user: usize,
}

impl PartialEq for Filter {
    /// The same function (by address) and pointer.
    fn eq(&self, o: &Filter) -> bool {
        self.func as usize == o.func as usize && self.user == o.user
    }
}

impl Filter {
    pub fn new(func: FilterFn, user: *mut c_void) -> Filter {
        Filter {
            func,
            user: user as usize,
        }
    }
    pub fn user(&self) -> *mut c_void {
        self.user as *mut c_void
    }
    /// Ask the filter, marking the thread as inside one (`inside`).
    #[inline(never)]
    pub fn call(&self, c: &Candidate) -> bool {
        let _in = Inside::enter();
        (self.func)(self.user(), c)
    }
}

#[cfg(feature = "std")]
std::thread_local! {
    static DEPTH: core::cell::Cell<u32> = const { core::cell::Cell::new(0) };
}

/// Whether this thread is inside a filter call (always false without
/// `std`, which has no thread-local storage: the C ABI then cannot refuse
/// a call made from a filter).
pub fn inside() -> bool {
    #[cfg(feature = "std")]
    {
        DEPTH.with(|d| d.get() != 0)
    }
    #[cfg(not(feature = "std"))]
    {
        false
    }
}

/// The thread is inside a filter until this drops.
struct Inside;

impl Inside {
    fn enter() -> Inside {
        #[cfg(feature = "std")]
        DEPTH.with(|d| d.set(d.get() + 1));
        Inside
    }
}

impl Drop for Inside {
    fn drop(&mut self) {
        #[cfg(feature = "std")]
        DEPTH.with(|d| d.set(d.get() - 1));
    }
}

/// What a structure's triangles answer for their candidates: the
/// geometry's and instance's ids and filter of each stored triangle id.
pub trait Accept: Sync {
    /// Whether the hit at `(t, u, v)` on the stored triangle `prim` of the
    /// ray `(org, dir)` is accepted.
    fn accept(&self, org: [f32; 3], dir: [f32; 3], t: f32, u: f32, v: f32, prim: u32) -> bool;
}

/// One lane's ray (origin, direction) and hit (t, u, v).
pub type Lane = ([f32; 3], [f32; 3], (f32, f32, f32));

/// A structure's view's filter hook: none (every candidate accepted), one
/// geometry's filter (a single mesh, an instance), or a map from stored
/// triangle ids to geometries (a flattened two-level scene).
#[derive(Clone, Copy, Default)]
pub enum Hook<'r> {
    #[default]
    None,
    One(OneFilter),
    Map(&'r dyn Accept),
}

impl core::fmt::Debug for Hook<'_> {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.write_str(match self {
            Hook::None => "Hook::None",
            Hook::One(_) => "Hook::One",
            Hook::Map(_) => "Hook::Map",
        })
    }
}

impl Hook<'_> {
    /// Whether a filter is asked.
    #[inline(always)]
    pub fn on(&self) -> bool {
        !matches!(self, Hook::None)
    }
    /// Out of line and cold, as `bits_on` and `quad`: the walks' hot loops
    /// keep only the test of `on` (inlined, unfiltered conference camera
    /// packets lost 2.7 %; out of line, within noise: docs/studies/filters.md).
    #[cold]
    #[inline(never)]
    fn accept(&self, org: [f32; 3], dir: [f32; 3], t: f32, u: f32, v: f32, prim: u32) -> bool {
        match self {
            Hook::None => true,
            Hook::One(f) => f.accept(org, dir, t, u, v, prim),
            Hook::Map(a) => a.accept(org, dir, t, u, v, prim),
        }
    }
    /// Whether one ray's candidate is accepted.
    #[inline(always)]
    pub fn accepts(&self, org: [f32; 3], dir: [f32; 3], t: f32, u: f32, v: f32, prim: u32) -> bool {
        !self.on() || self.accept(org, dir, t, u, v, prim)
    }
    /// The lanes of `m` (a quad whose rays `ray()` reads, only when a
    /// filter is asked) hitting `prim` at `(t, u, v)` that are accepted.
    #[inline(always)]
    pub fn quad_with(
        &self,
        m: M4,
        hit: (F4, F4, F4),
        prim: u32,
        ray: impl Fn() -> ([F4; 3], [F4; 3]),
    ) -> M4 {
        if self.on() && m.any() {
            let (org, dir) = ray();
            quad(self, &org, &dir, m, hit, prim)
        } else {
            m
        }
    }
    /// `quad_with` on the lanes `bits` (bit `4k + i`: lane `i` of quad `k`) of
    /// a wide group, each lane's ray and hit read by `lane(k, i)`.
    #[inline(always)]
    pub fn bits(&self, bits: u32, prim: u32, lane: impl Fn(usize, usize) -> Lane) -> u32 {
        if self.on() {
            self.bits_on(bits, prim, &lane)
        } else {
            bits
        }
    }
    #[cold]
    #[inline(never)]
    fn bits_on(&self, bits: u32, prim: u32, lane: &dyn Fn(usize, usize) -> Lane) -> u32 {
        let mut out = bits;
        let mut m = bits;
        while m != 0 {
            let b = m.trailing_zeros() as usize;
            m &= m - 1;
            let (org, dir, (t, u, v)) = lane(b / 4, b % 4);
            if !self.accept(org, dir, t, u, v, prim) {
                out &= !(1 << b);
            }
        }
        out
    }
}

#[cold]
#[inline(never)]
fn quad(a: &Hook<'_>, org: &[F4; 3], dir: &[F4; 3], m: M4, hit: (F4, F4, F4), prim: u32) -> M4 {
    let mut out = m.bitmask();
    let mut left = out;
    while left != 0 {
        let i = left.trailing_zeros() as usize;
        left &= left - 1;
        let o = [org[0][i], org[1][i], org[2][i]];
        let d = [dir[0][i], dir[1][i], dir[2][i]];
        if !a.accept(o, d, hit.0[i], hit.1[i], hit.2[i], prim) {
            out &= !(1 << i);
        }
    }
    mask_from_bits(out)
}

/// One geometry's filter under its ids: a single mesh's (geometry 0, no
/// instance) or an instance's.
#[derive(Clone, Copy, Debug)]
pub struct OneFilter {
    pub filter: Filter,
    pub geometry: u32,
    pub instance: u32,
}

impl OneFilter {
    /// A context's single mesh.
    pub fn mesh(filter: Filter) -> OneFilter {
        OneFilter {
            filter,
            geometry: 0,
            instance: INVALID_ID,
        }
    }
}

impl Accept for OneFilter {
    fn accept(&self, org: [f32; 3], dir: [f32; 3], t: f32, u: f32, v: f32, prim: u32) -> bool {
        self.filter.call(&Candidate {
            org,
            dir,
            t,
            u,
            v,
            prim,
            geometry: self.geometry,
            instance: self.instance,
        })
    }
}

// Filter holds a function pointer and an address: Send and Sync as data.
const _: () = {
    const fn sync<T: Sync + Send>() {}
    sync::<Filter>();
    sync::<OneFilter>();
};

#[cfg(test)]
mod tests {
    use super::*;

    extern "C" fn odd_prims(_: *mut c_void, c: &Candidate) -> bool {
        assert!(inside());
        c.prim % 2 == 1
    }

    #[test]
    fn hooks_ask_the_filter_per_lane() {
        let h = Hook::One(OneFilter::mesh(Filter::new(
            odd_prims,
            core::ptr::null_mut(),
        )));
        assert!(!inside());
        assert!(h.accepts([0.0; 3], [1.0; 3], 1.0, 0.0, 0.0, 3));
        assert!(!h.accepts([0.0; 3], [1.0; 3], 1.0, 0.0, 0.0, 2));
        assert!(!inside());
        let z = [F4::ZERO; 3];
        let hit = (F4::ONE, F4::ZERO, F4::ZERO);
        let m = M4::new(true, false, true, true);
        let ray = || (z, z);
        assert_eq!(h.quad_with(m, hit, 4, ray).bitmask(), 0);
        assert_eq!(h.quad_with(m, hit, 5, ray).bitmask(), m.bitmask());
        assert_eq!(Hook::None.quad_with(m, hit, 4, ray).bitmask(), m.bitmask());
        let lane = |_: usize, _: usize| ([0.0; 3], [1.0; 3], (1.0, 0.0, 0.0));
        assert_eq!(h.bits(0b1011_0001, 2, lane), 0);
        assert_eq!(h.bits(0b1011_0001, 7, lane), 0b1011_0001);
    }
}
