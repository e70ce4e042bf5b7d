//! Micro-timings of the numeric toolbox on a filter's hot path: Cholesky of
//! a 6 × 6 SPD matrix, the ESS of 1000 log weights, one EKF step
//! (predict + update) on the oscillator. `#[ignore]`d and never asserting a
//! time: run with
//! `cargo test -p beliefbus-core --release --lib timing -- --ignored --nocapture`
//! and read the printed ns/op (the machine is shared, so compare runs made
//! one after another).

use std::hint::black_box;
use std::time::Instant;

/// Median over 7 batches of `reps` calls, in ns per call.
fn ns_per_op(reps: usize, mut f: impl FnMut()) -> f64 {
    let mut batches: Vec<f64> = (0..7)
        .map(|_| {
            let t = Instant::now();
            for _ in 0..reps {
                f();
            }
            t.elapsed().as_nanos() as f64 / reps as f64
        })
        .collect();
    batches.sort_by(f64::total_cmp);
    batches[3]
}

fn spd6() -> [f64; 36] {
    let mut a = [0.0; 36];
    for j in 0..6 {
        for i in 0..6 {
            let (x, y) = (i as f64, j as f64);
            a[i + j * 6] = (0.3 * (x - y)).cos() + if i == j { 2.0 } else { 0.0 };
        }
    }
    a
}

#[test]
#[ignore = "timing: prints ns/op, asserts nothing about time"]
fn timing_cholesky() {
    let a = spd6();
    let t = ns_per_op(200_000, || {
        let mut l = black_box(a);
        black_box(crate::math::linalg::cholesky(&mut l, 6));
        black_box(&l);
    });
    println!("cholesky 6x6 (math::linalg): {t:.1} ns/op");
    // nalgebra's, for the record: a run-time dimension means a DMatrix,
    // which allocates for the copy and for the factor.
    let m = nalgebra::DMatrix::from_column_slice(6, 6, &a);
    let t = ns_per_op(200_000, || {
        black_box(black_box(&m).clone().cholesky());
    });
    println!("cholesky 6x6 (nalgebra DMatrix, allocating): {t:.1} ns/op");
}

#[test]
#[ignore = "timing: prints ns/op, asserts nothing about time"]
fn timing_ess() {
    let lw: Vec<f64> = (0..1000)
        .map(|i| -0.5 * ((i % 37) as f64 - 18.0).powi(2) / 9.0)
        .collect();
    let mut w = vec![0.0; 1000];
    let t = ns_per_op(2_000, || {
        black_box(crate::math::weights::ess_from_log(black_box(&lw)));
    });
    println!("ess_from_log of 1000 log weights: {t:.1} ns/op");
    let t = ns_per_op(2_000, || {
        black_box(crate::math::weights::normalise(black_box(&lw), &mut w));
    });
    println!("normalise (+ ess) of 1000 log weights: {t:.1} ns/op");
}

#[test]
#[ignore = "timing: prints ns/op, asserts nothing about time"]
fn timing_ekf_step() {
    use crate::filter::ekf::testutil::{oscillator_data, prior};
    use crate::filter::ekf::{Ekf, EkfConfig};
    use crate::filter::kalman::testmodels::oscillator;
    use crate::filter::BayesFilter;
    use crate::model::Measurement;
    let data = oscillator_data(2000, 0.05, 3);
    let cfg = EkfConfig { max_dt: 0.01 };
    let mut ekf = Ekf::new(oscillator([0.2, 0.3]), &cfg, &prior(), 0.0).unwrap();
    let mut k = 0;
    let t = ns_per_op(2000 / 7, || {
        let (t, u, y) = &data[k];
        k += 1;
        ekf.predict(*t, &[*u]).unwrap();
        black_box(ekf.update(&Measurement::full(y)).unwrap());
    });
    println!("ekf step (5 RK4 substeps + update, d = 2): {t:.1} ns/op");
}
