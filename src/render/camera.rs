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
    pub fn new(cam: &Camera, width: u32, height: u32) -> Result<Self> {
        let eye = Vec3::from(cam.eye);
        let fwd = Vec3::from(cam.look_at) - eye;
        let up = Vec3::from(cam.up);
        // Stated as what is valid, so that NaN fails.
        let valid = eye.is_finite()
            && fwd.is_finite()
            && up.is_finite()
            && fwd.length_squared() > 0.0
            && cam.fov_y_deg > 0.0
            && cam.fov_y_deg < 180.0
            && width > 0
            && height > 0;
        if !valid {
            return Err(Error::InvalidArgument(
                "camera: finite eye/look_at/up, eye != look_at, fov in (0, 180), a non-empty image",
            ));
        }
        let w = fwd.normalize();
        let u = w.cross(up);
        let u2 = u.length_squared();
        if u2.is_nan() || u2 <= 0.0 {
            return Err(Error::InvalidArgument(
                "camera: up must not be parallel to the view direction",
            ));
        }
        let u = u.normalize();
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
    #[inline(always)]
    pub fn quad(&self, x: u32, y: u32) -> Ray4 {
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
    /// The renderers' and `CameraRays`' one packet generator.
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
        let inside = x0 + side <= rect.x1 && y0 + side <= rect.y1;
        for (q, (quad, act)) in quads[..nq].iter_mut().zip(&mut active[..nq]).enumerate() {
            let (qx, qy) = demorton(q);
            let (x, y) = (x0 + 2 * qx, y0 + 2 * qy);
            *quad = self.quad(x, y);
            *act = if inside {
                M4::TRUE
            } else {
                let (cx, cy) = (x + 1 < rect.x1, y + 1 < rect.y1);
                let (ax, ay) = (x < rect.x1, y < rect.y1);
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
        Ok(CameraRays {
            rays,
            rect,
            side,
            tiles_x: rw.div_ceil(side),
            tiles_y: rh.div_ceil(side),
        })
    }

    /// Rays in all: whole tiles, so a multiple of the packet's rays.
    pub fn count(&self) -> usize {
        self.tiles_x as usize * self.tiles_y as usize * (self.side * self.side) as usize
    }

    /// Top-left pixel of tile `k`.
    #[inline(always)]
    fn tile(&self, k: usize) -> (u32, u32) {
        let (tx, ty) = (k as u32 % self.tiles_x, k as u32 / self.tiles_x);
        (self.rect.x0 + tx * self.side, self.rect.y0 + ty * self.side)
    }

    /// Pixel of ray `j` of a tile whose top-left pixel is (x0, y0).
    #[inline(always)]
    fn in_tile(&self, (x0, y0): (u32, u32), j: usize) -> (u32, u32) {
        let (qx, qy) = demorton(j >> 2);
        let l = (j & 3) as u32;
        (x0 + 2 * qx + (l & 1), y0 + 2 * qy + (l >> 1))
    }

    /// Pixel of ray `i` (any `i < count`; may lie outside the rectangle).
    #[inline(always)]
    fn at(&self, i: usize) -> (u32, u32) {
        let per = (self.side * self.side) as usize;
        self.in_tile(self.tile(i / per), i % per)
    }

    /// The pixel ray `i` is shot through, relative to the rectangle's
    /// corner; `None` for the lanes of part-empty tiles outside it.
    #[inline(always)]
    pub fn pixel(&self, i: usize) -> Option<(u32, u32)> {
        let (x, y) = self.at(i);
        (x < self.rect.x1 && y < self.rect.y1).then(|| (x - self.rect.x0, y - self.rect.y0))
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
    fn at(&mut self, i: usize) -> (u32, u32) {
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
        let r = &self.rays.rect;
        (x < r.x1 && y < r.y1).then(|| (y - r.y0) as usize * self.row + (x - r.x0) as usize)
    }

    /// Buffer indices of the four rays `i .. i + 4` of a quad (`i` a multiple of
    /// 4), in `Ray4` lane order: pixels (x, y), (x+1, y), (x, y+1),
    /// (x+1, y+1), two pairs side by side in the buffer.
    #[inline(always)]
    pub fn quad(&mut self, i: usize) -> [Option<usize>; 4] {
        let (x, y) = self.at(i);
        let r = &self.rays.rect;
        let (ax, bx, ay, by) = (x < r.x1, x + 1 < r.x1, y < r.y1, y + 1 < r.y1);
        // Only formed for pixels inside, whose index is in the buffer.
        let at = |inside: bool, dx: u32, dy: u32| {
            inside.then(|| (y + dy - r.y0) as usize * self.row + (x + dx - r.x0) as usize)
        };
        [
            at(ax && ay, 0, 0),
            at(bx && ay, 1, 0),
            at(ax && by, 0, 1),
            at(bx && by, 1, 1),
        ]
    }
}

impl RaySource for CameraRays<'_> {
    #[inline(always)]
    fn ray(&self, i: usize) -> Ray {
        let (x, y) = self.at(i);
        self.rays.ray(x, y)
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
            let q = pr.quad(x, y);
            for (l, (dx, dy)) in [(0, 0), (1, 0), (0, 1), (1, 1)].into_iter().enumerate() {
                assert_eq!(
                    bits(&q.lane(l)),
                    bits(&pr.ray(x + dx, y + dy)),
                    "({x}, {y}) lane {l}"
                );
            }
        }
    }

    #[test]
    fn camera_rays_cover_the_rectangle_once() {
        let pr = camera();
        let rect = PixelRect {
            x0: 5,
            y0: 9,
            x1: 5 + 37,
            y1: 9 + 21,
        };
        for side in [2, 4, 8, 16, 32] {
            let p = TraceParams {
                method: Method::BvhFrustum,
                packet: side,
                ..TraceParams::default()
            };
            let cr = CameraRays::new(&pr, rect, Some(&p)).unwrap();
            let n = cr.count();
            assert_eq!(n % (side * side) as usize, 0);
            let mut seen = [[0u8; 37]; 21];
            let (mut index, mut quads_at) = (cr.index(40), cr.index(40));
            let nq = (side * side / 4) as usize;
            let mut quads = [Ray4::from_rays(&[pr.ray(0, 0); 4]); 256];
            let mut active = [M4::FALSE; 256];
            for start in (0..n).step_by(nq * 4) {
                assert_eq!(cr.pack(start, nq * 4, &mut quads, &mut active), nq);
                for k in 0..nq * 4 {
                    let (q, l) = (k / 4, k % 4);
                    let px = cr.pixel(start + k);
                    assert_eq!(active[q].test(l), px.is_some());
                    let at = px.map(|(x, y)| y as usize * 40 + x as usize);
                    assert_eq!(index.of(start + k), at);
                    assert_eq!(quads_at.quad(start + 4 * q)[l], at);
                    if let Some((x, y)) = px {
                        seen[y as usize][x as usize] += 1;
                        let r = pr.ray(rect.x0 + x, rect.y0 + y);
                        assert_eq!(bits(&quads[q].lane(l)), bits(&r));
                        assert_eq!(bits(&cr.ray(start + k)), bits(&r));
                    }
                }
            }
            assert!(seen.iter().flatten().all(|&c| c == 1), "side {side}");
        }
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
