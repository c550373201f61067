//! Eric Haines' Standard Procedural Databases, tessellated to triangles.
//!
//! Source: erich666/StandardProceduralDatabases (`tetra.c`, `balls.c`,
//! `gears.c`, `libvec.c`; CC0/MIT) and Haines, "A Proposal for Standard
//! Graphics Environments", IEEE CG&A 7(11), 1987. Coordinates, views and
//! lights are SPD's: +Z up (tetra's view has its own up vector), 45 degree
//! field of view. Geometry is built in f64 like the C code and stored as f32.
//!
//! SPD's matrices are row-vector (`p * M`); its `lib_create_axis_rotate_matrix`
//! and `lib_create_rotate_matrix` are the transposes of glam's column-vector
//! matrices, so `M_glam * p` gives the same right-handed rotation.
//!
//! # Deviations
//! - balls: spheres are cube-projected meshes (SPD's OUTPUT_PATCHES idea,
//!   Readme "File Structure"), not curved primitives; see [`balls`].
//! - gears: each concave 144-gon face is fanned from an added centre vertex;
//!   the side quads are split into two triangles. SPD emits the bottom face's
//!   vertices in reverse order; we reuse the top ring dropped by the
//!   thickness (the same point set, proven in [`gears`]).
//! - Only each database's first light is exported.

use super::{Mesh, View};
use glam::{DMat3, DVec3, Vec3};
use std::f64::consts::PI;

/// Tetra's light (SPD's only one).
pub const TETRA_LIGHT: Vec3 = Vec3::new(2.0, -18.0, -5.0);
/// Balls' first of three SPD lights.
pub const BALLS_LIGHT: Vec3 = Vec3::new(4.0, 3.0, 2.0);
/// Gears' first of five SPD lights.
pub const GEARS_LIGHT: Vec3 = Vec3::new(2.0, 4.0, 4.0);

fn f32v(p: DVec3) -> Vec3 {
    p.as_vec3()
}

// ---------------------------------------------------------------- tetra

/// Sierpinski tetrahedron (`tetra.c`): centre 0, half-size 1, recursed into
/// the 4 sub-tetrahedra at `c + (±s/2)` with sign product +1. `4^sf`
/// triangles (`sf` 0 is treated as 1, as in SPD where depth <= 1 is a leaf),
/// 4 unshared vertices per leaf tetrahedron.
pub fn tetra(sf: u32) -> Mesh {
    let sf = sf.max(1);
    let leaves = 4usize.pow(sf - 1);
    let mut m = Mesh::with_capacity(4 * leaves, 4 * leaves);
    tetra_rec(&mut m, sf, DVec3::ZERO, 1.0);
    m
}

fn tetra_rec(m: &mut Mesh, depth: u32, c: DVec3, s: f64) {
    // Cube corners with x*y*z == +1, in SPD's loop order (x, then y, then z).
    let mut corners = [DVec3::ZERO; 4];
    let mut n = 0;
    for x in [-1.0, 1.0] {
        for y in [-1.0, 1.0] {
            for z in [-1.0f64, 1.0] {
                if x * y * z > 0.0 {
                    corners[n] = DVec3::new(x, y, z);
                    n += 1;
                }
            }
        }
    }
    if depth <= 1 {
        let base = m.vertex_count() as u32;
        for k in corners {
            m.push_vertex(f32v(c + k * s));
        }
        // SPD's face order: 0 1 2, 3 2 1, 2 3 0, 1 0 3 (odd faces reversed).
        for f in 0..4u32 {
            let (a, b, cc) = (f % 4, (f + 1) % 4, (f + 2) % 4);
            let (a, cc) = if f % 2 == 1 { (cc, a) } else { (a, cc) };
            m.push_triangle(base + a, base + b, base + cc);
        }
    } else {
        for k in corners {
            tetra_rec(m, depth - 1, c + k * (s / 2.0), s / 2.0);
        }
    }
}

