//! Scoring a filter's data association against the truth (synthetic data
//! only, diagnostics): every landmark of a map is tagged with the true
//! landmark of the return that started it, and each later association of
//! a return is checked against that tag. Per map (a particle's or
//! EKF-SLAM's) and return whose true landmark `t` is known:
//!
//! - `Known(k)` is *wrong* when map entry k was started by another true
//!   landmark (tag(k) ≠ t): the return corrects the wrong estimate;
//! - `New` is *missed* when the map already holds an entry started by t:
//!   the return starts a duplicate instead of re-observing it;
//! - `Discard` is neither (it is counted in [`super::SlamStats::discarded`]).
//!
//! Both are counted per map and return ("scored"), so for a particle
//! filter they are fractions of the M per-particle associations, each
//! particle judged by its own map's lineage: a particle that merged two
//! landmarks earlier keeps the first one's tag, and re-observations of
//! either go on being scored against it. The tags follow the maps through
//! resampling ([`super::particles::SlamParticles`]). A map whose length
//! stops matching its tags (a filter that removes landmarks, or one that
//! does not report) makes the run's figures unavailable rather than wrong.

use super::assoc::Association;
use super::map::SharedMap;

/// The step's true landmarks and the run's counts.
#[derive(Clone, Debug, Default)]
pub struct AssocAudit {
    /// True landmark of each return of the coming step; empty: not scored.
    truth: Vec<u32>,
    scored: usize,
    wrong: usize,
    missed: usize,
    broken: bool,
}

/// A run's association counts: returns scored (summed over maps), wrong
/// and missed associations among them.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct AuditCounts {
    pub scored: usize,
    pub wrong: usize,
    pub missed: usize,
}

impl AuditCounts {
    /// Wrong and missed associations per association scored; NaN when
    /// nothing was scored.
    pub fn rates(&self) -> (f64, f64) {
        if self.scored == 0 {
            return (f64::NAN, f64::NAN);
        }
        let n = self.scored as f64;
        (self.wrong as f64 / n, self.missed as f64 / n)
    }
}

impl AssocAudit {
    /// Forget the counts (a new run).
    pub fn reset(&mut self) {
        *self = Self {
            truth: std::mem::take(&mut self.truth),
            ..Self::default()
        };
        self.truth.clear();
    }

    /// The true landmarks of the next step's returns, one per return
    /// (empty: the step is not scored).
    pub fn set_truth(&mut self, ids: &[usize]) {
        self.truth.clear();
        self.truth.extend(ids.iter().map(|&i| i as u32));
    }

    /// Score one map's associations `assoc` of this step's returns and tag
    /// the entries they started. `tags` held one tag per entry of the map
    /// before the step (`before` entries); the map now has `after`.
    pub fn score(
        &mut self,
        tags: &mut SharedMap<u32>,
        before: usize,
        after: usize,
        assoc: &[Association],
    ) {
        if self.broken || self.truth.is_empty() || self.truth.len() != assoc.len() {
            return;
        }
        if tags.len() != before {
            self.broken = true;
            return;
        }
        for (a, &t) in assoc.iter().zip(&self.truth) {
            match *a {
                Association::Known(k) => {
                    self.scored += 1;
                    if tags.get(k) != Some(&t) {
                        self.wrong += 1;
                    }
                }
                Association::New => {
                    self.scored += 1;
                    if tags.iter().take(before).any(|&g| g == t) {
                        self.missed += 1;
                    }
                    tags.push(t);
                }
                Association::Discard => {}
            }
        }
        if tags.len() != after {
            self.broken = true;
        }
    }

    /// The counts so far; nothing scored if the tags lost step with a map.
    pub fn counts(&self) -> AuditCounts {
        if self.broken {
            return AuditCounts::default();
        }
        AuditCounts {
            scored: self.scored,
            wrong: self.wrong,
            missed: self.missed,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use Association::{Discard, Known, New};

    /// A hand-worked sequence on one map: landmarks 7 and 9 start entries
    /// 0 and 1; a 9 given to entry 0 is wrong, a second New for 7 is a
    /// missed one (and starts entry 2), a discard is not scored.
    #[test]
    fn counts_match_a_hand_worked_sequence() {
        let mut a = AssocAudit::default();
        let mut tags = SharedMap::new();
        let mut len = 0;
        let mut step = |a: &mut AssocAudit, tags: &mut SharedMap<u32>, t: usize, s: Association| {
            a.set_truth(&[t]);
            let after = len + usize::from(s == New);
            a.score(tags, len, after, &[s]);
            len = after;
        };
        step(&mut a, &mut tags, 7, New);
        step(&mut a, &mut tags, 9, New);
        step(&mut a, &mut tags, 7, Known(0));
        step(&mut a, &mut tags, 9, Known(0));
        step(&mut a, &mut tags, 7, New);
        step(&mut a, &mut tags, 9, Discard);
        step(&mut a, &mut tags, 7, Known(2));
        assert_eq!(
            a.counts(),
            AuditCounts {
                scored: 6,
                wrong: 1,
                missed: 1
            }
        );
        assert_eq!(tags.iter().copied().collect::<Vec<_>>(), vec![7, 9, 7]);
        let (w, m) = a.counts().rates();
        assert!((w - 1.0 / 6.0).abs() < 1e-15 && (m - 1.0 / 6.0).abs() < 1e-15);
    }

    #[test]
    fn a_map_out_of_step_with_its_tags_makes_the_figures_unavailable() {
        let mut a = AssocAudit::default();
        let mut tags = SharedMap::new();
        a.set_truth(&[1]);
        a.score(&mut tags, 0, 1, &[New]);
        assert_eq!(a.counts().scored, 1);
        // The map lost an entry the tags still have (a removal).
        a.score(&mut tags, 0, 0, &[Known(0)]);
        assert_eq!(a.counts(), AuditCounts::default());
        assert!(a.counts().rates().0.is_nan());
        a.reset();
        assert_eq!(a.counts(), AuditCounts::default());
    }

    #[test]
    fn steps_without_truth_are_not_scored() {
        let mut a = AssocAudit::default();
        let mut tags = SharedMap::new();
        a.score(&mut tags, 0, 1, &[New]);
        a.set_truth(&[]);
        a.score(&mut tags, 0, 1, &[New]);
        assert_eq!(a.counts(), AuditCounts::default());
        assert!(tags.is_empty());
    }
}
