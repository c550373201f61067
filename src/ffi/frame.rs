//! `sheaf_frame`: everything a render call needs besides the structure and
//! the pixels. `sheaf_camera`, `sheaf_light` and `sheaf_shading` are the
//! crate's `Camera`, `PointLight` and `Shading` under their C names.

use super::{check_non_null, flag, guard_free, read_in, sheaf_ray, write_out};
use crate::error::{Error, Result};
use crate::{Camera, Frame, PointLight, PrimaryRays, Shading};

/// One frame to render: pinhole camera, one point light with hard shadows,
/// Lambert shading, image size in pixels.
#[repr(C)]
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct sheaf_frame {
    pub camera: Camera,
    pub light: PointLight,
    pub shading: sheaf_shading,
    /// Image width in pixels (> 0, at most `sheaf_limits.max_image_width`).
    pub width: u32,
    /// Image height in pixels (> 0, at most `sheaf_limits.max_image_height`).
    pub height: u32,
}

impl sheaf_frame {
    pub fn to_core(&self) -> Result<Frame> {
        Ok(Frame {
            camera: self.camera,
            light: self.light,
            shading: self.shading.to_core()?,
            width: self.width,
            height: self.height,
        })
    }
}

/// Lambert shading of a frame (the crate's `Shading`).
#[repr(C)]
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct sheaf_shading {
    /// Linear RGB diffuse albedo of every surface.
    pub albedo: [f32; 3],
    /// Ambient fraction lighting every visible surface.
    pub ambient: f32,
    /// Linear RGB of pixels whose primary ray misses.
    pub background: [f32; 3],
    /// 1: trace shadow rays; 0: every surface facing the light is lit.
    /// Other values: `SHEAF_STATUS_INVALID_ARGUMENT`.
    pub shadows: u8,
}

impl sheaf_shading {
    pub fn of(s: &Shading) -> sheaf_shading {
        sheaf_shading {
            albedo: s.albedo,
            ambient: s.ambient,
            background: s.background,
            shadows: s.shadows.into(),
        }
    }

    pub fn to_core(&self) -> Result<Shading> {
        Ok(Shading {
            albedo: self.albedo,
            ambient: self.ambient,
            background: self.background,
            shadows: flag(self.shadows, "sheaf_shading.shadows must be 0 or 1")?,
        })
    }
}

/// Write the default shading (a warm grey albedo, 12% ambient, a blue
/// background, shadows on) to `*out`.
///
/// `out` must not be NULL. Thread-safe.
#[unsafe(no_mangle)]
pub extern "C" fn sheaf_shading_default(out: *mut sheaf_shading) -> super::sheaf_status {
    guard_free(|| {
        check_non_null!(out);
        write_out(out, sheaf_shading::of(&Shading::default()));
        Ok(())
    })
}

/// The camera ray every render call shoots through the centre of pixel
/// (x, y) of `*frame` (x to the right, y downwards), bit for bit, written
/// to `*out`: from the eye, `tmin = 0`, `tmax = INFINITY`, the direction
/// not normalised. Tracing it with `sheaf_context_trace` gives the hit the
/// frame's pixel shows (`sheaf_context_deferred_pixel`).
///
/// Thread-safe.
///
/// Errors: `SHEAF_STATUS_NULL_POINTER`, `SHEAF_STATUS_INVALID_ARGUMENT`
/// (camera, zero width or height, pixel outside the image).
#[unsafe(no_mangle)]
pub extern "C" fn sheaf_frame_camera_ray(
    frame: *const sheaf_frame,
    x: u32,
    y: u32,
    out: *mut sheaf_ray,
) -> super::sheaf_status {
    guard_free(|| {
        let f = read_in(frame)?;
        check_non_null!(out);
        if x >= f.width || y >= f.height {
            return Err(Error::InvalidArgument("pixel outside the image"));
        }
        let r = PrimaryRays::new(&f.camera, f.width, f.height)?.ray(x, y);
        write_out(out, sheaf_ray::from(r));
        Ok(())
    })
}
