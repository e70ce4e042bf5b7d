//! Step 1 of implicit sampling (paper 003 §2): locate the mode
//! μ = argmin F and φ = F(μ) of F = −log p, and factor the Hessian there,
//! H = ∇²F(μ) = L Lᵀ.
//!
//! Newton's method with the analytic gradient and (banded) Hessian of the
//! objective and an Armijo backtracking line search:
//!
//! ```text
//! (H_k + τ I) d = −g_k,   x_{k+1} = x_k + α d,   F(x_k + α d) ≤ F(x_k) + c₁ α g_kᵀ d
//! ```
//!
//! τ = 0 while H_k is positive definite; otherwise τ grows tenfold from
//! 10⁻⁸·max|H_ii| until the Cholesky factorisation succeeds (a
//! Levenberg–Marquardt safeguard, so a saddle or a concave region never
//! produces an ascent direction). Iteration stops when the Newton decrement
//! ½ gᵀH⁻¹g falls below `tol_decrement` (the error of φ to second order).
//! On return the workspace holds the factor L of the (possibly shifted)
//! Hessian at the returned point, which the maps of [`super::maps`] use; any
//! positive-definite H keeps the weights of those maps exact.
//!
//! Variables may be pinned (held at their current value, an equality
//! constraint): their gradient entries are zeroed and their Hessian rows and
//! columns replaced by the identity, so the step leaves them unchanged. This
//! is how the constrained minimisations of the double slit are solved.

use super::banded::SymBand;

/// A twice-differentiable objective F: ℝᴺ → ℝ ∪ {+∞} whose Hessian has
/// half-bandwidth [`Objective::bandwidth`].
pub trait Objective {
    /// N.
    fn dim(&self) -> usize;
    /// Half-bandwidth of the Hessian (N − 1 for a dense one).
    fn bandwidth(&self) -> usize;
    /// F(x); +∞ where the density vanishes.
    fn value(&self, x: &[f64]) -> f64;
    /// F(x), its gradient into `g` and its Hessian into `h` (already
    /// resized to N and zeroed by the caller).
    fn derivatives(&self, x: &[f64], g: &mut [f64], h: &mut SymBand) -> f64;
    /// F(x) and its gradient into `g` (no Hessian).
    fn gradient(&self, x: &[f64], g: &mut [f64]) -> f64;
    /// Whether F can be +∞ where its derivative pass still reports a finite
    /// value (a constraint only [`Objective::value`] checks): then the
    /// minimiser checks the start with a value pass first.
    fn has_barrier(&self) -> bool {
        true
    }
    /// The directional derivative ∇F(x)·d (the random map's dλ/dρ needs
    /// it); `scratch` has length ≥ N.
    fn directional(&self, x: &[f64], d: &[f64], scratch: &mut [f64]) -> f64 {
        let n = self.dim();
        self.gradient(x, &mut scratch[..n]);
        (0..n).map(|i| scratch[i] * d[i]).sum()
    }
}

/// Settings of the Newton minimiser.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct NewtonOptions {
    /// Iteration cap.
    pub max_iter: usize,
    /// Stop when ½ gᵀH⁻¹g ≤ tol_decrement · max(1, |F|).
    pub tol_decrement: f64,
    /// Armijo constant c₁.
    pub armijo: f64,
    /// Backtracking steps before giving up.
    pub max_backtrack: usize,
    /// After a step, test convergence with the gradient at the new point and
    /// the factor of the previous one before paying for a new Hessian. On
    /// success the returned factor is that of the last Hessian evaluated
    /// (exact for quadratic F; any positive-definite factor keeps the
    /// sampling weights exact).
    pub reuse_factor: bool,
    /// Return the iterate reached after `max_iter` iterations instead of
    /// failing (real-time iteration: a controller called every few ms keeps
    /// refining the same, warm-started plan across calls, so a bounded
    /// number of Newton steps per call suffices). The workspace then holds
    /// the gradient and factor at that iterate, and `decrement` says how far
    /// from the minimum it is. (Returning the stepped point with the previous
    /// factor saves a Hessian pass but measured far worse on the ship: with
    /// the control-limit penalty the Hessian changes with the active set.)
    pub accept_at_cap: bool,
}

