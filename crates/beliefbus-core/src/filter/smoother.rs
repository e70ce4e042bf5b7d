//! Fixed-interval smoothing on the chain (thesis §3.5, eq. 3.19–3.20):
//! forward–backward on the time-equalised chain M_n^δ.
//!
//! ```text
//! α_0 = π₀,    α_{k+1}(z) ∝ p(y_{k+1} | z) Σ_{z'} α_k(z') P^{Δ_{k+1}}(z | z')
//! β_K = 1,     β_k(z) = Σ_{z'} P^{Δ_{k+1}}(z' | z) p(y_{k+1} | z') β_{k+1}(z')
//! P(ξ(t_k) = z | Y_{t_K}) ∝ α_k(z) β_k(z)
//! ```
//!
//! P^{Δ} is ⌊Δ/δ⌋ steps of P^δ and a fraction of one (as in the filter).
//! α and β are normalised at every step (scale-free); the thesis's "uniform
//! density at T as the prior" of β is β_K = 1. This is the batch smoother
//! (one chain for every instant, the observation times t_k); the thesis's
//! incremental Alg. 3.1 (new samples with `ApproximateDensity`, new time
//! instants by `SampleTime`) is not implemented — see the issue report.

use crate::belief::Gaussian;
use crate::chain::{ChainView, PropagationKernel, TimeEqualized};
use crate::filter::chain_filter::{log_likelihoods, normalise, observation_means};
use crate::filter::FilterError;
use crate::model::{Measurement, SdeModel};
use crate::MAX_STATE;

/// Smoothed (and filtered) summaries at t₀ and at every observation time.
#[derive(Clone, Debug)]
pub struct Smoothed {
    /// t₀, t₁, …, t_K.
    pub times: Vec<f64>,
    /// Filtered beliefs α_k (mean, covariance).
    pub filtered: Vec<Gaussian>,
    /// Smoothed beliefs α_k β_k.
    pub smoothed: Vec<Gaussian>,
    /// Smoothed marginals, (K + 1) × n, when requested.
    pub marginals: Option<Vec<f64>>,
}

