//! Perspective grids and spherical light grids are exact (perspective/light
//! grid paper sections 3-4, and the exactness argument of `accel::pgrid`):
//! in deferred frames (`Context::render_deferred`)
//! - every camera ray traced through the perspective grid returns the same
//!   triangle and bitwise the same t as the BVH single ray with the same
//!   triangle test, on every scene and view, for every triangle test and
//!   several tile, group and slice settings, with partial edge tiles;
//! - every shadow bit a light grid sets equals single-ray BVH occlusion of
//!   the very shadow ray the frame traced (`deferred_shadow_ray`), for
//!   lights inside, outside, on the bounds, on a surface, between objects,
//!   behind the model, a spot, up to 8 lights at once, and several chunk
//!   sizes and light tile counts;
//! - degenerate frames (one light tile, tiny images, no hit, no shadow ray)
//!   stay exact and report what they did;
//! - every mix of grid and traced passes gives the image `render` gives;
//! - bad input is rejected with the documented error, and the next frame
//!   works.

use crate::common;

use common::{TestScene, builtin_scenes, obj_scenes, par_map};
use glam::Vec3;
use sheaf::accel::bvh::BvhParams;
use sheaf::scenes::View;
use sheaf::{
    Camera, DeferredInfo, DeferredJob, Error, Frame, GridParams, Hit, Isa, Limits, Method,
    OnCaller, OwnedContext, PgridParams, PointLight, PrimaryPass, Ray, Shading, ShadowPass,
    TraceParams, TriTest,
};

/// Image sizes: no side a multiple of 16 (edge tiles are partial), odd
/// heights (edge 2x2 quads are partial).
const BUILTIN_WH: (u32, u32) = (94, 71);
const OBJ_WH: (u32, u32) = (158, 117);

const TESTS: [TriTest; 3] = [
    TriTest::MollerTrumbore,
    TriTest::Watertight,
    TriTest::Projection,
];

/// A context for `s` with pools for `structures` and the perspective grids,
/// images up to `wh`, and the projection test.
fn context(s: &TestScene, wh: (u32, u32), structures: u32) -> OwnedContext {
    let mut l = Limits::for_triangles(s.triangles());
    l.max_vertices = (s.vertices.len() / 3) as u32;
    l.structures = structures | Limits::PGRID;
    l.projection_test = true;
    l.max_image_width = wh.0;
    l.max_image_height = wh.1;
    // Room for lights on a surface: the triangles touching the light span
    // every light tile.
    l.max_pgrid_refs = 8 * s.triangles() + (1 << 21);
    OwnedContext::new(&l).unwrap()
}

fn camera(v: &View) -> Camera {
    Camera {
        eye: v.eye.to_array(),
        look_at: v.look_at.to_array(),
        up: v.up.to_array(),
        fov_y_deg: v.fov_y_deg,
    }
}

fn frame(v: &View, light: Vec3, wh: (u32, u32), shadows: bool) -> Frame {
    Frame {
        camera: camera(v),
        light: PointLight::new(light.to_array(), [0.9, 0.8, 0.7]),
        shading: Shading {
            shadows,
            ..Shading::default()
        },
        width: wh.0,
        height: wh.1,
    }
}

/// The lane widths a configuration is checked at: the CPU's own, and with
/// `extra` every other level (`sheaf::isa`; run in baseline code where the
/// CPU lacks them).
fn levels(extra: bool) -> Vec<Isa> {
    sheaf::isa::set_emulation(true);
    let mut v = vec![Isa::Auto];
    if extra {
        let own = sheaf::isa::effective(Isa::Auto);
        v.extend(
            [Isa::Sse2, Isa::Avx2, Isa::Avx512]
                .into_iter()
                .filter(|&i| i != own),
        );
    }
    v
}

fn pgrid_params(test: TriTest) -> PgridParams {
    PgridParams {
        test,
        ..PgridParams::default()
    }
}

fn build_bvh(ctx: &mut OwnedContext, s: &TestScene, test: TriTest) {
    ctx.build_bvh(
        &s.scene(),
        &BvhParams {
            test,
            ..BvhParams::default()
        },
    )
    .unwrap();
}

/// One deferred frame into a fresh RGBA8 image.
fn deferred(
    ctx: &mut OwnedContext,
    f: &Frame,
    lights: &[PointLight],
    primary: PrimaryPass,
    shadow: ShadowPass,
) -> sheaf::Result<(DeferredInfo, Vec<u8>)> {
    // A stride wider than the row, whose padding must stay untouched.
    let stride = f.width as usize * 4 + 8;
    let mut px = vec![0xa5u8; stride * f.height as usize];
    let info = ctx.render_deferred(
        &DeferredJob {
            frame: f,
            lights,
            primary,
            shadow,
        },
        &mut px,
        stride,
        &mut OnCaller,
    )?;
    let row = f.width as usize * 4;
    assert!(
        px.chunks(stride)
            .all(|r| r[row..].iter().all(|&b| b == 0xa5)),
        "render_deferred wrote past the row into the stride's padding"
    );
    Ok((info, pack(&px, f, stride)))
}

/// The image with `render` (one ray at a time with `method`).
fn rendered(ctx: &mut OwnedContext, f: &Frame, method: Method) -> Vec<u8> {
    let stride = f.width as usize * 4;
    let mut px = vec![0u8; stride * f.height as usize];
    ctx.render(method, f, &mut px, stride).unwrap();
    px
}

/// Rows of `px` without the stride's padding.
fn pack(px: &[u8], f: &Frame, stride: usize) -> Vec<u8> {
    let row = f.width as usize * 4;
    (0..f.height as usize)
        .flat_map(|y| px[y * stride..y * stride + row].iter().copied())
        .collect()
}

/// Asserts `bad` is empty, printing the count and the first few.
fn assert_none(bad: &[String], of: usize, what: &str) {
    assert!(
        bad.is_empty(),
        "{what}: {} of {of} differ; first:\n  {}",
        bad.len(),
        bad.iter().take(8).cloned().collect::<Vec<_>>().join("\n  ")
    );
}

/// Reference hits of the view's camera rays (row-major), BVH single ray.
fn reference_hits(ctx: &mut OwnedContext, v: &View, wh: (u32, u32)) -> Vec<Hit> {
    let rays = v.rays(wh.0, wh.1);
    let mut hits = vec![Hit::MISS; rays.len()];
    ctx.trace(Method::BvhSingle, &rays, &mut hits).unwrap();
    hits
}

/// Pixels of the last deferred frame whose hit differs from `want`.
fn primary_mismatches(ctx: &OwnedContext, want: &[Hit], wh: (u32, u32)) -> Vec<String> {
    let mut bad = Vec::new();
    for y in 0..wh.1 {
        for x in 0..wh.0 {
            let (got, _) = ctx.deferred_pixel(x, y).expect("pixel of the last frame");
            let exp = want[(y * wh.0 + x) as usize];
            let same = got.prim == exp.prim
                && got.is_hit() == exp.is_hit()
                && (!exp.is_hit() || got.t.to_bits() == exp.t.to_bits());
            if !same {
                bad.push(format!(
                    "pixel ({x}, {y}): deferred prim {} t {:e}, BvhSingle prim {} t {:e}",
                    got.prim as i64, got.t, exp.prim as i64, exp.t
                ));
            }
        }
    }
    assert!(ctx.deferred_pixel(wh.0, 0).is_none() && ctx.deferred_pixel(0, wh.1).is_none());
    bad
}

/// What a shadow check saw.
#[derive(Default, Debug)]
struct ShadowCount {
    rays: usize,
    occluded: usize,
    /// (rays, occluded) of each light.
    per_light: Vec<(usize, usize)>,
}

/// The shadow bits of the last deferred frame against BVH single-ray
/// occlusion of the frame's own shadow rays, light by light; pixels without
/// a shadow ray must have the bit clear, bits past the lights too.
fn shadow_mismatches(
    ctx: &mut OwnedContext,
    lights: &[PointLight],
    wh: (u32, u32),
    bad: &mut Vec<String>,
) -> ShadowCount {
    let mut n = ShadowCount::default();
    for (l, light) in lights.iter().enumerate() {
        let (mut rays, mut at): (Vec<Ray>, Vec<(u32, u32, u8)>) = (Vec::new(), Vec::new());
        for y in 0..wh.1 {
            for x in 0..wh.0 {
                let (hit, bits) = ctx.deferred_pixel(x, y).unwrap();
                if l == 0 && (bits as u32) >> lights.len() != 0 {
                    bad.push(format!(
                        "pixel ({x}, {y}): bits {bits:#010b} past {} lights",
                        lights.len()
                    ));
                }
                match ctx.deferred_shadow_ray(x, y, light) {
                    Some(r) => {
                        rays.push(r);
                        at.push((x, y, bits));
                    }
                    None if bits & (1 << l) != 0 => bad.push(format!(
                        "light {l} pixel ({x}, {y}): bit set without a shadow ray (hit {})",
                        hit.prim as i64
                    )),
                    None => {}
                }
            }
        }
        let mut occ = vec![false; rays.len()];
        ctx.occluded(Method::BvhSingle, &rays, &mut occ).unwrap();
        for ((r, &(x, y, bits)), &o) in rays.iter().zip(&at).zip(&occ) {
            let got = bits & (1 << l) != 0;
            if got != o {
                bad.push(format!(
                    "light {l} {light:?} pixel ({x}, {y}): light grid {got}, BvhSingle {o}; ray {r:?}"
                ));
            }
        }
        let o = occ.iter().filter(|&&o| o).count();
        n.rays += rays.len();
        n.occluded += o;
        n.per_light.push((rays.len(), o));
    }
    n
}

