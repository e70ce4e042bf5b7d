use beliefbus::chain::*;
use beliefbus::model::ship::{Ship, ShipParams};
use beliefbus::model::SdeModel;
use std::time::Instant;
fn main() {
    let m = Ship::new(ShipParams::paper(0.01)).unwrap();
    let kind = std::env::args().nth(1).unwrap_or("gauss".into());
    let cfg = if kind == "gauss" {
        ChainConfig::gaussian(4)
    } else {
        ChainConfig::moment_matched(4)
    };
    let mut rng = beliefbus::rng::stream(1, 0);
    let n = 30_000;
    let pts = Sampler::Uniform.sample_many(m.bounds(), n + 3000, &mut rng);
    let t = Instant::now();
    let mut c = Chain::batch(&m, cfg.clone(), &pts[..n * 4]).unwrap();
    println!("batch {:.0}/s", n as f64 / t.elapsed().as_secs_f64());
    let mut rec = vec![];
    let t = Instant::now();
    for i in n..n + 3000 {
        c.add_state(&m, &pts[i * 4..i * 4 + 4], &mut rec).unwrap();
    }
    println!(
        "incremental {:.0}/s deg {:.1}",
        3000.0 / t.elapsed().as_secs_f64(),
        c.mean_out_degree()
    );
}
