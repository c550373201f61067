//! Whitted ray tracing: point-light shadows, mirror reflections and
//! refractions, one ray at a time (the reference) or in large packets.
//!
//! Source: Overbeck, Ramamoorthi, Mark 2008, "Large Ray Packets for
//! Real-time Whitted Ray Tracing", section 2.4 (secondary packets are
//! grouped by the screen position of their ancestral camera rays, n x n)
//! and section 6 (the Whitted tracer: camera packets, point-light shadow
//! packets, reflection and refraction packets, each traced with its own
//! method and frustum).
//!
//! # Shading model
//! A ray that misses gives `Shading::background`. A ray that hits a surface
//! with material `m` (`Materials::lookup`) gives
//!
//! ```text
//! L = kd * m.diffuse * (ambient + sum_l [l unshadowed] * cos_l * l.color)
//!   + kr * L(reflected ray) + kt * L(refracted ray)
//! kr = m.reflect  (0 once max_reflect reflections are on the path)
//! kt = m.transmit (0 once max_refract refractions are on the path)
//! kd = 1 - kr - kt
//! ```
//!
//! so when a bounce limit is reached the weight that ray would have carried
//! goes to the local diffuse shading instead (the colour of a path is
//! always a weighted sum with weights adding up to 1). `cos_l` is the cosine
//! between the facing normal and the direction to light `l` (0 when the
//! surface faces away); the sum runs over `WhittedJob::lights` (or
//! `Frame::light` when that is empty), in order.
//!
//! - Normals are two-sided: the geometric normal is flipped to face the
//!   incoming ray. A ray arriving on the side the geometric normal points
//!   to is *entering* the material (Snell's law with `eta = 1 / ior`), one
//!   arriving from behind is *leaving* it (`eta = ior`). Closed refractive
//!   objects therefore need outward-facing normals (consistent winding).
//! - Reflection: `r = d + 2 cos_i n` (`d` the unit incoming direction, `n`
//!   the facing normal, `cos_i = -n.d`); origin `p + n * eps`.
//! - Refraction: `t = eta d + (eta cos_i - sqrt(k)) n`,
//!   `k = 1 - eta^2 (1 - cos_i^2)`; origin `p - n * eps`. When `k < 0`
//!   (total internal reflection) the transmitted weight travels along `r`
//!   from `p + n * eps` instead; it still counts as a refraction bounce.
//! - `eps = SHADOW_OFFSET * scene_scale`; secondary rays have unit
//!   directions, `tmin = 0`, `tmax = +inf`.
//! - Shadow rays are exactly those of `render::render_rows`: from the light
//!   to `p + n * eps`, `tmax = 1`, only where the surface faces the light
//!   and `Shading::shadows` is set.
//!
//! With no reflective or transmissive materials the image is bitwise the
//! image `render_rows` makes (one light).
//!
//! # Single rays and packets
//! `render_whitted_rows` traces each pixel's ray tree depth first with
//! `Tracer::intersect` / `occluded`. `render_whitted_tiles` traces n x n
//! tiles (n = `primary.packet`, 2x2 quads in Morton order as in
//! `render_tiles`): the camera packet, then per light a shadow packet from
//! the light (`shadow_packet`, split in depth as for plain frames), then the
//! reflection packet (the lanes whose surface reflects, same quad layout,
//! the others inactive), recursively and depth first, then the refraction
//! packet likewise. Each ray class is traced in packets of its own side
//! (`TraceParams::packet`, at most the tile's; Morton order makes each an
//! n x n sub-tile): camera rays with `primary`, the shadow rays of camera
//! hits with `shadow`, reflection and refraction rays and the shadow rays of
//! their hits with `secondary`. Packets with no active lane are not traced.
//! Each lane carries a throughput weight and adds `weight * local colour`
//! to its pixel. Both paths shade through the same per-ray functions and
//! visit a pixel's ray tree in the same order, so they write the same bytes.
//!
//! NOTE(perf): on the grid, CGT packets of reflection and refraction rays
//! (and of their shadow rays) are several times slower than single 3DDDA
//! rays (balls and gears, 512 x 512, 2 + 2 bounces: 10-20x the triangle
//! tests): the rays diverge, so each slice's frustum covers many cells.
//! Use `secondary = TraceParams::dda()` with the grid; the BVH's
//! Partition traversal is the paper's answer (section 5.4).
//!
//! # Memory
//! No allocation, and the packet path keeps its packets in the calling
//! thread slot's scratch, not on the stack: per recursion level (one per
//! bounce, at most `1 + Limits::max_bounces` levels) the level's hits and
//! its child packet, once the tile, the shading of one level (surfaces, one
//! shadow packet) and the traversal below it (`scratch`, counted in
//! `required_bytes`).
//!
//! # Deviations
//! - The paper does not define its shading; the model above is the classic
//!   Whitted one with constant (not Fresnel) coefficients.
//! - Reflectance and transmittance are scalars, so a lane's throughput is
//!   one f32 (one `F4` per quad), not an RGB triple.
#![forbid(unsafe_code)]

