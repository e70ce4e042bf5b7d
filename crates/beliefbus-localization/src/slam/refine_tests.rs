//! The refined re-observation step on linear-Gaussian toys, where the
//! answers are Kalman's: the proposal is the optimal one, the weight the
//! Kalman predictive likelihood whatever ξ and θ_old, and a particle run
//! recovers the exact posterior of a static feature.

use super::refine::{backward_term, linear_map, newton, Objective};
use crate::laser::Curvature;
use beliefbus_core::filter::resample::systematic;
use beliefbus_core::math::weights::normalise;
use beliefbus_core::rng::stream;
use nalgebra::{
    DMatrix, DVector, Matrix2, Matrix2x3, Matrix3, Matrix5, SMatrix, SVector, Vector2, Vector3,
    Vector5,
};
use rand::RngExt;
use rand_distr::StandardNormal;

/// Linear sightings of θ: Σ_i ½‖z_i − H_x x_i − H_m θ‖²_{S⁻¹}.
struct LinearPast {
    hx: Matrix2x3<f64>,
    hm: Matrix2<f64>,
    sinv: Matrix2<f64>,
    seen: Vec<(Vector3<f64>, Vector2<f64>)>,
}

impl LinearPast {
    fn add(&self, th: &Vector2<f64>, g: &mut Vector2<f64>, h: &mut Matrix2<f64>) -> f64 {
        let mut v = 0.0;
        for (x, z) in &self.seen {
            let nu = z - self.hx * x - self.hm * th;
            let sn = self.sinv * nu;
            v += 0.5 * nu.dot(&sn);
            *g -= self.hm.transpose() * sn;
            *h += self.hm.transpose() * self.sinv * self.hm;
        }
        v
    }
}

impl Objective<2> for LinearPast {
    fn eval(
        &self,
        v: &SVector<f64, 2>,
        _: Curvature,
        g: &mut SVector<f64, 2>,
        h: &mut SMatrix<f64, 2, 2>,
    ) -> f64 {
        *g = Vector2::zeros();
        *h = Matrix2::zeros();
        self.add(v, g, h)
    }
}

/// ½‖x − f‖²_{P⁻¹} + ½‖z − H_x x − H_m θ‖²_{S⁻¹} + past(θ).
struct LinearSighting<'a> {
    f: Vector3<f64>,
    pinv: Matrix3<f64>,
    z: Vector2<f64>,
    past: &'a LinearPast,
}

impl Objective<5> for LinearSighting<'_> {
    fn eval(
        &self,
        v: &SVector<f64, 5>,
        _: Curvature,
        g: &mut SVector<f64, 5>,
        h: &mut SMatrix<f64, 5, 5>,
    ) -> f64 {
        let x = Vector3::new(v[0], v[1], v[2]);
        let th = Vector2::new(v[3], v[4]);
        let p = self.past;
        let d = x - self.f;
        let nu = self.z - p.hx * x - p.hm * th;
        let sn = p.sinv * nu;
        let j = SMatrix::<f64, 2, 5>::from_fn(|r, c| {
            if c < 3 {
                p.hx[(r, c)]
            } else {
                p.hm[(r, c - 3)]
            }
        });
        *g = -j.transpose() * sn;
        *h = j.transpose() * p.sinv * j;
        let pd = self.pinv * d;
        for a in 0..3 {
            g[a] += pd[a];
            for b in 0..3 {
                h[(a, b)] += self.pinv[(a, b)];
            }
        }
        let (mut g2, mut h2) = (Vector2::zeros(), Matrix2::zeros());
        let v2 = p.add(&th, &mut g2, &mut h2);
        for a in 0..2 {
            g[3 + a] += g2[a];
            for b in 0..2 {
                h[(3 + a, 3 + b)] += h2[(a, b)];
            }
        }
        0.5 * d.dot(&pd) + 0.5 * nu.dot(&sn) + v2
    }
}

fn toy_past() -> LinearPast {
    let hx = Matrix2x3::new(-0.8, -0.6, 0.1, 0.05, -0.07, -1.0);
    let hm = Matrix2::new(0.8, 0.6, -0.05, 0.07);
    let s = Matrix2::new(0.04, 0.01, 0.01, 0.02);
    LinearPast {
        hx,
        hm,
        sinv: s.try_inverse().unwrap(),
        seen: vec![],
    }
}

fn log_normal_n(z: &DVector<f64>, mean: &DVector<f64>, cov: &DMatrix<f64>) -> f64 {
    let n = z.len() as f64;
    let d = z - mean;
    let c = cov.clone().cholesky().unwrap();
    let q = d.dot(&c.solve(&d));
    -0.5 * n * (2.0 * std::f64::consts::PI).ln() - 0.5 * cov.determinant().ln() - 0.5 * q
}

