//! A panic inside a call poisons the context: with the `fault-injection`
//! feature, each build and frame has a point that panics when armed
//! (`sheaf::fault`). Through the C ABI the call returns
//! `SHEAF_STATUS_PANIC`, and from then on every call on that context but
//! `sheaf_context_last_error` and `sheaf_context_destroy` returns
//! `SHEAF_STATUS_POISONED` (nothing reads the half-built structure), while
//! other contexts are untouched and destroy frees the poisoned one.
//!
//! Run with `cargo test --release --features fault-injection --test
//! fault_injection` (.ci/run does); without the feature this file is empty.
#![cfg(feature = "fault-injection")]

use sheaf::Limits;
use sheaf::fault::{self, Point};
use sheaf::ffi::{self, sheaf_context, sheaf_hit, sheaf_method, sheaf_ray, sheaf_status};

const W: u32 = 32;
const H: u32 = 24;

/// A ground and a box: 14 triangles, 4 floats per vertex.
fn scene() -> (Vec<f32>, Vec<u32>) {
    let mut v = Vec::new();
    let mut idx = Vec::new();
    let mut quad = |v: &mut Vec<f32>, p: [[f32; 3]; 4]| {
        let b = (v.len() / 4) as u32;
        for q in p {
            v.extend_from_slice(&[q[0], q[1], q[2], 0.0]);
        }
        idx.extend_from_slice(&[b, b + 1, b + 2, b, b + 2, b + 3]);
    };
    quad(
        &mut v,
        [
            [-5.0, -5.0, 0.0],
            [5.0, -5.0, 0.0],
            [5.0, 5.0, 0.0],
            [-5.0, 5.0, 0.0],
        ],
    );
    let (a, z) = (1.0f32, 1.5f32);
    quad(&mut v, [[-a, -a, z], [a, -a, z], [a, a, z], [-a, a, z]]);
    quad(
        &mut v,
        [[-a, -a, 0.0], [a, -a, 0.0], [a, -a, z], [-a, -a, z]],
    );
    quad(&mut v, [[a, -a, 0.0], [a, a, 0.0], [a, a, z], [a, -a, z]]);
    quad(&mut v, [[a, a, 0.0], [-a, a, 0.0], [-a, a, z], [a, a, z]]);
    quad(
        &mut v,
        [[-a, a, 0.0], [-a, -a, 0.0], [-a, -a, z], [-a, a, z]],
    );
    (v, idx)
}

fn frame() -> ffi::sheaf_frame {
    let mut f = ffi::sheaf_frame {
        camera: sheaf::Camera {
            eye: [6.0, -8.0, 5.0],
            look_at: [0.0, 0.0, 0.5],
            up: [0.0, 0.0, 1.0],
            fov_y_deg: 40.0,
        },
        light: sheaf::PointLight {
            position: [4.0, -3.0, 8.0],
            color: [1.0; 3],
            ..Default::default()
        },
        shading: ffi::sheaf_shading::of(&sheaf::Shading::default()),
        width: W,
        height: H,
    };
    f.light.color = [1.0; 3];
    f
}

struct Ctx {
    ctx: *mut sheaf_context,
    v: Vec<f32>,
    idx: Vec<u32>,
}

impl Ctx {
    /// A context with every structure built.
    fn built() -> Ctx {
        let (v, idx) = scene();
        let mut l = Limits::for_triangles((idx.len() / 3) as u32);
        l.structures = Limits::ALL_STRUCTURES;
        l.max_image_width = 64;
        l.max_image_height = 64;
        let l = ffi::sheaf_limits::of(&l);
        let mut ctx = std::ptr::null_mut();
        assert_eq!(ffi::sheaf_context_create(&l, &mut ctx), sheaf_status::Ok);
        let c = Ctx { ctx, v, idx };
        assert_eq!(c.set_geometry(), sheaf_status::Ok);
        assert_eq!(
            ffi::sheaf_context_build_grid(c.ctx, std::ptr::null()),
            sheaf_status::Ok
        );
        assert_eq!(
            ffi::sheaf_context_build_bvh(c.ctx, std::ptr::null()),
            sheaf_status::Ok
        );
        assert_eq!(
            ffi::sheaf_context_build_kd(c.ctx, std::ptr::null()),
            sheaf_status::Ok
        );
        assert_eq!(
            ffi::sheaf_context_build_pgrid(c.ctx, std::ptr::null()),
            sheaf_status::Ok
        );
        c
    }

    fn set_geometry(&self) -> sheaf_status {
        ffi::sheaf_context_set_geometry(
            self.ctx,
            self.v.as_ptr(),
            16,
            (self.v.len() / 4) as u32,
            self.idx.as_ptr(),
            (self.idx.len() / 3) as u32,
        )
    }

    fn trace(&self, out: &mut [sheaf_hit]) -> sheaf_status {
        let rays: Vec<sheaf_ray> = (0..out.len())
            .map(|i| sheaf_ray {
                org: [-3.0 + 0.2 * i as f32, -6.0, 0.7],
                tmin: 0.0,
                dir: [0.0, 1.0, -0.05],
                tmax: f32::INFINITY,
            })
            .collect();
        ffi::sheaf_context_trace(
            self.ctx,
            sheaf_method::BvhSingle as u32,
            rays.as_ptr(),
            out.as_mut_ptr(),
            out.len(),
        )
    }

