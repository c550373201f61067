//! Per-frame builds of the perspective grid (section 3) and of a light's
//! spherical grid (section 4.1).
//!
//! Both builds follow the paper: every triangle emits one (cell, triangle)
//! pair per cell it spans into the pair pool, the pairs are radix sorted by
//! cell id (`mem::sort`), and a scan over the sorted keys gives each cell's
//! range. Cells are `tiles x depth slices`; for the camera a tile is a
//! square of pixels, for a light a rectangle of (a, b) space.
//!
//! When the pairs outgrow `Limits::max_pgrid_refs` the build keeps counting,
//! reports the number needed, and leaves that grid unbuilt (these grids
//! live for one frame: the render call that needed it fails).

use super::{
    CellsInfo, LightFrame, Pgrid, PgridParams, PgridPools, Pinhole, SceneInfo, Slices, tile_coord,
};
use crate::error::{Error, Pool, Result};
use crate::geom::{Aabb, ProjTri, Scene, TriTest, TriVerts};
use crate::math;
use crate::mem::par::{MAX_WORKERS, Par, Parts, share};
use crate::mem::sort::{bits_for, radix_sort_with};
use core::ops::Range;
use glam::Vec3;

/// Padding of projected bounds, in pixels (rounding of the projection is
/// about 1e-6 of the image width; this is far more).
const PIXEL_PAD: f32 = 0.05;
/// Padding of angular spans, in pseudo-angle units (rounding of the
/// pseudo-angle's division and dot products is about 1e-7).
const ANGLE_PAD: f32 = 1e-5;

/// Load `scene`'s triangles (and projection data when `params.test` needs
/// it) and remember `params` for the grids of the next frames.
pub fn load(g: &mut Pgrid<'_>, scene: &Scene<'_>, params: &PgridParams) -> Result<SceneInfo> {
    params.validate()?;
    let n = scene.triangle_count() as usize;
    if n > g.pools.tris.len() {
        return Err(Error::Capacity {
            pool: Pool::Triangles,
            needed: n as u64,
            available: g.pools.tris.len() as u64,
        });
    }
    let proj = params.test == TriTest::Projection;
    if proj && g.pools.proj.len() < n {
        return Err(Error::InvalidArgument(
            "the projection test needs Limits::projection_test",
        ));
    }
    let mut info = SceneInfo {
        triangles: n as u32,
        excluded: 0,
        bounds: Aabb::EMPTY,
        params: Some(*params),
    };
    for i in 0..n {
        let t = scene.triangle(i as u32);
        let ok = Scene::classify(&t).is_none();
        g.pools.tris[i] = t;
        g.pools.ok[i] = ok as u8;
        if ok {
            for v in [t.v0, t.v1, t.v2] {
                info.bounds.grow(Vec3::from(v));
            }
            if proj {
                g.pools.proj[i] = ProjTri::new(&t);
            }
        } else {
            info.excluded += 1;
        }
    }
    crate::fault_point!(PgridLoad);
    g.scene = info;
    g.cam_built = false;
    g.light_built = false;
    Ok(info)
}

/// Inclusive cell box of one triangle: tiles x0..=x1, y0..=y1, slices
/// s0..=s1.
#[derive(Clone, Copy, Debug)]
struct CellBox {
    x: [u32; 2],
    y: [u32; 2],
    s: [u32; 2],
}

/// Emits pairs into the pools, counting past the capacity.
struct Pairs<'p> {
    keys: &'p mut [u32],
    vals: &'p mut [u32],
    n: u64,
}

impl Pairs<'_> {
    #[inline]
    fn emit(&mut self, b: &CellBox, tiles_x: u32, slices: u32, tri: u32) {
        for ty in b.y[0]..=b.y[1] {
            for tx in b.x[0]..=b.x[1] {
                let base = (ty * tiles_x + tx) * slices;
                for s in b.s[0]..=b.s[1] {
                    let i = self.n as usize;
                    if i < self.keys.len() {
                        self.keys[i] = base + s;
                        self.vals[i] = tri;
                    }
                    self.n += 1;
                }
            }
        }
    }
}

