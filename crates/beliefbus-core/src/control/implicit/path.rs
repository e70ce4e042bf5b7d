//! The path functional F of paper 003 eq. (15), with errata E2–E6, for a
//! control-affine model (see [`crate::model::affine`]):
//!
//! ```text
//! y₀ = x(t),  τ_i = t + iΔt,  r_i = P (y_i − y_{i−1} − f0(y_{i−1}) Δt)          (E5: f at i−1)
//! F(y₁..y_n) = Φ(y_n)/γ + Δt/(2γ) Σ_{i=1}^{n} [V(y_i) + V(y_{i−1})]              (E5: brackets)
//!            + ½ Σ_{i=1}^{n} r_iᵀ (Σ_b Δt)⁻¹ r_i
//! ψ(x, t) ≈ (2πΔt)^{−N/2} (det Σ_b)^{−n/2} J_z ∫ e^{−F} dz                     (E5/E6 normaliser)
//! ```
//!
//! Σ_b is the noise covariance on the noise-driven coordinates: Σ = GQQᵀGᵀ
//! for a [`PathStructure::Full`] model, BQQᵀBᵀ on the velocities of a
//! [`PathStructure::SecondOrder`] one (P selects those rows). The path
//! variables z are the noise-driven coordinates only:
//! - `Full`: z_i = y_i ∈ ℝᵐ, i = 1..n (N = mn, J_z = 1);
//! - `SecondOrder`: x = (q, v); with Euler, q_{i+1} = q_i + v_i Δt, so the
//!   velocities v₁..v_n are in one-to-one linear correspondence with the
//!   positions z_i = q_{i+1}, i = 1..n (N = pn). Using positions as variables
//!   keeps the Hessian banded (v_i = (q_{i+1} − q_i)/Δt is local) whereas
//!   positions as functions of velocities would make it dense; the constant
//!   Jacobian of the change of variables is J_z = Δt^{−N}.
//!
//! Every path point is an affine function of a few consecutive blocks of
//! the "extended" vector (prefix blocks fixed by x(t), then z), so the term
//! of step i couples (K+2) blocks and the Hessian has half-bandwidth
//! (K+2)·b − 1 (block-tridiagonal for `Full`, K = 0). Derivatives are
//! analytic: the model supplies ∂f0/∂x and the curvature Σ w_k ∇²f0_k, the
//! cost supplies ∇V, ∇²V, ∇Φ, ∇²Φ.
//!
//! The prefix gradient ∂F/∂x(t) (what [`PathFunctional::gradient_x`]
//! returns) is the x-derivative of F at fixed z, used for the analytic
//! control estimate (envelope theorem at μ).

use super::banded::SymBand;
use super::newton::Objective;
use crate::model::affine::{check_condition_8, AffineError, ControlAffine, PathStructure};
use crate::{MAX_CONTROL, MAX_STATE};

pub use crate::control::cost::DiagonalQuadraticCost;
pub use crate::model::path_cost::{Gate, PathCost, MAX_GATE_INTERVALS};

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
    roff: usize,
    pub structure: PathStructure,
    /// Path time step Δt.
    pub dt: f64,
    /// γ of condition (8).
    pub gamma: f64,
    /// (Σ_b Δt)⁻¹, b×b column-major.
    s: [f64; MAX_STATE * MAX_STATE],
    /// log det Σ_b.
    pub log_det_sigma_b: f64,
    /// R⁻¹ (p×p) and G (m×p), column-major.
    pub rinv: [f64; MAX_CONTROL * MAX_CONTROL],
    pub g: [f64; MAX_STATE * MAX_CONTROL],
    /// Soft control limit (see [`PathSetup::with_control_limit`]).
    limit: Option<ControlLimit>,
    /// The stencil (s_{i−1}, s_i) = D · (z_i, z_{i−1}, …, z_{i−K−1}) (2m × W)
    /// as its nonzeros (row, column, value).
    nz: [(u8, u8, f64); 3 * MAX_STATE],
    nnz: usize,
    w: usize,
}

/// A soft box limit on the controls a path implies.
#[derive(Clone, Copy, Debug, PartialEq)]
struct ControlLimit {
    u_max: f64,
    /// δ: width of the cubic blend (0: the C¹ kink max(0, e)²).
    blend: f64,
    /// κΔt/γ: F units per (excess control)² per step.
    weight: f64,
    /// B⁻¹ (b×b): the implied control of an increment r is B⁻¹r/Δt.
    binv: [f64; MAX_CONTROL * MAX_CONTROL],
}

