//! Rays as a ray stream: the eight field arrays a `RayStream` borrows.

use sheaf::{Ray, RayStream};

/// The field arrays of some rays: origin x, y, z, direction x, y, z,
/// tmin, tmax.
pub struct Columns(pub [Vec<f32>; 8]);

impl Columns {
    pub fn of(rays: &[Ray]) -> Columns {
        let fields: [fn(&Ray) -> f32; 8] = [
            |r| r.org[0],
            |r| r.org[1],
            |r| r.org[2],
            |r| r.dir[0],
            |r| r.dir[1],
            |r| r.dir[2],
            |r| r.tmin,
            |r| r.tmax,
        ];
        Columns(fields.map(|f| rays.iter().map(f).collect()))
    }

    /// The rays as a stream over these arrays.
    pub fn stream(&self) -> RayStream<'_> {
        let c = &self.0;
        RayStream {
            org: [&c[0], &c[1], &c[2]],
            dir: [&c[3], &c[4], &c[5]],
            tmin: &c[6],
            tmax: &c[7],
        }
    }
}
