//! Control-affine models with the noise entering through the control
//! channel — the class path-integral control applies to (paper 003 §3, eq. 7):
//!
//! ```text
//! dx = f0(x) dt + G (u dt + Q dW),   x ∈ ℝᵐ, u ∈ ℝᵖ, G m×p (constant), Q p×r
//! cost  E[ Φ(x(t_f)) + ∫ ½ uᵀRu + V(x) dt ]          (½: erratum E2)
//! ```
//!
//! The HJB equation linearises under J = −γ log ψ iff a scalar γ satisfies
//! condition (8), `γ G R⁻¹ Gᵀ = G Q Qᵀ Gᵀ`; the path noise covariance is then
//! Σ = G Q Qᵀ Gᵀ. [`check_condition_8`] verifies it and returns γ.
//!
//! [`PathStructure`] says which coordinates the noise drives, i.e. what the
//! path variables of the sampler are:
//! - `Full`: Σ has full rank, every coordinate of every path point is a
//!   variable (double slit, Himmelblau);
//! - `SecondOrder`: x = (q, v) with q, v ∈ ℝᵖ, dq = v dt exactly and the
//!   control and noise entering only v (G = [0; B], B invertible): only the
//!   noise-driven velocities are sampled, as the paper does for the arm
//!   (§3.2); positions follow from them.
//!
//! Implementations here: [`ControlledBrownian`] (dx = u dt + √σ dW, the
//! double slit and Himmelblau problems), [`LinearAffine`] (linear f0, for
//! the Riccati checks), [`DoubleIntegrator`] (the feedback-linearised arm,
//! eq. 17) and the drifting [`Ship`], whose position noise e dw₁, e dw₂
//! cannot be written in the form (7) and is dropped by the controller's
//! model (the velocity noise e dw₃, e dw₄ shares the control channel).

use super::ship::Ship;
use crate::{MAX_CONTROL, MAX_STATE};

/// Which coordinates are path variables of the sampler.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum PathStructure {
    /// Every state coordinate (Σ = GQQᵀGᵀ invertible).
    Full,
    /// x = (q, v), dq = v dt, noise and control in v only.
    SecondOrder,
}

/// A control-affine SDE whose noise enters through the control matrix G.
pub trait ControlAffine: Send + Sync {
    /// m.
    fn state_dim(&self) -> usize;
    /// p.
    fn control_dim(&self) -> usize;
    /// r, the number of columns of Q.
    fn noise_dim(&self) -> usize;
    /// Which coordinates the noise drives.
    fn structure(&self) -> PathStructure;
    /// f0(x) into `f` (length m).
    fn drift0(&self, x: &[f64], f: &mut [f64]);
    /// ∂f0/∂x, m×m column-major.
    fn drift0_jacobian(&self, x: &[f64], jac: &mut [f64]);
    /// The curvature Σ_k w_k ∇²f0_k(x) (m×m column-major) of w·f0, needed
    /// for the exact Hessian of the path functional.
    fn drift0_curvature(&self, x: &[f64], w: &[f64], out: &mut [f64]);
    /// G, m×p column-major.
    fn input_matrix(&self, g: &mut [f64]);
    /// Q, p×r column-major.
    fn noise_matrix(&self, q: &mut [f64]);
}

/// Why a model cannot be used for path-integral control.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum AffineError {
    #[error("dimensions: state {m} (max {MAX_STATE}), control {p} (max {MAX_CONTROL}), noise {r}")]
    Dimensions { m: usize, p: usize, r: usize },
    #[error("R must be symmetric positive definite")]
    ControlCost,
    #[error("condition (8) fails: G Q Qᵀ Gᵀ is not a multiple of G R⁻¹ Gᵀ (relative residual {residual:.3e}); path-integral control needs γ G R⁻¹ Gᵀ = G Q Qᵀ Gᵀ")]
    Condition8 { residual: f64 },
    #[error("the noise covariance on the path variables is singular; use PathStructure::SecondOrder for noise on velocities only")]
    SingularNoise,
    #[error("second-order structure needs m = 2p, G = [0; B] with B invertible and dq/dt = v")]
    NotSecondOrder,
}

