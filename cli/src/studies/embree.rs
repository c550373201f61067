//! Embree 3 (Debian's libembree3) traced on `sheaf bench`'s own rays, for
//! the reference points of its speed-vs-accuracy chart: a triangle mesh
//! built with Embree's default quality (MEDIUM), camera rays one at a time
//! (`rtcIntersect1`) and in 4 x 2 pixel packets (`rtcIntersect8`, the width
//! Embree runs fastest on this machine class, benches/embree), shadow rays
//! with `rtcOccluded1`. Compiled only where `build.rs` found Embree
//! (`--cfg embree`).
//!
//! The one module of the CLI with `unsafe`: the FFI declarations and the
//! calls, each with a `// SAFETY:` comment. The structs mirror Embree's
//! headers for `RTC_MAX_INSTANCE_LEVEL_COUNT == 1` and no minimum curve
//! width, which `build.rs` checks before enabling this module.
#![allow(unsafe_code)]

use core::ffi::{c_char, c_void};
use sheaf::{Hit, Ray, Scene};

const GEOMETRY_TRIANGLE: u32 = 0;
const BUFFER_INDEX: u32 = 0;
const BUFFER_VERTEX: u32 = 1;
const FORMAT_UINT3: u32 = 0x5003;
const FORMAT_FLOAT3: u32 = 0x9003;
const QUALITY_MEDIUM: u32 = 1;
const FLAG_COHERENT: u32 = 1;
const INVALID_ID: u32 = u32::MAX;

#[repr(C)]
struct Context {
    flags: u32,
    filter: *const c_void,
    inst_id: [u32; 1],
}

#[repr(C, align(16))]
#[derive(Clone, Copy)]
struct RtcRay {
    org: [f32; 3],
    tnear: f32,
    dir: [f32; 3],
    time: f32,
    tfar: f32,
    mask: u32,
    id: u32,
    flags: u32,
}

#[repr(C, align(16))]
#[derive(Clone, Copy)]
struct RtcHit {
    ng: [f32; 3],
    u: f32,
    v: f32,
    prim_id: u32,
    geom_id: u32,
    inst_id: [u32; 1],
}

#[repr(C)]
#[derive(Clone, Copy)]
struct RayHit {
    ray: RtcRay,
    hit: RtcHit,
}

#[repr(C, align(32))]
#[derive(Clone, Copy)]
struct RtcRay8 {
    org: [[f32; 8]; 3],
    tnear: [f32; 8],
    dir: [[f32; 8]; 3],
    time: [f32; 8],
    tfar: [f32; 8],
    mask: [u32; 8],
    id: [u32; 8],
    flags: [u32; 8],
}

#[repr(C, align(32))]
#[derive(Clone, Copy)]
struct RtcHit8 {
    ng: [[f32; 8]; 3],
    u: [f32; 8],
    v: [f32; 8],
    prim_id: [u32; 8],
    geom_id: [u32; 8],
    inst_id: [[u32; 8]; 1],
}

#[repr(C)]
#[derive(Clone, Copy)]
struct RayHit8 {
    ray: RtcRay8,
    hit: RtcHit8,
}

// Embree 3's C API (rtcore_device.h, rtcore_scene.h, rtcore_geometry.h).
unsafe extern "C" {
    fn rtcNewDevice(config: *const c_char) -> *mut c_void;
    fn rtcReleaseDevice(device: *mut c_void);
    fn rtcNewScene(device: *mut c_void) -> *mut c_void;
    fn rtcSetSceneBuildQuality(scene: *mut c_void, quality: u32);
    fn rtcCommitScene(scene: *mut c_void);
    fn rtcReleaseScene(scene: *mut c_void);
    fn rtcNewGeometry(device: *mut c_void, kind: u32) -> *mut c_void;
    fn rtcSetSharedGeometryBuffer(
        geometry: *mut c_void,
        kind: u32,
        slot: u32,
        format: u32,
        ptr: *const c_void,
        offset: usize,
        stride: usize,
        count: usize,
    );
    fn rtcCommitGeometry(geometry: *mut c_void);
    fn rtcAttachGeometry(scene: *mut c_void, geometry: *mut c_void) -> u32;
    fn rtcReleaseGeometry(geometry: *mut c_void);
    fn rtcIntersect1(scene: *mut c_void, ctx: *mut Context, rayhit: *mut RayHit);
    fn rtcIntersect8(valid: *const i32, scene: *mut c_void, ctx: *mut Context, rh: *mut RayHit8);
    fn rtcOccluded1(scene: *mut c_void, ctx: *mut Context, ray: *mut RtcRay);
}

/// A committed Embree scene of one triangle mesh; primitive ids are the
/// scene's triangle ids.
pub struct Embree {
    device: *mut c_void,
    scene: *mut c_void,
    /// The shared vertex and index buffers (Embree reads them while the
    /// scene lives; the vertex buffer has one float of padding at the end,
    /// which Embree's SSE loads need).
    _vertices: Vec<f32>,
    _indices: Vec<u32>,
}

// SAFETY: a committed Embree scene is safe to trace from several threads
// at once (Embree's API contract); nothing here mutates it after `new`.
unsafe impl Sync for Embree {}

