//! A procedural animated scene: every frame moves or deforms most vertices,
//! so acceleration structures must be rebuilt per frame (the dynamic case;
//! animated by per-frame transforms, as Haines' SPD scenes can be).
//!
//! Content (+Z up, like the SPD scenes):
//! - a static ground grid, ±12 at z = 0;
//! - a deforming blob: a cube-projected sphere (as in [`super::spd::balls`])
//!   whose radius is modulated by travelling waves;
//! - two tori and four boxes orbiting the blob while spinning (rigid).
//!
//! Topology is fixed at construction; [`Animated::set_time`] only rewrites
//! vertex positions in place. Every motion rate is a whole multiple of
//! `2 pi / PERIOD`, so the animation loops and time is wrapped into one
//! period before use (f32 angles stay precise at any `t`).
//!
//! Clearances (so views never start inside an object): the blob stays within
//! radius 1.65 of its centre; boxes (bounding radius 0.64) orbit at 3.4; tori
//! (bounding radius 1.18) orbit at 6.0; the lowest any moving part reaches is
//! z = 0.1, above the ground.
#![forbid(unsafe_code)]

use super::{Mesh, View};
use glam::{Quat, Vec3};
use std::f32::consts::TAU;

/// Seconds after which the animation repeats exactly.
pub const PERIOD: f32 = 12.0;
/// Base angular rate: one turn per period.
const W: f32 = TAU / PERIOD;

const BLOB_CENTRE: Vec3 = Vec3::new(0.0, 0.0, 2.0);
const BLOB_RADIUS: f32 = 1.4;

/// A rigid motion: orbit about the Z axis with a vertical bob, spinning about
/// a fixed local axis. Rates are multiples of `W`.
#[derive(Clone, Copy, Debug)]
struct Orbit {
    radius: f32,
    height: f32,
    bob: f32,
    rate: f32,
    phase: f32,
    spin_axis: Vec3,
    spin_rate: f32,
}

impl Orbit {
    fn at(&self, t: f32) -> (Vec3, Quat) {
        let a = self.phase + self.rate * t;
        let (s, c) = a.sin_cos();
        let pos = Vec3::new(
            self.radius * c,
            self.radius * s,
            self.height + self.bob * (2.0 * a).sin(),
        );
        (
            pos,
            Quat::from_axis_angle(self.spin_axis, self.phase + self.spin_rate * t),
        )
    }
}

#[derive(Clone, Copy, Debug)]
enum Motion {
    /// `rest` holds unit directions from the blob centre.
    Blob,
    /// `rest` holds the part's vertices about its own origin.
    Rigid(Orbit),
}

/// One moving part: a contiguous vertex range of the mesh.
#[derive(Clone, Debug)]
struct Part {
    first: usize,
    rest: Vec<Vec3>,
    motion: Motion,
}

/// The animated scene. `mesh` always holds the current frame.
#[derive(Clone, Debug)]
pub struct Animated {
    pub mesh: Mesh,
    parts: Vec<Part>,
    time: f32,
}

/// Blob radius along unit direction `d` at wrapped time `t`: two travelling
/// waves, amplitude at most 0.18 of the radius, so it stays in [0.82, 1.18] R.
fn blob_radius(d: Vec3, t: f32) -> f32 {
    use std::f32::consts::PI;
    let w1 = (3.0 * PI * d.x + 4.0 * W * t).sin() * (2.0 * PI * d.y - 3.0 * W * t).cos();
    let w2 = (4.0 * PI * d.z + 6.0 * W * t).sin();
    BLOB_RADIUS * (1.0 + 0.12 * w1 + 0.06 * w2)
}

fn grid(m: &mut Mesh, n: u32, half: f32) {
    let base = m.vertex_count() as u32;
    for j in 0..=n {
        for i in 0..=n {
            let f = |k: u32| -half + 2.0 * half * k as f32 / n as f32;
            m.push_vertex(Vec3::new(f(i), f(j), 0.0));
        }
    }
    let id = |i: u32, j: u32| base + j * (n + 1) + i;
    for j in 0..n {
        for i in 0..n {
            m.push_quad(id(i, j), id(i + 1, j), id(i + 1, j + 1), id(i, j + 1));
        }
    }
}

/// Torus about local Z: `nu` segments around, `nv` around the tube, wound outward.
fn torus(major: f32, minor: f32, nu: u32, nv: u32) -> (Vec<Vec3>, Vec<u32>) {
    let mut p = Vec::with_capacity((nu * nv) as usize);
    for i in 0..nu {
        let (su, cu) = (TAU * i as f32 / nu as f32).sin_cos();
        for j in 0..nv {
            let (sv, cv) = (TAU * j as f32 / nv as f32).sin_cos();
            let r = major + minor * cv;
            p.push(Vec3::new(r * cu, r * su, minor * sv));
        }
    }
    let id = |i: u32, j: u32| (i % nu) * nv + (j % nv);
    let mut idx = Vec::with_capacity(6 * (nu * nv) as usize);
    for i in 0..nu {
        for j in 0..nv {
            idx.extend_from_slice(&[
                id(i, j),
                id(i + 1, j),
                id(i + 1, j + 1),
                id(i, j),
                id(i + 1, j + 1),
                id(i, j + 1),
            ]);
        }
    }
    (p, idx)
}

