//! The projection PF on linear-Gaussian models against the exact Kalman
//! filter (written here): for a linear-Gaussian model the posterior is
//! Gaussian, so the projection loses nothing and the PPF's θ̂ must track
//! the Kalman mean and covariance within Monte Carlo error.

use beliefbus_projection::rng::{stream, SimRng};
use beliefbus_projection::{FilterModel, Gaussian, ProjectionPf};
use nalgebra::{Matrix2, Vector2};
use rand::RngExt;
use rand_distr::StandardNormal;

/// x' = a x + u + w, w ~ N(0, q); y = x + v, v ~ N(0, r).
struct Scalar {
    a: f64,
    q: f64,
    r: f64,
}

impl FilterModel for Scalar {
    fn state_dim(&self) -> usize {
        1
    }
    fn obs_dim(&self) -> usize {
        1
    }
    fn sample_transition(&self, x: &mut [f64], u: &[f64], rng: &mut SimRng) {
        x[0] = self.a * x[0] + u[0] + self.q.sqrt() * rng.sample::<f64, _>(StandardNormal);
    }
    fn obs_log_likelihood(&self, x: &[f64], y: &[f64]) -> f64 {
        -0.5 * (y[0] - x[0]).powi(2) / self.r
    }
}

#[test]
fn scalar_ppf_tracks_the_kalman_filter() {
    let m = Scalar {
        a: 0.9,
        q: 0.5,
        r: 0.3,
    };
    let n = 4000;
    let fam = Gaussian::new(1).unwrap();
    let prior = fam.params(&[2.0], &[1.0]).unwrap();
    let mut pf = ProjectionPf::new(fam, n, &prior).unwrap();
    let mut rng = stream(21, 0);
    let mut env = stream(21, 1);
    pf.initialize(&m, &mut rng);
    let (mut mk, mut pk) = (2.0, 1.0);
    let mut x = 2.0 + env.sample::<f64, _>(StandardNormal);
    let mut worst: f64 = 0.0;
    for k in 0..200 {
        let u = (k as f64 * 0.1).sin();
        if k > 0 {
            x = m.a * x + u + m.q.sqrt() * env.sample::<f64, _>(StandardNormal);
            pf.predict(&m, &[u], &mut rng);
            mk = m.a * mk + u;
            pk = m.a * m.a * pk + m.q;
        }
        let y = x + m.r.sqrt() * env.sample::<f64, _>(StandardNormal);
        let p = pf.update(&m, &[y]).unwrap();
        let gain = pk / (pk + m.r);
        mk += gain * (y - mk);
        pk *= 1.0 - gain;
        // Monte Carlo error of a weighted mean / variance: the effective
        // sample size is above n/4 here; 5 standard errors per step.
        let ess = n as f64 / 4.0;
        let z_mean = (p.mean[0] - mk).abs() / (pk / ess).sqrt();
        let z_var = (p.cov[(0, 0)] - pk).abs() / (pk * (2.0 / ess).sqrt());
        worst = worst.max(z_mean).max(z_var);
        assert!(
            z_mean < 5.0 && z_var < 5.0,
            "step {k}: ppf ({}, {}) kalman ({mk}, {pk})",
            p.mean[0],
            p.cov[(0, 0)]
        );
    }
    // Not vacuous: the filters did differ by sampling error.
    assert!(worst > 0.1, "suspiciously exact agreement {worst}");
}

/// Constant velocity, position observed: x' = F x + w, y = x_1 + v.
struct Cv {
    f: Matrix2<f64>,
    q_chol: Matrix2<f64>,
    r: f64,
}

impl FilterModel for Cv {
    fn state_dim(&self) -> usize {
        2
    }
    fn obs_dim(&self) -> usize {
        1
    }
    fn sample_transition(&self, x: &mut [f64], _u: &[f64], rng: &mut SimRng) {
        let z = Vector2::new(
            rng.sample::<f64, _>(StandardNormal),
            rng.sample::<f64, _>(StandardNormal),
        );
        let v = self.f * Vector2::new(x[0], x[1]) + self.q_chol * z;
        x[0] = v[0];
        x[1] = v[1];
    }
    fn obs_log_likelihood(&self, x: &[f64], y: &[f64]) -> f64 {
        -0.5 * (y[0] - x[0]).powi(2) / self.r
    }
}

#[test]
fn vector_ppf_tracks_the_kalman_filter() {
    let dt: f64 = 0.5;
    let f = Matrix2::new(1.0, dt, 0.0, 1.0);
    let q = Matrix2::new(dt.powi(3) / 3.0, dt * dt / 2.0, dt * dt / 2.0, dt) * 0.4;
    let model = Cv {
        f,
        q_chol: q.cholesky().unwrap().l(),
        r: 0.5,
    };
    let n = 5000;
    let fam = Gaussian::new(2).unwrap();
    let p0 = Matrix2::new(1.0, 0.0, 0.0, 0.5);
    let prior = fam.params(&[0.0, 1.0], p0.as_slice()).unwrap();
    let mut pf = ProjectionPf::new(fam, n, &prior).unwrap();
    let mut rng = stream(22, 0);
    let mut env = stream(22, 1);
    pf.initialize(&model, &mut rng);
    let mut m = Vector2::new(0.0, 1.0);
    let mut p = p0;
    let mut x = Vector2::new(0.3, 0.8);
    let h = nalgebra::RowVector2::new(1.0, 0.0);
    for k in 0..100 {
        if k > 0 {
            let z = Vector2::new(
                env.sample::<f64, _>(StandardNormal),
                env.sample::<f64, _>(StandardNormal),
            );
            x = f * x + model.q_chol * z;
            pf.predict(&model, &[], &mut rng);
            m = f * m;
            p = f * p * f.transpose() + q;
        }
        let y = x[0] + model.r.sqrt() * env.sample::<f64, _>(StandardNormal);
        let est = pf.update(&model, &[y]).unwrap();
        let s = (h * p * h.transpose())[(0, 0)] + model.r;
        let kgain = p * h.transpose() / s;
        m += kgain * (y - m[0]);
        p -= kgain * h * p;
        let ess = n as f64 / 4.0;
        for i in 0..2 {
            let z = (est.mean[i] - m[i]).abs() / (p[(i, i)] / ess).sqrt();
            assert!(z < 5.0, "step {k} mean {i}: {} vs {}", est.mean[i], m[i]);
            for j in 0..2 {
                let se = ((p[(i, i)] * p[(j, j)] + p[(i, j)].powi(2)) / ess).sqrt();
                assert!(
                    (est.cov[(i, j)] - p[(i, j)]).abs() < 5.0 * se,
                    "step {k} cov {i}{j}: {} vs {}",
                    est.cov[(i, j)],
                    p[(i, j)]
                );
            }
        }
    }
}
