//! `sheaf_frame`: everything a render call needs besides the structure and
//! the pixels. `sheaf_camera`, `sheaf_light` and `sheaf_shading` are the
//! crate's `Camera`, `PointLight` and `Shading` under their C names.

use super::{check_non_null, guard_free, write_out};
use crate::render::{Camera, Frame, PointLight, Shading};

/// One frame to render: pinhole camera, one point light with hard shadows,
/// Lambert shading, image size in pixels.
#[repr(C)]
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct sheaf_frame {
    pub camera: Camera,
    pub light: PointLight,
    pub shading: Shading,
    /// Image width in pixels (> 0, at most `sheaf_limits.max_image_width`).
    pub width: u32,
    /// Image height in pixels (> 0, at most `sheaf_limits.max_image_height`).
    pub height: u32,
}

impl sheaf_frame {
    pub fn to_core(&self) -> Frame {
        Frame {
            camera: self.camera,
            light: self.light,
            shading: self.shading,
            width: self.width,
            height: self.height,
        }
    }
}

/// Write the default shading (a warm grey albedo, 12% ambient, a blue
/// background, shadows on) to `*out`.
///
/// `out` must not be NULL. Thread-safe.
#[unsafe(no_mangle)]
pub extern "C" fn sheaf_shading_default(out: *mut Shading) -> super::sheaf_status {
    guard_free(|| {
        check_non_null!(out);
        write_out(out, Shading::default());
        Ok(())
    })
}