use super::material::{Material, Materials};
use super::{
    Band, Frame, Packets, PixelRect, PointLight, PrimaryRays, SHADOW_OFFSET, ShadowPacket, Tracer,
    demorton, encode, shadow_packet,
};
use crate::accel::slot::Slot;
use crate::error::{Error, Result};
use crate::geom::{F4, Hit, Hit4, INVALID_ID, M4, Ray, Ray4};
use crate::math;
use crate::trace::{Counters, RayKind, TraceParams};
use glam::Vec3;

/// Most bounces (reflections plus refractions) on one path: bounds the
/// recursion depth and the stack (see the module docs, Memory).
pub const MAX_BOUNCES: u32 = 8;

/// Bounce limits (C: `sheaf_whitted_params`).
#[repr(C)]
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct WhittedParams {
    /// Most mirror reflections on a path. Default 2 (the paper's
    /// "2-bounce reflections", section 5.2).
    pub max_reflect: u32,
    /// Most refractions on a path. Default 2 (the paper's "2-deep
    /// refractions", section 5.2).
    pub max_refract: u32,
}

impl Default for WhittedParams {
    fn default() -> Self {
        WhittedParams {
            max_reflect: 2,
            max_refract: 2,
        }
    }
}

impl WhittedParams {
    /// `max_reflect + max_refract <= MAX_BOUNCES`.
    pub fn validate(&self) -> Result<()> {
        if self.max_reflect as u64 + self.max_refract as u64 > MAX_BOUNCES as u64 {
            return Err(Error::InvalidArgument(
                "whitted max_reflect + max_refract must be <= 8",
            ));
        }
        Ok(())
    }
}

/// Everything a Whitted frame needs besides the structure and the pixels.
/// `Copy`, read-only: share one across rendering threads.
#[derive(Clone, Copy, Debug)]
pub struct WhittedJob<'a> {
    pub frame: &'a Frame,
    /// Point lights; empty: `frame.light` alone.
    pub lights: &'a [PointLight],
    pub materials: Materials<'a>,
    pub params: WhittedParams,
    /// Camera rays (traced with `RayKind::Primary`). Its `packet` is the
    /// tile side of `render_whitted_tiles`.
    pub primary: TraceParams,
    /// Shadow rays of the surfaces camera rays hit, traced from the light
    /// (`RayKind::Shadow`).
    pub shadow: TraceParams,
    /// Reflection and refraction rays (`RayKind::Secondary`), and the shadow
    /// rays of the surfaces they hit (`RayKind::Shadow`, from the light):
    /// those end points scatter like the secondary hits, so they get the
    /// secondary method and packet size (on the grid, single rays beat CGT
    /// packets for both).
    pub secondary: TraceParams,
}

impl<'a> WhittedJob<'a> {
    /// A job tracing every kind of ray with `p`, lit by `frame.light`.
    pub fn new(
        frame: &'a Frame,
        materials: Materials<'a>,
        params: WhittedParams,
        p: TraceParams,
    ) -> Self {
        WhittedJob {
            frame,
            lights: &[],
            materials,
            params,
            primary: p,
            shadow: p,
            secondary: p,
        }
    }

    /// The lights shading uses: `lights`, or `frame.light` when empty.
    #[inline]
    pub fn lights(&self) -> &'a [PointLight] {
        if self.lights.is_empty() {
            core::slice::from_ref(&self.frame.light)
        } else {
            self.lights
        }
    }

    /// Checks the bounce limits, the materials, the three `TraceParams` and
    /// that every light is finite, and that the context's limits `l` hold
    /// the frame (Whitted renderer, bounces, packet sides).
    pub fn validate(&self, l: &crate::mem::Limits) -> Result<()> {
        l.check_renderer(crate::mem::Limits::WHITTED)?;
        self.params.validate()?;
        let bounces = self.params.max_reflect + self.params.max_refract;
        if bounces > l.max_bounces {
            return Err(Error::Capacity {
                pool: crate::error::Pool::Bounces,
                needed: bounces.into(),
                available: l.max_bounces.into(),
            });
        }
        self.materials.validate()?;
        self.primary.validate_for(l)?;
        self.shadow.validate_for(l)?;
        self.secondary.validate_for(l)?;
        for l in self.lights() {
            l.validate()?;
        }
        Ok(())
    }
}

// ---------------------------------------------------------------------------
// Per-ray shading, shared by both paths (same operations in the same order).

