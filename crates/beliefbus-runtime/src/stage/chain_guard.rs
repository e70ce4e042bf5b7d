//! Stale-chain fallback of the filter stage: when is the live
//! chain filter's belief published, and when a Gaussian filter's that runs
//! beside it on every observation.
//!
//! The moving-frame chain (`refine.moving_frame`) needs a fresh version
//! every `refine.publish_period_ms`: each version is a point cloud built
//! around the belief of its time, and the frame only carries the belief's
//! translation. When refine (nice 19) is starved of CPU, stopped or dead,
//! the last version grows old and the chain loses track (one version in
//! 30 s gave rmse_position 7.7 against the PF's 0.3). The filter stage
//! therefore runs a cheap Gaussian filter (the EKF of `[filter.ekf]`) on
//! every observation next to the chain, and [`StaleGuard`] decides per
//! step which of the two beliefs goes out.
//!
//! **Stale** (checked after each update, in this order):
//! 1. *degenerate* — the chain's update was refused or had to re-spread its
//!    mass (no state with mass explained the observation: the belief left
//!    the version's support);
//! 2. *age* — moving frame only: the installed version is older than
//!    `max_age_ms` (filter clock, from its install; default 1000 ms, five
//!    of the default config's 200 ms publish periods). An absolute time, not
//!    a multiple of the publish period: how long a version stays valid is a
//!    property of the belief's motion, and a refine configured (or forced)
//!    to publish slowly must not stretch it. A fixed-frame (incremental)
//!    chain is one point set for the whole run and stays valid until its
//!    belief leaves it, which 1 and 3 see;
//! 3. *evidence* — the chain predicts the observations worse than the
//!    fallback: with ℓ = log p(y_k | y_{1:k−1}) of each filter's update
//!    (the chain's mixture Σ_z φ(z) N(y; g(z), R), the EKF's
//!    N(y; g(m), HPHᵀ + R)), the average of Δ_k = ℓ_chain − ℓ_fallback
//!    over about `evidence_window` observations,
//!    e_k = e_{k−1} + (clamp(Δ_k, ±EVIDENCE_CLAMP) − e_{k−1}) / window,
//!    falls below −`evidence_margin` nats. The predictive log-likelihood is
//!    a proper score, so this is the comparison "which filter explains the
//!    data better right now" that needs no ground truth; the clamp keeps
//!    one outlier from deciding alone.
//!
//! **Episodes.** The first stale step opens an episode: from then on the
//! fallback's belief is published (flagged `belief_status::CHAIN_FALLBACK`)
//! while the chain keeps filtering on its last version (so "refine died"
//! still means "filtering goes on with the last chain", and nothing has to
//! be rebuilt when it comes back). The episode ends when a new version is
//! installed: the chain's belief is then re-initialised from the fallback's
//! Gaussian on that version ([`StaleGuard::installed`] returns true), and
//! the chain is published again. Ending only at an install (hysteresis)
//! keeps the published belief from flapping between two filters whose means
//! differ, and a chain that was judged worse than the fallback on one
//! version is not trusted again before it gets a new one.
//!
//! **Tether.** On an install outside an episode the fallback is reset to the
//! chain's belief when the chain explained the data at least as well since
//! the last install (evidence average ≥ 0): it then starts each version at
//! the chain's accuracy and only has to carry the belief over one episode.
//! When the chain was doubtful (average < 0 but not yet below −margin) the
//! fallback stays independent: tethering it then would copy the chain's
//! error into it every version, and the evidence test could never see the
//! difference (measured: `configs/ship-1khz.toml` on the fixed-frame chain,
//! which loses track under MPPI, ended at rmse 8.45 with an always-tethered
//! fallback). So the fallback is at least as good as the last chain
//! in the two cases it stands in for: the last chain going stale by age
//! (the fallback took its belief at the last install) and a chain that
//! explains the data worse (criterion 3 is exactly "worse").
//!
//! Counted ([`StaleGuard::counts`]): steps published from the fallback,
//! episodes (by their opening cause), re-initialisations from the
//! fallback, and the oldest version age seen at a step. The guard is plain
//! arithmetic on a few numbers: no allocation on the per-observation path.

