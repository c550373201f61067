//! Test fixtures shared by the families' unit tests: ray sets over a
//! scene (camera, shadow and reflection rays, invalid lanes, random rays)
//! and their packets, the lattice scene, triangle soups, owned BVH pools.
//! The BVH single ray is the fixtures' reference tracer (shadow and
//! reflection rays start at its hits). The kd-tree's tests use these, not
//! the BVH's test modules.

use crate::accel::bvh::build::build;
use crate::accel::bvh::traverse_single;
use crate::accel::bvh::{Bvh, BvhNode, BvhParams, BvhPools, BvhView, PrimRef, RayKind};
use crate::counters::Counters;
use crate::geom::{Aabb, Hit, M4, ProjTri, Ray, Ray4, Scene, TriTest, TriVerts, TriangleTest};
use crate::render::{PrimaryRays, demorton};
use glam::Vec3;

/// Owned BVH pools.
pub struct Store {
    pub nodes: Vec<BvhNode>,
    pub tris: Vec<TriVerts>,
    pub proj: Vec<ProjTri>,
    pub ids: Vec<u32>,
    pub slot: Vec<u32>,
    pub refs: Vec<PrimRef>,
    pub scratch: Vec<u8>,
}

impl Store {
    /// Pools for `n` triangles (with projection data when `proj`).
    pub fn new(n: usize, proj: bool) -> Store {
        Store::with_refs(n, n, proj)
    }
    /// Pools for `n` triangles and `refs` references: `refs - n` of them
    /// the `High` build's spatial-split reserve.
    pub fn with_refs(n: usize, refs: usize, proj: bool) -> Store {
        Store {
            nodes: vec![BvhNode::default(); 2 * refs],
            tris: vec![TriVerts::default(); refs],
            proj: vec![ProjTri::default(); if proj { refs } else { 0 }],
            ids: vec![0; refs],
            slot: vec![0; n],
            refs: vec![PrimRef::default(); refs],
            scratch: vec![0; crate::accel::bvh::build::SCRATCH],
        }
    }
    pub fn bvh(&mut self) -> Bvh<'_> {
        Bvh::new(self.pools())
    }
    /// The pools themselves (a two-level scene's shared BVH pools).
    pub fn pools(&mut self) -> BvhPools<'_> {
        BvhPools {
            nodes: &mut self.nodes,
            tris: &mut self.tris,
            proj: &mut self.proj,
            tri_ids: &mut self.ids,
            slot_of: &mut self.slot,
            refs: &mut self.refs,
            scratch: &mut self.scratch,
        }
    }
}

/// Small triangles in the planes x = 1e-9 * 2.2^i: built with two bins
/// and leaf size 1, every plane can only peel off the farthest one, so
/// the tree would be 53 levels deep and MAX_DEPTH caps it with a forced
/// leaf. (Coordinates from 2e-9 to 7e9 keep the triangle tests and the
/// SAH areas far from overflow and underflow.)
pub fn deep_tris() -> Vec<[[f32; 3]; 3]> {
    (1..55)
        .map(|i| {
            let x = 1e-9 * 2.2f32.powi(i);
            let s = 0.01 * x;
            [[x, 0.0, 0.0], [x, s, 0.0], [x, 0.0, s]]
        })
        .collect()
}

/// A scene's buffers as packed f32 vertices and indices.
pub fn soup(tris: &[[[f32; 3]; 3]]) -> (Vec<f32>, Vec<u32>) {
    let v: Vec<f32> = tris
        .iter()
        .flat_map(|t| t.iter().flatten().copied())
        .collect();
    let ix: Vec<u32> = (0..3 * tris.len() as u32).collect();
    (v, ix)
}

/// A w x h "image" of rays (`None`: inactive lane) and the frustum
/// kinds to trace it with.
pub struct RaySet {
    pub name: &'static str,
    pub w: u32,
    pub h: u32,
    pub rays: Vec<Option<Ray>>,
    pub kinds: &'static [RayKind],
}

pub fn camera(v: &crate::scenes::View, w: u32, h: u32) -> PrimaryRays {
    let cam = crate::Camera {
        eye: v.eye.to_array(),
        look_at: v.look_at.to_array(),
        up: v.up.to_array(),
        fov_y_deg: v.fov_y_deg,
    };
    PrimaryRays::new(&cam, w, h).unwrap()
}

