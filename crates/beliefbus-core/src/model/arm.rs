//! The two-link planar arm of paper 003 §3.2 (Slotine & Li's model, Table 3):
//!
//! ```text
//! M(θ) θ̈ + C(θ, θ̇) θ̇ = τ
//! M = [a₁ + 2a₃cos θ₂, a₂ + a₃cos θ₂; a₂ + a₃cos θ₂, a₂]
//! C = [−a₃ sin θ₂ θ̇₂, −a₃ sin θ₂ (θ̇₁ + θ̇₂); a₃ sin θ₂ θ̇₁, 0]
//! a₁ = m₁l_c1² + m₂(l₁² + l_c2²) + I₁ + I₂,  a₂ = m₂l_c2² + I₂,  a₃ = m₂ l₁ l_c2
//! ```
//!
//! Erratum E13: the paper prints a₁ with m₂l_c1² and M₁₁ = a₁ + a₃cos θ₂ and
//! the control law τ = C + Mu; the standard model above is used (its Ṁ − 2C
//! is skew-symmetric, so the unforced arm conserves kinetic energy — tested).
//! The inverse-dynamics law τ = C(θ,θ̇)θ̇ + M(θ)u turns the arm into the
//! double integrator θ̈ = u (eq. 17) when the model is exact.

/// Parameters of Table 3 (SI units).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ArmParams {
    pub l1: f64,
    pub lc1: f64,
    pub lc2: f64,
    pub m1: f64,
    pub m2: f64,
    pub i1: f64,
    pub i2: f64,
}

impl ArmParams {
    /// Table 3.
    pub fn table3() -> Self {
        Self {
            l1: 1.0,
            lc1: 0.5,
            lc2: 0.5,
            m1: 1.0,
            m2: 1.0,
            i1: 2.0,
            i2: 2.0,
        }
    }

    /// (a₁, a₂, a₃).
    pub fn coefficients(&self) -> (f64, f64, f64) {
        let a1 = self.m1 * self.lc1 * self.lc1
            + self.m2 * (self.l1 * self.l1 + self.lc2 * self.lc2)
            + self.i1
            + self.i2;
        let a2 = self.m2 * self.lc2 * self.lc2 + self.i2;
        let a3 = self.m2 * self.l1 * self.lc2;
        (a1, a2, a3)
    }

    /// M(θ), row-major.
    pub fn mass(&self, theta: [f64; 2]) -> [[f64; 2]; 2] {
        let (a1, a2, a3) = self.coefficients();
        let c2 = theta[1].cos();
        [[a1 + 2.0 * a3 * c2, a2 + a3 * c2], [a2 + a3 * c2, a2]]
    }

    /// C(θ, θ̇), row-major.
    pub fn coriolis(&self, theta: [f64; 2], dtheta: [f64; 2]) -> [[f64; 2]; 2] {
        let (_, _, a3) = self.coefficients();
        let s2 = theta[1].sin();
        [
            [-a3 * s2 * dtheta[1], -a3 * s2 * (dtheta[0] + dtheta[1])],
            [a3 * s2 * dtheta[0], 0.0],
        ]
    }

    /// Inverse dynamics τ = C θ̇ + M u.
    pub fn torque(&self, theta: [f64; 2], dtheta: [f64; 2], u: [f64; 2]) -> [f64; 2] {
        let m = self.mass(theta);
        let c = self.coriolis(theta, dtheta);
        [
            c[0][0] * dtheta[0] + c[0][1] * dtheta[1] + m[0][0] * u[0] + m[0][1] * u[1],
            c[1][0] * dtheta[0] + c[1][1] * dtheta[1] + m[1][0] * u[0] + m[1][1] * u[1],
        ]
    }

    /// Forward dynamics θ̈ = M⁻¹(τ − C θ̇).
    pub fn acceleration(&self, theta: [f64; 2], dtheta: [f64; 2], tau: [f64; 2]) -> [f64; 2] {
        let m = self.mass(theta);
        let c = self.coriolis(theta, dtheta);
        let r0 = tau[0] - c[0][0] * dtheta[0] - c[0][1] * dtheta[1];
        let r1 = tau[1] - c[1][0] * dtheta[0] - c[1][1] * dtheta[1];
        let det = m[0][0] * m[1][1] - m[0][1] * m[1][0];
        [
            (m[1][1] * r0 - m[0][1] * r1) / det,
            (-m[1][0] * r0 + m[0][0] * r1) / det,
        ]
    }

