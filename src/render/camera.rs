//! The pinhole camera and its rays, made in the kernel: one ray per pixel
//! (`PrimaryRays::ray`), a 2x2 quad of them at once (`quad`), a packet of
//! n x n pixels with its quads in Morton order (`packet`), and a pixel
//! rectangle traced as such packets by any method (`CameraRays`, a
//! `RaySource`: `Context::trace_camera`, `trace_scene_camera` and the C
//! `sheaf_context_trace_camera`).
//!
//! Ray tracing's camera packets follow the image: Wald et al. 2001 trace
//! 2x2 pixel quads, CGT (Wald et al. 2006, section 4) and the BVH packet
//! papers (Wald, Boulos and Shirley 2007; Overbeck, Ramamoorthi and Mark
//! 2008) tiles of n x n pixels. A caller's ray array must be laid out
//! that way by hand; here the kernel makes the tile's quads itself.
//!
//! # Exactness
//! `quad` computes each lane's direction as `ray` does, component by
//! component, `corner + du * (x + 0.5) + dv * (y + 0.5)` in the same order
//! (Rust never fuses a multiply and an add), so every generated ray is bit
//! for bit `ray(x, y)`, the ray `sheaf_frame_camera_ray` returns; every
//! method then answers it as it answers that ray in a ray array (unit test
//! below; `tests/context.rs` for every method's hits).
//!
//! # Deviations
//! A packet's pixels outside the rectangle are traced as inactive lanes
//! (their results are dropped), so a rectangle whose sides are not
//! multiples of the packet side pays for part-empty packets at its right
//! and bottom edges, as the renderers' tiles do at the image's.

use crate::error::{Error, Result};
use crate::geom::{F4, M4, Ray, Ray4};
use crate::math;
use crate::trace::{RaySource, TraceParams};
use glam::Vec3;

/// Pinhole camera (C: `sheaf_camera`). Any finite camera is valid whose
/// `look_at` differs from `eye` and whose `up` is neither zero nor
/// parallel to the view (within 1e-6 radians): the vectors are normalised
/// (at any finite scale) before use.
#[repr(C)]
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Camera {
    pub eye: [f32; 3],
    pub look_at: [f32; 3],
    pub up: [f32; 3],
    /// Vertical field of view in degrees, in (0, 180).
    pub fov_y_deg: f32,
}

/// Camera basis and per-pixel ray generation for a `width x height` image.
#[derive(Clone, Copy, Debug)]
pub struct PrimaryRays {
    eye: Vec3,
    corner: Vec3,
    du: Vec3,
    dv: Vec3,
    pinhole: crate::accel::pgrid::Pinhole,
}

