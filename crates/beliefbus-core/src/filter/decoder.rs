//! MAP trajectory decoding (thesis §3.6, eq. 3.21, Alg. 3.2; paper 001
//! §VII-D): Viterbi on a Markov-chain approximation.
//!
//! ```text
//! γ_{t_{k+1}}(z) = max_{z'} γ_{t_k}(z') P(z | z') P(y_{t_{k+1}} | z)     (eq. 3.21, back-pointers kept)
//! ```
//!
//! These are the papers' forms, kept as the baselines of the `decoding`
//! experiment; the converging decoder is
//! [`crate::filter::layered_decoder`] (same Viterbi, with the corrections
//! listed there). Two forms:
//! - [`viterbi`] — on the time-equalised chain M_n^δ with sampled
//!   observations at given times (paper 001's decoder): one max-product step
//!   per δ (fractional last step as in the filter), back-pointers per step.
//!   Known weakness, measured by the `decoding` experiment: as δ shrinks the
//!   self-loop p^δ(z|z) = 1 − δ/Δt → 1 dominates the max-product (the lazy
//!   chain's most probable path mostly stays put), so this decoder does not
//!   converge with n; the time-augmented decoder does.
//! - [`decode_time_augmented`] — Alg. 3.2: a chain on z = (t, x) ∈ [0, T] × S
//!   built for the augmented diffusion ṫ = 1 + σ_t w̃ ([`TimeAugmented`]),
//!   states sorted by t, `UpdateGamma` over in-neighbours with earlier time,
//!   start at the root (0, x₀) (x₀ known), end at the best state on {T} × S
//!   (which [`TimeAugmented`]-chains must sample densely, Remark 3.9).
//!
//! Edge likelihood (the thesis leaves it open): for an edge z' → z spanning
//! ℓ = t(z) − t(z') of a continuous observation dy = g dt + G dv with
//! diagonal G, the Girsanov (Radon–Nikodym) factor of the increment
//! Δy = y(t(z)) − y(t(z')):
//! ```text
//! log L(z' → z) = Σ_i [ g_i(x') Δy_i − ½ g_i(x')² ℓ ] / G_i²
//! ```
//! It is the continuous-time likelihood of eq. 3.5 restricted to the edge, so
//! paths with different numbers of edges are comparable; the Gaussian density
//! of Δy would add a factor Π (2π G² ℓ)^{-1/2} e^{−Δy²/2G²ℓ} that depends on
//! how the path cuts [0, T] and favours long edges.

use crate::chain::{ChainView, PropagationKernel, TimeEqualized};
use crate::filter::chain_filter::{log_likelihoods, observation_means};
use crate::filter::FilterError;
use crate::model::{Bounds, Dims, Measurement, SdeModel};
use crate::{MAX_NOISE, MAX_STATE};

/// A decoded trajectory.
#[derive(Clone, Debug, PartialEq)]
pub struct Decoded {
    /// Slots of the chain along the path.
    pub slots: Vec<u32>,
    /// Time of each point.
    pub times: Vec<f64>,
    /// State of each point, flat (len × d).
    pub states: Vec<f64>,
    /// log of the maximised path score.
    pub log_score: f64,
}

impl Decoded {
    /// Linear interpolation of the decoded path at time t (clamped), into x.
    pub fn at(&self, t: f64, x: &mut [f64]) {
        let d = x.len();
        let k = self.times.len();
        if k == 0 {
            return;
        }
        let j = self.times.partition_point(|&s| s <= t);
        if j == 0 {
            x.copy_from_slice(&self.states[..d]);
            return;
        }
        if j >= k {
            x.copy_from_slice(&self.states[(k - 1) * d..k * d]);
            return;
        }
        let (t0, t1) = (self.times[j - 1], self.times[j]);
        let a = if t1 > t0 { (t - t0) / (t1 - t0) } else { 1.0 };
        for i in 0..d {
            x[i] = (1.0 - a) * self.states[(j - 1) * d + i] + a * self.states[j * d + i];
        }
    }
}