/// A hit as shading sees it.
#[derive(Clone, Copy, Debug)]
struct Surface {
    /// Hit point `org + dir * t` (as `render::surface` computes it).
    p: Vec3,
    /// Unit normal facing the incoming ray.
    n: Vec3,
    /// Unit incoming direction.
    u: Vec3,
    /// The ray arrived on the side the geometric normal points to.
    entering: bool,
    mat: Material,
}

/// The surface `ray` hit, or None for a miss (or a triangle the structure
/// does not hold, which `render_rows` also shades as a miss).
#[inline]
fn surface_at<T: Tracer + ?Sized>(
    tracer: &T,
    job: &WhittedJob<'_>,
    ray: &Ray,
    hit: &Hit,
) -> Option<Surface> {
    if !hit.is_hit() {
        return None;
    }
    let tri = tracer.triangle(hit.prim)?;
    let d = Vec3::from(ray.dir);
    let mut n = tri.normal().normalize_or_zero();
    let behind = n.dot(d) > 0.0;
    if behind {
        n = -n; // two-sided: face the incoming ray
    }
    let p = Vec3::from(ray.org) + d * hit.t;
    let mat = job.materials.lookup(hit.prim, job.frame.shading.albedo);
    Some(Surface {
        p,
        n,
        u: d.normalize_or_zero(),
        entering: !behind,
        mat,
    })
}

/// Cosine towards `light` and, when the surface faces it (and shadows are
/// on), the shadow ray from the light to just off the surface: the
/// arithmetic of `render::surface`.
#[inline]
fn light_ray(light: &PointLight, s: &Surface, shadows: bool, eps: f32) -> (f32, Option<Ray>) {
    light.at(s.p, s.n, shadows, eps)
}

/// Light sum after one more light (`lit`: the cosine, or 0 when shadowed).
#[inline]
fn add_light(sum: Vec3, light: &PointLight, lit: f32) -> Vec3 {
    sum + Vec3::from(light.color) * lit
}

/// How a hit's weight splits: diffuse, reflected, transmitted (see the
/// module docs: a path at a bounce limit sends that weight to diffuse).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Split {
    pub kd: f32,
    pub kr: f32,
    pub kt: f32,
}

/// The split of material `m` on a path that already has `reflections`
/// reflections and `refractions` refractions.
#[inline]
pub fn split(m: &Material, params: &WhittedParams, reflections: u32, refractions: u32) -> Split {
    let kr = if m.reflect > 0.0 && reflections < params.max_reflect {
        m.reflect
    } else {
        0.0
    };
    let kt = if m.transmit > 0.0 && refractions < params.max_refract {
        m.transmit
    } else {
        0.0
    };
    Split {
        kd: 1.0 - kr - kt,
        kr,
        kt,
    }
}

/// Local (diffuse) colour of a hit with diffuse weight `kd` and light sum `sum`.
#[inline]
fn local(s: &Surface, kd: f32, sum: Vec3) -> Vec3 {
    Vec3::from(s.mat.diffuse) * kd * sum
}

/// `acc + c * w`: the one place colour accumulates.
#[inline]
fn accumulate(acc: Vec3, c: Vec3, w: f32) -> Vec3 {
    acc + c * w
}

/// Mirror direction of unit direction `u` about unit normal `n` facing it.
#[inline]
pub fn reflect(u: Vec3, n: Vec3) -> Vec3 {
    let c = -n.dot(u);
    u + n * (2.0 * c)
}

/// Refracted direction of unit direction `u` through a surface with unit
/// normal `n` facing it, `eta` = index before / index after (Snell's law);
/// None on total internal reflection.
#[inline]
pub fn refract(u: Vec3, n: Vec3, eta: f32) -> Option<Vec3> {
    let c = -n.dot(u);
    let k = 1.0 - eta * eta * (1.0 - c * c);
    if k < 0.0 {
        None
    } else {
        Some(u * eta + n * (eta * c - math::sqrt(k)))
    }
}

#[inline]
fn reflect_ray(s: &Surface, eps: f32) -> Ray {
    Ray::new(s.p + s.n * eps, reflect(s.u, s.n), 0.0, f32::INFINITY)
}

/// The transmitted ray, or the reflected one on total internal reflection.
#[inline]
fn refract_ray(s: &Surface, eps: f32) -> Ray {
    let eta = if s.entering {
        1.0 / s.mat.ior
    } else {
        s.mat.ior
    };
    match refract(s.u, s.n, eta) {
        Some(t) => Ray::new(s.p - s.n * eps, t, 0.0, f32::INFINITY),
        None => reflect_ray(s, eps),
    }
}