/// Tetra views: SPD's (Kay & Kajiya's, with its tilted up vector), a
/// close-up, one from inside the central octahedral hole, and one grazing
/// the base face (the face opposite SPD's up direction).
pub fn tetra_views() -> Vec<View> {
    let up = Vec3::new(-0.816497, -0.816497, 0.816497);
    let spd = View {
        eye: Vec3::new(1.022846, -3.177154, -2.174512),
        look_at: Vec3::new(-0.004103, -0.004103, 0.216539),
        up,
        fov_y_deg: View::SPD_FOV_Y_DEG,
    };
    let close = View {
        eye: spd.look_at.lerp(spd.eye, 0.45),
        ..spd
    };
    // The big tetrahedron minus its 4 corner sub-tetrahedra is the
    // octahedron |x|+|y|+|z| <= 1; its centre is empty at every sf >= 2.
    let inside = View {
        eye: Vec3::new(0.02, -0.03, 0.01),
        look_at: Vec3::new(0.5, -0.5, -0.2),
        ..spd
    };
    // Base face: corners (1,1,1), (1,-1,-1), (-1,1,-1), plane x+y-z = 1,
    // `up` points from it to the apex. Look across it from beyond the edge
    // opposite (1,1,1), a hair above the plane.
    let u = up.normalize();
    let centroid = Vec3::new(1.0, 1.0, -1.0) / 3.0;
    let along = Vec3::new(-1.0, -1.0, -2.0).normalize(); // in the plane, away from (1,1,1)
    let grazing = View {
        eye: centroid + 3.0 * along + 0.04 * u,
        look_at: centroid + 0.12 * u,
        ..spd
    };
    vec![spd, close, inside, grazing]
}

// ---------------------------------------------------------------- balls

/// The 9 child directions of `balls.c`'s `create_objset`: the trio
/// (1,1,0), (1,0,-1), (0,1,-1) / sqrt 2, rotated about (1,-1,0) by
/// asin(2/sqrt 6), then copied at 0, 120 and 240 degrees about Z.
fn objset() -> [DVec3; 9] {
    let d = 1.0 / 2f64.sqrt();
    let tilt = DMat3::from_axis_angle(
        DVec3::new(1.0, -1.0, 0.0).normalize(),
        (2.0 / 6f64.sqrt()).asin(),
    );
    let trio = [
        DVec3::new(d, d, 0.0),
        DVec3::new(d, 0.0, -d),
        DVec3::new(0.0, d, -d),
    ]
    .map(|v| tilt * v);
    let mut set = [DVec3::ZERO; 9];
    for s in 0..3 {
        let rz = DMat3::from_rotation_z(s as f64 * 2.0 * PI / 3.0);
        for v in 0..3 {
            set[s * 3 + v] = rz * trio[v];
        }
    }
    set
}

/// Sphereflake spheres `(centre, radius)` in `balls.c`'s output order
/// (pre-order): root r = 0.5 at the origin growing along +Z; each child has
/// radius r/3 at distance r(1 + 1/3) along the parent's 9 directions, the
/// set rotated so +Z maps onto the parent's own direction. `sum 9^n, n = 0..=sf`
/// spheres.
pub fn sphereflake(sf: u32) -> Vec<(Vec3, f32)> {
    sphereflake_f64(sf)
        .into_iter()
        .map(|(c, r)| (f32v(c), r as f32))
        .collect()
}

fn sphereflake_f64(sf: u32) -> Vec<(DVec3, f64)> {
    let set = objset();
    let mut out = Vec::with_capacity(sphere_count(sf));
    flake(&mut out, sf, DVec3::ZERO, 0.5, DVec3::Z, &set);
    out
}

/// `sum 9^n, n = 0..=sf`.
pub fn sphere_count(sf: u32) -> usize {
    (0..=sf).map(|n| 9usize.pow(n)).sum()
}