/// Primary rays of `view`; shadow rays from `light` to their lit hits
/// (as the renderer shoots them); reflection rays at their hits; the
/// primary rays with inactive and invalid lanes sprinkled in; random
/// rays with scattered origins and mixed direction signs.
pub fn ray_sets<T: TriangleTest>(
    b: &BvhView<'_>,
    view: &crate::scenes::View,
    light: Vec3,
    w: u32,
    h: u32,
    seed: u64,
) -> Vec<RaySet> {
    let pr = camera(view, w, h);
    let mut ctr = Counters::default();
    let bounds = if b.nodes.is_empty() {
        Aabb {
            min: Vec3::ZERO,
            max: Vec3::ONE,
        }
    } else {
        b.nodes[0].aabb()
    };
    let eps = 1e-4
        * bounds
            .min
            .abs()
            .max(bounds.max.abs())
            .max_element()
            .max(1e-6);
    let mut primary = Vec::new();
    let mut shadow = Vec::new();
    let mut reflect = Vec::new();
    for y in 0..h {
        for x in 0..w {
            let r = pr.ray(x, y);
            primary.push(Some(r));
            let hit = traverse_single::intersect::<T>(b, &r, &mut ctr);
            let (mut s, mut f) = (None, None);
            if let Some(tri) = b.triangle(hit.prim) {
                let d = Vec3::from(r.dir);
                let mut n = tri.normal().normalize_or_zero();
                if n.dot(d) > 0.0 {
                    n = -n;
                }
                let p = Vec3::from(r.org) + d * hit.t;
                if n.dot(light - p) > 0.0 {
                    let end = p + n * eps;
                    s = Some(Ray::new(light, end - light, 0.0, 1.0));
                }
                f = Some(Ray::new(
                    p + n * eps,
                    d - 2.0 * d.dot(n) * n,
                    0.0,
                    f32::INFINITY,
                ));
            }
            shadow.push(s);
            reflect.push(f);
        }
    }
    let mut rng = Rng(seed | 1);
    let mut mixed = primary.clone();
    for (i, r) in mixed.iter_mut().enumerate() {
        match rng.next() % 16 {
            0 => *r = None,
            1 => {
                let mut x = r.unwrap();
                x.dir = [f32::NAN, x.dir[1], x.dir[2]];
                *r = Some(x);
            }
            2 => *r = Some(Ray::new(Vec3::from(r.unwrap().org), Vec3::ZERO, 0.0, 1.0)),
            3 => {
                let mut x = r.unwrap();
                x.tmin = 2.0;
                x.tmax = 1.0;
                *r = Some(x);
            }
            4 => {
                // Bounded and late-starting rays.
                let mut x = r.unwrap();
                x.tmin = 0.3 * (i % 5) as f32;
                x.tmax = x.tmin + 0.7 * (1 + i % 3) as f32;
                *r = Some(x);
            }
            _ => {}
        }
    }
    let (c, d) = (0.5 * (bounds.min + bounds.max), bounds.diagonal());
    let mut random = Vec::new();
    for i in 0..(w * h) as usize {
        let o = c + Vec3::new(
            rng.range(-0.8, 0.8),
            rng.range(-0.8, 0.8),
            rng.range(-0.8, 0.8),
        ) * d;
        let mut dir = Vec3::new(
            rng.range(-1.0, 1.0),
            rng.range(-1.0, 1.0),
            rng.range(-1.0, 1.0),
        );
        if i % 9 == 0 {
            dir[(i / 9) % 3] = if i % 2 == 0 { 0.0 } else { -0.0 };
        }
        random.push(if i % 13 == 0 {
            None
        } else {
            Some(Ray::new(o, dir, 0.0, f32::INFINITY))
        });
    }
    // Coherent bundle from scattered origins (a general frustum that culls).
    let mut bundle = Vec::new();
    let axis = (view.look_at - view.eye).normalize();
    for _ in 0..(w * h) as usize {
        let o = view.eye
            + Vec3::new(
                rng.range(-0.05, 0.05),
                rng.range(-0.05, 0.05),
                rng.range(-0.05, 0.05),
            ) * d;
        let dir = axis
            + 0.2
                * Vec3::new(
                    rng.range(-1.0, 1.0),
                    rng.range(-1.0, 1.0),
                    rng.range(-1.0, 1.0),
                );
        bundle.push(Some(Ray::new(o, dir, 0.0, f32::INFINITY)));
    }
    use RayKind::*;
    vec![
        RaySet {
            name: "primary",
            w,
            h,
            rays: primary,
            kinds: &[Primary, Auto],
        },
        RaySet {
            name: "shadow",
            w,
            h,
            rays: shadow,
            kinds: &[Shadow, Auto],
        },
        RaySet {
            name: "reflect",
            w,
            h,
            rays: reflect,
            kinds: &[Secondary, Auto],
        },
        RaySet {
            name: "mixed",
            w,
            h,
            rays: mixed,
            kinds: &[Primary, Auto],
        },
        RaySet {
            name: "random",
            w,
            h,
            rays: random,
            kinds: &[Auto, Secondary],
        },
        RaySet {
            name: "bundle",
            w,
            h,
            rays: bundle,
            kinds: &[Secondary, Primary, Shadow],
        },
    ]
}

