//! The moving-frame chain versions (thesis §3.3 chains built for a drift
//! seen from a frame that moves with the belief): each version is a batch
//! chain (Alg. 2.1) of states drawn around the belief, built for
//! f(x, u₀) − w with w the mean drift of its states, so that the chain
//! carries the belief's shape and the filter carries its motion as a
//! translation of the frame
//! ([`crate::filter::live_chain::LiveChainFilter::set_moving_frame`]).

use crate::belief::Gaussian;
use crate::chain::{BatchBuild, Chain, ChainConfig, Sampler, TimeEqualized};
use crate::model::{Bounds, Dims, SdeJacobians, SdeModel};
use crate::rng::SimRng;
use crate::MAX_STATE;

/// The model in the frame that moves at the constant velocity `w`:
/// drift f(x, u) − w (the moving-frame chains, `refine.moving_frame`).
pub struct Framed<'a, M: SdeModel + ?Sized> {
    pub inner: &'a M,
    pub w: [f64; MAX_STATE],
}

impl<M: SdeModel + ?Sized> SdeModel for Framed<'_, M> {
    fn name(&self) -> &str {
        self.inner.name()
    }
    fn dims(&self) -> Dims {
        self.inner.dims()
    }
    fn drift(&self, x: &[f64], u: &[f64], f: &mut [f64]) {
        self.inner.drift(x, u, f);
        for (fi, wi) in f.iter_mut().zip(&self.w) {
            *fi -= wi;
        }
    }
    fn diffusion(&self, x: &[f64], big_f: &mut [f64]) {
        self.inner.diffusion(x, big_f)
    }
    fn obs_mean(&self, x: &[f64], g: &mut [f64]) {
        self.inner.obs_mean(x, g)
    }
    fn obs_std(&self, std: &mut [f64]) {
        self.inner.obs_std(std)
    }
    fn obs_residual(&self, y: &[f64], yhat: &[f64], r: &mut [f64]) {
        self.inner.obs_residual(y, yhat, r)
    }
    fn bounds(&self) -> &Bounds {
        self.inner.bounds()
    }
    fn drift_soa(&self, n: usize, x: &[f64], u: &[f64], f: &mut [f64]) {
        self.inner.drift_soa(n, x, u, f);
        let d = self.inner.dims().state;
        for (i, wi) in self.w[..d].iter().enumerate() {
            for fk in &mut f[i * n..(i + 1) * n] {
                *fk -= wi;
            }
        }
    }
}

/// The Jacobians are the model's: subtracting a constant w leaves ∂f/∂x
/// unchanged.
impl<M: SdeJacobians + ?Sized> SdeJacobians for Framed<'_, M> {
    fn drift_jacobian(&self, x: &[f64], u: &[f64], jac: &mut [f64]) {
        self.inner.drift_jacobian(x, u, jac)
    }
    fn obs_jacobian(&self, x: &[f64], jac: &mut [f64]) {
        self.inner.obs_jacobian(x, jac)
    }
}

/// How a moving-frame version is drawn and built (the `refine` settings).
#[derive(Clone, Debug)]
pub struct FrameBuild {
    /// Sampling std = `inflate` × belief std ...
    pub inflate: f64,
    /// ... mixed with this fraction of uniform draws ...
    pub uniform_fraction: f64,
    /// ... the std floored at this fraction of the bounds' width.
    pub min_std_fraction: f64,
    pub chain: ChainConfig,
    /// δ's upper bound (the filter's sample period).
    pub dt: f64,
}

/// The sampling distribution N(mean, (inflate·σ)²) of `belief`'s
/// covariance (σ floored), mixed with uniform draws.
pub fn sampler_around<M: SdeModel + ?Sized>(
    model: &M,
    belief: &Gaussian,
    mean: &[f64],
    p: &FrameBuild,
) -> Option<Sampler> {
    let d = belief.dim;
    let b = model.bounds();
    let mut g = *belief;
    g.mean_mut().copy_from_slice(mean);
    for i in 0..d {
        let floor = p.min_std_fraction * (b.hi()[i] - b.lo()[i]);
        let v = g.cov_at(i, i);
        if v < floor * floor {
            g.set_cov(i, i, floor * floor);
        }
    }
    Sampler::around(&g, p.inflate, p.uniform_fraction)
}

