//! The constants of a path problem: [`PathSetup`] (dimensions, γ, noise
//! precision, stencil, optional control limit) and the initial path.

use crate::model::affine::{check_condition_8, AffineError, ControlAffine, PathStructure};
use crate::model::path_cost::Gate;
use crate::{MAX_CONTROL, MAX_STATE};

/// Constants of a path problem: dimensions, γ, the noise precision and the
/// stencil mapping blocks of z to path points. Built once per controller.
#[derive(Clone, Debug)]
pub struct PathSetup {
    /// State dimension m.
    pub m: usize,
    /// Control dimension p.
    pub p: usize,
    /// Block size b of z (m for Full, p for SecondOrder).
    pub b: usize,
    /// Stencil depth K (0 Full, 1 SecondOrder); K+1 prefix blocks.
    pub k: usize,
    /// First residual row (0 Full, p SecondOrder).
    pub(super) roff: usize,
    pub structure: PathStructure,
    /// Path time step Δt.
    pub dt: f64,
    /// γ of condition (8).
    pub gamma: f64,
    /// (Σ_b Δt)⁻¹, b×b column-major.
    pub(super) s: [f64; MAX_STATE * MAX_STATE],
    /// log det Σ_b.
    pub log_det_sigma_b: f64,
    /// R⁻¹ (p×p) and G (m×p), column-major.
    pub rinv: [f64; MAX_CONTROL * MAX_CONTROL],
    pub g: [f64; MAX_STATE * MAX_CONTROL],
    /// Soft control limit (see [`PathSetup::with_control_limit`]).
    pub(super) limit: Option<ControlLimit>,
    /// The stencil (s_{i−1}, s_i) = D · (z_i, z_{i−1}, …, z_{i−K−1}) (2m × W)
    /// as its nonzeros (row, column, value).
    pub(super) nz: [(u8, u8, f64); 3 * MAX_STATE],
    pub(super) nnz: usize,
    pub(super) w: usize,
}

/// A soft box limit on the controls a path implies.
#[derive(Clone, Copy, Debug, PartialEq)]
pub(super) struct ControlLimit {
    u_max: f64,
    /// δ: width of the cubic blend (0: the C¹ kink max(0, e)²).
    blend: f64,
    /// κΔt/γ: F units per (excess control)² per step.
    weight: f64,
    /// B⁻¹ (b×b): the implied control of an increment r is B⁻¹r/Δt.
    binv: [f64; MAX_CONTROL * MAX_CONTROL],
}

/// Largest window (K+2)·b.
pub(super) const MAX_W: usize = 2 * MAX_STATE;

impl PathSetup {
    /// Check condition (8) for control cost R (p×p column-major) and build
    /// the constants for path step `dt`.
    pub fn new<M: ControlAffine + ?Sized>(
        model: &M,
        r: &[f64],
        dt: f64,
    ) -> Result<Self, AffineError> {
        let gamma = check_condition_8(model, r)?;
        let (m, p) = (model.state_dim(), model.control_dim());
        let structure = model.structure();
        let (b, k, roff) = match structure {
            PathStructure::Full => (m, 0, 0),
            PathStructure::SecondOrder => (p, 1, p),
        };
        let nr = model.noise_dim();
        let mut gbuf = [0.0; MAX_STATE * MAX_CONTROL];
        let mut qbuf = [0.0; MAX_CONTROL * MAX_STATE];
        model.input_matrix(&mut gbuf[..m * p]);
        model.noise_matrix(&mut qbuf[..p * nr]);
        let g = nalgebra::DMatrix::from_column_slice(m, p, &gbuf[..m * p]);
        let q = nalgebra::DMatrix::from_column_slice(p, nr, &qbuf[..p * nr]);
        let sigma = &g * &q * q.transpose() * g.transpose();
        let sigma_b = sigma.view((roff, roff), (b, b)).into_owned();
        let chol = sigma_b
            .clone()
            .cholesky()
            .ok_or(AffineError::SingularNoise)?;
        let log_det_sigma_b = 2.0 * chol.l().diagonal().iter().map(|v| v.ln()).sum::<f64>();
        let sinv = chol.inverse() / dt;
        let rinv = nalgebra::DMatrix::from_column_slice(p, p, &r[..p * p])
            .cholesky()
            .ok_or(AffineError::ControlCost)?
            .inverse();
        let mut setup = Self {
            m,
            p,
            b,
            k,
            roff,
            structure,
            dt,
            gamma,
            s: [0.0; MAX_STATE * MAX_STATE],
            log_det_sigma_b,
            rinv: [0.0; MAX_CONTROL * MAX_CONTROL],
            g: gbuf,
            limit: None,
            nz: [(0, 0, 0.0); 3 * MAX_STATE],
            nnz: 0,
            w: (k + 2) * b,
        };
        setup.s[..b * b].copy_from_slice(sinv.as_slice());
        setup.rinv[..p * p].copy_from_slice(rinv.as_slice());
        setup.build_stencil();
        Ok(setup)
    }