impl PrimaryRays {
    /// The camera's basis, normalised whatever the scale of its vectors
    /// (an `up` of 1e20 or 1e-30, an eye 3e19 from its target): only a
    /// camera degenerate after normalisation (`eye == look_at`, `up` zero
    /// or parallel to the view) or with a non-finite field is refused.
    pub fn new(cam: &Camera, width: u32, height: u32) -> Result<Self> {
        let eye = Vec3::from(cam.eye);
        // In f64: the difference of two finite f32 points never overflows.
        let fwd = glam::DVec3::from(cam.look_at.map(f64::from)) - eye.as_dvec3();
        let up = Vec3::from(cam.up);
        // Stated as what is valid, so that NaN fails.
        let valid = eye.is_finite()
            && Vec3::from(cam.look_at).is_finite()
            && up.is_finite()
            && cam.fov_y_deg > 0.0
            && cam.fov_y_deg < 180.0
            && width > 0
            && height > 0;
        if !valid {
            return Err(Error::InvalidArgument(
                "camera: finite eye/look_at/up, fov in (0, 180), a non-empty image",
            ));
        }
        // The plain basis where every square is a normal f32 (every
        // ordinary camera: its bits are the ones sheaf always made), else
        // the same basis normalised at any scale.
        let plain = || {
            let f = Vec3::from(cam.look_at) - eye;
            if !f.length_squared().is_normal() {
                return None;
            }
            let w = f.normalize();
            let u = w.cross(up);
            let u2 = u.length_squared();
            (u2.is_normal() && u2 >= 1e-12 * up.length_squared()).then(|| (w, u.normalize()))
        };
        let (w, u) = match plain() {
            Some(b) => b,
            None => {
                let m = fwd.abs().max_element();
                if m <= 0.0 {
                    return Err(Error::InvalidArgument(
                        "camera: eye and look_at must differ",
                    ));
                }
                let w = (fwd / m).normalize().as_vec3();
                // Parallel: within rounding of the view direction (the
                // sine of the angle between the unit vectors below 1e-6),
                // where the basis would be rounding noise.
                let u = unit(up)
                    .map(|up| w.cross(up))
                    .filter(|u| u.length() >= 1e-6)
                    .and_then(unit)
                    .ok_or(Error::InvalidArgument(
                        "camera: up must be non-zero and not parallel to the view direction",
                    ))?;
                (w, u)
            }
        };
        let v = u.cross(w);
        let half_h = math::tan(cam.fov_y_deg.to_radians() * 0.5);
        let half_w = half_h * width as f32 / height as f32;
        let du = u * (2.0 * half_w / width as f32);
        let dv = -v * (2.0 * half_h / height as f32);
        let corner = w - u * half_w + v * half_h;
        Ok(PrimaryRays {
            eye,
            corner,
            du,
            dv,
            pinhole: crate::accel::pgrid::Pinhole {
                eye,
                right: u,
                down: -v,
                fwd: w,
                half_w,
                half_h,
                width,
                height,
            },
        })
    }

    /// The camera as the perspective grid maps it.
    pub fn pinhole(&self) -> crate::accel::pgrid::Pinhole {
        self.pinhole
    }

    /// Ray through the centre of pixel (x, y); y grows downwards.
    #[inline]
    pub fn ray(&self, x: u32, y: u32) -> Ray {
        self.ray_at(x.into(), y.into())
    }

    /// `ray` of a pixel coordinate that may lie past the image (the lanes
    /// of a packet overhanging it at the u32 edge): the same operations,
    /// since a u64 and a u32 of one value convert to the same f32.
    #[inline(always)]
    fn ray_at(&self, x: u64, y: u64) -> Ray {
        let d = self.corner + self.du * (x as f32 + 0.5) + self.dv * (y as f32 + 0.5);
        Ray::new(self.eye, d, 0.0, f32::INFINITY)
    }

    /// The image size this camera was made for.
    pub fn size(&self) -> (u32, u32) {
        (self.pinhole.width, self.pinhole.height)
    }

    /// The 2x2 quad of pixels (x, y), (x+1, y), (x, y+1), (x+1, y+1) in
    /// `Ray4` lane order, each lane bit for bit `ray` of its pixel: the
    /// same IEEE operations in the same order, four lanes at once.
    /// Pixel coordinates are u64 so that a quad overhanging the image at
    /// the u32 edge has its own (finite) rays, not wrapped ones.
    #[inline(always)]
    pub fn quad(&self, x: u64, y: u64) -> Ray4 {
        let fx = F4::new(x as f32, (x + 1) as f32, x as f32, (x + 1) as f32) + F4::splat(0.5);
        let fy = F4::new(y as f32, y as f32, (y + 1) as f32, (y + 1) as f32) + F4::splat(0.5);
        let (c, du, dv) = (self.corner, self.du, self.dv);
        let d = |c: f32, du: f32, dv: f32| F4::splat(c) + F4::splat(du) * fx + F4::splat(dv) * fy;
        Ray4 {
            org: [self.eye.x, self.eye.y, self.eye.z].map(F4::splat),
            dir: [d(c.x, du.x, dv.x), d(c.y, du.y, dv.y), d(c.z, du.z, dv.z)],
            tmin: F4::ZERO,
            tmax: F4::INFINITY,
        }
    }