impl Default for NewtonOptions {
    fn default() -> Self {
        Self {
            max_iter: 50,
            tol_decrement: 1e-13,
            armijo: 1e-4,
            max_backtrack: 40,
            reuse_factor: false,
            accept_at_cap: false,
        }
    }
}

/// Why the minimisation failed.
#[derive(Debug, Clone, Copy, PartialEq, thiserror::Error)]
pub enum NewtonError {
    #[error("objective is not finite at the starting point")]
    InfeasibleStart,
    #[error("line search found no decrease")]
    LineSearch,
    #[error("no convergence within {0} iterations")]
    MaxIter(usize),
    #[error("Hessian could not be made positive definite")]
    Factorisation,
}

/// Result of a minimisation.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct NewtonResult {
    /// φ = F(μ).
    pub phi: f64,
    /// Newton iterations (derivative evaluations − 1).
    pub iterations: usize,
    /// Diagonal shift τ in the final factor (0 if H(μ) was positive definite).
    pub shift: f64,
    /// Final Newton decrement ½ gᵀH⁻¹g.
    pub decrement: f64,
}

/// Buffers of the minimiser, sized once for the largest problem.
#[derive(Clone, Debug)]
pub struct NewtonWorkspace {
    /// Gradient at the current point.
    pub g: Vec<f64>,
    /// Hessian at the current point.
    pub h: SymBand,
    /// Cholesky factor of the (shifted) Hessian at the current point.
    pub l: SymBand,
    d: Vec<f64>,
    trial: Vec<f64>,
    /// Pinned variables (constraints); length ≥ N, all false by default.
    pub pinned: Vec<bool>,
}

impl NewtonWorkspace {
    /// Buffers for objectives of dimension ≤ `n` and half-bandwidth `kd`.
    pub fn new(n: usize, kd: usize) -> Self {
        Self {
            g: vec![0.0; n],
            h: SymBand::new(n, kd),
            l: SymBand::new(n, kd),
            d: vec![0.0; n],
            trial: vec![0.0; n],
            pinned: vec![false; n],
        }
    }

    /// Evaluate derivatives at x and factor the Hessian into `self.l`
    /// (pinned variables as identity rows; shifted by τ if not positive
    /// definite). Returns (F, τ).
    pub fn factor<O: Objective + ?Sized>(
        &mut self,
        obj: &O,
        x: &[f64],
    ) -> Result<(f64, f64), NewtonError> {
        let n = obj.dim();
        self.h.resize(n);
        let f = obj.derivatives(x, &mut self.g[..n], &mut self.h);
        if !f.is_finite() {
            return Err(NewtonError::InfeasibleStart);
        }
        for i in 0..n {
            if self.pinned[i] {
                self.g[i] = 0.0;
                self.h.pin(i);
            }
        }
        let mut tau = 0.0;
        let base = 1e-8 * self.h.max_abs_diagonal().max(1e-300);
        for _ in 0..60 {
            self.l.copy_from(&self.h);
            if tau > 0.0 {
                self.l.add_diagonal(tau);
            }
            if self.l.cholesky_in_place().is_ok() {
                return Ok((f, tau));
            }
            tau = if tau == 0.0 { base } else { tau * 10.0 };
        }
        Err(NewtonError::Factorisation)
    }