/// One step's Δ is clamped to ±this many nats before it enters the average.
pub const EVIDENCE_CLAMP: f64 = 20.0;

pub use crate::config::stale::StaleConfig;

/// What an install does with the two beliefs.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Install {
    /// It ends a stale episode: the chain starts from the fallback's belief.
    Reinit,
    /// The chain explained the data at least as well as the fallback since
    /// the last install (evidence average ≥ 0): the fallback takes the
    /// chain's belief.
    Tether,
    /// The chain was doubtful (evidence average < 0, not yet stale): the
    /// fallback stays independent, so that it can still win.
    Keep,
}

/// Which belief a step publishes.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Source {
    Chain,
    Fallback,
}

/// What opened a stale episode (index into [`GuardCounts::by_cause`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq, strum::IntoStaticStr, strum::VariantNames)]
#[strum(serialize_all = "snake_case")]
#[repr(usize)]
pub enum Cause {
    Degenerate = 0,
    Age = 1,
    Evidence = 2,
}

impl Cause {
    pub const ALL: [Cause; 3] = [Cause::Degenerate, Cause::Age, Cause::Evidence];
    /// Report name.
    pub fn name(self) -> &'static str {
        self.into()
    }
}

/// One filter step as the guard sees it.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Step {
    /// The chain's log predictive likelihood of the observation (None: its
    /// update was refused).
    pub chain: Option<f64>,
    /// The fallback's (None: refused).
    pub fallback: Option<f64>,
    /// The chain re-spread its mass in this update.
    pub respread: bool,
}

/// What the guard counted.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct GuardCounts {
    /// Steps whose published belief came from the fallback.
    pub fallback_steps: u64,
    /// Stale episodes opened, and by cause.
    pub episodes: u64,
    pub by_cause: [u64; 3],
    /// Chain beliefs re-initialised from the fallback (episodes ended by a
    /// new version).
    pub reinits: u64,
    /// Largest age of the installed version at a step, ns.
    pub stale_max_ns: u64,
    /// Installs that left the fallback untethered ([`Install::Keep`]).
    pub untethered: u64,
}

/// The staleness decision (see the module docs).
#[derive(Clone, Debug)]
pub struct StaleGuard {
    max_age_ns: u64,
    inv_window: f64,
    margin: f64,
    installed_ns: Option<u64>,
    evidence: f64,
    episode: bool,
    counts: GuardCounts,
}

impl StaleGuard {
    /// A guard for `cfg`; the age criterion applies when `moving` (the
    /// moving frame).
    pub fn new(cfg: &StaleConfig, moving: bool) -> Self {
        let age_ms = if moving { cfg.max_age_ms } else { 0.0 };
        Self {
            max_age_ns: (age_ms.max(0.0) * 1e6) as u64,
            inv_window: 1.0 / cfg.evidence_window.max(1.0),
            margin: cfg.evidence_margin,
            installed_ns: None,
            evidence: 0.0,
            episode: false,
            counts: GuardCounts::default(),
        }
    }

    /// A version was installed at `now_ns`: what the caller does with the
    /// two beliefs (see [`Install`]). The evidence average restarts when
    /// they are made equal, and runs on when the fallback stays apart.
    pub fn installed(&mut self, now_ns: u64) -> Install {
        self.installed_ns = Some(now_ns);
        if std::mem::replace(&mut self.episode, false) {
            self.counts.reinits += 1;
            self.evidence = 0.0;
            Install::Reinit
        } else if self.evidence >= 0.0 {
            self.evidence = 0.0;
            Install::Tether
        } else {
            self.counts.untethered += 1;
            Install::Keep
        }
    }

