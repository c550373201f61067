//! The two-level scene flattened into world-space triangles, for the
//! families that rebuild everything per frame: the uniform grid, the
//! kd-tree and the perspective/light grids build over it as over one mesh
//! (the coherent grid paper, Wald et al. 2006, section 5: rebuild the
//! whole scene every frame; its instances are expanded, not entered).
//!
//! Every instance a mask sees (its mask and its geometry's both share a
//! bit with it, as `TwoLevelView::visible`) contributes its geometry's
//! stored triangles, each vertex mapped by the instance's transform
//! (`Affine::point`, f32), in instance-id order and, within an instance,
//! in its BVH's leaf order. Each world triangle keeps its instance and its
//! caller triangle id, so hits map back to (geometry, instance, triangle).
//!
//! # Exactness
//! The world triangles are a plain mesh, so every family's packets equal
//! its own single ray on them, bitwise, as on any mesh. Against the
//! two-level BVH (which maps the ray into object space instead) they
//! differ by the rounding of the mapped vertices: `tests/exact/twolevel_exact.rs`
//! compares both with the f64 oracle on the flattened scene and counts
//! that difference under its own tolerance.
//!
//! # Deviations
//! - The world triangles are the stored (traceable) ones: a triangle the
//!   geometry's build excluded (non-finite, zero area) is not expanded,
//!   and one the transform makes degenerate is excluded by the family's
//!   build, as any mesh's.
//! - The expansion costs 56 bytes per triangle of `Limits::max_triangles`
//!   (vertices, an identity index buffer, ids), carved only for contexts
//!   with a two-level scene and a grid, kd-tree or perspective grid.

use super::TwoLevelView;
use crate::error::{Error, Pool, Result};
use crate::geom::{Scene, TriVerts};
use crate::mem::par::{self, Par, Parts};

/// A flattened triangle's origin: its instance and its geometry's caller
/// triangle id.
pub type FlatId = [u32; 2];

/// The flattened scene's pools (carved once).
pub struct FlatPools<'a> {
    /// World triangles, three vertices each.
    pub tris: &'a mut [TriVerts],
    /// `0..3 * tris.len()`, written once: the index buffer of a
    /// non-indexed mesh.
    pub indices: &'a mut [u32],
    pub ids: &'a mut [FlatId],
}

impl<'a> FlatPools<'a> {
    /// The flattened scene's pools under `l`: `max_triangles` world
    /// triangles when there is a two-level scene and a structure that
    /// traces it flattened (the grid, the kd-tree, the perspective grids),
    /// else none.
    #[deny(clippy::arithmetic_side_effects)]
    pub fn carve(a: &mut impl crate::mem::Carve<'a>, l: &crate::mem::Limits) -> Result<Self> {
        use crate::mem::{Limits, TOO_BIG, when};
        let on = l.max_geometries > 0 && l.has(Limits::GRID | Limits::KD | Limits::PGRID);
        let n = when(on, l.max_triangles as usize);
        Ok(FlatPools {
            tris: a.take(n)?,
            indices: a.take(n.checked_mul(3).ok_or(TOO_BIG)?)?,
            ids: a.take(n)?,
        })
    }
}

/// What the last flattening wrote.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct FlatInfo {
    /// World triangles and the instances they came from.
    pub triangles: u32,
    pub instances: u32,
    /// The mask the instances were chosen by.
    pub mask: u32,
}

/// The flattened scene: pools and what the last flattening wrote.
pub struct Flat<'a> {
    pools: FlatPools<'a>,
    info: Option<FlatInfo>,
}

impl<'a> Flat<'a> {
    pub fn new(p: FlatPools<'a>) -> Self {
        for (i, x) in p.indices.iter_mut().enumerate() {
            *x = i as u32;
        }
        Flat {
            pools: p,
            info: None,
        }
    }

    /// No pools (a placeholder while the pools are lent out).
    pub fn empty() -> Flat<'a> {
        Flat {
            pools: FlatPools {
                tris: &mut [],
                indices: &mut [],
                ids: &mut [],
            },
            info: None,
        }
    }

    /// Capacity in world triangles (0: not carved).
    pub fn capacity(&self) -> usize {
        self.pools.tris.len().min(self.pools.indices.len() / 3)
    }

    pub fn info(&self) -> Option<FlatInfo> {
        self.info
    }

    /// Expand every instance of `v` that `mask` sees, on `par`'s workers
    /// (the same triangles, in the same order, for any worker count). On
    /// error (`Capacity(Triangles)`: more world triangles than the pools
    /// hold) nothing is written and the previous flattening stays.
    pub fn flatten(&mut self, v: &TwoLevelView<'_>, mask: u32, par: &dyn Par) -> Result<FlatInfo> {
        let workers = par::workers_of(par)?;
        let (mut total, mut instances) = (0u64, 0u32);
        for id in 0..v.instance_slots() {
            if let Some(g) = v.instance(id).and_then(|i| v.visible(i, id, mask.into())) {
                total += g.info.triangles as u64;
                instances += 1;
            }
        }
        if total > self.capacity() as u64 {
            return Err(Error::Capacity {
                pool: Pool::Triangles,
                needed: total,
                available: self.capacity() as u64,
            });
        }
        let n = total as usize;
        self.info = None;
        // Both cut alike: the same length, even parts.
        let tris = Parts::even(&mut self.pools.tris[..n], workers);
        let ids = Parts::even(&mut self.pools.ids[..n], workers);
        par.run(&|w| {
            let (out, out_ids) = (tris.get(w), ids.get(w));
            expand(v, mask, tris.start(w), out, out_ids);
        });
        let info = FlatInfo {
            triangles: n as u32,
            instances,
            mask,
        };
        self.info = Some(info);
        Ok(info)
    }

    /// The last flattening as a mesh (`None` before one).
    pub fn scene(&self) -> Option<Scene<'_>> {
        let n = self.info?.triangles as usize;
        // The identity index buffer is valid by construction: no scan of
        // its 3n indices per build.
        Some(Scene::trusted(
            bytemuck::cast_slice(&self.pools.tris[..n]),
            3 * n as u32,
            &self.pools.indices[..3 * n],
        ))
    }

    /// Instance and caller triangle id of world triangle `prim` of the
    /// last flattening.
    pub fn id(&self, prim: u32) -> Option<FlatId> {
        let n = self.info?.triangles;
        (prim < n).then(|| self.pools.ids[prim as usize])
    }
}