fn flake(
    out: &mut Vec<(DVec3, f64)>,
    depth: u32,
    centre: DVec3,
    r: f64,
    dir: DVec3,
    set: &[DVec3; 9],
) {
    out.push((centre, r));
    if depth == 0 {
        return;
    }
    // balls.c's rotation from +Z to `dir`, epsilon tests included (child
    // directions come out a hair short of unit length).
    let m = if dir.z >= 0.9999 {
        DMat3::IDENTITY
    } else if dir.z <= -0.9999 {
        DMat3::from_rotation_y(PI)
    } else {
        DMat3::from_axis_angle(DVec3::Z.cross(dir).normalize(), DVec3::Z.dot(dir).acos())
    };
    let scale = r * (1.0 + 1.0 / 3.0);
    for &o in set {
        let p = m * o * scale + centre;
        flake(out, depth - 1, p, r / 3.0, (p - centre) / scale, set);
    }
}

/// Unit sphere tessellated by projecting a cube: each face is a `res x res`
/// grid of quads (uniform on the cube face), every grid point pushed out to
/// the sphere, each quad split into 2 triangles along its first diagonal.
/// Grid points on cube edges and corners are shared: `(res+1)^3 - (res-1)^3`
/// vertices, `12 res^2` triangles, all wound outward. No poles, so no
/// slivers (the reason SPD prefers it to a UV sphere, Readme "File Structure").
pub(crate) fn cube_sphere(res: u32) -> (Vec<DVec3>, Vec<u32>) {
    let n = res as usize + 1;
    let mut slot = vec![u32::MAX; n * n * n];
    let mut dirs = Vec::new();
    let mut idx = Vec::with_capacity(36 * n * n);
    // (fixed axis, at max?, tangent u, tangent v) with u x v = outward normal.
    let faces = [
        (0, true, 1, 2),
        (0, false, 2, 1),
        (1, true, 2, 0),
        (1, false, 0, 2),
        (2, true, 0, 1),
        (2, false, 1, 0),
    ];
    for (axis, at_max, ua, va) in faces {
        let mut id = |u: usize, v: usize| {
            let mut g = [0usize; 3];
            g[axis] = if at_max { res as usize } else { 0 };
            g[ua] = u;
            g[va] = v;
            let s = &mut slot[(g[0] * n + g[1]) * n + g[2]];
            if *s == u32::MAX {
                *s = dirs.len() as u32;
                let c =
                    DVec3::new(g[0] as f64, g[1] as f64, g[2] as f64) * (2.0 / res as f64) - 1.0;
                dirs.push(c.normalize());
            }
            *s
        };
        for v in 0..res as usize {
            for u in 0..res as usize {
                let (a, b, c, d) = (id(u, v), id(u + 1, v), id(u + 1, v + 1), id(u, v + 1));
                idx.extend_from_slice(&[a, b, c, a, c, d]);
            }
        }
    }
    (dirs, idx)
}

/// Sphereflake (`balls.c`) with the floor square ±12 at z = -0.5 (2
/// triangles, first) and `sum 9^n, n = 0..=sf` spheres, each a cube-projected
/// sphere with `sphere_res` subdivisions per cube-face edge (`12 res^2`
/// triangles per sphere; `sphere_res` 0 is treated as 1; SPD's own patch
/// output uses 4). Vertices lie on the true spheres, so the mesh is inscribed.
pub fn balls(sf: u32, sphere_res: u32) -> Mesh {
    let res = sphere_res.max(1);
    let (dirs, tmpl) = cube_sphere(res);
    let spheres = sphereflake_f64(sf);
    let mut m = Mesh::with_capacity(
        4 + dirs.len() * spheres.len(),
        2 + tmpl.len() / 3 * spheres.len(),
    );
    // SPD's corner order: (+,+), (-,+), (-,-), (+,-): counter-clockwise from above.
    let f = [(12.0, 12.0), (-12.0, 12.0), (-12.0, -12.0), (12.0, -12.0)]
        .map(|(x, y)| m.push_vertex(Vec3::new(x, y, -0.5)));
    m.push_quad(f[0], f[1], f[2], f[3]);
    for (c, r) in spheres {
        let base = m.vertex_count() as u32;
        for &d in &dirs {
            m.push_vertex(f32v(c + d * r));
        }
        m.indices.extend(tmpl.iter().map(|&i| base + i));
    }
    m
}

