//! Tests of the layered decoder against exact answers: the linear
//! discretisation, brute-force path enumeration, the RTS smoother.

use super::*;
use crate::belief::Gaussian;
use crate::filter::rts::rts_1d;
use crate::model::linear::{ou_1d, LinearSde};
use crate::model::Bounds;
use crate::rng::stream;
use nalgebra::DMatrix;
use rand::RngExt;
use rand_distr::StandardNormal;

#[test]
fn moment_propagation_matches_exact_linear_discretisation() {
    let a = DMatrix::from_row_slice(2, 2, &[-1.0, 0.5, -0.3, -2.0]);
    let f = DMatrix::from_row_slice(2, 2, &[0.2, 0.0, 0.05, 0.1]);
    let model = LinearSde::new(
        "lin2",
        a,
        DMatrix::zeros(2, 0),
        f,
        DMatrix::identity(2, 2),
        vec![0.1, 0.1],
        Bounds::new_box(&[-2.0, -2.0], &[2.0, 2.0]).unwrap(),
    );
    let x = [0.7, -0.4];
    for tau in [0.02, 0.3] {
        let (mut m, mut p) = ([0.0; 2], [0.0; 4]);
        propagate_gaussian(&model, &x, tau, 16, &mut m, &mut p);
        let disc = model.discretize(tau);
        for i in 0..2 {
            let want = disc.ad[(i, 0)] * x[0] + disc.ad[(i, 1)] * x[1];
            assert!((m[i] - want).abs() < 1e-8, "mean {i}: {} vs {want}", m[i]);
            for j in 0..2 {
                let q = disc.qd[(i, j)];
                assert!(
                    (p[i + 2 * j] - q).abs() < 1e-6 * q.abs().max(1e-4),
                    "cov {} vs {q}",
                    p[i + 2 * j]
                );
            }
        }
    }
}

/// Root + three layers of four 1-D states with unequal steps: the
/// decoder's path and score equal the best of all 4³ paths scored from
/// the closed-form OU transition and the trapezoid Girsanov factor.
#[test]
// Long: builds a tiny chain, enumerates every path and compares, in one
// place so the brute force visibly uses the same scores.
fn layered_viterbi_matches_brute_force_enumeration() {
    let (a, s, g) = (1.5, 0.3, 0.2);
    let model = ou_1d(a, s, 1.0, 2.0);
    let times = vec![0.0, 0.1, 0.25, 0.3];
    let pts = [
        [-0.2, 0.1, 0.35, 0.5],
        [-0.3, 0.0, 0.2, 0.4],
        [-0.1, 0.05, 0.3, 0.6],
    ];
    let vols = [
        [0.1, 0.2, 0.15, 0.3],
        [0.2, 0.1, 0.1, 0.2],
        [0.05, 0.1, 0.2, 0.1],
    ];
    let mut layers = vec![Layer::point(&[0.3])];
    for (p, v) in pts.iter().zip(&vols) {
        layers.push(Layer {
            dim: 1,
            states: p.to_vec(),
            log_vol: v.iter().map(|x: &f64| x.ln()).collect(),
        });
    }
    let path = ObsPath {
        times: vec![0.0, 0.1, 0.2, 0.3],
        y: vec![0.0, 0.04, 0.05, 0.09],
        m: 1,
    };
    let y = |t: f64| {
        let mut o = [0.0];
        path.at(t, &mut o);
        o[0]
    };
    for normalise in [false, true] {
        let cfg = LayeredConfig {
            c_near: 0.1,
            min_near: 4, // Near = the whole next layer
            substeps: 8,
            normalise,
        };
        let chain =
            LayeredChain::build(&model, times.clone(), layers.clone(), vec![0, 1, 2, 3], cfg)
                .unwrap();
        let dec = decode_layered(&model, &chain, &[g], &path, None).unwrap();
        let ln_n = |x1: f64, x0: f64, tau: f64| {
            let mu = (-a * tau).exp() * x0;
            let var = s * s * (1.0 - (-2.0 * a * tau).exp()) / (2.0 * a);
            -0.5 * (x1 - mu).powi(2) / var - 0.5 * (2.0 * std::f64::consts::PI * var).ln()
        };
        let (mut best, mut arg) = (f64::NEG_INFINITY, vec![]);
        for code in 0..64usize {
            let idx = [0, code % 4, (code / 4) % 4, code / 16];
            let mut w = 0.0;
            let mut prev = 0.3;
            for k in 1..4 {
                let tau = times[k] - times[k - 1];
                let x = pts[k - 1][idx[k]];
                w += ln_n(x, prev, tau);
                if normalise {
                    let z: f64 = (0..4)
                        .map(|j| ln_n(pts[k - 1][j], prev, tau).exp() * vols[k - 1][j])
                        .sum();
                    w -= z.ln();
                }
                let dy = y(times[k]) - y(times[k - 1]);
                w += (0.5 * (prev + x) * dy - tau / 6.0 * (prev * prev + prev * x + x * x))
                    / (g * g);
                prev = x;
            }
            if w > best {
                best = w;
                arg = idx.iter().map(|&v| v as u32).collect();
            }
        }
        assert_eq!(dec.slots, arg, "normalise={normalise}");
        assert!(
            (dec.log_score - best).abs() < 1e-6,
            "{} vs {best}",
            dec.log_score
        );
        assert_eq!(dec.states[3], pts[2][arg[3] as usize]);
    }
}

