//! How the light-dark episode sits in the pipeline's fixed-size vectors.
//!
//! ```text
//! state   (x, r, e)        x position; r the reward of the period that ended at this
//!                          sample (−u²h for a move, ±R for a declaration, 0 otherwise);
//!                          e the episode event at this sample (EVENT_*)
//! obs     (y, v, n)        y = x + G(x) v; v the velocity the plant applied in the period
//!                          that ended here; n = 1 on an episode's first sample
//! control (v, d, k, t)     v velocity; d = 1 declares (the terminal action); k the policy
//!                          version it was computed with (0: the file, +1 per swap); t the
//!                          policy lookup's time in ns (the plant reads v and d only)
//! belief  dim 3            the Gaussian summary (E x, Var x; r and e nominal) in the first
//!                          9 covariance slots, then the chain filter's distribution:
//!                          cov[9] = n, cov[10..10+n] = P(z_i), i < n
//! ```
//!
//! A 3-dimensional belief leaves 55 of the message's 64 covariance slots
//! unused; the chain filter's distribution over the policy's states rides
//! there, so the `pomdp` controller acts on exactly the distribution the
//! filter computed (not on a Gaussian fitted to it). Every other reader —
//! the report, the monitor, a restart — reads the 3 × 3 block only. Hence
//! at most [`MAX_CHAIN`] chain states on the live path.

use beliefbus_core::belief::Gaussian;
use beliefbus_core::MAX_STATE;
use beliefbus_pomdp::chain_pomdp::ChainPomdp;

pub const STATE: usize = 3;
pub const OBS: usize = 3;
pub const CONTROL: usize = 4;

/// Control components.
pub const U_VELOCITY: usize = 0;
pub const U_DECLARE: usize = 1;
pub const U_VERSION: usize = 2;
pub const U_LOOKUP_NS: usize = 3;

/// Episode events (state component 2).
pub const EVENT_NONE: f64 = 0.0;
/// Declared inside the goal.
pub const EVENT_GOAL: f64 = 1.0;
/// Declared outside the goal.
pub const EVENT_MISS: f64 = -1.0;
/// Reset after `max_steps` moves without a declaration.
pub const EVENT_TIMEOUT: f64 = -2.0;

/// Where the count of chain probabilities sits in `cov`.
const COUNT: usize = STATE * STATE;
/// The chain states the message can carry.
pub const MAX_CHAIN: usize = MAX_STATE * MAX_STATE - COUNT - 1;

/// Write the chain distribution `p` (at most [`MAX_CHAIN`] entries) after
/// the Gaussian block.
pub fn write_chain(g: &mut Gaussian, p: &[f64]) {
    let n = p.len().min(MAX_CHAIN);
    g.cov[COUNT] = n as f64;
    g.cov[COUNT + 1..COUNT + 1 + n].copy_from_slice(&p[..n]);
}

/// The chain distribution a `chain-pomdp` belief carries (`None`: the
/// belief has none, or a malformed count).
pub fn read_chain(g: &Gaussian) -> Option<&[f64]> {
    if g.dim != STATE {
        return None;
    }
    let n = g.cov[COUNT];
    if !(n >= 1.0 && n <= MAX_CHAIN as f64 && n.fract() == 0.0) {
        return None;
    }
    Some(&g.cov[COUNT + 1..COUNT + 1 + n as usize])
}

/// The control for action `a`: (velocity, 0), or (0, 1) for the terminal
/// action.
#[inline]
pub fn write_action(cp: &ChainPomdp, a: usize, u: &mut [f64]) {
    match cp.control(a) {
        Some(c) => {
            u[U_VELOCITY] = c[0];
            u[U_DECLARE] = 0.0;
        }
        None => {
            u[U_VELOCITY] = 0.0;
            u[U_DECLARE] = 1.0;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_chain_distribution_round_trips_beside_the_gaussian_block() {
        let mut g = Gaussian::zeros(STATE);
        g.set_cov(0, 0, 0.25);
        g.set_cov(2, 2, 1e-6);
        let p: Vec<f64> = (0..20).map(|i| i as f64 / 190.0).collect();
        write_chain(&mut g, &p);
        assert_eq!(read_chain(&g), Some(&p[..]));
        // The Gaussian block is untouched.
        assert_eq!(g.cov_at(0, 0), 0.25);
        assert_eq!(g.cov_at(2, 2), 1e-6);
        // A plain Gaussian carries none.
        assert_eq!(read_chain(&Gaussian::zeros(STATE)), None);
        assert_eq!(read_chain(&Gaussian::zeros(2)), None);
    }
}
