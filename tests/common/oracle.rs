//! The f64 oracle's comparison under named tolerances, each counted:
//! - `TIE_REL`: the oracle's two nearest hits are within this relative t of
//!   each other (either triangle is a right answer in f32);
//! - `EDGE_BARY`: the oracle's hit, or a triangle in front of it, is within
//!   this barycentric distance of an edge (an f32 test may decide either way);
//! - `T_REL`: on agreement, the f32 t must be within this relative distance
//!   of the f64 t, plus `POS_EPS` times the ray's t scale (a hit at the
//!   origin has a t of rounding size).

// Each test binary names the tolerances it reports (not every one uses all).
#[allow(unused_imports)]
pub use sheaf::reference::{EDGE_BARY, T_REL, TIE_REL};
use sheaf::reference::{RefHit, Verdict, judge};
use sheaf::{Hit, Ray, Scene};

#[derive(Default, Debug)]
pub struct Tally {
    pub rays: u64,
    pub exact: u64,
    pub ties: u64,
    pub edges: u64,
    pub errors: Vec<String>,
}

/// `got` against the oracle's `want` for ray `i`, counted in `t` (an
/// error when no named tolerance explains a disagreement).
pub fn classify_hit(
    scene: &Scene,
    i: usize,
    ray: &Ray,
    got: &Hit,
    want: &RefHit,
    t: &mut Tally,
    what: &str,
) {
    t.rays += 1;
    match judge(scene, ray, got.prim, got.t, *want) {
        Verdict::Exact => t.exact += 1,
        Verdict::Tie => t.ties += 1,
        Verdict::Edge => t.edges += 1,
        Verdict::WrongT(want) => t.errors.push(format!(
            "{what} ray {i} {ray:?}: same triangle {} but t {} vs f64 {} (rel {:e})",
            got.prim,
            got.t,
            want.t,
            (got.t as f64 - want.t).abs() / want.t.abs().max(1e-30)
        )),
        Verdict::Wrong(want) => t.errors.push(format!(
            "{what} ray {i} {ray:?}: got prim {} t {} / f64 prim {} t {} (gap {:e}, edge {:e})",
            got.prim, got.t, want.prim, want.t, want.gap, want.edge
        )),
    }
}
