//! F against finite differences (both structures), the control-limit
//! blend, and the constant Hessian of a linear-quadratic problem.

use super::*;
use crate::control::implicit::banded::SymBand;
use crate::control::implicit::newton::Objective;
use crate::model::affine::{
    ControlAffine, ControlledBrownian, DoubleIntegrator, LinearAffine, PathStructure,
};
use crate::model::ship::{Ship, ShipParams};

/// Pendulum with damping: a nonlinear Full-structure model.
struct Pendulum;
impl ControlAffine for Pendulum {
    fn state_dim(&self) -> usize {
        2
    }
    fn control_dim(&self) -> usize {
        2
    }
    fn noise_dim(&self) -> usize {
        2
    }
    fn structure(&self) -> PathStructure {
        PathStructure::Full
    }
    fn drift0(&self, x: &[f64], f: &mut [f64]) {
        f[0] = x[1];
        f[1] = -x[0].sin() - 0.1 * x[1] + 0.2 * x[0] * x[1];
    }
    fn drift0_jacobian(&self, x: &[f64], j: &mut [f64]) {
        j[0] = 0.0;
        j[1] = -x[0].cos() + 0.2 * x[1];
        j[2] = 1.0;
        j[3] = -0.1 + 0.2 * x[0];
    }
    fn drift0_curvature(&self, x: &[f64], w: &[f64], out: &mut [f64]) {
        out[0] = w[1] * x[0].sin();
        out[1] = w[1] * 0.2;
        out[2] = w[1] * 0.2;
        out[3] = 0.0;
    }
    fn input_matrix(&self, g: &mut [f64]) {
        g[..4].copy_from_slice(&[1.0, 0.3, 0.0, 1.0]);
    }
    fn noise_matrix(&self, q: &mut [f64]) {
        q[..4].copy_from_slice(&[0.5, 0.0, 0.0, 0.5]);
    }
}

/// A non-quadratic cost: V = Σ c_i x_i⁴/4 + ½|x − g|², Φ = cosh-like.
struct Quartic;
impl PathCost for Quartic {
    fn running(&self, x: &[f64]) -> f64 {
        x.iter()
            .enumerate()
            .map(|(i, v)| 0.1 * (i as f64 + 1.0) * v.powi(4) / 4.0 + 0.5 * (v - 0.3).powi(2))
            .sum()
    }
    fn running_derivatives(&self, x: &[f64], g: &mut [f64], h: &mut [f64]) -> f64 {
        let d = x.len();
        h[..d * d].fill(0.0);
        for i in 0..d {
            let c = 0.1 * (i as f64 + 1.0);
            g[i] = c * x[i].powi(3) + (x[i] - 0.3);
            h[i + i * d] = 3.0 * c * x[i] * x[i] + 1.0;
        }
        self.running(x)
    }
    fn terminal(&self, x: &[f64]) -> f64 {
        x.iter()
            .map(|v| (v - 1.0).powi(2) + 0.2 * v.powi(4))
            .sum::<f64>()
            + 0.5 * x[0] * x[x.len() - 1]
    }
    fn terminal_derivatives(&self, x: &[f64], g: &mut [f64], h: &mut [f64]) -> f64 {
        let d = x.len();
        h[..d * d].fill(0.0);
        for i in 0..d {
            g[i] = 2.0 * (x[i] - 1.0) + 0.8 * x[i].powi(3);
            h[i + i * d] = 2.0 + 2.4 * x[i] * x[i];
        }
        g[0] += 0.5 * x[d - 1];
        g[d - 1] += 0.5 * x[0];
        h[(d - 1) * d] += 0.5;
        h[d - 1] += 0.5;
        self.terminal(x)
    }
}

/// Acceptance test: analytic gradient, banded Hessian, prefix gradient and
/// mixed derivatives of F match central finite differences.
fn check<M: ControlAffine, C: PathCost>(
    model: &M,
    cost: &C,
    r: &[f64],
    dt: f64,
    x: &[f64],
    n: usize,
    z: &[f64],
    limit: Option<(f64, f64)>,
) {
    // The C¹ kink (δ = 0), a blend narrower than most excesses, and one
    // wide enough that the cubic branch carries them.
    if limit.is_some() {
        for blend in [0.0, 0.5, 5.0] {
            check_blend(model, cost, r, dt, x, n, z, limit, blend);
        }
    } else {
        check_blend(model, cost, r, dt, x, n, z, None, 0.0);
    }
}