/// Viterbi on M_n^δ: the most probable chain path given sampled
/// observations `ys` (K × m) at `times` after `t0`, from the prior mass
/// `prior`. Returns the path at t₀ and at every observation time.
// One function (~110 lines): the checks, the forward max-product pass and
// the back-tracking share the score and back-pointer arrays (thesis
// Alg. 3.1 read in one place).
pub fn viterbi<M: SdeModel>(
    model: &M,
    view: &ChainView,
    delta: f64,
    prior: &[f64],
    t0: f64,
    times: &[f64],
    ys: &[f64],
) -> Result<Decoded, FilterError> {
    let n = view.len();
    let m = model.dims().obs;
    let k_obs = times.len();
    if prior.len() != n || ys.len() != k_obs * m {
        return Err(FilterError::Dimension {
            what: "prior or observations",
            got: prior.len(),
            expected: n,
        });
    }
    let eq = TimeEqualized::new(delta).map_err(|_| FilterError::NonFinite("delta"))?;
    let kern = PropagationKernel::build(view, delta, false);
    let (in_off, in_src, in_w) = kern.incoming();
    let log_w: Vec<f64> = in_w.iter().map(|w| w.ln()).collect();
    let log_stay: Vec<f64> = kern.stay().iter().map(|s| s.ln()).collect();
    let gz = observation_means(model, view.states, view.dim);
    let mut g: Vec<f64> = prior.iter().map(|p| p.ln()).collect();
    let mut g2 = vec![0.0; n];
    let mut ll = vec![0.0; n];
    // back-pointers per sub-step; obs_step[k] = sub-step index after obs k
    let mut bp: Vec<u32> = Vec::new();
    let mut obs_step = Vec::with_capacity(k_obs);
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
        let nsub = whole + (frac > 0.0) as usize;
        for s in 0..nsub {
            let theta = if s < whole { 1.0 } else { frac };
            let base = bp.len();
            bp.resize(base + n, 0);
            for z in 0..n {
                let stay = if theta == 1.0 {
                    log_stay[z]
                } else {
                    ((1.0 - theta) + theta * kern.stay()[z]).ln()
                };
                let mut best = g[z] + stay;
                let mut arg = z as u32;
                let lt = theta.ln();
                for e in in_off[z] as usize..in_off[z + 1] as usize {
                    let v = g[in_src[e] as usize] + log_w[e] + lt;
                    if v > best {
                        best = v;
                        arg = in_src[e];
                    }
                }
                g2[z] = best;
                bp[base + z] = arg;
            }
            std::mem::swap(&mut g, &mut g2);
        }
        let meas = Measurement::full(&ys[k * m..(k + 1) * m]);
        log_likelihoods(model, &gz, &meas, &mut ll);
        for z in 0..n {
            g[z] += ll[z];
        }
        obs_step.push(bp.len() / n.max(1));
        t_prev = times[k];
    }
    // backtrack
    let (mut z, log_score) =
        g.iter()
            .enumerate()
            .fold((0usize, f64::NEG_INFINITY), |acc, (i, &v)| {
                if v > acc.1 {
                    (i, v)
                } else {
                    acc
                }
            });
    if !log_score.is_finite() {
        return Err(FilterError::Degenerate);
    }
    let total_steps = bp.len() / n.max(1);
    let mut at_step = vec![0u32; total_steps + 1];
    at_step[total_steps] = z as u32;
    for s in (0..total_steps).rev() {
        z = bp[s * n + z] as usize;
        at_step[s] = z as u32;
    }
    let d = view.dim;
    let mut out = Decoded {
        slots: vec![at_step[0]],
        times: vec![t0],
        states: view.state(at_step[0] as usize).to_vec(),
        log_score,
    };
    for (k, &s) in obs_step.iter().enumerate() {
        let slot = at_step[s];
        out.slots.push(slot);
        out.times.push(times[k]);
        out.states.extend_from_slice(view.state(slot as usize));
    }
    debug_assert_eq!(out.states.len(), out.times.len() * d);
    Ok(out)
}

/// A continuous observation path y(t) sampled on a grid, with linear
/// interpolation in between (y is the integrated observation, y(0) = 0).
#[derive(Clone, Debug)]
pub struct ObsPath {
    pub times: Vec<f64>,
    /// y at each grid time, len × m.
    pub y: Vec<f64>,
    pub m: usize,
}