    /// Minimise `obj` starting from `x` (overwritten by the minimiser μ).
    /// On success `self.l` is the factor of the Hessian at μ and `self.g`
    /// the gradient there (zero up to the tolerance, except in pinned
    /// coordinates). One function: the iteration, its Armijo line search
    /// and the factor reuse share the step, the trial point and the stale
    /// factor; apart, each piece would need all of them.
    pub fn minimise<O: Objective + ?Sized>(
        &mut self,
        obj: &O,
        x: &mut [f64],
        opts: &NewtonOptions,
    ) -> Result<NewtonResult, NewtonError> {
        let n = obj.dim();
        debug_assert!(x.len() >= n && self.g.len() >= n);
        let x = &mut x[..n];
        if obj.has_barrier() && !obj.value(x).is_finite() {
            return Err(NewtonError::InfeasibleStart);
        }
        for it in 0..=opts.max_iter {
            let (f, tau) = self.factor(obj, x)?;
            // d = −(H + τI)⁻¹ g, decrement = ½ gᵀ(H + τI)⁻¹g.
            let d = &mut self.d[..n];
            for i in 0..n {
                d[i] = -self.g[i];
            }
            self.l.solve_in_place(d);
            let slope: f64 = (0..n).map(|i| self.g[i] * d[i]).sum();
            let decrement = -0.5 * slope;
            if decrement <= opts.tol_decrement * f.abs().max(1.0) {
                return Ok(NewtonResult {
                    phi: f,
                    iterations: it,
                    shift: tau,
                    decrement,
                });
            }
            if it == opts.max_iter {
                if opts.accept_at_cap {
                    return Ok(NewtonResult {
                        phi: f,
                        iterations: it,
                        shift: tau,
                        decrement,
                    });
                }
                break;
            }
            let mut alpha = 1.0;
            let mut accepted = false;
            // With factor reuse the full step's value comes with its gradient
            // (one pass instead of a value pass and a gradient pass): g at x
            // is no longer needed once the slope is known.
            let mut g_at_trial = false;
            let mut f_new = f;
            for _ in 0..opts.max_backtrack {
                for i in 0..n {
                    self.trial[i] = x[i] + alpha * d[i];
                }
                let ft = if opts.reuse_factor && alpha == 1.0 {
                    g_at_trial = true;
                    obj.gradient(&self.trial[..n], &mut self.g[..n])
                } else {
                    g_at_trial = false;
                    obj.value(&self.trial[..n])
                };
                if ft.is_finite() && ft <= f + opts.armijo * alpha * slope {
                    accepted = true;
                    f_new = ft;
                    break;
                }
                alpha *= 0.5;
            }
            if !accepted {
                if g_at_trial || opts.reuse_factor {
                    // self.g was overwritten at the full step: restore ∇F(x).
                    obj.gradient(x, &mut self.g[..n]);
                    for i in 0..n {
                        if self.pinned[i] {
                            self.g[i] = 0.0;
                        }
                    }
                }
                // No decrease representable in floating point: at a minimum
                // to machine precision if the decrement is tiny relative to F.
                if decrement <= 1e-9 * f.abs().max(1.0) {
                    return Ok(NewtonResult {
                        phi: f,
                        iterations: it,
                        shift: tau,
                        decrement,
                    });
                }
                return Err(NewtonError::LineSearch);
            }
            x.copy_from_slice(&self.trial[..n]);
            if opts.reuse_factor {
                let f = if g_at_trial {
                    f_new
                } else {
                    obj.gradient(x, &mut self.g[..n])
                };
                for i in 0..n {
                    if self.pinned[i] {
                        self.g[i] = 0.0;
                    }
                }
                let d = &mut self.d[..n];
                d.copy_from_slice(&self.g[..n]);
                self.l.solve_in_place(d);
                let dec = 0.5 * (0..n).map(|i| self.g[i] * d[i]).sum::<f64>();
                if dec <= opts.tol_decrement * f.abs().max(1.0) {
                    return Ok(NewtonResult {
                        phi: f,
                        iterations: it + 1,
                        shift: tau,
                        decrement: dec,
                    });
                }
            }
        }
        Err(NewtonError::MaxIter(opts.max_iter))
    }
}