#[inline]
fn pixel(c: Vec3) -> [u8; 4] {
    [encode(c.x), encode(c.y), encode(c.z), 255]
}

// ---------------------------------------------------------------------------
// Single rays.

/// What every node of a frame's ray trees shares: the tracer, the job,
/// the offset of shadow and secondary rays off surfaces and, for packets,
/// each ray type's parameters with its traversal chosen once.
struct Trees<'a, T: ?Sized> {
    tracer: &'a T,
    job: &'a WhittedJob<'a>,
    eps: f32,
    /// Camera rays, reflection and refraction rays.
    primary: Traced<'a>,
    secondary: Traced<'a>,
    /// Shadow rays from the camera rays' hits, and from deeper hits.
    shadow: Traced<'a>,
    secondary_shadow: Traced<'a>,
}

/// A ray type's parameters (with its frustum kind) and its traversal.
struct Traced<'a> {
    p: TraceParams,
    packets: Packets<'a>,
}

impl<'a> Traced<'a> {
    fn new<T: Tracer + ?Sized>(tracer: &'a T, p: &TraceParams, kind: RayKind, any: bool) -> Self {
        let p = p.with_kind(kind);
        Traced {
            p,
            packets: tracer.packets(&p, any),
        }
    }
    fn none(p: &TraceParams) -> Self {
        Traced {
            p: *p,
            packets: Packets::Unbuilt,
        }
    }
}

impl<'a, T: Tracer + ?Sized> Trees<'a, T> {
    /// For single rays (no packet traversal chosen).
    fn new(tracer: &'a T, job: &'a WhittedJob<'a>) -> Self {
        Trees {
            tracer,
            job,
            eps: SHADOW_OFFSET * tracer.scene_scale(),
            primary: Traced::none(&job.primary),
            secondary: Traced::none(&job.secondary),
            shadow: Traced::none(&job.shadow),
            secondary_shadow: Traced::none(&job.secondary),
        }
    }
    /// For packets: each ray type's traversal chosen once.
    fn packets(tracer: &'a T, job: &'a WhittedJob<'a>) -> Self {
        Trees {
            primary: Traced::new(tracer, &job.primary, RayKind::Primary, false),
            secondary: Traced::new(tracer, &job.secondary, RayKind::Secondary, false),
            shadow: Traced::new(tracer, &job.shadow, RayKind::Shadow, true),
            secondary_shadow: Traced::new(tracer, &job.secondary, RayKind::Shadow, true),
            ..Trees::new(tracer, job)
        }
    }
}

/// How deep a node of the ray tree is: the reflections and refractions on
/// the path from the camera (what `WhittedParams` bounds).
#[derive(Clone, Copy, Debug, Default)]
struct Depth {
    reflections: u32,
    refractions: u32,
}

impl Depth {
    /// A camera ray's (no bounce yet).
    fn is_camera(self) -> bool {
        self.reflections + self.refractions == 0
    }
    fn reflected(self) -> Self {
        Depth {
            reflections: self.reflections + 1,
            ..self
        }
    }
    fn refracted(self) -> Self {
        Depth {
            refractions: self.refractions + 1,
            ..self
        }
    }
}

/// Add the colour of `ray`'s tree, weighted by `w`, to `acc`: depth first,
/// local shading, then the reflected subtree, then the refracted one.
fn trace_ray<T: Tracer + ?Sized>(
    f: &Trees<'_, T>,
    ray: &Ray,
    w: f32,
    depth: Depth,
    acc: &mut Vec3,
    ctr: &mut Counters,
) {
    let (tracer, job, eps) = (f.tracer, f.job, f.eps);
    let sh = &job.frame.shading;
    let hit = tracer.intersect(ray, ctr);
    let Some(s) = surface_at(tracer, job, ray, &hit) else {
        *acc = accumulate(*acc, Vec3::from(sh.background), w);
        return;
    };
    let mut sum = Vec3::splat(sh.ambient);
    for light in job.lights() {
        let (cos, sray) = light_ray(light, &s, sh.shadows, eps);
        let lit = match sray {
            Some(r) if tracer.occluded(&r, ctr) => 0.0,
            _ => cos,
        };
        sum = add_light(sum, light, lit);
    }
    let k = split(&s.mat, &job.params, depth.reflections, depth.refractions);
    *acc = accumulate(*acc, local(&s, k.kd, sum), w);
    if k.kr > 0.0 {
        let ray = reflect_ray(&s, eps);
        trace_ray(f, &ray, w * k.kr, depth.reflected(), acc, ctr);
    }
    if k.kt > 0.0 {
        let ray = refract_ray(&s, eps);
        trace_ray(f, &ray, w * k.kt, depth.refracted(), acc, ctr);
    }
}