    /// Whether the chain's belief of the step just filtered at `now_ns` is
    /// stale (see the module docs): `chain_ok` its update succeeded,
    /// `respread` it re-spread its mass. Opens an episode on the first stale
    /// step. The evidence criterion uses the average up to the previous
    /// step, so that in a healthy step the fallback can run after the
    /// chain's belief is published (off the sensor→belief path) and be
    /// scored then ([`Self::score`]). Before the first version nothing is
    /// judged (the chain filter answers with its own Gaussian filter).
    pub fn check(&mut self, now_ns: u64, chain_ok: bool, respread: bool) -> bool {
        let Some(t_in) = self.installed_ns else {
            return false;
        };
        let age = now_ns.saturating_sub(t_in);
        self.counts.stale_max_ns = self.counts.stale_max_ns.max(age);
        if !self.episode {
            let cause = if !chain_ok || respread {
                Cause::Degenerate
            } else if self.max_age_ns > 0 && age > self.max_age_ns {
                Cause::Age
            } else if self.margin > 0.0 && self.evidence < -self.margin {
                Cause::Evidence
            } else {
                return false;
            };
            self.episode = true;
            self.counts.episodes += 1;
            self.counts.by_cause[cause as usize] += 1;
        }
        true
    }

    /// Add one step's predictive log-likelihoods to the evidence average
    /// (a refused update on either side adds nothing).
    pub fn score(&mut self, chain: Option<f64>, fallback: Option<f64>) {
        if self.installed_ns.is_none() {
            return;
        }
        if let (Some(c), Some(f)) = (chain, fallback) {
            let d = (c - f).clamp(-EVIDENCE_CLAMP, EVIDENCE_CLAMP);
            if d.is_finite() {
                self.evidence += (d - self.evidence) * self.inv_window;
            }
        }
    }

    /// Count a step whose published belief is the fallback's.
    pub fn published_fallback(&mut self) {
        self.counts.fallback_steps += 1;
    }

    /// [`Self::check`], [`Self::score`] and the choice for one step with
    /// both updates done: the fallback's belief when stale, unless its
    /// update was refused and the chain's was not.
    pub fn judge(&mut self, now_ns: u64, s: Step) -> Source {
        let stale = self.check(now_ns, s.chain.is_some(), s.respread);
        self.score(s.chain, s.fallback);
        if !stale || (s.fallback.is_none() && s.chain.is_some()) {
            return Source::Chain;
        }
        self.published_fallback();
        Source::Fallback
    }

