//! Naive path-integral Monte Carlo, the baseline paper 003 §3 shows failing:
//! simulate the uncontrolled SDE (12) with Euler–Maruyama and average e^{−G}
//!
//! ```text
//! y₀ = x,  y_i = y_{i−1} + f0(y_{i−1}) Δt + G Q ΔW_i,   ΔW_i ~ N(0, Δt I)
//! G(y) = Φ(y_n)/γ + Δt/(2γ) Σ_i [V(y_i) + V(y_{i−1})]   (+∞ through a wall)
//! ψ(x) ≈ (1/M) Σ_j e^{−G(y^j)},   u = γ R⁻¹ Gᵀ ∂ₓ log ψ
//! ```
//!
//! ∂ₓ log ψ by central differences along the columns of G with common random
//! numbers (the same increments for x ± h g_j). When no path survives (every
//! G = +∞, e.g. every walker hits the double-slit wall) the estimate does not
//! exist and [`NaiveError::NoSurvivors`] is returned. Sums are kept in the log
//! domain (streaming log-sum-exp), no per-sample storage: M may be 10⁵+.

use super::implicit::path::{Gate, PathCost, PathSetup};
use super::{ControlError, ControlInfo, Controller};
use crate::belief::Gaussian;
use crate::model::affine::{AffineError, ControlAffine};
use crate::rng::SimRng;
use crate::{MAX_CONTROL, MAX_STATE};
use rand::RngExt;
use rand_distr::StandardNormal;

/// Why the naive estimate failed.
#[derive(Debug, Clone, Copy, PartialEq, thiserror::Error)]
pub enum NaiveError {
    #[error("no sampled path has finite cost (all {0} hit the wall)")]
    NoSurvivors(usize),
}

/// Result of one naive estimate.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct NaiveEstimate {
    /// log ψ (Monte Carlo, no constants needed: G has none).
    pub log_psi: f64,
    /// u = γR⁻¹Gᵀ∂ₓ log ψ.
    pub u: [f64; MAX_CONTROL],
    /// Paths (from x itself) with finite G, i.e. through the wall.
    pub survivors: usize,
    /// Effective sample size of e^{−G}.
    pub ess: f64,
}

/// Running log-sum-exp with the sum of squares for the ESS.
#[derive(Clone, Copy)]
struct Lse {
    max: f64,
    sum: f64,
    sum2: f64,
}

impl Lse {
    const EMPTY: Self = Self {
        max: f64::NEG_INFINITY,
        sum: 0.0,
        sum2: 0.0,
    };
    fn push(&mut self, l: f64) {
        if l == f64::NEG_INFINITY {
            return;
        }
        if l > self.max {
            let s = (self.max - l).exp();
            self.sum = self.sum * s + 1.0;
            self.sum2 = self.sum2 * s * s + 1.0;
            self.max = l;
        } else {
            let e = (l - self.max).exp();
            self.sum += e;
            self.sum2 += e * e;
        }
    }
    fn value(&self) -> f64 {
        if self.sum > 0.0 {
            self.max + self.sum.ln()
        } else {
            f64::NEG_INFINITY
        }
    }
}

/// The naive estimator for a control-affine model.
#[derive(Clone, Debug)]
pub struct NaivePathIntegral {
    setup: PathSetup,
    noise_dim: usize,
    /// G·Q, m × r column-major.
    gq: [f64; MAX_STATE * MAX_STATE],
}

impl NaivePathIntegral {
    /// For `model` with control cost R (p×p) and path step `dt`; checks (8).
    pub fn new<M: ControlAffine + ?Sized>(
        model: &M,
        r: &[f64],
        dt: f64,
    ) -> Result<Self, AffineError> {
        let setup = PathSetup::new(model, r, dt)?;
        let (m, p, nr) = (model.state_dim(), model.control_dim(), model.noise_dim());
        let mut q = [0.0; MAX_CONTROL * MAX_STATE];
        model.noise_matrix(&mut q[..p * nr]);
        let mut gq = [0.0; MAX_STATE * MAX_STATE];
        for i in 0..m {
            for j in 0..nr {
                gq[i + j * m] = (0..p).map(|k| setup.g[i + k * m] * q[k + j * p]).sum();
            }
        }
        Ok(Self {
            setup,
            noise_dim: nr,
            gq,
        })
    }

    /// γ of condition (8).
    pub fn gamma(&self) -> f64 {
        self.setup.gamma
    }

