//! The two-level scene through the C ABI: geometries set in every update
//! mode from any mesh buffers, updated, removed in any order; instances
//! with any transform (rigid, mirrored, raw bits, NaN, singular, huge);
//! commits; `trace_scene` / `occluded_scene` with every method, mask and
//! flag; the flattened grid, kd-tree and perspective-grid builds and
//! `scene_prim`; and a second thread tracing while the first moves an
//! instance and commits.
//!
//! A model of the scene (each geometry's triangles as the call read them,
//! its reservation, mode and mask; each instance's geometry, transform and
//! mask; a snapshot at every commit) checks each call:
//! - a set whose reservation fits the model's free budget is never
//!   refused for capacity (the budget does not fragment), and a commit
//!   reports the model's free triangles;
//! - after a successful edit the scene answers `NOT_BUILT` until the next
//!   commit; after a failed one the last scene trace gives the same bytes;
//! - a scene hit names a live instance of the commit, its geometry and
//!   one of that geometry's triangles, seen by the ray mask, with
//!   `tmin <= t < tmax`; results are written only on success;
//! - every BVH method (and the packets) equals the single ray bitwise,
//!   grid and kd methods their structure's single ray, and occluded the
//!   nearest hit's existence (finite, moderate scenes and rays);
//! - where every visible geometry is well shaped (the canned scene, no
//!   triangle left out by a build) and placed by a rigid transform, the
//!   nearest hits agree with the f64 oracle over the model's world
//!   triangles within `sheaf::reference`'s named tolerances.

use super::*;
use sheaf::ffi::{
    bvh::{sheaf_refit_info, sheaf_refit_params},
    sheaf_geometry_params, sheaf_mesh, sheaf_scene_hit, sheaf_scene_info,
};
use sheaf::geom::TriVerts;
use sheaf::reference::{self, Verdict};
use sheaf::{Ray, Scene};
use std::collections::HashMap;

const NONE: u32 = ffi::SHEAF_INVALID_ID;
const S_SCENE: u8 = 0xC3;

// ---- inputs --------------------------------------------------------------------

#[derive(Arbitrary, Debug)]
pub enum SceneOp {
    /// `set_scene_geometry`; `params` None passes NULL (the defaults).
    Set {
        id: u8,
        mesh: MeshIn,
        params: Option<GeomParamsIn>,
        null_mesh: bool,
    },
    /// `update_scene_geometry` with the stored mesh moved, or another one.
    Update {
        id: u8,
        mesh: UpdateIn,
        want_info: bool,
    },
    Remove(u8),
    SetInstance {
        id: u8,
        geometry: u8,
        xf: XformIn,
        mask: MaskIn,
        null: bool,
    },
    RemoveInstance(u8),
    /// `commit_scene` (true: with a NULL info).
    Commit(bool),
    Trace {
        params: Option<TraceIn>,
        rays: RaysIn,
        mask: MaskIn,
        flags: u8,
        occluded: bool,
    },
    /// `build_scene_grid` / `_kd` / `_pgrid` (kind % 3).
    Flatten {
        kind: u8,
        grid: Option<GridIn>,
        kd: Option<KdIn>,
        pgrid: Option<PgridIn>,
        mask: MaskIn,
    },
    /// `scene_prim` of a world triangle number, or of a deferred pixel.
    Prim {
        structure: N,
        prim: N,
        pixel: Option<(u8, u8)>,
    },
    /// A trace on a second thread while this one moves an instance and
    /// commits.
    Concurrent {
        params: Option<TraceIn>,
        rays: RaysIn,
        instance: u8,
        xf: XformIn,
    },
    /// A shortcut: canned geometries, rigid instances of them, a commit.
    Warmup(u8),
}

#[derive(Arbitrary, Debug)]
pub enum MeshIn {
    Any(GeomIn),
    Canned(u8, [F; 3]),
}

#[derive(Arbitrary, Debug)]
pub enum UpdateIn {
    /// The stored mesh with vertex `which` (or, past its vertices, every
    /// vertex) moved by `by` in 1/8 units.
    Moved {
        which: u8,
        by: [i8; 3],
    },
    Mesh(MeshIn),
}

#[derive(Arbitrary, Debug)]
pub struct GeomParamsIn {
    mode: N,
    reserve: N,
    bvh: Option<BvhIn>,
    rebuild_above: F,
    mask: MaskIn,
}

#[derive(Arbitrary, Debug, Clone, Copy)]
pub enum MaskIn {
    All,
    Bits(u8),
    Any(u32),
}

impl MaskIn {
    fn get(self) -> u32 {
        match self {
            MaskIn::All => !0,
            MaskIn::Bits(b) => b as u32 & 7,
            MaskIn::Any(x) => x,
        }
    }
}

#[derive(Arbitrary, Debug, Clone, Copy)]
pub enum XformIn {
    /// A rotation about axis `axis % 3` by `angle` / 256 turns, a scale
    /// per axis (uniform unless `stretch`), an optional mirror of x, and a
    /// translation in 1/8 units.
    Rigid {
        angle: u8,
        axis: u8,
        scale: u8,
        stretch: bool,
        mirror: bool,
        t: [i8; 3],
    },
    Raw([F; 12]),
    /// A singular matrix (a zero row, two equal rows, a zero column).
    Singular(u8),
    /// Entries scaled by 2^(e % 128) or 2^-(e % 128).
    Huge(u8, bool),
}