/// Box with half extents `h` about the origin: 8 corners (bit k of the index
/// selects +h along axis k), 12 triangles wound outward.
fn cuboid(h: Vec3) -> (Vec<Vec3>, Vec<u32>) {
    let p = (0..8)
        .map(|k| Vec3::new(sgn(k & 1), sgn(k & 2), sgn(k & 4)) * h)
        .collect();
    let quads = [
        [0, 4, 6, 2],
        [1, 3, 7, 5],
        [0, 1, 5, 4],
        [2, 6, 7, 3],
        [0, 2, 3, 1],
        [4, 5, 7, 6],
    ];
    let idx = quads
        .iter()
        .flat_map(|q| [q[0], q[1], q[2], q[0], q[2], q[3]])
        .collect();
    (p, idx)
}

fn sgn(bit: u32) -> f32 {
    if bit != 0 { 1.0 } else { -1.0 }
}

impl Animated {
    /// Builds the scene at `t = 0`. Triangles grow with `detail^2` (`detail`
    /// 0 is treated as 1): `17_920 d^2 + 48`, i.e. ground `512 d^2`, blob
    /// `12_288 d^2`, tori `2 * 2_560 d^2`, boxes 48 (17_968 at detail 1).
    pub fn new(detail: u32) -> Self {
        let d = detail.max(1);
        let mut mesh = Mesh::default();
        let mut parts = Vec::new();
        grid(&mut mesh, 16 * d, 12.0);

        let mut add = |mesh: &mut Mesh, rest: Vec<Vec3>, idx: &[u32], motion: Motion| {
            let first = mesh.vertex_count();
            for _ in 0..rest.len() {
                mesh.push_vertex(Vec3::ZERO); // placed by set_time below
            }
            mesh.indices.extend(idx.iter().map(|&i| first as u32 + i));
            parts.push(Part {
                first,
                rest,
                motion,
            });
        };

        let (dirs, idx) = super::spd::cube_sphere(32 * d);
        add(
            &mut mesh,
            dirs.iter().map(|d| d.as_vec3()).collect(),
            &idx,
            Motion::Blob,
        );

        let (tp, ti) = torus(0.9, 0.28, 64 * d, 20 * d);
        let tori = [
            Orbit {
                radius: 6.0,
                height: 1.6,
                bob: 0.4,
                rate: W,
                phase: 0.0,
                spin_axis: Vec3::new(0.3, 1.0, 0.5).normalize(),
                spin_rate: 3.0 * W,
            },
            Orbit {
                radius: 6.0,
                height: 1.6,
                bob: 0.4,
                rate: -W,
                phase: 3.0,
                spin_axis: Vec3::new(1.0, -0.2, 0.7).normalize(),
                spin_rate: -4.0 * W,
            },
        ];
        for o in tori {
            add(&mut mesh, tp.clone(), &ti, Motion::Rigid(o));
        }

        for k in 0..4 {
            let h = [
                Vec3::new(0.45, 0.35, 0.3),
                Vec3::new(0.3, 0.3, 0.3),
                Vec3::new(0.4, 0.2, 0.35),
                Vec3::new(0.25, 0.45, 0.3),
            ][k];
            let (bp, bi) = cuboid(h);
            let axis = [
                Vec3::Z,
                Vec3::X,
                Vec3::new(1.0, 1.0, 0.0),
                Vec3::new(0.0, 1.0, 1.0),
            ][k]
                .normalize();
            // Same orbit and rate for all four, a quarter turn apart: they never meet.
            let o = Orbit {
                radius: 3.4,
                height: 1.0,
                bob: 0.25,
                rate: 2.0 * W,
                phase: k as f32 * TAU / 4.0,
                spin_axis: axis,
                spin_rate: (3 + k) as f32 * W,
            };
            add(&mut mesh, bp, &bi, Motion::Rigid(o));
        }

        let mut a = Self {
            mesh,
            parts,
            time: f32::NAN,
        };
        a.set_time(0.0);
        a
    }

    /// Poses the scene at time `t` seconds, rewriting `mesh.vertices` in place
    /// (no allocation; indices untouched). `t` is wrapped into one [`PERIOD`];
    /// a non-finite `t` is treated as 0 so vertices stay finite.
    pub fn set_time(&mut self, t: f32) {
        let t = if t.is_finite() {
            t.rem_euclid(PERIOD)
        } else {
            0.0
        };
        self.time = t;
        let Self { mesh, parts, .. } = self;
        for part in parts.iter() {
            let dst = &mut mesh.vertices[3 * part.first..3 * (part.first + part.rest.len())];
            let out = dst.chunks_exact_mut(3).zip(&part.rest);
            match part.motion {
                Motion::Blob => {
                    for (o, &d) in out {
                        o.copy_from_slice(&(BLOB_CENTRE + d * blob_radius(d, t)).to_array());
                    }
                }
                Motion::Rigid(orbit) => {
                    let (pos, rot) = orbit.at(t);
                    for (o, &p) in out {
                        o.copy_from_slice(&(pos + rot * p).to_array());
                    }
                }
            }
        }
    }

