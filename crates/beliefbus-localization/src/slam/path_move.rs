//! Resample-move for implicit SLAM (reading (i)): after a resampling,
//! every particle's last W poses are moved by Metropolis–Hastings steps
//! that leave the particle posterior invariant (Gilks & Berzuini 2001,
//! "resample-move"; Doucet, de Freitas & Gordon 2001 §1.3).
//!
//! The target. A particle of [`super::implicit::ImplicitSlam`] is a path
//! X_{0:n} and *sampled* landmark positions θ; its importance weight is for
//! the joint posterior p(X_{0:n}, θ | u, z) with a flat prior 1/A on each
//! θ. With θ and the poses before the window held, the window's poses
//! X_{n−W+1:n} have the exact conditional
//!
//! ```text
//! π(X_w) ∝ Π_{s in window} N(x_s; f(x_{s−1}, u_s), Σ₁(β_{s−1}))
//!          · Π_{sightings i at s} N(z_i; h(x_s, θ_{k_i}), Σ₂)
//! ```
//!
//! (det Σ₁(β) = det Σ₀ does not depend on the heading, so the motion
//! normalisers cancel). Each pose in turn gets a random-walk proposal
//! x' = x + c T(β_{s−1}) C₀ ξ (C₀ the step's Cholesky factor, the rotation
//! taken at the held previous pose so the proposal is symmetric) accepted
//! with probability min(1, e^{E(x) − E(x')}), E the terms of π that contain
//! x_s: its own motion term, the next step's motion term and its
//! sightings. A π-invariant kernel applied to each particle keeps a weighted
//! set targeting the joint posterior, so the weights are not touched.
//!
//! Why this target and not the window with the landmark updates re-done:
//! in reading (i) θ is part of the state, so the conditional above is exact
//! with nothing linearised and nothing but the window's sightings stored.
//! Moving θ as well would need every earlier sighting of each landmark,
//! which reading (i) does not keep. The association of each return is the
//! one the particle made when the return arrived; the move treats it as
//! data.
//!
//! Storage: the controls, step lengths and Σ₀ factors of the window are
//! shared by all particles (one ring of W + 1 slots); each particle has a
//! row of W + 1 poses and of up to [`MAX_SIGHTINGS`] sightings per slot in
//! flat buffers, sized once. A pose whose step had more sightings than that
//! is held fixed (moving it without all its terms would change π). A
//! resampling copies the rows in O(M·W); a move costs O(M·W·sweeps).

use super::assoc::RangeBearing;
use crate::carpark::normal3;
use crate::error::LocalizationError;
use crate::geometry::{wrap_angle, Point, Pose};
use crate::laser::{term_cost, LaserNoise, Observation};
use crate::vehicle::{Control, StepNoise, Ute};
use beliefbus_core::rng::SimRng;
use rand::RngExt;

/// Sightings kept per particle and window step.
pub const MAX_SIGHTINGS: usize = 8;

/// The move's settings.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct MoveConfig {
    /// Poses moved (the window W).
    pub window: usize,
    /// Sweeps over the window per move.
    pub sweeps: usize,
    /// c: the random walk's scale relative to the step noise.
    pub scale: f64,
}

impl MoveConfig {
    pub fn validate(&self) -> Result<(), LocalizationError> {
        if self.window == 0 || self.sweeps == 0 {
            return Err(LocalizationError::Invalid {
                name: "move window / sweeps",
                value: 0.0,
                need: "must be at least 1",
            });
        }
        LocalizationError::positive("move scale", self.scale).map(|_| ())
    }
}

/// One window step's shared data: the vehicle (its dt), the control and Σ₀.
#[derive(Clone, Copy, Debug)]
struct StepData {
    ute: Ute,
    u: Control,
    noise: StepNoise,
}

/// A sighting kept for the move: the landmark's index in the particle's
/// map and the return.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Sighting {
    pub landmark: usize,
    pub z: RangeBearing,
}

/// The window of every particle.
#[derive(Clone, Debug)]
pub struct PathWindow {
    pub cfg: MoveConfig,
    m: usize,
    slots: usize,
    head: usize,
    len: usize,
    steps: Vec<Option<StepData>>,
    poses: Vec<Pose>,
    tmp_poses: Vec<Pose>,
    sights: Vec<Sighting>,
    tmp_sights: Vec<Sighting>,
    /// Sightings per (particle, slot); MAX_SIGHTINGS + 1 marks an overflow.
    count: Vec<u8>,
    tmp_count: Vec<u8>,
    /// Proposals made and accepted, over the run.
    pub proposed: usize,
    pub accepted: usize,
}

impl PathWindow {
    pub fn new(m: usize, cfg: MoveConfig) -> Result<Self, LocalizationError> {
        cfg.validate()?;
        let slots = cfg.window + 1;
        let blank = Sighting {
            landmark: 0,
            z: RangeBearing {
                range: 0.0,
                bearing: 0.0,
            },
        };
        Ok(Self {
            cfg,
            m,
            slots,
            head: 0,
            len: 1,
            steps: vec![None; slots],
            poses: vec![Pose::zeros(); m * slots],
            tmp_poses: vec![Pose::zeros(); m * slots],
            sights: vec![blank; m * slots * MAX_SIGHTINGS],
            tmp_sights: vec![blank; m * slots * MAX_SIGHTINGS],
            count: vec![0; m * slots],
            tmp_count: vec![0; m * slots],
            proposed: 0,
            accepted: 0,
        })
    }