    /// The camera packet of the `side` x `side` pixels from (x0, y0):
    /// `(side / 2)^2` quads in Morton order (`demorton`), lanes of pixels
    /// outside `rect` inactive (they still hold their pixel's finite ray).
    /// The renderers' and `CameraRays`' one packet generator; (x0, y0) is
    /// a pixel of the image, the packet may reach past `u32::MAX`.
    #[inline]
    pub fn packet(
        &self,
        x0: u32,
        y0: u32,
        side: u32,
        rect: &PixelRect,
        quads: &mut [Ray4],
        active: &mut [M4],
    ) -> usize {
        let nq = ((side / 2) * (side / 2)) as usize;
        // In u64: a packet may overhang a rectangle that ends at u32::MAX.
        let (x0, y0, side) = (u64::from(x0), u64::from(y0), u64::from(side));
        let (x1, y1) = (u64::from(rect.x1), u64::from(rect.y1));
        let inside = x0 + side <= x1 && y0 + side <= y1;
        for (q, (quad, act)) in quads[..nq].iter_mut().zip(&mut active[..nq]).enumerate() {
            let (qx, qy) = demorton(q);
            let (x, y) = (x0 + 2 * u64::from(qx), y0 + 2 * u64::from(qy));
            *quad = self.quad(x, y);
            *act = if inside {
                M4::TRUE
            } else {
                let (cx, cy) = (x + 1 < x1, y + 1 < y1);
                let (ax, ay) = (x < x1, y < y1);
                M4::new(ax && ay, cx && ay, ax && cy, cx && cy)
            };
        }
        nq
    }
}

/// A rectangle of pixels, `x0 <= x < x1`, `y0 <= y < y1` (C:
/// `sheaf_pixel_rect`); x grows to the right, y downwards.
#[repr(C)]
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct PixelRect {
    pub x0: u32,
    pub y0: u32,
    pub x1: u32,
    pub y1: u32,
}

impl PixelRect {
    /// The whole `width x height` image.
    pub fn image(width: u32, height: u32) -> PixelRect {
        PixelRect {
            x0: 0,
            y0: 0,
            x1: width,
            y1: height,
        }
    }
    /// Width and height in pixels.
    pub fn size(&self) -> (u32, u32) {
        (self.x1 - self.x0, self.y1 - self.y0)
    }
    /// The results a buffer of the rectangle's pixels needs, rows `row`
    /// apart (pixel (x, y) at `(y - y0) * row + (x - x0)`):
    /// `InvalidArgument` when `row` is below the width or the count
    /// overflows.
    pub fn results(&self, row: usize) -> Result<usize> {
        let (w, h) = self.size();
        let need = (h.max(1) as usize - 1)
            .checked_mul(row)
            .and_then(|n| n.checked_add(w as usize));
        match need {
            Some(need) if row >= w as usize => Ok(need),
            _ => Err(Error::InvalidArgument(
                "results must hold the rectangle's pixels, rows at least its width apart",
            )),
        }
    }
    /// `results`, and `InvalidArgument` when `len` is fewer.
    pub fn check_results(&self, len: usize, row: usize) -> Result<()> {
        if len >= self.results(row)? {
            Ok(())
        } else {
            Err(Error::InvalidArgument(
                "results must hold the rectangle's pixels, rows at least its width apart",
            ))
        }
    }
    /// `InvalidArgument` unless the rectangle is non-empty and inside a
    /// `width x height` image.
    pub fn check(&self, width: u32, height: u32) -> Result<()> {
        if self.x0 < self.x1 && self.y0 < self.y1 && self.x1 <= width && self.y1 <= height {
            Ok(())
        } else {
            Err(Error::InvalidArgument(
                "pixel rectangle empty or outside the image",
            ))
        }
    }
}

