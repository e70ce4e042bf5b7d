//! Linear-Gaussian SDE, the model on which every approximate filter and
//! controller is checked against an exact answer (Kalman, Kalman–Bucy,
//! Riccati):
//!
//! ```text
//! dx = (A x + B u) dt + F dw,     y_k = C x_k + v_k,  v_k ~ N(0, diag(σ²))
//! ```
//!
//! [`LinearSde::discretize`] gives the exact transition over Δ for a control
//! held constant (Van Loan 1978):
//! `x_{k+1} = A_d x_k + B_d u + q`, `q ~ N(0, Q_d)`, with
//! `A_d = e^{AΔ}`, `B_d = ∫₀^Δ e^{As} ds B`, `Q_d = ∫₀^Δ e^{As} F Fᵀ e^{Aᵀs} ds`.

use super::{Bounds, Dims, SdeJacobians, SdeModel};
use nalgebra::DMatrix;

/// A linear-Gaussian SDE with a bounding box for chain construction.
#[derive(Clone, Debug)]
pub struct LinearSde {
    pub a: DMatrix<f64>,
    pub b: DMatrix<f64>,
    pub f: DMatrix<f64>,
    pub c: DMatrix<f64>,
    pub obs_std: Vec<f64>,
    bounds: Bounds,
    name: String,
}

/// Exact discrete-time transition of a [`LinearSde`] over one step.
#[derive(Clone, Debug)]
pub struct Discretized {
    pub ad: DMatrix<f64>,
    pub bd: DMatrix<f64>,
    pub qd: DMatrix<f64>,
}

impl LinearSde {
    /// Build from matrices (A d×d, B d×c, F d×k, C m×d) and per-component
    /// observation σ. Panics on inconsistent shapes (a programming error).
    pub fn new(
        name: &str,
        a: DMatrix<f64>,
        b: DMatrix<f64>,
        f: DMatrix<f64>,
        c: DMatrix<f64>,
        obs_std: Vec<f64>,
        bounds: Bounds,
    ) -> Self {
        let d = a.nrows();
        assert_eq!(a.ncols(), d, "A must be square");
        assert_eq!(b.nrows(), d, "B must have d rows");
        assert_eq!(f.nrows(), d, "F must have d rows");
        assert_eq!(c.ncols(), d, "C must have d columns");
        assert_eq!(c.nrows(), obs_std.len(), "one σ per observation");
        assert_eq!(bounds.dim(), d, "bounds dimension");
        Self {
            a,
            b,
            f,
            c,
            obs_std,
            bounds,
            name: name.to_string(),
        }
    }

    /// Exact discretisation over `dt` (Van Loan's block matrix exponentials).
    pub fn discretize(&self, dt: f64) -> Discretized {
        let d = self.a.nrows();
        let c = self.b.ncols();
        // exp([[-A, FFᵀ], [0, Aᵀ]] Δ) = [[·, A_d⁻¹ Q_d], [0, A_dᵀ]]
        let mut m = DMatrix::zeros(2 * d, 2 * d);
        m.view_mut((0, 0), (d, d)).copy_from(&(-&self.a * dt));
        m.view_mut((0, d), (d, d))
            .copy_from(&(&self.f * self.f.transpose() * dt));
        m.view_mut((d, d), (d, d))
            .copy_from(&(self.a.transpose() * dt));
        let e = m.exp();
        let ad = e.view((d, d), (d, d)).transpose();
        let qd = &ad * e.view((0, d), (d, d));
        let qd = (&qd + qd.transpose()) * 0.5;
        // exp([[A, B], [0, 0]] Δ) = [[A_d, B_d], [0, I]]
        let mut n = DMatrix::zeros(d + c, d + c);
        n.view_mut((0, 0), (d, d)).copy_from(&(&self.a * dt));
        n.view_mut((0, d), (d, c)).copy_from(&(&self.b * dt));
        let en = n.exp();
        let bd = en.view((0, d), (d, c)).into_owned();
        Discretized { ad, bd, qd }
    }
}

