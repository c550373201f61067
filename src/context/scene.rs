//! The context's two-level scene (`accel::twolevel`): geometries set,
//! updated and removed between frames, instances placing them, a commit
//! that builds the top level, and rays traced through it. Its pools are
//! carved with the context's when `Limits::max_geometries` is not 0.
//!
//! The grid, the kd-tree and the perspective grids trace the same scene
//! flattened into world triangles (`twolevel::flatten`), rebuilt from a
//! commit with `build_*_scene`; `Sources` remembers which commit and mask
//! each was built from, so a trace never maps a hit through the ids of
//! another flattening.

use super::Context;
use crate::accel::bvh::{BvhInfo, BvhView};
use crate::accel::grid::{GridInfo, GridParams};
use crate::accel::kd::{KdInfo, KdParams};
use crate::accel::method::Structure;
use crate::accel::pgrid::{PgridParams, SceneInfo};
use crate::accel::slot::Slot;
use crate::accel::twolevel::RayControls;
use crate::accel::twolevel::TwoLevel;
use crate::accel::twolevel::flatten::{Flat, FlatInfo};
use crate::accel::twolevel::traverse_packet::{self, SceneCall};
use crate::accel::twolevel::traverse_single::{self, SceneHit};
use crate::accel::twolevel::{GeometryParams, TwoLevelInfo, TwoLevelView, UpdateInfo};
use crate::counters::{Counters, elapsed_ns, now};
use crate::error::{Error, Result};
use crate::geom::{
    Accept, Affine, Candidate, Cull, Filter, Hook, M4, OneFilter, Ray, Ray4, Scene, with_test,
};
use crate::mem::Limits;
use crate::mem::par::{Par, Serial};
use crate::render::{CameraRays, PixelRect, PrimaryRays};
use crate::trace::scene::{Batch, Tracing, packet_rays, packets};
use crate::trace::{DynRays, RaySource, RayStream, SceneHitStream, TraceParams};

/// The two-level scene and its flattening into world triangles: one field
/// of the context, so the structures built over the flattening can ask
/// its geometries' filters (`Accept`) while a deferred frame lends the
/// context's other fields out.
pub(super) struct World<'a> {
    pub scene: TwoLevel<'a>,
    pub flat: Flat<'a>,
}

impl World<'_> {
    /// Whether a committed geometry has a filter (its candidates on the
    /// flattened scene go to `accept`).
    fn filtering(&self) -> bool {
        self.scene.filtering()
    }
}

/// Candidates on world triangles go to their geometry's filter, with its
/// own triangle id and the instance's, and the world ray.
impl Accept for World<'_> {
    fn accept(&self, org: [f32; 3], dir: [f32; 3], t: f32, u: f32, v: f32, prim: u32) -> bool {
        let Some([instance, prim]) = self.flat.id(prim) else {
            return true;
        };
        self.scene
            .instance_filter(instance)
            .is_none_or(|(f, geometry)| {
                f.call(&Candidate {
                    org,
                    dir,
                    t,
                    u,
                    v,
                    prim,
                    geometry,
                    instance,
                })
            })
    }
}

/// Who decides on the candidates of structure `s` (`Limits::GRID`, `BVH`,
/// `KD`, `PGRID`): the single mesh's filter when `s` was built from the
/// mesh, the scene geometries' when it answers for the current
/// flattening, nobody when it was built from an older one.
pub(super) fn hook<'r>(
    sources: &Sources,
    s: u32,
    mesh: Option<Filter>,
    world: &'r World<'_>,
) -> Hook<'r> {
    match Sources::slot(s).and_then(|i| sources.built[i]) {
        None => mesh.map_or(Hook::None, |f| Hook::One(OneFilter::mesh(f))),
        Some(_) if sources.current(s).is_ok() && world.filtering() => Hook::Map(world),
        Some(_) => Hook::None,
    }
}

/// Slot scratch a two-level packet batch of up to `q` quads holds (its
/// quads, their lanes, their hits) with the top level's
/// (`traverse_packet::scratch`), under which the geometries' packet
/// traversals run.
pub(super) const fn scratch(q: usize) -> usize {
    use crate::mem::scratch::bytes;
    bytes::<Ray4>(q) + bytes::<M4>(q) + bytes::<SceneHit>(4 * q) + traverse_packet::scratch(q)
}

