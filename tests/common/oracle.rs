//! The f64 oracle's comparison under named tolerances, each counted:
//! - `TIE_REL`: the oracle's two nearest hits are within this relative t of
//!   each other (either triangle is a right answer in f32);
//! - `EDGE_BARY`: the oracle's hit, or a triangle in front of it, is within
//!   this barycentric distance of an edge (an f32 test may decide either way);
//! - `T_REL`: on agreement, the f32 t must be within this relative distance
//!   of the f64 t.

use sheaf::geom::INVALID_ID;
use sheaf::reference::{self, RefHit};
use sheaf::{Hit, Ray, Scene};

pub const TIE_REL: f64 = 1e-5;
pub const EDGE_BARY: f64 = 1e-5;
pub const T_REL: f64 = 1e-4;

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
    let mut want = *want;
    if got.prim != want.prim
        || (got.prim != INVALID_ID && (got.t as f64 - want.t).abs() > T_REL * want.t.abs())
    {
        want = reference::with_edge_distance(scene, ray, want);
    }
    if got.prim == want.prim {
        if got.prim != INVALID_ID {
            let rel = (got.t as f64 - want.t).abs() / want.t.abs().max(1e-30);
            if rel > T_REL && want.edge > EDGE_BARY {
                t.errors.push(format!(
                    "{what} ray {i} {ray:?}: same triangle {} but t {} vs f64 {} (rel {rel:e})",
                    got.prim, got.t, want.t
                ));
                return;
            }
        }
        t.exact += 1;
    } else if want.gap <= TIE_REL {
        t.ties += 1;
    } else if want.edge <= EDGE_BARY {
        t.edges += 1;
    } else {
        t.errors.push(format!(
            "{what} ray {i} {ray:?}: got prim {} t {} / f64 prim {} t {} (gap {:e}, edge {:e})",
            got.prim, got.t, want.prim, want.t, want.gap, want.edge
        ));
    }
}