/// A packet: quads, active masks, the pixel of every lane.
pub type Packed = (Vec<Ray4>, Vec<M4>, Vec<[Option<usize>; 4]>);

/// Packets of side `n` over `set` (quads in Morton order per tile, as
/// `render::render_tiles` packs them), with the pixel of every lane.
pub fn packets(set: &RaySet, n: u32) -> Vec<Packed> {
    let q = ((n / 2) * (n / 2)) as usize;
    let lane_xy = [(0u32, 0u32), (1, 0), (0, 1), (1, 1)];
    let filler = Ray::new(Vec3::ZERO, Vec3::X, 0.0, 0.0);
    let mut out = Vec::new();
    for ty in (0..set.h).step_by(n as usize) {
        for tx in (0..set.w).step_by(n as usize) {
            let (mut quads, mut active, mut pix) = (Vec::new(), Vec::new(), Vec::new());
            for k in 0..q {
                let (qx, qy) = demorton(k);
                let mut lanes = [filler; 4];
                let mut m = [false; 4];
                let mut p = [None; 4];
                for (i, (dx, dy)) in lane_xy.iter().enumerate() {
                    let (x, y) = (tx + 2 * qx + dx, ty + 2 * qy + dy);
                    if x < set.w && y < set.h {
                        let at = (y * set.w + x) as usize;
                        p[i] = Some(at);
                        if let Some(r) = set.rays[at] {
                            lanes[i] = r;
                            m[i] = true;
                        }
                    }
                }
                quads.push(Ray4::from_rays(&lanes));
                active.push(M4::new(m[0], m[1], m[2], m[3]));
                pix.push(p);
            }
            out.push((quads, active, pix));
        }
    }
    out
}

pub fn same(a: &Hit, b: &Hit) -> bool {
    a.prim == b.prim
        && a.t.to_bits() == b.t.to_bits()
        && a.u.to_bits() == b.u.to_bits()
        && a.v.to_bits() == b.v.to_bits()
}

/// Build a BVH over `v`, `ix` with test `T` into `st`.
pub fn built<'s, T: TriangleTest>(
    st: &'s mut Store,
    v: &[f32],
    ix: &[u32],
    leaf: u32,
) -> crate::accel::bvh::Bvh<'s> {
    let scene = Scene::from_f32(v, ix).unwrap();
    *st = Store::new(
        scene.triangle_count() as usize,
        T::KIND == TriTest::Projection,
    );
    let mut bvh = st.bvh();
    let p = BvhParams {
        leaf_size: leaf,
        test: T::KIND,
        ..BvhParams::default()
    };
    build(&mut bvh, &scene, &p).unwrap();
    bvh
}

