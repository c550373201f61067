//! Whole frames: a pinhole camera, one point light with hard shadows, Lambert
//! shading, written into a caller's RGBA8 framebuffer.
//!
//! Each pixel traces one primary ray and, when its surface faces the light,
//! one shadow ray. The tracing itself is delegated to a `Tracer`, so every
//! structure and method renders through the same shading code.
#![forbid(unsafe_code)]

use crate::error::{Error, Result};
use crate::geom::{Hit, Ray, TriVerts};
use crate::math;
use crate::trace::Counters;
use glam::Vec3;

/// Pinhole camera (C: `sheaf_camera`).
#[repr(C)]
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Camera {
    pub eye: [f32; 3],
    pub look_at: [f32; 3],
    pub up: [f32; 3],
    /// Vertical field of view in degrees, in (0, 180).
    pub fov_y_deg: f32,
}

/// Point light (C: `sheaf_light`).
#[repr(C)]
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PointLight {
    pub position: [f32; 3],
    /// Linear RGB intensity (no distance falloff).
    pub color: [f32; 3],
}

/// Shading constants (C: `sheaf_shading`).
#[repr(C)]
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Shading {
    /// Linear RGB diffuse albedo of every surface.
    pub albedo: [f32; 3],
    /// Ambient fraction lighting every visible surface.
    pub ambient: f32,
    /// Linear RGB of pixels whose primary ray misses.
    pub background: [f32; 3],
    /// Trace shadow rays (false: every surface facing the light is lit).
    pub shadows: bool,
}

impl Default for Shading {
    fn default() -> Self {
        Shading { albedo: [0.8, 0.78, 0.72], ambient: 0.12, background: [0.078, 0.361, 0.753], shadows: true }
    }
}

/// Camera basis and per-pixel ray generation for a `width x height` image.
#[derive(Clone, Copy, Debug)]
pub struct PrimaryRays {
    eye: Vec3,
    corner: Vec3,
    du: Vec3,
    dv: Vec3,
}

impl PrimaryRays {
    pub fn new(cam: &Camera, width: u32, height: u32) -> Result<Self> {
        let eye = Vec3::from(cam.eye);
        let fwd = Vec3::from(cam.look_at) - eye;
        let up = Vec3::from(cam.up);
        let ok = eye.is_finite() && fwd.is_finite() && up.is_finite() && fwd.length_squared() > 0.0;
        if !ok || !(cam.fov_y_deg > 0.0 && cam.fov_y_deg < 180.0) {
            return Err(Error::InvalidArgument("camera: finite eye/look_at/up, eye != look_at, fov in (0, 180)"));
        }
        let w = fwd.normalize();
        let u = w.cross(up);
        if !(u.length_squared() > 0.0) {
            return Err(Error::InvalidArgument("camera: up must not be parallel to the view direction"));
        }
        let u = u.normalize();
        let v = u.cross(w);
        let half_h = math::tan(cam.fov_y_deg.to_radians() * 0.5);
        let half_w = half_h * width as f32 / height as f32;
        let du = u * (2.0 * half_w / width as f32);
        let dv = -v * (2.0 * half_h / height as f32);
        let corner = w - u * half_w + v * half_h;
        Ok(PrimaryRays { eye, corner, du, dv })
    }

    /// Ray through the centre of pixel (x, y); y grows downwards.
    #[inline]
    pub fn ray(&self, x: u32, y: u32) -> Ray {
        let d = self.corner + self.du * (x as f32 + 0.5) + self.dv * (y as f32 + 0.5);
        Ray::new(self.eye, d, 0.0, f32::INFINITY)
    }
}

/// What a structure offers the renderer: nearest hits, occlusion, and the
/// triangle a hit refers to (for its normal).
pub trait Tracer: Sync {
    fn intersect(&self, ray: &Ray, ctr: &mut Counters) -> Hit;
    fn occluded(&self, ray: &Ray, ctr: &mut Counters) -> bool;
    fn triangle(&self, prim: u32) -> Option<TriVerts>;
    /// Scale of the scene, for the shadow-ray origin offset.
    fn scene_scale(&self) -> f32;
}

/// Everything a frame needs besides the structure and the pixels.
#[derive(Clone, Copy, Debug)]
pub struct Frame {
    pub camera: Camera,
    pub light: PointLight,
    pub shading: Shading,
    pub width: u32,
    pub height: u32,
}

/// Shadow-ray origin offset along the normal, relative to the scene scale:
/// large enough to leave the surface's own rounding error, small enough not
/// to skip contact shadows.
const SHADOW_OFFSET: f32 = 1e-4;

/// Render rows `y0..y1` of `frame` into `pixels`, whose row `y` starts at
/// byte `(y - y0) * stride`. RGBA8, sRGB-encoded (gamma 2.2), alpha 255.
pub fn render_rows<T: Tracer + ?Sized>(
    tracer: &T,
    frame: &Frame,
    rays: &PrimaryRays,
    y0: u32,
    y1: u32,
    pixels: &mut [u8],
    stride: usize,
    ctr: &mut Counters,
) {
    let light = Vec3::from(frame.light.position);
    let lcol = Vec3::from(frame.light.color);
    let sh = &frame.shading;
    let albedo = Vec3::from(sh.albedo);
    let eps = SHADOW_OFFSET * tracer.scene_scale();
    for y in y0..y1 {
        let row = &mut pixels[(y - y0) as usize * stride..];
        for x in 0..frame.width {
            let ray = rays.ray(x, y);
            let hit = tracer.intersect(&ray, ctr);
            let mut c = Vec3::from(sh.background);
            if let Some(tri) = hit.is_hit().then(|| tracer.triangle(hit.prim)).flatten() {
                let d = Vec3::from(ray.dir);
                let mut n = tri.normal().normalize_or_zero();
                if n.dot(d) > 0.0 {
                    n = -n; // two-sided: face the viewer
                }
                let p = Vec3::from(ray.org) + d * hit.t;
                let to_l = light - p;
                let cos = n.dot(to_l.normalize_or_zero());
                let mut lit = 0.0;
                if cos > 0.0 {
                    lit = cos;
                    if sh.shadows {
                        let o = p + n * eps;
                        let sray = Ray::new(o, light - o, 0.0, 1.0);
                        if tracer.occluded(&sray, ctr) {
                            lit = 0.0;
                        }
                    }
                }
                c = albedo * (Vec3::splat(sh.ambient) + lcol * lit);
            }
            let px = &mut row[x as usize * 4..x as usize * 4 + 4];
            px[0] = encode(c.x);
            px[1] = encode(c.y);
            px[2] = encode(c.z);
            px[3] = 255;
        }
    }
}

#[inline]
fn encode(x: f32) -> u8 {
    (math::powf(x.clamp(0.0, 1.0), 1.0 / 2.2) * 255.0 + 0.5) as u8
}