/// Balls views: SPD's, a close-up on the root's upper children, one from
/// among the spheres (inside the scene bounds, outside every sphere) and one
/// grazing the floor.
pub fn balls_views() -> Vec<View> {
    let spd = View::z_up(Vec3::new(2.1, 1.3, 1.7), Vec3::ZERO);
    let close = View::z_up(Vec3::new(1.05, 0.65, 0.95), Vec3::new(0.0, 0.0, 0.35));
    let inside = View::z_up(Vec3::new(1.1, -0.35, -0.2), Vec3::new(-0.4, 0.9, 0.05));
    let grazing = View::z_up(Vec3::new(7.0, 4.5, -0.45), Vec3::new(0.0, 0.0, -0.3));
    vec![spd, close, inside, grazing]
}

// ---------------------------------------------------------------- gears

const TEETH: usize = 36;
/// Outer tooth radius ratio: a hair under 1 so meshing gears never touch.
const OUTER_EDGE_RATIO: f64 = 0.995;
const INNER_EDGE_RATIO: f64 = 0.9;
const EDGE_DIFF: f64 = 1.0 - INNER_EDGE_RATIO;
const DEPTH_RATIO: f64 = 0.1;
/// Triangles per gear: 144 (top fan) + 144 (bottom fan) + 2 * 144 (sides).
pub const GEAR_TRIANGLES: usize = 4 * 4 * TEETH;

/// `gears.c`'s layout for size factor `sf` (>= 1): (outer radius R, first
/// centre, grid step, thickness).
fn gear_layout(sf: u32) -> (f64, DVec3, DVec3, f64) {
    let s = sf as f64;
    let r = 1.0 / (s - (s - 1.0) * EDGE_DIFF / 2.0);
    let first = DVec3::new(-1.0 + r, -1.0 + r, 1.0);
    let step = DVec3::new(r * (2.0 - EDGE_DIFF), r * (2.0 - EDGE_DIFF), -1.0 / s);
    let thickness = DEPTH_RATIO.min(1.0 / (2.0 * s));
    (r, first, step, thickness)
}

/// Gear set (`gears.c`): `sf^3` gears (`sf` 0 is treated as 1) on a grid,
/// then the ground square ±2 at z = 0 (2 triangles, last). Each gear's face
/// is SPD's concave 144-gon: per tooth, outer points at ±0.19 tooth angles
/// (radius 0.995R) and inner points at +0.3/+0.7 (0.9R). Every alternate gear
/// is turned half a tooth.
///
/// Triangulation: the 144 vertices are emitted at strictly increasing angle
/// about the gear centre (-0.19, 0.19, 0.3, 0.7, then 0.81 = next tooth's
/// -0.19), so the polygon is star-shaped about its centre and the fan from
/// an added centre vertex covers it exactly, without overlap. SPD's bottom
/// face runs its teeth at angle `-k` with negated offsets, giving angles
/// `j + {±0.19, 0.3, 0.7}` tooth angles again: the top ring's point set,
/// dropped by the thickness. Top faces face +Z, bottoms -Z, sides outward;
/// each side quad is SPD's `p_i, p_i - t, p_i+1 - t, p_i+1`. 576 triangles
/// and 290 vertices per gear.
pub fn gears(sf: u32) -> Mesh {
    let sf = sf.max(1);
    let (r, first, step, thickness) = gear_layout(sf);
    let n = (sf * sf * sf) as usize;
    let mut m = Mesh::with_capacity(n * (2 * 4 * TEETH + 2) + 4, n * GEAR_TRIANGLES + 2);
    for iz in 0..sf {
        for iy in 0..sf {
            for ix in 0..sf {
                let c = first + DVec3::new(ix as f64, iy as f64, iz as f64) * step;
                let offset = PI * ((ix + iy + iz) % 2) as f64 / TEETH as f64;
                gear(
                    &mut m,
                    c,
                    offset,
                    OUTER_EDGE_RATIO * r,
                    INNER_EDGE_RATIO * r,
                    thickness,
                );
            }
        }
    }
    let g = [(2.0, 2.0), (-2.0, 2.0), (-2.0, -2.0), (2.0, -2.0)]
        .map(|(x, y)| m.push_vertex(Vec3::new(x, y, 0.0)));
    m.push_quad(g[0], g[1], g[2], g[3]);
    m
}