/// Largest window (K+2)·b.
const MAX_W: usize = 2 * MAX_STATE;

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
        // Stencil D (2m × W, column-major, leading dimension 2m).
        let rows = 2 * m;
        let mut dmat = [0.0; 2 * MAX_STATE * MAX_W];
        let mut put = |row: usize, blk: usize, c: usize, v: f64| {
            dmat[row + (blk * b + c) * rows] = v;
        };
        match structure {
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
        for col in 0..setup.w {
            for row in 0..rows {
                let v = dmat[row + col * rows];
                if v != 0.0 {
                    setup.nz[setup.nnz] = (row as u8, col as u8, v);
                    setup.nnz += 1;
                }
            }
        }
        Ok(setup)
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
    fn limit_penalty(&self, r: &[f64], gr: &mut [f64], hr: Option<&mut [f64]>) -> f64 {
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

/// F for one initial state and horizon: an [`Objective`] over z.
pub struct PathFunctional<'a, M: ControlAffine + ?Sized, C: PathCost + ?Sized> {
    pub setup: &'a PathSetup,
    pub model: &'a M,
    pub cost: &'a C,
    /// Prefix blocks (from x(t)).
    prefix: [f64; 2 * MAX_STATE],
    /// Steps n.
    pub n: usize,
    /// Optional wall (double slit).
    pub gate: Option<Gate>,
}

/// Optional outputs of one derivative pass.
struct Outputs<'o> {
    g: Option<&'o mut [f64]>,
    h: Option<&'o mut SymBand>,
    ge: Option<&'o mut [f64]>,
    /// ∂²F/∂z∂e for the first K+1 variable blocks: ((K+1)b) × ((K+1)b),
    /// column-major with leading dimension (K+1)b.
    cross: Option<&'o mut [f64]>,
    exact: bool,
    /// Stop after this step (the prefix terms live in steps ≤ K+1).
    last_step: usize,
}

impl<'a, M: ControlAffine + ?Sized, C: PathCost + ?Sized> PathFunctional<'a, M, C> {
    /// F for initial state `x` and `n` steps.
    pub fn new(
        setup: &'a PathSetup,
        model: &'a M,
        cost: &'a C,
        x: &[f64],
        n: usize,
        gate: Option<Gate>,
    ) -> Self {
        let mut prefix = [0.0; 2 * MAX_STATE];
        setup.prefix_from_state(x, &mut prefix);
        Self {
            setup,
            model,
            cost,
            prefix,
            n,
            gate,
        }
    }

    /// Replace the initial state.
    pub fn set_state(&mut self, x: &[f64]) {
        self.setup.prefix_from_state(x, &mut self.prefix);
    }

    /// Replace the prefix directly (used for directional perturbations).
    pub fn set_prefix(&mut self, e: &[f64]) {
        let l = self.setup.prefix_len();
        self.prefix[..l].copy_from_slice(&e[..l]);
    }

    /// The prefix (K+1 blocks).
    pub fn prefix(&self) -> &[f64] {
        &self.prefix[..self.setup.prefix_len()]
    }

    #[inline]
    fn block<'z>(&'z self, z: &'z [f64], i: isize) -> &'z [f64] {
        let b = self.setup.b;
        let e = i + self.setup.k as isize; // index into the extended vector
        if e <= self.setup.k as isize {
            let e = e as usize;
            &self.prefix[e * b..(e + 1) * b]
        } else {
            let v = (i - 1) as usize;
            &z[v * b..(v + 1) * b]
        }
    }

    /// Path point s_i into `s`.
    #[inline]
    fn state(&self, z: &[f64], i: usize, s: &mut [f64]) {
        let st = self.setup;
        match st.structure {
            PathStructure::Full => s[..st.m].copy_from_slice(self.block(z, i as isize)),
            PathStructure::SecondOrder => {
                let p = st.p;
                let a = self.block(z, i as isize - 1);
                let c = self.block(z, i as isize);
                let inv = 1.0 / st.dt;
                for j in 0..p {
                    s[j] = a[j];
                    s[p + j] = (c[j] - a[j]) * inv;
                }
            }
        }
    }

    fn gate_ok(&self, i: usize, s: &[f64]) -> bool {
        match self.gate {
            Some(g) if g.step == i => g.interval_of(s[g.coord]).is_some(),
            _ => true,
        }
    }

    /// Path point at step i of z (public for diagnostics and plotting).
    pub fn path_point(&self, z: &[f64], i: usize, s: &mut [f64]) {
        self.state(z, i, s);
    }

    /// ∂F/∂x(t) at fixed z (length m), and F.
    pub fn gradient_x(&self, z: &[f64], gx: &mut [f64]) -> f64 {
        let mut ge = [0.0; 2 * MAX_STATE];
        let f = self.pass(
            z,
            Outputs {
                g: None,
                h: None,
                ge: Some(&mut ge),
                cross: None,
                exact: true,
                last_step: usize::MAX,
            },
        );
        self.setup.state_gradient(&ge, gx);
        f
    }

