//! The on-line policy table: at most `capacity` of the solver's α-vectors,
//! chosen at the beliefs the controller meets.
//!
//! The solver keeps every non-dominated vector (pruning its lower bound
//! by its own sampled beliefs loses plans, solver docs), so its set grows
//! into the hundreds while the controller, on the chain filter's beliefs,
//! only ever uses a few dozen of them. Here the closed loop — the run's
//! plant, the `chain-pomdp` filter, and the table being built — is
//! simulated off line over seeded episodes; the table is the set of
//! vectors that attain max_α α·b at the visited beliefs B,
//!
//! ```text
//! Γ_B = { argmax_{α∈Γ} α·b : b ∈ B }      (ties: the first vector)
//! ```
//!
//! so at every b ∈ B the table picks the same vector as the full set — the
//! same action and the same value, bit for bit. When Γ_B exceeds the
//! capacity the most used vectors are kept and the loss
//! max_{b∈B} (V_Γ(b) − V_table(b)) is reported. Elsewhere both value
//! functions are max-of-linear with slopes bounded by L = max |α(z)|, so
//! at any belief b the loss is at most loss(b′) + 2 L ‖b − b′‖₁ for the
//! nearest b′ ∈ B.
//!
//! The beliefs a table meets depend on the table, so the simulation is
//! repeated acting with the table just built (fresh seeds), adding the
//! full set's maximisers at the newly visited beliefs, until a pass meets
//! no maximiser not seen before (or after [`PASSES`]).

use super::encoding::{write_action, CONTROL, EVENT_NONE};
use super::filter::ChainBeliefFilter;
use super::flat::FlatPolicy;
use super::plant::LightDarkPlant;
use super::LightDarkSystem;
use crate::backends::FilterContext;
use crate::Plant;
use beliefbus_core::belief::Gaussian;
use beliefbus_core::filter::BayesFilter;
use beliefbus_core::model::Measurement;

/// Simulation passes at most (the first acts with the full set).
pub const PASSES: u64 = 4;

/// What the bounded table was built from, and its loss there.
#[derive(Clone, Debug, PartialEq)]
pub struct PruneReport {
    /// Vectors in the full (dominance-filtered) set.
    pub full: usize,
    /// Distinct maximisers at the sampled beliefs (> table size when the
    /// capacity bound dropped some).
    pub maximisers: usize,
    /// Sampled beliefs.
    pub beliefs: usize,
    /// max over the sampled beliefs of V_full(b) − V_table(b) (0 unless
    /// the capacity dropped a maximiser).
    pub loss: f64,
    /// L = max |α(z)| over the full set (the bound's slope).
    pub slope: f64,
    /// Simulation passes made.
    pub passes: u64,
}

/// The chain distributions the closed loop visits over `episodes`
/// episodes, acting with `table`; row-major, n per belief.
pub fn sample_beliefs(
    sys: &LightDarkSystem,
    table: &FlatPolicy,
    episodes: u64,
    seed: u64,
) -> Vec<f64> {
    let n = table.n;
    let mut plant = LightDarkPlant::new(sys, seed, 0.005);
    let ctx = FilterContext {
        seed,
        sample_dt: sys.pomdp.period,
        start: Gaussian::zeros(super::encoding::STATE),
        resumed: false,
        t0: 0.0,
    };
    let mut filter = ChainBeliefFilter::new(sys, &ctx);
    let mut out = Vec::new();
    let (mut y, mut u) = ([0.0; 3], [0.0; CONTROL]);
    let mut done = 0;
    // The first step starts the first episode (no event).
    while done < episodes {
        plant.step();
        if plant.state()[2] != EVENT_NONE {
            done += 1;
        }
        plant.measure(&mut y);
        // A filter error keeps the prediction, as the live stage does.
        let _ = filter.update(&Measurement::full(&y));
        let b = filter.chain_belief();
        out.extend_from_slice(&b[..n]);
        write_action(&sys.pomdp, table.act(b), &mut u);
        plant.set_control(&u);
    }
    out
}

/// The table of at most `capacity` vectors of `full` that attain the
/// maximum at `beliefs` (row-major, `full.n` per belief): the most used
/// first, then in `full`'s order. Returns the table, the number of
/// distinct maximisers and the loss at `beliefs`.
pub fn select(full: &FlatPolicy, beliefs: &[f64], capacity: usize) -> (FlatPolicy, usize, f64) {
    let best: Vec<(usize, f64)> = beliefs.chunks_exact(full.n).map(|b| full.best(b)).collect();
    select_with(full, beliefs, &best, capacity)
}

/// [`select`] with the full set's maximiser and value at each belief.
fn select_with(
    full: &FlatPolicy,
    beliefs: &[f64],
    best: &[(usize, f64)],
    capacity: usize,
) -> (FlatPolicy, usize, f64) {
    let mut hits = vec![0u64; full.len()];
    for &(k, _) in best {
        hits[k] += 1;
    }
    let mut used: Vec<usize> = (0..full.len()).filter(|&k| hits[k] > 0).collect();
    let maximisers = used.len();
    // Most hits first (stable: ties keep full's order), then back in
    // full's order so ties at a belief resolve as in the full set.
    used.sort_by_key(|&k| std::cmp::Reverse(hits[k]));
    used.truncate(capacity.max(1));
    used.sort_unstable();
    let table = full.subset(&used);
    let loss = beliefs
        .chunks_exact(full.n)
        .zip(best)
        .map(|(b, &(_, v))| v - table.best(b).1)
        .fold(0.0, f64::max);
    (table, maximisers, loss)
}

/// The bounded table for `full` (module doc): `episodes` simulated
/// episodes per pass from `seed`.
pub fn bounded_table(
    sys: &LightDarkSystem,
    full: &FlatPolicy,
    capacity: usize,
    episodes: u64,
    seed: u64,
) -> (FlatPolicy, PruneReport) {
    let n = full.n;
    let mut beliefs = sample_beliefs(sys, full, episodes, seed);
    let mut best: Vec<(usize, f64)> = beliefs.chunks_exact(n).map(|b| full.best(b)).collect();
    let mut seen = vec![false; full.len()];
    best.iter().for_each(|&(k, _)| seen[k] = true);
    let (mut table, mut maximisers, mut loss) = select_with(full, &beliefs, &best, capacity);
    let mut passes = 1;
    while passes < PASSES {
        let more = sample_beliefs(sys, &table, episodes, seed.wrapping_add(passes));
        passes += 1;
        let mut new = false;
        for b in more.chunks_exact(n) {
            let kv = full.best(b);
            new |= !seen[kv.0];
            seen[kv.0] = true;
            best.push(kv);
        }
        beliefs.extend_from_slice(&more);
        (table, maximisers, loss) = select_with(full, &beliefs, &best, capacity);
        // Acting with this table meets no maximiser the last one missed.
        if !new {
            break;
        }
    }
    let slope = full.alphas.iter().fold(0.0, |m: f64, a| m.max(a.abs()));
    let report = PruneReport {
        full: full.len(),
        maximisers,
        beliefs: beliefs.len() / n.max(1),
        loss,
        slope,
        passes,
    };
    (table, report)
}