/// Scene bounds.
fn bounds(s: &TestScene) -> (Vec3, Vec3) {
    let mut lo = Vec3::splat(f32::INFINITY);
    let mut hi = Vec3::splat(f32::NEG_INFINITY);
    for p in s.vertices.chunks_exact(3) {
        lo = lo.min(Vec3::new(p[0], p[1], p[2]));
        hi = hi.max(Vec3::new(p[0], p[1], p[2]));
    }
    (lo, hi)
}

fn vertices(s: &TestScene, prim: u32) -> [Vec3; 3] {
    let v = |k: usize| {
        let i = s.indices[3 * prim as usize + k] as usize;
        Vec3::new(
            s.vertices[3 * i],
            s.vertices[3 * i + 1],
            s.vertices[3 * i + 2],
        )
    };
    [v(0), v(1), v(2)]
}

/// The eight test lights of a view (named): the scene's light, one far
/// outside, one on a corner of the bounds, one on a vertex and one on the
/// centroid of the triangle seen in the image centre, one between two
/// visible surfaces, one behind the model from the camera, and a spot
/// (20 degrees, soft edge 5) aimed at the scene centre. `hits` are the view's
/// reference hits (row-major).
fn test_lights(
    s: &TestScene,
    v: &View,
    hits: &[Hit],
    wh: (u32, u32),
) -> Vec<(&'static str, PointLight)> {
    let (lo, hi) = bounds(s);
    let c = 0.5 * (lo + hi);
    let diag = hi - lo;
    let rays = v.rays(wh.0, wh.1);
    let at = |x: u32, y: u32| -> Option<(Vec3, u32)> {
        let i = (y * wh.0 + x) as usize;
        let h = hits[i];
        h.is_hit().then(|| {
            (
                Vec3::from(rays[i].org) + Vec3::from(rays[i].dir) * h.t,
                h.prim,
            )
        })
    };
    // The hit nearest the image centre along the middle row.
    let (cx, cy) = (wh.0 / 2, wh.1 / 2);
    let centre = (0..wh.0)
        .flat_map(|d| [cx.saturating_sub(d), (cx + d).min(wh.0 - 1)])
        .find_map(|x| at(x, cy));
    let tri = centre.map(|(_, p)| vertices(s, p));
    let vertex = tri.map_or(c, |t| t[1]);
    let centroid = tri.map_or(c, |t| (t[0] + t[1] + t[2]) / 3.0);
    let between = match (at(wh.0 / 4, cy), at(3 * wh.0 / 4, cy)) {
        (Some((a, _)), Some((b, _))) => 0.5 * (a + b),
        (Some((a, _)), None) | (None, Some((a, _))) => 0.5 * (a + v.eye),
        _ => c,
    };
    let away = (c - v.eye).normalize_or_zero();
    let behind = c + away * 0.75 * diag.length();
    // The spot stands towards the scene light, close enough that its 20
    // degree cone's edge crosses the scene.
    let towards = (s.light - c)
        .try_normalize()
        .unwrap_or((v.eye - c).normalize());
    let spot_pos = c + towards * 0.8 * diag.length();
    let pl = |p: Vec3| PointLight::new(p.to_array(), [0.3, 0.25, 0.2]);
    vec![
        ("scene", pl(s.light)),
        ("far", pl(c + 10.0 * diag)),
        ("corner", pl(hi)),
        ("vertex", pl(vertex)),
        ("centroid", pl(centroid)),
        ("between", pl(between)),
        ("behind", pl(behind)),
        (
            "spot",
            PointLight {
                spot_direction: (c - spot_pos).to_array(),
                spot_angle_deg: 20.0,
                spot_soft_deg: 5.0,
                ..pl(spot_pos)
            },
        ),
    ]
}

// ---------------------------------------------------------------------------
// 1. Camera rays.

/// (tile, group, slices): tiles 2 to 32, direct and indirect mapping, one
/// slice up to 64; tracing tiles up to 64 pixels.
const PRIMARY_PARAMS: &[(u32, u32, u32)] = &[
    (8, 2, 32),
    (4, 1, 1),
    (4, 4, 8),
    (16, 1, 64),
    (16, 4, 8),
    (8, 1, 64),
    (2, 2, 8),
    (32, 2, 64),
    (32, 1, 1),
];

fn check_primary(
    s: &TestScene,
    wh: (u32, u32),
    tests: &[TriTest],
    params: &[(u32, u32, u32)],
    filter: Option<sheaf::Filter>,
) -> String {
    let mut ctx = context(s, wh, Limits::BVH);
    ctx.set_filter(filter);
    let mut report = String::new();
    for &test in tests {
        build_bvh(&mut ctx, s, test);
        let (mut pixels, mut hits) = (0usize, 0usize);
        for (vname, v) in &s.views {
            let want = reference_hits(&mut ctx, v, wh);
            let f = frame(v, s.light, wh, false);
            // Every third configuration (tiles 8, 16 and 2: lane groups
            // within a row of quads and across rows) at every lane width.
            let configs = params.iter().enumerate().flat_map(|(i, &c)| {
                levels(i % 3 == 0 && test == tests[0])
                    .into_iter()
                    .map(move |isa| (c, isa))
            });
            for ((tile, group, slices), isa) in configs {
                let p = PgridParams {
                    tile,
                    group,
                    slices,
                    isa,
                    ..pgrid_params(test)
                };
                ctx.build_pgrid(&s.scene(), &p).unwrap();
                let what = format!(
                    "{} {vname} {test:?} tile {tile} group {group} slices {slices} {isa:?}",
                    s.name
                );
                let (info, _) =
                    deferred(&mut ctx, &f, &[], PrimaryPass::Pgrid, ShadowPass::LightGrid)
                        .unwrap_or_else(|e| panic!("{what}: {e}"));
                let bad = primary_mismatches(&ctx, &want, wh);
                assert_none(&bad, want.len(), &what);
                let shadowed = (0..wh.0 * wh.1)
                    .filter(|i| ctx.deferred_pixel(i % wh.0, i / wh.0).unwrap().1 != 0)
                    .count();
                assert_eq!(shadowed, 0, "{what}: shadows off, yet shadow bits");
                let exp_hits = want.iter().filter(|h| h.is_hit()).count();
                assert_eq!(info.hits, exp_hits as u64, "{what}: DeferredInfo.hits");
                assert_eq!(info.shadow_rays, 0, "{what}: shadows off, yet shadow rays");
                assert_eq!(info.camera.depth.count, slices, "{what}: camera slices");
                assert_eq!(
                    info.camera.tiles,
                    [wh.0.div_ceil(tile), wh.1.div_ceil(tile)],
                    "{what}: camera tiles"
                );
                pixels += want.len();
                hits += exp_hits;
            }
        }
        assert!(hits > 0, "{} {test:?}: no view hits anything", s.name);
        report += &format!(
            "{:>10} {test:?}: {pixels} pixels, {hits} hits equal\n",
            s.name
        );
    }
    report
}

#[test]
fn builtin_primary_hits_equal_the_bvh_single_ray() {
    for r in par_map(&builtin_scenes(), |s| {
        check_primary(s, BUILTIN_WH, &TESTS, PRIMARY_PARAMS, None)
    }) {
        print!("{r}");
    }
}

#[test]
fn obj_primary_hits_equal_the_bvh_single_ray() {
    let scenes = obj_scenes();
    if scenes.is_empty() {
        eprintln!("note: no OBJ scenes: skipped");
        return;
    }
    let params = &[(8, 2, 32), (4, 4, 64), (16, 1, 8)];
    for r in par_map(&scenes, |s| check_primary(s, OBJ_WH, &TESTS, params, None)) {
        print!("{r}");
    }
}

// ---------------------------------------------------------------------------
// 2. Shadow rays.

/// (chunk r, light tiles), the first with every triangle test, the rest
/// with Moller-Trumbore.
const SHADOW_PARAMS: &[(u32, u32)] = &[(256, 64), (16, 1), (16, 7), (64, 64), (1024, 64)];

