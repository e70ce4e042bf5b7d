//! Prediction on the active version (thesis eq. 3.8–3.9 in gather form):
//!
//! ```text
//! φ ← ((P^δ)ᵀ)^{⌊Δ/δ⌋} φ, then φ ← (1 − θ) φ + θ (P^δ)ᵀ φ,  θ = frac(Δ/δ)
//! ```
//!
//! split (Lie) per chain step with the control's transport by
//! v = f(x̂, u) − f(x̂, u₀) ([`crate::filter::control_transport`]), or, in
//! the moving frame, with the frame's translation ([`super::moving`]).

use super::{LiveChainFilter, TRANSPORT_MIN_JUMP};
use crate::chain::snapshot::SnapshotView;
use crate::filter::control_transport::ControlTransport;
use crate::filter::{check_predict, FilterError};
use crate::model::SdeModel;
use crate::MAX_STATE;

impl<M: SdeModel, S: AsRef<[u64]>> LiveChainFilter<M, S> {
    /// Propagate to `t` with `u` held.
    pub fn predict(&mut self, t: f64, u: &[f64]) -> Result<(), FilterError> {
        check_predict(self.t, t, u, self.dims)?;
        let dt = t - self.t;
        if self.active.is_none() {
            self.fallback.predict(t, u)?;
            self.t = t;
            self.belief.set(None);
            return Ok(());
        }
        if dt == 0.0 {
            return Ok(());
        }
        let mut v = [0.0; MAX_STATE];
        if self.moving {
            self.move_frame(u, dt);
        } else {
            self.control_velocity(u, &mut v);
        }
        if let Some(act) = self.active.as_ref() {
            let view = act.snap.view();
            let tr = &mut self.transport[act.buf];
            let n = view.len();
            self.tmp.clear();
            self.tmp.resize(n, 0.0);
            let q = dt / view.delta;
            let whole = (q + 1e-9).floor();
            let frac = (q - whole).max(0.0);
            // Lie splitting per chain step: the u₀ chain, then the control's
            // transport over the same time (see `control_transport`), applied
            // once the accumulated displacement makes the fastest active state
            // jump with probability one.
            for _ in 0..whole as usize {
                step(&view, &self.phi, &mut self.tmp);
                std::mem::swap(&mut self.phi, &mut self.tmp);
                let pd = &mut self.pending_d;
                transport_by(tr, &view, pd, &v, view.delta, &mut self.phi, &mut self.tmp);
            }
            if frac > 1e-9 {
                self.tmp.resize(n, 0.0);
                step(&view, &self.phi, &mut self.tmp);
                for z in 0..n {
                    self.phi[z] = (1.0 - frac) * self.phi[z] + frac * self.tmp[z];
                }
                let (pd, h) = (&mut self.pending_d, frac * view.delta);
                transport_by(tr, &view, pd, &v, h, &mut self.phi, &mut self.tmp);
            }
        }
        self.t = t;
        self.belief.set(None);
        Ok(())
    }

    /// The control's drift v = f(x̂, u) − f(x̂, u₀) at the belief mean, u₀
    /// the reference control the versions are built for
    /// ([`LiveChainFilter::set_reference_control`]); exact for
    /// control-affine models with constant input matrix.
    fn control_velocity(&self, u: &[f64], v: &mut [f64]) {
        let d = self.dims.state;
        let nu = self.dims.control;
        let m = self.last.mean;
        let mut f0 = [0.0; MAX_STATE];
        self.model.drift(&m[..d], &self.u_ref[..nu], &mut f0[..d]);
        self.model.drift(&m[..d], u, &mut v[..d]);
        for k in 0..d {
            v[k] -= f0[k];
            if !v[k].is_finite() {
                v[k] = 0.0;
            }
        }
    }
}

/// Accumulate the displacement v·h into `pd` and transport it (with the
/// rates `tr` of the version `view`) once it is about a jump length.
fn transport_by(
    tr: &mut ControlTransport,
    view: &SnapshotView,
    pd: &mut [f64; MAX_STATE],
    v: &[f64],
    h: f64,
    phi: &mut [f64],
    tmp: &mut Vec<f64>,
) {
    let d = view.dim;
    for k in 0..d {
        pd[k] += v[k] * h;
    }
    if tr.apply(view, &pd[..d], 1.0, TRANSPORT_MIN_JUMP, phi, tmp) {
        *pd = [0.0; MAX_STATE];
    }
}

/// One step of the equalised chain: out = (P^δ)ᵀ phi, read in gather form
/// (stay weight and incoming edges) from the snapshot.
fn step(view: &SnapshotView, phi: &[f64], out: &mut [f64]) {
    let n = view.len();
    for z in 0..n {
        let (s, e) = (view.in_off[z] as usize, view.in_off[z + 1] as usize);
        let mut acc = 0.0;
        for (w, &src) in view.in_w[s..e].iter().zip(&view.in_src[s..e]) {
            acc += w * phi[src as usize];
        }
        out[z] = view.stay[z] * phi[z] + acc;
    }
}
