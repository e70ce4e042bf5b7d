//! `decoding` — MAP trajectory decoding, paper 001 §VII-D (Fig. 6) and
//! thesis §3.6.2 (Fig. 3-8): the 2-D linear system dx_i = −a x_i dt + σ dw_i,
//! dy_i = x_i dt + γ dv_i, σ = γ = 0.1, T = 2 s; total squared error
//! ∫₀^T ‖x − x̂‖² dt at 1,000 and 20,000 states and its convergence over n.
//!
//! Paper 001 (a = 1): 11.34e-3 at 1,000 states, 3.3e-3 at 20,000; thesis
//! (a = 3): 4.9e-3 at 20,000. Unstated and chosen here: x(0) = (0.5, −0.5)
//! known to the decoders, S = [−1, 1]², 20 trajectories by default (100 in
//! the thesis's curve: `--runs 100`). Methods:
//! - `decoder`: Alg. 3.2 on the time-augmented chain over [0, T] × S
//!   (σ_t = 0.01, moment-matching kernel, k = ⌈1.5 log n⌉ in 3-D, half the
//!   samples on {T} × S as Remark 3.9 prescribes, root (0, x₀)), with the
//!   Girsanov edge likelihood on the continuous observation path;
//! - `viterbi`: Viterbi on the time-equalised 2-D chain M_n^δ (paper 001's
//!   form) with observations sampled every Δ = 0.02 s (y_k = Δy/Δ,
//!   σ = γ/√Δ);
//! - `viterbi_advected`: the same on the advected chain (Δt = δ = Δ, no
//!   self-loops from equalisation). Measured (20 runs): on M_n^δ the error
//!   grows as δ shrinks with n (0.089 at δ = 0.01, 0.27 at 0.0025); a
//!   likely cause is the self-loop probability 1 − δ/Δt(z) → 1, which makes
//!   the most probable *discrete* path stay put (every jump costs
//!   log(δ/Δt)). The advected chain is 2–3× better up to 5,000 states but
//!   also degrades at 20,000, so that is not the whole story (open);
//! - `exact_map`: for this linear-Gaussian system the MAP trajectory of the
//!   sampled observations is the Rauch–Tung–Striebel smoother mean (exact
//!   discretisation) — the floor the decoders converge to.
//!
//! x̂ is the linear interpolation of the decoded points; the integral is a
//! Riemann sum on the 1 ms simulation grid. Chains are built once per n.

use anyhow::Result;
use nalgebra::{DMatrix, DVector};
use rand_distr::StandardNormal;

use super::chain_util::{mean_se, Params};
use super::{ExperimentArgs, ExperimentReport, Progress, Row};
use crate::chain::{Chain, ChainConfig, NearRule, Sampler, TimeEqualized};
use crate::filter::decoder::{decode_time_augmented, viterbi, Decoded, ObsPath, TimeAugmented};
use crate::model::linear::LinearSde;
use crate::model::Bounds;
use crate::rng::stream;
use rand::RngExt;