/// Linear RGB colour of one ray's Whitted tree (single rays), as the
/// renderers compute it before encoding.
pub fn radiance<T: Tracer + ?Sized>(
    tracer: &T,
    job: &WhittedJob<'_>,
    ray: &Ray,
    ctr: &mut Counters,
) -> [f32; 3] {
    let mut acc = Vec3::ZERO;
    trace_ray(
        &Trees::new(tracer, job),
        ray,
        1.0,
        Depth::default(),
        &mut acc,
        ctr,
    );
    acc.to_array()
}

/// Render `band` of `job.frame` one ray tree at a time with
/// `Tracer::intersect` and `occluded`. RGBA8 as `render_rows`. The
/// reference of `render_whitted_tiles`.
#[inline(never)]
pub fn render_whitted_rows<T: Tracer + ?Sized>(
    tracer: &T,
    job: &WhittedJob<'_>,
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
    let f = Trees::new(tracer, job);
    for y in y0..y1 {
        let row = &mut pixels[(y - y0) as usize * stride..];
        for x in 0..job.frame.width {
            let mut acc = Vec3::ZERO;
            trace_ray(&f, &rays.ray(x, y), 1.0, Depth::default(), &mut acc, ctr);
            row[x as usize * 4..x as usize * 4 + 4].copy_from_slice(&pixel(acc));
        }
    }
}

// ---------------------------------------------------------------------------
// Packets.

const LANE_XY: [(u32, u32); 4] = [(0, 0), (1, 0), (0, 1), (1, 1)];

/// Filler of lanes no ray of the quad is active in.
#[inline]
fn idle_ray() -> Ray {
    Ray::new(Vec3::ZERO, Vec3::X, 0.0, 0.0)
}

/// Pack a quad: inactive lanes repeat an active lane's ray (finite, inside
/// the packet's bounds) so no traversal sees stray data.
#[inline]
fn pack(lanes: &mut [Ray; 4], m: &[bool; 4]) -> (Ray4, M4) {
    if let Some(k) = (0..4).find(|&i| m[i]) {
        for i in 0..4 {
            if !m[i] {
                lanes[i] = lanes[k];
            }
        }
    }
    (Ray4::from_rays(lanes), M4::new(m[0], m[1], m[2], m[3]))
}

/// Render `band` (`y0` a multiple of the packet side) in n x n tiles,
/// n = `job.primary.packet`: primary packets with `job.primary`, shadow
/// packets with `job.shadow`, reflection and refraction packets with
/// `job.secondary`. Same bytes as `render_whitted_rows` with the same
/// structure. `slot` is the calling thread's mailbox.
pub fn render_whitted_tiles<T: Tracer + ?Sized>(
    tracer: &T,
    job: &WhittedJob<'_>,
    rays: &PrimaryRays,
    band: Band<'_>,
    slot: &mut Slot<'_>,
    ctr: &mut Counters,
) {
    match job.primary.packet {
        2 => tiles::<T, 1>(tracer, job, rays, band, slot, ctr),
        4 => tiles::<T, 4>(tracer, job, rays, band, slot, ctr),
        8 => tiles::<T, 16>(tracer, job, rays, band, slot, ctr),
        16 => tiles::<T, 64>(tracer, job, rays, band, slot, ctr),
        _ => tiles::<T, { crate::accel::packet::MAX_QUADS }>(tracer, job, rays, band, slot, ctr),
    }
}

/// A packet of one level of the ray trees: its quads, their active lanes
/// and each lane's throughput (the weight its colour is added with), in
/// the slot's scratch.
struct Packet<'s> {
    rays: &'s mut [Ray4],
    active: &'s mut [M4],
    w: &'s mut [F4],
}

impl<'s> Packet<'s> {
    /// An idle packet of `q` quads with throughput `w` from `slot`, and the
    /// rest of the slot.
    fn idle(slot: Slot<'s>, q: usize, w: F4) -> (Packet<'s>, Slot<'s>) {
        let (rays, slot) = slot.take(q, Ray4::from_rays(&[idle_ray(); 4]));
        let (active, slot) = slot.take(q, M4::FALSE);
        let (w, slot) = slot.take(q, w);
        (Packet { rays, active, w }, slot)
    }
}

/// Slot scratch of a Whitted tile of up to `q` quads at the deepest of
/// `bounces` bounces: the tile (camera packet, colours), per level (the
/// camera's and one per bounce) a packet of hits, per bounce the child
/// packet, and the largest shading scratch (`shade_packet`).
pub const fn scratch(q: usize, bounces: u32) -> usize {
    use crate::mem::scratch::bytes;
    let packet = bytes::<Ray4>(q) + bytes::<M4>(q) + bytes::<F4>(q);
    let shade = bytes::<[Option<Surface>; 4]>(q)
        + bytes::<[Vec3; 4]>(q)
        + bytes::<Ray4>(q)
        + bytes::<M4>(q)
        + bytes::<Hit4>(q)
        + 2 * bytes::<F4>(q);
    // One level per bounce plus the camera level.
    let levels = bounces as usize + 1;
    packet + bytes::<[Vec3; 4]>(q) + levels * bytes::<Hit4>(q) + (levels - 1) * packet + shade
}