impl Pairs<'_> {
    /// `emit`, skipping tiles without rays and slices beyond their rays'
    /// reach; whether any pair was emitted.
    #[inline]
    fn emit_reached(
        &mut self,
        b: &CellBox,
        tiles_x: u32,
        slices: u32,
        tri: u32,
        reach: &[u32],
    ) -> bool {
        let before = self.n;
        for ty in b.y[0]..=b.y[1] {
            for tx in b.x[0]..=b.x[1] {
                let tile = ty * tiles_x + tx;
                let end = reach[tile as usize].min(b.s[1] + 1);
                let base = tile * slices;
                for s in b.s[0]..end {
                    let i = self.n as usize;
                    if i < self.keys.len() {
                        self.keys[i] = base + s;
                        self.vals[i] = tri;
                    }
                    self.n += 1;
                }
            }
        }
        self.n > before
    }
}

/// What one triangle gave the pair emission.
enum Mapped {
    /// Not in the grid (outside it, or no ray reaches its cells).
    Skip,
    /// Facing away from the camera (culled).
    Backface,
    /// Pairs emitted; its padded bounds for `PgridPools::px_box`.
    Cells([f32; 4]),
}

/// Pairs and triangles of one grid build (per worker, then summed).
#[derive(Clone, Copy, Default)]
struct Emitted {
    pairs: u64,
    mapped: u32,
    backfaces: u32,
}

