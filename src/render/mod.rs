//! Whole frames: a pinhole camera, one point light with hard shadows, Lambert
//! shading, written into a caller's RGBA8 framebuffer.
//!
//! Each pixel traces one primary ray and, when its surface faces the light,
//! one shadow ray. The tracing itself is delegated to a `Tracer`, so every
//! structure and method renders through the same shading code.
//!
//! Single-ray methods render pixel by pixel (`render_rows`). Packet methods
//! render n x n tiles (`render_tiles`): the tile's 2x2 quads in Morton order
//! (so every quarter of a packet is a contiguous sub-packet), primary
//! packets first, then shadow packets traced *from the light* towards the
//! hit points (a common origin, CGT section 4.7), split into four while the
//! hit points' distances from the light differ by more than `split`.
//! Both paths shoot the same shadow rays, so they produce the same image.
#![forbid(unsafe_code)]

pub mod camera;
pub mod deferred;
pub mod material;
pub mod whitted;

use crate::accel::slot::Slot;
use crate::error::{Error, Result};
use crate::geom::{F4, Hit, Hit4, M4, Ray, Ray4, TriVerts};
use crate::math;
use crate::trace::{Counters, TraceParams};
pub use crate::trace::{Packets, Tracer};
pub use camera::{Camera, CameraRays, PixelRect, PrimaryRays, demorton};
use glam::Vec3;

/// Slot scratch a packet tile of `render_tiles` of up to `q` quads holds
/// while it traces: camera and shadow quads, masks and hits, shadow
/// distances, cosines.
pub const fn scratch(q: usize) -> usize {
    use crate::mem::scratch::bytes;
    2 * (bytes::<Ray4>(q) + bytes::<M4>(q) + bytes::<Hit4>(q)) + 2 * bytes::<F4>(q)
}

/// Point light, optionally a spot light (C: `sheaf_light`; a zeroed spot
/// part is a point light shining everywhere).
#[repr(C)]
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PointLight {
    pub position: [f32; 3],
    /// Linear RGB intensity (no distance falloff).
    pub color: [f32; 3],
    /// Axis of a spot light (any length; used when `spot_angle_deg > 0`).
    pub spot_direction: [f32; 3],
    /// Half-angle of the spot's cone in degrees, in [0, 90); 0: a point
    /// light. Surfaces outside the cone get no light and no shadow ray.
    pub spot_angle_deg: f32,
    /// Width in degrees of the soft edge inside the cone, where the light
    /// falls off smoothly to 0 at the cone (0: a hard edge).
    pub spot_soft_deg: f32,
}

impl Default for PointLight {
    fn default() -> Self {
        PointLight {
            position: [0.0; 3],
            color: [1.0; 3],
            spot_direction: [0.0, 0.0, -1.0],
            spot_angle_deg: 0.0,
            spot_soft_deg: 0.0,
        }
    }
}

impl PointLight {
    /// A point light at `position` with `color`.
    pub fn new(position: [f32; 3], color: [f32; 3]) -> PointLight {
        PointLight {
            position,
            color,
            ..PointLight::default()
        }
    }

    /// Whether this is a spot light.
    pub fn is_spot(&self) -> bool {
        self.spot_angle_deg > 0.0
    }

    /// Finite position and colour; a spot's angle in (0, 90), a non-zero
    /// finite axis and a soft edge in [0, angle].
    pub fn validate(&self) -> Result<()> {
        let ok = Vec3::from(self.position).is_finite() && Vec3::from(self.color).is_finite();
        if !ok {
            return Err(Error::InvalidArgument(
                "light position and color must be finite",
            ));
        }
        if self.spot_angle_deg == 0.0 {
            return Ok(());
        }
        let axis = Vec3::from(self.spot_direction);
        // Stated as what is valid, so that NaN fails.
        let valid = self.spot_angle_deg > 0.0
            && self.spot_angle_deg < 90.0
            && axis.is_finite()
            && axis.length_squared() > 0.0
            && self.spot_soft_deg >= 0.0
            && self.spot_soft_deg <= self.spot_angle_deg;
        if !valid {
            return Err(Error::InvalidArgument(
                "spot light: angle in [0, 90), finite non-zero direction, soft edge in [0, angle]",
            ));
        }
        Ok(())
    }

    /// Light reaching direction `d` (unit, from the light): 1 for a point
    /// light; for a spot 1 inside the soft edge, 0 outside the cone, a
    /// smoothstep between.
    #[inline]
    pub fn spot(&self, d: Vec3) -> f32 {
        if !self.is_spot() {
            return 1.0;
        }
        let c = Vec3::from(self.spot_direction).normalize_or_zero().dot(d);
        let outer = math::cos(self.spot_angle_deg.to_radians());
        let inner = math::cos((self.spot_angle_deg - self.spot_soft_deg).to_radians());
        if c <= outer {
            0.0
        } else if c >= inner {
            1.0
        } else {
            let x = (c - outer) / (inner - outer);
            x * x * (3.0 - 2.0 * x)
        }
    }