// Not inlined: the five size classes would share one caller frame.
#[inline(never)]
fn tiles<T: Tracer + ?Sized, const Q: usize>(
    tracer: &T,
    job: &WhittedJob<'_>,
    rays: &PrimaryRays,
    band: Band<'_>,
    slot: &mut Slot<'_>,
    ctr: &mut Counters,
) {
    let Band {
        y0,
        y1,
        pixels,
        stride,
    } = band;
    let n = 2 * (Q as u32).isqrt();
    let f = Trees::packets(tracer, job);
    let width = job.frame.width;
    // Camera rays have throughput 1.
    let (pk, s) = Packet::idle(slot.reborrow(), Q, F4::ONE);
    let (acc, mut slot) = s.take(Q, [Vec3::ZERO; 4]);
    let rect = PixelRect {
        x0: 0,
        y0,
        x1: width,
        y1,
    };
    // Stepped ranges: a tile origin past u32::MAX is never formed.
    for ty in (y0..y1).step_by(n as usize) {
        for tx in (0..width).step_by(n as usize) {
            rays.packet(tx, ty, n, &rect, pk.rays, pk.active);
            acc.fill([Vec3::ZERO; 4]);
            level::<T, Q>(&f, &pk, Depth::default(), acc, &mut slot, ctr);
            for (q, (quad, m)) in acc.iter().zip(pk.active.iter()).enumerate() {
                let (qx, qy) = demorton(q);
                for (i, (dx, dy)) in LANE_XY.iter().enumerate() {
                    if m.test(i) {
                        let (x, y) = (tx + 2 * qx + dx, ty + 2 * qy + dy);
                        let at = (y - y0) as usize * stride + x as usize * 4;
                        pixels[at..at + 4].copy_from_slice(&pixel(quad[i]));
                    }
                }
            }
        }
    }
}

/// The packets of `p` in a tile of `q` quads: runs of `(p.packet / 2)^2`
/// quads (Morton order makes each an n x n sub-tile), at most the tile;
/// single-ray methods take the whole tile (they trace lane by lane).
#[inline]
fn packets(p: &TraceParams, q: usize) -> impl Iterator<Item = core::ops::Range<usize>> {
    let k = if p.method.is_packet() {
        ((p.packet / 2) as usize).pow(2).clamp(1, q)
    } else {
        q
    };
    (0..q).step_by(k).map(move |s| s..(s + k).min(q))
}

/// One recursion level: trace the packet, shade its hits (shadow packets
/// included), then recurse into its reflection packet and its refraction
/// packet. Lane (q, i) of every level belongs to pixel lane (q, i) of the tile.
#[inline(never)]
fn level<T: Tracer + ?Sized, const Q: usize>(
    f: &Trees<'_, T>,
    pk: &Packet<'_>,
    depth: Depth,
    acc: &mut [[Vec3; 4]],
    slot: &mut Slot<'_>,
    ctr: &mut Counters,
) {
    let Traced { p, packets: traced } = if depth.is_camera() {
        &f.primary
    } else {
        &f.secondary
    };
    let (rays, active) = (&pk.rays, &pk.active);
    // This level's hits and child packet stay in the slot's scratch while
    // the deeper levels use the rest of it.
    let (hits, mut slot) = slot.split(Q, Hit4::MISS);
    for r in packets(p, Q) {
        if active[r.clone()].iter().any(|m| m.any()) {
            traced.run(
                p,
                &rays[r.clone()],
                &active[r.clone()],
                &mut hits[r],
                &mut slot,
                ctr,
            );
        }
    }
    let (want_r, want_t) = shade_packet::<T, Q>(f, pk, hits, depth, acc, &mut slot, ctr);
    if !(want_r || want_t) {
        return;
    }
    let (mut cpk, mut slot) = Packet::idle(slot, Q, F4::ZERO);
    if want_r && child::<T, Q>(f, true, pk, hits, depth, &mut cpk) {
        level::<T, Q>(f, &cpk, depth.reflected(), acc, &mut slot, ctr);
    }
    if want_t && child::<T, Q>(f, false, pk, hits, depth, &mut cpk) {
        level::<T, Q>(f, &cpk, depth.refracted(), acc, &mut slot, ctr);
    }
}

