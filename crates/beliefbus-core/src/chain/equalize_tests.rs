//! Exponential backup and the propagation kernel (dense, fractional, sparse, backward) against direct sums.

use super::*;

#[test]
fn backup_halves_until_every_touched_state_fits() {
    let mut eq = TimeEqualized::new(0.1).unwrap();
    let holding = [0.5, 0.03, 0.011, 0.2];
    assert!(!eq.backup(&holding, &[0, 3]));
    assert_eq!(eq.delta(), 0.1);
    // the new state (slot 0) fits; a reconnected neighbour (slot 2) does not
    assert!(eq.backup(&holding, &[0, 2]));
    assert!((eq.delta() - 0.1 / 16.0).abs() < 1e-15);
    assert_eq!(eq.halvings, 4);
    let mut eq2 = TimeEqualized::new(0.1).unwrap();
    eq2.fit(&holding);
    assert_eq!(eq2.delta(), eq.delta());
    let (whole, frac) = eq.steps(0.1);
    assert_eq!((whole, frac), (16, 0.0));
    let (whole, frac) = eq.steps(0.1 + 0.5 * eq.delta());
    assert_eq!(whole, 16);
    assert!((frac - 0.5).abs() < 1e-9);
}

#[test]
fn forward_and_backward_are_transposes_and_conserve_mass() {
    // 3 states; rows: 0→{1:0.5,2:0.5}, 1→{0:1}, 2→{0:0.2,1:0.8}
    let states = [0.0, 1.0, 2.0];
    let ids = [0, 1, 2];
    let holding = [0.5, 0.25, 1.0];
    let radius = [1.0; 3];
    let off = [0, 2, 3, 5];
    let cols = [1, 2, 0, 0, 1];
    let probs = [0.5, 0.5, 1.0, 0.2, 0.8];
    let view = ChainView {
        dim: 1,
        states: &states,
        ids: &ids,
        holding: &holding,
        radius: &radius,
        row_offsets: &off,
        cols: &cols,
        probs: &probs,
    };
    view.validate().unwrap();
    let k = PropagationKernel::build(&view, 0.2, true);
    // dense P^δ
    let mut p = [[0.0; 3]; 3];
    for i in 0..3 {
        p[i][i] = 1.0 - 0.2 / holding[i];
        let (c, w) = view.row(i);
        for (j, wj) in c.iter().zip(w) {
            p[i][*j as usize] += 0.2 / holding[i] * wj;
        }
    }
    let phi = [0.2, 0.3, 0.5];
    let mut out = [0.0; 3];
    k.forward(&phi, &mut out);
    for z in 0..3 {
        let want: f64 = (0..3).map(|s| p[s][z] * phi[s]).sum();
        assert!((out[z] - want).abs() < 1e-15);
    }
    assert!((out.iter().sum::<f64>() - 1.0).abs() < 1e-15);
    // sparse push over the support equals the dense gather, also for
    // a fraction of a step
    for theta in [1.0, 0.37] {
        let mut phi = [0.4, 0.0, 0.6];
        let (mut dense, mut sparse) = ([0.0; 3], [0.0; 3]);
        k.forward_fraction(theta, &phi, &mut dense);
        let (mut next, mut seen) = (vec![], vec![0u32; 3]);
        k.forward_sparse(
            theta,
            &mut phi,
            &[0, 2],
            &mut sparse,
            &mut next,
            &mut seen,
            1,
        );
        for z in 0..3 {
            assert!((dense[z] - sparse[z]).abs() < 1e-15);
        }
        assert_eq!(phi, [0.0; 3]);
        next.sort_unstable();
        assert_eq!(next, vec![0, 1, 2]);
        assert_eq!(seen, vec![1; 3]);
    }
    let v = [1.0, -2.0, 3.0];
    k.backward(&v, &mut out);
    for z in 0..3 {
        let want: f64 = (0..3).map(|c| p[z][c] * v[c]).sum();
        assert!((out[z] - want).abs() < 1e-15);
    }
}

/// A random chain of `n` states: rows of 1–6 distinct columns with
/// random probabilities; holding times δ (no self-loop) on every third
/// state, else in (δ, 10δ).
fn random_chain(n: usize, delta: f64, seed: u64) -> (Vec<f64>, Vec<u32>, Vec<u32>, Vec<f64>) {
    use rand::RngExt;
    let mut rng = crate::rng::stream(seed, 0);
    let mut holding = vec![];
    let (mut off, mut cols, mut probs) = (vec![0u32], vec![], vec![]);
    for i in 0..n {
        holding.push(if i % 3 == 0 {
            delta
        } else {
            delta * (1.0 + 9.0 * rng.random::<f64>())
        });
        let k = 1 + (rng.random::<f64>() * 6.0) as usize;
        let mut row: Vec<u32> = vec![];
        while row.len() < k {
            let c = (rng.random::<f64>() * n as f64) as u32;
            if c as usize != i && !row.contains(&c) {
                row.push(c);
            }
        }
        let w: Vec<f64> = (0..k).map(|_| 0.05 + rng.random::<f64>()).collect();
        let sum: f64 = w.iter().sum();
        cols.extend(row);
        probs.extend(w.iter().map(|x| x / sum));
        off.push(cols.len() as u32);
    }
    (holding, off, cols, probs)
}