/// Emit the pairs of every traceable triangle with `map`, sort them by cell
/// and scan them into the start pool, on `par`'s workers: the camera
/// grid's pools, or the light grid's when `light`.
///
/// Each worker maps an even share of the triangles into its own region of
/// the pair pool (counting past it); the sort's first pass gathers the
/// regions in worker order, so the pairs come out as one thread emits them
/// (triangle order within a cell) for any worker count. When a region
/// overflows while the pool would hold every pair, the workers map their
/// triangles again into regions cut at the counts of the first round.
fn emit_sorted<F>(
    p: &mut PgridPools<'_>,
    n: usize,
    cells: u32,
    light: bool,
    par: &dyn Par,
    map: &F,
) -> Result<Emitted>
where
    // Generic, not `dyn`: inlined into the per-triangle loop.
    F: Fn(u32, &TriVerts, &mut Pairs<'_>) -> Mapped + Sync,
{
    let workers = par.workers();
    let PgridPools {
        tris,
        ok,
        px_box,
        keys,
        cam_tris,
        light_tris,
        cam_start,
        light_start,
        tmp_keys,
        tmp_vals,
        counts,
        ..
    } = p;
    let (vals, start) = if light {
        (light_tris, light_start)
    } else {
        (cam_tris, cam_start)
    };
    let cap = vals.len().min(keys.len());
    let (tris, ok) = (&**tris, &**ok);
    let mut bounds = [cap; MAX_WORKERS + 1];
    for (w, b) in bounds.iter_mut().enumerate().take(workers) {
        *b = share(cap, w, workers).start;
    }
    let mut got = [Emitted::default(); MAX_WORKERS];
    for round in 0..2 {
        {
            let b = &bounds[..workers + 1];
            let (ks, vs) = (
                Parts::at(&mut keys[..cap], b),
                Parts::at(&mut vals[..cap], b),
            );
            let bs = Parts::even(&mut px_box[..n], workers);
            let out = Parts::even(&mut got[..workers], workers);
            par.run(&|w| {
                let mut pairs = Pairs {
                    keys: ks.get(w),
                    vals: vs.get(w),
                    n: 0,
                };
                let (first, mut e) = (bs.start(w), Emitted::default());
                for (k, px) in bs.get(w).iter_mut().enumerate() {
                    let i = first + k;
                    if ok[i] == 0 {
                        continue;
                    }
                    match map(i as u32, &tris[i], &mut pairs) {
                        Mapped::Skip => {}
                        Mapped::Backface => e.backfaces += 1,
                        Mapped::Cells(b) => {
                            *px = b;
                            e.mapped += 1;
                        }
                    }
                }
                e.pairs = pairs.n;
                out.get(w)[0] = e;
            });
        }
        let needed: u64 = got[..workers].iter().map(|e| e.pairs).sum();
        if needed > vals.len() as u64 {
            // The pairs outgrow the pool: report how many it would need.
            return Err(Error::Capacity {
                pool: Pool::PgridRefs,
                needed,
                available: vals.len() as u64,
            });
        }
        let fits = (0..workers).all(|w| got[w].pairs <= (bounds[w + 1] - bounds[w]) as u64);
        if fits {
            break;
        }
        debug_assert_eq!(round, 0, "regions cut at the counts hold the pairs");
        for w in 0..workers {
            bounds[w + 1] = bounds[w] + got[w].pairs as usize;
        }
    }
    let parts: [Range<usize>; MAX_WORKERS] =
        core::array::from_fn(|w| bounds[w]..bounds[w] + got[w].pairs as usize);
    let m = radix_sort_with(
        keys,
        vals,
        tmp_keys,
        tmp_vals,
        &parts[..workers],
        bits_for(cells),
        counts,
        par,
    );
    // start[c]: the first pair of cell c or above. Keys are sorted, so the
    // cells passed in each worker's share of the pairs are one run of the
    // start pool: worker w fills cells keys[s_w - 1] + 1 ..= keys[e_w - 1]
    // (the last worker also the cells after the last key).
    let (keys, start) = (&keys[..m], &mut start[..cells as usize + 1]);
    let mut cut = [start.len(); MAX_WORKERS + 1];
    for (w, c) in cut.iter_mut().enumerate().take(workers) {
        let s_w = share(m, w, workers).start;
        *c = if s_w == 0 {
            0
        } else {
            keys[s_w - 1] as usize + 1
        };
    }
    let runs = Parts::at(start, &cut[..workers + 1]);
    par.run(&|w| {
        let (run, base) = (runs.get(w), runs.start(w));
        let mut at = 0;
        for i in share(m, w, workers) {
            let end = keys[i] as usize + 1 - base;
            run[at..end].fill(i as u32);
            at = end;
        }
        if w == workers - 1 {
            run[at..].fill(m as u32);
        }
    });
    let mut all = Emitted::default();
    for e in &got[..workers] {
        all.pairs += e.pairs;
        all.mapped += e.mapped;
        all.backfaces += e.backfaces;
    }
    Ok(all)
}

fn check_cells(cells: u64, available: usize) -> Result<()> {
    if cells + 1 > available as u64 {
        return Err(Error::Capacity {
            pool: Pool::PgridCells,
            needed: cells,
            available: available.saturating_sub(1) as u64,
        });
    }
    Ok(())
}

/// Build the perspective grid of camera `cam` (section 3): tiles of
/// `params.tile` pixels, `params.slices` depth slices between the scene's
/// nearest and farthest depth.
pub fn build_camera(g: &mut Pgrid<'_>, cam: &Pinhole, par: &dyn Par) -> Result<CellsInfo> {
    crate::mem::par::workers_of(par)?;
    let params = g.scene.params.ok_or(Error::NotBuilt)?;
    g.cam_built = false;
    let t = params.tile;
    let tiles = [cam.width.div_ceil(t), cam.height.div_ceil(t)];
    let cells = tiles[0] as u64 * tiles[1] as u64 * params.slices as u64;
    check_cells(cells, g.pools.cam_start.len())?;
    // Depth range: the scene box's corners.
    let b = g.scene.bounds;
    let (mut near, mut far) = (f32::INFINITY, 0.0f32);
    if !b.is_empty() {
        for i in 0..8 {
            let c = Vec3::new(
                if i & 1 == 0 { b.min.x } else { b.max.x },
                if i & 2 == 0 { b.min.y } else { b.max.y },
                if i & 4 == 0 { b.min.z } else { b.max.z },
            );
            let z = (c - cam.eye).dot(cam.fwd);
            near = near.min(z);
            far = far.max(z);
        }
    }
    let depth = Slices::new(near, far, params.slices, super::DEPTH_PAD);
    let mut info = CellsInfo {
        tiles,
        depth,
        ..CellsInfo::default()
    };
    // Geometry closer than z_eps is not projected: a triangle reaching
    // there within tip_r of the eye is put in every tile of slice 0.
    let z_eps = b.diagonal().length().max(far).max(1e-30) * 1e-6;
    let tip_r = z_eps * math::sqrt(1.0 + cam.half_w * cam.half_w + cam.half_h * cam.half_h) * 2.0;
    let pad = PIXEL_PAD + 1e-5 * cam.width.max(cam.height) as f32;
    let inv_t = 1.0 / t as f32;
    let cm = CameraMap {
        cam,
        depth: &depth,
        tiles,
        inv_t,
        pad,
        z_eps,
        tip_r,
    };
    let n = g.scene.triangles as usize;
    let (cull, slices) = (params.cull_backfaces, params.slices);
    let map = |i: u32, tri: &TriVerts, pairs: &mut Pairs<'_>| {
        if cull {
            let v0 = Vec3::from(tri.v0);
            let nrm = (Vec3::from(tri.v1) - v0).cross(Vec3::from(tri.v2) - v0);
            if nrm.dot(v0 - cam.eye) > 0.0 {
                return Mapped::Backface;
            }
        }
        match cm.camera_box(tri) {
            Some((cb, pb)) => {
                pairs.emit(&cb, tiles[0], slices, i);
                Mapped::Cells(pb)
            }
            None => Mapped::Skip,
        }
    };
    let e = emit_sorted(&mut g.pools, n, cells as u32, false, par, &map)?;
    let needed = e.pairs;
    info.mapped = e.mapped;
    info.backfaces = e.backfaces;
    info.refs = needed as u32;
    g.cam = info;
    g.pinhole = *cam;
    crate::fault_point!(PgridCamera);
    g.cam_built = true;
    Ok(info)
}