    /// ψ and u at x over n steps from M unguided paths. One function: the
    /// sample loop advances the 1 + 2p variants (x, x ± h g_j) in lockstep
    /// with the same noise, and that shared state is the whole body.
    #[allow(clippy::too_many_arguments)]
    pub fn estimate<M: ControlAffine + ?Sized, C: PathCost + ?Sized>(
        &self,
        model: &M,
        cost: &C,
        x: &[f64],
        n: usize,
        gate: Option<Gate>,
        samples: usize,
        h: f64,
        rng: &mut SimRng,
    ) -> Result<NaiveEstimate, NaiveError> {
        let st = &self.setup;
        let (m, p, nr) = (st.m, st.p, self.noise_dim);
        let dt = st.dt;
        let sq = dt.sqrt();
        let hw = dt / (2.0 * st.gamma);
        // Variants: x, then x ± h g_j.
        let nv = 1 + 2 * p;
        let mut y = [[0.0; MAX_STATE]; 1 + 2 * MAX_CONTROL];
        let mut lse = [Lse::EMPTY; 1 + 2 * MAX_CONTROL];
        let mut survivors = 0;
        let mut f = [0.0; MAX_STATE];
        let mut dw = [0.0; MAX_STATE];
        for _ in 0..samples {
            let mut g = [0.0; 1 + 2 * MAX_CONTROL];
            let mut alive = [true; 1 + 2 * MAX_CONTROL];
            for v in 0..nv {
                y[v][..m].copy_from_slice(&x[..m]);
                if v > 0 {
                    let (j, s) = ((v - 1) / 2, if v % 2 == 1 { 1.0 } else { -1.0 });
                    for c in 0..m {
                        y[v][c] += s * h * st.g[c + j * m];
                    }
                }
                g[v] = hw * cost.running(&y[v][..m]);
            }
            for i in 1..=n {
                for d in dw[..nr].iter_mut() {
                    *d = rng.sample::<f64, _>(StandardNormal) * sq;
                }
                let mut any = false;
                for v in 0..nv {
                    if !alive[v] {
                        continue;
                    }
                    model.drift0(&y[v][..m], &mut f[..m]);
                    for c in 0..m {
                        let mut s = y[v][c] + f[c] * dt;
                        for k in 0..nr {
                            s += self.gq[c + k * m] * dw[k];
                        }
                        y[v][c] = s;
                    }
                    if let Some(gt) = gate {
                        if gt.step == i && gt.interval_of(y[v][gt.coord]).is_none() {
                            alive[v] = false;
                            continue;
                        }
                    }
                    let wc = if i < n { 2.0 * hw } else { hw };
                    g[v] += wc * cost.running(&y[v][..m]);
                    any = true;
                }
                if !any {
                    break; // every variant hit the wall: e^{−G} = 0 for all
                }
            }
            for v in 0..nv {
                if alive[v] {
                    g[v] += cost.terminal(&y[v][..m]) / st.gamma;
                    lse[v].push(-g[v]);
                }
            }
            if alive[0] {
                survivors += 1;
            }
        }
        let l0 = lse[0].value();
        if !l0.is_finite() {
            return Err(NaiveError::NoSurvivors(samples));
        }
        let mut grad = [0.0; MAX_CONTROL];
        for j in 0..p {
            let (lp, lm) = (lse[1 + 2 * j].value(), lse[2 + 2 * j].value());
            grad[j] = if lp.is_finite() && lm.is_finite() {
                (lp - lm) / (2.0 * h)
            } else {
                f64::NAN
            };
        }
        let mut u = [0.0; MAX_CONTROL];
        for i in 0..p {
            u[i] = st.gamma * (0..p).map(|j| st.rinv[i + j * p] * grad[j]).sum::<f64>();
        }
        Ok(NaiveEstimate {
            log_psi: l0 - (samples as f64).ln(),
            u,
            survivors,
            ess: lse[0].sum * lse[0].sum / lse[0].sum2,
        })
    }
}

/// Naive path-integral control as a [`Controller`] (receding horizon on
/// the belief mean), for comparisons.
pub struct NaivePiController<M: ControlAffine, C: PathCost> {
    model: M,
    cost: C,
    est: NaivePathIntegral,
    horizon_steps: usize,
    samples: usize,
    fd_step: f64,
    u_max: f64,
    rng: SimRng,
}

impl<M: ControlAffine, C: PathCost> NaivePiController<M, C> {
    /// R = r I; errors if condition (8) fails.
    pub fn new(
        model: M,
        cost: C,
        r: f64,
        dt: f64,
        horizon_steps: usize,
        samples: usize,
        u_max: f64,
        seed: u64,
    ) -> Result<Self, ControlError> {
        let p = model.control_dim();
        let mut rm = [0.0; MAX_CONTROL * MAX_CONTROL];
        for i in 0..p {
            rm[i + i * p] = r;
        }
        let est = NaivePathIntegral::new(&model, &rm[..p * p], dt)
            .map_err(|e| ControlError::Model(e.to_string()))?;
        if horizon_steps == 0 || samples == 0 {
            return Err(ControlError::Model(
                "naive PI needs horizon_steps ≥ 1 and samples ≥ 1".into(),
            ));
        }
        Ok(Self {
            model,
            cost,
            est,
            horizon_steps,
            samples,
            fd_step: 1e-3,
            u_max,
            rng: crate::rng::stream(seed, 0x4e41_4956),
        })
    }
}

