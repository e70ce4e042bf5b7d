use beliefbus::chain::*;
use beliefbus::model::linear::LinearSde;
use beliefbus::model::{Bounds, SdeModel};
use nalgebra::DMatrix;
fn main() {
    let args: Vec<String> = std::env::args().collect();
    let s: f64 = args.get(1).map(|v| v.parse().unwrap()).unwrap_or(0.03);
    let m = LinearSde::new(
        "ou2",
        DMatrix::from_row_slice(2, 2, &[-0.5, 0.0, 0.0, -1.0]),
        DMatrix::zeros(2, 0),
        DMatrix::from_row_slice(2, 2, &[s, 0.0, 0.0, s]),
        DMatrix::identity(2, 2),
        vec![0.1, 0.1],
        Bounds::new_box(&[-1.0, -1.0], &[1.0, 1.0]).unwrap(),
    );
    for kind in ["gauss", "lp"] {
        for n in [1000usize, 4000, 16000, 64000] {
            let cfg = if kind == "gauss" {
                ChainConfig::gaussian(2)
            } else {
                ChainConfig::moment_matched(2)
            };
            let mut rng = beliefbus::rng::stream(1, n as u64);
            let t = std::time::Instant::now();
            let c = Chain::sample_batch(&m, cfg, &Sampler::Uniform, n, &mut rng).unwrap();
            let el = t.elapsed().as_secs_f64();
            let r = diagnostics::report(&c, m.bounds(), 1.0);
            println!("{kind} n={n} t={el:.3}s deg={:.1} rel_drift={:.3} rel_cov={:.3} med_drift={:.3e} med_cov={:.3e} h={:.3e} r={:.3e} stats={:?}", r.mean_out_degree, r.rel_drift_err, r.rel_cov_err, r.median_drift_err, r.median_cov_err, r.mean_holding, r.mean_radius, c.stats());
        }
    }
}