fn gear(m: &mut Mesh, c: DVec3, offset: f64, outer: f64, inner: f64, thickness: f64) {
    let tooth = 2.0 * PI / TEETH as f64;
    let ring = 4 * TEETH as u32;
    let down = DVec3::new(0.0, 0.0, -thickness);
    let top_c = m.push_vertex(f32v(c));
    let top0 = m.vertex_count() as u32;
    for k in 0..TEETH {
        let a = offset + tooth * k as f64;
        for (da, rad) in [(-0.19, outer), (0.19, outer), (0.3, inner), (0.7, inner)] {
            let (s, co) = (a + da * tooth).sin_cos();
            m.push_vertex(f32v(c + DVec3::new(co * rad, s * rad, 0.0)));
        }
    }
    let bot_c = m.push_vertex(f32v(c + down));
    let bot0 = m.vertex_count() as u32;
    for i in 0..ring {
        let p = m.vertex(top0 as usize + i as usize);
        m.push_vertex(p + f32v(down));
    }
    for i in 0..ring {
        let j = (i + 1) % ring;
        m.push_triangle(top_c, top0 + i, top0 + j);
        m.push_triangle(bot_c, bot0 + j, bot0 + i);
        m.push_quad(top0 + i, bot0 + i, bot0 + j, top0 + j);
    }
}

/// Gears views for size factor `sf`: SPD's, a close-up on the first
/// (top-layer corner) gear, one between the top two layers of gears (inside
/// the scene bounds) and one grazing the ground under the lowest layer.
pub fn gears_views(sf: u32) -> Vec<View> {
    let sf = sf.max(1);
    let (r, first, step, thickness) = gear_layout(sf);
    let spd = View::z_up(Vec3::new(-1.1, -2.1, 2.6), Vec3::ZERO);
    let close = View::z_up(f32v(first + DVec3::new(-1.2, -2.0, 1.6) * r), f32v(first));
    // Mid-height of the gap under the top layer; with one layer, halfway
    // between it and the ground.
    let z = if sf >= 2 {
        (first.z - thickness + first.z + step.z) / 2.0
    } else {
        0.5
    };
    let z = z as f32;
    let inside = View::z_up(Vec3::new(0.0, -0.4, z), Vec3::new(0.8, 0.6, z - 0.05));
    let grazing = View::z_up(Vec3::new(-1.95, -1.7, 0.04), Vec3::new(1.0, 1.2, 0.08));
    vec![spd, close, inside, grazing]
}

#[cfg(test)]
mod tests {
    use super::super::check;
    use super::*;