/// Sampling std of a version's cloud per axis: `inflate` × the belief's
/// std, floored as in [`sampler_around`].
fn cloud_std(bounds: &Bounds, belief: &Gaussian, p: &FrameBuild) -> [f64; MAX_STATE] {
    let mut s = [0.0; MAX_STATE];
    for i in 0..belief.dim {
        let floor = p.min_std_fraction * (bounds.hi()[i] - bounds.lo()[i]);
        s[i] = p.inflate * belief.cov_at(i, i).max(0.0).sqrt().max(floor);
    }
    s
}

/// How many sampling std of the cloud must fit inside S on each side of
/// its centre (≈ 1.2 % of a normal axis beyond each face).
pub const CLOUD_FIT: f64 = 2.25;

/// The centre of a version's cloud: the belief mean m moved into S just
/// far enough that `CLOUD_FIT` sampling std s_i fit on each side of it,
///
/// ```text
/// c_i = clamp(m_i, lo_i + k s_i, hi_i − k s_i)   ((lo_i + hi_i)/2 when the interval is empty)
/// (c_a, c_b) ← (c_a, c_b) · min(1, max(R − k max(s_a, s_b), 0) / ‖(c_a, c_b)‖)   (a disc of radius R on axes a, b)
/// ```
///
/// with k = `CLOUD_FIT`. In frame coordinates a state z stands for z + F,
/// so where the cloud sits is free — the filter sets F at the install to
/// the belief mean minus the installed mass's mean, and F moves at
/// f(x̂, u) − f(x̂ − F, u₀) + w, exact while f(z + F, u) − f(z, u₀) does not
/// depend on z (the ship inside its disc: an offset in velocity moves the
/// positions by exactly that offset) — whereas S restricts every draw
/// ([`Sampler::sample`] rejects draws outside it, then falls back to
/// uniform ones). A cloud centred on a belief near or beyond a face of S
/// (the ship's velocities past v_max, which the controlled ship reaches a
/// third of the time at 1 kHz) is cut to a slab on that face and padded
/// with uniform states: the install then puts the belief on one or two
/// states, and the next versions, drawn around that collapsed belief, keep
/// it there (measured in the flagship loop: the belief's effective support
/// 1.0 state for seconds, position errors of 2–12).
///
/// Positions move only near the disc's edge (at most by k·s); the filter
/// corrects the observation for the frame's offset to first order at the
/// mass mean (`LiveChainFilter::update`).
pub fn cloud_centre(bounds: &Bounds, belief: &Gaussian, p: &FrameBuild) -> [f64; MAX_STATE] {
    let d = belief.dim;
    let s = cloud_std(bounds, belief, p);
    let mut c = belief.mean;
    for i in 0..d {
        let (lo, hi) = (bounds.lo()[i], bounds.hi()[i]);
        let (a, b) = (lo + CLOUD_FIT * s[i], hi - CLOUD_FIT * s[i]);
        c[i] = if a <= b {
            c[i].clamp(a, b)
        } else {
            0.5 * (lo + hi)
        };
    }
    if let Some(disc) = bounds.disc() {
        let (i, j) = disc.axes;
        let room = (disc.radius - CLOUD_FIT * s[i].max(s[j])).max(0.0);
        let r = c[i].hypot(c[j]);
        if r > room {
            let f = if r > 0.0 { room / r } else { 0.0 };
            c[i] *= f;
            c[j] *= f;
        }
    }
    c
}