impl XformIn {
    /// Row-major 3x4 matrix and whether it is a sane rigid placement.
    fn get(self) -> ([f32; 12], bool) {
        match self {
            XformIn::Rigid {
                angle,
                axis,
                scale,
                stretch,
                mirror,
                t,
            } => {
                let a = angle as f64 / 256.0 * core::f64::consts::TAU;
                let (s, c) = a.sin_cos();
                let k = [0.5, 1.0, 2.0, 3.0];
                let sc = if stretch {
                    [
                        k[scale as usize % 4],
                        k[scale as usize / 4 % 4],
                        k[scale as usize / 16 % 4],
                    ]
                } else {
                    [k[scale as usize % 4]; 3]
                };
                let r: [[f64; 3]; 3] = match axis % 3 {
                    0 => [[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]],
                    1 => [[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]],
                    _ => [[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]],
                };
                let mut m = [0f32; 12];
                for row in 0..3 {
                    for col in 0..3 {
                        let flip = if mirror && col == 0 { -1.0 } else { 1.0 };
                        m[4 * row + col] = (r[row][col] * sc[col] * flip) as f32;
                    }
                    m[4 * row + 3] = t[row] as f32 / 8.0;
                }
                (m, true)
            }
            XformIn::Raw(v) => (v.map(|x| x.get()), false),
            XformIn::Singular(k) => {
                let mut m = [1.0, 0.0, 0.0, 0.5, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0];
                match k % 3 {
                    0 => m[4..7].fill(0.0),
                    1 => m.copy_within(0..4, 8),
                    _ => {
                        let col = k as usize / 3 % 3;
                        for row in 0..3 {
                            m[4 * row + col] = 0.0;
                        }
                    }
                }
                (m, false)
            }
            XformIn::Huge(e, down) => {
                let f = if down {
                    (-(e as i32 % 128) as f32).exp2()
                } else {
                    ((e as i32 % 128) as f32).exp2()
                };
                let m = [f, 0.0, 0.0, f, 0.0, f, 0.0, 0.0, 0.0, 0.0, f, -f];
                (m, false)
            }
        }
    }
}

fn transform(m: &[f32; 12], p: [f32; 3]) -> [f32; 3] {
    let d = |r: usize| {
        m[4 * r] as f64 * p[0] as f64
            + m[4 * r + 1] as f64 * p[1] as f64
            + m[4 * r + 2] as f64 * p[2] as f64
            + m[4 * r + 3] as f64
    };
    [d(0) as f32, d(1) as f32, d(2) as f32]
}

// ---- the model -------------------------------------------------------------------

#[derive(Clone, Debug)]
struct GeoModel {
    /// Object-space triangles as the last set or update read them.
    tris: Vec<[[f32; 3]; 3]>,
    /// The vertices and indices the last set or update read (a REFIT
    /// update sends these indices with moved vertices).
    verts: Vec<[f32; 3]>,
    idx: Vec<u32>,
    /// Left out by the last build (a refit keeps them out).
    out: Vec<bool>,
    /// Triangles of the budget the geometry holds.
    kept: u32,
    mode: u32,
    mask: u32,
    /// Finite within +-1e4 (the exactness comparisons apply).
    moderate: bool,
    /// Well shaped for the oracle: the canned scene, nothing left out.
    oracle: bool,
}

#[derive(Clone, Copy, Debug)]
struct InstModel {
    geometry: u32,
    m: [f32; 12],
    mask: u32,
    rigid: bool,
    moderate: bool,
}

#[derive(Clone, Debug)]
struct Snapshot {
    geoms: Vec<Option<GeoModel>>,
    insts: Vec<Option<InstModel>>,
}

/// A successful scene trace to repeat after failed edits.
struct SceneTrace {
    params: Option<sheaf_trace_params>,
    rays: Vec<sheaf_ray>,
    mask: u32,
    flags: u32,
    occluded: bool,
    out: Vec<u8>,
}

pub struct SceneModel {
    budget: u32,
    geoms: Vec<Option<GeoModel>>,
    insts: Vec<Option<InstModel>>,
    /// The scene as last committed, while nothing changed since.
    committed: Option<Snapshot>,
    commits: u32,
    /// The flattening: (commit, mask, structure bits built over it).
    flat: Option<(u32, u32, u32)>,
    last: Option<SceneTrace>,
    compacted: u64,
}

impl SceneModel {
    pub fn new(l: &Limits) -> SceneModel {
        SceneModel {
            budget: l.scene_triangles(),
            geoms: vec![None; l.max_geometries as usize],
            insts: vec![None; l.scene_instances() as usize],
            committed: None,
            commits: 0,
            flat: None,
            last: None,
            compacted: 0,
        }
    }

    fn free(&self) -> u32 {
        self.budget - self.geoms.iter().flatten().map(|g| g.kept).sum::<u32>()
    }

    /// A successful edit: the scene answers NOT_BUILT until committed.
    fn changed(&mut self) {
        self.committed = None;
        self.last = None;
    }

    /// A flat build or set_geometry succeeded: structures the scene's
    /// flattening built may answer NOT_BUILT now.
    pub fn flat_rebuilt(&mut self) {
        if self
            .last
            .as_ref()
            .is_some_and(|l| l.params.is_some_and(|p| !is_bvh(p.method)))
        {
            self.last = None;
        }
    }
}

fn is_bvh(method: u32) -> bool {
    matches!(method, 2..=6 | 10..=12)
}

// ---- calls ---------------------------------------------------------------------