    /// Whether a stale episode is open.
    pub fn stale(&self) -> bool {
        self.episode
    }
    /// The evidence average e (nats per observation, chain − fallback).
    pub fn evidence(&self) -> f64 {
        self.evidence
    }
    /// What was counted so far.
    pub fn counts(&self) -> GuardCounts {
        self.counts
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const MS: u64 = 1_000_000;

    fn ok(c: f64, f: f64) -> Step {
        Step {
            chain: Some(c),
            fallback: Some(f),
            respread: false,
        }
    }

    #[test]
    fn before_the_first_version_nothing_is_judged() {
        let mut g = StaleGuard::new(&StaleConfig::default(), true);
        for k in 0..100 {
            assert_eq!(g.judge(k * 10 * MS, ok(-50.0, 0.0)), Source::Chain);
        }
        assert_eq!(g.counts(), GuardCounts::default());
    }

    #[test]
    fn an_old_version_opens_an_episode_that_the_next_install_ends() {
        let mut g = StaleGuard::new(&StaleConfig::default(), true);
        assert_eq!(g.installed(0), Install::Tether);
        let mut first_stale = None;
        for k in 1..=150u64 {
            let t = k * 10 * MS;
            if g.judge(t, ok(-1.0, -1.0)) == Source::Fallback && first_stale.is_none() {
                first_stale = Some(t);
            }
        }
        // The first step past 1000 ms, and every step after it.
        assert_eq!(first_stale, Some(1010 * MS));
        let c = g.counts();
        assert_eq!((c.episodes, c.fallback_steps), (1, 50));
        assert_eq!(c.by_cause[Cause::Age as usize], 1);
        assert_eq!(c.stale_max_ns, 1500 * MS);
        // A fresh version ends it: the caller re-initialises the chain.
        assert_eq!(g.installed(1505 * MS), Install::Reinit);
        assert!(!g.stale());
        assert_eq!(g.judge(1510 * MS, ok(-1.0, -1.0)), Source::Chain);
        assert_eq!(g.counts().reinits, 1);
        // A second install outside an episode is a tether, not a re-init,
        // while the chain is at least as good as the fallback; a doubtful
        // chain (average < 0, above −margin) leaves the fallback apart and
        // its average runs on.
        assert_eq!(g.installed(1700 * MS), Install::Tether);
        assert_eq!(g.counts().reinits, 1);
        g.judge(1710 * MS, ok(-2.0, -1.0));
        let e = g.evidence();
        assert!(e < 0.0 && e > -2.0);
        assert_eq!(g.installed(1720 * MS), Install::Keep);
        assert_eq!((g.evidence(), g.counts().untethered), (e, 1));
    }

    #[test]
    fn a_fixed_frame_chain_never_goes_stale_by_age() {
        let mut g = StaleGuard::new(&StaleConfig::default(), false);
        g.installed(0);
        for k in 1..=6000u64 {
            assert_eq!(g.judge(k * 10 * MS, ok(-1.0, -1.5)), Source::Chain);
        }
        assert_eq!(g.counts().episodes, 0);
        assert_eq!(g.counts().stale_max_ns, 60_000 * MS);
    }

    #[test]
    fn evidence_opens_an_episode_when_the_average_deficit_passes_the_margin() {
        let cfg = StaleConfig {
            evidence_window: 10.0,
            evidence_margin: 2.0,
            ..StaleConfig::default()
        };
        let mut g = StaleGuard::new(&cfg, true);
        g.installed(0);
        // A 5-nat deficit per step: e_k = −5(1 − 0.9^k) < −2 first at
        // k = 5 (−5·(1 − 0.59049) = −2.05; k = 4: −1.72); step k is judged
        // on e_{k−1}, so step 6 is the first stale one.
        let mut k_stale = None;
        for k in 1..=8u64 {
            if g.judge(k * MS, ok(-6.0, -1.0)) == Source::Fallback && k_stale.is_none() {
                k_stale = Some(k);
            }
        }
        assert_eq!(k_stale, Some(6));
        assert_eq!(g.counts().by_cause[Cause::Evidence as usize], 1);
        assert!((g.evidence() + 5.0 * (1.0 - 0.9f64.powi(8))).abs() < 1e-12);
        // A chain as good as the fallback, or better, is never stale by
        // evidence; one outlier is clamped to 20 nats: 20/10 = 2 is not
        // below the margin.
        let mut g = StaleGuard::new(&cfg, true);
        g.installed(0);
        assert_eq!(g.judge(MS, ok(-1e6, 0.0)), Source::Chain);
        assert!((g.evidence() + 2.0).abs() < 1e-12);
        for k in 2..100 {
            assert_eq!(g.judge(k * MS, ok(0.5, 0.0)), Source::Chain);
        }
    }

    #[test]
    fn a_refused_or_respread_chain_update_is_stale_at_once() {
        let mut g = StaleGuard::new(&StaleConfig::default(), true);
        g.installed(0);
        let s = Step {
            respread: true,
            ..ok(-1.0, -1.0)
        };
        assert_eq!(g.judge(MS, s), Source::Fallback);
        assert_eq!(g.counts().by_cause[Cause::Degenerate as usize], 1);
        let mut g = StaleGuard::new(&StaleConfig::default(), true);
        g.installed(0);
        let s = Step {
            chain: None,
            fallback: Some(-1.0),
            respread: false,
        };
        assert_eq!(g.judge(MS, s), Source::Fallback);
        // In an episode a refused fallback update leaves the chain's belief.
        let s = Step {
            chain: Some(-1.0),
            fallback: None,
            respread: false,
        };
        assert_eq!(g.judge(2 * MS, s), Source::Chain);
        assert_eq!(g.counts().fallback_steps, 1);
        assert!(g.stale());
    }

    #[test]
    fn config_rejects_bad_values() {
        assert!(StaleConfig::default().validate().is_ok());
        let bad = [
            StaleConfig {
                max_age_ms: -1.0,
                ..StaleConfig::default()
            },
            StaleConfig {
                evidence_window: 0.5,
                ..StaleConfig::default()
            },
            StaleConfig {
                evidence_margin: f64::NAN,
                ..StaleConfig::default()
            },
        ];
        for b in bad {
            assert!(b.validate().is_err(), "{b:?}");
        }
    }
}