/// Forward–backward over the observations `(t_k, y_k)` (times increasing,
/// after `t0`), from the prior mass `prior` on the chain `view` with time
/// step `delta` (≤ every holding time). `ys` is K × m.
// One function (~130 lines): the forward pass stores every α_k that the
// backward pass multiplies in place; both passes and the marginal output
// share those buffers, and the two passes read as the thesis' recursions.
pub fn smooth<M: SdeModel>(
    model: &M,
    view: &ChainView,
    delta: f64,
    prior: &[f64],
    t0: f64,
    times: &[f64],
    ys: &[f64],
    keep_marginals: bool,
) -> Result<Smoothed, FilterError> {
    let n = view.len();
    let m = model.dims().obs;
    let k_obs = times.len();
    if prior.len() != n {
        return Err(FilterError::Dimension {
            what: "prior weights",
            got: prior.len(),
            expected: n,
        });
    }
    if ys.len() != k_obs * m {
        return Err(FilterError::Dimension {
            what: "observations",
            got: ys.len(),
            expected: k_obs * m,
        });
    }
    let eq = TimeEqualized::new(delta).map_err(|_| FilterError::NonFinite("delta"))?;
    let kern = PropagationKernel::build(view, delta, true);
    let gz = observation_means(model, view.states, view.dim);
    // forward pass, storing every α
    let mut alpha = vec![0.0; (k_obs + 1) * n];
    alpha[..n].copy_from_slice(prior);
    normalise(&mut alpha[..n]);
    let mut tmp = vec![0.0; n];
    let mut tmp2 = vec![0.0; n];
    let mut ll = vec![0.0; n];
    let mut t_prev = t0;
    for k in 0..k_obs {
        let dt = times[k] - t_prev;
        if !(dt >= 0.0) {
            return Err(FilterError::TimeBackwards {
                now: t_prev,
                asked: times[k],
            });
        }
        let (whole, frac) = eq.steps(dt);
        tmp.copy_from_slice(&alpha[k * n..(k + 1) * n]);
        for _ in 0..whole {
            kern.forward(&tmp, &mut tmp2);
            std::mem::swap(&mut tmp, &mut tmp2);
        }
        if frac > 0.0 {
            kern.forward_fraction(frac, &tmp, &mut tmp2);
            std::mem::swap(&mut tmp, &mut tmp2);
        }
        let meas = Measurement::full(&ys[k * m..(k + 1) * m]);
        let lmax = log_likelihoods(model, &gz, &meas, &mut ll);
        let out = &mut alpha[(k + 1) * n..(k + 2) * n];
        for z in 0..n {
            out[z] = tmp[z] * (ll[z] - lmax).exp();
        }
        if !normalise(out) {
            return Err(FilterError::Degenerate);
        }
        t_prev = times[k];
    }
    // backward pass
    let mut beta = vec![1.0; n];
    let mut marg = if keep_marginals {
        Some(vec![0.0; (k_obs + 1) * n])
    } else {
        None
    };
    let mut smoothed = vec![Gaussian::zeros(view.dim); k_obs + 1];
    let mut post = vec![0.0; n];
    for k in (0..=k_obs).rev() {
        if k < k_obs {
            // β_k = P^{Δ_{k+1}} (L_{k+1} ∘ β_{k+1})
            let meas = Measurement::full(&ys[k * m..(k + 1) * m]);
            let lmax = log_likelihoods(model, &gz, &meas, &mut ll);
            for z in 0..n {
                tmp[z] = beta[z] * (ll[z] - lmax).exp();
            }
            let t_from = if k == 0 { t0 } else { times[k - 1] };
            let (whole, frac) = eq.steps(times[k] - t_from);
            // apply the fraction first: P^Δ = P^{θδ} (P^δ)^whole commute
            if frac > 0.0 {
                kern.backward(&tmp, &mut tmp2);
                for z in 0..n {
                    tmp2[z] = (1.0 - frac) * tmp[z] + frac * tmp2[z];
                }
                std::mem::swap(&mut tmp, &mut tmp2);
            }
            for _ in 0..whole {
                kern.backward(&tmp, &mut tmp2);
                std::mem::swap(&mut tmp, &mut tmp2);
            }
            let s: f64 = tmp.iter().sum();
            if !(s > 0.0 && s.is_finite()) {
                return Err(FilterError::Degenerate);
            }
            for z in 0..n {
                beta[z] = tmp[z] / s;
            }
        }
        let a = &alpha[k * n..(k + 1) * n];
        for z in 0..n {
            post[z] = a[z] * beta[z];
        }
        if !normalise(&mut post) {
            return Err(FilterError::Degenerate);
        }
        smoothed[k] = moments(view, &post);
        if let Some(mm) = marg.as_mut() {
            mm[k * n..(k + 1) * n].copy_from_slice(&post);
        }
    }
    let filtered = (0..=k_obs)
        .map(|k| moments(view, &alpha[k * n..(k + 1) * n]))
        .collect();
    let mut all_times = Vec::with_capacity(k_obs + 1);
    all_times.push(t0);
    all_times.extend_from_slice(times);
    Ok(Smoothed {
        times: all_times,
        filtered,
        smoothed,
        marginals: marg,
    })
}