/// A moving-frame version (`refine.moving_frame`): a batch chain (Alg. 2.1)
/// of `n` states drawn around `belief` ([`sampler_around`]), built for
/// f(x, u₀) − w with w the mean drift of its states under the reference
/// control u₀ = `p.chain.control` (the filter computes the same w from the
/// snapshot and its own u₀,
/// [`crate::filter::live_chain::frame_of`]), and δ fitted to its holding
/// times. Built in one go; [`FrameJob`] builds the same version in slices.
pub fn build_framed<M: SdeModel + ?Sized>(
    model: &M,
    belief: &Gaussian,
    n: usize,
    p: &FrameBuild,
    rng: &mut SimRng,
) -> Result<(Chain, TimeEqualized), super::ChainError> {
    let mut job = FrameJob::start(model, belief, n, p, rng)?;
    job.run(model, || true)?;
    job.finish()
}

/// A moving-frame version under construction: the points drawn and w
/// computed at [`FrameJob::start`], the batch chain then built in slices
/// ([`BatchBuild`]) — what [`build_framed`] does in one go, with the same
/// random numbers and the same result.
pub struct FrameJob {
    build: BatchBuild,
    w: [f64; MAX_STATE],
    dt: f64,
}

impl FrameJob {
    /// Draw the `n` states around `belief` and compute w (O(n) model
    /// evaluations); nothing of the chain is built yet.
    pub fn start<M: SdeModel + ?Sized>(
        model: &M,
        belief: &Gaussian,
        n: usize,
        p: &FrameBuild,
        rng: &mut SimRng,
    ) -> Result<Self, super::ChainError> {
        let d = belief.dim;
        let nu = model.dims().control;
        // Around the belief moved into S (see `cloud_centre`): the frame
        // F carries the offset.
        let centre = cloud_centre(model.bounds(), belief, p);
        let sampler = sampler_around(model, belief, &centre[..d], p);
        let mut pts = vec![0.0; n * d];
        for x in pts.chunks_exact_mut(d) {
            match &sampler {
                Some(smp) => smp.sample(model.bounds(), rng, x),
                None => Sampler::Uniform.sample(model.bounds(), rng, x),
            }
        }
        let mut w = [0.0; MAX_STATE];
        let mut f = [0.0; MAX_STATE];
        for x in pts.chunks_exact(d) {
            model.drift(x, &p.chain.control[..nu], &mut f[..d]);
            for a in 0..d {
                w[a] += f[a];
            }
        }
        for wa in &mut w[..d] {
            *wa /= n as f64;
        }
        let framed = Framed { inner: model, w };
        // δ's bound is checked before any work is done.
        TimeEqualized::new(p.dt)?;
        Ok(Self {
            build: BatchBuild::new(&framed, p.chain.clone(), pts)?,
            w,
            dt: p.dt,
        })
    }

    /// Continue the build while `more()` says so (at least one unit of
    /// work per call, see [`BatchBuild::run`]); `model` is the one given to
    /// [`Self::start`]. Returns whether the chain is complete.
    pub fn run<M: SdeModel + ?Sized>(
        &mut self,
        model: &M,
        more: impl FnMut() -> bool,
    ) -> Result<bool, super::ChainError> {
        let framed = Framed {
            inner: model,
            w: self.w,
        };
        self.build.run(&framed, more)
    }

    /// Whether the chain is complete.
    pub fn is_done(&self) -> bool {
        self.build.is_done()
    }

    /// States of the version.
    pub fn len(&self) -> usize {
        self.build.len()
    }

    /// Whether the version has no states.
    pub fn is_empty(&self) -> bool {
        self.build.is_empty()
    }

    /// Units of work done and in all ([`BatchBuild::progress`]).
    pub fn progress(&self) -> (usize, usize) {
        self.build.progress()
    }