/// Every view with all eight test lights at once for each (chunk, light
/// tiles) (the first triangle test), and the scene light alone (the
/// frame's own light, `lights` empty) with the first (chunk, light tiles).
fn check_shadows(
    s: &TestScene,
    wh: (u32, u32),
    tests: &[TriTest],
    params: &[(u32, u32)],
    filter: Option<sheaf::Filter>,
) -> String {
    let mut ctx = context(s, wh, Limits::BVH);
    ctx.set_filter(filter);
    let mut report = String::new();
    for &test in tests {
        build_bvh(&mut ctx, s, test);
        let mut n = ShadowCount::default();
        let mut per_light = [(0usize, 0usize); 8];
        let mut names = [""; 8];
        for (vname, v) in &s.views {
            let want = reference_hits(&mut ctx, v, wh);
            let named = test_lights(s, v, &want, wh);
            let lights: Vec<PointLight> = named.iter().map(|l| l.1).collect();
            for (n, l) in names.iter_mut().zip(&named) {
                *n = l.0;
            }
            let f = frame(v, s.light, wh, true);
            // The first configuration of the first test also at every
            // lane width, with the eight lights.
            let configs = params.iter().enumerate().flat_map(|(k, &c)| {
                levels(k == 0 && test == tests[0])
                    .into_iter()
                    .map(move |isa| (k, c, isa))
            });
            for (k, (chunk, light_tiles), isa) in configs {
                if k > 0 && test != tests[0] {
                    continue;
                }
                let p = PgridParams {
                    chunk,
                    light_tiles,
                    isa,
                    ..pgrid_params(test)
                };
                ctx.build_pgrid(&s.scene(), &p).unwrap();
                let sets = [("8 lights", &lights[..]), ("frame light", &[][..])];
                let n_sets = if k == 0 && isa == Isa::Auto { 2 } else { 1 };
                for &(set, ls) in &sets[..n_sets] {
                    let what = format!(
                        "{} {vname} {test:?} chunk {chunk} light tiles {light_tiles} {set} {isa:?}",
                        s.name
                    );
                    let (info, _) =
                        deferred(&mut ctx, &f, ls, PrimaryPass::Pgrid, ShadowPass::LightGrid)
                            .unwrap_or_else(|e| panic!("{what}: {e}"));
                    assert_none(&primary_mismatches(&ctx, &want, wh), want.len(), &what);
                    let ls = if ls.is_empty() {
                        core::slice::from_ref(&f.light)
                    } else {
                        ls
                    };
                    let mut bad = Vec::new();
                    let c = shadow_mismatches(&mut ctx, ls, wh, &mut bad);
                    assert_none(&bad, c.rays, &what);
                    assert_eq!(
                        info.shadow_rays, c.rays as u64,
                        "{what}: DeferredInfo.shadow_rays"
                    );
                    assert_eq!(info.reorder.rays as usize, c.rays, "{what}: reorder.rays");
                    assert!(
                        info.reorder.tiles_used <= info.reorder.chunks
                            && info.reorder.chunks as usize
                                <= c.rays.div_ceil(chunk as usize)
                                    + info.reorder.tiles_used as usize
                            && info.reorder.max_tile_rays as usize <= c.rays,
                        "{what}: reorder {:?}",
                        info.reorder
                    );
                    if c.rays > 0 {
                        assert!(
                            info.light.tiles[0] <= light_tiles,
                            "{what}: {:?}",
                            info.light
                        );
                    }
                    if light_tiles == 1 && c.rays > 0 {
                        assert_eq!(info.light.tiles, [1, 1], "{what}");
                    }
                    if ls.len() == 8 {
                        for (sum, (rays, occ)) in per_light.iter_mut().zip(&c.per_light) {
                            sum.0 += rays;
                            sum.1 += occ;
                        }
                    }
                    n.rays += c.rays;
                    n.occluded += c.occluded;
                }
            }
        }
        assert!(
            n.rays > 0 && n.occluded > 0,
            "{} {test:?}: no shadow ray, or none occluded: {n:?}",
            s.name
        );
        report += &format!(
            "{:>10} {test:?}: {} shadow rays ({} occluded) equal; per test light (rays, occluded): {}\n",
            s.name,
            n.rays,
            n.occluded,
            names
                .iter()
                .zip(&per_light)
                .map(|(n, c)| format!("{n} {c:?}"))
                .collect::<Vec<_>>()
                .join(", ")
        );
    }
    report
}

#[test]
fn builtin_shadow_bits_equal_single_ray_occlusion() {
    for r in par_map(&builtin_scenes(), |s| {
        check_shadows(s, BUILTIN_WH, &TESTS, SHADOW_PARAMS, None)
    }) {
        print!("{r}");
    }
}

/// With the cut-out filter (`common::filter`) on the mesh, the
/// perspective grid's hits and the light grid's shadow bits are the BVH
/// single ray's with the same filter: the grids ask it for the caller's
/// triangle ids.
#[test]
fn filtered_hits_and_shadows_equal_the_filtered_single_ray() {
    let filter = Some(common::filter::plain());
    for r in par_map(&builtin_scenes(), |s| {
        check_primary(s, BUILTIN_WH, &TESTS[..1], &PRIMARY_PARAMS[..3], filter)
            + &check_shadows(s, BUILTIN_WH, &TESTS[..1], &SHADOW_PARAMS[..2], filter)
    }) {
        print!("{r}");
    }
}

#[test]
fn obj_shadow_bits_equal_single_ray_occlusion() {
    let scenes = obj_scenes();
    if scenes.is_empty() {
        eprintln!("note: no OBJ scenes: skipped");
        return;
    }
    for r in par_map(&scenes, |s| {
        check_shadows(
            s,
            OBJ_WH,
            &[TriTest::MollerTrumbore],
            &[(256, 64), (16, 7)],
            None,
        )
    }) {
        print!("{r}");
    }
}

/// A frame large enough for the full 64 x 64 light tiles (at least 8 rays
/// per tile on average: 32768 shadow rays).
#[test]
fn light_grid_of_64_by_64_tiles_is_exact() {
    let wh = (256, 224);
    let scenes = builtin_scenes();
    let s = scenes.iter().find(|s| s.name == "gears").unwrap();
    let mut l = Limits::for_triangles(s.triangles());
    l.max_vertices = (s.vertices.len() / 3) as u32;
    l.structures = Limits::BVH | Limits::PGRID;
    l.max_image_width = wh.0;
    l.max_image_height = wh.1;
    l.max_pgrid_refs = 4 << 20; // gears' camera grid at 256 x 224 needs 1.1M
    let mut ctx = OwnedContext::new(&l).unwrap();
    build_bvh(&mut ctx, s, TriTest::MollerTrumbore);
    ctx.build_pgrid(
        &s.scene(),
        &PgridParams {
            light_tiles: 64,
            chunk: 64,
            ..pgrid_params(TriTest::MollerTrumbore)
        },
    )
    .unwrap();
    let mut best = 0;
    for (vname, v) in &s.views {
        let f = frame(v, s.light, wh, true);
        let (info, _) =
            deferred(&mut ctx, &f, &[], PrimaryPass::Pgrid, ShadowPass::LightGrid).unwrap();
        let mut bad = Vec::new();
        let c = shadow_mismatches(&mut ctx, &[f.light], wh, &mut bad);
        assert_none(&bad, c.rays, &format!("gears {vname} 64 light tiles"));
        if c.rays >= 8 * 64 * 64 {
            assert_eq!(info.light.tiles, [64, 64], "gears {vname}: {} rays", c.rays);
        }
        best = best.max(c.rays);
        println!(
            "gears {vname}: {} shadow rays, light tiles {:?}, {:?}",
            c.rays, info.light.tiles, info.reorder
        );
    }
    assert!(
        best >= 8 * 64 * 64,
        "no view makes 32768 shadow rays ({best}): 64 x 64 tiles untested"
    );
}

// ---------------------------------------------------------------------------
// 3. Degenerate frames.

/// One light tile holding every shadow ray, split into chunks of 16: still
/// exact, `ceil(rays / 16)` chunks, one tile used.
#[test]
fn one_light_tile_holds_every_ray_in_chunks_of_16() {
    for s in builtin_scenes() {
        let mut ctx = context(&s, BUILTIN_WH, Limits::BVH);
        build_bvh(&mut ctx, &s, TriTest::Watertight);
        ctx.build_pgrid(
            &s.scene(),
            &PgridParams {
                light_tiles: 1,
                chunk: 16,
                ..pgrid_params(TriTest::Watertight)
            },
        )
        .unwrap();
        for (vname, v) in &s.views {
            let what = format!("{} {vname}", s.name);
            let f = frame(v, s.light, BUILTIN_WH, true);
            let (info, _) =
                deferred(&mut ctx, &f, &[], PrimaryPass::Pgrid, ShadowPass::LightGrid).unwrap();
            let mut bad = Vec::new();
            let c = shadow_mismatches(&mut ctx, &[f.light], BUILTIN_WH, &mut bad);
            assert_none(&bad, c.rays, &what);
            let r = info.reorder;
            assert_eq!(r.rays as usize, c.rays, "{what}: {r:?}");
            if c.rays > 0 {
                assert_eq!(info.light.tiles, [1, 1], "{what}");
                assert_eq!(r.tiles_used, 1, "{what}: {r:?}");
                assert_eq!(r.max_tile_rays as usize, c.rays, "{what}: {r:?}");
                assert_eq!(r.chunks as usize, c.rays.div_ceil(16), "{what}: {r:?}");
            } else {
                assert_eq!((r.tiles_used, r.chunks), (0, 0), "{what}: {r:?}");
            }
        }
    }
}

/// Images smaller than a tile (1x1, 2x2, odd sizes): every hit and shadow
/// bit exact; the whole frame is one light tile's worth of rays.
#[test]
fn tiny_images_are_exact() {
    for s in builtin_scenes() {
        for wh in [(1, 1), (2, 2), (3, 5), (7, 2)] {
            let mut ctx = context(&s, wh, Limits::BVH);
            for test in [TriTest::MollerTrumbore, TriTest::Projection] {
                build_bvh(&mut ctx, &s, test);
                for (tile, group) in [(8, 2), (2, 1), (32, 2)] {
                    ctx.build_pgrid(
                        &s.scene(),
                        &PgridParams {
                            tile,
                            group,
                            chunk: 16,
                            ..pgrid_params(test)
                        },
                    )
                    .unwrap();
                    for (vname, v) in &s.views {
                        let what = format!(
                            "{} {vname} {wh:?} {test:?} tile {tile} group {group}",
                            s.name
                        );
                        // Narrow views, so a tiny image still hits something.
                        let v = View {
                            fov_y_deg: 10.0,
                            ..*v
                        };
                        let want = reference_hits(&mut ctx, &v, wh);
                        let lights = [
                            PointLight::new(s.light.to_array(), [1.0; 3]),
                            PointLight::new(v.eye.to_array(), [0.5; 3]),
                        ];
                        let f = frame(&v, s.light, wh, true);
                        let (info, _) = deferred(
                            &mut ctx,
                            &f,
                            &lights,
                            PrimaryPass::Pgrid,
                            ShadowPass::LightGrid,
                        )
                        .unwrap_or_else(|e| panic!("{what}: {e}"));
                        assert_none(&primary_mismatches(&ctx, &want, wh), want.len(), &what);
                        let mut bad = Vec::new();
                        let c = shadow_mismatches(&mut ctx, &lights, wh, &mut bad);
                        assert_none(&bad, c.rays, &what);
                        assert_eq!(info.shadow_rays, c.rays as u64, "{what}");
                        // At most 8 rays per light: one light tile.
                        if c.rays > 0 && wh.0 * wh.1 <= 8 {
                            assert_eq!(info.light.tiles, [1, 1], "{what}: {} rays", c.rays);
                        }
                    }
                }
            }
        }
    }
}