    /// The stencil (s_{i−1}, s_i) = D · (z_i, …, z_{i−K−1}): D (2m × W,
    /// column-major, leading dimension 2m) kept as its nonzeros.
    fn build_stencil(&mut self) {
        let (m, p, b, dt) = (self.m, self.p, self.b, self.dt);
        let rows = 2 * m;
        let mut dmat = [0.0; 2 * MAX_STATE * MAX_W];
        let mut put = |row: usize, blk: usize, c: usize, v: f64| {
            dmat[row + (blk * b + c) * rows] = v;
        };
        match self.structure {
            PathStructure::Full => {
                for c in 0..m {
                    put(c, 1, c, 1.0); // s_{i−1} = z_{i−1}
                    put(m + c, 0, c, 1.0); // s_i = z_i
                }
            }
            PathStructure::SecondOrder => {
                for c in 0..p {
                    // s_i = (z_{i−1}, (z_i − z_{i−1})/Δt)
                    put(m + c, 1, c, 1.0);
                    put(m + p + c, 0, c, 1.0 / dt);
                    put(m + p + c, 1, c, -1.0 / dt);
                    // s_{i−1} = (z_{i−2}, (z_{i−1} − z_{i−2})/Δt)
                    put(c, 2, c, 1.0);
                    put(p + c, 1, c, 1.0 / dt);
                    put(p + c, 2, c, -1.0 / dt);
                }
            }
        }
        for col in 0..self.w {
            for row in 0..rows {
                let v = dmat[row + col * rows];
                if v != 0.0 {
                    self.nz[self.nnz] = (row as u8, col as u8, v);
                    self.nnz += 1;
                }
            }
        }
    }

    /// Add a soft box limit |u_c| ≤ u_max on the controls implied by the
    /// path increments, u_i = B⁻¹ r_i/Δt (B = G on the noise-driven rows):
    /// F gains Σ_i (κΔt/γ) Σ_c φ_δ(|u_{i,c}| − u_max), a running cost
    /// κ·φ_δ(excess) per unit time, with the C² quadratic–cubic blend
    ///
    ///   φ_δ(e) = 0 (e ≤ 0),  e³/(3δ) (0 < e ≤ δ),  e² − δe + δ²/3 (e > δ)
    ///
    /// (φ' = e²/δ then 2e − δ; φ'' = 2e/δ then 2). δ = 0 gives the C¹
    /// max(0, e)², whose Hessian jumps where a control reaches the limit:
    /// Newton then cycles between active sets; the blend lets the Hessian
    /// grow continuously. This is not in paper 003 (which has no limits):
    /// it approximates the input-constrained value function, whose optimal
    /// control is the clamp of −R⁻¹Gᵀ∂ₓJ for diagonal R, so the plan stops
    /// assuming forces the actuator cannot give. κ = 0 leaves F as in
    /// eq. (15). Needs b = p (B square and invertible).
    pub fn with_control_limit(
        mut self,
        u_max: f64,
        kappa: f64,
        blend: f64,
    ) -> Result<Self, AffineError> {
        if kappa <= 0.0 {
            self.limit = None;
            return Ok(self);
        }
        if self.b != self.p || !(u_max > 0.0) || !(blend >= 0.0 && blend.is_finite()) {
            return Err(AffineError::ControlCost);
        }
        let (m, b, roff) = (self.m, self.b, self.roff);
        let bm = nalgebra::DMatrix::from_fn(b, b, |i, j| self.g[roff + i + j * m]);
        let binv = bm.try_inverse().ok_or(AffineError::ControlCost)?;
        let mut l = ControlLimit {
            u_max,
            blend,
            weight: kappa * self.dt / self.gamma,
            binv: [0.0; MAX_CONTROL * MAX_CONTROL],
        };
        l.binv[..b * b].copy_from_slice(binv.as_slice());
        self.limit = Some(l);
        Ok(self)
    }