pub fn step(st: &mut State, op: &SceneOp) {
    match op {
        SceneOp::Set {
            id,
            mesh,
            params,
            null_mesh,
        } => set(st, *id as u32, mesh, params.as_ref(), *null_mesh),
        SceneOp::Update {
            id,
            mesh,
            want_info,
        } => update(st, *id as u32, mesh, *want_info),
        SceneOp::Remove(id) => {
            let id = *id as u32 % 8;
            let before = stats_of(st.ctx);
            let s = ffi::sheaf_context_remove_scene_geometry(st.ctx, id);
            let m = &mut st.scene;
            let placed = m.insts.iter().flatten().any(|i| i.geometry == id);
            let set = m.geoms.get(id as usize).is_some_and(Option::is_some);
            assert_eq!(
                s == OK,
                set && !placed,
                "remove geometry {id}: {s:?} (set {set}, placed {placed})"
            );
            if s == OK {
                m.geoms[id as usize] = None;
                m.changed();
            }
            scene_after(st, s, &before, "remove_scene_geometry");
        }
        SceneOp::SetInstance {
            id,
            geometry,
            xf,
            mask,
            null,
        } => set_instance(
            st,
            *id as u32 % 12,
            *geometry as u32 % 6,
            xf,
            mask.get(),
            *null,
        ),
        SceneOp::RemoveInstance(id) => {
            let id = *id as u32 % 12;
            let before = stats_of(st.ctx);
            let s = ffi::sheaf_context_remove_instance(st.ctx, id);
            let live = st.scene.insts.get(id as usize).is_some_and(Option::is_some);
            assert_eq!(s == OK, live, "remove_instance {id}: {s:?}, live {live}");
            if s == OK {
                st.scene.insts[id as usize] = None;
                st.scene.changed();
            }
            scene_after(st, s, &before, "remove_instance");
        }
        SceneOp::Commit(null) => commit(st, *null),
        SceneOp::Trace {
            params,
            rays,
            mask,
            flags,
            occluded,
        } => {
            let flags = match flags % 8 {
                0..=3 => 0,
                4 | 5 => 1 + (*flags as u32 >> 3) % 2,
                6 => 3,
                _ => *flags as u32,
            };
            trace(
                st,
                params.map(|p| p.get()),
                rays,
                mask.get(),
                flags,
                *occluded,
            );
        }
        SceneOp::Flatten {
            kind,
            grid,
            kd,
            pgrid,
            mask,
        } => flatten(st, *kind, grid, kd, pgrid, mask.get()),
        SceneOp::Prim {
            structure,
            prim,
            pixel,
        } => prim_of(st, *structure, *prim, *pixel),
        SceneOp::Concurrent {
            params,
            rays,
            instance,
            xf,
        } => concurrent(st, params.map(|p| p.get()), rays, *instance as u32 % 12, xf),
        SceneOp::Warmup(k) => {
            let n = 1 + *k as u32 % 3;
            // Geometry 0 in the mode `k` names (STATIC, REFIT, REBUILD),
            // so the update below can succeed; the others the defaults.
            let p0 = GeomParamsIn {
                mode: N::Small(*k / 3),
                reserve: N::Small(0),
                bvh: None,
                rebuild_above: F::Small((*k >> 4) as i8),
                mask: MaskIn::All,
            };
            for g in 0..n {
                let mesh = MeshIn::Canned(k.wrapping_add(g as u8 * 5), [F::Small(g as i8 * 9); 3]);
                set(st, g, &mesh, (g == 0).then_some(&p0), false);
            }
            for i in 0..n + 1 {
                let xf = XformIn::Rigid {
                    angle: k.wrapping_mul(i as u8 + 1),
                    axis: i as u8,
                    scale: *k >> 2,
                    stretch: k & 1 != 0,
                    mirror: i == 2,
                    t: [i as i8 * 40, -(i as i8) * 24, i as i8 * 8],
                };
                set_instance(st, i, i % n, &xf, !0, false);
            }
            commit(st, false);
            // Traces of a fan of rays at the scene (the first run's corpus
            // never reached a successful scene trace by mutation alone):
            // single rays, then a method and packet chosen by `k`, nearest
            // and occluded.
            let rays = RaysIn {
                rays: Vec::new(),
                fan: Some((
                    [F::Small(40), F::Small(-56), F::Small(24)],
                    [F::Small(0); 3],
                    *k,
                )),
                tmax: RayTmax::Inf,
                claim: None,
                ray_offset: 0,
                hit_offset: 0,
                overlap: false,
                null_rays: false,
                null_hits: false,
            };
            let p = TraceIn {
                method: N::Small(2 + k % 11),
                packet: N::Small(k / 11),
                macrocells: false,
                mailbox: false,
                culling: false,
                ray_kind: N::Small(0),
                entry: N::Small(0),
                split: F::Small(0),
                isa: N::Small(k / 7),
            };
            trace(st, None, &rays, !0, 0, false);
            trace(st, Some(p.get()), &rays, !0, 0, k % 2 == 0);
            // The rest of the scene API in one go (run 7's corpus reached
            // no successful update, remove, flattened build or scene_prim
            // by mutation): a flattened build and a lookup, an update of
            // geometry 0 and the last geometry removed with its instances,
            // each followed by a commit and a trace.
            flatten(st, *k, &None, &None, &None, !0);
            prim_of(st, N::Small(*k % 3), N::Small(*k >> 2), None);
            let moved = UpdateIn::Moved {
                which: *k,
                by: [1, -2, 3],
            };
            update(st, 0, &moved, k & 8 != 0);
            commit(st, false);
            trace(st, Some(p.get()), &rays, !0, 0, k % 2 != 0);
            for i in (0..n + 1).filter(|i| i % n == n - 1) {
                step(st, &SceneOp::RemoveInstance(i as u8));
            }
            step(st, &SceneOp::Remove((n - 1) as u8));
            commit(st, true);
            trace(st, None, &rays, !0, 0, false);
        }
    }
}

/// After an exclusive scene call: the common checks, and on failure the
/// last scene trace gives the same bytes.
fn scene_after(st: &mut State, s: sheaf_status, before: &str, what: &str) {
    st.after(s, before, what);
    if s != OK {
        if let Some(l) = &st.scene.last {
            let again = run(
                st.ctx,
                l.params.as_ref(),
                &l.rays,
                l.mask,
                l.flags,
                l.occluded,
            );
            assert!(
                again.as_ref() == Ok(&l.out),
                "after {what} failed with {s:?}: the last scene trace ({:?}) gives {:?}",
                l.params,
                again.err()
            );
        }
    }
}

/// The mesh buffers of `m` (the canned scene or any buffers).
fn mesh_of(m: &MeshIn) -> (MeshBuf, bool) {
    match m {
        MeshIn::Any(g) => (MeshBuf::of(g), false),
        MeshIn::Canned(k, shift) => (MeshBuf::of(&canned(*k, *shift)), true),
    }
}