#[test]
fn around_layer_volumes_integrate_the_set_and_the_belief() {
    let bounds = Bounds::new_box(&[-1.0, -1.0], &[1.0, 1.0]).unwrap();
    let b = Gaussian::diagonal(&[0.2, -0.1], &[0.05, 0.08]);
    let mut rng = stream(7, 1);
    let n = 20_000;
    let l = Layer::around(&b, 2.0, 0.1, &bounds, n, &mut rng).unwrap();
    // Σ v = importance-sampling estimate of μ(S) = 4
    let vol: f64 = l.log_vol.iter().map(|v| v.exp()).sum();
    assert!((vol - 4.0).abs() < 0.2, "Σ v = {vol}");
    // Σ v N(x; m, P) estimates ∫ N = 1
    let ig: f64 = (0..n)
        .map(|i| {
            let x = l.state(i);
            let q = ((x[0] - 0.2) / 0.05).powi(2) + ((x[1] + 0.1) / 0.08).powi(2);
            l.log_vol[i].exp() * (-0.5 * q).exp() / (2.0 * std::f64::consts::PI * 0.05 * 0.08)
        })
        .sum();
    assert!((ig - 1.0).abs() < 0.05, "∫N ≈ {ig}");
}

/// Seeded OU runs: the decoded path's mean squared distance to the
/// exact MAP path (fine-grid RTS mean) at the layer times falls with n
/// and ends well below the posterior variance (the floor's own scale).
#[test]
fn layered_decoder_converges_to_the_exact_map_path() {
    let (a, sig, gam, x0) = (1.0, 0.1, 0.1, 0.3);
    let h = 1e-3;
    let steps = 1000;
    let model = ou_1d(a, sig, 1.0, 1.0);
    let bounds = Bounds::new_box(&[-1.0], &[1.0]).unwrap();
    let times: Vec<f64> = (0..=10).map(|k| k as f64 * 0.1).collect();
    let cfg = LayeredConfig {
        normalise: false,
        ..LayeredConfig::default()
    };
    let sizes = [20usize, 100, 1000];
    let chains: Vec<LayeredChain> = sizes
        .iter()
        .map(|&n| {
            let mut rng = stream(11, n as u64);
            let set = Layer::uniform(&bounds, n, &mut rng);
            let mut of = vec![1; times.len()];
            of[0] = 0;
            LayeredChain::build(
                &model,
                times.clone(),
                vec![Layer::point(&[x0]), set],
                of,
                cfg,
            )
            .unwrap()
        })
        .collect();
    let mut dist = [0.0; 3];
    let mut post_var = 0.0;
    let runs = 12;
    for r in 0..runs {
        let mut rng = stream(12, r);
        let (mut x, mut y) = (x0, 0.0);
        let (mut ts, mut ys, mut obs) = (vec![0.0], vec![0.0], vec![]);
        for k in 1..=steps {
            let dy = x * h + gam * h.sqrt() * rng.sample::<f64, _>(StandardNormal);
            x += -a * x * h + sig * h.sqrt() * rng.sample::<f64, _>(StandardNormal);
            y += dy;
            obs.push(dy / h);
            ts.push(k as f64 * h);
            ys.push(y);
        }
        let rts = rts_1d(a, sig, gam, x0, 0.0, h, &obs);
        let path = ObsPath {
            times: ts,
            y: ys,
            m: 1,
        };
        for (i, c) in chains.iter().enumerate() {
            let dec = decode_layered(&model, c, &[gam], &path, None).unwrap();
            for (k, &t) in times.iter().enumerate().skip(1) {
                let j = (t / h).round() as usize;
                dist[i] += (dec.states[k] - rts.smooth_m[j]).powi(2) / (10.0 * runs as f64);
            }
        }
        post_var += rts.smooth_p.iter().sum::<f64>() / (rts.smooth_p.len() as f64 * runs as f64);
    }
    eprintln!("distance to the exact MAP {dist:?}, posterior variance {post_var}");
    assert!(
        dist[1] < dist[0] && dist[2] < dist[1],
        "not decreasing: {dist:?}"
    );
    assert!(
        dist[2] < 0.02 * post_var,
        "{dist:?} vs posterior variance {post_var}"
    );
}