/// Dense objectives for tests and small problems: F with closures.
pub struct DenseObjective<V, D>
where
    V: Fn(&[f64]) -> f64,
    D: Fn(&[f64], &mut [f64], &mut SymBand) -> f64,
{
    pub n: usize,
    pub value: V,
    pub derivatives: D,
}

impl<V, D> Objective for DenseObjective<V, D>
where
    V: Fn(&[f64]) -> f64,
    D: Fn(&[f64], &mut [f64], &mut SymBand) -> f64,
{
    fn dim(&self) -> usize {
        self.n
    }
    fn bandwidth(&self) -> usize {
        self.n.saturating_sub(1)
    }
    fn value(&self, x: &[f64]) -> f64 {
        (self.value)(x)
    }
    fn derivatives(&self, x: &[f64], g: &mut [f64], h: &mut SymBand) -> f64 {
        (self.derivatives)(x, g, h)
    }
    fn gradient(&self, x: &[f64], g: &mut [f64]) -> f64 {
        let mut h = SymBand::new(self.n, self.bandwidth());
        (self.derivatives)(x, g, &mut h)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Rosenbrock: a curved valley with an indefinite Hessian away from the
    /// minimum; the safeguarded Newton must still reach (1, 1).
    #[allow(clippy::type_complexity)]
    fn rosenbrock(
    ) -> DenseObjective<impl Fn(&[f64]) -> f64, impl Fn(&[f64], &mut [f64], &mut SymBand) -> f64>
    {
        DenseObjective {
            n: 2,
            value: |x: &[f64]| (1.0 - x[0]).powi(2) + 100.0 * (x[1] - x[0] * x[0]).powi(2),
            derivatives: |x: &[f64], g: &mut [f64], h: &mut SymBand| {
                let (a, b) = (x[0], x[1]);
                g[0] = -2.0 * (1.0 - a) - 400.0 * a * (b - a * a);
                g[1] = 200.0 * (b - a * a);
                h.set(0, 0, 2.0 - 400.0 * (b - a * a) + 800.0 * a * a);
                h.set(1, 0, -400.0 * a);
                h.set(1, 1, 200.0);
                (1.0 - a).powi(2) + 100.0 * (b - a * a).powi(2)
            },
        }
    }

    /// Real-time iteration: at the cap the iterate reached is returned (not
    /// an error), F has decreased, and the workspace holds the gradient and
    /// the factor of the Hessian at that iterate; without `accept_at_cap`
    /// the same cap is an error. Repeated capped calls, each warm-started
    /// from the last, reach the minimum.
    #[test]
    fn accept_at_cap_returns_the_iterate_with_its_derivatives() {
        let obj = rosenbrock();
        for reuse_factor in [false, true] {
            let opts = NewtonOptions {
                max_iter: 1,
                reuse_factor,
                accept_at_cap: true,
                ..NewtonOptions::default()
            };
            let mut ws = NewtonWorkspace::new(2, 1);
            let mut x = [-1.2, 1.0];
            let f0 = obj.value(&x);
            let r = ws.minimise(&obj, &mut x, &opts).unwrap();
            assert_eq!(r.iterations, 1);
            assert!(r.phi < f0 && (r.phi - obj.value(&x)).abs() < 1e-12);
            assert!(r.decrement > opts.tol_decrement);
            let (mut g, mut h) = ([0.0; 2], SymBand::new(2, 1));
            obj.derivatives(&x, &mut g, &mut h);
            assert_eq!(&ws.g[..2], &g[..]);
            let mut hf = h.clone();
            if r.shift > 0.0 {
                hf.add_diagonal(r.shift);
            }
            hf.cholesky_in_place().unwrap();
            for (i, j) in [(0, 0), (1, 0), (1, 1)] {
                assert!((ws.l.get(i, j) - hf.get(i, j)).abs() < 1e-9);
            }
            let strict = NewtonOptions {
                accept_at_cap: false,
                ..opts
            };
            let mut y = [-1.2, 1.0];
            assert_eq!(
                ws.minimise(&obj, &mut y, &strict),
                Err(NewtonError::MaxIter(1))
            );
            for _ in 0..60 {
                ws.minimise(&obj, &mut x, &opts).unwrap();
            }
            assert!((x[0] - 1.0).abs() < 1e-6 && (x[1] - 1.0).abs() < 1e-6);
        }
    }

    #[test]
    fn minimises_rosenbrock_from_an_indefinite_start() {
        let obj = DenseObjective {
            n: 2,
            value: |x: &[f64]| (1.0 - x[0]).powi(2) + 100.0 * (x[1] - x[0] * x[0]).powi(2),
            derivatives: |x: &[f64], g: &mut [f64], h: &mut SymBand| {
                let (a, b) = (x[0], x[1]);
                g[0] = -2.0 * (1.0 - a) - 400.0 * a * (b - a * a);
                g[1] = 200.0 * (b - a * a);
                h.set(0, 0, 2.0 - 400.0 * (b - a * a) + 800.0 * a * a);
                h.set(1, 0, -400.0 * a);
                h.set(1, 1, 200.0);
                (1.0 - a).powi(2) + 100.0 * (b - a * a).powi(2)
            },
        };
        let mut ws = NewtonWorkspace::new(2, 1);
        let mut x = [-1.2, 1.0];
        let r = ws
            .minimise(&obj, &mut x, &NewtonOptions::default())
            .unwrap();
        assert!(
            (x[0] - 1.0).abs() < 1e-6 && (x[1] - 1.0).abs() < 1e-6,
            "{x:?}"
        );
        assert!(r.phi < 1e-12);
        // The factor is that of the Hessian at (1, 1): [[802, −400], [−400, 200]].
        let l00 = ws.l.get(0, 0);
        assert!((l00 * l00 - 802.0).abs() < 1e-3);
    }

    #[test]
    fn quadratic_converges_in_one_step_and_respects_pins() {
        // F = ½ xᵀ A x − bᵀx, A tridiagonal.
        let n = 6;
        let obj = DenseObjective {
            n,
            value: |x: &[f64]| {
                let mut f = 0.0;
                for i in 0..6 {
                    f += x[i] * x[i] - (i as f64) * x[i];
                    if i > 0 {
                        f -= 0.5 * x[i] * x[i - 1];
                    }
                }
                f
            },
            derivatives: |x: &[f64], g: &mut [f64], h: &mut SymBand| {
                let mut f = 0.0;
                for i in 0..6 {
                    f += x[i] * x[i] - (i as f64) * x[i];
                    g[i] = 2.0 * x[i] - i as f64;
                    h.add(i, i, 2.0);
                    if i > 0 {
                        f -= 0.5 * x[i] * x[i - 1];
                        g[i] -= 0.5 * x[i - 1];
                        g[i - 1] -= 0.5 * x[i];
                        h.add(i, i - 1, -0.5);
                    }
                }
                f
            },
        };
        let mut ws = NewtonWorkspace::new(n, 5);
        let mut x = [0.0; 6];
        let r = ws
            .minimise(&obj, &mut x, &NewtonOptions::default())
            .unwrap();
        assert_eq!(r.iterations, 1);
        // Gradient zero at the minimiser.
        let mut g = [0.0; 6];
        let mut h = SymBand::new(6, 5);
        obj.derivatives(&x, &mut g, &mut h);
        assert!(g.iter().all(|v| v.abs() < 1e-12));
        // Pin x₂ = 5: the other gradient entries vanish, x₂ stays.
        let mut y = [0.0; 6];
        y[2] = 5.0;
        ws.pinned[2] = true;
        ws.minimise(&obj, &mut y, &NewtonOptions::default())
            .unwrap();
        obj.derivatives(&y, &mut g, &mut h);
        assert_eq!(y[2], 5.0);
        for i in [0, 1, 3, 4, 5] {
            assert!(g[i].abs() < 1e-12);
        }
        assert!(g[2].abs() > 1e-3);
    }
}