/// A camera looking away from the scene: every pixel misses, no shadow
/// ray is made, the image is the background (as `render`'s), no error,
/// with every pass combination.
#[test]
fn camera_looking_away_hits_nothing() {
    for s in builtin_scenes() {
        let mut ctx = context(&s, BUILTIN_WH, Limits::BVH | Limits::GRID);
        build_bvh(&mut ctx, &s, TriTest::MollerTrumbore);
        ctx.build_grid(&s.scene(), &GridParams::default()).unwrap();
        ctx.build_pgrid(&s.scene(), &pgrid_params(TriTest::MollerTrumbore))
            .unwrap();
        let (lo, hi) = bounds(&s);
        let c = 0.5 * (lo + hi);
        let dir = Vec3::new(0.3, -0.8, 0.5).normalize();
        let eye = c + dir * 2.0 * (hi - lo).length();
        let v = View {
            eye,
            look_at: eye + dir,
            up: if dir.z.abs() > 0.9 { Vec3::Y } else { Vec3::Z },
            fov_y_deg: 60.0,
        };
        let f = frame(&v, s.light, BUILTIN_WH, true);
        let want = rendered(&mut ctx, &f, Method::BvhSingle);
        assert!(
            want.chunks(4).all(|p| p == &want[..4]),
            "{}: reference is not all background",
            s.name
        );
        let lights = [f.light, PointLight::new(c.to_array(), [1.0; 3])];
        let traced = TraceParams::bvh(Method::BvhRanged, 16);
        for (primary, shadow) in [
            (PrimaryPass::Pgrid, ShadowPass::LightGrid),
            (PrimaryPass::Traced(traced), ShadowPass::LightGrid),
            (PrimaryPass::Pgrid, ShadowPass::Traced(traced)),
        ] {
            for ls in [&[][..], &lights[..]] {
                let what = format!(
                    "{} looking away {primary:?} {shadow:?} {} lights",
                    s.name,
                    ls.len()
                );
                let (info, img) = deferred(&mut ctx, &f, ls, primary, shadow)
                    .unwrap_or_else(|e| panic!("{what}: {e}"));
                assert_eq!((info.hits, info.shadow_rays), (0, 0), "{what}");
                assert_eq!(info.reorder.chunks, 0, "{what}");
                assert!(img == want, "{what}: image is not the background");
                for y in 0..f.height {
                    for x in 0..f.width {
                        let (h, bits) = ctx.deferred_pixel(x, y).unwrap();
                        assert!(
                            !h.is_hit() && bits == 0,
                            "{what}: pixel ({x}, {y}) {h:?} {bits}"
                        );
                        assert!(ctx.deferred_shadow_ray(x, y, &f.light).is_none(), "{what}");
                    }
                }
            }
        }
    }
}

/// Hits but no shadow ray: a spot aimed away from the scene (every surface
/// outside its cone), alone and beside a point light. No error, bits exact.
#[test]
fn spot_aimed_away_makes_no_shadow_rays() {
    for s in builtin_scenes() {
        let mut ctx = context(&s, BUILTIN_WH, Limits::BVH);
        build_bvh(&mut ctx, &s, TriTest::MollerTrumbore);
        ctx.build_pgrid(&s.scene(), &pgrid_params(TriTest::MollerTrumbore))
            .unwrap();
        let (lo, hi) = bounds(&s);
        let c = 0.5 * (lo + hi);
        let pos = c + 3.0 * (hi - lo);
        let spot = PointLight {
            spot_direction: (pos - c).to_array(), // away from the scene
            spot_angle_deg: 30.0,
            spot_soft_deg: 0.0,
            ..PointLight::new(pos.to_array(), [1.0; 3])
        };
        let v = &s.views[0].1;
        let f = frame(v, s.light, BUILTIN_WH, true);
        for ls in [vec![spot], vec![f.light, spot], vec![spot, f.light, spot]] {
            let what = format!("{} spot away, {} lights", s.name, ls.len());
            let (info, _) =
                deferred(&mut ctx, &f, &ls, PrimaryPass::Pgrid, ShadowPass::LightGrid).unwrap();
            assert!(info.hits > 0, "{what}: the view must hit");
            let mut bad = Vec::new();
            let n = shadow_mismatches(&mut ctx, &ls, BUILTIN_WH, &mut bad);
            assert_none(&bad, n.rays, &what);
            for y in 0..f.height {
                for x in 0..f.width {
                    assert!(
                        ctx.deferred_shadow_ray(x, y, &spot).is_none(),
                        "{what}: ({x}, {y})"
                    );
                }
            }
            assert_eq!(info.shadow_rays, n.rays as u64, "{what}");
        }
    }
}

// ---------------------------------------------------------------------------
// 4. Mixed passes.

/// Every combination of grid and traced passes (packets of the BVH and
/// the grid's CGT for shadows) gives the same image, and with one light it
/// is `render`'s image with the BVH single ray.
#[test]
fn mixed_passes_give_the_same_image() {
    let mut scenes = builtin_scenes();
    if let Some(s) = common::obj_scene("legocar/legocar.obj", "legocar") {
        scenes.push(s);
    }
    let out = par_map(&scenes, |s| {
        let wh = BUILTIN_WH;
        let mut ctx = context(s, wh, Limits::BVH | Limits::GRID);
        let mut frames = 0;
        // Tracing tiles of 32 and 4 pixels (traced shadow packets take the
        // tracing tile's side).
        for (test, tile, group) in [
            (TriTest::MollerTrumbore, 16, 2),
            (TriTest::Watertight, 4, 1),
        ] {
            build_bvh(&mut ctx, s, test);
            ctx.build_grid(
                &s.scene(),
                &GridParams {
                    test,
                    ..GridParams::default()
                },
            )
            .unwrap();
            ctx.build_pgrid(
                &s.scene(),
                &PgridParams {
                    tile,
                    group,
                    ..pgrid_params(test)
                },
            )
            .unwrap();
            for (vname, v) in &s.views {
                let f = frame(v, s.light, wh, true);
                let want = rendered(&mut ctx, &f, Method::BvhSingle);
                let bvh16 = TraceParams::bvh(Method::BvhRanged, 16);
                let cgt = TraceParams::cgt(8);
                let passes = [
                    (PrimaryPass::Pgrid, ShadowPass::LightGrid),
                    (PrimaryPass::Traced(bvh16), ShadowPass::LightGrid),
                    (PrimaryPass::Pgrid, ShadowPass::Traced(bvh16)),
                    (PrimaryPass::Pgrid, ShadowPass::Traced(cgt)),
                    (PrimaryPass::Pgrid, ShadowPass::Traced(TraceParams::cgt(4))),
                    (PrimaryPass::Traced(cgt), ShadowPass::Traced(bvh16)),
                    (
                        PrimaryPass::Traced(TraceParams::bvh(Method::BvhSingle, 0)),
                        ShadowPass::LightGrid,
                    ),
                    (
                        PrimaryPass::Pgrid,
                        ShadowPass::Traced(TraceParams::bvh(Method::BvhSingle, 0)),
                    ),
                ];
                for (k, (primary, shadow)) in passes.into_iter().enumerate() {
                    // The frame's light, and (once) the same light given.
                    let sets = [&[][..], core::slice::from_ref(&f.light)];
                    for ls in &sets[..if k == 0 { 2 } else { 1 }] {
                        let what = format!(
                            "{} {vname} {test:?} tile {tile} group {group}: {primary:?} + {shadow:?}, {} lights",
                            s.name,
                            ls.len()
                        );
                        let (_, img) = deferred(&mut ctx, &f, ls, primary, shadow)
                            .unwrap_or_else(|e| panic!("{what}: {e}"));
                        if k == 0 {
                            for y in 0..wh.1 {
                                for x in 0..wh.0 {
                                    let bits = ctx.deferred_pixel(x, y).unwrap().1;
                                    assert!(bits <= 1, "{what}: ({x}, {y}) bits {bits}");
                                }
                            }
                        }
                        let bad: Vec<String> = img
                            .chunks(4)
                            .zip(want.chunks(4))
                            .enumerate()
                            .filter(|(_, (a, b))| a != b)
                            .map(|(i, (a, b))| {
                                format!(
                                    "pixel ({}, {}): deferred {a:?}, render {b:?}",
                                    i as u32 % wh.0,
                                    i as u32 / wh.0
                                )
                            })
                            .collect();
                        assert_none(&bad, want.len() / 4, &what);
                        frames += 1;
                    }
                }
            }
        }
        format!(
            "{:>10}: {frames} deferred frames equal render's image\n",
            s.name
        )
    });
    for r in out {
        print!("{r}");
    }
}

