//! The moving frame of [`LiveChainFilter`] (see
//! [`LiveChainFilter::set_moving_frame`]): each version is a chain built
//! for f − w around the belief, and the belief's motion is a translation F
//! of the frame, dF/dt = f(x̂, u) − f(x̂ − F, u₀) + w.

use super::LiveChainFilter;
use crate::chain::snapshot::SnapshotView;
use crate::model::SdeModel;
use crate::{MAX_CONTROL, MAX_STATE};

/// The moving frame of a chain version: the mean drift w under the
/// reference control `u0` of its states and their mean c. A moving-frame
/// chain is built for f(x, u₀) − w (see `stage::refine`), and refine
/// computes the same w from the same states.
pub fn frame_of<M: SdeModel + ?Sized>(
    model: &M,
    view: &SnapshotView,
    u0: &[f64],
) -> ([f64; MAX_STATE], [f64; MAX_STATE]) {
    let d = view.dim;
    let nu = model.dims().control;
    let mut u = [0.0; MAX_CONTROL];
    u[..nu].copy_from_slice(&u0[..nu]);
    let (mut w, mut c) = ([0.0; MAX_STATE], [0.0; MAX_STATE]);
    let mut f = [0.0; MAX_STATE];
    let n = view.len();
    for i in 0..n {
        let z = view.state(i);
        model.drift(z, &u[..nu], &mut f[..d]);
        for a in 0..d {
            w[a] += f[a];
            c[a] += z[a];
        }
    }
    for a in 0..d {
        w[a] /= n.max(1) as f64;
        c[a] /= n.max(1) as f64;
    }
    (w, c)
}

impl<M: SdeModel, S: AsRef<[u64]>> LiveChainFilter<M, S> {
    /// Moving frame (`refine.moving_frame`): every version is a
    /// chain built for g(z) = f(z, u₀) − w, w the mean uncontrolled drift of
    /// its states ([`frame_of`]), around the belief: the chain carries the
    /// belief's shape, a frame displacement F carries its motion. Mass at z
    /// stands for the state z + F, and F moves with what the chain does not
    /// model, evaluated at the belief mean x̂:
    ///
    /// ```text
    /// dF/dt = f(x̂, u) − g(x̂ − F) = f(x̂, u) − f(x̂ − F, u₀) + w
    /// ```
    ///
    /// exact for every state when f(z + F, u) − f(z, u₀) does not depend on
    /// z (the ship inside the disc: positions move at the velocity offset,
    /// velocities at the control), first order otherwise. F is a pure
    /// translation: no numerical diffusion, where a jump chain for the
    /// ship's position drift v on states of spacing r diffuses at about
    /// |v|·r/2 (its velocity information washes out), and no control
    /// transport (rates are not prepared). Each version (a lineage of its
    /// own) is installed from the Gaussian belief with F = x̂ − c, c the
    /// mean of its states, so the belief sits on them.
    pub fn set_moving_frame(&mut self, on: bool) {
        self.moving = on;
        self.frame_w = [0.0; MAX_STATE];
        self.frame_d = [0.0; MAX_STATE];
    }
    /// The active version's frame velocity w and displacement F.
    pub fn frame(&self) -> ([f64; MAX_STATE], [f64; MAX_STATE]) {
        (self.frame_w, self.frame_d)
    }

    /// Total displacement between the mass's states and the belief.
    pub(super) fn shift(&self) -> [f64; MAX_STATE] {
        let mut s = [0.0; MAX_STATE];
        for k in 0..self.dims.state {
            s[k] = self.pending_d[k] + self.frame_d[k];
        }
        s
    }

    /// F over `dt` with `u` held (see [`Self::set_moving_frame`]): with
    /// z̄ = x̂ − F the mass mean in frame coordinates (moved by the chain at
    /// f(z̄, u₀) − w) and r(F, z̄) = f(z̄ + F, u) − f(z̄, u₀) + w, one Heun
    /// step
    ///
    /// ```text
    /// k₁ = r(F, z̄),  k₂ = r(F + k₁·dt, z̄ + (f(z̄, u₀) − w)·dt),  F += (k₁ + k₂)·dt/2
    /// ```
    ///
    /// — second order; exact for a linear SDE whose A² = 0 (the double
    /// integrator: F_p gains F_v·dt + u·dt²/2). The former Euler step
    /// F += k₁·dt dropped u·dt²/2 of position per step under a control,
    /// a bias the chain filter could only observe away.
    pub(super) fn move_frame(&mut self, u: &[f64], dt: f64) {
        let d = self.dims.state;
        let nu = self.dims.control;
        let u0 = self.u_ref;
        let m = self.last.mean;
        let mut zb = [0.0; MAX_STATE];
        for k in 0..d {
            zb[k] = m[k] - self.frame_d[k];
        }
        // r(F, z̄) into `r`; f(z̄, u₀) into `f0`.
        let rate = |f: &[f64; MAX_STATE],
                    zb: &[f64; MAX_STATE],
                    r: &mut [f64; MAX_STATE],
                    f0: &mut [f64; MAX_STATE]| {
            let mut x = [0.0; MAX_STATE];
            for k in 0..d {
                x[k] = zb[k] + f[k];
            }
            self.model.drift(&x[..d], u, &mut r[..d]);
            self.model.drift(&zb[..d], &u0[..nu], &mut f0[..d]);
            for k in 0..d {
                r[k] += self.frame_w[k] - f0[k];
            }
        };
        let (mut k1, mut k2, mut f0) = ([0.0; MAX_STATE], [0.0; MAX_STATE], [0.0; MAX_STATE]);
        let f = self.frame_d;
        rate(&f, &zb, &mut k1, &mut f0);
        let (mut f1, mut z1) = (f, zb);
        for k in 0..d {
            f1[k] += k1[k] * dt;
            z1[k] += (f0[k] - self.frame_w[k]) * dt;
        }
        rate(&f1, &z1, &mut k2, &mut f0);
        for k in 0..d {
            let r = 0.5 * (k1[k] + k2[k]);
            if r.is_finite() {
                self.frame_d[k] += r * dt;
            }
        }
    }
}