pub fn run(args: &ExperimentArgs) -> Result<ExperimentReport> {
    let mut rep = ExperimentReport::new("decoding");
    let mut p = Params::new(args);
    let runs = args.runs.unwrap_or(20);
    rep.param("runs", runs);
    rep.param("seed", args.seed);
    let a = p.f64(&mut rep, "a", 1.0)?;
    let sigma = p.f64(&mut rep, "sigma", 0.1)?;
    let gamma = p.f64(&mut rep, "gamma", 0.1)?;
    let t_end = p.f64(&mut rep, "horizon_s", 2.0)?;
    let dt_obs = p.f64(&mut rep, "obs_period_s", 0.02)?;
    let sizes = p.list(&mut rep, "states", &[1000, 2000, 5000, 10000, 20000])?;
    let sigma_t = p.f64(&mut rep, "sigma_t", 0.01)?;
    let boundary_fraction = p.f64(&mut rep, "boundary_fraction", 0.5)?;
    p.finish()?;
    rep.param("x0", "(0.5, -0.5)");
    let x0 = [0.5, -0.5];
    let dt_sim = 1e-3;
    let steps_sim = (t_end / dt_sim).round() as usize;
    let k_obs = (t_end / dt_obs).round() as usize;
    let stride = (dt_obs / dt_sim).round() as usize;
    let model = LinearSde::new(
        "decode2",
        DMatrix::from_diagonal_element(2, 2, -a),
        DMatrix::zeros(2, 0),
        DMatrix::from_diagonal_element(2, 2, sigma),
        DMatrix::identity(2, 2),
        vec![gamma / dt_obs.sqrt(); 2],
        Bounds::new_box(&[-1.0, -1.0], &[1.0, 1.0])?,
    );
    // chains, once per size
    let mut aug_chains = vec![];
    let mut mn_chains = vec![];
    let mut adv_chains = vec![];
    for &n in &sizes {
        let mut rng = stream(args.seed, 500 + n as u64);
        let aug = TimeAugmented::new(&model, sigma_t, t_end).map_err(anyhow::Error::msg)?;
        let mut pts = vec![0.0, x0[0], x0[1]];
        let mut z = [0.0; 3];
        for _ in 0..n {
            Sampler::Uniform.sample(crate::model::SdeModel::bounds(&aug), &mut rng, &mut z);
            if rng.random::<f64>() < boundary_fraction {
                // on {T} × S, jittered by < 1e-9 T (see decode_time_augmented)
                z[0] = t_end * (1.0 - 1e-9 * rng.random::<f64>());
            }
            pts.extend_from_slice(&z);
        }
        let mut cfg = ChainConfig::moment_matched(3);
        cfg.near = NearRule::Knn { c: 1.5 };
        let mut c = Chain::batch(&aug, cfg, &pts)?;
        c.compact();
        aug_chains.push(c);
        let mut cfg2 = ChainConfig::moment_matched(2);
        cfg2.near = NearRule::Knn { c: 1.5 };
        let mut c2 = Chain::sample_batch(&model, cfg2, &Sampler::Uniform, n, &mut rng)?;
        let mut eq = TimeEqualized::new(dt_obs)?;
        eq.fit(c2.holding());
        c2.compact();
        mn_chains.push((c2, eq.delta()));
        // the advected chain (Δt = δ = the observation period): no lazy
        // self-loops from equalisation (see the module doc)
        let mut cfg3 = ChainConfig::moment_matched(2);
        cfg3.near = NearRule::Knn { c: 1.5 };
        cfg3.step = Some(dt_obs);
        let mut c3 = Chain::sample_batch(&model, cfg3, &Sampler::Uniform, n, &mut rng)?;
        let mut eq3 = TimeEqualized::new(dt_obs)?;
        eq3.fit(c3.holding());
        c3.compact();
        adv_chains.push((c3, eq3.delta()));
    }
    let disc = model.discretize(dt_obs);
    let mut err_aug = vec![vec![]; sizes.len()];
    let mut err_mn = vec![vec![]; sizes.len()];
    let mut err_adv = vec![vec![]; sizes.len()];
    let mut err_exact = vec![];
    let mut bar = Progress::new("decoding", runs, args.progress);
    for r in 0..runs {
        let mut rng = stream(args.seed, r as u64);
        // truth and continuous observation path on the fine grid
        let mut x = x0;
        let mut y = [0.0, 0.0];
        let mut truth = vec![x0[0], x0[1]];
        let mut times = vec![0.0];
        let mut ypath = vec![0.0, 0.0];
        for k in 1..=steps_sim {
            for i in 0..2 {
                let xi = x[i];
                x[i] +=
                    -a * xi * dt_sim + sigma * dt_sim.sqrt() * rng.sample::<f64, _>(StandardNormal);
                y[i] += xi * dt_sim + gamma * dt_sim.sqrt() * rng.sample::<f64, _>(StandardNormal);
            }
            truth.extend_from_slice(&x);
            times.push(k as f64 * dt_sim);
            ypath.extend_from_slice(&y);
        }
        let path = ObsPath {
            times: times.clone(),
            y: ypath.clone(),
            m: 2,
        };
        // sampled observations y_k = Δy/Δ
        let mut obs_t = vec![];
        let mut ys = vec![];
        for k in 1..=k_obs {
            let (i1, i0) = (k * stride, (k - 1) * stride);
            obs_t.push(k as f64 * dt_obs);
            for c in 0..2 {
                ys.push((ypath[i1 * 2 + c] - ypath[i0 * 2 + c]) / dt_obs);
            }
        }
        let sq_err = |dec: &Decoded| {
            let mut xh = [0.0; 2];
            let mut s = 0.0;
            for k in 0..=steps_sim {
                dec.at(times[k], &mut xh);
                s += ((truth[2 * k] - xh[0]).powi(2) + (truth[2 * k + 1] - xh[1]).powi(2)) * dt_sim;
            }
            s
        };
        for i in 0..sizes.len() {
            let v = aug_chains[i].compact_view().expect("compact");
            let dec = decode_time_augmented(&model, &v, 0, t_end, &[gamma, gamma], &path)?;
            err_aug[i].push(sq_err(&dec));
            for (chains, errs) in [(&mn_chains, &mut err_mn), (&adv_chains, &mut err_adv)] {
                let (c2, delta) = &chains[i];
                let v2 = c2.compact_view().expect("compact");
                let mut near = vec![];
                c2.nearest(&x0, 1, &mut near);
                let mut prior = vec![0.0; c2.len()];
                prior[near[0].0 as usize] = 1.0;
                let dec2 = viterbi(&model, &v2, *delta, &prior, 0.0, &obs_t, &ys)?;
                errs[i].push(sq_err(&dec2));
            }
        }
        // exact: Kalman + RTS on the sampled observations
        let rts = rts_smoother(&disc, &x0, &ys, gamma / dt_obs.sqrt());
        let dec = Decoded {
            slots: vec![],
            times: (0..=k_obs).map(|k| k as f64 * dt_obs).collect(),
            states: rts,
            log_score: 0.0,
        };
        err_exact.push(sq_err(&dec));
        bar.tick();
    }
    // Paper 001's figures are single trajectories (Fig. 6 a, b): the
    // comparable range is the spread of one run's error, not the mean's.
    let q = |v: &[f64], p: f64| {
        let mut w = v.to_vec();
        w.sort_by(f64::total_cmp);
        w[((w.len() - 1) as f64 * p).round() as usize]
    };
    let (m, se) = mean_se(&err_exact);
    rep.results.push(
        Row::new("exact_map")
            .num("sq_error", m)
            .num("stderr", se)
            .num("p10", q(&err_exact, 0.1))
            .num("p90", q(&err_exact, 0.9)),
    );
    for (i, &n) in sizes.iter().enumerate() {
        let (m, se) = mean_se(&err_aug[i]);
        rep.results.push(
            Row::new("decoder")
                .int("n_states", n as u64)
                .num("sq_error", m)
                .num("stderr", se)
                .num("p10", q(&err_aug[i], 0.1))
                .num("p90", q(&err_aug[i], 0.9))
                .num("out_degree", aug_chains[i].mean_out_degree()),
        );
    }
    for (name, chains, errs) in [
        ("viterbi", &mn_chains, &err_mn),
        ("viterbi_advected", &adv_chains, &err_adv),
    ] {
        for (i, &n) in sizes.iter().enumerate() {
            let (m, se) = mean_se(&errs[i]);
            rep.results.push(
                Row::new(name)
                    .int("n_states", n as u64)
                    .num("sq_error", m)
                    .num("stderr", se)
                    .num("p10", q(&errs[i], 0.1))
                    .num("p90", q(&errs[i], 0.9))
                    .num("delta_s", chains[i].1),
            );
        }
    }
    let fit = |errs: &[Vec<f64>]| {
        let xs: Vec<f64> = sizes.iter().map(|&n| (n as f64).ln()).collect();
        let ys: Vec<f64> = errs.iter().map(|e| mean_se(e).0.ln()).collect();
        slope(&xs, &ys)
    };
    rep.notes.push(
        "paper 001's 11.34e-3 and 3.3e-3 are the errors of single trajectories (Fig. 6 a, b), \
         so compare them with one run's spread (p10..p90), and both with exact_map, the \
         linear-Gaussian floor no decoder beats on average"
            .into(),
    );
    rep.notes.push(format!(
        "log-log slope of sq_error vs n: decoder {:.3}, viterbi {:.3}, viterbi_advected {:.3}",
        fit(&err_aug),
        fit(&err_mn),
        fit(&err_adv)
    ));
    rep.paper.push(
        Row::new("decoder")
            .int("n_states", 1000)
            .num("sq_error", 11.34e-3)
            .text("source", "paper 001, a=1"),
    );
    rep.paper.push(
        Row::new("decoder")
            .int("n_states", 20000)
            .num("sq_error", 3.3e-3)
            .text("source", "paper 001, a=1"),
    );
    rep.paper.push(
        Row::new("decoder")
            .int("n_states", 20000)
            .num("sq_error", 4.9e-3)
            .text("source", "thesis, a=3"),
    );
    Ok(rep)
}