    /// F, ∇_z F into `g` and the prefix gradient ∂F/∂e into `ge`.
    pub fn gradient_with_prefix(&self, z: &[f64], g: &mut [f64], ge: &mut [f64]) -> f64 {
        self.pass(
            z,
            Outputs {
                g: Some(g),
                h: None,
                ge: Some(ge),
                cross: None,
                exact: true,
                last_step: usize::MAX,
            },
        )
    }

    /// Everything at once (the final Newton iterate): F, ∇_z F, ∇²_z F,
    /// ∂F/∂e and the mixed block ∂²F/∂z∂e.
    pub fn full_derivatives(
        &self,
        z: &[f64],
        g: &mut [f64],
        h: &mut SymBand,
        ge: &mut [f64],
        cross: &mut [f64],
    ) -> f64 {
        self.pass(
            z,
            Outputs {
                g: Some(g),
                h: Some(h),
                ge: Some(ge),
                cross: Some(cross),
                exact: true,
                last_step: usize::MAX,
            },
        )
    }

    /// Only the prefix gradient ∂F/∂e (O(1): the first K+1 steps); the
    /// likelihood-ratio control estimate needs nothing else per sample.
    pub fn prefix_gradient(&self, z: &[f64], ge: &mut [f64]) {
        self.pass(
            z,
            Outputs {
                g: None,
                h: None,
                ge: Some(ge),
                cross: None,
                exact: true,
                last_step: self.setup.k + 1,
            },
        );
    }

    /// Only the prefix derivatives ∂F/∂e and ∂²F/∂z∂e (O(1): just the
    /// first K+1 steps touch the prefix).
    pub fn prefix_derivatives(&self, z: &[f64], ge: &mut [f64], cross: &mut [f64]) {
        self.pass(
            z,
            Outputs {
                g: None,
                h: None,
                ge: Some(ge),
                cross: Some(cross),
                exact: true,
                last_step: self.setup.k + 1,
            },
        );
    }