/// World triangles `from..from + out.len()` of the flattening of `v` by
/// `mask` into `out` and `ids`.
fn expand(v: &TwoLevelView<'_>, mask: u32, from: usize, out: &mut [TriVerts], ids: &mut [FlatId]) {
    let end = from + out.len();
    let mut at = 0usize;
    for id in 0..v.instance_slots() {
        if at >= end {
            break;
        }
        let Some(inst) = v.instance(id) else { continue };
        let Some(g) = v.visible(inst, id, mask.into()) else {
            continue;
        };
        let count = g.info.triangles as usize;
        let m = &inst.transform;
        for k in from.max(at)..end.min(at + count) {
            let t = &g.tris[k - at];
            out[k - from] = TriVerts {
                v0: m.point(t.v0),
                v1: m.point(t.v1),
                v2: m.point(t.v2),
            };
            ids[k - from] = [id, g.tri_ids[k - at]];
        }
        at += count;
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::accel::twolevel::GeometryParams;
    use crate::accel::twolevel::testkit::Store;
    use crate::geom::Affine;
    use crate::mem::par::Serial;

    #[test]
    fn flattening_maps_every_visible_instance_for_any_worker_count() {
        let mesh = crate::scenes::builtin("gears").unwrap().mesh;
        let scene = Scene::from_f32(&mesh.vertices, &mesh.indices).unwrap();
        let n = scene.triangle_count() as usize;
        let mut store = Store::new(2 * n, 2, 4, false);
        let mut s = store.scene();
        s.set_geometry(0, &scene, &GeometryParams::default(), &Serial)
            .unwrap();
        let moved = Affine::rotated(30.0, 1, [2.0, 1.0, 0.5], [3.0, 0.0, -1.0]);
        s.set_instance(0, 0, &Affine::IDENTITY, 1).unwrap();
        s.set_instance(2, 0, &moved, 2).unwrap();
        s.set_instance(3, 0, &moved, 4).unwrap();
        s.commit();
        let v = s.view().unwrap();
        let cap = 3 * n;
        let (mut tris, mut idx, mut ids) = (
            vec![TriVerts::default(); cap],
            vec![0u32; 3 * cap],
            vec![[0u32; 2]; cap],
        );
        let mut f = Flat::new(FlatPools {
            tris: &mut tris,
            indices: &mut idx,
            ids: &mut ids,
        });
        let info = f.flatten(&v, 3, &Serial).unwrap();
        let stored = v.geometry(0).unwrap().info.triangles;
        assert_eq!((info.triangles, info.instances), (2 * stored, 2));
        let one: Vec<TriVerts> = (0..info.triangles).map(|i| tri(&f, i)).collect();
        // Instance 0 is the identity: its triangles are the caller's.
        for p in 0..stored {
            let [inst, prim] = f.id(p).unwrap();
            assert_eq!(inst, 0);
            assert_eq!(tri(&f, p), scene.triangle(prim));
        }
        // Instance 2 follows, mapped; instance 3's mask is not seen.
        let [inst, prim] = f.id(stored).unwrap();
        assert_eq!(inst, 2);
        assert_eq!(tri(&f, stored).v1, moved.point(scene.triangle(prim).v1));
        assert_eq!(f.id(2 * stored), None);
        // Three workers (run in reverse) write the same triangles.
        f.flatten(&v, 3, &crate::accel::testkit::Backwards(3))
            .unwrap();
        assert!((0..info.triangles).all(|i| tri(&f, i) == one[i as usize]));
        // Too many triangles: refused, the last flattening kept.
        let mut small = Flat::new(FlatPools {
            tris: &mut tris[..n],
            indices: &mut idx[..3 * n],
            ids: &mut ids[..n],
        });
        let one = small.flatten(&v, 1, &Serial).unwrap();
        assert!(matches!(
            small.flatten(&v, !0, &Serial),
            Err(Error::Capacity { .. })
        ));
        assert_eq!(small.info(), Some(one));
    }

    fn tri(f: &Flat<'_>, i: u32) -> TriVerts {
        f.scene().unwrap().triangle(i)
    }
}