    /// One RK4 step of length dt under constant torque; state (θ₁, θ₂, θ̇₁, θ̇₂).
    pub fn rk4_step(&self, x: [f64; 4], tau: [f64; 2], dt: f64) -> [f64; 4] {
        let f = |s: [f64; 4]| {
            let a = self.acceleration([s[0], s[1]], [s[2], s[3]], tau);
            [s[2], s[3], a[0], a[1]]
        };
        let add = |s: [f64; 4], k: [f64; 4], h: f64| {
            [
                s[0] + h * k[0],
                s[1] + h * k[1],
                s[2] + h * k[2],
                s[3] + h * k[3],
            ]
        };
        let k1 = f(x);
        let k2 = f(add(x, k1, dt / 2.0));
        let k3 = f(add(x, k2, dt / 2.0));
        let k4 = f(add(x, k3, dt));
        let mut out = x;
        for i in 0..4 {
            out[i] += dt / 6.0 * (k1[i] + 2.0 * k2[i] + 2.0 * k3[i] + k4[i]);
        }
        out
    }

    /// Kinetic energy ½ θ̇ᵀ M θ̇.
    pub fn kinetic_energy(&self, x: [f64; 4]) -> f64 {
        let m = self.mass([x[0], x[1]]);
        0.5 * (m[0][0] * x[2] * x[2] + 2.0 * m[0][1] * x[2] * x[3] + m[1][1] * x[3] * x[3])
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn inverse_dynamics_linearises_the_exact_arm() {
        let p = ArmParams::table3();
        let (th, dth, u) = ([0.4, -1.1], [0.7, 1.3], [-2.0, 0.5]);
        let tau = p.torque(th, dth, u);
        let a = p.acceleration(th, dth, tau);
        assert!((a[0] - u[0]).abs() < 1e-12 && (a[1] - u[1]).abs() < 1e-12);
    }

    /// Relative kinetic-energy drift of the unforced arm over 2 s (RK4,
    /// 1 ms) for a given mass matrix M(θ₂) and the model's C.
    fn energy_drift(p: &ArmParams, mass: impl Fn(f64) -> [[f64; 2]; 2]) -> f64 {
        let energy = |s: [f64; 4]| {
            let m = mass(s[1]);
            0.5 * (m[0][0] * s[2] * s[2] + 2.0 * m[0][1] * s[2] * s[3] + m[1][1] * s[3] * s[3])
        };
        let f = |s: [f64; 4]| {
            let m = mass(s[1]);
            let c = p.coriolis([s[0], s[1]], [s[2], s[3]]);
            let r0 = -c[0][0] * s[2] - c[0][1] * s[3];
            let r1 = -c[1][0] * s[2] - c[1][1] * s[3];
            let det = m[0][0] * m[1][1] - m[0][1] * m[1][0];
            [
                s[2],
                s[3],
                (m[1][1] * r0 - m[0][1] * r1) / det,
                (-m[1][0] * r0 + m[0][0] * r1) / det,
            ]
        };
        let mut x = [0.3, 1.0, 2.0, -3.0];
        let e0 = energy(x);
        let h = 1e-3;
        for _ in 0..2000 {
            let add = |s: [f64; 4], k: [f64; 4], a: f64| {
                [
                    s[0] + a * k[0],
                    s[1] + a * k[1],
                    s[2] + a * k[2],
                    s[3] + a * k[3],
                ]
            };
            let k1 = f(x);
            let k2 = f(add(x, k1, h / 2.0));
            let k3 = f(add(x, k2, h / 2.0));
            let k4 = f(add(x, k3, h));
            for i in 0..4 {
                x[i] += h / 6.0 * (k1[i] + 2.0 * k2[i] + 2.0 * k3[i] + k4[i]);
            }
        }
        (energy(x) - e0).abs() / e0
    }

    /// With τ = 0 the arm conserves kinetic energy (Ṁ − 2C skew-symmetric);
    /// the printed M₁₁ = a₁ + a₃cos θ₂ (E13) breaks this.
    #[test]
    fn unforced_arm_conserves_energy() {
        let p = ArmParams::table3();
        let (a1, a2, a3) = p.coefficients();
        assert!(energy_drift(&p, |t2| p.mass([0.0, t2])) < 1e-9);
        let printed = |t2: f64| {
            let c2 = t2.cos();
            [[a1 + a3 * c2, a2 + a3 * c2], [a2 + a3 * c2, a2]]
        };
        assert!(energy_drift(&p, printed) > 1e-3);
        // The model's own RK4 step agrees.
        let mut x = [0.3, 1.0, 2.0, -3.0];
        let e0 = p.kinetic_energy(x);
        for _ in 0..100 {
            x = p.rk4_step(x, [0.0, 0.0], 1e-3);
        }
        assert!((p.kinetic_energy(x) - e0).abs() < 1e-9 * e0);
    }
}