impl ObsPath {
    /// y(t), linearly interpolated (clamped to the grid), into `out`.
    pub fn at(&self, t: f64, out: &mut [f64]) {
        let k = self.times.len();
        let j = self.times.partition_point(|&s| s <= t);
        let m = self.m;
        if j == 0 {
            out.copy_from_slice(&self.y[..m]);
        } else if j >= k {
            out.copy_from_slice(&self.y[(k - 1) * m..k * m]);
        } else {
            let (t0, t1) = (self.times[j - 1], self.times[j]);
            let a = (t - t0) / (t1 - t0);
            for i in 0..m {
                out[i] = (1.0 - a) * self.y[(j - 1) * m + i] + a * self.y[j * m + i];
            }
        }
    }
}

/// The diffusion of `inner` augmented with time, z = (t, x):
/// `dt = 1·ds + σ_t dw₀`, `dx = f(x) ds + F(x) dw` (thesis §3.6.1), on
/// [0, T] × S. Observations are those of `inner` (of x).
pub struct TimeAugmented<'a, M: SdeModel> {
    pub inner: &'a M,
    pub sigma_t: f64,
    bounds: Bounds,
}

impl<'a, M: SdeModel> TimeAugmented<'a, M> {
    /// Augment `inner` on the horizon [0, `horizon`]. Fails when the
    /// augmented dimension exceeds [`MAX_STATE`].
    pub fn new(inner: &'a M, sigma_t: f64, horizon: f64) -> Result<Self, String> {
        let d = inner.dims().state;
        if d + 1 > MAX_STATE || inner.dims().noise + 1 > MAX_NOISE {
            return Err(format!("time augmentation needs d + 1 ≤ {MAX_STATE}"));
        }
        let b = inner.bounds();
        let mut lo = vec![0.0];
        lo.extend_from_slice(b.lo());
        let mut hi = vec![horizon];
        hi.extend_from_slice(b.hi());
        let mut bounds = Bounds::new_box(&lo, &hi).map_err(|e| e.to_string())?;
        if let Some(disc) = b.disc() {
            bounds = bounds
                .with_disc((disc.axes.0 + 1, disc.axes.1 + 1), disc.radius)
                .map_err(|e| e.to_string())?;
        }
        Ok(Self {
            inner,
            sigma_t,
            bounds,
        })
    }
}

impl<M: SdeModel> SdeModel for TimeAugmented<'_, M> {
    fn name(&self) -> &str {
        "time-augmented"
    }
    fn dims(&self) -> Dims {
        let d = self.inner.dims();
        Dims {
            state: d.state + 1,
            noise: d.noise + 1,
            obs: d.obs,
            control: 0,
        }
    }
    fn drift(&self, z: &[f64], _u: &[f64], f: &mut [f64]) {
        f[0] = 1.0;
        let u0 = [0.0; crate::MAX_CONTROL];
        let c = self.inner.dims().control;
        self.inner.drift(&z[1..], &u0[..c], &mut f[1..]);
    }
    fn diffusion(&self, z: &[f64], big_f: &mut [f64]) {
        let d = self.inner.dims().state;
        let k = self.inner.dims().noise;
        let da = d + 1;
        let mut inner = [0.0; MAX_STATE * MAX_NOISE];
        self.inner.diffusion(&z[1..], &mut inner[..d * k]);
        big_f[..da * (k + 1)].fill(0.0);
        big_f[0] = self.sigma_t;
        for c in 0..k {
            for r in 0..d {
                big_f[(r + 1) + (c + 1) * da] = inner[r + c * d];
            }
        }
    }
    fn obs_mean(&self, z: &[f64], g: &mut [f64]) {
        self.inner.obs_mean(&z[1..], g)
    }
    fn obs_std(&self, std: &mut [f64]) {
        self.inner.obs_std(std)
    }
    fn bounds(&self) -> &Bounds {
        &self.bounds
    }
}