    /// Every particle at `start`, the window empty.
    pub fn reset(&mut self, start: &Pose) {
        self.head = 0;
        self.len = 1;
        self.steps.fill(None);
        self.count.fill(0);
        for j in 0..self.m {
            self.poses[j * self.slots] = *start;
        }
        self.proposed = 0;
        self.accepted = 0;
    }

    /// The slot of the pose `age` steps back (0: the newest).
    fn slot(&self, age: usize) -> usize {
        (self.head + self.slots - age) % self.slots
    }

    /// Open the next step (shared data); its poses and sightings follow.
    pub fn advance(&mut self, ute: Ute, u: Control, noise: StepNoise) {
        self.head = (self.head + 1) % self.slots;
        self.len = (self.len + 1).min(self.slots);
        self.steps[self.head] = Some(StepData { ute, u, noise });
        for j in 0..self.m {
            self.count[j * self.slots + self.head] = 0;
        }
    }

    /// Particle j's pose at the newest step.
    pub fn set_pose(&mut self, j: usize, x: Pose) {
        self.poses[j * self.slots + self.head] = x;
    }

    /// Particle j's pose `age` steps back.
    pub fn pose(&self, j: usize, age: usize) -> Pose {
        self.poses[j * self.slots + self.slot(age)]
    }

    /// Poses kept (the newest and up to W before it).
    pub fn len(&self) -> usize {
        self.len
    }

    pub fn is_empty(&self) -> bool {
        self.len == 0
    }

    /// The number of particles.
    pub fn particles(&self) -> usize {
        self.m
    }

    /// A sighting of particle j at the newest step.
    pub fn add_sighting(&mut self, j: usize, landmark: usize, z: RangeBearing) {
        let c = &mut self.count[j * self.slots + self.head];
        if (*c as usize) < MAX_SIGHTINGS {
            self.sights[(j * self.slots + self.head) * MAX_SIGHTINGS + *c as usize] =
                Sighting { landmark, z };
            *c += 1;
        } else {
            *c = MAX_SIGHTINGS as u8 + 1;
        }
    }

    /// Copy every particle's row from its ancestor `anc[j]` (after a
    /// resampling).
    pub fn resample(&mut self, anc: &[usize]) {
        let s = self.slots;
        for (j, &a) in anc.iter().enumerate() {
            self.tmp_poses[j * s..(j + 1) * s].copy_from_slice(&self.poses[a * s..(a + 1) * s]);
            self.tmp_count[j * s..(j + 1) * s].copy_from_slice(&self.count[a * s..(a + 1) * s]);
            let k = MAX_SIGHTINGS * s;
            self.tmp_sights[j * k..(j + 1) * k].copy_from_slice(&self.sights[a * k..(a + 1) * k]);
        }
        std::mem::swap(&mut self.poses, &mut self.tmp_poses);
        std::mem::swap(&mut self.count, &mut self.tmp_count);
        std::mem::swap(&mut self.sights, &mut self.tmp_sights);
    }

    /// The terms of π containing the pose at `age` (≤ len − 2), at value x:
    /// its own motion term from the pose before it, the next pose's motion
    /// term (unless it is the newest) and its sightings against `lm`.
    fn energy(
        &self,
        j: usize,
        age: usize,
        x: &Pose,
        laser: &LaserNoise,
        lm: &impl Fn(usize) -> Point,
    ) -> f64 {
        let s = self.slot(age);
        let prev = self.pose(j, age + 1);
        let d = self.steps[s].expect("a kept pose has its step");
        let mut r = x - d.ute.predict_mean(&prev, d.u);
        // The heading residual wrapped as in the filters' own motion term.
        r[2] = wrap_angle(r[2]);
        let mut e = 0.5 * r.dot(&(d.noise.precision(prev[2]) * r));
        if age > 0 {
            let dn = self.steps[self.slot(age - 1)].expect("a kept pose has its step");
            let mut rn = self.pose(j, age - 1) - dn.ute.predict_mean(x, dn.u);
            rn[2] = wrap_angle(rn[2]);
            e += 0.5 * rn.dot(&(dn.noise.precision(x[2]) * rn));
        }
        let c = self.count[j * self.slots + s] as usize;
        for i in 0..c {
            let si = self.sights[(j * self.slots + s) * MAX_SIGHTINGS + i];
            let o = Observation {
                range: si.z.range,
                bearing: si.z.bearing,
                landmark: 0,
            };
            e += term_cost(x, lm(si.landmark), &o, laser);
        }
        e
    }

    /// Move particle j's window (oldest pose first, the anchor held), with
    /// `lm` its map; returns its new newest pose.
    pub fn move_particle(
        &mut self,
        j: usize,
        laser: &LaserNoise,
        lm: impl Fn(usize) -> Point,
        rng: &mut SimRng,
    ) -> Pose {
        for _ in 0..self.cfg.sweeps {
            for age in (0..self.len.saturating_sub(1)).rev() {
                let s = self.slot(age);
                if self.count[j * self.slots + s] as usize > MAX_SIGHTINGS {
                    continue;
                }
                let x = self.pose(j, age);
                let prev = self.pose(j, age + 1);
                let d = self.steps[s].expect("a kept pose has its step");
                let xp = x + d.noise.draw(prev[2], &normal3(rng)) * self.cfg.scale;
                let de = self.energy(j, age, &xp, laser, &lm) - self.energy(j, age, &x, laser, &lm);
                self.proposed += 1;
                let u: f64 = rng.random();
                if de.is_finite() && u.ln() < -de {
                    self.poses[j * self.slots + s] = xp;
                    self.accepted += 1;
                }
            }
        }
        self.pose(j, 0)
    }
}