/// `b` as a `sheaf_mesh`.
fn mesh_ptrs(b: &MeshBuf) -> sheaf_mesh {
    sheaf_mesh {
        vertices: b.vp,
        vertex_stride_bytes: b.stride,
        vertex_count: b.nv,
        indices: b.ip,
        triangle_count: b.nt,
    }
}

/// The triangles a successful call read from `b`.
fn triangles(b: &MeshBuf) -> Vec<[[f32; 3]; 3]> {
    (0..b.nt as usize)
        .map(|t| {
            [0, 1, 2].map(|k| {
                // SAFETY: the call accepted the buffers: indices aligned and
                // below the vertex count, every vertex inside the buffer.
                let i = unsafe { b.ip.add(3 * t + k).read() } as usize;
                let p = unsafe { b.vp.cast::<u8>().add(i * b.stride).cast::<[f32; 3]>() };
                unsafe { p.read_unaligned() }
            })
        })
        .collect()
}

/// The indices of `b`, a mesh the call accepted, and its vertices up to
/// the last one they use (a claimed count may be far larger, at stride 0).
fn arrays(b: &MeshBuf) -> (Vec<[f32; 3]>, Vec<u32>) {
    // SAFETY: the call accepted the buffers: 3 * nt aligned indices, each
    // below the vertex count, every vertex inside the buffer.
    let idx: Vec<u32> = (0..3 * b.nt as usize)
        .map(|k| unsafe { b.ip.add(k).read() })
        .collect();
    let used = idx.iter().max().map_or(0, |&i| i as usize + 1);
    if used > 400 {
        // More than a `MeshBuf` holds: a moved copy is refused (its
        // indices past its vertices), which the update checks as any.
        return (Vec::new(), idx);
    }
    let verts = (0..used)
        .map(|i| {
            // SAFETY: as above.
            let p = unsafe { b.vp.cast::<u8>().add(i * b.stride).cast::<[f32; 3]>() };
            unsafe { p.read_unaligned() }
        })
        .collect();
    (verts, idx)
}

fn left_out(tris: &[[[f32; 3]; 3]]) -> Vec<bool> {
    tris.iter()
        .map(|t| {
            Scene::classify(&TriVerts {
                v0: t[0],
                v1: t[1],
                v2: t[2],
            })
            .is_some()
        })
        .collect()
}

fn set(st: &mut State, id: u32, mesh: &MeshIn, params: Option<&GeomParamsIn>, null_mesh: bool) {
    let id = id % 6;
    let (b, canned) = mesh_of(mesh);
    let mut p = sheaf_geometry_params {
        size: 0,
        mode: 0,
        bvh: core::ptr::null(),
        refit: core::ptr::null(),
        filter: None,
        filter_user: core::ptr::null_mut(),
        max_triangles: 0,
        mask: !0,
        opaque: 0,
        reserved: 0,
    };
    assert_eq!(
        ffi::sheaf_geometry_params_default(&mut p, core::mem::size_of_val(&p)),
        OK
    );
    // The params point to their BVH and refit params: these live through
    // the call.
    let mut bvh = default_bvh();
    let mut refit = default_refit();
    if let Some(g) = params {
        p.mode = small(g.mode, |v| v % 3);
        p.max_triangles = small(g.reserve, |v| v * 4);
        if let Some(b) = &g.bvh {
            bvh = b.get();
        }
        refit.rebuild_above = match g.rebuild_above {
            F::Small(v) => [0.0, 1.0, 1.5, 4.0][v as usize % 4],
            x => x.get(),
        };
        p.bvh = &bvh;
        p.refit = &refit;
        p.mask = g.mask.get();
    }
    let mesh = mesh_ptrs(&b);
    let m = &st.scene;
    let cap = if p.max_triangles == 0 {
        b.nt
    } else {
        p.max_triangles
    };
    let old = m.geoms.get(id as usize).and_then(Option::as_ref);
    let in_place = old.is_some_and(|g| g.kept >= cap);
    let before = stats_of(st.ctx);
    let s = ffi::sheaf_context_set_scene_geometry(
        st.ctx,
        id,
        if null_mesh { core::ptr::null() } else { &mesh },
        if params.is_some() {
            &p
        } else {
            core::ptr::null()
        },
    );
    if null_mesh {
        assert_eq!(s, sheaf_status::NullPointer);
    }
    if s == sheaf_status::CapacityTriangles {
        // The budget does not fragment: only a reservation past the free
        // triangles (or a mesh past its reservation) is refused.
        assert!(
            b.nt > cap || (!in_place && cap > m.free()),
            "geometry {id}: {cap} triangles refused with {} free (in place {in_place})",
            m.free()
        );
    }
    if s == OK {
        assert!((id as usize) < m.geoms.len());
        let kept = if in_place { old.unwrap().kept } else { cap };
        let tris = triangles(&b);
        let (verts, idx) = arrays(&b);
        let out = left_out(&tris);
        let moderate = b.moderate();
        st.scene.geoms[id as usize] = Some(GeoModel {
            oracle: canned && moderate && !out.contains(&true),
            tris,
            verts,
            idx,
            out,
            kept,
            mode: p.mode,
            mask: p.mask,
            moderate,
        });
        st.scene.changed();
    }
    scene_after(st, s, &before, "set_scene_geometry");
}

fn default_bvh() -> sheaf_bvh_params {
    let mut b = sheaf_bvh_params {
        size: 0,
        leaf_size: 0,
        bins: 0,
        traversal_cost: 0.0,
        test: 0,
        quality: 0,
        width: 0,
        presplit: 0,
    };
    assert_eq!(
        ffi::sheaf_bvh_params_default(&mut b, core::mem::size_of_val(&b)),
        OK
    );
    b
}

fn default_refit() -> sheaf_refit_params {
    let mut r = sheaf_refit_params {
        size: 0,
        rebuild_above: 0.0,
    };
    assert_eq!(
        ffi::sheaf_refit_params_default(&mut r, core::mem::size_of_val(&r)),
        OK
    );
    r
}