/// Alg. 3.2 on a time-augmented chain `view` (coordinates (t, x)):
/// Viterbi from the root slot over in-edges with earlier time, ending at
/// the best state with t ≥ `horizon` − 1e-6 · max(1, horizon) (states on
/// {T} × S may carry a tiny jitter in t: the k-d tree cannot hold many
/// points with one equal coordinate). `g_coeff` is the diagonal of
/// G in dy = g(x) dt + G dv; `inner` supplies g.
// One function (~120 lines): the time-ordered pass over in-edges and the
// back-tracking share the score and back-pointer arrays (thesis Alg. 3.2
// read in one place).
pub fn decode_time_augmented<M: SdeModel>(
    inner: &M,
    view: &ChainView,
    root: usize,
    horizon: f64,
    g_coeff: &[f64],
    path: &ObsPath,
) -> Result<Decoded, FilterError> {
    let n = view.len();
    let da = view.dim;
    let d = da - 1;
    let m = inner.dims().obs;
    if root >= n || g_coeff.len() != m || path.m != m {
        return Err(FilterError::Dimension {
            what: "root, G or observation path",
            got: g_coeff.len(),
            expected: m,
        });
    }
    // incoming edges by counting sort
    let mut in_off = vec![0u32; n + 1];
    for &c in view.cols {
        in_off[c as usize + 1] += 1;
    }
    for i in 0..n {
        in_off[i + 1] += in_off[i];
    }
    let mut fill = in_off[..n].to_vec();
    let mut in_src = vec![0u32; view.nnz()];
    let mut in_lp = vec![0.0; view.nnz()];
    for i in 0..n {
        let (c, p) = view.row(i);
        for (&j, &pj) in c.iter().zip(p) {
            let pos = fill[j as usize] as usize;
            fill[j as usize] += 1;
            in_src[pos] = i as u32;
            in_lp[pos] = pj.ln();
        }
    }
    // observation means and y at every state's time
    let mut gz = vec![0.0; n * m];
    let mut yz = vec![0.0; n * m];
    for i in 0..n {
        let z = view.state(i);
        inner.obs_mean(&z[1..], &mut gz[i * m..(i + 1) * m]);
        path.at(z[0], &mut yz[i * m..(i + 1) * m]);
    }
    let inv_g2: Vec<f64> = g_coeff.iter().map(|g| 1.0 / (g * g)).collect();
    let mut order: Vec<u32> = (0..n as u32).collect();
    order.sort_by(|&a, &b| {
        view.state(a as usize)[0]
            .total_cmp(&view.state(b as usize)[0])
            .then(a.cmp(&b))
    });
    let mut gamma = vec![f64::NEG_INFINITY; n];
    let mut back = vec![u32::MAX; n];
    gamma[root] = 0.0;
    for &zi in &order {
        let z = zi as usize;
        if z == root {
            continue;
        }
        let tz = view.state(z)[0];
        let mut best = f64::NEG_INFINITY;
        let mut arg = u32::MAX;
        for e in in_off[z] as usize..in_off[z + 1] as usize {
            let s = in_src[e] as usize;
            let ts = view.state(s)[0];
            if !(ts < tz) || gamma[s] == f64::NEG_INFINITY {
                continue;
            }
            let ell = tz - ts;
            let mut lik = 0.0;
            for i in 0..m {
                let g = gz[s * m + i];
                let dy = yz[z * m + i] - yz[s * m + i];
                lik += (g * dy - 0.5 * g * g * ell) * inv_g2[i];
            }
            let v = gamma[s] + in_lp[e] + lik;
            if v > best {
                best = v;
                arg = s as u32;
            }
        }
        gamma[z] = best;
        back[z] = arg;
    }
    let mut end = usize::MAX;
    let mut best = f64::NEG_INFINITY;
    for i in 0..n {
        if view.state(i)[0] >= horizon - 1e-6 * horizon.max(1.0) && gamma[i] > best {
            best = gamma[i];
            end = i;
        }
    }
    if end == usize::MAX {
        return Err(FilterError::Degenerate);
    }
    let mut slots = vec![end as u32];
    let mut z = end;
    while z != root {
        z = back[z] as usize;
        slots.push(z as u32);
    }
    slots.reverse();
    let mut out = Decoded {
        slots: slots.clone(),
        times: Vec::with_capacity(slots.len()),
        states: Vec::with_capacity(slots.len() * d),
        log_score: best,
    };
    for &s in &slots {
        let z = view.state(s as usize);
        out.times.push(z[0]);
        out.states.extend_from_slice(&z[1..]);
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::filter::smoother::tests::Small;
    use crate::model::linear::ou_1d;

    #[test]
    fn viterbi_matches_brute_force_on_a_small_chain() {
        let small = Small::new();
        let view = small.view();
        let model = ou_1d(1.0, 0.5, 0.4, 2.0);
        let delta = 0.05;
        let p = small.dense(delta);
        let prior = [0.1, 0.4, 0.3, 0.2];
        let times = [0.05, 0.10, 0.15, 0.20];
        let ys = [0.2, -0.3, 0.5, 0.7];
        let dec = viterbi(&model, &view, delta, &prior, 0.0, &times, &ys).unwrap();
        let lik = |y: f64, z: f64| -0.5 * ((y - z) / 0.4f64).powi(2);
        let (mut best, mut arg) = (f64::NEG_INFINITY, vec![]);
        for path in 0..4usize.pow(5) {
            let mut s = [0usize; 5];
            let mut c = path;
            for v in s.iter_mut() {
                *v = c % 4;
                c /= 4;
            }
            let mut w = prior[s[0]].ln();
            for j in 0..4 {
                w += p[s[j]][s[j + 1]].ln() + lik(ys[j], small.states[s[j + 1]]);
            }
            if w > best {
                best = w;
                arg = s.iter().map(|&v| v as u32).collect();
            }
        }
        assert_eq!(dec.slots, arg);
        assert!(
            (dec.log_score - best).abs() < 1e-10,
            "{} vs {best}",
            dec.log_score
        );
    }

    #[test]
    // Long: the DAG, its path enumeration and the comparison belong
    // together so the brute force visibly uses the same scores.
    fn time_augmented_viterbi_matches_brute_force_over_dag_paths() {
        // (t, x) states: root at t=0; two layers; two end states at T = 1.
        let states = vec![
            0.0, 0.0, // 0 root
            0.4, 0.2, // 1
            0.5, -0.3, // 2
            0.7, 0.1, // 3
            1.0, 0.3, // 4 end
            1.0, -0.2, // 5 end
        ];
        let ids: Vec<u32> = (0..6).collect();
        let holding = vec![0.4; 6];
        let radius = vec![1.0; 6];
        let rows: Vec<Vec<(u32, f64)>> = vec![
            vec![(1, 0.6), (2, 0.4)],
            vec![(3, 0.5), (4, 0.3), (2, 0.2)],
            vec![(3, 0.7), (5, 0.3)],
            vec![(4, 0.5), (5, 0.4), (1, 0.1)],
            vec![(3, 1.0)],
            vec![(3, 1.0)],
        ];
        let mut off = vec![0u32];
        let (mut cols, mut probs) = (vec![], vec![]);
        for r in &rows {
            for &(c, p) in r {
                cols.push(c);
                probs.push(p);
            }
            off.push(cols.len() as u32);
        }
        let view = ChainView {
            dim: 2,
            states: &states,
            ids: &ids,
            holding: &holding,
            radius: &radius,
            row_offsets: &off,
            cols: &cols,
            probs: &probs,
        };
        view.validate().unwrap();
        let model = ou_1d(1.0, 0.5, 0.4, 2.0); // g(x) = x
        let path = ObsPath {
            times: vec![0.0, 0.5, 1.0],
            y: vec![0.0, 0.1, 0.05],
            m: 1,
        };
        let gcoef = [0.3];
        let dec = decode_time_augmented(&model, &view, 0, 1.0, &gcoef, &path).unwrap();
        // brute force over all time-increasing paths root → end
        let y = |t: f64| {
            let mut o = [0.0];
            path.at(t, &mut o);
            o[0]
        };
        fn walk(
            z: usize,
            score: f64,
            acc: &mut Vec<usize>,
            rows: &[Vec<(u32, f64)>],
            st: &[f64],
            y: &dyn Fn(f64) -> f64,
            best: &mut (f64, Vec<usize>),
        ) {
            if st[2 * z] >= 1.0 && score > best.0 {
                *best = (score, acc.clone());
            }
            for &(c, p) in &rows[z] {
                let c = c as usize;
                let (tz, tc) = (st[2 * z], st[2 * c]);
                if tc <= tz {
                    continue;
                }
                let g = st[2 * z + 1];
                let lik = (g * (y(tc) - y(tz)) - 0.5 * g * g * (tc - tz)) / 0.09;
                acc.push(c);
                walk(c, score + p.ln() + lik, acc, rows, st, y, best);
                acc.pop();
            }
        }
        let mut best = (f64::NEG_INFINITY, vec![]);
        walk(0, 0.0, &mut vec![0], &rows, &states, &y, &mut best);
        let want: Vec<u32> = best.1.iter().map(|&v| v as u32).collect();
        assert_eq!(dec.slots, want);
        assert!((dec.log_score - best.0).abs() < 1e-12);
        let mut x = [0.0];
        dec.at(0.0, &mut x);
        assert_eq!(x[0], 0.0);
    }
}
