//! The exact reference for the decoders and smoothers on a linear model: a
//! scalar Kalman filter and Rauch–Tung–Striebel smoother on the Euler
//! discretisation of one OU axis observed through the increments of its
//! integral (the decoding experiment's system):
//!
//! ```text
//! x_{k+1} = φ x_k + N(0, q),   φ = 1 − a h,  q = σ² h
//! o_k = x_k + N(0, r),         r = γ²/h,     k = 0..N−1 (x_N not observed)
//! G_k = P_k φ / P⁻_{k+1},      m^s_k = m_k + G_k (m^s_{k+1} − m⁻_{k+1})
//! ```

/// Scalar Kalman filter + RTS smoother on the Euler model of one axis:
/// x_{k+1} = (1 − a h) x_k + N(0, σ² h), o_k = Δy_{k+1}/h = x_k + N(0, γ²/h)
/// for k < N (x_N is not observed). Returns (causal predicted mean and
/// variance, smoothed mean, smoothed variance), each of length N + 1.
pub struct Rts1 {
    pub pred_m: Vec<f64>,
    pub pred_p: Vec<f64>,
    pub smooth_m: Vec<f64>,
    pub smooth_p: Vec<f64>,
}

pub fn rts_1d(a: f64, sigma: f64, gamma: f64, m0: f64, p0: f64, h: f64, obs: &[f64]) -> Rts1 {
    let n = obs.len();
    let phi = 1.0 - a * h;
    let q = sigma * sigma * h;
    let r = gamma * gamma / h;
    let mut out = Rts1 {
        pred_m: Vec::with_capacity(n + 1),
        pred_p: Vec::with_capacity(n + 1),
        smooth_m: vec![0.0; n + 1],
        smooth_p: vec![0.0; n + 1],
    };
    let mut fm = vec![0.0; n + 1];
    let mut fp = vec![0.0; n + 1];
    let (mut m, mut p) = (m0, p0);
    for k in 0..=n {
        out.pred_m.push(m);
        out.pred_p.push(p);
        if k < n {
            let kg = p / (p + r);
            m += kg * (obs[k] - m);
            p *= 1.0 - kg;
        }
        fm[k] = m;
        fp[k] = p;
        m *= phi;
        p = phi * phi * p + q;
    }
    out.smooth_m[n] = fm[n];
    out.smooth_p[n] = fp[n];
    for k in (0..n).rev() {
        let pp = out.pred_p[k + 1];
        let g = if pp > 0.0 { fp[k] * phi / pp } else { 0.0 };
        out.smooth_m[k] = fm[k] + g * (out.smooth_m[k + 1] - out.pred_m[k + 1]);
        out.smooth_p[k] = fp[k] + g * g * (out.smooth_p[k + 1] - pp);
    }
    out
}