/// One step: the 5-D proposal is the Kalman posterior of (x, θ) given the
/// prior N(f, P) × (θ's Gaussian from the earlier sightings) and z, and the
/// weight of every draw, for every θ_old, is log N(z; predicted, S_z).
#[test]
fn refined_step_is_the_optimal_proposal_with_kalman_weights_on_a_linear_toy() {
    let mut past = toy_past();
    past.seen
        .push((Vector3::new(-3.0, 1.0, 0.2), Vector2::new(2.0, 0.3)));
    past.seen
        .push((Vector3::new(-2.0, 1.5, 0.1), Vector2::new(1.4, 0.2)));
    let p = Matrix3::new(0.3, 0.05, 0.01, 0.05, 0.2, -0.02, 0.01, -0.02, 0.04);
    let f = Vector3::new(0.2, -0.1, 0.3);
    let z = Vector2::new(0.9, -0.25);
    let obj = LinearSighting {
        f,
        pinv: p.try_inverse().unwrap(),
        z,
        past: &past,
    };
    let m = newton(&obj, Vector5::zeros(), 50, 1e-20).unwrap();
    // θ's Gaussian from the earlier sightings: information Σ H_mᵀS⁻¹H_m.
    let bm = newton(&past, Vector2::zeros(), 50, 1e-20).unwrap();
    let (mu_p, pp) = (bm.mu, (bm.l * bm.l.transpose()).try_inverse().unwrap());
    // Kalman on v = (x, θ), observation z = [H_x H_m] v.
    let mut prior = Matrix5::zeros();
    prior.fixed_view_mut::<3, 3>(0, 0).copy_from(&p);
    prior.fixed_view_mut::<2, 2>(3, 3).copy_from(&pp);
    let mean = Vector5::new(f[0], f[1], f[2], mu_p[0], mu_p[1]);
    let j = SMatrix::<f64, 2, 5>::from_fn(|r, c| {
        if c < 3 {
            past.hx[(r, c)]
        } else {
            past.hm[(r, c - 3)]
        }
    });
    let s = past.sinv.try_inverse().unwrap();
    let sz = j * prior * j.transpose() + s;
    let k = prior * j.transpose() * sz.try_inverse().unwrap();
    let post_mean = mean + k * (z - j * mean);
    let post_cov = prior - k * sz * k.transpose();
    assert!(
        (m.mu - post_mean).norm() < 1e-9,
        "{} vs {}",
        m.mu,
        post_mean
    );
    let cov = (m.l * m.l.transpose()).try_inverse().unwrap();
    assert!((cov - post_cov).norm() < 1e-9 * post_cov.norm());
    let want = log_normal_n(
        &DVector::from_column_slice(z.as_slice()),
        &DVector::from_column_slice((j * mean).as_slice()),
        &DMatrix::from_column_slice(2, 2, sz.as_slice()),
    );
    let konst = -0.5 * p.determinant().ln()
        - 0.5 * s.determinant().ln()
        - (2.0 * std::f64::consts::PI).ln();
    let mut rng = stream(7, 0);
    for _ in 0..5 {
        let xi = Vector5::from_fn(|_, _| rng.sample(StandardNormal));
        let old = Vector2::new(
            rng.sample::<f64, _>(StandardNormal),
            rng.sample::<f64, _>(StandardNormal),
        ) * 3.0;
        let (v, inc) = linear_map(&obj, &m, &xi).unwrap();
        assert!((m.l.transpose() * (v - m.mu) - xi).norm() < 1e-9);
        let (back, _) = backward_term(&past, &old, 50, 1e-20).unwrap();
        let lw = inc + back + konst;
        assert!((lw - want).abs() < 1e-8, "{lw} vs {want}");
    }
}