/// How one camera-grid build maps triangles to cells: the camera, its depth
/// slices and tiles (`inv_t`: tiles per pixel), the pixel padding, and the
/// near-eye limits (`z_eps`, `tip_r`) of `build_camera`.
struct CameraMap<'a> {
    cam: &'a Pinhole,
    depth: &'a Slices,
    tiles: [u32; 2],
    inv_t: f32,
    pad: f32,
    z_eps: f32,
    tip_r: f32,
}

impl CameraMap<'_> {
    /// Cells of one triangle in the camera grid, `None` when it cannot be
    /// seen.
    fn camera_box(&self, tri: &TriVerts) -> Option<(CellBox, [f32; 4])> {
        let CameraMap {
            cam,
            depth,
            tiles,
            inv_t,
            pad,
            z_eps,
            tip_r,
        } = *self;
        let q = [
            Vec3::from(tri.v0) - cam.eye,
            Vec3::from(tri.v1) - cam.eye,
            Vec3::from(tri.v2) - cam.eye,
        ];
        let z = [q[0].dot(cam.fwd), q[1].dot(cam.fwd), q[2].dot(cam.fwd)];
        // Near the eye (camera rays start there, t >= 0, so a triangle through
        // the eye is hit at t = 0 whatever its depths): every tile, slice 0 on.
        let tip = z.iter().any(|&z| z < z_eps) && closest_distance(Vec3::ZERO, &q) <= tip_r;
        if !tip && z.iter().all(|&z| z <= 0.0) {
            return None; // behind the eye: camera rays have depth > 0
        }
        // Clip against depth >= z_eps (Sutherland-Hodgman, at most 4 points).
        let mut poly = [Vec3::ZERO; 4];
        let mut pz = [0.0f32; 4];
        let mut m = 0;
        for k in 0..3 {
            let (a, b) = (k, (k + 1) % 3);
            if z[a] >= z_eps {
                poly[m] = q[a];
                pz[m] = z[a];
                m += 1;
            }
            if (z[a] >= z_eps) != (z[b] >= z_eps) {
                let s = (z_eps - z[a]) / (z[b] - z[a]);
                poly[m] = q[a] + (q[b] - q[a]) * s;
                pz[m] = z_eps;
                m += 1;
            }
        }
        let mut xr = [f32::INFINITY, f32::NEG_INFINITY];
        let mut yr = xr;
        let mut zr = xr;
        for k in 0..m {
            let (x, y) = cam.pixel(poly[k], pz[k]);
            xr = [xr[0].min(x), xr[1].max(x)];
            yr = [yr[0].min(y), yr[1].max(y)];
            zr = [zr[0].min(pz[k]), zr[1].max(pz[k])];
        }
        if tip {
            let top = zr[1].max(z_eps);
            let all = [
                f32::NEG_INFINITY,
                f32::NEG_INFINITY,
                f32::INFINITY,
                f32::INFINITY,
            ];
            return Some((
                CellBox {
                    x: [0, tiles[0] - 1],
                    y: [0, tiles[1] - 1],
                    s: [0, depth.hi(top)],
                },
                all,
            ));
        }
        if m == 0
            || xr[1] + pad < 0.0
            || yr[1] + pad < 0.0
            || xr[0] - pad > cam.width as f32
            || yr[0] - pad > cam.height as f32
        {
            return None;
        }
        Some((
            CellBox {
                x: [
                    tile_coord((xr[0] - pad) * inv_t, tiles[0]),
                    tile_coord((xr[1] + pad) * inv_t, tiles[0]),
                ],
                y: [
                    tile_coord((yr[0] - pad) * inv_t, tiles[1]),
                    tile_coord((yr[1] + pad) * inv_t, tiles[1]),
                ],
                s: [depth.lo(zr[0]), depth.hi(zr[1])],
            },
            [xr[0] - pad, yr[0] - pad, xr[1] + pad, yr[1] + pad],
        ))
    }
}