impl<M: ControlAffine + 'static, C: PathCost + 'static> Controller for NaivePiController<M, C> {
    fn name(&self) -> &'static str {
        "naive_mc"
    }
    fn control_dim(&self) -> usize {
        self.model.control_dim()
    }
    fn set_goal(&mut self, goal: &[f64]) {
        self.cost.set_goal(goal);
    }
    fn reset(&mut self) {}
    fn compute(
        &mut self,
        _t: f64,
        belief: &Gaussian,
        u: &mut [f64],
    ) -> Result<ControlInfo, ControlError> {
        let (m, p) = (self.model.state_dim(), self.model.control_dim());
        if belief.dim != m {
            return Err(ControlError::Dimension {
                got: belief.dim,
                expected: m,
            });
        }
        if !belief.is_finite() {
            return Err(ControlError::NonFinite);
        }
        let e = self
            .est
            .estimate(
                &self.model,
                &self.cost,
                belief.mean(),
                self.horizon_steps,
                None,
                self.samples,
                self.fd_step,
                &mut self.rng,
            )
            .map_err(|_| ControlError::Numerical("no sampled path has finite cost"))?;
        for i in 0..p {
            u[i] = if e.u[i].is_finite() {
                e.u[i].clamp(-self.u_max, self.u_max)
            } else {
                0.0
            };
        }
        Ok(ControlInfo {
            cost: -self.est.gamma() * e.log_psi,
            samples: self.samples,
            ess: e.ess,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::model::double_slit::{DoubleSlit, SlitCost};

    /// After the wall the naive estimate is consistent: ψ and u approach the
    /// analytic values with enough samples.
    #[test]
    fn naive_estimate_is_consistent_without_a_wall() {
        let p = DoubleSlit::default();
        let model = p.model();
        let est = NaivePathIntegral::new(&model, &[p.r], p.dt).unwrap();
        let mut rng = crate::rng::stream(1, 0);
        let e = est
            .estimate(&model, &SlitCost, &[1.0], 50, None, 200_000, 1e-3, &mut rng)
            .unwrap();
        let exact = p.log_psi(1.0, 1.0);
        assert!((e.log_psi - exact).abs() < 0.02, "{} vs {exact}", e.log_psi);
        assert!(
            (e.u[0] - p.control(1.0, 1.0)).abs() < 0.05,
            "{} vs {}",
            e.u[0],
            p.control(1.0, 1.0)
        );
    }

    /// Before the wall it fails, as the paper says: with 5 000 walkers from
    /// x(0) = 1 none passes the slits (P ≈ 6·10⁻⁷ each).
    #[test]
    fn naive_estimate_fails_before_the_wall() {
        let p = DoubleSlit::default();
        let model = p.model();
        let est = NaivePathIntegral::new(&model, &[p.r], p.dt).unwrap();
        let mut rng = crate::rng::stream(2, 0);
        let r = est.estimate(
            &model,
            &SlitCost,
            &[1.0],
            100,
            p.gate_from(0.0),
            5000,
            1e-3,
            &mut rng,
        );
        assert_eq!(r, Err(NaiveError::NoSurvivors(5000)));
    }

    /// As a controller on ẍ = u with a smooth cost the naive estimate is
    /// consistent: with many walkers it lands near the path-integral control.
    #[test]
    fn naive_controller_is_consistent_on_a_smooth_problem() {
        use crate::control::implicit::{
            DiagonalQuadraticCost, EstimatorOptions, PathSampler, PathSetup,
        };
        use crate::model::affine::{LinearAffine, PathStructure};
        let model = LinearAffine {
            m: 2,
            p: 1,
            r: 1,
            a: vec![0.0, 0.0, 1.0, 0.0],
            g: vec![0.0, 1.0],
            q: vec![1.0],
            structure: PathStructure::SecondOrder,
        };
        let cost = DiagonalQuadraticCost::new(&[0.5, 0.1], &[1.0, 0.5]);
        let (r, dt, n) = (2.0, 0.05, 20);
        let setup = PathSetup::new(&model, &[r], dt).unwrap();
        let mut s = PathSampler::new(setup, n, 16, 1);
        let x = [0.5, -0.2];
        let exact = s
            .estimate(
                &model,
                &cost,
                &x,
                n,
                None,
                &EstimatorOptions::default(),
                &mut crate::rng::stream(1, 2),
            )
            .unwrap()
            .u[0];
        let mut c = NaivePiController::new(model, cost, r, dt, n, 100_000, 100.0, 3).unwrap();
        let mut u = [0.0];
        c.compute(0.0, &Gaussian::diagonal(&x, &[0.0, 0.0]), &mut u)
            .unwrap();
        assert!(
            (u[0] - exact).abs() < 0.1 * exact.abs(),
            "naive {} vs implicit {exact}",
            u[0]
        );
    }
}
