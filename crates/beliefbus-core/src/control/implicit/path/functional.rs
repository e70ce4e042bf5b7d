//! F for one initial state and horizon as an [`Objective`]: the path
//! points of z, the value, and the entry points of the derivative pass
//! ([`super::pass`]).

use super::setup::PathSetup;
use crate::control::implicit::banded::SymBand;
use crate::control::implicit::newton::Objective;
use crate::model::affine::{ControlAffine, PathStructure};
use crate::model::path_cost::{Gate, PathCost};
use crate::MAX_STATE;

/// F for one initial state and horizon: an [`Objective`] over z.
pub struct PathFunctional<'a, M: ControlAffine + ?Sized, C: PathCost + ?Sized> {
    pub setup: &'a PathSetup,
    pub model: &'a M,
    pub cost: &'a C,
    /// Prefix blocks (from x(t)).
    pub(super) prefix: [f64; 2 * MAX_STATE],
    /// Steps n.
    pub n: usize,
    /// Optional wall (double slit).
    pub gate: Option<Gate>,
}

/// Optional outputs of one derivative pass.
pub(super) struct Outputs<'o> {
    pub(super) g: Option<&'o mut [f64]>,
    pub(super) h: Option<&'o mut SymBand>,
    pub(super) ge: Option<&'o mut [f64]>,
    /// ∂²F/∂z∂e for the first K+1 variable blocks: ((K+1)b) × ((K+1)b),
    /// column-major with leading dimension (K+1)b.
    pub(super) cross: Option<&'o mut [f64]>,
    pub(super) exact: bool,
    /// Stop after this step (the prefix terms live in steps ≤ K+1).
    pub(super) last_step: usize,
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
    pub(super) fn block<'z>(&'z self, z: &'z [f64], i: isize) -> &'z [f64] {
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
    pub(super) fn state(&self, z: &[f64], i: usize, s: &mut [f64]) {
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

    pub(super) fn gate_ok(&self, i: usize, s: &[f64]) -> bool {
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