/// The camera rays of a pixel rectangle as a `RaySource`: packets of
/// `side` x `side` pixels (the call's packet side; 2 for single-ray
/// methods), tiles row by row over the rectangle, inside a tile the 2x2
/// quads in Morton order. Ray `i` is pixel `pixel(i)`; `count` rays in
/// all, those of pixels outside the rectangle (part-empty edge tiles)
/// inactive in packets and dropped by the caller (`pixel` is `None`).
#[derive(Clone, Copy, Debug)]
pub struct CameraRays<'a> {
    rays: &'a PrimaryRays,
    rect: PixelRect,
    side: u32,
    tiles_x: u32,
    tiles_y: u32,
}

impl<'a> CameraRays<'a> {
    /// The rays of `rect` (inside the camera's image) in packets of
    /// `p`'s side (2 without `p` or for single-ray methods).
    pub fn new(
        rays: &'a PrimaryRays,
        rect: PixelRect,
        p: Option<&TraceParams>,
    ) -> Result<CameraRays<'a>> {
        let (w, h) = rays.size();
        rect.check(w, h)?;
        let side = match p {
            Some(p) if p.method.is_packet() => {
                p.validate()?;
                p.packet
            }
            _ => 2,
        };
        let (rw, rh) = rect.size();
        let (tiles_x, tiles_y) = (rw.div_ceil(side), rh.div_ceil(side));
        // `count` in a usize: whole tiles may hold more rays than pixels.
        (tiles_x as usize)
            .checked_mul(tiles_y as usize)
            .and_then(|n| n.checked_mul((side * side) as usize))
            .ok_or(Error::InvalidArgument(
                "pixel rectangle: more rays than the address space",
            ))?;
        Ok(CameraRays {
            rays,
            rect,
            side,
            tiles_x,
            tiles_y,
        })
    }

    /// Rays in all: whole tiles, so a multiple of the packet's rays
    /// (`new` checked that it fits a `usize`).
    pub fn count(&self) -> usize {
        self.tiles_x as usize * self.tiles_y as usize * (self.side * self.side) as usize
    }

    /// Top-left pixel of tile `k`: inside the rectangle, so a u32.
    #[inline(always)]
    fn tile(&self, k: usize) -> (u32, u32) {
        // `k` may pass u32::MAX (2^32 tiles of 2x2 pixels); the quotient
        // and remainder are below `tiles_y` and `tiles_x`.
        let tiles_x = self.tiles_x as usize;
        let (tx, ty) = ((k % tiles_x) as u32, (k / tiles_x) as u32);
        (self.rect.x0 + tx * self.side, self.rect.y0 + ty * self.side)
    }

    /// Pixel of ray `j` of a tile whose top-left pixel is (x0, y0), in u64:
    /// a part-empty tile at a rectangle ending at u32::MAX reaches past it.
    #[inline(always)]
    fn in_tile(&self, (x0, y0): (u32, u32), j: usize) -> (u64, u64) {
        let (qx, qy) = demorton(j >> 2);
        let l = (j & 3) as u64;
        (
            u64::from(x0) + 2 * u64::from(qx) + (l & 1),
            u64::from(y0) + 2 * u64::from(qy) + (l >> 1),
        )
    }

    /// Pixel of ray `i` (any `i < count`; may lie outside the rectangle).
    #[inline(always)]
    fn at(&self, i: usize) -> (u64, u64) {
        let per = (self.side * self.side) as usize;
        self.in_tile(self.tile(i / per), i % per)
    }

    /// Whether pixel (x, y) of `at` lies inside the rectangle (it is at
    /// or right of and below its corner by construction).
    #[inline(always)]
    fn inside(&self, (x, y): (u64, u64)) -> bool {
        x < u64::from(self.rect.x1) && y < u64::from(self.rect.y1)
    }

    /// The pixel ray `i` is shot through, relative to the rectangle's
    /// corner; `None` for the lanes of part-empty tiles outside it.
    #[inline(always)]
    pub fn pixel(&self, i: usize) -> Option<(u32, u32)> {
        let (x, y) = self.at(i);
        // Inside: below x1 and y1, so the offsets fit a u32.
        self.inside((x, y)).then(|| {
            (
                (x - u64::from(self.rect.x0)) as u32,
                (y - u64::from(self.rect.y0)) as u32,
            )
        })
    }

    /// Where each ray's result goes in a buffer of the rectangle's pixels,
    /// rows `row` apart (`PixelIndex`).
    pub fn index(&self, row: usize) -> PixelIndex<'_, 'a> {
        PixelIndex {
            rays: self,
            row,
            shift: (self.side * self.side).trailing_zeros(),
            tile: usize::MAX,
            origin: (0, 0),
        }
    }
}

