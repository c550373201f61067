//! The exactness suites, one test binary (`cargo test --test exact`; one
//! suite: `cargo test --test exact kd_exact::`): every packet method
//! against its single ray, bit for bit, per family (`bvh_exact`,
//! `cgt_exact`, `kd_exact`, `pgrid_exact`, `twolevel_exact`), the
//! Whitted renderer (`whitted`), the single rays against the f64 oracle
//! (`reference_equivalence`) and the scratch each family's limits declare
//! (`scratch`). One binary instead of eight: the shared harness
//! (`tests/common`) compiles and links once, and the harness runs the
//! suites' tests side by side on both cores. Some suites turn on
//! `isa::set_emulation` (process-wide): it lets forced lane widths the CPU
//! lacks run emulated, which no suite here expects to be refused.

#[path = "../common/mod.rs"]
mod common;

mod bvh_exact;
mod cgt_exact;
mod filter_exact;
mod kd_exact;
mod pgrid_exact;
mod reference_equivalence;
mod scratch;
mod twolevel_exact;
mod whitted;