    #[test]
    fn tetra_counts_and_lattice() {
        for sf in 1..=6 {
            let m = tetra(sf);
            assert_eq!(m.triangle_count(), 4usize.pow(sf));
            check::indices_in_range(&m);
        }
        assert_eq!(tetra(0).triangle_count(), 4);
        let m = tetra(6);
        check::mesh_sane(&m);
        assert_eq!(m.bounds(), (Vec3::splat(-1.0), Vec3::splat(1.0)));
        // Every vertex sits on the 2^-(sf-1) lattice: the build is exact.
        let cell = 1.0 / 32.0;
        assert!(m.vertices.iter().all(|&v| (v / cell).fract() == 0.0));
        // Leaves are regular tetrahedra with edge 2 * sqrt 2 * 2^-(sf-1).
        let [a, b, c] = m.triangle(0);
        let e = 2.0 * 2f32.sqrt() * cell;
        for d in [a.distance(b), b.distance(c), c.distance(a)] {
            assert!((d - e).abs() < 1e-6);
        }
    }

    #[test]
    fn tetra_views_sane() {
        let v = tetra_views();
        check::views_sane(&v);
        let m = tetra(6);
        assert!(check::inside(v[2].eye, m.bounds()));
        // The inside eye is in the central octahedral hole.
        assert!(v[2].eye.abs().element_sum() < 1.0);
        // Grazing: the view direction is within ~3 degrees of the base plane.
        let n = Vec3::new(1.0, 1.0, -1.0).normalize();
        let d = (v[3].look_at - v[3].eye).normalize();
        assert!(d.dot(n).abs() < 0.05);
    }

    #[test]
    fn objset_matches_spd() {
        let set = objset();
        // The classic flake: 3 children tilted up at z = sqrt(2/3) (trio
        // member 0 of each copy), 6 around the parent's equator.
        for (i, d) in set.iter().enumerate() {
            assert!((d.length() - 1.0).abs() < 1e-12);
            let z = if i % 3 == 0 {
                (2.0f64 / 3.0).sqrt()
            } else {
                0.0
            };
            assert!((d.z - z).abs() < 1e-12, "{i}: {d}");
        }
        // The trio is spread 120 degrees about Z.
        let rz = DMat3::from_rotation_z(2.0 * PI / 3.0);
        for v in 0..3 {
            assert!((rz * set[v] - set[3 + v]).length() < 1e-12);
        }
    }

    #[test]
    fn sphereflake_counts_and_tangency() {
        for sf in 0..=4 {
            assert_eq!(sphereflake_f64(sf).len(), sphere_count(sf));
        }
        assert_eq!(sphere_count(4), 7381); // balls.c's header table
        let s = sphereflake_f64(2);
        // Pre-order: sphere 1 is the root's first child, 2 its first grandchild.
        let (c0, r0) = s[0];
        let (c1, r1) = s[1];
        let (c2, r2) = s[2];
        assert_eq!((r0, r1, r2), (0.5, 0.5 / 3.0, 0.5 / 9.0));
        assert!((c0.distance(c1) - (r0 + r1)).abs() < 1e-12);
        assert!((c1.distance(c2) - (r1 + r2)).abs() < 1e-12);
        // No two spheres overlap (touching is allowed).
        for (i, &(a, ra)) in s.iter().enumerate() {
            for &(b, rb) in &s[i + 1..] {
                assert!(a.distance(b) >= ra + rb - 1e-9);
            }
        }
        // Nothing reaches below the floor.
        assert!(s.iter().all(|&(c, r)| c.z - r >= -0.5 - 1e-12));
    }

    #[test]
    fn cube_sphere_shape() {
        for res in 1..=4u32 {
            let (d, i) = cube_sphere(res);
            let n = res as usize;
            assert_eq!(d.len(), (n + 1).pow(3) - (n - 1).pow(3));
            assert_eq!(i.len(), 3 * 12 * n * n);
            // Outward winding: every normal points away from the centre.
            for t in i.chunks_exact(3) {
                let [a, b, c] = [d[t[0] as usize], d[t[1] as usize], d[t[2] as usize]];
                assert!((b - a).cross(c - a).dot(a + b + c) > 0.0);
            }
        }
    }

