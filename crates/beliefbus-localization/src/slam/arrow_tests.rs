//! The arrow-structured joint step against dense linear algebra: its
//! derivatives against finite differences, its minimiser, factor, draws and
//! feature covariances against the dense Hessian, and with one feature the
//! 5-D Newton of [`super::implicit_refine::SightingObjective`].

use super::arrow::Arrow;
use super::assoc::RangeBearing;
use super::implicit_refine::SightingObjective;
use super::joint::JointObjective;
use super::refine::{cov_block, newton};
use super::refined_map::RefinedLandmark;
use crate::geometry::{Point, Pose};
use crate::laser::{predict, LaserNoise};
use nalgebra::{DMatrix, DVector, Matrix2, Matrix3, Vector2, Vector3, Vector5};

fn laser() -> LaserNoise {
    LaserNoise {
        var_range: 0.01,
        var_bearing: 1e-4,
    }
}

fn rb(x: &Pose, m: Point, e: (f64, f64)) -> RangeBearing {
    let (r, b) = predict(x, m);
    RangeBearing {
        range: r + e.0,
        bearing: b + e.1,
    }
}

/// A landmark at m seen `n` times from poses along a line.
fn seen(m: Point, n: usize) -> RefinedLandmark {
    let rinv = Matrix2::new(100.0, 0.0, 0.0, 1e4);
    let x0 = Pose::new(-4.0, -1.0, 0.2);
    let mut lm = RefinedLandmark::new(
        [m[0] + 0.1, m[1] - 0.05],
        Matrix2::identity(),
        &x0,
        &rb(&x0, m, (0.02, 0.002)),
    );
    for k in 1..n {
        let x = Pose::new(
            -4.0 + 0.7 * k as f64,
            -1.0 + 0.1 * k as f64,
            0.2 + 0.03 * k as f64,
        );
        lm.add_sighting(&x, &rb(&x, m, (-0.01, 0.001 * k as f64)), &rinv);
    }
    lm
}

fn prec() -> Matrix3<f64> {
    Matrix3::new(40.0, 3.0, -1.0, 3.0, 30.0, 2.0, -1.0, 2.0, 200.0)
}

fn dense(a: &Arrow, x: &Pose, th: &[Point]) -> (f64, DVector<f64>, DMatrix<f64>) {
    let (v, g, h) = a.dense(x, th);
    let n = g.len();
    (
        v,
        DVector::from_vec(g),
        DMatrix::from_fn(n, n, |i, j| h[i][j]),
    )
}

fn flat(x: &Pose, th: &[Point]) -> DVector<f64> {
    let mut v = vec![x[0], x[1], x[2]];
    for t in th {
        v.extend_from_slice(t);
    }
    DVector::from_vec(v)
}

fn unflat(v: &DVector<f64>) -> (Pose, Vec<Point>) {
    let x = Pose::new(v[0], v[1], v[2]);
    let th = (0..(v.len() - 3) / 2)
        .map(|b| [v[3 + 2 * b], v[4 + 2 * b]])
        .collect();
    (x, th)
}

/// Two known features (with earlier sightings, one seen twice in the
/// step) and a new one.
fn three_features() -> Arrow {
    let truth = Pose::new(0.3, 0.2, 0.1);
    let f = Pose::new(0.1, 0.35, 0.16);
    let mut a = Arrow::default();
    a.begin(f, prec(), laser());
    let (m1, m2, m3) = ([6.0, 8.0], [-5.0, 9.0], [2.0, 12.0]);
    let l1 = seen(m1, 4);
    a.push(Some(l1), &[rb(&truth, m1, (0.03, -0.004))], l1.m);
    let l2 = seen(m2, 11);
    a.push(
        Some(l2),
        &[
            rb(&truth, m2, (-0.05, 0.002)),
            rb(&truth, m2, (0.02, 0.006)),
        ],
        l2.m,
    );
    let z3 = rb(&truth, m3, (0.01, 0.003));
    let (g3, _, _) = super::assoc::inverse(&f, &z3);
    a.push(None, &[z3], g3);
    a
}