/// A tracing tile of 64 pixels (pgrid tile 32 x group 2, or 16 x 4, both
/// accepted by `build_pgrid` and within the default `max_tile`) with shadow
/// packets traced per tile: the image must equal `render`'s (and the call
/// must not panic: no panic is reachable from caller input).
#[test]
fn pgrid_tracing_tile_of_64_with_traced_shadow_packets() {
    let scenes = builtin_scenes();
    let s = &scenes[0];
    let wh = BUILTIN_WH;
    let mut ctx = context(s, wh, Limits::BVH);
    build_bvh(&mut ctx, s, TriTest::MollerTrumbore);
    let v = &s.views[0].1;
    let f = frame(v, s.light, wh, true);
    let want = rendered(&mut ctx, &f, Method::BvhSingle);
    let mut failed = Vec::new();
    for (tile, group) in [(32, 2), (16, 4)] {
        ctx.build_pgrid(
            &s.scene(),
            &PgridParams {
                tile,
                group,
                ..pgrid_params(TriTest::MollerTrumbore)
            },
        )
        .unwrap();
        for shadow in [
            ShadowPass::LightGrid,
            ShadowPass::Traced(TraceParams::bvh(Method::BvhSingle, 0)),
            ShadowPass::Traced(TraceParams::bvh(Method::BvhRanged, 16)),
        ] {
            let what = format!("{} tile {tile} group {group} {shadow:?}", s.name);
            let r = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| {
                deferred(&mut ctx, &f, &[], PrimaryPass::Pgrid, shadow)
            }));
            // Traced shadow packets take the tracing tile's side, at most 32.
            let packets = matches!(shadow, ShadowPass::Traced(p) if p.tile_side() > 0);
            match r {
                Ok(Err(Error::InvalidArgument(_))) if packets && tile * group > 32 => {}
                Ok(Ok(_)) if packets && tile * group > 32 => failed.push(format!(
                    "{what}: traced packets of side {} accepted",
                    tile * group
                )),
                Ok(Ok((_, img))) if img == want => {}
                Ok(Ok(_)) => failed.push(format!("{what}: image differs from render's")),
                Ok(Err(e)) => failed.push(format!("{what}: error {e}")),
                Err(p) => failed.push(format!(
                    "{what}: render_deferred panicked: {}",
                    p.downcast_ref::<String>().map_or("?", |s| s.as_str())
                )),
            }
        }
    }
    assert!(
        failed.is_empty(),
        "{} of 6 frames failed:\n  {}",
        failed.len(),
        failed.join("\n  ")
    );
}

// ---------------------------------------------------------------------------
// 5. Bad input.

fn is_invalid(r: &sheaf::Result<(DeferredInfo, Vec<u8>)>) -> bool {
    matches!(r, Err(Error::InvalidArgument(_)))
}

#[test]
fn bad_input_is_rejected_and_the_next_frame_works() {
    let scenes = builtin_scenes();
    let s = &scenes[1];
    let wh = BUILTIN_WH;
    let v = &s.views[0].1;
    let f = frame(v, s.light, wh, true);
    let bvh16 = TraceParams::bvh(Method::BvhRanged, 16);
    let mt = pgrid_params(TriTest::MollerTrumbore);

    // Without Limits::PGRID: build_pgrid and render_deferred refuse.
    {
        let mut l = Limits::for_triangles(s.triangles());
        l.max_vertices = (s.vertices.len() / 3) as u32;
        l.structures = Limits::BVH;
        let mut ctx = OwnedContext::new(&l).unwrap();
        build_bvh(&mut ctx, s, TriTest::MollerTrumbore);
        assert!(matches!(
            ctx.build_pgrid(&s.scene(), &mt),
            Err(Error::InvalidArgument(_))
        ));
        for (p, sh) in [
            (PrimaryPass::Pgrid, ShadowPass::LightGrid),
            (PrimaryPass::Traced(bvh16), ShadowPass::Traced(bvh16)),
        ] {
            let r = deferred(&mut ctx, &f, &[], p, sh);
            assert!(
                is_invalid(&r),
                "no PGRID pools, {p:?} {sh:?}: {:?}",
                r.map(|x| x.0)
            );
        }
        assert!(ctx.deferred_pixel(0, 0).is_none());
    }

    let mut ctx = context(s, wh, Limits::BVH | Limits::GRID);
    build_bvh(&mut ctx, s, TriTest::MollerTrumbore);
    let want = rendered(&mut ctx, &f, Method::BvhSingle);
    let good = |ctx: &mut OwnedContext, what: &str| {
        for (p, sh) in [
            (PrimaryPass::Pgrid, ShadowPass::LightGrid),
            (PrimaryPass::Traced(bvh16), ShadowPass::LightGrid),
        ] {
            let (_, img) =
                deferred(ctx, &f, &[], p, sh).unwrap_or_else(|e| panic!("after {what}: {e}"));
            assert!(
                img == want,
                "after {what}: the next frame differs from render's"
            );
        }
    };

    // Grid passes before build_pgrid: NotBuilt; traced passes alone work.
    for (p, sh) in [
        (PrimaryPass::Pgrid, ShadowPass::LightGrid),
        (PrimaryPass::Pgrid, ShadowPass::Traced(bvh16)),
        (PrimaryPass::Traced(bvh16), ShadowPass::LightGrid),
    ] {
        let r = deferred(&mut ctx, &f, &[], p, sh);
        assert!(
            matches!(r, Err(Error::NotBuilt)),
            "{p:?} {sh:?} before build_pgrid: {:?}",
            r.map(|x| x.0)
        );
    }
    assert!(ctx.deferred_pixel(0, 0).is_none(), "no frame yet");
    let (_, img) = deferred(
        &mut ctx,
        &f,
        &[],
        PrimaryPass::Traced(bvh16),
        ShadowPass::Traced(bvh16),
    )
    .expect("traced passes need no build_pgrid");
    assert!(img == want, "traced passes without build_pgrid");
    // A traced structure not built: NotBuilt.
    let r = deferred(
        &mut ctx,
        &f,
        &[],
        PrimaryPass::Traced(TraceParams::cgt(8)),
        ShadowPass::Traced(bvh16),
    );
    assert!(
        matches!(r, Err(Error::NotBuilt)),
        "grid not built: {:?}",
        r.map(|x| x.0)
    );

    // build_pgrid rejects out-of-domain parameters and keeps the last good ones.
    ctx.build_pgrid(&s.scene(), &mt).unwrap();
    good(&mut ctx, "build_pgrid");
    for (what, p) in [
        ("chunk 8", PgridParams { chunk: 8, ..mt }),
        ("chunk 15", PgridParams { chunk: 15, ..mt }),
        ("chunk 4097", PgridParams { chunk: 4097, ..mt }),
        ("tile 3", PgridParams { tile: 3, ..mt }),
        ("tile 0", PgridParams { tile: 0, ..mt }),
        ("tile 64", PgridParams { tile: 64, ..mt }),
        ("group 3", PgridParams { group: 3, ..mt }),
        ("group 0", PgridParams { group: 0, ..mt }),
        (
            "tile 32 group 4",
            PgridParams {
                tile: 32,
                group: 4,
                ..mt
            },
        ),
        ("slices 0", PgridParams { slices: 0, ..mt }),
        ("slices 1025", PgridParams { slices: 1025, ..mt }),
        (
            "light_slices 0",
            PgridParams {
                light_slices: 0,
                ..mt
            },
        ),
        (
            "light_tiles 0",
            PgridParams {
                light_tiles: 0,
                ..mt
            },
        ),
        (
            "light_tiles 257",
            PgridParams {
                light_tiles: 257,
                ..mt
            },
        ),
    ] {
        let r = ctx.build_pgrid(&s.scene(), &p);
        assert!(
            matches!(r, Err(Error::InvalidArgument(_))),
            "build_pgrid {what}: {r:?}"
        );
        good(&mut ctx, what);
    }
    // The projection test without Limits::projection_test.
    {
        let mut l = Limits::for_triangles(s.triangles());
        l.max_vertices = (s.vertices.len() / 3) as u32;
        l.structures = Limits::BVH | Limits::PGRID;
        l.max_image_width = wh.0;
        l.max_image_height = wh.1;
        let mut c2 = OwnedContext::new(&l).unwrap();
        let r = c2.build_pgrid(&s.scene(), &pgrid_params(TriTest::Projection));
        assert!(
            matches!(r, Err(Error::InvalidArgument(_))),
            "projection without pools: {r:?}"
        );
    }

    // Bad jobs: too many lights, bad spots, bad packets.
    let pl = PointLight::new(s.light.to_array(), [1.0; 3]);
    let spot = |angle: f32, soft: f32, dir: [f32; 3]| PointLight {
        spot_direction: dir,
        spot_angle_deg: angle,
        spot_soft_deg: soft,
        ..pl
    };
    let nine = [pl; 9];
    let bad_lights: &[(&str, &[PointLight])] = &[
        ("9 lights", &nine),
        ("spot 95 degrees", &[spot(95.0, 0.0, [0.0, 0.0, -1.0])]),
        ("spot 90 degrees", &[pl, spot(90.0, 0.0, [0.0, 0.0, -1.0])]),
        ("spot -10 degrees", &[spot(-10.0, 0.0, [0.0, 0.0, -1.0])]),
        ("spot soft > angle", &[spot(20.0, 25.0, [0.0, 0.0, -1.0])]),
        ("spot zero axis", &[spot(20.0, 5.0, [0.0; 3])]),
        ("spot NaN angle", &[spot(f32::NAN, 0.0, [0.0, 0.0, -1.0])]),
        (
            "light at infinity",
            &[PointLight::new([f32::INFINITY, 0.0, 0.0], [1.0; 3])],
        ),
        (
            "NaN colour",
            &[PointLight::new([0.0; 3], [f32::NAN, 0.0, 0.0])],
        ),
    ];
    for &(what, ls) in bad_lights {
        for (p, sh) in [
            (PrimaryPass::Pgrid, ShadowPass::LightGrid),
            (PrimaryPass::Traced(bvh16), ShadowPass::Traced(bvh16)),
        ] {
            let r = deferred(&mut ctx, &f, ls, p, sh);
            assert!(is_invalid(&r), "{what} {p:?} {sh:?}: {:?}", r.map(|x| x.0));
        }
        good(&mut ctx, what);
    }
    // 8 lights is the most, and fine.
    let eight = [pl; 8];
    let (info, _) = deferred(
        &mut ctx,
        &f,
        &eight,
        PrimaryPass::Pgrid,
        ShadowPass::LightGrid,
    )
    .unwrap();
    assert!(info.shadow_rays > 0);
    let bad_packet = TraceParams {
        packet: 12,
        ..bvh16
    };
    for (what, p, sh) in [
        (
            "primary packet 12",
            PrimaryPass::Traced(bad_packet),
            ShadowPass::LightGrid,
        ),
        (
            "shadow packet 12",
            PrimaryPass::Pgrid,
            ShadowPass::Traced(bad_packet),
        ),
    ] {
        assert!(is_invalid(&deferred(&mut ctx, &f, &[], p, sh)), "{what}");
        good(&mut ctx, what);
    }
    // The frame: too large for the limits, bad stride, short buffer.
    let big = Frame {
        width: wh.0 + 1,
        ..f
    };
    let r = deferred(
        &mut ctx,
        &big,
        &[],
        PrimaryPass::Pgrid,
        ShadowPass::LightGrid,
    );
    assert!(
        matches!(r, Err(Error::Capacity { .. })),
        "image past the limits: {:?}",
        r.map(|x| x.0)
    );
    good(&mut ctx, "image past the limits");
    let mut px = vec![0u8; 4 * (wh.0 * wh.1) as usize];
    let job = DeferredJob {
        frame: &f,
        lights: &[],
        primary: PrimaryPass::Pgrid,
        shadow: ShadowPass::LightGrid,
    };
    assert!(matches!(
        ctx.render_deferred(&job, &mut px, 4 * wh.0 as usize - 4, &mut OnCaller),
        Err(Error::InvalidArgument(_))
    ));
    assert!(matches!(
        ctx.render_deferred(&job, &mut px[4..], 4 * wh.0 as usize, &mut OnCaller),
        Err(Error::InvalidArgument(_))
    ));
    good(&mut ctx, "bad framebuffer");

    // A tracing tile wider than Limits::max_tile.
    {
        let mut l = Limits::for_triangles(s.triangles());
        l.max_vertices = (s.vertices.len() / 3) as u32;
        l.structures = Limits::BVH | Limits::PGRID;
        l.max_image_width = wh.0;
        l.max_image_height = wh.1;
        l.max_tile = 16;
        let mut c2 = OwnedContext::new(&l).unwrap();
        build_bvh(&mut c2, s, TriTest::MollerTrumbore);
        for (tile, group) in [(16, 2), (8, 4), (32, 1)] {
            c2.build_pgrid(&s.scene(), &PgridParams { tile, group, ..mt })
                .unwrap();
            let r = deferred(&mut c2, &f, &[], PrimaryPass::Pgrid, ShadowPass::LightGrid);
            assert!(
                is_invalid(&r),
                "tile {tile} x group {group} > max_tile 16: {:?}",
                r.map(|x| x.0)
            );
            // Traced passes do not use the pgrid's tile.
            let (_, img) = deferred(
                &mut c2,
                &f,
                &[],
                PrimaryPass::Traced(bvh16),
                ShadowPass::Traced(bvh16),
            )
            .unwrap();
            assert!(
                img == want,
                "traced frame after tile {tile} x group {group}"
            );
        }
        let r = deferred(
            &mut c2,
            &f,
            &[],
            PrimaryPass::Traced(TraceParams::bvh(Method::BvhRanged, 32)),
            ShadowPass::Traced(bvh16),
        );
        assert!(
            is_invalid(&r),
            "packet 32 > max_tile 16: {:?}",
            r.map(|x| x.0)
        );
        c2.build_pgrid(
            &s.scene(),
            &PgridParams {
                tile: 8,
                group: 2,
                ..mt
            },
        )
        .unwrap();
        let (_, img) =
            deferred(&mut c2, &f, &[], PrimaryPass::Pgrid, ShadowPass::LightGrid).unwrap();
        assert!(img == want, "tile 8 x group 2 within max_tile 16");
    }

    // Pools too small for the grids: a Capacity error, then traced frames work.
    {
        let mut l = Limits::for_triangles(s.triangles());
        l.max_vertices = (s.vertices.len() / 3) as u32;
        l.structures = Limits::BVH | Limits::PGRID;
        l.max_image_width = wh.0;
        l.max_image_height = wh.1;
        l.max_pgrid_refs = 16;
        let mut c2 = OwnedContext::new(&l).unwrap();
        build_bvh(&mut c2, s, TriTest::MollerTrumbore);
        c2.build_pgrid(&s.scene(), &mt).unwrap();
        for (p, sh) in [
            (PrimaryPass::Pgrid, ShadowPass::LightGrid),
            (PrimaryPass::Traced(bvh16), ShadowPass::LightGrid),
        ] {
            let r = deferred(&mut c2, &f, &[], p, sh);
            assert!(
                matches!(r, Err(Error::Capacity { .. })),
                "16 pgrid refs, {p:?} {sh:?}: {:?}",
                r.map(|x| x.0)
            );
        }
        let (_, img) = deferred(
            &mut c2,
            &f,
            &[],
            PrimaryPass::Traced(bvh16),
            ShadowPass::Traced(bvh16),
        )
        .unwrap();
        assert!(img == want, "traced frame after a capacity error");
    }
    good(&mut ctx, "everything");
}