/// Local shading of a traced packet: per light one shadow packet from the
/// light, then `acc += w * local` per active lane (background for misses).
/// Returns whether any lane reflects and whether any transmits.
#[inline(never)]
fn shade_packet<T: Tracer + ?Sized, const Q: usize>(
    f: &Trees<'_, T>,
    pk: &Packet<'_>,
    hits: &[Hit4],
    depth: Depth,
    acc: &mut [[Vec3; 4]],
    slot: &mut Slot<'_>,
    ctr: &mut Counters,
) -> (bool, bool) {
    let (tracer, job, eps) = (f.tracer, f.job, f.eps);
    let (rays, active, w) = (&pk.rays, &pk.active, &pk.w);
    let Depth {
        reflections,
        refractions,
    } = depth;
    let sh = &job.frame.shading;
    let (surf, s) = slot.reborrow().take(Q, [None::<Surface>; 4]);
    let (sum, s) = s.take(Q, [Vec3::splat(sh.ambient); 4]);
    let mut any_hit = false;
    for (q, lanes) in surf.iter_mut().enumerate() {
        for (i, s) in lanes.iter_mut().enumerate() {
            if active[q].test(i) {
                *s = surface_at(tracer, job, &rays[q].lane(i), &hits[q].lane(i));
                any_hit |= s.is_some();
            }
        }
    }
    if any_hit {
        let Traced {
            p: shadow,
            packets: shadowed,
        } = if depth.is_camera() {
            &f.shadow
        } else {
            &f.secondary_shadow
        };
        let (squads, s) = s.take(Q, Ray4::from_rays(&[idle_ray(); 4]));
        let (sactive, s) = s.take(Q, M4::FALSE);
        let (shits, s) = s.take(Q, Hit4::MISS);
        let (sdist, s) = s.take(Q, F4::ZERO);
        let (cosines, mut slot) = s.take(Q, F4::ZERO);
        for light in job.lights() {
            for q in 0..Q {
                let mut lanes = [idle_ray(); 4];
                let mut m = [false; 4];
                for i in 0..4 {
                    cosines[q][i] = 0.0;
                    if let Some(s) = &surf[q][i] {
                        let (cos, sray) = light_ray(light, s, sh.shadows, eps);
                        cosines[q][i] = cos;
                        if let Some(r) = sray {
                            sdist[q][i] = Vec3::from(r.dir).length();
                            lanes[i] = r;
                            m[i] = true;
                        }
                    }
                }
                (squads[q], sactive[q]) = pack(&mut lanes, &m);
                shits[q] = Hit4::MISS;
            }
            for r in packets(shadow, Q) {
                let packet = ShadowPacket {
                    rays: &squads[r.clone()],
                    active: &sactive[r.clone()],
                    dist: &sdist[r.clone()],
                };
                shadow_packet(shadowed, shadow, packet, &mut shits[r], &mut slot, ctr);
            }
            for q in 0..Q {
                for i in 0..4 {
                    if surf[q][i].is_some() {
                        let lit = if shits[q].prim[i] != INVALID_ID {
                            0.0
                        } else {
                            cosines[q][i]
                        };
                        sum[q][i] = add_light(sum[q][i], light, lit);
                    }
                }
            }
        }
    }
    let (mut want_r, mut want_t) = (false, false);
    for q in 0..Q {
        for i in 0..4 {
            if !active[q].test(i) {
                continue;
            }
            acc[q][i] = match &surf[q][i] {
                None => accumulate(acc[q][i], Vec3::from(sh.background), w[q][i]),
                Some(s) => {
                    let k = split(&s.mat, &job.params, reflections, refractions);
                    want_r |= k.kr > 0.0;
                    want_t |= k.kt > 0.0;
                    accumulate(acc[q][i], local(s, k.kd, sum[q][i]), w[q][i])
                }
            };
        }
    }
    (want_r, want_t)
}

/// Build the reflection (`reflected`) or refraction packet of a traced
/// packet into `out`: the lanes whose split gives that direction a weight,
/// with throughput `w * kr` (or `w * kt`). Returns whether any lane is active.
fn child<T: Tracer + ?Sized, const Q: usize>(
    f: &Trees<'_, T>,
    reflected: bool,
    pk: &Packet<'_>,
    hits: &[Hit4],
    depth: Depth,
    out: &mut Packet<'_>,
) -> bool {
    let (tracer, job, eps) = (f.tracer, f.job, f.eps);
    let (rays, active, w) = (&pk.rays, &pk.active, &pk.w);
    let Depth {
        reflections,
        refractions,
    } = depth;
    let mut any = false;
    for q in 0..Q {
        let mut lanes = [idle_ray(); 4];
        let mut m = [false; 4];
        for i in 0..4 {
            if !active[q].test(i) {
                continue;
            }
            let Some(s) = surface_at(tracer, job, &rays[q].lane(i), &hits[q].lane(i)) else {
                continue;
            };
            let k = split(&s.mat, &job.params, reflections, refractions);
            let kk = if reflected { k.kr } else { k.kt };
            if kk > 0.0 {
                lanes[i] = if reflected {
                    reflect_ray(&s, eps)
                } else {
                    refract_ray(&s, eps)
                };
                out.w[q][i] = w[q][i] * kk;
                m[i] = true;
            }
        }
        any |= m.iter().any(|&b| b);
        (out.rays[q], out.active[q]) = pack(&mut lanes, &m);
    }
    any
}

