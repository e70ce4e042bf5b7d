//! Association of a whole scan's returns at once, the same for every SLAM
//! filter: each return is scored against every candidate landmark by the
//! ML rule of [`super::assoc`] (d² = νᵀS⁻¹ν, log-likelihood
//! −½d² − ½ log det S, gate, new-landmark threshold), and then either
//!
//! - **independently** (`exclusive` off): each return takes its own
//!   best gated candidate, exactly [`super::assoc::Chooser`]; two returns of
//!   one scan may then take the same landmark; or
//! - **with mutual exclusion** (`exclusive` on): one landmark explains
//!   at most one return of a scan (one tree gives one detection). The
//!   gated pairs are taken greedily in order of decreasing likelihood, each
//!   pair whose return and landmark are both still free is accepted:
//!   the nearest-neighbour rule with exclusion, a greedy approximation of
//!   the joint maximum-likelihood assignment. A return left without a free
//!   gated landmark starts a new one when every one of its d² exceeds the
//!   new-landmark threshold and is discarded (ambiguous) otherwise, as in
//!   the independent rule.
//!
//! With one return per scan both rules are the same. Buffers are reused:
//! no allocation per scan once they have grown to the scan's size.

use super::assoc::{AssocConfig, Association};
use nalgebra::{Matrix2, Vector2};

/// How the returns of one scan share landmarks.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum Exclusion {
    /// Each return on its own (two may take one landmark).
    #[default]
    Off,
    /// One landmark per return; a return beaten to its landmark takes its
    /// next gated candidate.
    NextBest,
    /// One landmark per return; a return beaten to its landmark is dropped.
    Drop,
}

impl Exclusion {
    /// `off`, `next` or `drop`.
    pub fn parse(v: &str) -> Option<Self> {
        match v {
            "off" | "0" => Some(Self::Off),
            "next" | "1" => Some(Self::NextBest),
            "drop" => Some(Self::Drop),
            _ => None,
        }
    }

    pub fn name(self) -> &'static str {
        match self {
            Self::Off => "off",
            Self::NextBest => "next",
            Self::Drop => "drop",
        }
    }
}

/// One gated (return, landmark) pair and its log-likelihood.
#[derive(Clone, Copy, Debug)]
struct Pair {
    ret: usize,
    lm: usize,
    ll: f64,
}

/// The scores of one scan's returns and the decision.
#[derive(Clone, Debug, Default)]
pub struct ScanAssoc {
    /// Mutual exclusion within a scan.
    pub exclusive: Exclusion,
    pairs: Vec<Pair>,
    min_d2: Vec<f64>,
    done: Vec<bool>,
    out: Vec<Association>,
}

impl ScanAssoc {
    pub fn with_capacity(n: usize) -> Self {
        Self {
            exclusive: Exclusion::Off,
            pairs: Vec::with_capacity(4 * n),
            min_d2: Vec::with_capacity(n),
            done: Vec::with_capacity(n),
            out: Vec::with_capacity(n),
        }
    }

    /// Start a scan of `returns` returns.
    pub fn begin(&mut self, returns: usize) {
        self.pairs.clear();
        self.min_d2.clear();
        self.min_d2.resize(returns, f64::INFINITY);
        self.out.clear();
    }

    /// Score landmark `lm` for return `ret` with innovation ν and covariance S.
    pub fn offer(
        &mut self,
        ret: usize,
        lm: usize,
        nu: &Vector2<f64>,
        s: &Matrix2<f64>,
        cfg: &AssocConfig,
    ) {
        let Some((d2, ll)) = super::assoc::innovation_score(nu, s) else {
            return;
        };
        self.min_d2[ret] = self.min_d2[ret].min(d2);
        if d2 < cfg.gate {
            self.pairs.push(Pair { ret, lm, ll });
        }
    }