    /// Light at surface point `p` with facing normal `n`: the cosine times
    /// the spot factor and, when that is positive and `shadows` is on, the
    /// shadow ray from the light to `p + n * eps'` (`tmax = 1`, exclusive,
    /// so the surface itself is never reported), `eps'` the larger of `eps`
    /// and `SHADOW_OFFSET_REL` of the ray's length: a far light's ray
    /// carries rounding relative to its length, and its own surface must
    /// stay beyond t = 1 for every triangle test. Every renderer shoots
    /// exactly these rays.
    #[inline]
    pub fn at(&self, p: Vec3, n: Vec3, shadows: bool, eps: f32) -> (f32, Option<Ray>) {
        let light = Vec3::from(self.position);
        let to = light - p;
        let len = to.length();
        let to = to.normalize_or_zero();
        let lit = n.dot(to) * self.spot(-to);
        if lit > 0.0 && shadows {
            let end = p + n * eps.max(SHADOW_OFFSET_REL * len);
            (lit, Some(Ray::new(light, end - light, 0.0, 1.0)))
        } else {
            (lit.max(0.0), None)
        }
    }
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
        Shading {
            albedo: [0.8, 0.78, 0.72],
            ambient: 0.12,
            background: [0.078, 0.361, 0.753],
            shadows: true,
        }
    }
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

impl Frame {
    /// Check the frame against `limits` (image size), and a band of its
    /// rows `[y0, y1)` against the band's buffer (`pixels_len` bytes, row
    /// `y0` first, `stride` bytes apart): its camera rays, or the error
    /// every renderer returns before writing a pixel.
    pub fn check_rows(
        &self,
        limits: &crate::mem::Limits,
        y0: u32,
        y1: u32,
        pixels_len: usize,
        stride: usize,
    ) -> Result<PrimaryRays> {
        let (w, h) = (self.width, self.height);
        if w == 0 || h == 0 {
            return Err(Error::InvalidArgument("image width and height must be > 0"));
        }
        if w > limits.max_image_width || h > limits.max_image_height {
            return Err(Error::Capacity {
                pool: crate::error::Pool::Image,
                needed: w as u64 * h as u64,
                available: limits.max_image_width as u64 * limits.max_image_height as u64,
            });
        }
        if stride < w as usize * 4 {
            return Err(Error::InvalidArgument(
                "framebuffer stride must be >= 4 * width",
            ));
        }
        if y0 >= y1 || y1 > h {
            return Err(Error::InvalidArgument(
                "rows must satisfy y0 < y1 <= height",
            ));
        }
        let need = ((y1 - y0 - 1) as usize)
            .checked_mul(stride)
            .and_then(|b| b.checked_add(w as usize * 4));
        if need.is_none_or(|n| pixels_len < n) {
            return Err(Error::InvalidArgument(
                "framebuffer smaller than height * stride",
            ));
        }
        PrimaryRays::new(&self.camera, w, h)
    }
}

/// Shadow-ray end point offset along the normal, relative to the scene
/// scale: large enough to leave the surface's own rounding error, small
/// enough not to skip contact shadows.
pub const SHADOW_OFFSET: f32 = 1e-4;

/// Shadow-ray end point offset relative to the ray's length (see
/// `PointLight::at`): only lights farther than 10 scene sizes reach it.
pub const SHADOW_OFFSET_REL: f32 = 1e-5;

/// The facing normal of a hit and, when the surface faces the light, the
/// shadow ray from the light to a point just off the surface (t = 1 there;
/// `tmax = 1` is exclusive, so the surface itself is never reported).
#[inline]
fn surface(
    frame: &Frame,
    ray: &Ray,
    hit: &Hit,
    tri: &TriVerts,
    eps: f32,
) -> (Vec3, f32, Option<Ray>) {
    let d = Vec3::from(ray.dir);
    let mut n = tri.normal().normalize_or_zero();
    if n.dot(d) > 0.0 {
        n = -n; // two-sided: face the viewer
    }
    let p = Vec3::from(ray.org) + d * hit.t;
    let (lit, sray) = frame.light.at(p, n, frame.shading.shadows, eps);
    (n, lit, sray)
}

#[inline]
fn shade(frame: &Frame, hit: bool, lit: f32) -> [u8; 4] {
    let sh = &frame.shading;
    let c = if hit {
        Vec3::from(sh.albedo) * (Vec3::splat(sh.ambient) + Vec3::from(frame.light.color) * lit)
    } else {
        Vec3::from(sh.background)
    };
    [encode(c.x), encode(c.y), encode(c.z), 255]
}