impl Embree {
    /// Embree's device and a MEDIUM-quality scene of `scene`'s triangles
    /// (three vertices each, unshared); `None` if Embree fails to start.
    pub fn new(scene: &Scene<'_>) -> Option<Embree> {
        let n = scene.triangle_count() as usize;
        let mut vertices = Vec::with_capacity(9 * n + 1);
        for t in 0..n as u32 {
            let tri = scene.triangle(t);
            for v in [tri.v0, tri.v1, tri.v2] {
                vertices.extend_from_slice(&v);
            }
        }
        vertices.push(0.0);
        let indices: Vec<u32> = (0..3 * n as u32).collect();
        // SAFETY: a NUL-terminated configuration string; a null device is
        // checked below.
        let device = unsafe { rtcNewDevice(c"threads=1".as_ptr()) };
        if device.is_null() {
            return None;
        }
        // SAFETY: `device` is live; the buffers outlive the scene (owned
        // by the returned value, released in `drop` after the scene), their
        // item counts and strides match their lengths; the geometry handle
        // is released once attached (the scene holds its own reference).
        let scene = unsafe {
            let s = rtcNewScene(device);
            rtcSetSceneBuildQuality(s, QUALITY_MEDIUM);
            let g = rtcNewGeometry(device, GEOMETRY_TRIANGLE);
            rtcSetSharedGeometryBuffer(
                g,
                BUFFER_VERTEX,
                0,
                FORMAT_FLOAT3,
                vertices.as_ptr().cast(),
                0,
                12,
                3 * n,
            );
            rtcSetSharedGeometryBuffer(
                g,
                BUFFER_INDEX,
                0,
                FORMAT_UINT3,
                indices.as_ptr().cast(),
                0,
                12,
                n,
            );
            rtcCommitGeometry(g);
            rtcAttachGeometry(s, g);
            rtcReleaseGeometry(g);
            rtcCommitScene(s);
            s
        };
        Some(Embree {
            device,
            scene,
            _vertices: vertices,
            _indices: indices,
        })
    }

    fn context() -> Context {
        Context {
            flags: FLAG_COHERENT,
            filter: core::ptr::null(),
            inst_id: [INVALID_ID],
        }
    }

    fn ray(r: &Ray) -> RtcRay {
        RtcRay {
            org: r.org,
            tnear: r.tmin,
            dir: r.dir,
            time: 0.0,
            tfar: r.tmax,
            mask: u32::MAX,
            id: 0,
            flags: 0,
        }
    }

    fn hit_of(prim: u32, geom: u32, t: f32, u: f32, v: f32) -> Hit {
        if geom == INVALID_ID {
            Hit::MISS
        } else {
            Hit { t, prim, u, v }
        }
    }

    /// Nearest hit of `r` (`rtcIntersect1`).
    pub fn intersect1(&self, r: &Ray) -> Hit {
        let mut rh = RayHit {
            ray: Self::ray(r),
            hit: RtcHit {
                ng: [0.0; 3],
                u: 0.0,
                v: 0.0,
                prim_id: INVALID_ID,
                geom_id: INVALID_ID,
                inst_id: [INVALID_ID],
            },
        };
        let mut ctx = Self::context();
        // SAFETY: the scene is committed; `ctx` and `rh` are valid, aligned
        // as Embree's structs and live for the call.
        unsafe { rtcIntersect1(self.scene, &mut ctx, &mut rh) };
        let h = &rh.hit;
        Self::hit_of(h.prim_id, h.geom_id, rh.ray.tfar, h.u, h.v)
    }

    /// Nearest hits of up to 8 rays (`rtcIntersect8`); lanes past
    /// `rays.len()` are off.
    pub fn intersect8(&self, rays: &[Ray], out: &mut [Hit]) {
        let k = rays.len().min(8);
        let mut valid = [0i32; 8];
        let mut rh = RayHit8 {
            ray: RtcRay8 {
                org: [[0.0; 8]; 3],
                tnear: [0.0; 8],
                dir: [[0.0; 8]; 3],
                time: [0.0; 8],
                tfar: [0.0; 8],
                mask: [u32::MAX; 8],
                id: [0; 8],
                flags: [0; 8],
            },
            hit: RtcHit8 {
                ng: [[0.0; 8]; 3],
                u: [0.0; 8],
                v: [0.0; 8],
                prim_id: [INVALID_ID; 8],
                geom_id: [INVALID_ID; 8],
                inst_id: [[INVALID_ID; 8]],
            },
        };
        for (i, r) in rays[..k].iter().enumerate() {
            valid[i] = -1;
            for a in 0..3 {
                rh.ray.org[a][i] = r.org[a];
                rh.ray.dir[a][i] = r.dir[a];
            }
            rh.ray.tnear[i] = r.tmin;
            rh.ray.tfar[i] = r.tmax;
        }
        let mut ctx = Self::context();
        // SAFETY: as `intersect1`; `valid` holds 8 lanes, `rh` is 32-byte
        // aligned as `RTCRayHit8` requires.
        unsafe { rtcIntersect8(valid.as_ptr(), self.scene, &mut ctx, &mut rh) };
        let h = &rh.hit;
        for (i, o) in out[..k].iter_mut().enumerate() {
            *o = Self::hit_of(h.prim_id[i], h.geom_id[i], rh.ray.tfar[i], h.u[i], h.v[i]);
        }
    }

    /// Whether anything blocks `r` in `[tmin, tmax)` (`rtcOccluded1`).
    pub fn occluded1(&self, r: &Ray) -> bool {
        let mut ray = Self::ray(r);
        let mut ctx = Self::context();
        // SAFETY: as `intersect1`.
        unsafe { rtcOccluded1(self.scene, &mut ctx, &mut ray) };
        ray.tfar == f32::NEG_INFINITY
    }
}

impl Drop for Embree {
    fn drop(&mut self) {
        // SAFETY: both handles are live and released once, the scene first.
        unsafe {
            rtcReleaseScene(self.scene);
            rtcReleaseDevice(self.device);
        }
    }
}