    /// The derivative pass: accumulate each step's term in (s_{i−1}, s_i)
    /// coordinates, then map to the window of z blocks through the stencil.
    fn pass(&self, z: &[f64], mut out: Outputs) -> f64 {
        let st = self.setup;
        let (m, b, dt, roff) = (st.m, st.b, st.dt, st.roff);
        let n = self.n;
        let m2 = 2 * m;
        let w = st.w;
        let kk = st.k as isize;
        let hw = dt / (2.0 * st.gamma);
        let inv_gamma = 1.0 / st.gamma;
        let need_h = out.h.is_some() || out.cross.is_some();
        if let Some(g) = out.g.as_deref_mut() {
            g[..n * b].fill(0.0);
        }
        if let Some(ge) = out.ge.as_deref_mut() {
            ge[..st.prefix_len()].fill(0.0);
        }
        if let Some(c) = out.cross.as_deref_mut() {
            let l = st.prefix_len();
            c[..l * l].fill(0.0);
        }
        let mut s_prev = [0.0; MAX_STATE];
        let mut s = [0.0; MAX_STATE];
        let mut f_prev = [0.0; MAX_STATE];
        let mut jf = [0.0; MAX_STATE * MAX_STATE];
        let mut vg = [0.0; MAX_STATE];
        let mut vh = [0.0; MAX_STATE * MAX_STATE];
        let mut curv = [0.0; MAX_STATE * MAX_STATE];
        let mut gs = [0.0; 2 * MAX_STATE];
        let mut hs = [0.0; 4 * MAX_STATE * MAX_STATE];
        let mut gw = [0.0; MAX_W];
        let mut hwin = [0.0; MAX_W * MAX_W];
        let mut r = [0.0; MAX_STATE];
        let mut sr = [0.0; MAX_STATE];
        let mut a = [0.0; MAX_STATE * MAX_STATE]; // P (I + J_f Δt), b×m
                                                  // Per-step scratch, hoisted (zeroing them every step showed in profiles).
        let mut hr = [0.0; MAX_STATE * MAX_STATE];
        let mut sa = [0.0; MAX_STATE * MAX_STATE];
        let mut wv = [0.0; MAX_STATE];
        let mut hsd = [0.0; 2 * MAX_STATE * MAX_W]; // Hs D, m2 × w
        let mut total = 0.0;

        self.state(z, 0, &mut s_prev);
        self.model.drift0(&s_prev[..m], &mut f_prev[..m]);
        self.model.drift0_jacobian(&s_prev[..m], &mut jf[..m * m]);
        for i in 1..=n.min(out.last_step) {
            self.state(z, i, &mut s);
            gs[..m2].fill(0.0);
            if need_h {
                hs[..m2 * m2].fill(0.0);
            }
            // Action ½ rᵀ S r, r = P(s − s_prev − f0(s_prev)Δt).
            for c in 0..b {
                r[c] = s[roff + c] - s_prev[roff + c] - f_prev[roff + c] * dt;
            }
            let mut act = 0.0;
            for c in 0..b {
                let mut v = 0.0;
                for d in 0..b {
                    v += st.s[c + d * b] * r[d];
                }
                sr[c] = v;
                act += 0.5 * r[c] * v;
            }
            total += act;
            // The action and the control-limit penalty both depend on s only
            // through r: sr = ∂/∂r, hr = ∂²/∂r².
            hr[..b * b].copy_from_slice(&st.s[..b * b]);
            total += st.limit_penalty(&r[..b], &mut sr[..b], need_h.then_some(&mut hr[..b * b]));
            // A = P (I + J_f Δt): rows roff..roff+b.
            for col in 0..m {
                for c in 0..b {
                    let row = roff + c;
                    a[c + col * b] = jf[row + col * m] * dt + if row == col { 1.0 } else { 0.0 };
                }
            }
            // gradient: s_prev part −Aᵀ S r, s part Pᵀ S r.
            for col in 0..m {
                let mut v = 0.0;
                for c in 0..b {
                    v += a[c + col * b] * sr[c];
                }
                gs[col] -= v;
            }
            for c in 0..b {
                gs[m + roff + c] += sr[c];
            }
            if need_h {
                // (prev, prev) += Aᵀ S A; (prev, cur) −= Aᵀ S P; (cur, cur) += Pᵀ S P.
                // sa = S A (b×m), then (prev, prev) += Aᵀ sa.
                for c2 in 0..m {
                    for d1 in 0..b {
                        let mut v = 0.0;
                        for d2 in 0..b {
                            v += hr[d1 + d2 * b] * a[d2 + c2 * b];
                        }
                        sa[d1 + c2 * b] = v;
                    }
                }
                for c1 in 0..m {
                    for c2 in 0..m {
                        let mut v = 0.0;
                        for d1 in 0..b {
                            v += a[d1 + c1 * b] * sa[d1 + c2 * b];
                        }
                        hs[c1 + c2 * m2] += v;
                    }
                    for d2 in 0..b {
                        // (Aᵀ H_r)[c1, d2] = (H_r A)[d2, c1] (H_r symmetric); (prev c1, cur roff+d2).
                        let v = sa[d2 + c1 * b];
                        hs[c1 + (m + roff + d2) * m2] -= v;
                        hs[(m + roff + d2) + c1 * m2] -= v;
                    }
                }
                for d1 in 0..b {
                    for d2 in 0..b {
                        hs[(m + roff + d1) + (m + roff + d2) * m2] += hr[d1 + d2 * b];
                    }
                }
                if out.exact {
                    // Σ_l (Sr)_l ∇²r_l = curvature of f0 at s_prev with w = −Δt Pᵀ S r.
                    wv[..m].fill(0.0);
                    for c in 0..b {
                        wv[roff + c] = -dt * sr[c];
                    }
                    self.model
                        .drift0_curvature(&s_prev[..m], &wv[..m], &mut curv[..m * m]);
                    for c1 in 0..m {
                        for c2 in 0..m {
                            hs[c1 + c2 * m2] += curv[c1 + c2 * m];
                        }
                    }
                }
            }
            // Trapezoidal potential: weight Δt/γ on interior points, Δt/(2γ) on ends.
            let wc = if i < n { 2.0 * hw } else { hw };
            let v = self
                .cost
                .running_derivatives(&s[..m], &mut vg[..m], &mut vh[..m * m]);
            total += wc * v;
            for c in 0..m {
                gs[m + c] += wc * vg[c];
            }
            if need_h {
                for c1 in 0..m {
                    for c2 in 0..m {
                        hs[(m + c1) + (m + c2) * m2] += wc * vh[c1 + c2 * m];
                    }
                }
            }
            if i == 1 {
                let v0 =
                    self.cost
                        .running_derivatives(&s_prev[..m], &mut vg[..m], &mut vh[..m * m]);
                total += hw * v0;
                for c in 0..m {
                    gs[c] += hw * vg[c];
                }
                if need_h {
                    for c1 in 0..m {
                        for c2 in 0..m {
                            hs[c1 + c2 * m2] += hw * vh[c1 + c2 * m];
                        }
                    }
                }
            }
            if i == n {
                let phi = self
                    .cost
                    .terminal_derivatives(&s[..m], &mut vg[..m], &mut vh[..m * m]);
                total += inv_gamma * phi;
                for c in 0..m {
                    gs[m + c] += inv_gamma * vg[c];
                }
                if need_h {
                    for c1 in 0..m {
                        for c2 in 0..m {
                            hs[(m + c1) + (m + c2) * m2] += inv_gamma * vh[c1 + c2 * m];
                        }
                    }
                }
            }
            // Map to the window through the sparse stencil: gw = Dᵀ gs,
            // Hw = Dᵀ Hs D (D has ≤ 3m nonzeros).
            let nz = &st.nz[..st.nnz];
            gw[..w].fill(0.0);
            for &(r, c, v) in nz {
                gw[c as usize] += v * gs[r as usize];
            }
            if need_h {
                // Two stages, each a run of contiguous axpys: T = Hs D
                // (column c of T += v · column r of Hs), then Hw = Dᵀ T.
                hsd[..m2 * w].fill(0.0);
                for &(r, c, v) in nz {
                    let src = &hs[r as usize * m2..(r as usize + 1) * m2];
                    let dst = &mut hsd[c as usize * m2..(c as usize + 1) * m2];
                    for (d, x) in dst.iter_mut().zip(src) {
                        *d += v * x;
                    }
                }
                hwin[..w * w].fill(0.0);
                for c2 in 0..w {
                    let tcol = &hsd[c2 * m2..(c2 + 1) * m2];
                    let hcol = &mut hwin[c2 * w..(c2 + 1) * w];
                    for &(r, c, v) in nz {
                        hcol[c as usize] += v * tcol[r as usize];
                    }
                }
            }
            // Scatter: window block jb ↔ z_{i−jb}; variable if i − jb ≥ 1.
            for jb in 0..(st.k + 2) {
                let zi = i as isize - jb as isize;
                for c in 0..b {
                    let j = jb * b + c;
                    if zi >= 1 {
                        if let Some(g) = out.g.as_deref_mut() {
                            g[(zi as usize - 1) * b + c] += gw[j];
                        }
                    } else if let Some(ge) = out.ge.as_deref_mut() {
                        ge[(zi + kk) as usize * b + c] += gw[j];
                    }
                }
            }
            if need_h {
                let lp = st.prefix_len();
                for jb1 in 0..(st.k + 2) {
                    let z1 = i as isize - jb1 as isize;
                    if z1 < 1 {
                        continue;
                    }
                    for jb2 in 0..(st.k + 2) {
                        let z2 = i as isize - jb2 as isize;
                        for c1 in 0..b {
                            let row = (z1 as usize - 1) * b + c1;
                            for c2 in 0..b {
                                let v = hwin[(jb1 * b + c1) + (jb2 * b + c2) * w];
                                if z2 >= 1 {
                                    let col = (z2 as usize - 1) * b + c2;
                                    if col <= row {
                                        if let Some(h) = out.h.as_deref_mut() {
                                            h.add(row, col, v);
                                        }
                                    }
                                } else if let Some(cr) = out.cross.as_deref_mut() {
                                    let col = (z2 + kk) as usize * b + c2;
                                    if row < lp {
                                        cr[row + col * lp] += v;
                                    }
                                }
                            }
                        }
                    }
                }
            }
            if i < n {
                self.model.drift0(&s[..m], &mut f_prev[..m]);
                self.model.drift0_jacobian(&s[..m], &mut jf[..m * m]);
            }
            s_prev[..m].copy_from_slice(&s[..m]);
        }
        total
    }
}