// ---------------------------------------------------------------------------
// Numerical corners.

/// One Pgrid + LightGrid frame of `v` with `lights`, its hits and shadow
/// bits checked against the BVH single ray (built by the caller with
/// `p.test`). Returns (hits, shadow counts); panics with the mismatches.
fn exact_frame(
    ctx: &mut OwnedContext,
    s: &TestScene,
    v: &View,
    wh: (u32, u32),
    lights: &[PointLight],
    p: &PgridParams,
    what: &str,
) -> (usize, ShadowCount) {
    let want = reference_hits(ctx, v, wh);
    ctx.build_pgrid(&s.scene(), p).unwrap();
    let f = frame(v, s.light, wh, true);
    let (info, _) = deferred(ctx, &f, lights, PrimaryPass::Pgrid, ShadowPass::LightGrid)
        .unwrap_or_else(|e| panic!("{what}: {e}"));
    assert_none(
        &primary_mismatches(ctx, &want, wh),
        want.len(),
        &format!("{what}: camera rays"),
    );
    let ls = if lights.is_empty() {
        core::slice::from_ref(&f.light)
    } else {
        lights
    };
    let mut bad = Vec::new();
    let c = shadow_mismatches(ctx, ls, wh, &mut bad);
    assert_none(&bad, c.rays, &format!("{what}: shadow rays"));
    assert_eq!(info.shadow_rays, c.rays as u64, "{what}");
    (want.iter().filter(|h| h.is_hit()).count(), c)
}

/// A scene moved by `off` (vertices, views and light).
fn moved(s: &TestScene, off: Vec3) -> TestScene {
    TestScene {
        name: format!("{} + {off}", s.name),
        vertices: s
            .vertices
            .chunks_exact(3)
            .flat_map(|p| (Vec3::new(p[0], p[1], p[2]) + off).to_array())
            .collect(),
        indices: s.indices.clone(),
        views: s
            .views
            .iter()
            .map(|(n, v)| {
                (
                    n.clone(),
                    View {
                        eye: v.eye + off,
                        look_at: v.look_at + off,
                        ..*v
                    },
                )
            })
            .collect(),
        light: s.light + off,
    }
}

/// Scenes 1000 diagonals from the origin (large world
/// coordinates): f32 rounding of the vertices is large next to the scene,
/// yet both grids must list every triangle a ray's test can hit.
#[test]
fn scenes_far_from_the_origin_are_exact() {
    let out = par_map(&builtin_scenes(), |s| {
        let (lo, hi) = bounds(s);
        let size = (hi - lo).length();
        let mut r = String::new();
        for k in [1e3f32] {
            let m = moved(s, Vec3::new(0.7, -0.4, 0.6) * size * k);
            let mut ctx = context(&m, BUILTIN_WH, Limits::BVH);
            for test in [TriTest::MollerTrumbore, TriTest::Watertight] {
                build_bvh(&mut ctx, &m, test);
                for (vname, v) in &m.views {
                    let what = format!("{} {vname} {test:?}", m.name);
                    let (hits, c) =
                        exact_frame(&mut ctx, &m, v, BUILTIN_WH, &[], &pgrid_params(test), &what);
                    r += &format!("{what}: {hits} hits, {c:?}\n");
                }
            }
        }
        r
    });
    for r in out {
        print!("{r}");
    }
}

/// Fields of view from 0.01 to 179 degrees.
#[test]
fn extreme_fields_of_view_are_exact() {
    let out = par_map(&builtin_scenes(), |s| {
        let mut ctx = context(s, BUILTIN_WH, Limits::BVH);
        let mut r = String::new();
        for test in [TriTest::MollerTrumbore, TriTest::Watertight] {
            build_bvh(&mut ctx, s, test);
            for (vname, v) in &s.views {
                for fov in [0.01f32, 0.2, 5.0, 150.0, 179.0] {
                    let v = View {
                        fov_y_deg: fov,
                        ..*v
                    };
                    let what = format!("{} {vname} fov {fov} {test:?}", s.name);
                    let (hits, c) =
                        exact_frame(&mut ctx, s, &v, BUILTIN_WH, &[], &pgrid_params(test), &what);
                    r += &format!("{what}: {hits} hits, {c:?}\n");
                }
            }
        }
        r
    });
    for r in out {
        print!("{r}");
    }
}

/// Where the triangle seen in view 0's centre is: its vertices, centroid,
/// unit normal, and a unit vector along an edge.
fn centre_triangle(ctx: &mut OwnedContext, s: &TestScene) -> ([Vec3; 3], Vec3, Vec3, Vec3) {
    let want = reference_hits(ctx, &s.views[0].1, BUILTIN_WH);
    let prim = want[want.len() / 2..]
        .iter()
        .chain(&want)
        .find(|h| h.is_hit())
        .unwrap()
        .prim;
    let t = vertices(s, prim);
    let n = (t[1] - t[0]).cross(t[2] - t[0]).normalize();
    (t, (t[0] + t[1] + t[2]) / 3.0, n, (t[1] - t[0]).normalize())
}

fn looking(eye: Vec3, look: Vec3) -> View {
    let up = if (look - eye).normalize().z.abs() > 0.9 {
        Vec3::Y
    } else {
        Vec3::Z
    };
    View {
        eye,
        look_at: look,
        up,
        fov_y_deg: 60.0,
    }
}