/// Build the grid of light `frame` (section 4.1): its (a, b) rectangle in
/// `frame.tiles`, `slices` distance slices between `near` and `far` (the
/// shadow rays' lengths). Triangles outside the rectangle or beyond `far`
/// cannot block any of this frame's shadow rays and are left out; so are
/// cells no ray reaches: `reach[tile]` is 0 for a tile without rays, else
/// one more than the last slice its rays reach (`Slices::hi` of their
/// lengths), and a tile's pairs stop there.
pub fn build_light(
    g: &mut Pgrid<'_>,
    frame: &LightFrame,
    near: f32,
    far: f32,
    slices: u32,
    reach: &[u32],
    par: &dyn Par,
) -> Result<CellsInfo> {
    crate::mem::par::workers_of(par)?;
    g.scene.params.ok_or(Error::NotBuilt)?;
    g.light_built = false;
    // The triangle bounds pool now holds (a, b) bounds: the camera grid's
    // pixel bounds are gone.
    g.cam_built = false;
    let tiles = frame.tiles;
    let cells = tiles[0] as u64 * tiles[1] as u64 * slices as u64;
    check_cells(cells, g.pools.light_start.len())?;
    let depth = Slices::new(near, far, slices, super::LIGHT_DEPTH_PAD);
    let mut info = CellsInfo {
        tiles,
        depth,
        ..CellsInfo::default()
    };
    let scale = g.scene.bounds.diagonal().length().max(far).max(1e-30);
    let far_reach = far * (1.0 + 2.0 * depth.pad) + depth.z0 * depth.pad;
    let a1 = frame.a0 + tiles[0] as f32 / frame.inv_da;
    let b1 = frame.b0 + tiles[1] as f32 / frame.inv_db;
    let n = g.scene.triangles as usize;
    let map = |i: u32, tri: &TriVerts, pairs: &mut Pairs<'_>| {
        let q = [
            Vec3::from(tri.v0) - frame.pos,
            Vec3::from(tri.v1) - frame.pos,
            Vec3::from(tri.v2) - frame.pos,
        ];
        let z = [
            q[0].dot(frame.fwd),
            q[1].dot(frame.fwd),
            q[2].dot(frame.fwd),
        ];
        let x = [
            q[0].dot(frame.right),
            q[1].dot(frame.right),
            q[2].dot(frame.right),
        ];
        let y = [q[0].dot(frame.up), q[1].dot(frame.up), q[2].dot(frame.up)];
        let eps = scale * 1e-6;
        let (alo, ahi) = angle_span(x, z, eps);
        if ahi < frame.a0 || alo > a1 {
            return Mapped::Skip;
        }
        let (blo, bhi) = angle_span(y, z, eps);
        if bhi < frame.b0 || blo > b1 {
            return Mapped::Skip;
        }
        let dmin = closest_distance(Vec3::ZERO, &q);
        if dmin > far_reach {
            return Mapped::Skip;
        }
        let dmax = q[0].length().max(q[1].length()).max(q[2].length());
        let cb = CellBox {
            x: [
                tile_coord((alo - frame.a0) * frame.inv_da, tiles[0]),
                tile_coord((ahi - frame.a0) * frame.inv_da, tiles[0]),
            ],
            y: [
                tile_coord((blo - frame.b0) * frame.inv_db, tiles[1]),
                tile_coord((bhi - frame.b0) * frame.inv_db, tiles[1]),
            ],
            s: [depth.lo(dmin), depth.hi(dmax)],
        };
        if pairs.emit_reached(&cb, tiles[0], slices, i, reach) {
            Mapped::Cells([alo, blo, ahi, bhi])
        } else {
            Mapped::Skip
        }
    };
    let e = emit_sorted(&mut g.pools, n, cells as u32, true, par, &map)?;
    let needed = e.pairs;
    info.mapped = e.mapped;
    info.refs = needed as u32;
    g.light = info;
    g.light_frame = *frame;
    g.light_built = true;
    Ok(info)
}