/// Every derivative of F against central differences at z, with the
/// control limit optionally on (and active): ∇_z F, the banded ∇²_z F,
/// ∂F/∂e and ∂²F/∂z∂e, the O(1) prefix pass against the full one, ∂F/∂x.
/// Long: one checklist over one problem, each assert naming its block.
#[allow(clippy::too_many_arguments)]
fn check_blend<M: ControlAffine, C: PathCost>(
    model: &M,
    cost: &C,
    r: &[f64],
    dt: f64,
    x: &[f64],
    n: usize,
    z: &[f64],
    limit: Option<(f64, f64)>,
    blend: f64,
) {
    let mut setup = PathSetup::new(model, r, dt).unwrap();
    let plain = setup.clone();
    if let Some((u_max, kappa)) = limit {
        setup = setup.with_control_limit(u_max, kappa, blend).unwrap();
    }
    let f = PathFunctional::new(&setup, model, cost, x, n, None);
    if limit.is_some() {
        // The penalty is active somewhere along z (else the check is moot).
        let f0 = PathFunctional::new(&plain, model, cost, x, n, None).value(z);
        assert!(
            f.value(z) > f0 + 1e-3,
            "limit inactive: {} vs {f0}",
            f.value(z)
        );
    }
    let nn = f.dim();
    assert_eq!(z.len(), nn);
    let kd = f.bandwidth();
    let mut g = vec![0.0; nn];
    let mut h = SymBand::new(nn, kd);
    let lp = setup.prefix_len();
    let mut ge = vec![0.0; lp];
    let mut cross = vec![0.0; lp * lp];
    let fz = f.full_derivatives(z, &mut g, &mut h, &mut ge, &mut cross);
    assert!((fz - f.value(z)).abs() < 1e-10 * fz.abs().max(1.0));
    let scale = |v: f64| 1e-5 * (1.0 + v.abs());
    let e = 1e-5;
    let mut zp = z.to_vec();
    let mut gp = vec![0.0; nn];
    let mut gm = vec![0.0; nn];
    let mut hh = SymBand::new(nn, kd);
    for j in 0..nn {
        zp[j] = z[j] + e;
        let fp = f.value(&zp);
        hh.resize(nn);
        f.derivatives(&zp, &mut gp, &mut hh);
        zp[j] = z[j] - e;
        let fm = f.value(&zp);
        hh.resize(nn);
        f.derivatives(&zp, &mut gm, &mut hh);
        zp[j] = z[j];
        let fd = (fp - fm) / (2.0 * e);
        assert!(
            (fd - g[j]).abs() < scale(g[j]) * 10.0,
            "grad {j}: fd {fd} vs {}",
            g[j]
        );
        for i in 0..nn {
            let fdh = (gp[i] - gm[i]) / (2.0 * e);
            let an = h.get(i, j);
            assert!(
                (fdh - an).abs() < scale(an) * 10.0,
                "hess ({i},{j}): fd {fdh} vs {an}"
            );
            if i.abs_diff(j) > kd {
                assert!(fdh.abs() < 1e-6, "outside the band ({i},{j}): {fdh}");
            }
        }
    }
    // Prefix gradient and ∂²F/∂z∂e.
    let mut fe = PathFunctional::new(&setup, model, cost, x, n, None);
    let e0: Vec<f64> = f.prefix().to_vec();
    for c in 0..lp {
        let mut ep = e0.clone();
        ep[c] += e;
        fe.set_prefix(&ep);
        let fp = fe.value(z);
        let mut gep = vec![0.0; lp];
        fe.gradient_with_prefix(z, &mut gp, &mut gep);
        ep[c] -= 2.0 * e;
        fe.set_prefix(&ep);
        let fm = fe.value(z);
        fe.gradient_with_prefix(z, &mut gm, &mut gep);
        let fd = (fp - fm) / (2.0 * e);
        assert!(
            (fd - ge[c]).abs() < 10.0 * scale(ge[c]),
            "prefix grad {c}: {fd} vs {}",
            ge[c]
        );
        for row in 0..lp.min(nn) {
            let fdc = (gp[row] - gm[row]) / (2.0 * e);
            let an = cross[row + c * lp];
            assert!(
                (fdc - an).abs() < 10.0 * scale(an),
                "cross ({row},{c}): {fdc} vs {an}"
            );
        }
        for row in lp..nn {
            assert!(
                ((gp[row] - gm[row]) / (2.0 * e)).abs() < 1e-5,
                "cross beyond the first blocks"
            );
        }
    }
    // The O(1) prefix pass agrees with the full pass.
    let (mut ge2, mut cross2) = (vec![0.0; lp], vec![0.0; lp * lp]);
    f.prefix_derivatives(z, &mut ge2, &mut cross2);
    for i in 0..lp {
        assert!((ge2[i] - ge[i]).abs() < 1e-12 * (1.0 + ge[i].abs()));
    }
    for i in 0..lp * lp {
        assert!((cross2[i] - cross[i]).abs() < 1e-12 * (1.0 + cross[i].abs()));
    }
    // ∂F/∂x.
    let m = setup.m;
    let mut gx = vec![0.0; m];
    f.gradient_x(z, &mut gx);
    for c in 0..m {
        let mut xp = x.to_vec();
        xp[c] += e;
        let fp = PathFunctional::new(&setup, model, cost, &xp, n, None).value(z);
        xp[c] -= 2.0 * e;
        let fm = PathFunctional::new(&setup, model, cost, &xp, n, None).value(z);
        let fd = (fp - fm) / (2.0 * e);
        assert!(
            (fd - gx[c]).abs() < 10.0 * scale(gx[c]),
            "∂F/∂x_{c}: {fd} vs {}",
            gx[c]
        );
    }
}

