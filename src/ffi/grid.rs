//! `sheaf_grid_params` and `sheaf_tri_test`: the tunables of the uniform grid.

use super::sized::{self, versioned};
use super::{flag, raw};
use crate::GridParams;
use crate::TriTest;
use crate::error::{Error, Result};

/// Ray-triangle test used by every traversal of a structure (a build
/// parameter; the crate's `TriTest`).
#[repr(u32)]
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum sheaf_tri_test {
    /// Moller-Trumbore: fastest setup, can leak through shared edges.
    MollerTrumbore = 0,
    /// Woop-Benthin-Wald 2013 watertight test.
    Watertight = 1,
    /// Wald 2004 precomputed projection test (needs `projection_test` in
    /// `sheaf_limits`).
    Projection = 2,
}

impl sheaf_tri_test {
    /// The C code of a crate test (exhaustive).
    pub const fn of(t: TriTest) -> sheaf_tri_test {
        match t {
            TriTest::MollerTrumbore => sheaf_tri_test::MollerTrumbore,
            TriTest::Watertight => sheaf_tri_test::Watertight,
            TriTest::Projection => sheaf_tri_test::Projection,
        }
    }

    /// The crate test with C code `raw`.
    pub fn to_core(raw: raw::sheaf_tri_test) -> Result<TriTest> {
        [
            TriTest::MollerTrumbore,
            TriTest::Watertight,
            TriTest::Projection,
        ]
        .into_iter()
        .find(|&t| sheaf_tri_test::of(t) as u32 == raw)
        .ok_or(Error::InvalidArgument("unknown sheaf_tri_test"))
    }
}

/// Tunables of the uniform grid (Wald et al. 2006, "Ray Tracing Animated
/// Scenes using Coherent Grid Traversal"). Start from
/// `sheaf_grid_params_default`.
#[repr(C)]
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct sheaf_grid_params {
    /// `sizeof` the caller's struct, set by `sheaf_grid_params_default`
    /// (docs/c-api.md, "Upgrading").
    pub size: u32,
    /// Cells per triangle, lambda (section 3, Figure 6: best near 5;
    /// default 5). Must be in (0, 1024].
    pub lambda: f32,
    /// Macrocell side M in cells (section 2.4: M = 6, the default); 0 or 1
    /// disables macrocells. At most 64.
    pub macrocell: u32,
    /// Ray-triangle test of every traversal of this grid (a `sheaf_tri_test`;
    /// default Moller-Trumbore).
    pub test: raw::sheaf_tri_test,
    /// When the cells for `lambda` exceed `sheaf_limits.max_grid_cells`,
    /// lower lambda to fit instead of failing (0 or 1; default 0).
    pub fit: u32,
}

impl sheaf_grid_params {
    pub fn of(p: &GridParams) -> sheaf_grid_params {
        sheaf_grid_params {
            size: core::mem::size_of::<sheaf_grid_params>() as u32,
            lambda: p.lambda,
            macrocell: p.macrocell,
            test: sheaf_tri_test::of(p.test) as u32,
            fit: p.fit.into(),
        }
    }
    /// The crate's parameters (the enum checked; the numbers are checked by the build).
    pub fn to_core(&self) -> Result<GridParams> {
        Ok(GridParams {
            lambda: self.lambda,
            macrocell: self.macrocell,
            test: sheaf_tri_test::to_core(self.test)?,
            fit: flag(self.fit, "sheaf_grid_params.fit must be 0 or 1")?,
        })
    }
}

versioned!(
    sheaf_grid_params => GridParams,
    [lambda, macrocell, test, fit],
    sheaf_grid_params::of(&GridParams::default())
);

/// Write the default grid parameters (lambda 5, macrocells of 6, Moller-
/// Trumbore, no fit) to `*out`.
///
/// `*out` is a struct of `size` bytes (sheaf.h's macro passes `sizeof
/// *out`; see `sheaf_limits_default`).
///
/// `out` must not be NULL. Errors: `SHEAF_STATUS_INVALID_ARGUMENT` when
/// `size` is no size of this struct. Thread-safe.
#[unsafe(no_mangle)]
pub extern "C" fn sheaf_grid_params_default(
    out: *mut sheaf_grid_params,
    size: usize,
) -> super::sheaf_status {
    sized::write_defaults(out, size)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn params_round_trip() {
        let p = GridParams {
            lambda: 3.0,
            macrocell: 4,
            test: TriTest::Watertight,
            fit: true,
        };
        assert_eq!(sheaf_grid_params::of(&p).to_core(), Ok(p));
        let bad = sheaf_grid_params {
            test: 9,
            ..sheaf_grid_params::of(&p)
        };
        assert!(bad.to_core().is_err());
    }
}