impl SdeModel for LinearSde {
    fn name(&self) -> &str {
        &self.name
    }
    fn dims(&self) -> Dims {
        Dims {
            state: self.a.nrows(),
            noise: self.f.ncols(),
            obs: self.c.nrows(),
            control: self.b.ncols(),
        }
    }
    fn drift(&self, x: &[f64], u: &[f64], out: &mut [f64]) {
        let d = self.a.nrows();
        for i in 0..d {
            let mut s = 0.0;
            for j in 0..d {
                s += self.a[(i, j)] * x[j];
            }
            for (j, uj) in u.iter().enumerate().take(self.b.ncols()) {
                s += self.b[(i, j)] * uj;
            }
            out[i] = s;
        }
    }
    fn diffusion(&self, _x: &[f64], big_f: &mut [f64]) {
        big_f[..self.f.len()].copy_from_slice(self.f.as_slice());
    }
    fn obs_mean(&self, x: &[f64], g: &mut [f64]) {
        for i in 0..self.c.nrows() {
            g[i] = (0..self.c.ncols()).map(|j| self.c[(i, j)] * x[j]).sum();
        }
    }
    fn obs_std(&self, std: &mut [f64]) {
        std[..self.obs_std.len()].copy_from_slice(&self.obs_std);
    }
    fn bounds(&self) -> &Bounds {
        &self.bounds
    }
}

impl SdeJacobians for LinearSde {
    fn drift_jacobian(&self, _x: &[f64], _u: &[f64], jac: &mut [f64]) {
        jac[..self.a.len()].copy_from_slice(self.a.as_slice());
    }
    fn obs_jacobian(&self, _x: &[f64], jac: &mut [f64]) {
        jac[..self.c.len()].copy_from_slice(self.c.as_slice());
    }
}

/// The scalar Ornstein–Uhlenbeck process dx = −a x dt + s dw observed as
/// y = x + σ v, on the box [−half_width, half_width].
pub fn ou_1d(a: f64, s: f64, obs_std: f64, half_width: f64) -> LinearSde {
    LinearSde::new(
        "ou1",
        DMatrix::from_element(1, 1, -a),
        DMatrix::zeros(1, 0),
        DMatrix::from_element(1, 1, s),
        DMatrix::from_element(1, 1, 1.0),
        vec![obs_std],
        Bounds::new_box(&[-half_width], &[half_width]).expect("valid box"),
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn scalar_ou_discretisation_is_exact() {
        let (a, s, dt) = (1.5, 0.4, 0.2);
        let d = ou_1d(a, s, 0.1, 5.0).discretize(dt);
        let ad = (-a * dt).exp();
        let qd = s * s * (1.0 - (-2.0 * a * dt).exp()) / (2.0 * a);
        assert!((d.ad[(0, 0)] - ad).abs() < 1e-12);
        assert!((d.qd[(0, 0)] - qd).abs() < 1e-12);
    }

    #[test]
    fn double_integrator_discretisation_is_exact() {
        // x = (p, v): dp = v dt, dv = u dt + s dw.
        let s = 0.5;
        let m = LinearSde::new(
            "di",
            DMatrix::from_row_slice(2, 2, &[0.0, 1.0, 0.0, 0.0]),
            DMatrix::from_row_slice(2, 1, &[0.0, 1.0]),
            DMatrix::from_row_slice(2, 1, &[0.0, s]),
            DMatrix::from_row_slice(1, 2, &[1.0, 0.0]),
            vec![0.1],
            Bounds::new_box(&[-10.0, -10.0], &[10.0, 10.0]).unwrap(),
        );
        let dt = 0.3;
        let d = m.discretize(dt);
        let q = s * s;
        let expect_q = [
            q * dt.powi(3) / 3.0,
            q * dt * dt / 2.0,
            q * dt * dt / 2.0,
            q * dt,
        ];
        for (got, want) in d.qd.as_slice().iter().zip(expect_q) {
            assert!((got - want).abs() < 1e-12, "{got} vs {want}");
        }
        assert!((d.bd[(0, 0)] - dt * dt / 2.0).abs() < 1e-12);
        assert!((d.bd[(1, 0)] - dt).abs() < 1e-12);
        assert!((d.ad[(0, 1)] - dt).abs() < 1e-12);
    }
}
