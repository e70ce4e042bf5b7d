use beliefbus::chain::*;
use beliefbus::filter::chain_filter::ChainFilter;
use beliefbus::filter::BayesFilter;
use beliefbus::model::ship::{Ship, ShipParams};
use beliefbus::model::Measurement;
use beliefbus::model::SdeModel;
fn cpu() -> f64 {
    let mut ts = libc::timespec {
        tv_sec: 0,
        tv_nsec: 0,
    };
    unsafe {
        libc::clock_gettime(libc::CLOCK_THREAD_CPUTIME_ID, &mut ts);
    }
    ts.tv_sec as f64 + ts.tv_nsec as f64 * 1e-9
}
fn main() {
    let m = Ship::new(ShipParams::paper(0.01)).unwrap();
    let kind = std::env::args().nth(1).unwrap_or("gauss".into());
    let cfg = if kind == "gauss" {
        ChainConfig::gaussian(4)
    } else {
        ChainConfig::moment_matched(4)
    };
    let mut rng = beliefbus::rng::stream(1, 0);
    let n = 10_000;
    let pts = Sampler::Uniform.sample_many(m.bounds(), n, &mut rng);
    let c = Chain::batch(&m, cfg.clone(), &pts).unwrap();
    let mut f = ChainFilter::new(m.clone(), c, 0.01).unwrap();
    let y = [5.0, 0.3];
    let steps = 2000;
    let (mut tp, mut tu) = (0.0, 0.0);
    for k in 1..=steps {
        let t0 = cpu();
        f.predict(k as f64 * 0.01, &[0.0, 0.0]).unwrap();
        let t1 = cpu();
        let _ = f.update(&Measurement::full(&y));
        tu += cpu() - t1;
        tp += t1 - t0;
    }
    println!("support {}", support(f.weights()));
    println!(
        "predict {:.1} us update {:.1} us nnz {}",
        tp / steps as f64 * 1e6,
        tu / steps as f64 * 1e6,
        f.chain().nnz()
    );
}
#[allow(dead_code)]
fn support(w: &[f64]) -> usize {
    w.iter().filter(|v| **v > 0.0).count()
}
