//! The derivative pass of F (eq. 15): for each step i the term in the
//! local coordinates (s_{i−1}, s_i) — the action ½ rᵀSr with the control
//! limit, the trapezoidal potential V and the terminal Φ — with its
//! gradient gs and Hessian Hs, then mapped to the window of z blocks
//! through the stencil D (gw = Dᵀgs, Hw = DᵀHsD) and scattered into the
//! requested outputs (∇_z F, banded ∇²_z F, ∂F/∂e, ∂²F/∂z∂e).

use super::functional::{Outputs, PathFunctional};
use super::setup::MAX_W;
use crate::model::affine::ControlAffine;
use crate::model::path_cost::PathCost;
use crate::MAX_STATE;

/// Scratch of one pass, on the stack and hoisted out of the step loop
/// (zeroing the per-step buffers every step showed in profiles).
struct Scratch {
    s_prev: [f64; MAX_STATE],
    s: [f64; MAX_STATE],
    f_prev: [f64; MAX_STATE],
    /// ∂f0/∂x at s_prev (m×m).
    jf: [f64; MAX_STATE * MAX_STATE],
    /// ∇V or ∇Φ and ∇²V or ∇²Φ of the cost term being added.
    vg: [f64; MAX_STATE],
    vh: [f64; MAX_STATE * MAX_STATE],
    curv: [f64; MAX_STATE * MAX_STATE],
    /// Gradient and Hessian of the step's term in (s_{i−1}, s_i) (2m, 2m×2m).
    gs: [f64; 2 * MAX_STATE],
    hs: [f64; 4 * MAX_STATE * MAX_STATE],
    /// The same in window coordinates (W, W×W).
    gw: [f64; MAX_W],
    hwin: [f64; MAX_W * MAX_W],
    /// Residual r, S r (∂/∂r of action and limit) and ∂²/∂r².
    r: [f64; MAX_STATE],
    sr: [f64; MAX_STATE],
    hr: [f64; MAX_STATE * MAX_STATE],
    /// A = P (I + J_f Δt), b×m, and S A.
    a: [f64; MAX_STATE * MAX_STATE],
    sa: [f64; MAX_STATE * MAX_STATE],
    wv: [f64; MAX_STATE],
    /// Hs D, 2m × W.
    hsd: [f64; 2 * MAX_STATE * MAX_W],
}

impl Scratch {
    fn new() -> Self {
        Self {
            s_prev: [0.0; MAX_STATE],
            s: [0.0; MAX_STATE],
            f_prev: [0.0; MAX_STATE],
            jf: [0.0; MAX_STATE * MAX_STATE],
            vg: [0.0; MAX_STATE],
            vh: [0.0; MAX_STATE * MAX_STATE],
            curv: [0.0; MAX_STATE * MAX_STATE],
            gs: [0.0; 2 * MAX_STATE],
            hs: [0.0; 4 * MAX_STATE * MAX_STATE],
            gw: [0.0; MAX_W],
            hwin: [0.0; MAX_W * MAX_W],
            r: [0.0; MAX_STATE],
            sr: [0.0; MAX_STATE],
            hr: [0.0; MAX_STATE * MAX_STATE],
            a: [0.0; MAX_STATE * MAX_STATE],
            sa: [0.0; MAX_STATE * MAX_STATE],
            wv: [0.0; MAX_STATE],
            hsd: [0.0; 2 * MAX_STATE * MAX_W],
        }
    }
}

