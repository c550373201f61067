//! Surface materials of the Whitted renderer (`render::whitted`): a diffuse
//! colour plus mirror reflectance, transmittance and index of refraction,
//! assigned to runs of triangles.
//!
//! Materials are borrowed from the caller (`Materials` holds two slices and
//! never allocates). A triangle's material is found by binary search over
//! `MaterialRange`s sorted by their first triangle.
#![forbid(unsafe_code)]

use crate::error::{Error, Result};

/// One surface material (C: `sheaf_material`).
///
/// A hit's light splits into a diffuse part `1 - reflect - transmit`, a
/// mirror-reflected part `reflect` and a refracted part `transmit` (see
/// `render::whitted` for the whole model).
#[repr(C)]
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Material {
    /// Linear RGB diffuse albedo, each component in [0, 1].
    pub diffuse: [f32; 3],
    /// Reflectance: fraction of the light arriving along the mirror
    /// direction, in [0, 1].
    pub reflect: f32,
    /// Transmittance: fraction of the light arriving through the surface
    /// along the refracted direction, in [0, 1]; `reflect + transmit <= 1`.
    pub transmit: f32,
    /// Index of refraction of the material behind the surface (the side
    /// its geometric normal points away from), relative to the medium in
    /// front; > 0. Only used when `transmit > 0`. Glass: 1.5.
    pub ior: f32,
}

impl Material {
    /// A purely diffuse material of colour `albedo`.
    pub const fn diffuse(albedo: [f32; 3]) -> Material {
        Material {
            diffuse: albedo,
            reflect: 0.0,
            transmit: 0.0,
            ior: 1.0,
        }
    }

    /// Finite values, coefficients in [0, 1], `reflect + transmit <= 1`, `ior > 0`.
    pub fn validate(&self) -> Result<()> {
        let unit = |x: f32| (0.0..=1.0).contains(&x);
        if !self.diffuse.iter().all(|&c| unit(c)) {
            return Err(Error::InvalidArgument(
                "material diffuse components must be finite and in [0, 1]",
            ));
        }
        if !unit(self.reflect) || !unit(self.transmit) {
            return Err(Error::InvalidArgument(
                "material reflect and transmit must be finite and in [0, 1]",
            ));
        }
        if self.reflect + self.transmit > 1.0 {
            return Err(Error::InvalidArgument(
                "material reflect + transmit must be <= 1",
            ));
        }
        if !(self.ior.is_finite() && self.ior > 0.0) {
            return Err(Error::InvalidArgument(
                "material ior must be finite and > 0",
            ));
        }
        Ok(())
    }
}

/// Triangles `first` up to (excluding) the next range's `first` use
/// material `material` (C: `sheaf_material_range`).
#[repr(C)]
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct MaterialRange {
    /// First triangle (index into the scene's index triples).
    pub first: u32,
    /// Index into `Materials::materials`, or `DEFAULT_MATERIAL`.
    pub material: u32,
}

/// `MaterialRange::material` of triangles that use the default diffuse
/// material (`Shading::albedo`).
pub const DEFAULT_MATERIAL: u32 = u32::MAX;

const UNIFORM: [MaterialRange; 1] = [MaterialRange {
    first: 0,
    material: 0,
}];

/// The materials of a scene, borrowed: a material table and the ranges of
/// triangles using each, sorted by `first`. Triangles before the first range
/// (all triangles when there are no ranges) use the default diffuse
/// material. `Copy`, read-only, shareable across threads.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Materials<'a> {
    pub materials: &'a [Material],
    pub ranges: &'a [MaterialRange],
}