    /// The association of every return of the scan, in order.
    pub fn decide(&mut self, cfg: &AssocConfig) -> &[Association] {
        let exclusive = self.exclusive;
        let n = self.min_d2.len();
        self.out.clear();
        self.out.resize(n, Association::Discard);
        self.done.clear();
        self.done.resize(n, false);
        // Best first; ties keep the order offered (stable on equal ll is not
        // needed for determinism: the order offered is deterministic).
        self.pairs.sort_unstable_by(|a, b| {
            b.ll.total_cmp(&a.ll)
                .then(a.ret.cmp(&b.ret))
                .then(a.lm.cmp(&b.lm))
        });
        for p in &self.pairs {
            if self.done[p.ret] {
                continue;
            }
            let taken = exclusive != Exclusion::Off
                && self
                    .out
                    .iter()
                    .any(|a| matches!(a, Association::Known(k) if *k == p.lm));
            if !taken {
                self.out[p.ret] = Association::Known(p.lm);
                self.done[p.ret] = true;
            } else if exclusive == Exclusion::Drop {
                self.done[p.ret] = true;
            }
        }
        for (a, &d2) in self.out.iter_mut().zip(&self.min_d2) {
            if !matches!(a, Association::Known(_)) && d2 > cfg.new_threshold {
                *a = Association::New;
            }
        }
        &self.out
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::slam::assoc::Chooser;

    fn s(v: f64) -> Matrix2<f64> {
        Matrix2::new(v, 0.0, 0.0, v)
    }

    /// Without exclusion the scan rule is the per-return Chooser, return by
    /// return, on random scores.
    #[test]
    fn independent_rule_is_the_per_return_chooser() {
        let cfg = AssocConfig::default();
        let mut rng = beliefbus_core::rng::stream(7, 0);
        use rand::RngExt;
        let mut sa = ScanAssoc::with_capacity(8);
        for _ in 0..200 {
            let n = rng.random_range(1..6usize);
            let k = rng.random_range(0..6usize);
            sa.begin(n);
            let mut want = Vec::new();
            let mut offers = Vec::new();
            for i in 0..n {
                let mut ch = Chooser::new();
                for l in 0..k {
                    let nu = Vector2::new(rng.random_range(-4.0..4.0), rng.random_range(-4.0..4.0));
                    let sv = s(rng.random_range(0.5..2.0));
                    ch.offer(l, &nu, &sv, &cfg);
                    offers.push((i, l, nu, sv));
                }
                want.push(ch.decide(&cfg));
            }
            for (i, l, nu, sv) in offers {
                sa.offer(i, l, &nu, &sv, &cfg);
            }
            assert_eq!(sa.decide(&cfg), &want[..]);
        }
    }

    /// Two returns whose best landmark is the same: without exclusion both
    /// take it; with exclusion the likelier return keeps it and the other
    /// takes its second choice, or is discarded if it has none.
    #[test]
    fn exclusion_gives_a_landmark_to_one_return_only() {
        let cfg = AssocConfig::default();
        let mut sa = ScanAssoc::with_capacity(4);
        let (near, mid, far) = (
            Vector2::new(0.1, 0.0),
            Vector2::new(1.0, 0.0),
            Vector2::new(2.0, 0.0),
        );
        let offer_all = |sa: &mut ScanAssoc| {
            sa.begin(2);
            sa.offer(0, 0, &near, &s(1.0), &cfg);
            sa.offer(1, 0, &mid, &s(1.0), &cfg);
            sa.offer(1, 1, &far, &s(1.0), &cfg);
        };
        offer_all(&mut sa);
        assert_eq!(
            sa.decide(&cfg),
            &[Association::Known(0), Association::Known(0)]
        );
        offer_all(&mut sa);
        sa.exclusive = Exclusion::NextBest;
        assert_eq!(
            sa.decide(&cfg),
            &[Association::Known(0), Association::Known(1)]
        );
        offer_all(&mut sa);
        sa.exclusive = Exclusion::Drop;
        assert_eq!(
            sa.decide(&cfg),
            &[Association::Known(0), Association::Discard]
        );
        sa.exclusive = Exclusion::NextBest;
        // Without a second candidate the loser is ambiguous (d² < new threshold).
        sa.begin(2);
        sa.offer(0, 0, &near, &s(1.0), &cfg);
        sa.offer(1, 0, &mid, &s(1.0), &cfg);
        assert_eq!(
            sa.decide(&cfg),
            &[Association::Known(0), Association::Discard]
        );
        // A return with nothing near starts a landmark under either rule.
        sa.begin(2);
        sa.offer(0, 0, &near, &s(1.0), &cfg);
        sa.offer(1, 0, &Vector2::new(10.0, 0.0), &s(1.0), &cfg);
        assert_eq!(sa.decide(&cfg), &[Association::Known(0), Association::New]);
    }
}