    #[test]
    fn balls_counts() {
        for (sf, res) in [(0, 1), (1, 2), (2, 3), (3, 2)] {
            let m = balls(sf, res);
            let per = 12 * (res * res) as usize;
            assert_eq!(m.triangle_count(), 2 + per * sphere_count(sf));
            check::indices_in_range(&m);
        }
        let m = balls(3, 2);
        check::mesh_sane(&m);
        let (lo, hi) = m.bounds();
        assert_eq!(
            (lo.x, lo.y, lo.z, hi.x, hi.y),
            (-12.0, -12.0, -0.5, 12.0, 12.0)
        );
    }

    #[test]
    fn balls_views_outside_spheres() {
        let v = balls_views();
        check::views_sane(&v);
        assert!(check::inside(v[2].eye, balls(3, 2).bounds()));
        for sf in [3, 4] {
            for (c, r) in sphereflake(sf) {
                for view in &v {
                    assert!(
                        view.eye.distance(c) > r * 1.05,
                        "eye {} in sphere {c} {r}",
                        view.eye
                    );
                }
            }
        }
        // Grazing: within ~2 degrees of the floor and above it.
        let d = (v[3].look_at - v[3].eye).normalize();
        assert!(d.z.abs() < 0.04 && v[3].eye.z > -0.5);
    }

    #[test]
    fn gears_counts() {
        for sf in 1..=4 {
            let m = gears(sf);
            let n = (sf * sf * sf) as usize;
            assert_eq!(m.triangle_count(), n * GEAR_TRIANGLES + 2);
            assert_eq!(m.vertex_count(), n * 290 + 4);
            check::indices_in_range(&m);
        }
        // SPD's table: sf 4 -> 128 faces + 9216 side quads + ground.
        assert_eq!(GEAR_TRIANGLES / 4, 144);
        let m = gears(4);
        check::mesh_sane(&m);
        let (lo, hi) = m.bounds();
        assert_eq!((lo, hi.x, hi.y), (Vec3::new(-2.0, -2.0, 0.0), 2.0, 2.0));
        assert!((hi.z - 1.0).abs() < 1e-6);
    }

    #[test]
    fn gear_faces_are_proper_fans() {
        // Each gear's 144 top fan triangles all turn counter-clockwise seen
        // from +Z and their angles at the centre sum to one full turn: the
        // fan tiles the star-shaped face exactly once. Bottoms mirror this.
        let m = gears(2);
        for g in 0..8 {
            let t0 = g * GEAR_TRIANGLES;
            let (mut top, mut bot) = (0.0f64, 0.0f64);
            for k in 0..144 {
                for (t, sign, sum) in [
                    (t0 + 4 * k, 1.0, &mut top),
                    (t0 + 4 * k + 1, -1.0, &mut bot),
                ] {
                    let [c, a, b] = m.triangle(t);
                    let (u, v) = ((a - c).truncate(), (b - c).truncate());
                    assert!(u.perp_dot(v) * sign > 0.0);
                    *sum += u.angle_to(v).abs() as f64;
                }
            }
            assert!(
                (top - 2.0 * PI).abs() < 1e-4 && (bot - 2.0 * PI).abs() < 1e-4,
                "{top} {bot}"
            );
        }
    }

    #[test]
    fn gears_views_clear_of_gears() {
        for sf in 1..=4 {
            let v = gears_views(sf);
            check::views_sane(&v);
            let (_, first, step, thickness) = gear_layout(sf);
            assert!(check::inside(v[2].eye, gears(sf).bounds()));
            // The inside eye is between gear slabs.
            for iz in 0..sf {
                let top = (first.z + iz as f64 * step.z) as f32;
                let e = v[2].eye.z;
                assert!(
                    e > top + 0.01 || e < top - thickness as f32 - 0.01,
                    "sf {sf}"
                );
            }
        }
    }
}