fn update(st: &mut State, id: u32, mesh: &UpdateIn, want_info: bool) {
    let id = id % 6;
    let Some(g) = st.scene.geoms.get(id as usize).cloned().flatten() else {
        let before = stats_of(st.ctx);
        let (b, _) = mesh_of(&MeshIn::Canned(0, [F::Small(0); 3]));
        let m = mesh_ptrs(&b);
        let s = ffi::sheaf_context_update_scene_geometry(st.ctx, id, &m, core::ptr::null_mut());
        assert_ne!(s, OK, "update of unset geometry {id}");
        return scene_after(st, s, &before, "update_scene_geometry");
    };
    // The moved mesh: the stored vertices, one (or all) moved, with the
    // stored indices (REFIT's contract: the same index buffer).
    let (b, canned) = match mesh {
        UpdateIn::Moved { which, by } => {
            let mut verts = g.verts.clone();
            let n = verts.len();
            for (k, v) in verts.iter_mut().enumerate() {
                if *which as usize >= n || *which as usize == k {
                    for a in 0..3 {
                        v[a] += by[a] as f32 / 8.0;
                    }
                }
            }
            (indexed(&verts, &g.idx), g.oracle)
        }
        UpdateIn::Mesh(m) => mesh_of(m),
    };
    let m = mesh_ptrs(&b);
    let mut info = sheaf_refit_info {
        ns: 7,
        sah_before: 7.0,
        sah_after: 7.0,
        newly_traceable: 7,
        rebuilt: 7,
    };
    let before = stats_of(st.ctx);
    let s = ffi::sheaf_context_update_scene_geometry(
        st.ctx,
        id,
        &m,
        if want_info {
            &mut info
        } else {
            core::ptr::null_mut()
        },
    );
    match g.mode {
        0 => assert_ne!(s, OK, "a STATIC geometry was updated"),
        1 if b.nt as usize != g.tris.len() => {
            assert_ne!(s, OK, "a refit to another triangle count")
        }
        2 if b.nt > g.kept => assert_ne!(s, OK, "a rebuild past the reservation"),
        _ => {}
    }
    if s == OK {
        let tris = triangles(&b);
        // A refit keeps the build's left-out triangles out; a rebuild (or
        // a refit whose growth passed rebuild_above) decides again.
        let rebuilt = g.mode == 2 || (want_info && info.rebuilt == 1);
        let known = g.mode == 2 || want_info;
        let out = if rebuilt {
            left_out(&tris)
        } else {
            let now = left_out(&tris);
            g.out.iter().zip(now).map(|(a, b)| *a || b).collect()
        };
        if g.mode == 2 {
            assert!(
                want_info && info.ns == 0 && info.rebuilt == 0 || !want_info,
                "a REBUILD update's info is not zeroed: {info:?}"
            );
        }
        let moderate = b.moderate();
        let (verts, idx) = arrays(&b);
        st.scene.geoms[id as usize] = Some(GeoModel {
            oracle: canned && known && moderate && !out.contains(&true),
            tris,
            verts,
            idx,
            out,
            moderate,
            ..g
        });
        st.scene.changed();
    } else if want_info {
        assert_eq!(info.ns, 7, "a failed update wrote its info");
    }
    scene_after(st, s, &before, "update_scene_geometry");
}

/// The mesh of `verts` and `idx` (natural stride).
fn indexed(verts: &[[f32; 3]], idx: &[u32]) -> MeshBuf {
    let g = GeomIn {
        verts: verts
            .iter()
            .map(|v| v.map(|x| F::Bits(x.to_bits())))
            .collect(),
        pad: 0,
        offset: 0,
        stride: None,
        claim_vertices: None,
        tris: idx
            .chunks_exact(3)
            .map(|t| [0, 1, 2].map(|k| IndexIn::Any(t[k])))
            .collect(),
        claim_triangles: None,
        index_misalign: 0,
        null_vertices: false,
        null_indices: false,
    };
    MeshBuf::of(&g)
}

fn set_instance(st: &mut State, id: u32, geometry: u32, xf: &XformIn, mask: u32, null: bool) {
    let (m, rigid) = xf.get();
    let before = stats_of(st.ctx);
    let s = ffi::sheaf_context_set_instance(
        st.ctx,
        id,
        geometry,
        if null { core::ptr::null() } else { m.as_ptr() },
        mask,
    );
    if null {
        assert_eq!(s, sheaf_status::NullPointer);
    }
    if m.iter().any(|x| !x.is_finite()) || matches!(xf, XformIn::Singular(_)) {
        assert_ne!(s, OK, "instance {id}: transform {m:?} accepted");
    }
    let set = st
        .scene
        .geoms
        .get(geometry as usize)
        .is_some_and(Option::is_some);
    if s == OK {
        assert!(set && (id as usize) < st.scene.insts.len());
        st.scene.insts[id as usize] = Some(InstModel {
            geometry,
            m,
            mask,
            rigid,
            moderate: m.iter().all(|&x| moderate(x)),
        });
        st.scene.changed();
    }
    scene_after(st, s, &before, "set_instance");
}

fn commit(st: &mut State, null: bool) {
    let mut info = sheaf_scene_info {
        instanced_triangles: 77,
        ..Default::default()
    };
    let before = stats_of(st.ctx);
    let s = ffi::sheaf_context_commit_scene(
        st.ctx,
        if null {
            core::ptr::null_mut()
        } else {
            &mut info
        },
    );
    let m = &mut st.scene;
    if m.geoms.is_empty() {
        assert_ne!(s, OK, "commit without a two-level scene");
    }
    if s == OK {
        if !null {
            let live = m.geoms.iter().flatten().count() as u32;
            assert_eq!(info.geometries, live, "{info:?}");
            assert_eq!(info.free_triangles, m.free(), "free triangles {info:?}");
            assert!(info.largest_free_run <= info.free_triangles, "{info:?}");
            assert!(info.compacted_triangles >= m.compacted, "{info:?}");
            assert!(info.instances <= m.insts.iter().flatten().count() as u32);
            m.compacted = info.compacted_triangles;
        }
        m.commits += 1;
        m.committed = Some(Snapshot {
            geoms: m.geoms.clone(),
            insts: m.insts.clone(),
        });
        // A new commit leaves the flattened structures NOT_BUILT.
        m.last = None;
    } else if !null {
        assert_eq!(
            info.instanced_triangles, 77,
            "a failed commit wrote its info"
        );
    }
    scene_after(st, s, &before, "commit_scene");
}

