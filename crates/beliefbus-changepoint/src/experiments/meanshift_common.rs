//! Shared pieces of the mean-shift experiments (Tables 1–3): the seeded
//! data of run i, one filter pass scored by SSE = Σ_t (μ̂_t − μ_t)², and the
//! paper's numbers.
//!
//! Like for like: every filter setting of run i sees the same sequence
//! (stream `DATA` of the seed) and the same filter random numbers (stream
//! `FILTER`), so differences between settings are not data noise.

use crate::error::ChangepointError;
use crate::meanshift::exact::ExactMeanShift;
use crate::meanshift::rbpf::{MeanShiftRbpf, RbpfConfig};
use crate::meanshift::MeanShiftModel;
use crate::rng::{self, SimRng};
use std::time::Instant;

/// Stream tags (distinct consumers of one seed).
pub const DATA: u64 = 0xDA7A;
pub const FILTER: u64 = 0xF117;
pub const RHO_DRAW: u64 = 0xB37A;

/// The generator of consumer `tag` for run `i`.
pub fn run_rng(seed: u64, tag: u64, i: usize) -> SimRng {
    rng::stream(seed ^ rng::splitmix64(tag), i as u64)
}

/// Outcome of one filter over one sequence.
#[derive(Clone, Copy, Debug, Default)]
pub struct Pass {
    pub sse: f64,
    pub resamplings: u64,
    /// Wall time of the filter pass in its worker thread (seconds).
    pub secs: f64,
}

/// Run the RBPF over `y` and score it against the true levels `mu`.
pub fn rbpf_pass(
    model: MeanShiftModel,
    cfg: RbpfConfig,
    y: &[f64],
    mu: &[f64],
    rng: SimRng,
) -> Result<Pass, ChangepointError> {
    let mut f = MeanShiftRbpf::new(model, cfg, rng)?;
    let t0 = Instant::now();
    let mut sse = 0.0;
    for (&yt, &mt) in y.iter().zip(mu) {
        let e = f.step(yt)? - mt;
        sse += e * e;
    }
    Ok(Pass {
        sse,
        resamplings: f.resamplings(),
        secs: t0.elapsed().as_secs_f64(),
    })
}

/// The exact filter's SSE, dropping segments whose posterior probability
/// falls below e^(−prune).
pub fn exact_pass(
    model: MeanShiftModel,
    prune: f64,
    y: &[f64],
    mu: &[f64],
) -> Result<Pass, ChangepointError> {
    let mut f = ExactMeanShift::with_pruning(model, -prune)?;
    let t0 = Instant::now();
    let mut sse = 0.0;
    for (&yt, &mt) in y.iter().zip(mu) {
        let e = f.step(yt)? - mt;
        sse += e * e;
    }
    Ok(Pass {
        sse,
        resamplings: 0,
        secs: t0.elapsed().as_secs_f64(),
    })
}

/// Simulate run i's sequence.
pub fn simulate(model: MeanShiftModel, n: usize, seed: u64, i: usize) -> (Vec<f64>, Vec<f64>) {
    let (mut mu, mut y) = (Vec::with_capacity(n), Vec::with_capacity(n));
    model.simulate(n, &mut run_rng(seed, DATA, i), &mut mu, &mut y);
    (mu, y)
}

/// The cv² bounds of Tables 1 and 3.
pub const BOUNDS: [f64; 9] = [0.0, 0.5, 1.0, 2.0, 4.0, 10.0, 20.0, 30.0, f64::INFINITY];

/// Table 1: resampling #, SSE, s.e. per bound (verbatim).
pub const TABLE1: [(f64, f64, f64); 9] = [
    (9999.0, 240.38, 9.65),
    (85.0, 205.24, 6.53),
    (51.0, 188.06, 6.73),
    (32.0, 193.24, 6.31),
    (22.0, 196.19, 6.53),
    (14.0, 206.01, 6.69),
    (10.0, 217.51, 8.27),
    (8.0, 208.75, 7.28),
    (0.0, 603.94, 28.11),
];

/// Table 2: ρ̃/ρ, SSE, s.e. (verbatim, cv² bound 1).
pub const TABLE2: [(f64, f64, f64); 10] = [
    (1.0, 188.06, 6.73),
    (2.0, 169.12, 5.39),
    (4.0, 159.58, 5.30),
    (5.0, 150.82, 4.63),
    (6.0, 152.07, 4.37),
    (7.0, 151.50, 4.61),
    (10.0, 158.80, 4.60),
    (15.0, 159.84, 5.07),
    (50.0, 169.86, 5.15),
    (100.0, 185.42, 5.00),
];

/// Table 3: resampling #, SSE(ρ), Bayes SSE, resampling #B (verbatim).
pub const TABLE3: [(f64, f64, f64, f64); 9] = [
    (9999.0, 288.52, 240.52, 9999.0),
    (100.0, 200.82, 174.73, 80.0),
    (50.0, 201.92, 158.16, 50.0),
    (35.0, 200.55, 153.56, 30.0),
    (30.0, 205.57, 184.35, 20.0),
    (15.0, 206.72, 188.47, 15.0),
    (12.0, 207.43, 190.20, 10.0),
    (9.0, 215.75, 186.31, 7.0),
    (0.0, 478.93, 501.01, 0.0),
];

/// The paper's row for a bound of Table 1/3, if it has one.
pub fn bound_index(b: f64) -> Option<usize> {
    BOUNDS.iter().position(|&x| x == b)
}