/// Least-squares slope of y on x.
pub fn slope(x: &[f64], y: &[f64]) -> f64 {
    let n = x.len() as f64;
    let mx = x.iter().sum::<f64>() / n;
    let my = y.iter().sum::<f64>() / n;
    let sxy: f64 = x.iter().zip(y).map(|(a, b)| (a - mx) * (b - my)).sum();
    let sxx: f64 = x.iter().map(|a| (a - mx).powi(2)).sum();
    sxy / sxx
}

/// Kalman filter + RTS smoother (C = I, R = r² I, known x₀) on the sampled
/// observations; returns the smoothed means at t₀..t_K, flat.
fn rts_smoother(
    disc: &crate::model::linear::Discretized,
    x0: &[f64],
    ys: &[f64],
    r: f64,
) -> Vec<f64> {
    let k = ys.len() / 2;
    let (ad, qd) = (&disc.ad, &disc.qd);
    let rr = DMatrix::from_diagonal_element(2, 2, r * r);
    let mut mf = vec![DVector::from_column_slice(x0)];
    let mut pf = vec![DMatrix::zeros(2, 2)];
    let mut mp = vec![DVector::zeros(2)];
    let mut pp = vec![DMatrix::zeros(2, 2)];
    for j in 0..k {
        let m = ad * &mf[j];
        let p = ad * &pf[j] * ad.transpose() + qd;
        let s = &p + &rr;
        let kg = &p * s.try_inverse().expect("S positive definite");
        let y = DVector::from_column_slice(&ys[2 * j..2 * j + 2]);
        let m2 = &m + &kg * (y - &m);
        let p2 = (DMatrix::identity(2, 2) - &kg) * &p;
        mp.push(m);
        pp.push(p);
        mf.push(m2);
        pf.push(p2);
    }
    let mut ms = mf.clone();
    for j in (0..k).rev() {
        let pinv = pp[j + 1]
            .clone()
            .try_inverse()
            .unwrap_or_else(|| DMatrix::zeros(2, 2));
        let g = &pf[j] * ad.transpose() * pinv;
        ms[j] = &mf[j] + &g * (&ms[j + 1] - &mp[j + 1]);
    }
    ms.iter()
        .flat_map(|m| m.iter().copied().collect::<Vec<_>>())
        .collect()
}