/// The rows a renderer writes: rows `y0..y1` of the frame into `pixels`,
/// whose row `y` starts at byte `(y - y0) * stride` (RGBA8, so `stride >=
/// 4 * width`). A whole frame is the band `0..height`; threads rendering
/// disjoint bands of one frame make its image, byte for byte.
#[derive(Debug)]
pub struct Band<'p> {
    pub y0: u32,
    pub y1: u32,
    pub pixels: &'p mut [u8],
    pub stride: usize,
}

/// How `render_tiles` traces a frame: `primary` for camera rays (its
/// `packet` is the tile side), `shadow` for shadow rays (traced as
/// packets of the tile, or its quarters).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct TileParams {
    pub primary: TraceParams,
    pub shadow: TraceParams,
}

/// A shadow packet traced from the light (`shadow_packet`): its quads, their
/// active lanes and each lane's distance from the light to its end point
/// (what `TraceParams::split` compares). The three slices have one entry
/// per quad.
#[derive(Clone, Copy, Debug)]
pub struct ShadowPacket<'a> {
    pub rays: &'a [Ray4],
    pub active: &'a [M4],
    pub dist: &'a [F4],
}

/// Render `band` of `frame` one ray at a time. RGBA8, sRGB-encoded (gamma
/// 2.2), alpha 255.
#[inline(never)]
pub fn render_rows<T: Tracer + ?Sized>(
    tracer: &T,
    frame: &Frame,
    rays: &PrimaryRays,
    band: Band<'_>,
    ctr: &mut Counters,
) {
    let Band {
        y0,
        y1,
        pixels,
        stride,
    } = band;
    let eps = SHADOW_OFFSET * tracer.scene_scale();
    for y in y0..y1 {
        let row = &mut pixels[(y - y0) as usize * stride..];
        for x in 0..frame.width {
            let ray = rays.ray(x, y);
            let hit = tracer.intersect(&ray, ctr);
            let tri = if hit.is_hit() {
                tracer.triangle(hit.prim)
            } else {
                None
            };
            let px = match tri {
                Some(tri) => {
                    let (_, cos, sray) = surface(frame, &ray, &hit, &tri, eps);
                    let lit = match sray {
                        Some(s) if tracer.occluded(&s, ctr) => 0.0,
                        _ => cos,
                    };
                    shade(frame, true, lit)
                }
                None => shade(frame, false, 0.0),
            };
            row[x as usize * 4..x as usize * 4 + 4].copy_from_slice(&px);
        }
    }
}

/// Render `band` (`y0` a multiple of the packet side) in n x n tiles with
/// packet methods: `params.primary.method` for camera rays,
/// `params.shadow.method` for shadow rays. Same output as `render_rows`
/// with the same structure.
pub fn render_tiles<T: Tracer + ?Sized>(
    tracer: &T,
    params: &TileParams,
    frame: &Frame,
    rays: &PrimaryRays,
    band: Band<'_>,
    slot: &mut Slot<'_>,
    ctr: &mut Counters,
) {
    match params.primary.packet {
        2 => tiles::<T, 1>(tracer, params, frame, rays, band, slot, ctr),
        4 => tiles::<T, 4>(tracer, params, frame, rays, band, slot, ctr),
        8 => tiles::<T, 16>(tracer, params, frame, rays, band, slot, ctr),
        16 => tiles::<T, 64>(tracer, params, frame, rays, band, slot, ctr),
        _ => tiles::<T, { crate::accel::packet::MAX_QUADS }>(
            tracer, params, frame, rays, band, slot, ctr,
        ),
    }
}