/// What a scene trace asks, as `Context::trace_scene_each` takes it: the
/// method `p` (None: single rays) on thread slot `slot`, the rays'
/// controls, and whether any hit will do (occlusion).
#[derive(Clone, Copy)]
struct SceneQuery<'p> {
    p: Option<&'p TraceParams>,
    slot: Option<u32>,
    ctl: RayControls,
    any: bool,
}

/// A flattening's origin: the commit (counted by `Sources::commits`) and
/// the mask it expanded.
type Key = (u64, u32);

/// Which commit of the two-level scene the flattened triangles and each
/// structure built over them come from (`None`: not built from the scene).
#[derive(Clone, Copy, Debug, Default)]
pub(super) struct Sources {
    commits: u64,
    flat: Option<Key>,
    /// The grid's, the kd-tree's and the perspective grids' (`slot`).
    built: [Option<Key>; 3],
}

impl Sources {
    /// Where structure `s` (`Limits::GRID`, `KD` or `PGRID`) keeps its
    /// origin (`None`: `s` is none of them).
    fn slot(s: u32) -> Option<usize> {
        match s {
            Limits::GRID => Some(0),
            Limits::KD => Some(1),
            Limits::PGRID => Some(2),
            _ => None,
        }
    }

    /// Structure `s` rebuilt from a mesh (or from the flattening `key`).
    pub(super) fn set(&mut self, s: u32, key: Option<Key>) {
        if let Some(i) = Self::slot(s) {
            self.built[i] = key;
        }
    }

    /// The flattening structure `s` answers for: built from it, still in
    /// the pools, of the current commit (`Err(NotBuilt)` else,
    /// `InvalidArgument` when `s` is not a flattened structure).
    fn current(&self, s: u32) -> Result<Key> {
        let i = Self::slot(s).ok_or(Error::InvalidArgument(
            "structure: Limits::GRID, KD or PGRID (built over the scene)",
        ))?;
        match self.built[i] {
            Some(k) if Some(k) == self.flat && k.0 == self.commits => Ok(k),
            _ => Err(Error::NotBuilt),
        }
    }
}

impl<'a> Context<'a> {
    /// The flattened triangles of the current commit for `mask`,
    /// flattened now unless they are already. On error the pools and
    /// `sources.flat` are unchanged (`Flat::flatten` writes nothing then).
    fn flat_for(&mut self, mask: u32, par: &dyn Par) -> Result<Key> {
        self.scene_pools()?;
        if self.world.flat.capacity() == 0 {
            return Err(Error::InvalidArgument(
                "no flattened scene: Limits::structures lacks GRID, KD and PGRID",
            ));
        }
        let key = (self.sources.commits, mask);
        if self.sources.flat != Some(key) {
            let v = self.world.scene.view()?;
            self.world.flat.flatten(&v, mask, par)?;
            self.sources.flat = Some(key);
        }
        Ok(key)
    }