fn wiggle(nn: usize, amp: f64, base: &[f64]) -> Vec<f64> {
    (0..nn)
        .map(|i| base[i % base.len()] + amp * ((i as f64) * 0.77).sin())
        .collect()
}

#[test]
fn derivatives_match_finite_differences_full_structure() {
    let n = 6;
    let z = wiggle(2 * n, 0.4, &[0.2, -0.5]);
    let r = [4.0, 0.0, 0.0, 4.0];
    check(&Pendulum, &Quartic, &r, 0.1, &[0.3, -0.2], n, &z, None);
    // With the soft control limit active on most steps.
    check(
        &Pendulum,
        &Quartic,
        &r,
        0.1,
        &[0.3, -0.2],
        n,
        &z,
        Some((0.7, 5.0)),
    );
    let slit = ControlledBrownian { dim: 1, sigma: 1.0 };
    let z = wiggle(5, 0.5, &[0.7]);
    check(&slit, &Quartic, &[0.1], 0.02, &[1.0], 5, &z, None);
    check(
        &slit,
        &Quartic,
        &[0.1],
        0.02,
        &[1.0],
        5,
        &z,
        Some((3.0, 2.0)),
    );
}

#[test]
fn derivatives_match_finite_differences_second_order() {
    // The ship outside its wall, moving outward (wall force active).
    let ship = Ship::new(ShipParams::paper(0.01)).unwrap();
    let n = 5;
    let x = [8.0, 5.0, 1.0, 0.5];
    // Positions continuing outward so the wall stays active along the path.
    let z: Vec<f64> = (0..n)
        .flat_map(|i| {
            let t = (i + 2) as f64 * 0.1;
            [8.0 + 1.0 * t + 0.01 * (i as f64).sin(), 5.0 + 0.5 * t]
        })
        .collect();
    let r = [0.5, 0.0, 0.0, 0.5];
    check(&ship, &Quartic, &r, 0.1, &x, n, &z, None);
    check(&ship, &Quartic, &r, 0.1, &x, n, &z, Some((3.0, 10.0)));
    let di = DoubleIntegrator { p: 2, sigma: 1.0 };
    let z = wiggle(2 * n, 0.3, &[0.1, -0.2]);
    let r = [0.01, 0.0, 0.0, 0.01];
    let x = [0.1, 0.2, -0.3, 0.4];
    check(&di, &Quartic, &r, 0.05, &x, n, &z, None);
    check(&di, &Quartic, &r, 0.05, &x, n, &z, Some((20.0, 1.0)));
}

#[test]
fn linear_model_with_quadratic_cost_has_constant_hessian() {
    let model = LinearAffine {
        m: 2,
        p: 1,
        r: 1,
        a: vec![0.0, -1.0, 1.0, -0.5],
        g: vec![0.0, 1.0],
        q: vec![0.7],
        structure: PathStructure::SecondOrder,
    };
    let setup = PathSetup::new(&model, &[2.0], 0.05).unwrap();
    assert!((setup.gamma - 2.0 * 0.49).abs() < 1e-12);
    let cost = DiagonalQuadraticCost::new(&[1.0, 0.1], &[5.0, 1.0]);
    let f = PathFunctional::new(&setup, &model, &cost, &[0.5, -0.2], 8, None);
    let (mut g, mut h1, mut h2) = (
        vec![0.0; 8],
        SymBand::new(8, setup.bandwidth()),
        SymBand::new(8, setup.bandwidth()),
    );
    f.derivatives(&[0.0; 8], &mut g, &mut h1);
    f.derivatives(&wiggle(8, 2.0, &[1.0]), &mut g, &mut h2);
    for i in 0..8 {
        for j in 0..8 {
            assert!((h1.get(i, j) - h2.get(i, j)).abs() < 1e-9);
        }
    }
}