/// One scene trace into fresh memory: the hit (24 bytes) or occluded
/// bytes, or the status.
fn run(
    ctx: *const sheaf_context,
    p: Option<&sheaf_trace_params>,
    rays: &[sheaf_ray],
    mask: u32,
    flags: u32,
    occluded: bool,
) -> Result<Vec<u8>, sheaf_status> {
    let pp = p.map_or(core::ptr::null(), |p| p);
    if occluded {
        let mut o = vec![S_SCENE; rays.len()];
        let s = ffi::sheaf_context_occluded_scene(
            ctx,
            pp,
            rays.as_ptr(),
            o.as_mut_ptr(),
            rays.len(),
            mask,
            flags,
        );
        if s != OK {
            assert!(
                o.iter().all(|&b| b == S_SCENE),
                "failed occluded_scene wrote"
            );
            return Err(s);
        }
        Ok(o)
    } else {
        let mut h = vec![0u8; 24 * rays.len()];
        h.fill(S_SCENE);
        let s = ffi::sheaf_context_trace_scene(
            ctx,
            pp,
            rays.as_ptr(),
            h.as_mut_ptr().cast(),
            rays.len(),
            mask,
            flags,
        );
        if s != OK {
            assert!(h.iter().all(|&b| b == S_SCENE), "failed trace_scene wrote");
            return Err(s);
        }
        Ok(h)
    }
}

fn hit_at(out: &[u8], k: usize) -> sheaf_scene_hit {
    let w =
        |i: usize| u32::from_le_bytes(out[24 * k + 4 * i..24 * k + 4 * i + 4].try_into().unwrap());
    sheaf_scene_hit {
        t: f32::from_bits(w(0)),
        u: f32::from_bits(w(1)),
        v: f32::from_bits(w(2)),
        prim: w(3),
        geometry: w(4),
        instance: w(5),
    }
}

fn trace(
    st: &mut State,
    params: Option<sheaf_trace_params>,
    r: &RaysIn,
    mask: u32,
    flags: u32,
    occluded: bool,
) {
    let mut rays = make_rays(r);
    let count = r.claim.map_or(rays.len(), |c| (c as usize).min(rays.len()));
    rays.truncate(count);
    // NULL arrays and results over the rays: refused, nothing written.
    if count > 0 && (r.null_rays || r.null_hits || r.overlap) {
        let mut buf = vec![S_SCENE; 24 * count];
        let mut rays_copy = rays.clone();
        let before = rays_copy.clone();
        let rp = if r.null_rays {
            core::ptr::null()
        } else {
            rays_copy.as_ptr()
        };
        let hp: *mut u8 = if r.null_hits {
            core::ptr::null_mut()
        } else if r.overlap {
            rays_copy.as_mut_ptr().cast()
        } else {
            buf.as_mut_ptr()
        };
        let pp = params.as_ref().map_or(core::ptr::null(), |p| p);
        let s = if occluded {
            ffi::sheaf_context_occluded_scene(st.ctx, pp, rp, hp, count, mask, flags)
        } else {
            ffi::sheaf_context_trace_scene(st.ctx, pp, rp, hp.cast(), count, mask, flags)
        };
        valid_status(s, "trace_scene (bad arrays)");
        assert_ne!(
            s, OK,
            "trace_scene with NULL or overlapping arrays accepted"
        );
        assert!(buf.iter().all(|&b| b == S_SCENE));
        assert!(
            rays_copy
                .iter()
                .zip(&before)
                .all(|(a, b)| format!("{a:?}") == format!("{b:?}")),
            "a refused scene trace wrote over its rays"
        );
        return;
    }
    let got = run(st.ctx, params.as_ref(), &rays, mask, flags, occluded);
    let s = got.as_ref().err().copied().unwrap_or(OK);
    valid_status(s, "trace_scene");
    let m = &st.scene;
    let Ok(out) = got else {
        let msg = last_error(st.ctx);
        assert!(
            msg != "no error",
            "trace_scene failed with {s:?}, no last error"
        );
        return;
    };
    let snap = m
        .committed
        .clone()
        .unwrap_or_else(|| panic!("trace_scene OK on a scene changed since its commit"));
    assert!(flags <= 2, "flags {flags} accepted");
    let method = params.map(|p| p.method);
    let flat_method = method.filter(|&x| !is_bvh(x));
    if let Some(x) = flat_method {
        let bit = if x <= 1 { Limits::GRID } else { Limits::KD };
        assert!(
            m.flat
                .is_some_and(|(c, fm, bits)| c == m.commits && fm == mask && bits & bit != 0),
            "method {x} answered without its flattened build ({:?}, commit {}, mask {mask})",
            m.flat,
            m.commits
        );
    }
    // Each hit names the commit's instances and triangles.
    for (k, ray) in rays.iter().enumerate() {
        if occluded {
            assert!(out[k] <= 1);
            continue;
        }
        let h = hit_at(&out, k);
        if h.prim == NONE {
            assert!(
                h.t == f32::INFINITY && h.geometry == NONE && h.instance == NONE,
                "miss {h:?}"
            );
            continue;
        }
        let inst = snap
            .insts
            .get(h.instance as usize)
            .copied()
            .flatten()
            .unwrap_or_else(|| panic!("ray {k}: hit of a dead instance {h:?}"));
        let g = snap.geoms[inst.geometry as usize].as_ref().unwrap();
        assert!(
            h.geometry == inst.geometry && (h.prim as usize) < g.tris.len(),
            "ray {k}: {h:?}, instance places geometry {}",
            inst.geometry
        );
        assert!(
            mask & inst.mask != 0 && mask & g.mask != 0,
            "ray {k}: masked {h:?}"
        );
        assert!(
            h.t >= ray.tmin && h.t < ray.tmax,
            "ray {k}: t outside {h:?} {ray:?}"
        );
    }
    let visible: Vec<(u32, InstModel)> = snap
        .insts
        .iter()
        .enumerate()
        .filter_map(|(i, x)| x.map(|x| (i as u32, x)))
        .filter(|(_, x)| {
            let g = snap.geoms[x.geometry as usize].as_ref().unwrap();
            mask & x.mask != 0 && mask & g.mask != 0
        })
        .collect();
    let sane = !st.wild_scene
        && rays
            .iter()
            .all(|r| r.org.iter().chain(&r.dir).all(|&x| moderate(x)) && moderate(r.tmin))
        && visible
            .iter()
            .all(|(_, x)| x.moderate && snap.geoms[x.geometry as usize].as_ref().unwrap().moderate);
    if sane {
        // The same answer from the structure's reference method.
        let reference = match flat_method {
            Some(x) => Some(sheaf_trace_params {
                method: if x <= 1 { 0 } else { 7 },
                ..default_trace()
            }),
            None => None,
        };
        if params.is_some() || occluded {
            let want = run(st.ctx, reference.as_ref(), &rays, mask, flags, occluded)
                .expect("the reference scene trace fails");
            same_hits(&rays, &out, &want, occluded, &params);
        }
        // occluded <=> a nearest hit exists (the same structure).
        let other = run(st.ctx, params.as_ref(), &rays, mask, flags, !occluded)
            .expect("the scene trace fails the other way");
        let (near, occ) = if occluded {
            (&other, &out)
        } else {
            (&out, &other)
        };
        for (k, &o) in occ.iter().enumerate() {
            assert_eq!(
                o == 1,
                hit_at(near, k).prim != NONE,
                "ray {k} {:?}: occluded {o} but nearest {:?} ({params:?})",
                rays[k],
                hit_at(near, k)
            );
        }
        if !occluded && flags == 0 {
            oracle(&snap, &visible, &rays, &out, &params);
        }
    }
    st.scene.last = Some(SceneTrace {
        params,
        rays,
        mask,
        flags,
        occluded,
        out,
    });
}