    /// Penalty of the increment r, its gradient (added to `gr`) and Hessian
    /// (added to `hr`, b×b) with respect to r.
    #[inline]
    pub(super) fn limit_penalty(&self, r: &[f64], gr: &mut [f64], hr: Option<&mut [f64]>) -> f64 {
        let Some(l) = self.limit else {
            return 0.0;
        };
        let b = self.b;
        let inv_dt = 1.0 / self.dt;
        let mut pen = 0.0;
        let mut hr = hr;
        for c in 0..b {
            let mut w = 0.0;
            for d in 0..b {
                w += l.binv[c + d * b] * r[d];
            }
            w *= inv_dt;
            let ex = w.abs() - l.u_max;
            if ex > 0.0 {
                // φ_δ(ex), φ', φ''.
                let (phi, d1, d2) = if ex < l.blend {
                    (
                        ex * ex * ex / (3.0 * l.blend),
                        ex * ex / l.blend,
                        2.0 * ex / l.blend,
                    )
                } else {
                    (
                        ex * ex - l.blend * ex + l.blend * l.blend / 3.0,
                        2.0 * ex - l.blend,
                        2.0,
                    )
                };
                pen += l.weight * phi;
                // ∂/∂r_d = κ' φ' sign(w) B⁻¹_{cd}/Δt; ∂²/∂r_d∂r_e = κ' φ'' B⁻¹_{cd}B⁻¹_{ce}/Δt².
                let gw = l.weight * d1 * w.signum() * inv_dt;
                for d in 0..b {
                    gr[d] += gw * l.binv[c + d * b];
                }
                if let Some(h) = hr.as_deref_mut() {
                    let hw = l.weight * d2 * inv_dt * inv_dt;
                    for d in 0..b {
                        for e in 0..b {
                            h[d + e * b] += hw * l.binv[c + d * b] * l.binv[c + e * b];
                        }
                    }
                }
            }
        }
        pen
    }

    /// Half-bandwidth of the Hessian: (K+2)·b − 1.
    pub fn bandwidth(&self) -> usize {
        self.w - 1
    }

    /// Number of path variables N for n steps.
    pub fn dim(&self, n: usize) -> usize {
        n * self.b
    }

    /// Length of the prefix (K+1 blocks).
    pub fn prefix_len(&self) -> usize {
        (self.k + 1) * self.b
    }

    /// The x-independent constant of log ψ for n steps:
    /// −(N/2) log Δt − (n/2) log det Σ_b + log J_z.
    pub fn log_psi_constant(&self, n: usize) -> f64 {
        let nn = self.dim(n) as f64;
        let jz = match self.structure {
            PathStructure::Full => 0.0,
            PathStructure::SecondOrder => -nn * self.dt.ln(),
        };
        -0.5 * nn * self.dt.ln() - 0.5 * n as f64 * self.log_det_sigma_b + jz
    }

    /// The prefix blocks fixed by the initial state x.
    pub fn prefix_from_state(&self, x: &[f64], prefix: &mut [f64]) {
        match self.structure {
            PathStructure::Full => prefix[..self.m].copy_from_slice(&x[..self.m]),
            PathStructure::SecondOrder => {
                let p = self.p;
                for c in 0..p {
                    prefix[c] = x[c];
                    prefix[p + c] = x[c] + x[p + c] * self.dt;
                }
            }
        }
    }

    /// δe = M_x δx: the prefix change caused by a state change δx.
    pub fn prefix_direction(&self, dx: &[f64], de: &mut [f64]) {
        self.prefix_from_state(dx, de);
    }

    /// ∂F/∂x from the prefix gradient: Mₓᵀ g_e.
    pub fn state_gradient(&self, ge: &[f64], gx: &mut [f64]) {
        match self.structure {
            PathStructure::Full => gx[..self.m].copy_from_slice(&ge[..self.m]),
            PathStructure::SecondOrder => {
                let p = self.p;
                for c in 0..p {
                    gx[c] = ge[c] + ge[p + c];
                    gx[p + c] = self.dt * ge[p + c];
                }
            }
        }
    }

    /// Index of the path variable holding coordinate `coord` of the path
    /// point at step `step` (Full structure only).
    pub fn gate_variable(&self, gate: &Gate) -> Option<usize> {
        match self.structure {
            PathStructure::Full if gate.step >= 1 && gate.coord < self.m => {
                Some((gate.step - 1) * self.m + gate.coord)
            }
            _ => None,
        }
    }

    /// Initial guess for n steps from state x: the uncontrolled Euler path.
    pub fn initial_path<M: ControlAffine + ?Sized>(
        &self,
        model: &M,
        x: &[f64],
        n: usize,
        z: &mut [f64],
    ) {
        let m = self.m;
        let mut s = [0.0; MAX_STATE];
        let mut f = [0.0; MAX_STATE];
        s[..m].copy_from_slice(&x[..m]);
        let mut q_next = [0.0; MAX_STATE];
        for i in 0..n {
            model.drift0(&s[..m], &mut f[..m]);
            for c in 0..m {
                s[c] += f[c] * self.dt;
            }
            match self.structure {
                PathStructure::Full => z[i * m..(i + 1) * m].copy_from_slice(&s[..m]),
                PathStructure::SecondOrder => {
                    // z_i = q_{i+1} = q_i + v_i Δt with s = (q_i, v_i) after this step.
                    let p = self.p;
                    for c in 0..p {
                        q_next[c] = s[c] + s[p + c] * self.dt;
                    }
                    z[i * p..(i + 1) * p].copy_from_slice(&q_next[..p]);
                }
            }
        }
    }
}
