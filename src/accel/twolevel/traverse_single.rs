//! One ray through a two-level scene: the top level walked front to back
//! like the BVH paper's single ray (`bvh::traverse_single`), and at each
//! instance the ray mapped into the instance's space by its inverse and
//! traced through its geometry's BVH by the 4-wide single ray
//! (`bvh::traverse_wide`, the binary walk where there is no wide tree),
//! with the nearest hit so far as its `tmax` (Wald, Benthin, Slusallek
//! 2003, section 3).
//!
//! # Exactness
//! The object-space ray is `inverse.point(org)`, `inverse.vector(dir)`
//! with the world ray's `tmin`; its `tmax` is the nearest hit's t rounded
//! up by one ulp (so a hit at the same t in another instance is still
//! found and the tie rule, `closer`, decides), or the world ray's. A
//! box is skipped only when its entry lies strictly beyond the nearest
//! hit. Hits are ordered by (t, instance, triangle).
//!
//! # Deviations
//! - Counters count the top level's box tests and each geometry walk's.

use super::{RayControls, TwoLevelView};
use crate::accel::bvh::traverse_single::RayBox;
use crate::accel::bvh::{BvhNode, traverse_wide};
use crate::counters::Counters;
use crate::geom::TriangleTest;
use crate::geom::{Hit, INVALID_ID, Ray};

/// The nearest hit of a two-level scene: the triangle's id in its
/// geometry, the geometry and the instance (C: `sheaf_scene_hit`).
#[repr(C)]
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SceneHit {
    pub t: f32,
    pub u: f32,
    pub v: f32,
    /// The triangle's index in its geometry's index buffer
    /// (`INVALID_ID`: a miss).
    pub prim: u32,
    pub geometry: u32,
    pub instance: u32,
}

impl SceneHit {
    pub const MISS: SceneHit = SceneHit {
        t: f32::INFINITY,
        u: 0.0,
        v: 0.0,
        prim: INVALID_ID,
        geometry: INVALID_ID,
        instance: INVALID_ID,
    };
    /// An occluded ray whose occluder is not known (kd packets'
    /// occlusion through the flattened scene: `Hit::OCCLUDED`).
    pub const OCCLUDED: SceneHit = SceneHit {
        t: 0.0,
        u: 0.0,
        v: 0.0,
        prim: INVALID_ID - 1,
        geometry: INVALID_ID,
        instance: INVALID_ID,
    };
    #[inline]
    pub fn is_hit(&self) -> bool {
        self.prim != INVALID_ID
    }
    /// Geometry `geometry`'s hit `h` through instance `instance`.
    #[inline(always)]
    pub fn of(h: &Hit, geometry: u32, instance: u32) -> SceneHit {
        SceneHit {
            t: h.t,
            u: h.u,
            v: h.v,
            prim: h.prim,
            geometry,
            instance,
        }
    }
    /// Whether a hit at `t` on `(instance, prim)` comes before this one:
    /// nearer, or as near and of a smaller instance, then triangle.
    #[inline(always)]
    pub fn closer(&self, t: f32, instance: u32, prim: u32) -> bool {
        t < self.t || (t == self.t && (instance, prim) < (self.instance, self.prim))
    }
}

/// The ray as instance `inst` sees it, its `tmax` cut to just past `best`.
#[inline(always)]
pub(crate) fn object_ray(inv: &crate::geom::Affine, ray: &Ray, best: f32) -> Ray {
    let tmax = if best < ray.tmax {
        best.next_up()
    } else {
        ray.tmax
    };
    Ray {
        org: inv.point(ray.org),
        dir: inv.vector(ray.dir),
        tmin: ray.tmin,
        tmax,
    }
}

/// The nearest hit of `ray` among instances whose mask, and whose
/// geometry's, shares a bit with `ctl.mask`, without the triangle side
/// `ctl.cull` (a miss for invalid rays).
pub fn intersect<T: TriangleTest>(
    s: &TwoLevelView<'_>,
    ray: &Ray,
    ctl: RayControls,
    ctr: &mut Counters,
) -> SceneHit {
    walk::<T, false>(s, ray, ctl, ctr)
}

/// Whether anything blocks `ray` in `[tmin, tmax)` (instances as in
/// `intersect`).
pub fn occluded<T: TriangleTest>(
    s: &TwoLevelView<'_>,
    ray: &Ray,
    ctl: RayControls,
    ctr: &mut Counters,
) -> bool {
    any_hit::<T>(s, ray, ctl, ctr).is_hit()
}

/// Some hit of `ray` in `[tmin, tmax)` (the first found), or a miss.
pub fn any_hit<T: TriangleTest>(
    s: &TwoLevelView<'_>,
    ray: &Ray,
    ctl: RayControls,
    ctr: &mut Counters,
) -> SceneHit {
    walk::<T, true>(s, ray, ctl, ctr)
}

fn walk<T: TriangleTest, const ANY: bool>(
    s: &TwoLevelView<'_>,
    ray: &Ray,
    ctl: RayControls,
    ctr: &mut Counters,
) -> SceneHit {
    let mut best = SceneHit::MISS;
    if s.tlas.is_empty() || !ray.is_valid() {
        return best;
    }
    let rb = RayBox::new(ray);
    let neg = ray.dir.map(f32::is_sign_negative);
    let mut st_node = [0u32; super::build::MAX_TOP_DEPTH + 1];
    let mut st_t = [0.0f32; super::build::MAX_TOP_DEPTH + 1];
    let mut sp = 0usize;
    let nodes: &[BvhNode] = s.tlas;
    // The root: entered like any node.
    if rb.entry(&nodes[0], ray.tmax).is_none() {
        return best;
    }
    let mut node = 0usize;
    loop {
        let n = &nodes[node];
        if !n.is_leaf() {
            let l = n.first as usize;
            let (near, far) = if neg[n.axis()] {
                (l + 1, l)
            } else {
                (l, l + 1)
            };
            let tmax = if best.t < ray.tmax { best.t } else { ray.tmax };
            ctr.aabb_at(1, 2);
            // `entry` rejects boxes entered beyond `tmax`; an entry equal
            // to the nearest hit is kept (a tie may sit there).
            let tn = rb.entry(&nodes[near], tmax);
            let tf = rb.entry(&nodes[far], tmax);
            match (tn, tf) {
                (Some(_), Some(t)) => {
                    st_node[sp] = far as u32;
                    st_t[sp] = t;
                    sp += 1;
                    node = near;
                    continue;
                }
                (Some(_), None) => {
                    node = near;
                    continue;
                }
                (None, Some(_)) => {
                    node = far;
                    continue;
                }
                (None, None) => {}
            }
        } else {
            let id = s.order[n.first as usize];
            let inst = &s.insts[id as usize];
            if let Some(g) = s.visible(inst, id, ctl) {
                let r = object_ray(&inst.inverse, ray, best.t);
                let h: Hit = traverse_wide::walk::<T, ANY>(&g, &r, ctr);
                if h.is_hit() && best.closer(h.t, id, h.prim) {
                    best = SceneHit::of(&h, inst.geometry, id);
                    if ANY {
                        return best;
                    }
                }
            }
        }
        loop {
            if sp == 0 {
                return best;
            }
            sp -= 1;
            if st_t[sp] <= best.t {
                node = st_node[sp] as usize;
                break;
            }
        }
    }
}