// Not inlined: the five size classes would share one caller frame.
#[inline(never)]
fn tiles<T: Tracer + ?Sized, const Q: usize>(
    tracer: &T,
    params: &TileParams,
    frame: &Frame,
    rays: &PrimaryRays,
    band: Band<'_>,
    slot: &mut Slot<'_>,
    ctr: &mut Counters,
) {
    let TileParams { primary, shadow } = params;
    let Band {
        y0,
        y1,
        pixels,
        stride,
    } = band;
    let n = 2 * (Q as u32).isqrt();
    // Shadow packets are the tile's (or its Morton quarters): their side
    // is the tile's, whatever `shadow.packet` says (a kd-tree kernel's
    // size class comes from it).
    let shadow = &TraceParams {
        packet: n,
        ..*shadow
    };
    // The band's traversals, chosen once for all its tiles.
    let (traced, shadowed) = (tracer.packets(primary, false), tracer.packets(shadow, true));
    let eps = SHADOW_OFFSET * tracer.scene_scale();
    let light = Vec3::from(frame.light.position);
    let lane_xy = [(0u32, 0u32), (1, 0), (0, 1), (1, 1)];
    // The tile's packets live in the slot's scratch (`scratch`).
    let blank = Ray4::from_rays(&[Ray::new(Vec3::ZERO, Vec3::X, 0.0, 0.0); 4]);
    let (quads, s) = slot.reborrow().take(Q, blank);
    let (active, s) = s.take(Q, M4::FALSE);
    let (hits, s) = s.take(Q, Hit4::MISS);
    let (squads, s) = s.take(Q, blank);
    let (sactive, s) = s.take(Q, M4::FALSE);
    let (shits, s) = s.take(Q, Hit4::MISS);
    let (sdist, s) = s.take(Q, F4::ZERO);
    let (cosines, mut slot) = s.take(Q, F4::ZERO);
    let rect = PixelRect {
        x0: 0,
        y0,
        x1: frame.width,
        y1,
    };
    // Stepped ranges: a tile origin past u32::MAX is never formed.
    for ty in (y0..y1).step_by(n as usize) {
        for tx in (0..frame.width).step_by(n as usize) {
            // Primary packet: the kernel's camera packet (`PrimaryRays::packet`).
            rays.packet(tx, ty, n, &rect, quads, active);
            hits.fill(Hit4::MISS);
            traced.run(primary, quads, active, hits, &mut slot, ctr);
            // Shadow packet from the light towards the lit hit points.
            for q in 0..Q {
                let mut lanes = [Ray::new(light, Vec3::X, 0.0, 0.0); 4];
                let mut m = [false; 4];
                for i in 0..4 {
                    cosines[q][i] = 0.0;
                    let h = hits[q].lane(i);
                    if !(active[q].test(i) && h.is_hit()) {
                        continue;
                    }
                    if let Some(tri) = tracer.triangle(h.prim) {
                        let (_, cos, sray) = surface(frame, &quads[q].lane(i), &h, &tri, eps);
                        cosines[q][i] = cos;
                        if let Some(s) = sray {
                            sdist[q][i] = Vec3::from(s.dir).length();
                            lanes[i] = s;
                            m[i] = true;
                        }
                    }
                }
                squads[q] = Ray4::from_rays(&lanes);
                sactive[q] = M4::new(m[0], m[1], m[2], m[3]);
                shits[q] = Hit4::MISS;
            }
            let packet = ShadowPacket {
                rays: squads,
                active: sactive,
                dist: sdist,
            };
            shadow_packet(&shadowed, shadow, packet, shits, &mut slot, ctr);
            // Shade and store.
            for q in 0..Q {
                let (qx, qy) = demorton(q);
                for (i, (dx, dy)) in lane_xy.iter().enumerate() {
                    if !active[q].test(i) {
                        continue;
                    }
                    let (x, y) = (tx + 2 * qx + dx, ty + 2 * qy + dy);
                    let hit = hits[q].prim[i] != crate::geom::INVALID_ID;
                    let lit = if shits[q].prim[i] != crate::geom::INVALID_ID {
                        0.0
                    } else {
                        cosines[q][i]
                    };
                    let at = (y - y0) as usize * stride + x as usize * 4;
                    pixels[at..at + 4].copy_from_slice(&shade(frame, hit, lit));
                }
            }
        }
    }
}

/// Trace a shadow packet with `shadowed` (occlusion, chosen for `p`),
/// splitting it into its four Morton quarters while its hit points'
/// distances from the light spread by more than `p.split`.
pub fn shadow_packet(
    shadowed: &Packets<'_>,
    p: &TraceParams,
    packet: ShadowPacket<'_>,
    hits: &mut [Hit4],
    slot: &mut Slot<'_>,
    ctr: &mut Counters,
) {
    let ShadowPacket { rays, active, dist } = packet;
    if !active.iter().any(|m| m.any()) {
        return;
    }
    if p.split > 0.0 && rays.len() >= 4 && rays.len() % 4 == 0 {
        let (mut lo, mut hi) = (f32::INFINITY, 0.0f32);
        for (m, d) in active.iter().zip(dist) {
            lo = lo.min(F4::select(*m, *d, F4::INFINITY).min_element());
            hi = hi.max(F4::select(*m, *d, F4::ZERO).max_element());
        }
        if hi > p.split * lo {
            ctr.packets_split += 1;
            let k = rays.len() / 4;
            for s in 0..4 {
                let r = s * k..(s + 1) * k;
                let quarter = ShadowPacket {
                    rays: &rays[r.clone()],
                    active: &active[r.clone()],
                    dist: &dist[r.clone()],
                };
                shadow_packet(shadowed, p, quarter, &mut hits[r], slot, ctr);
            }
            return;
        }
    }
    shadowed.run(p, rays, active, hits, slot, ctr);
}

#[inline]
pub(crate) fn encode(x: f32) -> u8 {
    (math::powf(x.clamp(0.0, 1.0), 1.0 / 2.2) * 255.0 + 0.5) as u8
}