/// A camera call's result positions: ray `i`'s pixel as an index into the
/// caller's buffer, for rays handed out packet by packet (the tile's
/// origin is worked out once per packet, not once per ray).
pub struct PixelIndex<'c, 'a> {
    rays: &'c CameraRays<'a>,
    row: usize,
    shift: u32,
    tile: usize,
    origin: (u32, u32),
}

impl PixelIndex<'_, '_> {
    /// Pixel of ray `i`, the tile's origin worked out when the tile changes.
    #[inline(always)]
    fn at(&mut self, i: usize) -> (u64, u64) {
        let k = i >> self.shift;
        if k != self.tile {
            self.tile = k;
            self.origin = self.rays.tile(k);
        }
        self.rays.in_tile(self.origin, i & ((1 << self.shift) - 1))
    }

    /// Buffer index of ray `i`'s pixel, `(y - y0) * row + (x - x0)`;
    /// `None` for a pixel outside the rectangle (the scene calls' per-ray
    /// results).
    #[inline(always)]
    pub fn of(&mut self, i: usize) -> Option<usize> {
        let (x, y) = self.at(i);
        self.rays.inside((x, y)).then(|| self.index((x, y)))
    }

    /// `(y - y0) * row + (x - x0)` of a pixel inside the rectangle: at most
    /// `PixelRect::results(row)`, which the caller checked fits a `usize`.
    #[inline(always)]
    fn index(&self, (x, y): (u64, u64)) -> usize {
        let r = &self.rays.rect;
        (y - u64::from(r.y0)) as usize * self.row + (x - u64::from(r.x0)) as usize
    }

    /// Buffer indices of the four rays `i .. i + 4` of a quad (`i` a multiple of
    /// 4), in `Ray4` lane order: pixels (x, y), (x+1, y), (x, y+1),
    /// (x+1, y+1), two pairs side by side in the buffer.
    #[inline(always)]
    pub fn quad(&mut self, i: usize) -> [Option<usize>; 4] {
        let (x, y) = self.at(i);
        let c = self.rays;
        // Only formed for pixels inside, whose index is in the buffer.
        let at = |dx: u64, dy: u64| {
            let p = (x + dx, y + dy);
            c.inside(p).then(|| self.index(p))
        };
        [at(0, 0), at(1, 0), at(0, 1), at(1, 1)]
    }
}

impl RaySource for CameraRays<'_> {
    #[inline(always)]
    fn ray(&self, i: usize) -> Ray {
        let (x, y) = self.at(i);
        self.rays.ray_at(x, y)
    }

    #[inline(always)]
    fn pack(&self, start: usize, n: usize, quads: &mut [Ray4], active: &mut [M4]) -> usize {
        let per = (self.side * self.side) as usize;
        if start.is_multiple_of(per) && n == per {
            // The batch's packets are whole tiles: generated, not gathered.
            let (x0, y0) = self.tile(start / per);
            return self
                .rays
                .packet(x0, y0, self.side, &self.rect, quads, active);
        }
        let nq = crate::trace::pack_quads(n, |k| self.ray(start + k), quads, active);
        for (k, act) in active[..nq].iter_mut().enumerate() {
            let lanes: [bool; 4] = core::array::from_fn(|l| {
                let i = start + 4 * k + l;
                act.test(l) && self.pixel(i).is_some()
            });
            *act = M4::new(lanes[0], lanes[1], lanes[2], lanes[3]);
        }
        nq
    }
}