/// A static feature seen from a random-walk pose T times (flat prior on θ,
/// the first sighting drawn jointly as a new feature): the weighted
/// particles' θ mean and covariance approach the exact (batch least
/// squares) posterior; the error at M = 2000 is within Monte Carlo bounds.
#[test]
fn refined_feature_posterior_matches_the_kalman_posterior_on_a_linear_toy() {
    let t_steps = 6;
    let q = Matrix3::new(0.2, 0.0, 0.0, 0.0, 0.2, 0.0, 0.0, 0.0, 0.05);
    let mut base = toy_past();
    let s = base.sinv.try_inverse().unwrap();
    // Data: truth θ, x_0 = 0 known.
    let mut rng = stream(11, 0);
    let theta = Vector2::new(4.0, -1.0);
    let lq = q.cholesky().unwrap().l();
    let ls = s.cholesky().unwrap().l();
    let mut x = Vector3::zeros();
    let mut zs = vec![];
    for _ in 0..t_steps {
        x += lq * Vector3::from_fn(|_, _| rng.sample(StandardNormal));
        zs.push(
            base.hx * x
                + base.hm * theta
                + ls * Vector2::from_fn(|_, _| rng.sample(StandardNormal)),
        );
    }
    // Exact posterior: information matrix over (x_1..x_T, θ).
    let n = 3 * t_steps + 2;
    let (mut lam, mut eta) = (DMatrix::<f64>::zeros(n, n), DVector::<f64>::zeros(n));
    let qi = q.try_inverse().unwrap();
    for t in 0..t_steps {
        let i = 3 * t;
        for a in 0..3 {
            for b in 0..3 {
                lam[(i + a, i + b)] += qi[(a, b)];
                if t > 0 {
                    lam[(i - 3 + a, i - 3 + b)] += qi[(a, b)];
                    lam[(i + a, i - 3 + b)] -= qi[(a, b)];
                    lam[(i - 3 + a, i + b)] -= qi[(a, b)];
                }
            }
        }
        let mut j = DMatrix::<f64>::zeros(2, n);
        for r in 0..2 {
            for c in 0..3 {
                j[(r, i + c)] = base.hx[(r, c)];
            }
            for c in 0..2 {
                j[(r, n - 2 + c)] = base.hm[(r, c)];
            }
        }
        let si = DMatrix::from_column_slice(2, 2, base.sinv.as_slice());
        lam += j.transpose() * &si * &j;
        eta += j.transpose() * &si * DVector::from_column_slice(zs[t].as_slice());
    }
    let cov = lam.clone().try_inverse().unwrap();
    let mean = &cov * eta;
    let (tm, tc) = (
        Vector2::new(mean[n - 2], mean[n - 1]),
        Matrix2::new(
            cov[(n - 2, n - 2)],
            cov[(n - 2, n - 1)],
            cov[(n - 1, n - 2)],
            cov[(n - 1, n - 1)],
        ),
    );
    // Particles.
    let m = 2000;
    let mut xs = vec![Vector3::<f64>::zeros(); m];
    let mut th = vec![Vector2::<f64>::zeros(); m];
    let mut seen: Vec<Vec<(Vector3<f64>, Vector2<f64>)>> = vec![vec![]; m];
    let (mut logw, mut w, mut anc) = (vec![0.0; m], vec![0.0; m], vec![0usize; m]);
    let konst = -0.5 * q.determinant().ln() - 0.5 * s.determinant().ln();
    for z in &zs {
        for p in 0..m {
            base.seen = std::mem::take(&mut seen[p]);
            let first = base.seen.is_empty();
            let obj = LinearSighting {
                f: xs[p],
                pinv: qi,
                z: *z,
                past: &base,
            };
            let mn = newton(&obj, Vector5::zeros(), 50, 1e-20).unwrap();
            let xi = Vector5::from_fn(|_, _| rng.sample(StandardNormal));
            let (v, inc) = linear_map(&obj, &mn, &xi).unwrap();
            let back = if first {
                0.0
            } else {
                backward_term(&base, &th[p], 50, 1e-20).unwrap().0
            };
            logw[p] += inc + back + konst;
            xs[p] = Vector3::new(v[0], v[1], v[2]);
            th[p] = Vector2::new(v[3], v[4]);
            base.seen.push((xs[p], *z));
            seen[p] = std::mem::take(&mut base.seen);
        }
        let st = normalise(&logw, &mut w).unwrap();
        if st.ess < 0.5 * m as f64 {
            systematic(&w, &mut rng, &mut anc).unwrap();
            let (x0, t0, s0) = (xs.clone(), th.clone(), seen.clone());
            for (k, &a) in anc.iter().enumerate() {
                xs[k] = x0[a];
                th[k] = t0[a];
                seen[k] = s0[a].clone();
            }
            logw.fill(0.0);
            w.fill(1.0 / m as f64);
        } else {
            for (l, &wi) in logw.iter_mut().zip(&w) {
                *l = wi.ln();
            }
        }
    }
    let em: Vector2<f64> = th.iter().zip(&w).map(|(t, &wi)| t * wi).sum();
    let ec: Matrix2<f64> = th
        .iter()
        .zip(&w)
        .map(|(t, &wi)| (t - em) * (t - em).transpose() * wi)
        .sum();
    for a in 0..2 {
        let se = (tc[(a, a)] / m as f64).sqrt();
        assert!(
            (em[a] - tm[a]).abs() < 5.0 * se,
            "mean {a}: {} vs {} (se {se})",
            em[a],
            tm[a]
        );
        assert!(
            (ec[(a, a)] / tc[(a, a)] - 1.0).abs() < 0.15,
            "var {a}: {} vs {}",
            ec[(a, a)],
            tc[(a, a)]
        );
    }
}
