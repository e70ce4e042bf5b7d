use beliefbus::chain::*;
use beliefbus::filter::chain_filter::ChainFilter;
use beliefbus::filter::BayesFilter;
use beliefbus::model::ship::{Ship, ShipParams};
use beliefbus::model::Measurement;
use beliefbus::model::SdeModel;
use std::time::Instant;
fn main() {
    let m = Ship::new(ShipParams::paper(0.01)).unwrap();
    for kind in ["gauss", "lp"] {
        let cfg = if kind == "gauss" {
            ChainConfig::gaussian(4)
        } else {
            ChainConfig::moment_matched(4)
        };
        let mut rng = beliefbus::rng::stream(1, 0);
        let n = 100_000;
        let pts = Sampler::Uniform.sample_many(m.bounds(), n, &mut rng);
        let t = Instant::now();
        let c = Chain::batch(&m, cfg.clone(), &pts).unwrap();
        let el = t.elapsed().as_secs_f64();
        println!(
            "{kind} batch n={n}: {:.0} states/s deg {:.1} stats {:?}",
            n as f64 / el,
            c.mean_out_degree(),
            c.stats()
        );
        // incremental: build 1e5 incrementally, time the last 10k
        let mut c = Chain::new(&m, cfg.clone()).unwrap();
        let mut rec = vec![];
        let t = Instant::now();
        for i in 0..n {
            if i == 90_000 {
                println!("  incremental to 90k: {:.2}s", t.elapsed().as_secs_f64());
            }
            c.add_state(&m, &pts[i * 4..i * 4 + 4], &mut rec).unwrap();
        }
        let el = t.elapsed().as_secs_f64();
        println!(
            "  incremental total {el:.2}s deg {:.1}",
            c.mean_out_degree()
        );
        // filter step n=1e4
        let cf_chain = Chain::batch(&m, cfg.clone(), &pts[..40_000]).unwrap();
        let mut f = ChainFilter::new(m.clone(), cf_chain, 0.01).unwrap();
        let y = [5.0, 0.3];
        let t0 = Instant::now();
        let steps = 200;
        for k in 1..=steps {
            f.predict(k as f64 * 0.01, &[0.0, 0.0]).unwrap();
            let _ = f.update(&Measurement::full(&y));
        }
        let el = t0.elapsed().as_secs_f64();
        println!(
            "  filter step n=1e4: {:.1} us, delta {:.2e}, substeps/step {}",
            el / steps as f64 * 1e6,
            f.delta(),
            f.substeps() as f64 / steps as f64
        );
    }
}