/// A lattice of unit squares in z = 0 (two triangles each, diagonals
/// alternating), a few raised triangles, and ray sets aimed exactly at
/// lattice points: frustum planes then pass through vertices and edges,
/// and watertight rays through shared vertices decide between
/// neighbours (the frustum must not cull the one a ray hits).
pub fn lattice() -> (Vec<f32>, Vec<u32>, Vec<RaySet>) {
    let m = 40i32;
    let mut tris: Vec<[[f32; 3]; 3]> = Vec::new();
    for y in 0..m {
        for x in 0..m {
            let (x0, y0, x1, y1) = (x as f32, y as f32, (x + 1) as f32, (y + 1) as f32);
            if (x + y) % 2 == 0 {
                tris.push([[x0, y0, 0.0], [x1, y0, 0.0], [x1, y1, 0.0]]);
                tris.push([[x0, y0, 0.0], [x1, y1, 0.0], [x0, y1, 0.0]]);
            } else {
                tris.push([[x0, y0, 0.0], [x1, y0, 0.0], [x0, y1, 0.0]]);
                tris.push([[x1, y0, 0.0], [x1, y1, 0.0], [x0, y1, 0.0]]);
            }
        }
    }
    for k in 0..30 {
        let (x, y) = ((k * 7 % m) as f32, (k * 11 % m) as f32);
        tris.push([[x, y, 2.0], [x + 3.0, y, 2.0], [x, y + 3.0, 1.0]]);
    }
    let (v, ix) = crate::accel::bvh::build::testutil::soup(&tris);
    let (w, h) = (64u32, 64u32);
    let eye = Vec3::new(20.0, 17.0, 30.0);
    let light = Vec3::new(-5.0, 50.0, 40.0);
    let mut rng = Rng(0x7777);
    let mut prim = Vec::new();
    let mut shadow = Vec::new();
    let mut general = Vec::new();
    for y in 0..h {
        for x in 0..w {
            // Pixel (x, y) -> lattice point (x - 12, 49 - y): a pinhole grid.
            let p = Vec3::new(x as f32 - 12.0, 49.0 - y as f32, 0.0);
            prim.push(Some(Ray::new(eye, p - eye, 0.0, f32::INFINITY)));
            shadow.push(Some(Ray::new(light, p - light, 0.0, 1.0)));
            let o = Vec3::new(
                rng.range(0.0, 40.0).floor(),
                rng.range(0.0, 40.0).floor(),
                8.0 + (x % 3) as f32,
            );
            let q = Vec3::new(o.x + (x % 5) as f32 - 2.0, o.y + (y % 5) as f32 - 2.0, 0.0);
            general.push(Some(Ray::new(o, q - o, 0.0, f32::INFINITY)));
        }
    }
    use RayKind::*;
    let sets = vec![
        RaySet {
            name: "lattice-primary",
            w,
            h,
            rays: prim,
            kinds: &[Primary, Auto],
        },
        RaySet {
            name: "lattice-shadow",
            w,
            h,
            rays: shadow,
            kinds: &[Shadow],
        },
        RaySet {
            name: "lattice-general",
            w,
            h,
            rays: general,
            kinds: &[Secondary],
        },
    ];
    (v, ix, sets)
}

/// Small deterministic generator (xorshift).
pub struct Rng(pub u64);
impl Rng {
    pub fn next(&mut self) -> u64 {
        self.0 ^= self.0 << 13;
        self.0 ^= self.0 >> 7;
        self.0 ^= self.0 << 17;
        self.0
    }
    pub fn f(&mut self) -> f32 {
        (self.next() >> 40) as f32 / (1u64 << 24) as f32
    }
    pub fn range(&mut self, lo: f32, hi: f32) -> f32 {
        lo + (hi - lo) * self.f()
    }
}