    /// The chain and δ fitted to its holding times, once complete.
    pub fn finish(self) -> Result<(Chain, TimeEqualized), super::ChainError> {
        let c = self.build.finish()?;
        let mut eq = TimeEqualized::new(self.dt)?;
        eq.fit(c.holding());
        Ok((c, eq))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::model::forwarding_check::{assert_forwarded, call_each, Counting};

    #[test]
    fn the_framed_model_forwards_every_override() {
        let m = Counting::new();
        let calls = m.calls.clone();
        let framed = Framed {
            inner: &m,
            w: [0.0; MAX_STATE],
        };
        call_each(&framed);
        assert_forwarded(&calls);
    }

    #[test]
    fn the_framed_drift_is_the_drift_less_w_in_both_layouts() {
        use crate::model::vanderpol::{VanDerPol, VanDerPolParams};
        let m = VanDerPol::new(VanDerPolParams::default()).unwrap();
        let mut w = [0.0; MAX_STATE];
        w[0] = 0.5;
        w[1] = -1.5;
        let framed = Framed { inner: &m, w };
        let xs = [[0.3, -1.0], [1.2, 2.0], [-2.0, 0.1]];
        let mut soa = [0.0; 6];
        for (k, x) in xs.iter().enumerate() {
            soa[k] = x[0];
            soa[3 + k] = x[1];
        }
        let mut f_soa = [0.0; 6];
        framed.drift_soa(3, &soa, &[], &mut f_soa);
        for (k, x) in xs.iter().enumerate() {
            let (mut f, mut g) = ([0.0; 2], [0.0; 2]);
            m.drift(x, &[], &mut f);
            framed.drift(x, &[], &mut g);
            assert_eq!([g[0], g[1]], [f[0] - 0.5, f[1] + 1.5]);
            assert_eq!([f_soa[k], f_soa[3 + k]], g);
        }
    }

    fn cloud_params() -> FrameBuild {
        FrameBuild {
            inflate: 2.0,
            uniform_fraction: 0.0,
            min_std_fraction: 0.01,
            chain: ChainConfig::moment_matched(4),
            dt: 0.01,
        }
    }

    /// The ship's S: the disc of radius 9 on the positions, |v_i| ≤ 4.
    fn ship_bounds() -> Bounds {
        Bounds::new_box(&[-9.0, -9.0, -4.0, -4.0], &[9.0, 9.0, 4.0, 4.0])
            .unwrap()
            .with_disc((0, 1), 9.0)
            .unwrap()
    }

    #[test]
    fn the_cloud_centre_is_the_belief_mean_moved_just_inside_s() {
        let b = ship_bounds();
        let p = cloud_params();
        let k = CLOUD_FIT;
        // Well inside: unchanged.
        let g = Gaussian::diagonal(&[1.0, -2.0, 0.5, -1.0], &[0.2, 0.2, 0.3, 0.3]);
        let c = cloud_centre(&b, &g, &p);
        assert_eq!(&c[..4], &g.mean[..4]);
        // v₁ = 6 and v₂ = −4.5 beyond their faces, v std 0.3 → s = 0.6:
        // the centre sits k·s inside each face; the positions stay.
        let g = Gaussian::diagonal(&[1.0, -2.0, 6.0, -4.5], &[0.2, 0.2, 0.3, 0.3]);
        let c = cloud_centre(&b, &g, &p);
        assert_eq!(&c[..2], &g.mean[..2]);
        assert!((c[2] - (4.0 - k * 0.6)).abs() < 1e-12, "{}", c[2]);
        assert!((c[3] - (-4.0 + k * 0.6)).abs() < 1e-12, "{}", c[3]);
        // An axis too narrow for ±k·s: its midpoint.
        let g = Gaussian::diagonal(&[1.0, -2.0, 3.0, 0.0], &[0.2, 0.2, 2.0, 0.3]);
        assert_eq!(cloud_centre(&b, &g, &p)[2], 0.0);
        // Near the wall: radially inward to R − k·max(s₁, s₂), direction kept.
        let g = Gaussian::diagonal(&[6.0, 6.0, 0.0, 0.0], &[0.2, 0.25, 0.3, 0.3]);
        let c = cloud_centre(&b, &g, &p);
        let room = 9.0 - k * 0.5;
        assert!((c[0].hypot(c[1]) - room).abs() < 1e-12);
        assert!((c[0] - c[1]).abs() < 1e-12);
        // The std floor counts: a collapsed velocity std (1e-4) uses
        // min_std_fraction · 8 = 0.08, s = 0.16.
        let g = Gaussian::diagonal(&[0.0, 0.0, 9.0, 0.0], &[0.2, 0.2, 1e-4, 0.3]);
        let c = cloud_centre(&b, &g, &p);
        assert!((c[2] - (4.0 - k * 0.16)).abs() < 1e-12, "{}", c[2]);
    }

    /// A version drawn around a ship belief moving at v₁ = 6 (beyond
    /// v_max = 4): every state is a draw of N(c, (inflate σ)²) around the
    /// moved centre, none a uniform fallback — the sample mean of each axis
    /// agrees with it within 5 standard errors (truncation at k = 2.25 std
    /// moves a mean by at most 0.032 s), its std within 10 %, and no state
    /// is farther than 6 s from c on any axis (a uniform draw on S is, with
    /// probability above one half). Drawn around the mean itself, the
    /// states would sit in a slab v₁ ∈ [~3.5, 4] and the rest be uniform.
    #[test]
    fn a_version_around_a_belief_beyond_a_face_of_s_is_a_full_cloud_inside_it() {
        use crate::model::ship::{Ship, ShipParams};
        let ship = Ship::new(ShipParams::paper(0.001)).unwrap();
        let p = cloud_params();
        let g = Gaussian::diagonal(&[2.0, 1.0, 6.0, -0.5], &[0.2, 0.2, 0.3, 0.3]);
        let c = cloud_centre(ship.bounds(), &g, &p);
        let n = 2000;
        let (chain, _) = build_framed(&ship, &g, n, &p, &mut crate::rng::stream(5, 1)).unwrap();
        assert_eq!(chain.len(), n);
        for a in 0..4 {
            let s = p.inflate * g.cov_at(a, a).sqrt();
            let xs: Vec<f64> = (0..n).map(|i| chain.state(i)[a]).collect();
            let mean = xs.iter().sum::<f64>() / n as f64;
            let sd = (xs.iter().map(|v| (v - mean).powi(2)).sum::<f64>() / n as f64).sqrt();
            let se = s / (n as f64).sqrt();
            assert!(
                (mean - c[a]).abs() < 5.0 * se,
                "axis {a}: mean {mean} vs {}",
                c[a]
            );
            assert!((sd / s - 1.0).abs() < 0.1, "axis {a}: sd {sd} vs {s}");
            assert!(xs.iter().all(|v| (v - c[a]).abs() < 6.0 * s), "axis {a}");
        }
    }

    #[test]
    fn a_version_built_in_slices_is_the_version_built_at_once() {
        use crate::chain::{moment_equations, NearRule};
        use crate::model::ship::{Ship, ShipParams};
        let ship = Ship::new(ShipParams::paper(0.01)).unwrap();
        let belief = Gaussian::diagonal(&[3.0, 0.5, 1.0, -0.5], &[0.3, 0.3, 0.2, 0.2]);
        let p = FrameBuild {
            inflate: 2.0,
            uniform_fraction: 0.02,
            min_std_fraction: 0.01,
            chain: ChainConfig::moment_matched(4).with_near(NearRule::Knn { c: 1.5 }),
            dt: 0.01,
        };
        assert!(p.chain.min_neighbours > moment_equations(4));
        let (mut whole, eq) =
            build_framed(&ship, &belief, 400, &p, &mut crate::rng::stream(3, 1)).unwrap();
        let mut job =
            FrameJob::start(&ship, &belief, 400, &p, &mut crate::rng::stream(3, 1)).unwrap();
        let mut slices = 1;
        // Slices of 25 units each.
        loop {
            let mut left = 25;
            if job
                .run(&ship, || {
                    left -= 1;
                    left > 0
                })
                .unwrap()
            {
                break;
            }
            slices += 1;
        }
        assert_eq!(slices, (2 * 400 + 2usize).div_ceil(25));
        let (mut sliced, eq2) = job.finish().unwrap();
        assert_eq!(eq2.delta(), eq.delta());
        assert_eq!(sliced.states(), whole.states());
        assert_eq!(sliced.holding(), whole.holding());
        let (vs, vw) = (sliced.view(), whole.view());
        assert_eq!((vs.cols, vs.probs), (vw.cols, vw.probs));
    }
}