/// Eyes a hair (1e-5 of the scene) in front of and behind a surface,
/// looking across it, into it, away from it and at the scene centre; lights
/// at the eye, a hair off the surface, on a vertex and 10 diagonals away.
#[test]
fn eyes_and_lights_a_hair_off_a_surface_are_exact() {
    let out = par_map(&builtin_scenes(), |s| {
        let mut ctx = context(s, BUILTIN_WH, Limits::BVH);
        let (lo, hi) = bounds(s);
        let (c, size) = (0.5 * (lo + hi), (hi - lo).length());
        let mut r = String::new();
        for test in [TriTest::MollerTrumbore, TriTest::Watertight] {
            build_bvh(&mut ctx, s, test);
            let (t, centroid, n, along) = centre_triangle(&mut ctx, s);
            let hair = 1e-5 * size;
            for (ename, eye) in [
                ("front", centroid + n * hair),
                ("back", centroid - n * hair),
            ] {
                for (dname, look) in [
                    ("across", eye + along),
                    ("into", eye - n),
                    ("out", eye + n),
                    ("centre", c),
                ] {
                    let lights = [
                        PointLight::new(eye.to_array(), [1.0; 3]),
                        PointLight::new((centroid + n * hair).to_array(), [1.0; 3]),
                        PointLight::new((centroid - n * hair).to_array(), [1.0; 3]),
                        PointLight::new((c + 10.0 * (hi - lo)).to_array(), [1.0; 3]),
                        PointLight::new(t[2].to_array(), [1.0; 3]),
                    ];
                    let what = format!("{} eye a hair {ename} looking {dname} {test:?}", s.name);
                    let (hits, c) = exact_frame(
                        &mut ctx,
                        s,
                        &looking(eye, look),
                        BUILTIN_WH,
                        &lights,
                        &pgrid_params(test),
                        &what,
                    );
                    r += &format!("{what}: {hits} hits, {c:?}\n");
                }
            }
        }
        r
    });
    for r in out {
        print!("{r}");
    }
}

/// The eye exactly on a surface (a vertex of the triangle seen in view 0's
/// centre, and its centroid), looking across the surface, into it, away
/// from it and at the scene centre. Camera rays start on the triangles
/// through the eye, which the triangle tests hit at t = 0 (or -0, since
/// tmin = 0 is inclusive): the BVH single ray reports the lowest such id,
/// so the perspective grid must list those triangles too. Camera rays only.
#[test]
fn camera_on_a_surface_sees_what_the_single_ray_sees() {
    let mut failed = Vec::new();
    let mut frames = 0;
    for s in builtin_scenes() {
        let mut ctx = context(&s, BUILTIN_WH, Limits::BVH);
        let (lo, hi) = bounds(&s);
        let c = 0.5 * (lo + hi);
        for test in [TriTest::MollerTrumbore, TriTest::Watertight] {
            build_bvh(&mut ctx, &s, test);
            let (t, centroid, n, along) = centre_triangle(&mut ctx, &s);
            ctx.build_pgrid(&s.scene(), &pgrid_params(test)).unwrap();
            for (ename, eye) in [("vertex", t[0]), ("centroid", centroid)] {
                for (dname, look) in [
                    ("across", eye + along),
                    ("into", eye - n),
                    ("out", eye + n),
                    ("centre", c),
                ] {
                    let v = looking(eye, look);
                    let want = reference_hits(&mut ctx, &v, BUILTIN_WH);
                    let f = frame(&v, s.light, BUILTIN_WH, false);
                    deferred(&mut ctx, &f, &[], PrimaryPass::Pgrid, ShadowPass::LightGrid).unwrap();
                    let bad = primary_mismatches(&ctx, &want, BUILTIN_WH);
                    frames += 1;
                    if !bad.is_empty() {
                        failed.push(format!(
                            "{} eye on {ename} ({eye}) looking {dname} {test:?}: {} of {} pixels differ, e.g. {}",
                            s.name,
                            bad.len(),
                            want.len(),
                            bad[0]
                        ));
                    }
                }
            }
        }
    }
    assert!(
        failed.is_empty(),
        "{} of {frames} frames differ from the BVH single ray:\n  {}",
        failed.len(),
        failed.join("\n  ")
    );
}

/// Scenes with triangles every structure excludes (zero area, a repeated
/// vertex, a collinear one), mixed in among the real ones: ids are the
/// caller's, excluded triangles never hit or shadow.
#[test]
fn excluded_triangles_are_skipped_with_the_callers_ids() {
    for s in builtin_scenes() {
        let mut m = TestScene {
            name: format!("{} with degenerate triangles", s.name),
            vertices: s.vertices.clone(),
            indices: Vec::new(),
            views: s.views.clone(),
            light: s.light,
        };
        let (lo, hi) = bounds(&s);
        let base = (m.vertices.len() / 3) as u32;
        for p in [lo, hi, 0.5 * (lo + hi), 0.25 * lo + 0.75 * hi] {
            m.vertices.extend(p.to_array());
        }
        for (k, tri) in s.indices.chunks_exact(3).enumerate() {
            m.indices.extend(tri);
            match k % 5 {
                0 => m.indices.extend([tri[0], tri[0], tri[1]]),
                2 => m.indices.extend([base, base + 2, base + 1]), // collinear, across the scene
                4 => m.indices.extend([tri[2], tri[2], tri[2]]),
                _ => {}
            }
        }
        let mut ctx = context(&m, BUILTIN_WH, Limits::BVH);
        let info = {
            build_bvh(&mut ctx, &m, TriTest::Watertight);
            ctx.build_pgrid(&m.scene(), &pgrid_params(TriTest::Watertight))
                .unwrap()
        };
        assert!(info.excluded > 0, "{}: {info:?}", m.name);
        for (vname, v) in &m.views {
            let what = format!("{} {vname}", m.name);
            let lights = [
                PointLight::new(m.light.to_array(), [1.0; 3]),
                PointLight::new((0.5 * (lo + hi)).to_array(), [1.0; 3]),
            ];
            exact_frame(
                &mut ctx,
                &m,
                v,
                BUILTIN_WH,
                &lights,
                &pgrid_params(TriTest::Watertight),
                &what,
            );
            // Hits name real triangles.
            for y in 0..BUILTIN_WH.1 {
                for x in 0..BUILTIN_WH.0 {
                    let (h, _) = ctx.deferred_pixel(x, y).unwrap();
                    if h.is_hit() {
                        let t = vertices(&m, h.prim);
                        assert!(
                            (t[1] - t[0]).cross(t[2] - t[0]).length() > 0.0,
                            "{what}: hit {}",
                            h.prim
                        );
                    }
                }
            }
        }
    }
}

/// Images one pixel wide or high.
#[test]
fn one_pixel_wide_and_high_images_are_exact() {
    for s in builtin_scenes() {
        for wh in [(1, 67), (67, 1), (2, 130)] {
            let mut ctx = context(&s, wh, Limits::BVH);
            build_bvh(&mut ctx, &s, TriTest::MollerTrumbore);
            for (tile, group) in [(8, 2), (32, 2), (2, 1)] {
                for (vname, v) in &s.views {
                    let what = format!("{} {vname} {wh:?} tile {tile} group {group}", s.name);
                    let p = PgridParams {
                        tile,
                        group,
                        ..pgrid_params(TriTest::MollerTrumbore)
                    };
                    let lights = [
                        PointLight::new(s.light.to_array(), [1.0; 3]),
                        PointLight::new(v.eye.to_array(), [1.0; 3]),
                    ];
                    exact_frame(&mut ctx, &s, v, wh, &lights, &p, &what);
                }
            }
        }
    }
}

/// The sun-like point lights of the distant-light tests: `k` scene
/// diagonals from the centre.
fn distant_light(s: &TestScene, k: f32) -> PointLight {
    let (lo, hi) = bounds(s);
    let dir = Vec3::new(0.3, 0.5, 0.8).normalize();
    PointLight::new(
        (0.5 * (lo + hi) + dir * k * (hi - lo).length()).to_array(),
        [1.0; 3],
    )
}

/// A distant, sun-like point light (100 scene diagonals away) with the
/// default pools (`Limits::for_triangles` plus PGRID, the image size) and
/// the default `PgridParams`: the frame must render. A light 10 diagonals
/// away fits in the same pools; the pairs needed grow with the distance,
/// since the depth padding of light-grid slices (`DEPTH_PAD`) is relative
/// to the distance from the light: for a far light every triangle spans
/// most distance slices (with one light slice the same frame needs 20 to
/// 30 times fewer pairs, printed).
#[test]
fn distant_light_fits_the_default_pools() {
    let mut failed = Vec::new();
    for s in builtin_scenes() {
        let mut l = Limits::for_triangles(s.triangles());
        l.max_vertices = (s.vertices.len() / 3) as u32;
        l.structures = Limits::BVH | Limits::PGRID;
        l.max_image_width = BUILTIN_WH.0;
        l.max_image_height = BUILTIN_WH.1;
        let mut ctx = OwnedContext::new(&l).unwrap();
        build_bvh(&mut ctx, &s, TriTest::MollerTrumbore);
        for (vname, v) in &s.views {
            let mut refs = Vec::new();
            for (k, slices) in [(10.0f32, 32), (100.0, 32), (100.0, 1)] {
                let p = PgridParams {
                    light_slices: slices,
                    ..pgrid_params(TriTest::MollerTrumbore)
                };
                ctx.build_pgrid(&s.scene(), &p).unwrap();
                let f = frame(v, s.light, BUILTIN_WH, true);
                let light = distant_light(&s, k);
                match deferred(
                    &mut ctx,
                    &f,
                    &[light],
                    PrimaryPass::Pgrid,
                    ShadowPass::LightGrid,
                ) {
                    Ok((info, _)) => refs.push(format!("{k}/{slices}: {} pairs", info.light.refs)),
                    Err(e) => {
                        refs.push(format!("{k}/{slices}: {e}"));
                        if slices == 32 {
                            failed.push(format!(
                                "{} {vname}: light {k} diagonals away: {e} (default pool {})",
                                s.name,
                                l.pgrid_refs()
                            ));
                        }
                    }
                }
            }
            println!(
                "{} {vname} (diagonals/light slices): {}",
                s.name,
                refs.join(", ")
            );
        }
    }
    assert!(
        failed.is_empty(),
        "{} frames fail with the default pools:\n  {}",
        failed.len(),
        failed.join("\n  ")
    );
}