/// Test rays for a scene: camera rays of every view, random rays through
/// the bounds (some from inside), axis-parallel rays with zero direction
/// components, rays along triangle edges and through vertices, bounded
/// and shadow-like rays, and invalid rays.
pub fn test_rays(tris: &[[[f32; 3]; 3]], views: &[crate::scenes::View], seed: u64) -> Vec<Ray> {
    let mut rays = Vec::new();
    for v in views {
        let cam = crate::Camera {
            eye: v.eye.to_array(),
            look_at: v.look_at.to_array(),
            up: v.up.to_array(),
            fov_y_deg: v.fov_y_deg,
        };
        let pr = crate::render::PrimaryRays::new(&cam, 24, 24).unwrap();
        for y in 0..24 {
            for x in 0..24 {
                rays.push(pr.ray(x, y));
            }
        }
    }
    let mut bb = Aabb::EMPTY;
    for t in tris {
        for p in t {
            bb.grow(Vec3::from(*p));
        }
    }
    if bb.is_empty() {
        bb = Aabb {
            min: Vec3::ZERO,
            max: Vec3::ONE,
        };
    }
    let (c, d) = (0.5 * (bb.min + bb.max), bb.diagonal());
    let mut r = Rng(seed | 1);
    let pt =
        |r: &mut Rng, s: f32| c + Vec3::new(r.range(-s, s), r.range(-s, s), r.range(-s, s)) * d;
    for i in 0..1500 {
        let o = pt(&mut r, if i % 3 == 0 { 0.4 } else { 1.5 });
        let to = pt(&mut r, 0.4);
        let mut dir = to - o;
        if i % 5 == 0 {
            // Axis-parallel or in an axis plane: exact zero components.
            let keep = (r.next() % 3) as usize;
            for a in 0..3 {
                if a != keep && (i % 2 == 0 || a == (keep + 1) % 3) {
                    dir[a] = if r.next().is_multiple_of(2) {
                        0.0
                    } else {
                        -0.0
                    };
                }
            }
        }
        let tmax = if i % 7 == 0 {
            r.range(0.2, 1.2)
        } else {
            f32::INFINITY
        };
        let tmin = if i % 11 == 0 { r.range(0.0, 0.5) } else { 0.0 };
        rays.push(Ray::new(o, dir, tmin, tmax));
    }
    // Through vertices and along/through edges of triangles.
    for k in 0..300usize.min(tris.len() * 2) {
        let t = tris[(r.next() as usize) % tris.len()];
        let v = Vec3::from(t[k % 3]);
        let w = Vec3::from(t[(k + 1) % 3]);
        let target = if k % 2 == 0 { v } else { 0.5 * (v + w) };
        let o = pt(&mut r, 1.5);
        rays.push(Ray::new(o, target - o, 0.0, f32::INFINITY));
        // Shadow-like: stop exactly at the target.
        rays.push(Ray::new(o, target - o, 0.0, 1.0));
    }
    // Invalid rays.
    let o = c;
    rays.push(Ray::new(o, Vec3::ZERO, 0.0, f32::INFINITY));
    rays.push(Ray::new(
        o,
        Vec3::new(f32::NAN, 1.0, 0.0),
        0.0,
        f32::INFINITY,
    ));
    rays.push(Ray::new(
        Vec3::new(f32::INFINITY, 0.0, 0.0),
        Vec3::X,
        0.0,
        f32::INFINITY,
    ));
    rays.push(Ray::new(o, Vec3::X, -1.0, f32::INFINITY));
    rays.push(Ray::new(o, Vec3::X, 2.0, 1.0));
    rays.push(Ray::new(o, Vec3::X, f32::NAN, 1.0));
    rays
}

pub fn tris_of(scene: &Scene<'_>) -> Vec<[[f32; 3]; 3]> {
    (0..scene.triangle_count())
        .map(|t| scene.triangle(t))
        .map(|t| [t.v0, t.v1, t.v2])
        .collect()
}

/// A `Par` that runs every task on the calling thread, the workers in
/// reverse order (no part of a joined build may depend on another's having
/// run first).
pub struct Backwards(pub usize);

impl crate::mem::par::Par for Backwards {
    fn workers(&self) -> usize {
        self.0
    }
    fn run(&self, task: &(dyn Fn(usize) + Sync)) {
        (0..self.0).rev().for_each(task)
    }
}

/// An OBJ file as one mesh (vertices, indices), or `None` when it cannot
/// be read (the scene tests skip absent scenes).
pub fn load_obj(path: &std::path::Path) -> Option<(Vec<f32>, Vec<u32>)> {
    let opts = tobj::LoadOptions {
        triangulate: true,
        single_index: false,
        ..Default::default()
    };
    let (models, _) = tobj::load_obj(path, &opts).ok()?;
    let (mut v, mut ix) = (Vec::new(), Vec::new());
    for m in models {
        let base = (v.len() / 3) as u32;
        v.extend_from_slice(&m.mesh.positions);
        ix.extend(m.mesh.indices.iter().map(|i| i + base));
    }
    Some((v, ix))
}

/// `file` of `../shared/scenes` (`load_obj`).
pub fn shared_scene(file: &str) -> Option<(Vec<f32>, Vec<u32>)> {
    let dir = std::path::PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../shared/scenes");
    load_obj(&dir.join(file))
}