/// Verify condition (8) for control cost R (p×p column-major) and return
/// γ, along with the structure's own requirements.
pub fn check_condition_8<M: ControlAffine + ?Sized>(
    model: &M,
    r: &[f64],
) -> Result<f64, AffineError> {
    let (m, p, nr) = (model.state_dim(), model.control_dim(), model.noise_dim());
    if m == 0 || m > MAX_STATE || p == 0 || p > MAX_CONTROL || nr == 0 || nr > MAX_STATE {
        return Err(AffineError::Dimensions { m, p, r: nr });
    }
    let rmat = nalgebra::DMatrix::from_column_slice(p, p, &r[..p * p]);
    if (&rmat - rmat.transpose()).norm() > 1e-12 * rmat.norm()
        || rmat.iter().any(|v| !v.is_finite())
    {
        return Err(AffineError::ControlCost);
    }
    let rinv = rmat.cholesky().ok_or(AffineError::ControlCost)?.inverse();
    let mut g = [0.0; MAX_STATE * MAX_CONTROL];
    let mut q = [0.0; MAX_CONTROL * MAX_STATE];
    model.input_matrix(&mut g[..m * p]);
    model.noise_matrix(&mut q[..p * nr]);
    let g = nalgebra::DMatrix::from_column_slice(m, p, &g[..m * p]);
    let q = nalgebra::DMatrix::from_column_slice(p, nr, &q[..p * nr]);
    let sigma = &g * &q * q.transpose() * g.transpose();
    let mr = &g * &rinv * g.transpose();
    let gamma = sigma.trace() / mr.trace();
    let residual = (&sigma - &mr * gamma).norm() / sigma.norm().max(1e-300);
    if !(gamma > 0.0) || !gamma.is_finite() || residual > 1e-9 {
        return Err(AffineError::Condition8 { residual });
    }
    match model.structure() {
        PathStructure::Full => {
            if sigma.clone().cholesky().is_none() {
                return Err(AffineError::SingularNoise);
            }
        }
        PathStructure::SecondOrder => {
            if m != 2 * p {
                return Err(AffineError::NotSecondOrder);
            }
            let top = g.view((0, 0), (p, p));
            let b = g.view((p, 0), (p, p)).into_owned();
            if top.norm() != 0.0 || b.determinant().abs() < 1e-12 {
                return Err(AffineError::NotSecondOrder);
            }
            // dq/dt = v at a few generic states.
            let mut f = [0.0; MAX_STATE];
            let mut x = [0.0; MAX_STATE];
            for k in 0..3 {
                for (i, xi) in x[..m].iter_mut().enumerate() {
                    *xi = 0.37 * (i as f64 + 1.0) * (k as f64 - 1.0) + 0.11 * i as f64;
                }
                model.drift0(&x[..m], &mut f[..m]);
                for i in 0..p {
                    if (f[i] - x[p + i]).abs() > 1e-12 * (1.0 + x[p + i].abs()) {
                        return Err(AffineError::NotSecondOrder);
                    }
                }
            }
        }
    }
    Ok(gamma)
}

/// dx = u dt + √σ dW in ℝᵈ (f0 = 0, G = I, Q = √σ I).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ControlledBrownian {
    pub dim: usize,
    /// Noise variance rate σ.
    pub sigma: f64,
}

impl ControlAffine for ControlledBrownian {
    fn state_dim(&self) -> usize {
        self.dim
    }
    fn control_dim(&self) -> usize {
        self.dim
    }
    fn noise_dim(&self) -> usize {
        self.dim
    }
    fn structure(&self) -> PathStructure {
        PathStructure::Full
    }
    fn drift0(&self, _x: &[f64], f: &mut [f64]) {
        f[..self.dim].fill(0.0);
    }
    fn drift0_jacobian(&self, _x: &[f64], jac: &mut [f64]) {
        jac[..self.dim * self.dim].fill(0.0);
    }
    fn drift0_curvature(&self, _x: &[f64], _w: &[f64], out: &mut [f64]) {
        out[..self.dim * self.dim].fill(0.0);
    }
    fn input_matrix(&self, g: &mut [f64]) {
        identity(self.dim, 1.0, g);
    }
    fn noise_matrix(&self, q: &mut [f64]) {
        identity(self.dim, self.sigma.sqrt(), q);
    }
}

fn identity(n: usize, s: f64, out: &mut [f64]) {
    out[..n * n].fill(0.0);
    for i in 0..n {
        out[i + i * n] = s;
    }
}

/// Linear drift f0 = A x with constant G and Q (column-major matrices).
#[derive(Clone, Debug, PartialEq)]
pub struct LinearAffine {
    pub m: usize,
    pub p: usize,
    pub r: usize,
    pub a: Vec<f64>,
    pub g: Vec<f64>,
    pub q: Vec<f64>,
    pub structure: PathStructure,
}

impl ControlAffine for LinearAffine {
    fn state_dim(&self) -> usize {
        self.m
    }
    fn control_dim(&self) -> usize {
        self.p
    }
    fn noise_dim(&self) -> usize {
        self.r
    }
    fn structure(&self) -> PathStructure {
        self.structure
    }
    fn drift0(&self, x: &[f64], f: &mut [f64]) {
        let m = self.m;
        for i in 0..m {
            f[i] = (0..m).map(|j| self.a[i + j * m] * x[j]).sum();
        }
    }
    fn drift0_jacobian(&self, _x: &[f64], jac: &mut [f64]) {
        jac[..self.m * self.m].copy_from_slice(&self.a);
    }
    fn drift0_curvature(&self, _x: &[f64], _w: &[f64], out: &mut [f64]) {
        out[..self.m * self.m].fill(0.0);
    }
    fn input_matrix(&self, g: &mut [f64]) {
        g[..self.m * self.p].copy_from_slice(&self.g);
    }
    fn noise_matrix(&self, q: &mut [f64]) {
        q[..self.p * self.r].copy_from_slice(&self.q);
    }
}

