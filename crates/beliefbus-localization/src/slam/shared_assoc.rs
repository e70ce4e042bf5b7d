//! One association per return for the whole particle set (paper 003 §4.2:
//! "data association is supplied by a separate maximum-likelihood step, the
//! same for all methods"), instead of one per particle. Every particle's
//! map then holds the same features under the same indices, as
//! EKF-SLAM's does, and a return is scored against the *set's* predictive
//! distribution of it, the moment-matched mixture over the particles:
//!
//! ```text
//! ν_kj = wrap(z − h(f^j, m_k^j)),  S_kj = H_x Σ₁(β_j) H_xᵀ + H_m Σ_mk^j H_mᵀ + Σ₂
//! ν̄_k = Σ_j w_j ν_kj,               S̄_k = Σ_j w_j (S_kj + (ν_kj − ν̄_k)(ν_kj − ν̄_k)ᵀ)
//! ```
//!
//! then the shared ML rule on (ν̄_k, S̄_k), return by return or for the
//! scan's returns jointly with mutual exclusion ([`super::scan_assoc`]). The
//! spread of the particles enters S̄ as EKF-SLAM's pose covariance enters its
//! S, so after a laser gap a return is matched against where the set as a
//! whole expects the landmark, not against each particle's one-step
//! prediction, which a particle far from the truth fails. The weights then
//! follow the model exactly for the imposed association (the association
//! is a function of the data and the previous set, as with any ML rule).

use super::assoc::{innovation, inverse, AssocConfig, Association, RangeBearing};
use super::particles::SlamParticles;
use super::scan_assoc::ScanAssoc;
use crate::geometry::{frame_rotation, Point, Pose};
use crate::vehicle::{Control, Ute};
use nalgebra::{Matrix2, Matrix3, Vector2};

/// The set-level association of return `z`; `None` when the particles'
/// maps differ in length (they were not built by shared association).
/// `lm` gives a landmark's position and covariance; `s0` is Σ₁ in the body
/// frame, `r` Σ₂.
#[allow(clippy::too_many_arguments)]
pub fn shared_association<L: Clone>(
    set: &SlamParticles<L>,
    ute: &Ute,
    u: Control,
    s0: &Matrix3<f64>,
    r: &Matrix2<f64>,
    z: &RangeBearing,
    cfg: &AssocConfig,
    lm: impl Fn(&L) -> (Point, Matrix2<f64>),
) -> Option<Association> {
    let mut scan = ScanAssoc::with_capacity(1);
    scan.begin(1);
    shared_offers(set, ute, u, s0, r, z, 0, cfg, &lm, &mut scan)?;
    Some(scan.decide(cfg)[0])
}

/// Score return `ret` (`z`) against the set's predictive distribution of
/// every candidate landmark into `scan`, so that a scan's returns can be
/// decided jointly ([`ScanAssoc::decide`]); `None` when the particles' maps
/// differ in length.
#[allow(clippy::too_many_arguments)]
pub fn shared_offers<L: Clone>(
    set: &SlamParticles<L>,
    ute: &Ute,
    u: Control,
    s0: &Matrix3<f64>,
    r: &Matrix2<f64>,
    z: &RangeBearing,
    ret: usize,
    cfg: &AssocConfig,
    lm: &impl Fn(&L) -> (Point, Matrix2<f64>),
    scan: &mut ScanAssoc,
) -> Option<()> {
    let n = set.maps[0].len();
    if set.maps.iter().any(|m| m.len() != n) {
        return None;
    }
    // Pre-filter on the heaviest particle, with the radius widened by the
    // set's spread so that a spread-out set still scores its candidates.
    let b = set.best();
    let fb = ute.predict_mean(&set.x[b], u);
    let (zp, _, _) = inverse(&fb, z);
    let radius = cfg.radius + 3.0 * set.position_spread();
    for (k, lb) in set.maps[b].iter().enumerate() {
        let (mb, _) = lm(lb);
        if (mb[0] - zp[0]).powi(2) + (mb[1] - zp[1]).powi(2) > radius * radius {
            continue;
        }
        // One pass: Σ w (S + (ν − ν̄)(ν − ν̄)ᵀ) = Σ w (S + ν νᵀ) − ν̄ ν̄ᵀ for
        // normalised weights.
        let (mut nu_bar, mut s_bar) = (Vector2::zeros(), Matrix2::zeros());
        for (j, x) in set.x.iter().enumerate() {
            let (nu, s) = predicted(ute, u, s0, &set.acc[j], r, x, set.maps[j].get(k)?, lm, z);
            nu_bar += set.w[j] * nu;
            s_bar += set.w[j] * (s + nu * nu.transpose());
        }
        s_bar -= nu_bar * nu_bar.transpose();
        scan.offer(ret, k, &nu_bar, &s_bar, cfg);
    }
    Some(())
}

/// ν and S of return z for one particle at pose x with landmark l and
/// accumulated noise `acc` (zero: the step's Σ₁ alone).
#[allow(clippy::too_many_arguments)]
fn predicted<L>(
    ute: &Ute,
    u: Control,
    s0: &Matrix3<f64>,
    acc: &Matrix3<f64>,
    r: &Matrix2<f64>,
    x: &Pose,
    l: &L,
    lm: &impl Fn(&L) -> (Point, Matrix2<f64>),
    z: &RangeBearing,
) -> (Vector2<f64>, Matrix2<f64>) {
    let f = ute.predict_mean(x, u);
    let (m, sm) = lm(l);
    let t = frame_rotation(x[2]);
    let mut sx = t * s0 * t.transpose();
    if *acc != Matrix3::zeros() {
        let fx = super::ekf::motion_jacobian(ute, x[2], u);
        sx += fx * acc * fx.transpose();
    }
    let (nu, hx, hm) = innovation(&f, m, z);
    (nu, hx * sx * hx.transpose() + hm * sm * hm.transpose() + r)
}