/// Mean and covariance of the mass `w` on the states of `view`.
pub fn moments(view: &ChainView, w: &[f64]) -> Gaussian {
    let d = view.dim;
    let mut g = Gaussian::zeros(d);
    let mut m1 = [0.0; MAX_STATE];
    for (i, &p) in w.iter().enumerate() {
        let z = view.state(i);
        for a in 0..d {
            m1[a] += p * z[a];
        }
    }
    let mut m2 = [0.0; MAX_STATE * MAX_STATE];
    for (i, &p) in w.iter().enumerate() {
        if p == 0.0 {
            continue;
        }
        let z = view.state(i);
        for a in 0..d {
            for b in 0..d {
                m2[a + b * d] += p * (z[a] - m1[a]) * (z[b] - m1[b]);
            }
        }
    }
    g.mean[..d].copy_from_slice(&m1[..d]);
    g.cov[..d * d].copy_from_slice(&m2[..d * d]);
    g
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;
    use crate::model::linear::ou_1d;

    /// A 4-state 1-D chain by hand and its dense P^δ.
    pub(crate) struct Small {
        pub states: Vec<f64>,
        pub ids: Vec<u32>,
        pub holding: Vec<f64>,
        pub radius: Vec<f64>,
        pub off: Vec<u32>,
        pub cols: Vec<u32>,
        pub probs: Vec<f64>,
    }

    impl Small {
        pub fn new() -> Self {
            Self {
                states: vec![-0.6, -0.1, 0.3, 0.8],
                ids: vec![0, 1, 2, 3],
                holding: vec![0.2, 0.1, 0.15, 0.25],
                radius: vec![1.0; 4],
                off: vec![0, 1, 3, 5, 7],
                cols: vec![1, 0, 2, 1, 3, 1, 2],
                probs: vec![1.0, 0.3, 0.7, 0.6, 0.4, 0.25, 0.75],
            }
        }
        pub fn view(&self) -> ChainView<'_> {
            ChainView {
                dim: 1,
                states: &self.states,
                ids: &self.ids,
                holding: &self.holding,
                radius: &self.radius,
                row_offsets: &self.off,
                cols: &self.cols,
                probs: &self.probs,
            }
        }
        pub fn dense(&self, delta: f64) -> Vec<Vec<f64>> {
            let v = self.view();
            let mut p = vec![vec![0.0; 4]; 4];
            for i in 0..4 {
                p[i][i] = 1.0 - delta / self.holding[i];
                let (c, w) = v.row(i);
                for (j, wj) in c.iter().zip(w) {
                    p[i][*j as usize] += delta / self.holding[i] * wj;
                }
            }
            p
        }
    }

    #[test]
    fn forward_backward_matches_brute_force_path_enumeration() {
        let small = Small::new();
        let view = small.view();
        view.validate().unwrap();
        let model = ou_1d(1.0, 0.5, 0.4, 2.0);
        let delta = 0.05;
        let p = small.dense(delta);
        let prior = [0.1, 0.4, 0.3, 0.2];
        // 4 observations, one every δ (one step each) and one after 2.5 δ
        let times = [0.05, 0.10, 0.15, 0.275];
        let ys = [0.2, -0.3, 0.5, 0.7];
        let sm = smooth(&model, &view, delta, &prior, 0.0, &times, &ys, true).unwrap();
        let marg = sm.marginals.unwrap();
        // brute force: transition over each interval as a dense matrix
        let mut trans = vec![];
        let mut t_prev = 0.0;
        for &t in &times {
            let q = (t - t_prev) / delta;
            let whole = (q + 1e-9).floor() as usize;
            let frac = q - whole as f64;
            let mut m = vec![vec![0.0; 4]; 4];
            for i in 0..4 {
                m[i][i] = 1.0;
            }
            let mul = |a: &Vec<Vec<f64>>, b: &Vec<Vec<f64>>| {
                let mut c = vec![vec![0.0; 4]; 4];
                for i in 0..4 {
                    for j in 0..4 {
                        c[i][j] = (0..4).map(|k| a[i][k] * b[k][j]).sum();
                    }
                }
                c
            };
            for _ in 0..whole {
                m = mul(&m, &p);
            }
            if frac > 1e-9 {
                let mut pf = vec![vec![0.0; 4]; 4];
                for i in 0..4 {
                    for j in 0..4 {
                        pf[i][j] = frac * p[i][j] + if i == j { 1.0 - frac } else { 0.0 };
                    }
                }
                m = mul(&m, &pf);
            }
            trans.push(m);
            t_prev = t;
        }
        let lik = |y: f64, z: f64| (-0.5 * ((y - z) / 0.4f64).powi(2)).exp();
        let k = times.len();
        let mut post = vec![vec![0.0; 4]; k + 1];
        let mut total = 0.0;
        for path in 0..4usize.pow(k as u32 + 1) {
            let mut s = [0usize; 5];
            let mut c = path;
            for v in s.iter_mut().take(k + 1) {
                *v = c % 4;
                c /= 4;
            }
            let mut w = prior[s[0]];
            for j in 0..k {
                w *= trans[j][s[j]][s[j + 1]] * lik(ys[j], small.states[s[j + 1]]);
            }
            total += w;
            for j in 0..=k {
                post[j][s[j]] += w;
            }
        }
        for j in 0..=k {
            for z in 0..4 {
                let want = post[j][z] / total;
                let got = marg[j * 4 + z];
                assert!((got - want).abs() < 1e-12, "t{j} z{z}: {got} vs {want}");
            }
        }
        // the last smoothed marginal is the filtered one
        assert!((sm.smoothed[k].mean[0] - sm.filtered[k].mean[0]).abs() < 1e-12);
    }
}