/// θ̈ = u + noise in ℝᵖ: x = (θ, θ̇), the feedback-linearised arm (eq. 17).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct DoubleIntegrator {
    pub p: usize,
    /// Noise variance rate σ on each velocity (Q = √σ I).
    pub sigma: f64,
}

impl ControlAffine for DoubleIntegrator {
    fn state_dim(&self) -> usize {
        2 * self.p
    }
    fn control_dim(&self) -> usize {
        self.p
    }
    fn noise_dim(&self) -> usize {
        self.p
    }
    fn structure(&self) -> PathStructure {
        PathStructure::SecondOrder
    }
    fn drift0(&self, x: &[f64], f: &mut [f64]) {
        let p = self.p;
        f[..p].copy_from_slice(&x[p..2 * p]);
        f[p..2 * p].fill(0.0);
    }
    fn drift0_jacobian(&self, _x: &[f64], jac: &mut [f64]) {
        let (p, m) = (self.p, 2 * self.p);
        jac[..m * m].fill(0.0);
        for i in 0..p {
            jac[i + (p + i) * m] = 1.0;
        }
    }
    fn drift0_curvature(&self, _x: &[f64], _w: &[f64], out: &mut [f64]) {
        out[..4 * self.p * self.p].fill(0.0);
    }
    fn input_matrix(&self, g: &mut [f64]) {
        let (p, m) = (self.p, 2 * self.p);
        g[..m * p].fill(0.0);
        for i in 0..p {
            g[p + i + i * m] = 1.0;
        }
    }
    fn noise_matrix(&self, q: &mut [f64]) {
        identity(self.p, self.sigma.sqrt(), q);
    }
}

impl Ship {
    /// ρ = ‖(x₁, x₂)‖ when the wall force acts (ρ ≥ R and moving outward).
    #[inline]
    fn wall_active(&self, x: &[f64]) -> Option<f64> {
        let rho2 = x[0] * x[0] + x[1] * x[1];
        let r = self.params.radius;
        (rho2 >= r * r && x[0] * x[2] + x[1] * x[3] >= 0.0).then(|| rho2.sqrt())
    }
}