    /// Structure `s` built by `build` over the current commit flattened
    /// for `mask`. On success `s` answers for that flattening. On error
    /// the builders keep `s` as it was (so its origin stays), and the
    /// flattening the other structures were built from is put back when
    /// it was replaced, so a failed build changes nothing they answer.
    fn build_over_scene<R>(
        &mut self,
        s: u32,
        mask: u32,
        par: &dyn Par,
        build: impl FnOnce(&mut Self, &Scene<'_>) -> Result<R>,
    ) -> Result<R> {
        let prev = self.sources.flat;
        let key = self.flat_for(mask, par)?;
        match self.over_flat(build) {
            Ok(r) => {
                self.sources.set(s, Some(key));
                Ok(r)
            }
            Err(e) => {
                if let Some(p) = prev.filter(|p| p.0 == self.sources.commits && *p != key) {
                    // Fits: it did before, and nothing changed since.
                    let _ = self.flat_for(p.1, par);
                }
                Err(e)
            }
        }
    }

    /// `f` with the flattened scene as a mesh, the pools lent out for the
    /// call (a structure's build borrows the context mutably).
    fn over_flat<R>(&mut self, f: impl FnOnce(&mut Self, &Scene<'_>) -> Result<R>) -> Result<R> {
        let flat = core::mem::replace(&mut self.world.flat, Flat::empty());
        let r = match flat.scene() {
            Some(scene) => f(self, &scene),
            None => Err(Error::NotBuilt),
        };
        self.world.flat = flat;
        r
    }

    /// Rebuild the grid over the committed scene's instances that `mask`
    /// sees, flattened into world triangles (the grid paper's
    /// rebuild-everything model). `trace_scene_with` then traces it with
    /// the grid's methods for that `mask`. The structures built over the
    /// scene share one flattening: building one for another mask (or
    /// after a new commit) flattens again, and the others answer
    /// `NotBuilt` until they are rebuilt for it. On error nothing they
    /// answer changes (`build_over_scene`).
    pub fn build_grid_scene(&mut self, params: &GridParams, mask: u32) -> Result<GridInfo> {
        self.build_grid_scene_with(params, mask, &Serial)
    }

    /// `build_grid_scene` on the caller's workers (the flattening and
    /// the grid build join them).
    pub fn build_grid_scene_with(
        &mut self,
        params: &GridParams,
        mask: u32,
        par: &dyn Par,
    ) -> Result<GridInfo> {
        self.build_over_scene(Limits::GRID, mask, par, |c, s| c.grid_over(s, params, par))
    }

    /// Rebuild the kd-tree over the committed scene's instances that
    /// `mask` sees (as `build_grid_scene`).
    pub fn build_kd_scene(&mut self, params: &KdParams, mask: u32) -> Result<KdInfo> {
        self.build_kd_scene_with(params, mask, &Serial)
    }

    /// `build_kd_scene` with the flattening and the kd-tree's build on the
    /// caller's workers (`build_kd_with`).
    pub fn build_kd_scene_with(
        &mut self,
        params: &KdParams,
        mask: u32,
        par: &dyn Par,
    ) -> Result<KdInfo> {
        self.build_over_scene(Limits::KD, mask, par, |c, s| c.kd_over(s, params, par))
    }

    /// Load the committed scene's instances that `mask` sees for the
    /// perspective and light grids (as `build_grid_scene`); a deferred
    /// frame's hits are then world triangles of the flattened scene, which
    /// `scene_prim` maps to (geometry, instance, triangle).
    pub fn build_pgrid_scene(&mut self, params: &PgridParams, mask: u32) -> Result<SceneInfo> {
        self.build_pgrid_scene_with(params, mask, &Serial)
    }

    /// `build_pgrid_scene` with the flattening on the caller's workers.
    pub fn build_pgrid_scene_with(
        &mut self,
        params: &PgridParams,
        mask: u32,
        par: &dyn Par,
    ) -> Result<SceneInfo> {
        self.build_over_scene(Limits::PGRID, mask, par, |c, s| c.pgrid_over(s, params))
    }

    /// The current commit's flattened scene as a mesh, with what it
    /// holds (`None` before a `build_*_scene` of this commit): for oracles
    /// and shading.
    pub fn flat_scene(&self) -> Option<(Scene<'_>, FlatInfo)> {
        self.sources
            .flat
            .filter(|k| k.0 == self.sources.commits && self.world.scene.view().is_ok())?;
        Some((self.world.flat.scene()?, self.world.flat.info()?))
    }

    /// Hit `h` of structure `structure` (`Limits::GRID`, `KD` or `PGRID`:
    /// a deferred frame's pixel) built by `build_*_scene`, as a scene hit:
    /// `h` with its geometry, instance and the geometry's own triangle id.
    /// A miss is `SceneHit::MISS`, a kd packet's occlusion marker
    /// `SceneHit::OCCLUDED`. Errors: `NotBuilt` when `structure` does not
    /// answer for the current commit's flattening (not built from it,
    /// built before a change or a commit, or another mask's flattening
    /// replaced it), `InvalidArgument` for another `structure` or when
    /// `h.prim` is not one of its triangles.
    pub fn scene_prim(&self, structure: u32, h: &crate::geom::Hit) -> Result<SceneHit> {
        let v = self.scene_view()?;
        self.sources.current(structure)?;
        self.flat_hit(&v, h).ok_or(Error::InvalidArgument(
            "not a triangle of the flattened scene",
        ))
    }

    /// Hit `h` on the flattened scene as a scene hit: a miss a miss, kd
    /// packets' occlusion marker (no occluder id) `SceneHit::OCCLUDED`,
    /// a world triangle its (geometry, instance, triangle); `None` for
    /// anything else.
    fn flat_hit(&self, v: &TwoLevelView<'_>, h: &crate::geom::Hit) -> Option<SceneHit> {
        if !h.is_hit() {
            return Some(SceneHit::MISS);
        }
        if h.prim == crate::geom::Hit::OCCLUDED.prim {
            return Some(SceneHit::OCCLUDED);
        }
        let [inst, prim] = self.world.flat.id(h.prim)?;
        let geometry = v.instance(inst)?.geometry;
        Some(SceneHit {
            prim,
            ..SceneHit::of(h, geometry, inst)
        })
    }

    /// Whether structure `s` (the grid or the kd-tree) answers for the
    /// current commit's flattening for `mask`.
    fn built_for(&self, s: Structure, mask: u32) -> Result<()> {
        let bit = match s {
            Structure::Grid => Limits::GRID,
            Structure::Kd => Limits::KD,
            Structure::Bvh => Limits::BVH,
        };
        if self.world.flat.capacity() == 0 || !self.limits.has(bit) {
            return Err(Error::InvalidArgument(
                "no grid or kd-tree over the scene: Limits::structures lacks it",
            ));
        }
        match self.sources.current(bit)? {
            (_, m) if m == mask => Ok(()),
            _ => Err(Error::InvalidArgument(
                "the structure was built over the scene for another mask",
            )),
        }
    }

    /// Geometry `id`'s filter from now on (`GeometryParams::filter`;
    /// `None`: every candidate accepted), for every method and the
    /// structures built over the scene. `InvalidArgument` when `id` is
    /// not set; nothing changes then.
    pub fn set_geometry_filter(&mut self, id: u32, filter: Option<Filter>) -> Result<()> {
        self.scene_pools()?;
        self.world.scene.set_filter(id, filter)
    }

    fn scene_pools(&self) -> Result<()> {
        if self.limits.max_geometries == 0 {
            return Err(Error::InvalidArgument(
                "no two-level scene: Limits::max_geometries is 0",
            ));
        }
        Ok(())
    }

    /// Set geometry `id` of the two-level scene to `scene` (replacing it
    /// if set), its BVH built with `p` in a run of the scene's triangle
    /// budget. On error nothing changes. Call `commit_scene` before
    /// tracing. See `TwoLevel::set_geometry` for the errors.
    pub fn set_geometry(
        &mut self,
        id: u32,
        scene: &Scene<'_>,
        p: &GeometryParams,
    ) -> Result<BvhInfo> {
        self.set_geometry_with(id, scene, p, &Serial)
    }

    /// `set_geometry` on the caller's workers (the LOW build joins them).
    pub fn set_geometry_with(
        &mut self,
        id: u32,
        scene: &Scene<'_>,
        p: &GeometryParams,
        par: &dyn Par,
    ) -> Result<BvhInfo> {
        self.scene_pools()?;
        self.world.scene.set_geometry(id, scene, p, par)
    }

    /// Update geometry `id` to `scene`'s moved vertices (`Refit`) or new
    /// triangles (`Rebuild`), as its mode says. See
    /// `TwoLevel::update_geometry`.
    pub fn update_geometry(&mut self, id: u32, scene: &Scene<'_>) -> Result<UpdateInfo> {
        self.update_geometry_with(id, scene, &Serial)
    }

    /// `update_geometry` on the caller's workers.
    pub fn update_geometry_with(
        &mut self,
        id: u32,
        scene: &Scene<'_>,
        par: &dyn Par,
    ) -> Result<UpdateInfo> {
        self.scene_pools()?;
        self.world.scene.update_geometry(id, scene, par)
    }

    /// Remove geometry `id` (refused while an instance places it).
    pub fn remove_geometry(&mut self, id: u32) -> Result<()> {
        self.scene_pools()?;
        self.world.scene.remove_geometry(id)
    }

    /// Set instance `id`: geometry `geometry` placed by `transform`
    /// (object to world), seen by rays whose mask shares a bit with
    /// `mask`. See `TwoLevel::set_instance`.
    pub fn set_instance(
        &mut self,
        id: u32,
        geometry: u32,
        transform: &Affine,
        mask: u32,
    ) -> Result<()> {
        self.scene_pools()?;
        self.world.scene.set_instance(id, geometry, transform, mask)
    }

    /// Remove instance `id`.
    pub fn remove_instance(&mut self, id: u32) -> Result<()> {
        self.scene_pools()?;
        self.world.scene.remove_instance(id)
    }

    /// Build the top level over the instances: after any change to the
    /// scene, before tracing it.
    pub fn commit_scene(&mut self) -> Result<TwoLevelInfo> {
        self.scene_pools()?;
        self.sources.commits += 1;
        Ok(self.world.scene.commit())
    }

    /// The committed two-level scene (`NotBuilt` when it changed since).
    pub fn scene_view(&self) -> Result<TwoLevelView<'_>> {
        self.scene_pools()?;
        self.world.scene.view()
    }

    /// Nearest hits of `rays` in the committed two-level scene, among
    /// instances `ctl` sees (a mask, or `RayControls` with culling), into
    /// `hits` (same length), one single ray each (the 4-wide single ray in
    /// every geometry).
    pub fn trace_scene(
        &mut self,
        rays: &[Ray],
        ctl: impl Into<RayControls>,
        hits: &mut [SceneHit],
    ) -> Result<Counters> {
        self.trace_scene_on(None, rays, ctl.into(), hits)
    }

    /// `trace_scene` with a method and its packet settings (packet
    /// methods take the rays in order as packets of `p.packet`^2 rays, as
    /// `trace_with` does). The `Bvh*` methods walk the two-level scene and
    /// give `trace_scene`'s hits, bit for bit. The grid's and the
    /// kd-tree's trace the flattened scene their `build_*_scene` built
    /// for this commit and `mask` (else `NotBuilt`; another mask is
    /// `InvalidArgument`), each bitwise its own single ray; their t, u, v
    /// are those of the world triangle.
    pub fn trace_scene_with(
        &mut self,
        p: &TraceParams,
        rays: &[Ray],
        ctl: impl Into<RayControls>,
        hits: &mut [SceneHit],
    ) -> Result<Counters> {
        self.trace_scene_on(Some(p), rays, ctl.into(), hits)
    }

    fn trace_scene_on(
        &mut self,
        p: Option<&TraceParams>,
        rays: &[Ray],
        ctl: RayControls,
        hits: &mut [SceneHit],
    ) -> Result<Counters> {
        let n = hits.len();
        self.scene_rays(p, rays, n, ctl, false, |i, h| hits[i] = h)
    }

    /// Rays `rays` traced (or with `any` tested for occlusion) into `out`
    /// (`n` results: `rays.len()`), with counters and time recorded.
    fn scene_rays(
        &mut self,
        p: Option<&TraceParams>,
        rays: &[Ray],
        n: usize,
        ctl: RayControls,
        any: bool,
        out: impl FnMut(usize, SceneHit),
    ) -> Result<Counters> {
        if rays.len() != n {
            return Err(Error::InvalidArgument(
                "rays and their results must have the same length",
            ));
        }
        let t = now();
        let ctr = self.trace_scene_each(p, None, n, ctl, any, |i| rays[i], out)?;
        self.stats.trace_ns = elapsed_ns(t);
        self.stats.counters = ctr;
        Ok(ctr)
    }

    /// Whether anything blocks each of `rays` in `[tmin, tmax)` (instances
    /// as in `trace_scene`), into `occluded` (same length).
    pub fn occluded_scene(
        &mut self,
        rays: &[Ray],
        ctl: impl Into<RayControls>,
        occluded: &mut [bool],
    ) -> Result<Counters> {
        self.occluded_scene_on(None, rays, ctl.into(), occluded)
    }

    /// `occluded_scene` with a BVH method (as `trace_scene_with`).
    pub fn occluded_scene_with(
        &mut self,
        p: &TraceParams,
        rays: &[Ray],
        ctl: impl Into<RayControls>,
        occluded: &mut [bool],
    ) -> Result<Counters> {
        self.occluded_scene_on(Some(p), rays, ctl.into(), occluded)
    }

    fn occluded_scene_on(
        &mut self,
        p: Option<&TraceParams>,
        rays: &[Ray],
        ctl: RayControls,
        occluded: &mut [bool],
    ) -> Result<Counters> {
        let n = occluded.len();
        self.scene_rays(p, rays, n, ctl, true, |i, h| occluded[i] = h.is_hit())
    }

    /// The committed two-level scene's answer for `count` rays read by
    /// `rays.ray(i)` (a closure, or a `RayStream`), handed to `out(i, hit)`: the nearest hit, or with `any`
    /// some hit (occlusion), for the instances and triangle sides `ctl`
    /// lets the rays see (a mask, or `RayControls`). Without `p`, one
    /// single ray each; with `p`, `p.method` on thread slot `slot` (or the
    /// highest free one): a BVH method through the two-level scene, or a
    /// grid or kd-tree method on the flattened scene (`trace_scene_with`;
    /// without culling). Read-only: many threads may call it at once (the
    /// C ABI's scene traces do), each with its own slot for packets.
    // Kept as it is: the C ABI's scene traces (ffi/) and the CLI call it.
    #[allow(clippy::too_many_arguments)] // the batch's parts, as `batch_on`
    pub fn trace_scene_each(
        &self,
        p: Option<&TraceParams>,
        slot: Option<u32>,
        count: usize,
        ctl: impl Into<RayControls>,
        any: bool,
        rays: impl RaySource,
        mut out: impl FnMut(usize, SceneHit),
    ) -> Result<Counters> {
        // Hits go out a run at a time (a packet's, a quad's or one), and
        // this loop, made for the caller's `out`, inlines it.
        let mut run = |start: usize, hits: &[SceneHit]| {
            for (k, h) in hits.iter().enumerate() {
                out(start + k, *h)
            }
        };
        let q = SceneQuery {
            p,
            slot,
            ctl: ctl.into(),
            any,
        };
        self.trace_scene_dyn(q, count, DynRays(&rays), &mut run)
    }

    /// `trace_scene_each`'s body, not generic: its traversals (every
    /// triangle test, culling and lane width) are compiled once, here,
    /// not again for each caller's rays and closure in every crate that
    /// calls it. `out(start, hits)` takes the hits of rays `start ..`;
    /// the cost is one indirect call per packet (a quad on the flattened
    /// scene, a ray for single rays) for the rays and one for the hits.
    fn trace_scene_dyn(
        &self,
        q: SceneQuery<'_>,
        count: usize,
        rays: DynRays<'_>,
        out: &mut dyn FnMut(usize, &[SceneHit]),
    ) -> Result<Counters> {
        let SceneQuery { p, slot, ctl, any } = q;
        self.scene_pools()?;
        let v = self.world.scene.view()?;
        let RayControls { mask, cull, .. } = ctl;
        let mut ctr = Counters::default();
        let Some(p) = p else {
            // One dispatch on the test, not one per ray.
            with_test!(v.info.test, |T| for i in 0..count {
                let r = rays.ray(i);
                let h = if any {
                    traverse_single::any_hit::<T>(&v, &r, ctl, &mut ctr)
                } else {
                    traverse_single::intersect::<T>(&v, &r, ctl, &mut ctr)
                };
                out(i, &[h]);
            });
            return Ok(ctr);
        };
        p.validate_for(&self.limits)?;
        // Forced opacity by the parameters or the ray flags.
        let ctl = RayControls {
            opaque: ctl.opaque || p.opaque,
            ..ctl
        };
        let structure = p.method.structure();
        if structure != Structure::Bvh {
            // The grid and the kd-tree trace the flattened scene.
            self.built_for(structure, mask)?;
            if cull != Cull::None {
                return Err(Error::InvalidArgument(
                    "culling is a BVH method's control: the grid and the kd-tree trace without it",
                ));
            }
            let v = &v;
            let p = &TraceParams {
                opaque: ctl.opaque,
                ..*p
            };
            return self.trace_quads(
                slot,
                p,
                count,
                rays,
                |i, h: &crate::geom::Hit4, n| {
                    let quad: [SceneHit; 4] = core::array::from_fn(|l| {
                        let sh = if l < n {
                            self.flat_hit(v, &h.lane(l))
                        } else {
                            None
                        };
                        debug_assert!(l >= n || sh.is_some(), "a hit outside the flattened scene");
                        sh.unwrap_or(SceneHit::MISS)
                    });
                    out(i, &quad[..n])
                },
                any,
            );
        }
        // The geometries' traversal (method, triangle test, lane width)
        // chosen once for the call; culling is the views' (`BvhView::cull`).
        let blas: Tracing<BvhView<'_>> = Tracing::of_test(v.info.test, p, any);
        let g = blas.as_fn();
        let c = &mut ctr;
        let call = SceneCall {
            scene: &v,
            params: p,
            ctl,
        };
        let trace = |q: &[Ray4], a: &[M4], h: &mut [SceneHit], sl: &mut Slot<'_>| {
            if any {
                traverse_packet::trace::<true>(&call, g, q, a, h, sl, c)
            } else {
                traverse_packet::trace::<false>(&call, g, q, a, h, sl, c)
            }
        };
        let per = packet_rays(p);
        self.with_slot(slot, |sl| {
            let hits = |start: usize, h: &[SceneHit], n: usize| out(start, &h[..n]);
            let batch = Batch {
                count,
                per,
                miss: SceneHit::MISS,
                k: 4,
            };
            packets(sl, batch, rays, trace, hits)
        })?;
        Ok(ctr)
    }