/// Nearest hits equal bit for bit in t, u, v, triangle, geometry and
/// instance (or the same occlusion answers), as the header promises.
fn same_hits(
    rays: &[sheaf_ray],
    got: &[u8],
    want: &[u8],
    occluded: bool,
    p: &Option<sheaf_trace_params>,
) {
    for k in 0..rays.len() {
        if occluded {
            assert_eq!(got[k], want[k], "ray {k} {:?}: occluded, {p:?}", rays[k]);
            continue;
        }
        let (a, b) = (hit_at(got, k), hit_at(want, k));
        assert!(
            [a.t, a.u, a.v].map(f32::to_bits) == [b.t, b.u, b.v].map(f32::to_bits)
                && (a.prim, a.geometry, a.instance) == (b.prim, b.geometry, b.instance),
            "ray {k} {:?}: {p:?} gives {a:?}, its reference {b:?}",
            rays[k]
        );
    }
}

/// The nearest hits against the f64 oracle over the model's world
/// triangles, where every visible geometry is well shaped and rigidly
/// placed.
fn oracle(
    snap: &Snapshot,
    visible: &[(u32, InstModel)],
    rays: &[sheaf_ray],
    out: &[u8],
    p: &Option<sheaf_trace_params>,
) {
    if !visible
        .iter()
        .all(|(_, x)| x.rigid && snap.geoms[x.geometry as usize].as_ref().unwrap().oracle)
    {
        return;
    }
    let mut verts = Vec::new();
    let mut index = HashMap::new();
    for (i, x) in visible {
        let g = snap.geoms[x.geometry as usize].as_ref().unwrap();
        for (t, tri) in g.tris.iter().enumerate() {
            index.insert((*i, t as u32), (verts.len() / 9) as u32);
            verts.extend(tri.iter().flat_map(|&v| transform(&x.m, v)));
        }
    }
    if verts.is_empty() {
        return;
    }
    let idx: Vec<u32> = (0..(verts.len() / 3) as u32).collect();
    let world = Scene::from_f32(&verts, &idx).expect("the model's world triangles");
    for (k, r) in rays.iter().enumerate() {
        let ray = Ray::from(*r);
        let want = reference::nearest(&world, &ray);
        let h = hit_at(out, k);
        let prim = if h.prim == NONE {
            NONE
        } else {
            index[&(h.instance, h.prim)]
        };
        match reference::judge(&world, &ray, prim, h.t, want) {
            Verdict::Exact | Verdict::Tie | Verdict::Edge => {}
            v => panic!("ray {k} {r:?}: {p:?} gives {h:?} (world {prim}); the oracle {v:?}"),
        }
    }
}