/// Shadow bits of distant lights (30 and 100 scene diagonals away, pools
/// large enough: one light slice) equal BVH single-ray occlusion of the
/// same rays, as for near lights.
#[test]
fn distant_light_shadows_equal_single_ray_occlusion() {
    let mut failed = Vec::new();
    for s in builtin_scenes() {
        let mut ctx = context(&s, BUILTIN_WH, Limits::BVH);
        for test in [TriTest::MollerTrumbore, TriTest::Watertight] {
            build_bvh(&mut ctx, &s, test);
            let p = PgridParams {
                light_slices: 1,
                ..pgrid_params(test)
            };
            ctx.build_pgrid(&s.scene(), &p).unwrap();
            for (vname, v) in &s.views {
                for k in [30.0f32, 100.0] {
                    let light = distant_light(&s, k);
                    let f = frame(v, s.light, BUILTIN_WH, true);
                    deferred(
                        &mut ctx,
                        &f,
                        &[light],
                        PrimaryPass::Pgrid,
                        ShadowPass::LightGrid,
                    )
                    .unwrap();
                    let mut bad = Vec::new();
                    let n = shadow_mismatches(&mut ctx, &[light], BUILTIN_WH, &mut bad);
                    if !bad.is_empty() {
                        failed.push(format!(
                            "{} {vname} {test:?} light {k} diagonals away: {} of {} shadow rays differ, e.g. {}",
                            s.name,
                            bad.len(),
                            n.rays,
                            bad[0]
                        ));
                    }
                }
            }
        }
    }
    assert!(
        failed.is_empty(),
        "{} frames differ:\n  {}",
        failed.len(),
        failed.join("\n  ")
    );
}

// ---------------------------------------------------------------------------
// Joined frames: a deferred frame's phases on workers the caller joins (`Par`).

/// A `Par` of real threads: each run spawns `self.0 - 1` scoped threads and
/// runs worker 0 on the caller.
struct Spawn(usize);

impl sheaf::mem::par::Par for Spawn {
    fn workers(&self) -> usize {
        self.0
    }
    fn run(&self, task: &(dyn Fn(usize) + Sync)) {
        std::thread::scope(|s| {
            for w in 1..self.0 {
                s.spawn(move || task(w));
            }
            task(0);
        });
    }
}

/// A `Par` running every worker on the calling thread, backwards.
struct Backwards(usize);

impl sheaf::mem::par::Par for Backwards {
    fn workers(&self) -> usize {
        self.0
    }
    fn run(&self, task: &(dyn Fn(usize) + Sync)) {
        (0..self.0).rev().for_each(task)
    }
}

/// A frame's statistics (without times), image, and every pixel's hit and
/// shadow bits.
type JoinedFrame = (DeferredInfo, Vec<u8>, Vec<(Hit, u8)>);

/// A frame on `par`'s workers, its image and every pixel's hit and bits.
fn joined_frame(
    ctx: &mut OwnedContext,
    job: &DeferredJob<'_>,
    par: &dyn sheaf::mem::par::Par,
) -> sheaf::Result<JoinedFrame> {
    let f = job.frame;
    let stride = f.width as usize * 4;
    let mut px = vec![0u8; stride * f.height as usize];
    let mut info = ctx.render_deferred(job, &mut px, stride, &mut sheaf::OnPar(par))?;
    info.times = Default::default();
    let all = (0..f.height)
        .flat_map(|y| (0..f.width).map(move |x| (x, y)))
        .map(|(x, y)| ctx.deferred_pixel(x, y).unwrap())
        .collect();
    Ok((info, px, all))
}

/// Frames on 2, 3 and 7 workers (real threads, and one thread running the
/// workers backwards) equal the calling thread's: pixels, hits, shadow bits
/// and the grids' and the reordering's statistics; two lights (one a
/// spot), small chunks, all light tiles. With the pair pool cut to exactly
/// the pairs the grids need, the workers' even regions overflow and they
/// map again at exact offsets: the same frame; one pair fewer fails alike.
#[test]
fn joined_frames_equal_the_calling_threads() {
    for s in builtin_scenes() {
        let wh = BUILTIN_WH;
        let mut ctx = context(&s, wh, Limits::BVH);
        let params = PgridParams {
            light_tiles: 64,
            chunk: 16,
            ..pgrid_params(TriTest::MollerTrumbore)
        };
        ctx.build_pgrid(&s.scene(), &params).unwrap();
        let (_, v) = &s.views[0];
        let f = frame(v, s.light, wh, true);
        let (lo, hi) = bounds(&s);
        let mut spot = PointLight::new(((lo + hi) * 0.5 + (hi - lo) * 0.7).to_array(), [0.5; 3]);
        spot.spot_direction = ((lo + hi) * 0.5 - Vec3::from(spot.position)).to_array();
        spot.spot_angle_deg = 40.0;
        let lights = [f.light, spot];
        let job = DeferredJob {
            frame: &f,
            lights: &lights,
            primary: PrimaryPass::Pgrid,
            shadow: ShadowPass::LightGrid,
        };
        let want = joined_frame(&mut ctx, &job, &sheaf::mem::par::Serial).unwrap();
        assert!(want.0.shadow_rays > 0, "{}: no shadow rays", s.name);
        let check = |ctx: &mut OwnedContext, what: &str| {
            for (name, par) in [
                ("2 threads", &Spawn(2) as &dyn sheaf::mem::par::Par),
                ("3 threads", &Spawn(3)),
                ("7 backwards", &Backwards(7)),
            ] {
                let got = joined_frame(ctx, &job, par).unwrap();
                assert_eq!(got.0, want.0, "{} {what} {name}: frame statistics", s.name);
                assert!(got.1 == want.1, "{} {what} {name}: image differs", s.name);
                assert!(
                    got.2 == want.2,
                    "{} {what} {name}: hits or bits differ",
                    s.name
                );
            }
        };
        check(&mut ctx, "");
        // Exactly the pairs of the larger grid: the regions overflow.
        // (The frame reports the last light's grid: each light alone.)
        let mut refs = want.0.camera.refs;
        for l in &lights {
            let one = DeferredJob {
                lights: core::slice::from_ref(l),
                ..job
            };
            let (info, ..) = joined_frame(&mut ctx, &one, &sheaf::mem::par::Serial).unwrap();
            refs = refs.max(info.light.refs);
        }
        let mut l = Limits::for_triangles(s.triangles());
        l.max_vertices = (s.vertices.len() / 3) as u32;
        l.structures = Limits::BVH | Limits::PGRID;
        l.max_image_width = wh.0;
        l.max_image_height = wh.1;
        l.max_pgrid_refs = refs;
        let mut tight = OwnedContext::new(&l).unwrap();
        tight.build_pgrid(&s.scene(), &params).unwrap();
        check(&mut tight, "exact pool");
        l.max_pgrid_refs = refs - 1;
        let mut short = OwnedContext::new(&l).unwrap();
        short.build_pgrid(&s.scene(), &params).unwrap();
        let serial = joined_frame(&mut short, &job, &sheaf::mem::par::Serial).map(|_| ());
        assert!(
            matches!(serial, Err(Error::Capacity { .. })),
            "{}: {serial:?}",
            s.name
        );
        for par in [&Spawn(3) as &dyn sheaf::mem::par::Par, &Backwards(7)] {
            let got = joined_frame(&mut short, &job, par).map(|_| ());
            assert_eq!(format!("{got:?}"), format!("{serial:?}"), "{}", s.name);
        }
    }
}

/// A context for no triangles and an empty scene: joined deferred frames
/// (both grid passes, and a traced camera pass with light-grid shadows)
/// render the sky on any worker count, as the calling thread does.
#[test]
fn joined_frames_of_an_empty_scene() {
    let wh = (37, 23);
    let mut l = Limits::for_triangles(0);
    l.structures = Limits::BVH | Limits::PGRID;
    l.max_image_width = wh.0;
    l.max_image_height = wh.1;
    let mut ctx = OwnedContext::new(&l).unwrap();
    let empty = sheaf::Scene::from_f32(&[], &[]).unwrap();
    ctx.build_pgrid(&empty, &pgrid_params(TriTest::MollerTrumbore))
        .unwrap();
    ctx.build_bvh(&empty, &BvhParams::default()).unwrap();
    let s = &builtin_scenes()[0];
    let f = frame(&s.views[0].1, s.light, wh, true);
    for primary in [
        PrimaryPass::Pgrid,
        PrimaryPass::Traced(TraceParams::bvh(Method::BvhRanged, 8)),
    ] {
        let job = DeferredJob {
            frame: &f,
            lights: &[],
            primary,
            shadow: ShadowPass::LightGrid,
        };
        let want = joined_frame(&mut ctx, &job, &sheaf::mem::par::Serial).unwrap();
        assert_eq!(want.0.hits, 0);
        for par in [&Spawn(3) as &dyn sheaf::mem::par::Par, &Backwards(16)] {
            let got = joined_frame(&mut ctx, &job, par).unwrap();
            assert_eq!(got.0, want.0);
            assert!(got.1 == want.1 && got.2 == want.2);
        }
    }
}