    /// The call that passes through `p`.
    fn call_through(&self, p: Point) -> sheaf_status {
        let f = frame();
        let stride = W as usize * 4;
        let mut img = vec![0u8; stride * H as usize];
        let tp = ffi::sheaf_trace_params::of(&sheaf::TraceParams {
            method: sheaf::Method::BvhSingle,
            ..Default::default()
        });
        match p {
            Point::SetGeometry => self.set_geometry(),
            Point::GridBuild => ffi::sheaf_context_build_grid(self.ctx, std::ptr::null()),
            Point::BvhBuild => ffi::sheaf_context_build_bvh(self.ctx, std::ptr::null()),
            Point::KdBuild => ffi::sheaf_context_build_kd(self.ctx, std::ptr::null()),
            Point::PgridLoad => ffi::sheaf_context_build_pgrid(self.ctx, std::ptr::null()),
            Point::PgridCamera => {
                let job = ffi::sheaf_deferred_job {
                    frame: f,
                    lights: std::ptr::null(),
                    light_count: 0,
                    primary_pgrid: 1,
                    shadow_light_grid: 1,
                    primary: &tp,
                    shadow: &tp,
                };
                ffi::sheaf_context_render_deferred(
                    self.ctx,
                    &job,
                    img.as_mut_ptr(),
                    stride,
                    img.len(),
                )
            }
            Point::Render => ffi::sheaf_context_render(
                self.ctx,
                sheaf_method::BvhSingle as u32,
                &f,
                img.as_mut_ptr(),
                stride,
                img.len(),
            ),
            Point::Whitted => ffi::sheaf_context_render_whitted(
                self.ctx,
                &tp,
                &tp,
                &tp,
                std::ptr::null(),
                &f,
                std::ptr::null(),
                0,
                std::ptr::null(),
                0,
                std::ptr::null(),
                0,
                img.as_mut_ptr(),
                stride,
                img.len(),
            ),
        }
    }

    fn last_error(&self) -> String {
        let mut buf = [0 as core::ffi::c_char; ffi::SHEAF_ERROR_MESSAGE_MAX];
        let mut n = 0usize;
        assert_eq!(
            ffi::sheaf_context_last_error(self.ctx, buf.as_mut_ptr(), buf.len(), &mut n),
            sheaf_status::Ok
        );
        let bytes: Vec<u8> = buf[..n].iter().map(|&c| c as u8).collect();
        String::from_utf8(bytes).unwrap()
    }
}

#[test]
fn every_point_is_reached_by_its_call_when_armed_and_not_otherwise() {
    let c = Ctx::built();
    for p in Point::ALL {
        // Unarmed: the call succeeds.
        assert_eq!(c.call_through(p), sheaf_status::Ok, "{p:?} unarmed");
    }
    ffi::sheaf_context_destroy(c.ctx);
}

#[test]
fn a_panic_poisons_the_context_until_destroy() {
    let mut counted = Vec::new();
    for p in Point::ALL {
        let c = Ctx::built();
        let other = Ctx::built();
        let mut want = vec![
            sheaf_hit {
                t: 0.0,
                prim: 0,
                u: 0.0,
                v: 0.0
            };
            32
        ];
        assert_eq!(c.trace(&mut want), sheaf_status::Ok);
        assert!(
            want.iter()
                .filter(|h| h.prim != ffi::SHEAF_INVALID_ID)
                .count()
                > 8
        );

        fault::arm(p);
        assert_eq!(
            c.call_through(p),
            sheaf_status::Panic,
            "{p:?}: the armed call panics"
        );
        assert_eq!(fault::disarm(), None, "{p:?} was reached");
        assert!(
            c.last_error().contains("panic"),
            "{p:?}: {}",
            c.last_error()
        );

        // Every later call is refused; nothing reads the half-built state.
        let mut hits = vec![
            sheaf_hit {
                t: 1.0,
                prim: 7,
                u: 0.0,
                v: 0.0
            };
            32
        ];
        let before = hits.clone();
        let mut st = sheaf::ffi::sheaf_stats::default();
        let refused = [
            c.trace(&mut hits),
            ffi::sheaf_context_stats(c.ctx, &mut st),
            ffi::sheaf_context_clear_geometry(c.ctx),
        ]
        .into_iter()
        .chain(Point::ALL.into_iter().map(|q| c.call_through(q)));
        let mut n = 0;
        for s in refused {
            assert_eq!(s, sheaf_status::Poisoned, "{p:?}: a call after the panic");
            n += 1;
        }
        assert!(
            hits.iter()
                .zip(&before)
                .all(|(a, b)| a.prim == b.prim && a.t.to_bits() == b.t.to_bits())
        );
        // The panic stays the last error (refusals are not recorded).
        assert!(c.last_error().contains("panic"), "{p:?}");
        counted.push((p, n));

        // Other contexts are untouched; destroy frees the poisoned one.
        let mut again = want.clone();
        assert_eq!(other.trace(&mut again), sheaf_status::Ok);
        assert!(
            again
                .iter()
                .zip(&want)
                .all(|(a, b)| a.prim == b.prim && a.t.to_bits() == b.t.to_bits())
        );
        ffi::sheaf_context_destroy(c.ctx);
        ffi::sheaf_context_destroy(other.ctx);
    }
    println!("fault point: calls refused with SHEAF_STATUS_POISONED after its panic");
    for (p, n) in counted {
        println!("  {p:?}: {n}");
    }
}