    /// The current time, wrapped into `[0, PERIOD)`.
    pub fn time(&self) -> f32 {
        self.time
    }

    /// Overview, close-up on the blob, one from inside the bounds between the
    /// boxes' and the tori's orbits (radius 4.38, clear of every part at every
    /// time; at t = 0 it looks between two boxes), and one grazing the ground.
    pub fn views(&self) -> Vec<View> {
        vec![
            View::z_up(Vec3::new(13.0, -11.0, 8.5), Vec3::new(0.0, 0.0, 1.2)),
            View::z_up(Vec3::new(2.6, -2.2, 2.9), BLOB_CENTRE),
            View::z_up(Vec3::new(3.1, -3.1, 0.9), Vec3::new(0.0, 0.0, 1.8)),
            View::z_up(Vec3::new(11.5, -2.5, 0.12), Vec3::new(0.0, 0.0, 0.3)),
        ]
    }

    /// A point light above and to the side of the scene.
    pub fn light(&self) -> Vec3 {
        Vec3::new(8.0, -6.0, 14.0)
    }
}

#[cfg(test)]
mod tests {
    use super::super::check;
    use super::*;

    const TIMES: [f32; 9] = [0.0, 0.37, 1.0, 2.5, 5.9, 11.99, 12.0, -3.3, 1.0e7];

    #[test]
    fn counts() {
        for d in [1, 2] {
            let a = Animated::new(d);
            assert_eq!(a.mesh.triangle_count(), 17_920 * (d * d) as usize + 48);
        }
        assert_eq!(Animated::new(0).mesh.triangle_count(), 17_968);
    }

    #[test]
    fn frames_are_sane_and_topology_fixed() {
        let mut a = Animated::new(1);
        check::mesh_sane(&a.mesh);
        let idx = a.mesh.indices.clone();
        let (ptr, len, cap) = (
            a.mesh.vertices.as_ptr(),
            a.mesh.vertices.len(),
            a.mesh.vertices.capacity(),
        );
        for t in TIMES {
            a.set_time(t);
            assert_eq!(a.mesh.indices, idx);
            // Rewritten in place: same buffer, same length, same capacity.
            assert_eq!(
                (
                    a.mesh.vertices.as_ptr(),
                    a.mesh.vertices.len(),
                    a.mesh.vertices.capacity()
                ),
                (ptr, len, cap)
            );
            check::mesh_sane(&a.mesh);
            assert!(
                a.mesh.bounds().0.z == 0.0,
                "t {t}: something dips below the ground"
            );
        }
        for t in [f32::NAN, f32::INFINITY, f32::NEG_INFINITY] {
            a.set_time(t);
            check::finite(&a.mesh);
        }
    }

    #[test]
    fn frames_differ_and_loop() {
        let mut a = Animated::new(1);
        let f0 = a.mesh.vertices.clone();
        a.set_time(0.5);
        let f1 = a.mesh.vertices.clone();
        // Every part moves (the ground, first, does not).
        for p in &a.parts {
            let r = 3 * p.first..3 * (p.first + p.rest.len());
            assert_ne!(f0[r.clone()], f1[r]);
        }
        a.set_time(PERIOD + 0.5);
        let f2 = &a.mesh.vertices;
        assert!(f1.iter().zip(f2).all(|(x, y)| (x - y).abs() < 1e-3));
    }

    #[test]
    fn views_clear_of_moving_parts() {
        let mut a = Animated::new(1);
        let views = a.views();
        check::views_sane(&views);
        assert!(a.light().is_finite());
        for k in 0..240 {
            a.set_time(k as f32 * PERIOD / 240.0);
            assert!(check::inside(views[2].eye, a.mesh.bounds()));
            // A bounding sphere per part (about its vertex mean) misses every eye.
            for p in &a.parts {
                let pts: Vec<Vec3> = (p.first..p.first + p.rest.len())
                    .map(|i| a.mesh.vertex(i))
                    .collect();
                let c = pts.iter().sum::<Vec3>() / pts.len() as f32;
                let r = pts.iter().map(|q| q.distance(c)).fold(0.0, f32::max);
                for v in &views {
                    assert!(
                        v.eye.distance(c) > r + 0.05,
                        "eye {} in part at {c} r {r}",
                        v.eye
                    );
                }
            }
        }
        // Grazing: within ~2 degrees of the ground.
        let d = (views[3].look_at - views[3].eye).normalize();
        assert!(d.z.abs() < 0.04 && views[3].eye.z > 0.0);
    }
}