impl<M: ControlAffine + ?Sized, C: PathCost + ?Sized> Objective for PathFunctional<'_, M, C> {
    fn dim(&self) -> usize {
        self.setup.dim(self.n)
    }

    fn bandwidth(&self) -> usize {
        self.setup.bandwidth()
    }

    /// Only a gate makes F infinite; the derivative pass reports F otherwise.
    fn has_barrier(&self) -> bool {
        self.gate.is_some()
    }

    fn value(&self, z: &[f64]) -> f64 {
        let st = self.setup;
        let (m, b, dt, roff) = (st.m, st.b, st.dt, st.roff);
        let n = self.n;
        let hw = dt / (2.0 * st.gamma);
        let mut s_prev = [0.0; MAX_STATE];
        let mut s = [0.0; MAX_STATE];
        let mut f_prev = [0.0; MAX_STATE];
        let mut r = [0.0; MAX_STATE];
        self.state(z, 0, &mut s_prev);
        self.model.drift0(&s_prev[..m], &mut f_prev[..m]);
        let mut total = hw * self.cost.running(&s_prev[..m]);
        for i in 1..=n {
            self.state(z, i, &mut s);
            for c in 0..b {
                r[c] = s[roff + c] - s_prev[roff + c] - f_prev[roff + c] * dt;
            }
            let mut act = 0.0;
            for c in 0..b {
                let mut v = 0.0;
                for d in 0..b {
                    v += st.s[c + d * b] * r[d];
                }
                act += r[c] * v;
            }
            total += 0.5 * act;
            if st.limit.is_some() {
                let mut scratch = [0.0; MAX_STATE];
                total += st.limit_penalty(&r[..b], &mut scratch[..b], None);
            }
            let wc = if i < n { 2.0 * hw } else { hw };
            total += wc * self.cost.running(&s[..m]);
            if !self.gate_ok(i, &s) {
                return f64::INFINITY;
            }
            if i < n {
                self.model.drift0(&s[..m], &mut f_prev[..m]);
            }
            s_prev[..m].copy_from_slice(&s[..m]);
        }
        total + self.cost.terminal(&s_prev[..m]) / st.gamma
    }

    fn derivatives(&self, z: &[f64], g: &mut [f64], h: &mut SymBand) -> f64 {
        self.pass(
            z,
            Outputs {
                g: Some(g),
                h: Some(h),
                ge: None,
                cross: None,
                exact: true,
                last_step: usize::MAX,
            },
        )
    }

    fn gradient(&self, z: &[f64], g: &mut [f64]) -> f64 {
        self.pass(
            z,
            Outputs {
                g: Some(g),
                h: None,
                ge: None,
                cross: None,
                exact: true,
                last_step: usize::MAX,
            },
        )
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::model::affine::{ControlledBrownian, DoubleIntegrator, LinearAffine};
    use crate::model::ship::{Ship, ShipParams};

    /// Pendulum with damping: a nonlinear Full-structure model.
    struct Pendulum;
    impl ControlAffine for Pendulum {
        fn state_dim(&self) -> usize {
            2
        }
        fn control_dim(&self) -> usize {
            2
        }
        fn noise_dim(&self) -> usize {
            2
        }
        fn structure(&self) -> PathStructure {
            PathStructure::Full
        }
        fn drift0(&self, x: &[f64], f: &mut [f64]) {
            f[0] = x[1];
            f[1] = -x[0].sin() - 0.1 * x[1] + 0.2 * x[0] * x[1];
        }
        fn drift0_jacobian(&self, x: &[f64], j: &mut [f64]) {
            j[0] = 0.0;
            j[1] = -x[0].cos() + 0.2 * x[1];
            j[2] = 1.0;
            j[3] = -0.1 + 0.2 * x[0];
        }
        fn drift0_curvature(&self, x: &[f64], w: &[f64], out: &mut [f64]) {
            out[0] = w[1] * x[0].sin();
            out[1] = w[1] * 0.2;
            out[2] = w[1] * 0.2;
            out[3] = 0.0;
        }
        fn input_matrix(&self, g: &mut [f64]) {
            g[..4].copy_from_slice(&[1.0, 0.3, 0.0, 1.0]);
        }
        fn noise_matrix(&self, q: &mut [f64]) {
            q[..4].copy_from_slice(&[0.5, 0.0, 0.0, 0.5]);
        }
    }

    /// A non-quadratic cost: V = Σ c_i x_i⁴/4 + ½|x − g|², Φ = cosh-like.
    struct Quartic;
    impl PathCost for Quartic {
        fn running(&self, x: &[f64]) -> f64 {
            x.iter()
                .enumerate()
                .map(|(i, v)| 0.1 * (i as f64 + 1.0) * v.powi(4) / 4.0 + 0.5 * (v - 0.3).powi(2))
                .sum()
        }
        fn running_derivatives(&self, x: &[f64], g: &mut [f64], h: &mut [f64]) -> f64 {
            let d = x.len();
            h[..d * d].fill(0.0);
            for i in 0..d {
                let c = 0.1 * (i as f64 + 1.0);
                g[i] = c * x[i].powi(3) + (x[i] - 0.3);
                h[i + i * d] = 3.0 * c * x[i] * x[i] + 1.0;
            }
            self.running(x)
        }
        fn terminal(&self, x: &[f64]) -> f64 {
            x.iter()
                .map(|v| (v - 1.0).powi(2) + 0.2 * v.powi(4))
                .sum::<f64>()
                + 0.5 * x[0] * x[x.len() - 1]
        }
        fn terminal_derivatives(&self, x: &[f64], g: &mut [f64], h: &mut [f64]) -> f64 {
            let d = x.len();
            h[..d * d].fill(0.0);
            for i in 0..d {
                g[i] = 2.0 * (x[i] - 1.0) + 0.8 * x[i].powi(3);
                h[i + i * d] = 2.0 + 2.4 * x[i] * x[i];
            }
            g[0] += 0.5 * x[d - 1];
            g[d - 1] += 0.5 * x[0];
            h[(d - 1) * d] += 0.5;
            h[d - 1] += 0.5;
            self.terminal(x)
        }
    }

    /// Acceptance test: analytic gradient, banded Hessian, prefix gradient and
    /// mixed derivatives of F match central finite differences.
    fn check<M: ControlAffine, C: PathCost>(
        model: &M,
        cost: &C,
        r: &[f64],
        dt: f64,
        x: &[f64],
        n: usize,
        z: &[f64],
        limit: Option<(f64, f64)>,
    ) {
        // The C¹ kink (δ = 0), a blend narrower than most excesses, and one
        // wide enough that the cubic branch carries them.
        if limit.is_some() {
            for blend in [0.0, 0.5, 5.0] {
                check_blend(model, cost, r, dt, x, n, z, limit, blend);
            }
        } else {
            check_blend(model, cost, r, dt, x, n, z, None, 0.0);
        }
    }

    #[allow(clippy::too_many_arguments)]
    fn check_blend<M: ControlAffine, C: PathCost>(
        model: &M,
        cost: &C,
        r: &[f64],
        dt: f64,
        x: &[f64],
        n: usize,
        z: &[f64],
        limit: Option<(f64, f64)>,
        blend: f64,
    ) {
        let mut setup = PathSetup::new(model, r, dt).unwrap();
        let plain = setup.clone();
        if let Some((u_max, kappa)) = limit {
            setup = setup.with_control_limit(u_max, kappa, blend).unwrap();
        }
        let f = PathFunctional::new(&setup, model, cost, x, n, None);
        if limit.is_some() {
            // The penalty is active somewhere along z (else the check is moot).
            let f0 = PathFunctional::new(&plain, model, cost, x, n, None).value(z);
            assert!(
                f.value(z) > f0 + 1e-3,
                "limit inactive: {} vs {f0}",
                f.value(z)
            );
        }
        let nn = f.dim();
        assert_eq!(z.len(), nn);
        let kd = f.bandwidth();
        let mut g = vec![0.0; nn];
        let mut h = SymBand::new(nn, kd);
        let lp = setup.prefix_len();
        let mut ge = vec![0.0; lp];
        let mut cross = vec![0.0; lp * lp];
        let fz = f.full_derivatives(z, &mut g, &mut h, &mut ge, &mut cross);
        assert!((fz - f.value(z)).abs() < 1e-10 * fz.abs().max(1.0));
        let scale = |v: f64| 1e-5 * (1.0 + v.abs());
        let e = 1e-5;
        let mut zp = z.to_vec();
        let mut gp = vec![0.0; nn];
        let mut gm = vec![0.0; nn];
        let mut hh = SymBand::new(nn, kd);
        for j in 0..nn {
            zp[j] = z[j] + e;
            let fp = f.value(&zp);
            hh.resize(nn);
            f.derivatives(&zp, &mut gp, &mut hh);
            zp[j] = z[j] - e;
            let fm = f.value(&zp);
            hh.resize(nn);
            f.derivatives(&zp, &mut gm, &mut hh);
            zp[j] = z[j];
            let fd = (fp - fm) / (2.0 * e);
            assert!(
                (fd - g[j]).abs() < scale(g[j]) * 10.0,
                "grad {j}: fd {fd} vs {}",
                g[j]
            );
            for i in 0..nn {
                let fdh = (gp[i] - gm[i]) / (2.0 * e);
                let an = h.get(i, j);
                assert!(
                    (fdh - an).abs() < scale(an) * 10.0,
                    "hess ({i},{j}): fd {fdh} vs {an}"
                );
                if i.abs_diff(j) > kd {
                    assert!(fdh.abs() < 1e-6, "outside the band ({i},{j}): {fdh}");
                }
            }
        }
        // Prefix gradient and ∂²F/∂z∂e.
        let mut fe = PathFunctional::new(&setup, model, cost, x, n, None);
        let e0: Vec<f64> = f.prefix().to_vec();
        for c in 0..lp {
            let mut ep = e0.clone();
            ep[c] += e;
            fe.set_prefix(&ep);
            let fp = fe.value(z);
            let mut gep = vec![0.0; lp];
            fe.gradient_with_prefix(z, &mut gp, &mut gep);
            ep[c] -= 2.0 * e;
            fe.set_prefix(&ep);
            let fm = fe.value(z);
            fe.gradient_with_prefix(z, &mut gm, &mut gep);
            let fd = (fp - fm) / (2.0 * e);
            assert!(
                (fd - ge[c]).abs() < 10.0 * scale(ge[c]),
                "prefix grad {c}: {fd} vs {}",
                ge[c]
            );
            for row in 0..lp.min(nn) {
                let fdc = (gp[row] - gm[row]) / (2.0 * e);
                let an = cross[row + c * lp];
                assert!(
                    (fdc - an).abs() < 10.0 * scale(an),
                    "cross ({row},{c}): {fdc} vs {an}"
                );
            }
            for row in lp..nn {
                assert!(
                    ((gp[row] - gm[row]) / (2.0 * e)).abs() < 1e-5,
                    "cross beyond the first blocks"
                );
            }
        }
        // The O(1) prefix pass agrees with the full pass.
        let (mut ge2, mut cross2) = (vec![0.0; lp], vec![0.0; lp * lp]);
        f.prefix_derivatives(z, &mut ge2, &mut cross2);
        for i in 0..lp {
            assert!((ge2[i] - ge[i]).abs() < 1e-12 * (1.0 + ge[i].abs()));
        }
        for i in 0..lp * lp {
            assert!((cross2[i] - cross[i]).abs() < 1e-12 * (1.0 + cross[i].abs()));
        }
        // ∂F/∂x.
        let m = setup.m;
        let mut gx = vec![0.0; m];
        f.gradient_x(z, &mut gx);
        for c in 0..m {
            let mut xp = x.to_vec();
            xp[c] += e;
            let fp = PathFunctional::new(&setup, model, cost, &xp, n, None).value(z);
            xp[c] -= 2.0 * e;
            let fm = PathFunctional::new(&setup, model, cost, &xp, n, None).value(z);
            let fd = (fp - fm) / (2.0 * e);
            assert!(
                (fd - gx[c]).abs() < 10.0 * scale(gx[c]),
                "∂F/∂x_{c}: {fd} vs {}",
                gx[c]
            );
        }
    }

    fn wiggle(nn: usize, amp: f64, base: &[f64]) -> Vec<f64> {
        (0..nn)
            .map(|i| base[i % base.len()] + amp * ((i as f64) * 0.77).sin())
            .collect()
    }

    #[test]
    fn derivatives_match_finite_differences_full_structure() {
        let n = 6;
        let z = wiggle(2 * n, 0.4, &[0.2, -0.5]);
        let r = [4.0, 0.0, 0.0, 4.0];
        check(&Pendulum, &Quartic, &r, 0.1, &[0.3, -0.2], n, &z, None);
        // With the soft control limit active on most steps.
        check(
            &Pendulum,
            &Quartic,
            &r,
            0.1,
            &[0.3, -0.2],
            n,
            &z,
            Some((0.7, 5.0)),
        );
        let slit = ControlledBrownian { dim: 1, sigma: 1.0 };
        let z = wiggle(5, 0.5, &[0.7]);
        check(&slit, &Quartic, &[0.1], 0.02, &[1.0], 5, &z, None);
        check(
            &slit,
            &Quartic,
            &[0.1],
            0.02,
            &[1.0],
            5,
            &z,
            Some((3.0, 2.0)),
        );
    }

    #[test]
    fn derivatives_match_finite_differences_second_order() {
        // The ship outside its wall, moving outward (wall force active).
        let ship = Ship::new(ShipParams::paper(0.01)).unwrap();
        let n = 5;
        let x = [8.0, 5.0, 1.0, 0.5];
        // Positions continuing outward so the wall stays active along the path.
        let z: Vec<f64> = (0..n)
            .flat_map(|i| {
                let t = (i + 2) as f64 * 0.1;
                [8.0 + 1.0 * t + 0.01 * (i as f64).sin(), 5.0 + 0.5 * t]
            })
            .collect();
        let r = [0.5, 0.0, 0.0, 0.5];
        check(&ship, &Quartic, &r, 0.1, &x, n, &z, None);
        check(&ship, &Quartic, &r, 0.1, &x, n, &z, Some((3.0, 10.0)));
        let di = DoubleIntegrator { p: 2, sigma: 1.0 };
        let z = wiggle(2 * n, 0.3, &[0.1, -0.2]);
        let r = [0.01, 0.0, 0.0, 0.01];
        let x = [0.1, 0.2, -0.3, 0.4];
        check(&di, &Quartic, &r, 0.05, &x, n, &z, None);
        check(&di, &Quartic, &r, 0.05, &x, n, &z, Some((20.0, 1.0)));
    }

    #[test]
    fn linear_model_with_quadratic_cost_has_constant_hessian() {
        let model = LinearAffine {
            m: 2,
            p: 1,
            r: 1,
            a: vec![0.0, -1.0, 1.0, -0.5],
            g: vec![0.0, 1.0],
            q: vec![0.7],
            structure: PathStructure::SecondOrder,
        };
        let setup = PathSetup::new(&model, &[2.0], 0.05).unwrap();
        assert!((setup.gamma - 2.0 * 0.49).abs() < 1e-12);
        let cost = DiagonalQuadraticCost::new(&[1.0, 0.1], &[5.0, 1.0]);
        let f = PathFunctional::new(&setup, &model, &cost, &[0.5, -0.2], 8, None);
        let (mut g, mut h1, mut h2) = (
            vec![0.0; 8],
            SymBand::new(8, setup.bandwidth()),
            SymBand::new(8, setup.bandwidth()),
        );
        f.derivatives(&[0.0; 8], &mut g, &mut h1);
        f.derivatives(&wiggle(8, 2.0, &[1.0]), &mut g, &mut h2);
        for i in 0..8 {
            for j in 0..8 {
                assert!((h1.get(i, j) - h2.get(i, j)).abs() < 1e-9);
            }
        }
    }
}
