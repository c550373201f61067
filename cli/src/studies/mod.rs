//! `sheaf bench`: the paper studies, one file each, measuring sheaf against
//! the papers it implements on the same scenes and rays.
//!
//! - `cgt`: speed against accuracy of every method (the CGT paper's grid
//!   and its 3DDDA, the BVH's and the kd-tree's), the f64 oracle, a chart;
//! - `bvh_whitted`: the large-packet BVH paper's Whitted study (`--whitted`);
//! - `kd_entry`: the AEPSA paper's entry-point study (`--entry`);
//! - `pgrid`: the perspective/light grid paper's section 5 (`--pgrid`);
//! - `stress`: where methods fail, adversarial scenes and rays (`--stress`).
//!
//! `common` holds what they share. The Embree comparison is a C program
//! (benches/embree); its input comes from `sheaf export` (`cmd::export`).
//! Where Embree 3 is installed, `embree` traces the speed-vs-accuracy
//! study's rays with it too, as reference points on its chart.

mod bvh_whitted;
mod cgt;
pub mod common;
#[cfg(embree)]
mod embree;
mod kd_entry;
mod pgrid;
mod stress;

use crate::BenchArgs;
use anyhow::Result;

/// `sheaf bench`: the study its flags name, else speed vs accuracy.
pub fn bench(a: &BenchArgs) -> Result<()> {
    if a.whitted {
        bvh_whitted::run(a)
    } else if a.entry {
        kd_entry::run(a)
    } else if a.pgrid {
        pgrid::run(a)
    } else if a.stress {
        stress::run(a)
    } else {
        cgt::run(a)
    }
}