/// Padded range of `pseudo_angle(x, z)` over the triangle whose
/// projection onto the (x, z) plane has these vertices: the arc between the
/// two vertices that bound the third when all three fit in an open half
/// plane through the origin (then every point of the triangle is inside
/// the arc, the cone of a convex set), else the whole circle `[-2, 2]`.
/// Arcs across the cut at +-2, and vertices within `eps` of the axis, also
/// give the whole circle.
pub fn angle_span(x: [f32; 3], z: [f32; 3], eps: f32) -> (f32, f32) {
    const FULL: (f32, f32) = (-2.0, 2.0);
    for k in 0..3 {
        if x[k] * x[k] + z[k] * z[k] <= eps * eps {
            return FULL;
        }
    }
    // cross(i, j) > 0: j lies counter-clockwise of i (growing angle).
    let cross = |i: usize, j: usize| z[i] * x[j] - x[i] * z[j];
    for i in 0..3 {
        for j in 0..3 {
            if i == j {
                continue; // (3 - i - j would underflow for i = j = 2)
            }
            let k = 3 - i - j;
            if cross(i, j) <= 0.0 || cross(i, k) < 0.0 || cross(k, j) < 0.0 {
                continue;
            }
            let lo = super::pseudo_angle(x[i], z[i]) - ANGLE_PAD;
            let hi = super::pseudo_angle(x[j], z[j]) + ANGLE_PAD;
            if lo < -2.0 + ANGLE_PAD || hi > 2.0 - ANGLE_PAD || lo > hi {
                return FULL;
            }
            return (lo, hi);
        }
    }
    FULL
}