#[cfg(test)]
mod tests {
    use super::*;

    fn close(a: Vec3, b: Vec3) -> bool {
        (a - b).abs().max_element() < 1e-6
    }

    #[test]
    fn params_validate() {
        assert!(WhittedParams::default().validate().is_ok());
        assert!(
            WhittedParams {
                max_reflect: 8,
                max_refract: 0
            }
            .validate()
            .is_ok()
        );
        assert!(
            WhittedParams {
                max_reflect: 5,
                max_refract: 4
            }
            .validate()
            .is_err()
        );
        assert!(
            WhittedParams {
                max_reflect: u32::MAX,
                max_refract: 2
            }
            .validate()
            .is_err()
        );
    }

    #[test]
    fn reflection_and_snell() {
        let n = Vec3::Z;
        let u = Vec3::new(1.0, 0.0, -1.0).normalize();
        assert!(close(reflect(u, n), Vec3::new(1.0, 0.0, 1.0).normalize()));
        // Entering glass at 45 degrees: sin t = sin i / 1.5.
        let t = refract(u, n, 1.0 / 1.5).unwrap();
        assert!((t.length() - 1.0).abs() < 1e-6);
        assert!((t.x - (0.5f32.sqrt() / 1.5)).abs() < 1e-6 && t.z < 0.0);
        // Head-on: straight through.
        assert!(close(refract(-n, n, 1.0 / 1.5).unwrap(), -n));
        // Leaving glass beyond the critical angle (41.8 degrees): total
        // internal reflection; just below it: grazing exit.
        assert!(refract(u, n, 1.5).is_none());
        let a = (1.0f32 / 1.5).asin() - 1e-3;
        let below = refract(Vec3::new(a.sin(), 0.0, -a.cos()), n, 1.5).unwrap();
        assert!(below.z.abs() < 0.1 && below.is_finite());
    }

    #[test]
    fn split_sends_capped_weight_to_diffuse() {
        let m = Material {
            diffuse: [1.0; 3],
            reflect: 0.3,
            transmit: 0.5,
            ior: 1.5,
        };
        let p = WhittedParams {
            max_reflect: 1,
            max_refract: 2,
        };
        let s = split(&m, &p, 0, 0);
        assert_eq!((s.kr, s.kt), (0.3, 0.5));
        assert!((s.kd + s.kr + s.kt - 1.0).abs() < 1e-6);
        assert_eq!(
            split(&m, &p, 1, 0),
            Split {
                kd: 0.5,
                kr: 0.0,
                kt: 0.5
            }
        );
        assert_eq!(
            split(&m, &p, 1, 2),
            Split {
                kd: 1.0,
                kr: 0.0,
                kt: 0.0
            }
        );
        assert_eq!(
            split(&Material::diffuse([0.5; 3]), &p, 0, 0),
            Split {
                kd: 1.0,
                kr: 0.0,
                kt: 0.0
            }
        );
    }

    #[test]
    fn total_internal_reflection_keeps_the_weight_on_the_mirror_ray() {
        let mat = Material {
            diffuse: [1.0; 3],
            reflect: 0.0,
            transmit: 1.0,
            ior: 1.5,
        };
        // Inside a glass surface (leaving it), grazing: the transmitted ray
        // is the mirror ray, offset outwards (to the incoming side).
        let u = Vec3::new(0.9, 0.0, -(1.0f32 - 0.81).sqrt());
        let s = Surface {
            p: Vec3::ZERO,
            n: Vec3::Z,
            u,
            entering: false,
            mat,
        };
        let r = refract_ray(&s, 1e-3);
        assert_eq!(r, reflect_ray(&s, 1e-3));
        assert!(r.org[2] > 0.0 && Vec3::from(r.dir).is_finite() && r.dir[2] > 0.0);
        // Entering at the same angle refracts inwards.
        let e = refract_ray(
            &Surface {
                entering: true,
                ..s
            },
            1e-3,
        );
        assert!(e.org[2] < 0.0 && e.dir[2] < 0.0);
    }
}