fn flatten(
    st: &mut State,
    kind: u8,
    grid: &Option<GridIn>,
    kd: &Option<KdIn>,
    pgrid: &Option<PgridIn>,
    mask: u32,
) {
    let before = stats_of(st.ctx);
    let (s, bit, what) = match kind % 3 {
        0 => {
            let p = grid.as_ref().map(GridIn::get);
            let pp = p.as_ref().map_or(core::ptr::null(), |p| p);
            (
                ffi::sheaf_context_build_scene_grid(st.ctx, pp, mask),
                Limits::GRID,
                "build_scene_grid",
            )
        }
        1 => {
            let p = kd.as_ref().map(KdIn::get);
            let pp = p.as_ref().map_or(core::ptr::null(), |p| p);
            (
                ffi::sheaf_context_build_scene_kd(st.ctx, pp, mask),
                Limits::KD,
                "build_scene_kd",
            )
        }
        _ => {
            let p = pgrid.as_ref().map(PgridIn::get);
            let pp = p.as_ref().map_or(core::ptr::null(), |p| p);
            (
                ffi::sheaf_context_build_scene_pgrid(st.ctx, pp, mask),
                Limits::PGRID,
                "build_scene_pgrid",
            )
        }
    };
    let m = &mut st.scene;
    if s == OK {
        assert!(
            m.committed.is_some(),
            "{what} on a scene changed since its commit"
        );
        let key = (m.commits, mask);
        m.flat = Some(match m.flat {
            Some((c, fm, bits)) if (c, fm) == key => (c, fm, bits | bit),
            _ => (key.0, key.1, bit),
        });
        m.flat_rebuilt();
        // The flat structures the context traces are rebuilt too.
        st.trace = None;
        st.render = None;
    }
    scene_after(st, s, &before, what);
}

fn prim_of(st: &mut State, structure: N, prim: N, pixel: Option<(u8, u8)>) {
    let structure = small(structure, |v| {
        [Limits::GRID, Limits::KD, Limits::PGRID, 2][v as usize % 4]
    });
    let mut hit = sheaf_hit {
        t: 1.5,
        prim: prim.get(),
        u: 0.25,
        v: 0.5,
    };
    if let Some((x, y)) = pixel {
        let mut bits = 0u8;
        if ffi::sheaf_context_deferred_pixel(
            st.ctx,
            x as u32 % 8,
            y as u32 % 8,
            &mut hit,
            &mut bits,
        ) != OK
        {
            return;
        }
    }
    let mut out = sheaf_scene_hit {
        t: 9.0,
        u: 9.0,
        v: 9.0,
        prim: 9,
        geometry: 9,
        instance: 9,
    };
    let s = ffi::sheaf_context_scene_prim(st.ctx, structure, &hit, &mut out);
    valid_status(s, "scene_prim");
    if s != OK {
        assert_eq!(out.prim, 9, "a failed scene_prim wrote");
        return;
    }
    let m = &st.scene;
    assert!(
        m.flat
            .is_some_and(|(c, _, bits)| c == m.commits && bits & structure != 0)
            && m.committed.is_some(),
        "scene_prim of structure {structure} answered without its build"
    );
    if hit.prim == NONE {
        assert!(out.prim == NONE && out.instance == NONE && out.geometry == NONE);
        return;
    }
    assert!(
        out.t.to_bits() == hit.t.to_bits()
            && out.u.to_bits() == hit.u.to_bits()
            && out.v.to_bits() == hit.v.to_bits(),
        "scene_prim changed t, u, v: {hit:?} -> {out:?}"
    );
    let snap = m.committed.as_ref().unwrap();
    let inst = snap
        .insts
        .get(out.instance as usize)
        .copied()
        .flatten()
        .unwrap_or_else(|| panic!("scene_prim names a dead instance {out:?}"));
    let g = snap.geoms[inst.geometry as usize].as_ref().unwrap();
    assert!(
        out.geometry == inst.geometry && (out.prim as usize) < g.tris.len(),
        "scene_prim {out:?}"
    );
}

fn concurrent(
    st: &mut State,
    params: Option<sheaf_trace_params>,
    r: &RaysIn,
    instance: u32,
    xf: &XformIn,
) {
    let rays = make_rays(r);
    let m = &st.scene;
    let (Some(_), Some(Some(inst))) = (&m.committed, m.insts.get(instance as usize)) else {
        return;
    };
    let inst = *inst;
    let Ok(want0) = run(st.ctx, params.as_ref(), &rays, !0, 0, false) else {
        return;
    };
    let (xm, rigid) = xf.get();
    let ctx = st.ctx as usize;
    let (traces, edit) = std::thread::scope(|sc| {
        let ta = sc.spawn(|| {
            let ctx = ctx as *const sheaf_context;
            (0..4)
                .map(|_| run(ctx, params.as_ref(), &rays, !0, 0, false))
                .collect::<Vec<_>>()
        });
        let tb = sc.spawn(|| {
            let ctx = ctx as *mut sheaf_context;
            let a = ffi::sheaf_context_set_instance(
                ctx,
                instance,
                inst.geometry,
                xm.as_ptr(),
                inst.mask,
            );
            let b = ffi::sheaf_context_commit_scene(ctx, core::ptr::null_mut());
            (a, b)
        });
        (ta.join().unwrap(), tb.join().unwrap())
    });
    valid_status(edit.0, "concurrent set_instance");
    valid_status(edit.1, "concurrent commit");
    let busy = sheaf_status::ContextBusy;
    assert!(
        edit.0 == OK || edit.0 == busy || edit.0 == sheaf_status::InvalidArgument,
        "concurrent set_instance {:?}",
        edit.0
    );
    assert!(
        edit.1 == OK || edit.1 == busy,
        "concurrent commit {:?}",
        edit.1
    );
    if edit.0 == OK {
        st.scene.insts[instance as usize] = Some(InstModel {
            m: xm,
            rigid,
            moderate: xm.iter().all(|&x| moderate(x)),
            ..inst
        });
        st.scene.changed();
    }
    if edit.1 == OK {
        let m = &mut st.scene;
        m.commits += 1;
        m.committed = Some(Snapshot {
            geoms: m.geoms.clone(),
            insts: m.insts.clone(),
        });
        m.last = None;
    } else if edit.0 == OK {
        st.scene.changed();
    }
    let want1 = run(st.ctx, params.as_ref(), &rays, !0, 0, false);
    for t in &traces {
        match t {
            Ok(h) => assert!(
                *h == want0 || want1.as_ref() == Ok(h),
                "a scene trace racing an edit and commit gave other hits"
            ),
            Err(s) => assert!(
                matches!(s, sheaf_status::ContextBusy | sheaf_status::NotBuilt),
                "a scene trace racing an edit: {s:?}"
            ),
        }
    }
}