impl<M: ControlAffine + ?Sized, C: PathCost + ?Sized> PathFunctional<'_, M, C> {
    /// The derivative pass: accumulate each step's term in (s_{i−1}, s_i)
    /// coordinates, then map to the window of z blocks through the stencil.
    pub(super) fn pass(&self, z: &[f64], mut out: Outputs) -> f64 {
        let st = self.setup;
        let (m, n) = (st.m, self.n);
        let need_h = out.h.is_some() || out.cross.is_some();
        if let Some(g) = out.g.as_deref_mut() {
            g[..n * st.b].fill(0.0);
        }
        if let Some(ge) = out.ge.as_deref_mut() {
            ge[..st.prefix_len()].fill(0.0);
        }
        if let Some(c) = out.cross.as_deref_mut() {
            let l = st.prefix_len();
            c[..l * l].fill(0.0);
        }
        let mut sc = Scratch::new();
        let mut total = 0.0;
        self.state(z, 0, &mut sc.s_prev);
        self.model.drift0(&sc.s_prev[..m], &mut sc.f_prev[..m]);
        self.model
            .drift0_jacobian(&sc.s_prev[..m], &mut sc.jf[..m * m]);
        for i in 1..=n.min(out.last_step) {
            self.state(z, i, &mut sc.s);
            sc.gs[..2 * m].fill(0.0);
            if need_h {
                sc.hs[..4 * m * m].fill(0.0);
            }
            self.action_step(&mut sc, need_h, &mut total);
            if need_h {
                self.action_hessian(&mut sc, out.exact);
            }
            self.potential_step(&mut sc, i, need_h, &mut total);
            self.to_window(&mut sc, need_h);
            self.scatter(&sc, i, &mut out, need_h);
            if i < n {
                self.model.drift0(&sc.s[..m], &mut sc.f_prev[..m]);
                self.model.drift0_jacobian(&sc.s[..m], &mut sc.jf[..m * m]);
            }
            sc.s_prev[..m].copy_from_slice(&sc.s[..m]);
        }
        total
    }

    /// The action ½ rᵀ S r, r = P(s − s_prev − f0(s_prev)Δt), plus the
    /// control-limit penalty; their gradient into gs (s_prev part −Aᵀ S r,
    /// s part Pᵀ S r) and, in `hr`, their Hessian in r. Adds the value to
    /// `total` term by term (the pass's summation order).
    #[inline]
    fn action_step(&self, sc: &mut Scratch, need_h: bool, total: &mut f64) {
        let st = self.setup;
        let (m, b, dt, roff) = (st.m, st.b, st.dt, st.roff);
        for c in 0..b {
            sc.r[c] = sc.s[roff + c] - sc.s_prev[roff + c] - sc.f_prev[roff + c] * dt;
        }
        let mut act = 0.0;
        for c in 0..b {
            let mut v = 0.0;
            for d in 0..b {
                v += st.s[c + d * b] * sc.r[d];
            }
            sc.sr[c] = v;
            act += 0.5 * sc.r[c] * v;
        }
        *total += act;
        // The action and the control-limit penalty both depend on s only
        // through r: sr = ∂/∂r, hr = ∂²/∂r².
        sc.hr[..b * b].copy_from_slice(&st.s[..b * b]);
        *total += st.limit_penalty(
            &sc.r[..b],
            &mut sc.sr[..b],
            need_h.then_some(&mut sc.hr[..b * b]),
        );
        // A = P (I + J_f Δt): rows roff..roff+b.
        for col in 0..m {
            for c in 0..b {
                let row = roff + c;
                sc.a[c + col * b] = sc.jf[row + col * m] * dt + if row == col { 1.0 } else { 0.0 };
            }
        }
        for col in 0..m {
            let mut v = 0.0;
            for c in 0..b {
                v += sc.a[c + col * b] * sc.sr[c];
            }
            sc.gs[col] -= v;
        }
        for c in 0..b {
            sc.gs[m + roff + c] += sc.sr[c];
        }
    }

    /// The action's Hessian in (s_prev, s): (prev, prev) += Aᵀ H_r A,
    /// (prev, cur) −= Aᵀ H_r P, (cur, cur) += Pᵀ H_r P, and with `exact` the
    /// drift's curvature Σ_l (H_r r)_l ∇²r_l.
    #[inline]
    fn action_hessian(&self, sc: &mut Scratch, exact: bool) {
        let st = self.setup;
        let (m, b, dt, roff) = (st.m, st.b, st.dt, st.roff);
        let m2 = 2 * m;
        // sa = S A (b×m), then (prev, prev) += Aᵀ sa.
        for c2 in 0..m {
            for d1 in 0..b {
                let mut v = 0.0;
                for d2 in 0..b {
                    v += sc.hr[d1 + d2 * b] * sc.a[d2 + c2 * b];
                }
                sc.sa[d1 + c2 * b] = v;
            }
        }
        for c1 in 0..m {
            for c2 in 0..m {
                let mut v = 0.0;
                for d1 in 0..b {
                    v += sc.a[d1 + c1 * b] * sc.sa[d1 + c2 * b];
                }
                sc.hs[c1 + c2 * m2] += v;
            }
            for d2 in 0..b {
                // (Aᵀ H_r)[c1, d2] = (H_r A)[d2, c1] (H_r symmetric); (prev c1, cur roff+d2).
                let v = sc.sa[d2 + c1 * b];
                sc.hs[c1 + (m + roff + d2) * m2] -= v;
                sc.hs[(m + roff + d2) + c1 * m2] -= v;
            }
        }
        for d1 in 0..b {
            for d2 in 0..b {
                sc.hs[(m + roff + d1) + (m + roff + d2) * m2] += sc.hr[d1 + d2 * b];
            }
        }
        if exact {
            // Σ_l (Sr)_l ∇²r_l = curvature of f0 at s_prev with w = −Δt Pᵀ S r.
            sc.wv[..m].fill(0.0);
            for c in 0..b {
                sc.wv[roff + c] = -dt * sc.sr[c];
            }
            self.model
                .drift0_curvature(&sc.s_prev[..m], &sc.wv[..m], &mut sc.curv[..m * m]);
            for c1 in 0..m {
                for c2 in 0..m {
                    sc.hs[c1 + c2 * m2] += sc.curv[c1 + c2 * m];
                }
            }
        }
    }

    /// Trapezoidal potential: weight Δt/γ on interior points, Δt/(2γ) on
    /// the ends (V(s_0) at the first step), and Φ(s_n)/γ at the last.
    #[inline]
    fn potential_step(&self, sc: &mut Scratch, i: usize, need_h: bool, total: &mut f64) {
        let st = self.setup;
        let (m, n) = (st.m, self.n);
        let hw = st.dt / (2.0 * st.gamma);
        let wc = if i < n { 2.0 * hw } else { hw };
        let v = self
            .cost
            .running_derivatives(&sc.s[..m], &mut sc.vg[..m], &mut sc.vh[..m * m]);
        *total += wc * v;
        add_cost_term(sc, m, m, wc, need_h);
        if i == 1 {
            let v0 = self.cost.running_derivatives(
                &sc.s_prev[..m],
                &mut sc.vg[..m],
                &mut sc.vh[..m * m],
            );
            *total += hw * v0;
            add_cost_term(sc, m, 0, hw, need_h);
        }
        if i == n {
            let phi =
                self.cost
                    .terminal_derivatives(&sc.s[..m], &mut sc.vg[..m], &mut sc.vh[..m * m]);
            let inv_gamma = 1.0 / st.gamma;
            *total += inv_gamma * phi;
            add_cost_term(sc, m, m, inv_gamma, need_h);
        }
    }

    /// Map to the window through the sparse stencil: gw = Dᵀ gs,
    /// Hw = Dᵀ Hs D (D has ≤ 3m nonzeros).
    #[inline]
    fn to_window(&self, sc: &mut Scratch, need_h: bool) {
        let st = self.setup;
        let (m2, w) = (2 * st.m, st.w);
        let nz = &st.nz[..st.nnz];
        sc.gw[..w].fill(0.0);
        for &(r, c, v) in nz {
            sc.gw[c as usize] += v * sc.gs[r as usize];
        }
        if need_h {
            // Two stages, each a run of contiguous axpys: T = Hs D
            // (column c of T += v · column r of Hs), then Hw = Dᵀ T.
            sc.hsd[..m2 * w].fill(0.0);
            for &(r, c, v) in nz {
                let src = &sc.hs[r as usize * m2..(r as usize + 1) * m2];
                let dst = &mut sc.hsd[c as usize * m2..(c as usize + 1) * m2];
                for (d, x) in dst.iter_mut().zip(src) {
                    *d += v * x;
                }
            }
            sc.hwin[..w * w].fill(0.0);
            for c2 in 0..w {
                let tcol = &sc.hsd[c2 * m2..(c2 + 1) * m2];
                let hcol = &mut sc.hwin[c2 * w..(c2 + 1) * w];
                for &(r, c, v) in nz {
                    hcol[c as usize] += v * tcol[r as usize];
                }
            }
        }
    }

    /// Scatter: window block jb ↔ z_{i−jb}; a variable if i − jb ≥ 1, else
    /// a prefix block (∂F/∂e, and the mixed block ∂²F/∂z∂e).
    #[inline]
    fn scatter(&self, sc: &Scratch, i: usize, out: &mut Outputs, need_h: bool) {
        let st = self.setup;
        let (b, w) = (st.b, st.w);
        let kk = st.k as isize;
        for jb in 0..(st.k + 2) {
            let zi = i as isize - jb as isize;
            for c in 0..b {
                let j = jb * b + c;
                if zi >= 1 {
                    if let Some(g) = out.g.as_deref_mut() {
                        g[(zi as usize - 1) * b + c] += sc.gw[j];
                    }
                } else if let Some(ge) = out.ge.as_deref_mut() {
                    ge[(zi + kk) as usize * b + c] += sc.gw[j];
                }
            }
        }
        if !need_h {
            return;
        }
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
                        let v = sc.hwin[(jb1 * b + c1) + (jb2 * b + c2) * w];
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
}

/// gs[off..off+m] += w ∇(cost) and Hs[off.., off..] += w ∇²(cost) from the
/// cost term in `vg`, `vh` (off = 0: s_prev, off = m: s).
#[inline]
fn add_cost_term(sc: &mut Scratch, m: usize, off: usize, w: f64, need_h: bool) {
    let m2 = 2 * m;
    for c in 0..m {
        sc.gs[off + c] += w * sc.vg[c];
    }
    if need_h {
        for c1 in 0..m {
            for c2 in 0..m {
                sc.hs[(off + c1) + (off + c2) * m2] += w * sc.vh[c1 + c2 * m];
            }
        }
    }
}