    /// Nearest hits of the camera rays through the pixels of `rect` in the
    /// committed two-level scene, made in the kernel as `trace_camera`
    /// makes them, pixel (x, y)'s hit into `hits[(y - rect.y0) * row + (x
    /// - rect.x0)]`: `p`, `slot` and `ctl` as `trace_scene_each`, and its
    /// hits for the rays `camera.ray(x, y)`, bit for bit.
    // Kept as it is: tests/exact/twolevel_exact.rs calls it.
    #[allow(clippy::too_many_arguments)] // the camera call's parts, as `trace_scene_each`
    pub fn trace_scene_camera(
        &self,
        p: Option<&TraceParams>,
        slot: Option<u32>,
        camera: &PrimaryRays,
        rect: PixelRect,
        ctl: impl Into<RayControls>,
        hits: &mut [SceneHit],
        row: usize,
    ) -> Result<Counters> {
        let rays = CameraRays::new(camera, rect, p)?;
        rect.check_results(hits.len(), row)?;
        let mut at = rays.index(row);
        let out = |i: usize, h: SceneHit| {
            if let Some(k) = at.of(i) {
                hits[k] = h;
            }
        };
        self.trace_scene_each(p, slot, rays.count(), ctl, false, rays, out)
    }

    /// Nearest hits of a ray stream in the committed two-level scene
    /// (`trace_scene_each` with rays and hits as structures of arrays,
    /// `trace::stream`): `p` and `slot` as there, and the same hits as the
    /// array-of-structs calls, bit for bit.
    pub fn trace_scene_stream(
        &self,
        p: Option<&TraceParams>,
        slot: Option<u32>,
        rays: &RayStream<'_>,
        ctl: impl Into<RayControls>,
        hits: &mut SceneHitStream<'_>,
    ) -> Result<Counters> {
        let n = rays.count()?;
        hits.check(n)?;
        self.trace_scene_each(p, slot, n, ctl, false, *rays, |i, h| hits.put(i, &h))
    }

    /// Occlusion of a ray stream in the committed two-level scene into
    /// `occluded` (one per ray), as `trace_scene_stream` takes its rays.
    pub fn occluded_scene_stream(
        &self,
        p: Option<&TraceParams>,
        slot: Option<u32>,
        rays: &RayStream<'_>,
        ctl: impl Into<RayControls>,
        occluded: &mut [bool],
    ) -> Result<Counters> {
        let n = rays.count()?;
        crate::trace::stream::one_per_ray(&[occluded.len()], n)?;
        let out = |i: usize, h: SceneHit| occluded[i] = h.is_hit();
        self.trace_scene_each(p, slot, n, ctl, true, *rays, out)
    }
}
