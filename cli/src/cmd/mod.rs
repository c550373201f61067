//! The commands `demo`, `render`, `info` and `export`, one file each, and
//! the one-line reports they share with the studies (`crate::studies`).

pub mod demo;
pub mod engine;
pub mod export;
pub mod info;
pub mod render;

use crate::GridOpts;
use crate::run::{ms, res};
use sheaf::{GridInfo, PrimaryPass, ShadowPass, TraceParams};
use std::fmt::Write as _;

pub fn v3(v: [f32; 3]) -> String {
    format!("{},{},{}", v[0], v[1], v[2])
}

pub fn mib(bytes: usize) -> f64 {
    bytes as f64 / (1024.0 * 1024.0)
}

pub fn grid_line(info: &GridInfo, g: &GridOpts) -> String {
    format!(
        "{} = {} cells (lambda {} asked, {:.2} used), {} refs ({:.2} per triangle), macrocell {}, {:?}",
        res(info),
        info.cells(),
        g.lambda,
        info.lambda,
        info.refs,
        info.refs as f64 / info.triangles.max(1) as f64,
        info.macrocell,
        info.test,
    )
}

/// The kd-tree's AEPSA Table 1 line and more: triangles, nodes, leaves,
/// % empty, average leaf depth, references per triangle, build time.
pub fn kd_line(k: &sheaf::accel::kd::KdInfo, build_ns: u64) -> String {
    let mut s = format!(
        "{} triangles, {} nodes, {} leaves ({:.2} % empty), avg leaf depth {:.2} (max {}, limit {}), {} refs ({:.2} per triangle), SAH cost {:.1}, build {:.2} ms",
        k.triangles,
        k.nodes,
        k.leaves,
        100.0 * k.empty_leaves as f64 / k.leaves.max(1) as f64,
        k.avg_leaf_depth,
        k.depth,
        k.max_depth,
        k.refs,
        k.refs as f64 / k.triangles.max(1) as f64,
        k.sah_cost,
        ms(build_ns)
    );
    if k.forced_leaves > 0 {
        let _ = write!(s, ", {} leaves forced by full pools", k.forced_leaves);
    }
    s
}

fn traced_label(p: &TraceParams) -> String {
    if p.method.is_packet() {
        format!("{} {}x{}", p.method.name(), p.packet, p.packet)
    } else {
        p.method.name().to_string()
    }
}

pub fn primary_label(p: &PrimaryPass) -> String {
    match p {
        PrimaryPass::Pgrid => "pgrid".into(),
        PrimaryPass::Traced(t) => traced_label(t),
    }
}

pub fn shadow_label(s: &ShadowPass) -> String {
    match s {
        ShadowPass::LightGrid => "light-grid".into(),
        ShadowPass::Traced(t) => traced_label(t),
    }
}

/// The Figure 10 phases of a deferred frame: (name, ns).
pub fn phases(t: &sheaf::render::deferred::PhaseTimes) -> [(&'static str, u64); 6] {
    [
        ("primary build", t.primary_build),
        ("primary traversal", t.primary_trace),
        ("data rearrangement", t.rearrange),
        ("shadow build", t.shadow_build),
        ("shadow traversal", t.shadow_trace),
        ("shade", t.shade),
    ]
}
