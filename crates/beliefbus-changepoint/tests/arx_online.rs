//! The per-step ARX interface against the filter driven with the plant's
//! own regressors (same random numbers: identical estimates), and the
//! posterior probability of a change since a true change-point rising above
//! 0.5 soon after a large jump.

use beliefbus_changepoint::arx::online::ArxOnline;
use beliefbus_changepoint::arx::plant::{ArxPlant, ThetaRegion};
use beliefbus_changepoint::arx::rbpf::{ArxRbpf, ArxRbpfConfig};
use beliefbus_changepoint::arx::ThetaPrior;
use beliefbus_changepoint::rng;
use rand_distr::{Distribution, StandardNormal};

#[test]
fn online_interface_equals_the_filter_on_plant_regressors() {
    let mut r = rng::stream(8, 0);
    let mut plant = ArxPlant::<3>::new(
        2,
        0.01,
        ThetaPrior::standard(),
        ThetaRegion::StableAr,
        &mut r,
    )
    .unwrap();
    let cfg = ArxRbpfConfig {
        rho: 0.01,
        ..ArxRbpfConfig::default()
    };
    let mut online =
        ArxOnline::<3>::new(2, ThetaPrior::standard(), cfg, rng::stream(8, 1)).unwrap();
    let mut direct = ArxRbpf::<3>::new(ThetaPrior::standard(), cfg, rng::stream(8, 1)).unwrap();
    for t in 1..=600u64 {
        let (y, phi, _, _) = plant.observe(&mut r);
        let a = online.observe(y).unwrap();
        if t >= plant.t0() {
            let b = direct.step(y, &phi).unwrap();
            assert_eq!(a, b, "t={t}");
        }
        let u: f64 = StandardNormal.sample(&mut r);
        plant.apply(y, u);
        online.apply(u).unwrap();
    }
}

#[test]
fn change_probability_detects_a_large_jump() {
    // θ = (0.3, -0.2, 1.0) for t < 400, then (-0.5, 0.3, -1.0).
    let mut r = rng::stream(21, 0);
    let cfg = ArxRbpfConfig {
        rho: 0.001,
        particles: 100,
        ..ArxRbpfConfig::default()
    };
    let mut f = ArxOnline::<3>::new(2, ThetaPrior::standard(), cfg, rng::stream(21, 1)).unwrap();
    let (mut y1, mut y2, mut u1) = (0.0, 0.0, 0.0);
    let tau = 400u64;
    let mut detected = None;
    for t in 1..=600u64 {
        let th = if t < tau {
            [0.3, -0.2, 1.0]
        } else {
            [-0.5, 0.3, -1.0]
        };
        let e: f64 = StandardNormal.sample(&mut r);
        let y = -th[0] * y1 - th[1] * y2 + th[2] * u1 + e;
        f.observe(y).unwrap();
        if t == tau - 1 {
            assert!(
                f.prob_change_since(200) < 0.5,
                "false alarm before the change"
            );
        }
        if t >= tau && detected.is_none() && f.prob_change_since(tau.saturating_sub(5)) > 0.5 {
            detected = Some(t - tau);
        }
        let u: f64 = StandardNormal.sample(&mut r);
        f.apply(u).unwrap();
        (y2, y1, u1) = (y1, y, u);
    }
    let d = detected.expect("change never detected");
    assert!(d <= 20, "detection delay {d}");
}
