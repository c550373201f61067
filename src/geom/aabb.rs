//! Axis-aligned bounding boxes.

use glam::Vec3;

/// An axis-aligned box; `Aabb::EMPTY` has min > max and grows by union.
#[derive(Clone, Copy, Debug, PartialEq)]
#[repr(C)]
pub struct Aabb {
    pub min: Vec3,
    pub max: Vec3,
}

impl Aabb {
    pub const EMPTY: Aabb = Aabb {
        min: Vec3::splat(f32::INFINITY),
        max: Vec3::splat(f32::NEG_INFINITY),
    };

    #[inline]
    pub fn is_empty(&self) -> bool {
        !(self.min.x <= self.max.x && self.min.y <= self.max.y && self.min.z <= self.max.z)
    }
    #[inline]
    pub fn grow(&mut self, p: Vec3) {
        self.min = self.min.min(p);
        self.max = self.max.max(p);
    }
    #[inline]
    pub fn union(&self, o: &Aabb) -> Aabb {
        Aabb {
            min: self.min.min(o.min),
            max: self.max.max(o.max),
        }
    }
    #[inline]
    pub fn diagonal(&self) -> Vec3 {
        self.max - self.min
    }
    #[inline]
    pub fn contains(&self, p: Vec3) -> bool {
        p.cmpge(self.min).all() && p.cmple(self.max).all()
    }

    /// Parametric overlap `[t0, t1]` of the ray `o + t d` (inside `[tmin, tmax]`)
    /// with the box, or `None`. Exact for zero direction components: such an
    /// axis constrains nothing when the origin lies within the slab, and rejects
    /// the ray otherwise (no `0 * inf` NaNs).
    #[inline]
    pub fn clip_ray(
        &self,
        o: Vec3,
        d: Vec3,
        rcp: Vec3,
        tmin: f32,
        tmax: f32,
    ) -> Option<(f32, f32)> {
        let mut t0 = tmin;
        let mut t1 = tmax;
        for a in 0..3 {
            if d[a] == 0.0 {
                if o[a] < self.min[a] || o[a] > self.max[a] {
                    return None;
                }
                continue;
            }
            let ta = (self.min[a] - o[a]) * rcp[a];
            let tb = (self.max[a] - o[a]) * rcp[a];
            let (near, far) = if ta <= tb { (ta, tb) } else { (tb, ta) };
            if near > t0 {
                t0 = near;
            }
            if far < t1 {
                t1 = far;
            }
        }
        if t0 <= t1 { Some((t0, t1)) } else { None }
    }
}

impl Default for Aabb {
    fn default() -> Self {
        Aabb::EMPTY
    }
}