/// Distance from `p` to the triangle `q` (Ericson, Real-Time Collision
/// Detection, 5.1.5: the closest point by Voronoi regions).
pub fn closest_distance(p: Vec3, q: &[Vec3; 3]) -> f32 {
    let (a, b, c) = (q[0], q[1], q[2]);
    let ab = b - a;
    let ac = c - a;
    let ap = p - a;
    let d1 = ab.dot(ap);
    let d2 = ac.dot(ap);
    if d1 <= 0.0 && d2 <= 0.0 {
        return ap.length();
    }
    let bp = p - b;
    let d3 = ab.dot(bp);
    let d4 = ac.dot(bp);
    if d3 >= 0.0 && d4 <= d3 {
        return bp.length();
    }
    let vc = d1 * d4 - d3 * d2;
    if vc <= 0.0 && d1 >= 0.0 && d3 <= 0.0 {
        let v = d1 / (d1 - d3);
        return (p - (a + ab * v)).length();
    }
    let cp = p - c;
    let d5 = ab.dot(cp);
    let d6 = ac.dot(cp);
    if d6 >= 0.0 && d5 <= d6 {
        return cp.length();
    }
    let vb = d5 * d2 - d1 * d6;
    if vb <= 0.0 && d2 >= 0.0 && d6 <= 0.0 {
        let w = d2 / (d2 - d6);
        return (p - (a + ac * w)).length();
    }
    let va = d3 * d6 - d5 * d4;
    if va <= 0.0 && (d4 - d3) >= 0.0 && (d5 - d6) >= 0.0 {
        let w = (d4 - d3) / ((d4 - d3) + (d5 - d6));
        return (p - (b + (c - b) * w)).length();
    }
    let denom = 1.0 / (va + vb + vc);
    let v = vb * denom;
    let w = vc * denom;
    let d = (p - (a + ab * v + ac * w)).length();
    // Rounding near the plane can overshoot; never report more than the
    // nearest vertex, and give the closest point a relative margin.
    d.min(ap.length()).min(bp.length()).min(cp.length()) * (1.0 - 1e-4)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn angle_span_of_a_triangle_ahead_and_across_the_cut() {
        let (lo, hi) = angle_span([-1.0, 1.0, 0.0], [1.0, 1.0, 2.0], 1e-9);
        assert!(
            (lo + 0.5).abs() < 1e-4 && (hi - 0.5).abs() < 1e-4,
            "{lo} {hi}"
        );
        // The vertex order does not matter.
        assert_eq!(
            angle_span([0.0, 1.0, -1.0], [2.0, 1.0, 1.0], 1e-9),
            (lo, hi)
        );
        // Behind the light, straddling the cut: the whole circle.
        assert_eq!(
            angle_span([-1.0, 1.0, 0.0], [-1.0, -1.0, -2.0], 1e-9),
            (-2.0, 2.0)
        );
        // Around the origin: the whole circle.
        assert_eq!(
            angle_span([-1.0, 1.0, 0.0], [-1.0, -1.0, 2.0], 1e-9),
            (-2.0, 2.0)
        );
        // Beside the light (to +x, behind and ahead): an arc through +1.
        let (lo, hi) = angle_span([1.0, 1.0, 2.0], [1.0, -1.0, 0.0], 1e-9);
        assert!(lo < 0.5 && hi > 1.5 && hi < 2.0, "{lo} {hi}");
    }

    #[test]
    fn pseudo_angle_is_monotone_in_the_angle() {
        let mut last = -3.0;
        // Strictly between the cut at -pi and pi (sin(+-pi) rounds to +-8.7e-8).
        for i in 1..4000 {
            let a = -core::f32::consts::PI + i as f32 * (2.0 * core::f32::consts::PI / 4000.0);
            let p = super::super::pseudo_angle(math::sin(a), math::cos(a));
            assert!(p >= last - 1e-6, "{a}: {p} < {last}");
            last = p;
        }
    }

    #[test]
    fn closest_distance_matches_sampling() {
        let q = [
            Vec3::new(1.0, 0.0, 0.0),
            Vec3::new(0.0, 2.0, 0.5),
            Vec3::new(-1.0, -1.0, 1.0),
        ];
        for p in [
            Vec3::ZERO,
            Vec3::new(3.0, 1.0, -2.0),
            Vec3::new(0.0, 0.2, 5.0),
            Vec3::new(-4.0, 0.0, 0.0),
        ] {
            let d = closest_distance(p, &q);
            let mut best = f32::INFINITY;
            for i in 0..=200 {
                for j in 0..=(200 - i) {
                    let (u, v) = (i as f32 / 200.0, j as f32 / 200.0);
                    let x = q[0] + (q[1] - q[0]) * u + (q[2] - q[0]) * v;
                    best = best.min((x - p).length());
                }
            }
            assert!(d <= best + 1e-5 && d >= best - 0.05, "{p}: {d} vs {best}");
        }
    }
}