/// The ship as the controller sees it: f0 = (v, wall(q, v)), G = [0; I₂],
/// Q = e I₂ (velocity noise only; the position noise is not of the form (7)
/// and is left out of the controller's model).
impl ControlAffine for Ship {
    fn state_dim(&self) -> usize {
        4
    }
    fn control_dim(&self) -> usize {
        2
    }
    fn noise_dim(&self) -> usize {
        2
    }
    fn structure(&self) -> PathStructure {
        PathStructure::SecondOrder
    }
    fn drift0(&self, x: &[f64], f: &mut [f64]) {
        f[0] = x[2];
        f[1] = x[3];
        f[2] = 0.0;
        f[3] = 0.0;
        // The wall force of `Ship::wall_force`, with ρ² compared first.
        if let Some(rho) = self.wall_active(x) {
            let k = -self.params.wall_gain / rho;
            f[2] = k * x[0];
            f[3] = k * x[1];
        }
    }
    fn drift0_jacobian(&self, x: &[f64], jac: &mut [f64]) {
        jac[..16].fill(0.0);
        jac[8] = 1.0; // ∂f1/∂x3
        jac[13] = 1.0; // ∂f2/∂x4
        if let Some(rho) = self.wall_active(x) {
            // ∂f_i/∂x_j = −K (δ_ij/ρ − x_i x_j/ρ³), i, j ∈ {1, 2}.
            let k = self.params.wall_gain;
            let r3 = rho * rho * rho;
            for i in 0..2 {
                for j in 0..2 {
                    let delta = if i == j { 1.0 } else { 0.0 };
                    jac[(i + 2) + j * 4] = -k * (delta / rho - x[i] * x[j] / r3);
                }
            }
        }
    }
    fn drift0_curvature(&self, x: &[f64], w: &[f64], out: &mut [f64]) {
        out[..16].fill(0.0);
        let Some(rho) = self.wall_active(x) else {
            return;
        };
        // a_i = −K q_i/ρ: ∂²a_i/∂q_j∂q_l = −K(−(δ_ij q_l + δ_il q_j + δ_jl q_i)/ρ³ + 3 q_i q_j q_l/ρ⁵).
        let k = self.params.wall_gain;
        let (r3, r5) = (rho.powi(3), rho.powi(5));
        let wq = w[2] * x[0] + w[3] * x[1];
        for j in 0..2 {
            for l in 0..2 {
                let delta = if j == l { 1.0 } else { 0.0 };
                let c = -(w[2 + j] * x[l] + w[2 + l] * x[j] + delta * wq) / r3
                    + 3.0 * wq * x[j] * x[l] / r5;
                out[j + l * 4] = -k * c;
            }
        }
    }
    fn input_matrix(&self, g: &mut [f64]) {
        g[..8].fill(0.0);
        g[2] = 1.0; // column 0: (0, 0, 1, 0)
        g[4 + 3] = 1.0; // column 1: (0, 0, 0, 1)
    }
    fn noise_matrix(&self, q: &mut [f64]) {
        identity(2, self.params.e, q);
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::model::ship::ShipParams;

    #[test]
    fn condition_8_gives_gamma_and_rejects_mismatch() {
        let ship = Ship::new(ShipParams::paper(0.01)).unwrap();
        // γ G R⁻¹ Gᵀ = e² G Gᵀ  ⇒  γ = r e².
        let g = check_condition_8(&ship, &[0.5, 0.0, 0.0, 0.5]).unwrap();
        assert!((g - 0.5 * 0.09).abs() < 1e-12);
        // Anisotropic R with isotropic noise violates (8).
        assert!(matches!(
            check_condition_8(&ship, &[0.5, 0.0, 0.0, 2.0]),
            Err(AffineError::Condition8 { .. })
        ));
        let slit = ControlledBrownian { dim: 1, sigma: 1.0 };
        assert!((check_condition_8(&slit, &[0.1]).unwrap() - 0.1).abs() < 1e-15);
        // A second-order model with noise on positions only is rejected.
        let bad = LinearAffine {
            m: 2,
            p: 1,
            r: 1,
            a: vec![0.0, 0.0, 1.0, 0.0],
            g: vec![1.0, 0.0],
            q: vec![1.0],
            structure: PathStructure::SecondOrder,
        };
        assert_eq!(
            check_condition_8(&bad, &[1.0]),
            Err(AffineError::NotSecondOrder)
        );
        let full_singular = LinearAffine {
            structure: PathStructure::Full,
            ..bad
        };
        assert_eq!(
            check_condition_8(&full_singular, &[1.0]),
            Err(AffineError::SingularNoise)
        );
    }

    #[test]
    fn ship_curvature_matches_finite_differences_of_the_jacobian() {
        let ship = Ship::new(ShipParams::paper(0.01)).unwrap();
        let x = [8.0, 5.0, 1.0, 0.5]; // outside the wall, moving out
        let w = [0.3, -0.2, 1.7, -0.9];
        let mut c = [0.0; 16];
        ship.drift0_curvature(&x, &w, &mut c);
        for l in 0..4 {
            let h = 1e-6;
            let (mut xp, mut xm) = (x, x);
            xp[l] += h;
            xm[l] -= h;
            let (mut jp, mut jm) = ([0.0; 16], [0.0; 16]);
            ship.drift0_jacobian(&xp, &mut jp);
            ship.drift0_jacobian(&xm, &mut jm);
            for j in 0..4 {
                // ∂/∂x_l of Σ_k w_k ∂f_k/∂x_j
                let fd: f64 = (0..4)
                    .map(|k| w[k] * (jp[k + j * 4] - jm[k + j * 4]) / (2.0 * h))
                    .sum();
                assert!(
                    (fd - c[j + l * 4]).abs() < 1e-6,
                    "({j},{l}): {fd} vs {}",
                    c[j + l * 4]
                );
            }
        }
        // drift0 and its Jacobian agree with the SdeModel ones at u = 0.
        use crate::model::{SdeJacobians, SdeModel};
        for x in [
            x,
            [1.0, 2.0, 0.3, 0.1],
            [-9.5, 0.5, -1.0, 0.0],
            [-9.5, 0.5, 1.0, 0.0],
        ] {
            let (mut f, mut f_ref) = ([0.0; 4], [0.0; 4]);
            ship.drift0(&x, &mut f);
            ship.drift(&x, &[0.0, 0.0], &mut f_ref);
            let (mut j, mut j_ref) = ([0.0; 16], [0.0; 16]);
            ship.drift0_jacobian(&x, &mut j);
            ship.drift_jacobian(&x, &[0.0, 0.0], &mut j_ref);
            for i in 0..4 {
                assert!((f[i] - f_ref[i]).abs() < 1e-12);
            }
            for i in 0..16 {
                assert!((j[i] - j_ref[i]).abs() < 1e-12);
            }
        }
    }
}
