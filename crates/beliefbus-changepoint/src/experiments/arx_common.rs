//! Shared pieces of the ARX experiments: the ranges of (17) and the seeded
//! open-loop data of run i.

use super::meanshift_common::{run_rng, DATA};
use crate::arx::linalg::Vector;
use crate::arx::plant::{ArxPlant, ThetaRegion};
use crate::arx::ThetaPrior;
use crate::error::ChangepointError;
use rand_distr::{Distribution, StandardNormal};

/// (n′, n″) of (17).
pub const RANGES: [(usize, usize); 4] = [(1, 500), (501, 1000), (1001, 2000), (2001, 3000)];

/// Open-loop data of run i: y_t, φ_t, θ_t for t = 1..n (u_t i.i.d.
/// N(0, 1)) and t₀.
pub type OpenLoop = (Vec<f64>, Vec<Vector<3>>, Vec<Vector<3>>, usize);

/// Simulate run i with k = 2, h = 1.
pub fn simulate_open_loop(
    n: usize,
    rho: f64,
    prior: ThetaPrior<3>,
    region: ThetaRegion,
    seed: u64,
    i: usize,
) -> Result<OpenLoop, ChangepointError> {
    let mut r = run_rng(seed, DATA, i);
    let mut plant = ArxPlant::<3>::new(2, rho, prior, region, &mut r)?;
    let (mut ys, mut phis, mut thetas) = (
        Vec::with_capacity(n),
        Vec::with_capacity(n),
        Vec::with_capacity(n),
    );
    for _ in 0..n {
        let (y, phi, th, _) = plant.observe(&mut r);
        let u: f64 = StandardNormal.sample(&mut r);
        plant.apply(y, u);
        ys.push(y);
        phis.push(phi);
        thetas.push(th);
    }
    Ok((ys, phis, thetas, plant.t0() as usize))
}