/// `v` scaled to length 1, its largest component made 1 first so that
/// no square overflows or underflows; `None` for a zero vector.
fn unit(v: Vec3) -> Option<Vec3> {
    let m = v.abs().max_element();
    (m > 0.0).then(|| (v / m).normalize())
}

/// Quad (x, y) of Morton index `i` (bits interleaved, x in the even bits).
#[inline]
pub fn demorton(i: usize) -> (u32, u32) {
    // Every other bit gathered by halving shifts (i < 1024: five steps
    // would cover 32 bits, four cover the ten bits a 32x32 packet uses).
    debug_assert!(i < 1024);
    let compact = |v: u32| {
        let v = v & 0x5555_5555;
        let v = (v | (v >> 1)) & 0x3333_3333;
        let v = (v | (v >> 2)) & 0x0f0f_0f0f;
        (v | (v >> 4)) & 0x00ff_00ff
    };
    (compact(i as u32), compact((i >> 1) as u32))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::trace::Method;

    fn camera() -> PrimaryRays {
        let cam = Camera {
            eye: [0.3, -1.7, 2.9],
            look_at: [0.1, 0.4, -0.2],
            up: [0.0, 1.0, 0.1],
            fov_y_deg: 53.0,
        };
        PrimaryRays::new(&cam, 1023, 517).unwrap()
    }

    fn bits(r: &Ray) -> [u32; 8] {
        let f = [r.org, r.dir].concat();
        core::array::from_fn(|k| match k {
            6 => r.tmin.to_bits(),
            7 => r.tmax.to_bits(),
            _ => f[k].to_bits(),
        })
    }

    #[test]
    fn quads_are_the_pixel_rays_bit_for_bit() {
        let pr = camera();
        for (x, y) in [(0, 0), (510, 257), (1021, 515), (1022, 516), (77, 3)] {
            let q = pr.quad(x.into(), y.into());
            for (l, (dx, dy)) in [(0, 0), (1, 0), (0, 1), (1, 1)].into_iter().enumerate() {
                assert_eq!(
                    bits(&q.lane(l)),
                    bits(&pr.ray(x + dx, y + dy)),
                    "({x}, {y}) lane {l}"
                );
            }
        }
    }

    /// Every pixel of `rect` is one active lane's, at its index in a
    /// buffer of rows `row` apart (below `results(row)`), with its pixel's
    /// ray bit for bit; every other lane is inactive and has no index.
    fn covers_once(pr: &PrimaryRays, rect: PixelRect, row: usize) {
        let (w, h) = rect.size();
        let need = rect.results(row).unwrap();
        for side in [2, 4, 8, 16, 32] {
            let p = TraceParams {
                method: Method::BvhFrustum,
                packet: side,
                ..TraceParams::default()
            };
            let cr = CameraRays::new(pr, rect, Some(&p)).unwrap();
            let n = cr.count();
            assert_eq!(n % (side * side) as usize, 0);
            let mut seen = vec![0u8; (w * h) as usize];
            let (mut index, mut quads_at) = (cr.index(row), cr.index(row));
            let nq = (side * side / 4) as usize;
            let mut quads = [Ray4::from_rays(&[pr.ray(0, 0); 4]); 256];
            let mut active = [M4::FALSE; 256];
            for start in (0..n).step_by(nq * 4) {
                assert_eq!(cr.pack(start, nq * 4, &mut quads, &mut active), nq);
                for k in 0..nq * 4 {
                    let (q, l) = (k / 4, k % 4);
                    let px = cr.pixel(start + k);
                    assert_eq!(active[q].test(l), px.is_some());
                    let at = px.map(|(x, y)| y as usize * row + x as usize);
                    assert_eq!(index.of(start + k), at);
                    assert_eq!(quads_at.quad(start + 4 * q)[l], at);
                    assert!(at.is_none_or(|a| a < need), "side {side}: {at:?} >= {need}");
                    // Every lane holds a finite ray, outside ones too.
                    assert!(Vec3::from(quads[q].lane(l).dir).is_finite());
                    if let Some((x, y)) = px {
                        seen[(y * w + x) as usize] += 1;
                        let r = pr.ray(rect.x0 + x, rect.y0 + y);
                        assert_eq!(bits(&quads[q].lane(l)), bits(&r));
                        assert_eq!(bits(&cr.ray(start + k)), bits(&r));
                    }
                }
            }
            assert!(seen.iter().all(|&c| c == 1), "{rect:?} side {side}");
        }
    }

    #[test]
    fn camera_rays_cover_the_rectangle_once() {
        let rect = PixelRect {
            x0: 5,
            y0: 9,
            x1: 5 + 37,
            y1: 9 + 21,
        };
        covers_once(&camera(), rect, 40);
    }

    /// Rectangles ending at `u32::MAX`, where a packet overhanging the
    /// rectangle has pixels past the u32 range: no lane wraps onto a
    /// pixel inside, every index stays in the buffer, at every side.
    #[test]
    fn camera_rays_at_the_u32_edge() {
        let cam = Camera {
            eye: [0.0, 0.0, 3.0],
            look_at: [0.0, 0.0, 0.0],
            up: [0.0, 1.0, 0.0],
            fov_y_deg: 40.0,
        };
        let m = u32::MAX;
        for (w, h, rect) in [
            (
                m,
                2,
                PixelRect {
                    x0: m - 5,
                    y0: 0,
                    x1: m,
                    y1: 2,
                },
            ),
            (
                2,
                m,
                PixelRect {
                    x0: 0,
                    y0: m - 3,
                    x1: 2,
                    y1: m,
                },
            ),
            (
                m,
                m,
                PixelRect {
                    x0: m - 7,
                    y0: m - 9,
                    x1: m,
                    y1: m,
                },
            ),
            (
                m,
                m,
                PixelRect {
                    x0: m - 1,
                    y0: m - 1,
                    x1: m,
                    y1: m,
                },
            ),
            (
                m,
                3,
                PixelRect {
                    x0: 0,
                    y0: 0,
                    x1: 3,
                    y1: 3,
                },
            ),
        ] {
            let pr = PrimaryRays::new(&cam, w, h).unwrap();
            let (rw, _) = rect.size();
            covers_once(&pr, rect, rw as usize);
            covers_once(&pr, rect, rw as usize + 3);
        }
    }

    /// A rectangle of more than 2^32 tiles: tile numbers past u32.
    #[test]
    fn tiles_past_u32_are_numbered_in_usize() {
        let pr = PrimaryRays::new(
            &Camera {
                eye: [0.0, 0.0, 3.0],
                look_at: [0.0, 0.0, 0.0],
                up: [0.0, 1.0, 0.0],
                fov_y_deg: 40.0,
            },
            1 << 18,
            1 << 18,
        )
        .unwrap();
        let rect = PixelRect::image(1 << 18, 1 << 18);
        let cr = CameraRays::new(&pr, rect, None).unwrap();
        // Tile (2^17 - 1, 2^16 + 5) is number 2^33 + ...; ray 0 of it.
        let tile = (((1usize << 16) + 5) << 17) + (1 << 17) - 1;
        assert!(tile > u32::MAX as usize);
        assert_eq!(cr.pixel(4 * tile), Some(((1 << 18) - 2, (1 << 17) + 10)));
    }

    #[test]
    fn demorton_gathers_every_other_bit() {
        for i in 0..1024 {
            let (mut x, mut y) = (0u32, 0u32);
            for b in 0..5 {
                x |= (((i >> (2 * b)) & 1) as u32) << b;
                y |= (((i >> (2 * b + 1)) & 1) as u32) << b;
            }
            assert_eq!(demorton(i), (x, y), "{i}");
        }
    }

    /// Any finite camera whose basis is not degenerate after normalisation
    /// gives its proper rays: the same as the camera at unit scale,
    /// whatever the length of `up` or the eye's distance; only a zero or
    /// parallel `up` and `eye == look_at` are refused.
    #[test]
    fn cameras_are_normalised_whatever_their_scale() {
        let base = Camera {
            eye: [0.0, -4.0, 0.0],
            look_at: [0.0, 0.0, 0.0],
            up: [0.0, 0.0, 1.0],
            fov_y_deg: 50.0,
        };
        let want = PrimaryRays::new(&base, 64, 48).unwrap();
        let dir = |pr: &PrimaryRays, x, y| Vec3::from(pr.ray(x, y).dir).normalize();
        let scaled = [
            Camera {
                up: [0.0, 0.0, 1e20],
                ..base
            },
            Camera {
                up: [0.0, 0.0, 1e-30],
                ..base
            },
            Camera {
                up: [0.0, 0.0, 1e-44],
                ..base
            },
            Camera {
                up: [0.0, 0.0, f32::MAX],
                ..base
            },
            Camera {
                eye: [0.0, -3e19, 0.0],
                ..base
            },
            Camera {
                eye: [0.0, -f32::MAX, 0.0],
                look_at: [0.0, f32::MAX, 0.0],
                ..base
            },
            Camera {
                eye: [0.0, -1e-38, 0.0],
                ..base
            },
        ];
        for cam in scaled {
            let pr = PrimaryRays::new(&cam, 64, 48).unwrap_or_else(|e| panic!("{cam:?}: {e}"));
            for (x, y) in [(0, 0), (63, 0), (0, 47), (63, 47), (31, 20)] {
                let (a, b) = (dir(&pr, x, y), dir(&want, x, y));
                assert!(
                    (a - b).length() < 1e-5,
                    "{cam:?} ({x}, {y}): {a} against {b}"
                );
            }
            // Distinct pixels, distinct rays (the bug: one ray for all).
            assert_ne!(dir(&pr, 0, 0), dir(&pr, 63, 47), "{cam:?}");
        }
        let degenerate = [
            Camera {
                up: [0.0, 0.0, 0.0],
                ..base
            },
            Camera {
                up: [0.0, 3e-30, 0.0],
                ..base
            },
            Camera {
                up: [0.0, -7e25, 0.0],
                ..base
            },
            Camera {
                look_at: base.eye,
                ..base
            },
            Camera {
                up: [0.0, 0.0, f32::INFINITY],
                ..base
            },
            Camera {
                eye: [f32::NAN, 0.0, 0.0],
                ..base
            },
        ];
        for cam in degenerate {
            assert!(PrimaryRays::new(&cam, 64, 48).is_err(), "{cam:?}");
        }
        // `up` the view direction as f32 arithmetic gives it: parallel
        // to rounding, refused.
        let (eye, at) = ([0.3f32, -1.7, 2.9], [0.1f32, 0.4, -0.2]);
        let up = [at[0] - eye[0], at[1] - eye[1], at[2] - eye[2]];
        let cam = Camera {
            eye,
            look_at: at,
            up,
            fov_y_deg: 50.0,
        };
        assert!(PrimaryRays::new(&cam, 64, 48).is_err());
    }

    #[test]
    fn bad_rectangles_are_refused() {
        let pr = camera();
        let bad = [
            PixelRect {
                x0: 0,
                y0: 0,
                x1: 0,
                y1: 4,
            },
            PixelRect {
                x0: 3,
                y0: 0,
                x1: 2,
                y1: 4,
            },
            PixelRect {
                x0: 0,
                y0: 0,
                x1: 1024,
                y1: 4,
            },
            PixelRect {
                x0: 0,
                y0: 500,
                x1: 4,
                y1: 518,
            },
        ];
        for r in bad {
            assert!(CameraRays::new(&pr, r, None).is_err(), "{r:?}");
        }
        assert!(CameraRays::new(&pr, PixelRect::image(1023, 517), None).is_ok());
    }
}