impl<'a> Materials<'a> {
    /// No materials: every triangle is diffuse with `Shading::albedo`.
    pub const NONE: Materials<'static> = Materials {
        materials: &[],
        ranges: &[],
    };

    /// Every triangle uses `material` (tests and benches).
    pub fn uniform(material: &'a Material) -> Materials<'a> {
        Materials {
            materials: core::slice::from_ref(material),
            ranges: &UNIFORM,
        }
    }

    /// Every material valid (`Material::validate`), ranges sorted by
    /// strictly increasing `first`, every range's material an index into
    /// `materials` or `DEFAULT_MATERIAL`.
    pub fn validate(&self) -> Result<()> {
        for m in self.materials {
            m.validate()?;
        }
        for (k, r) in self.ranges.iter().enumerate() {
            if r.material != DEFAULT_MATERIAL && r.material as usize >= self.materials.len() {
                return Err(Error::InvalidArgument(
                    "material range refers to a material past the table",
                ));
            }
            if k > 0 && self.ranges[k - 1].first >= r.first {
                return Err(Error::InvalidArgument(
                    "material ranges must be sorted by strictly increasing first",
                ));
            }
        }
        Ok(())
    }

    /// The material of triangle `prim`: its range's, or diffuse `albedo`
    /// for triangles before the first range, ranges naming
    /// `DEFAULT_MATERIAL` (and, never panicking, indices past the table).
    #[inline]
    pub fn lookup(&self, prim: u32, albedo: [f32; 3]) -> Material {
        let k = self.ranges.partition_point(|r| r.first <= prim);
        if k == 0 {
            return Material::diffuse(albedo);
        }
        match self.materials.get(self.ranges[k - 1].material as usize) {
            Some(m) => *m,
            None => Material::diffuse(albedo),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const A: [f32; 3] = [0.5, 0.25, 0.125];

    #[test]
    fn lookup_by_range() {
        let mats = [
            Material {
                diffuse: [1.0, 0.0, 0.0],
                reflect: 0.5,
                transmit: 0.0,
                ior: 1.0,
            },
            Material {
                diffuse: [0.0, 1.0, 0.0],
                reflect: 0.0,
                transmit: 0.6,
                ior: 1.5,
            },
        ];
        let ranges = [
            MaterialRange {
                first: 2,
                material: 1,
            },
            MaterialRange {
                first: 5,
                material: DEFAULT_MATERIAL,
            },
            MaterialRange {
                first: 7,
                material: 0,
            },
        ];
        let m = Materials {
            materials: &mats,
            ranges: &ranges,
        };
        m.validate().unwrap();
        let got: [Material; 9] = core::array::from_fn(|i| m.lookup(i as u32, A));
        let d = Material::diffuse(A);
        assert_eq!(
            got,
            [d, d, mats[1], mats[1], mats[1], d, d, mats[0], mats[0]]
        );
        assert_eq!(m.lookup(u32::MAX, A), mats[0]);
        assert_eq!(Materials::NONE.lookup(3, A), d);
        assert_eq!(Materials::uniform(&mats[1]).lookup(12345, A), mats[1]);
    }

    #[test]
    fn validation() {
        let ok = Material {
            diffuse: [1.0, 0.5, 0.0],
            reflect: 0.4,
            transmit: 0.6,
            ior: 1.5,
        };
        assert!(ok.validate().is_ok());
        let bad = [
            Material {
                diffuse: [1.5, 0.0, 0.0],
                ..ok
            },
            Material {
                diffuse: [f32::NAN, 0.0, 0.0],
                ..ok
            },
            Material {
                reflect: -0.1,
                ..ok
            },
            Material {
                transmit: f32::INFINITY,
                ..ok
            },
            Material {
                reflect: 0.5,
                transmit: 0.6,
                ..ok
            },
            Material { ior: 0.0, ..ok },
            Material {
                ior: f32::NAN,
                ..ok
            },
        ];
        for b in bad {
            assert!(
                matches!(b.validate(), Err(Error::InvalidArgument(_))),
                "{b:?}"
            );
            assert!(Materials::uniform(&b).validate().is_err());
        }
        let mats = [ok];
        let unsorted = [
            MaterialRange {
                first: 3,
                material: 0,
            },
            MaterialRange {
                first: 3,
                material: 0,
            },
        ];
        assert!(
            Materials {
                materials: &mats,
                ranges: &unsorted
            }
            .validate()
            .is_err()
        );
        let past = [MaterialRange {
            first: 0,
            material: 1,
        }];
        assert!(
            Materials {
                materials: &mats,
                ranges: &past
            }
            .validate()
            .is_err()
        );
        let default = [MaterialRange {
            first: 0,
            material: DEFAULT_MATERIAL,
        }];
        assert!(
            Materials {
                materials: &[],
                ranges: &default
            }
            .validate()
            .is_ok()
        );
    }
}