#[test]
fn arrow_derivatives_match_finite_differences() {
    let a = three_features();
    let x = Pose::new(0.2, 0.1, 0.05);
    let th = vec![[6.2, 7.9], [-4.9, 9.2], [2.1, 11.7]];
    let (val, g, h) = dense(&a, &x, &th);
    let v = flat(&x, &th);
    assert!((val - a.value(&x, &th)).abs() < 1e-9 * val.abs().max(1.0));
    let e = 1e-6;
    for k in 0..v.len() {
        let (mut vp, mut vm) = (v.clone(), v.clone());
        vp[k] += e;
        vm[k] -= e;
        let (xp, tp) = unflat(&vp);
        let (xm, tm) = unflat(&vm);
        let fd = (a.value(&xp, &tp) - a.value(&xm, &tm)) / (2.0 * e);
        assert!(
            (fd - g[k]).abs() < 1e-5 * g.norm().max(1.0),
            "grad {k}: {fd} vs {}",
            g[k]
        );
        let col = (dense(&a, &xp, &tp).1 - dense(&a, &xm, &tm).1) / (2.0 * e);
        for i in 0..v.len() {
            assert!(
                (col[i] - h[(i, k)]).abs() < 1e-5 * h.norm(),
                "hess ({i},{k})"
            );
        }
    }
}

#[test]
fn arrow_minimum_factor_draws_and_covariances_match_dense_algebra() {
    let mut a = three_features();
    let m = a.minimise(50, 1e-14).unwrap();
    let (x, th) = (a.x, a.th.clone());
    let (phi, g, h) = dense(&a, &x, &th);
    assert!(g.norm() < 1e-6, "{}", g.norm());
    assert!((phi - m.phi).abs() < 1e-9);
    let hc = h.clone().cholesky().unwrap();
    let ld: f64 = hc.l().diagonal().iter().map(|d| d.ln()).sum();
    assert!((ld - m.log_det_l).abs() < 1e-8, "{ld} vs {}", m.log_det_l);
    let hinv = hc.inverse();
    for b in 0..3 {
        let c = a.cov(b).unwrap();
        for i in 0..2 {
            for j in 0..2 {
                let want = hinv[(3 + 2 * b + i, 3 + 2 * b + j)];
                assert!(
                    (c[(i, j)] - want).abs() < 1e-8 * want.abs().max(1e-12),
                    "cov {b}"
                );
            }
        }
    }
    let mu = flat(&x, &th);
    let xi_x = Vector3::new(0.7, -1.2, 0.4);
    let xi_t = [
        Vector2::new(-0.3, 1.1),
        Vector2::new(2.0, 0.5),
        Vector2::new(-1.5, -0.2),
    ];
    let (mut xs, mut ts) = (Pose::zeros(), vec![]);
    let inc = a.draw(&xi_x, &xi_t, &mut xs, &mut ts).unwrap();
    let d = flat(&xs, &ts) - &mu;
    let q = xi_x.dot(&xi_x) + xi_t.iter().map(|v| v.dot(v)).sum::<f64>();
    assert!((d.dot(&(&h * &d)) - q).abs() < 1e-8 * q, "quadratic form");
    let want = 0.5 * q - a.value(&xs, &ts) - m.log_det_l;
    assert!((inc - want).abs() < 1e-9);
}

/// With one feature the arrow step is the 5-D Newton of F^j(x, θ).
#[test]
fn one_feature_arrow_equals_the_dense_five_dimensional_step() {
    let truth = Pose::new(0.3, 0.2, 0.1);
    let f = Pose::new(0.1, 0.35, 0.16);
    let mf = [6.0, 8.0];
    let lm = seen(mf, 5);
    let z = rb(&truth, mf, (0.03, -0.004));
    let mut a = Arrow::default();
    a.begin(f, prec(), laser());
    a.push(Some(lm), &[z], lm.m);
    let am = a.minimise(50, 1e-14).unwrap();
    let obj = SightingObjective {
        joint: JointObjective {
            f,
            prec: prec(),
            z,
            laser: laser(),
        },
        past: Some(&lm),
        fixed_obs: &[],
        fixed_map: &[],
    };
    let v0 = Vector5::new(f[0], f[1], f[2], lm.m[0], lm.m[1]);
    let dm = newton(&obj, v0, 50, 1e-14).unwrap();
    let v = Vector5::new(a.x[0], a.x[1], a.x[2], a.th[0][0], a.th[0][1]);
    assert!((v - dm.mu).norm() < 1e-8, "{v} vs {}", dm.mu);
    assert!((am.phi - dm.phi).abs() < 1e-9);
    assert!((am.log_det_l - dm.log_det_l).abs() < 1e-8);
    let c = a.cov(0).unwrap();
    let cd = cov_block(&dm.l, 3).unwrap();
    assert!((c - cd).norm() < 1e-8 * cd.norm());
}
