//! `sheaf bench --stress`: stability where methods fail (issue 7, part 2).
//!
//! The adversarial scenes and rays, their tests and the packet fallbacks are
//! still being written (branch `wip/stress-fallback`); until they land this
//! command says so instead of printing a partial report.

use crate::{BenchArgs, Failure};

/// `sheaf bench --stress`.
pub fn run(_a: &BenchArgs) -> Result<(), Failure> {
    Err(Failure(
        "sheaf bench --stress is not on main yet: the stability study is in progress (see README, Limits)".into(),
    ))
}