/// About 100 lines: one scenario (random chain, sparse support, several
/// θ and epochs) compared step by step with the dense map.
#[test]
fn sparse_push_over_the_support_equals_the_dense_step() {
    // The filter's sparse step against the dense gather (P^δ)ᵀ φ on a
    // random chain with and without self-loops, over several steps (the
    // support grows), for θ = 1 and a fraction, after a re-weighting of
    // the rows (control tilt) too: equal up to rounding, every slot
    // with mass is listed once, φ is consumed, and the epoch stamps
    // need no clearing between calls.
    use rand::RngExt;
    let n = 300;
    let delta = 0.01;
    let (holding, off, cols, probs) = random_chain(n, delta, 7);
    let states: Vec<f64> = (0..n).map(|i| i as f64).collect();
    let ids: Vec<u32> = (0..n as u32).collect();
    let radius = vec![1.0; n];
    let view = ChainView {
        dim: 1,
        states: &states,
        ids: &ids,
        holding: &holding,
        radius: &radius,
        row_offsets: &off,
        cols: &cols,
        probs: &probs,
    };
    view.validate().unwrap();
    let mut k = PropagationKernel::build(&view, delta, true);
    let mut seen = vec![0u32; n];
    let mut epoch = 0u32;
    let mut rng = crate::rng::stream(7, 1);
    for round in 0..2 {
        if round == 1 {
            // re-weight every row (as the control tilt does)
            let tilted: Vec<f64> = (0..n)
                .flat_map(|i| {
                    let (s, e) = (off[i] as usize, off[i + 1] as usize);
                    let w: Vec<f64> = (s..e).map(|_| 0.1 + rng.random::<f64>()).collect();
                    let sum: f64 = w.iter().sum();
                    w.into_iter().map(move |x| x / sum)
                })
                .collect();
            k.set_jump_probs(&holding, &off, &tilted);
        }
        for theta in [1.0, 0.37] {
            // mass on 5 states, then 4 steps
            let mut phi = vec![0.0; n];
            let mut active: Vec<u32> = vec![0, 1, 2, 3, 150];
            for (j, &z) in active.iter().enumerate() {
                phi[z as usize] = 0.1 + 0.05 * j as f64;
            }
            let mut dense = phi.clone();
            let (mut out, mut next) = (vec![0.0; n], Vec::new());
            for _ in 0..4 {
                let mut d2 = vec![0.0; n];
                k.forward_fraction(theta, &dense, &mut d2);
                dense = d2;
                epoch += 1;
                k.forward_sparse(
                    theta, &mut phi, &active, &mut out, &mut next, &mut seen, epoch,
                );
                assert!(phi.iter().all(|&v| v == 0.0), "φ not consumed");
                std::mem::swap(&mut phi, &mut out);
                std::mem::swap(&mut active, &mut next);
                let mut listed = active.clone();
                listed.sort_unstable();
                listed.dedup();
                assert_eq!(listed.len(), active.len(), "a slot listed twice");
                let with_mass: Vec<u32> =
                    (0..n as u32).filter(|&z| phi[z as usize] != 0.0).collect();
                assert_eq!(listed, with_mass, "θ = {theta}");
                for z in 0..n {
                    assert!(
                        (phi[z] - dense[z]).abs() <= 1e-15,
                        "θ = {theta}, slot {z}: {} vs {}",
                        phi[z],
                        dense[z]
                    );
                    assert_eq!(seen[z] == epoch, phi[z] != 0.0);
                }
                // mass is conserved
                assert!((phi.iter().sum::<f64>() - 1.0).abs() < 1e-14);
            }
        }
    }
    // θ = 1 leaves out a self-loop-free state that receives nothing
    // (holding = δ: every third slot; no row into it)
    let z0 = (0..n as u32)
        .step_by(3)
        .find(|z| !cols.contains(z))
        .expect("the seeded chain has an unreached slot");
    assert_eq!(k.stay()[z0 as usize], 0.0);
    let mut phi = vec![0.0; n];
    phi[z0 as usize] = 1.0;
    let (mut out, mut next) = (vec![0.0; n], Vec::new());
    epoch += 1;
    k.forward_sparse(1.0, &mut phi, &[z0], &mut out, &mut next, &mut seen, epoch);
    assert!(!next.contains(&z0) && !next.is_empty());
    assert_eq!(out[z0 as usize], 0.0);
    assert!((out.iter().sum::<f64>() - 1.0).abs() < 1e-15);
}
