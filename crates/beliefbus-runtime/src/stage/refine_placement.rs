//! Refine's `steady` placement (`refine.placement = "steady"`,
//! `docs/degenerate-chains.md`, "The live pipeline") and the row
//! diagnostics of the versions it builds.
//!
//! A model whose noise enters through its velocities only (F Fᵀ singular)
//! needs versions that carry the posterior's position–velocity(–attitude)
//! correlations; the belief's own covariance right after an install is the
//! chain's, already smeared by its numerical diffusion on the noise-free
//! coordinates. `steady` draws every fresh version around N(x̂, P∞) instead,
//! P∞ the steady-state posterior covariance of the model linearised at x̂
//! under the latest control (or u₀) and observed at the sensor period
//! (`chain::steady::steady_posterior`, a discrete Riccati solve: data-free),
//! and between fresh versions publishes the latest one again as a new
//! lineage every `refine.recenter_ms` ([`Refiner::recentre`]): the filter
//! installs it from its Gaussian belief, which re-centres the frame on the
//! belief at the cost of an O(n) install instead of a chain build.

use super::{Refiner, StageError};
use crate::belief::Gaussian;
use crate::chain::diagnostics::row_report;
use crate::chain::snapshot::{relabel, SnapshotMeta};
use crate::chain::steady::steady_posterior;
use crate::chain::Chain;
use crate::config::placement::Placement;
use crate::model::SdeModel;

/// Row diagnostics summed over the versions refine built
/// (`chain::diagnostics::row_report`): rows, rows meeting their matched
/// moment equations exactly, and rows the kernel fitted by least squares.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct RowCounts {
    pub versions: u64,
    pub rows: u64,
    pub exact: u64,
    pub least_squares: u64,
}

impl RowCounts {
    /// Add the rows of a version.
    pub fn add(&mut self, c: &Chain) {
        let r = row_report(c);
        self.versions += 1;
        self.rows += r.rows as u64;
        self.exact += r.exact as u64;
        self.least_squares += r.least_squares;
    }
}

impl Refiner {
    /// The Gaussian a fresh version is drawn around: the belief
    /// (`belief` placement) or N(x̂, P∞) (`steady`; the belief when P∞
    /// cannot be solved at x̂, counted in `steady_failures`).
    pub(super) fn placement_belief(&mut self) -> Gaussian {
        if self.cfg.refine.placement != Placement::Steady {
            return self.belief;
        }
        let d = self.belief.dim;
        let nu = self.model.dims().control;
        let mut x = [0.0; crate::MAX_STATE];
        x[..d].copy_from_slice(self.belief.mean());
        self.model.bounds().project(&mut x[..d]);
        let u = self.control.unwrap_or_else(|| self.reference_control());
        match steady_posterior(&self.model, &x[..d], &u[..nu], self.cfg.sample_dt()) {
            Ok(mut g) => {
                g.mean_mut().copy_from_slice(self.belief.mean());
                g
            }
            Err(_) => {
                self.steady_failures += 1;
                self.belief
            }
        }
    }

    /// Whether the steady placement re-publishes versions.
    pub fn recentres(&self) -> bool {
        self.cfg.refine.moving_frame
            && self.cfg.refine.placement == Placement::Steady
            && self.cfg.refine.recenter_ms > 0.0
    }

    /// Give the snapshot `buf` (the last one written by
    /// [`Refiner::write_snapshot`]) the next version and a lineage of its
    /// own, so that the filter installs it afresh from its belief.
    pub fn recentre(&mut self, buf: &mut [u64], t_pub_ns: u64) -> Result<(), StageError> {
        self.version += 1;
        self.recentred += 1;
        let meta = SnapshotMeta {
            version: self.version,
            lineage: self.lineage ^ self.frames.rotate_left(40) ^ self.recentred.rotate_left(20),
            t_pub_ns,
        };
        relabel(buf, meta).map_err(|e| StageError::Build {
            what: "chain snapshot",
            reason: e.to_string(),
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::chain::snapshot::HeldSnapshot;
    use crate::config::{load, PipelineConfig};
    use std::path::Path;
    use std::time::Duration;

    fn cfg(placement: &str) -> PipelineConfig {
        let o: Vec<String> = [
            "refine.max_states=3000",
            "refine.initial_states=3000",
            "refine.uniform_fraction=0",
            "refine.min_std_fraction=0",
            &format!("refine.placement={placement}"),
        ]
        .iter()
        .map(|s| s.to_string())
        .collect();
        load(
            &Path::new(env!("CARGO_MANIFEST_DIR")).join("../../configs/default.toml"),
            &o,
        )
        .unwrap()
    }

    /// Sample covariance of the version's states.
    fn state_cov(r: &Refiner) -> Vec<f64> {
        let c = r.chain.as_ref().unwrap();
        let (n, d) = (c.len(), c.dim());
        let mut m = vec![0.0; d];
        for i in 0..n {
            for (a, ma) in m.iter_mut().enumerate() {
                *ma += c.state(i)[a] / n as f64;
            }
        }
        let mut cov = vec![0.0; d * d];
        for i in 0..n {
            let z = c.state(i);
            for a in 0..d {
                for b in 0..d {
                    cov[a + b * d] += (z[a] - m[a]) * (z[b] - m[b]) / (n - 1) as f64;
                }
            }
        }
        cov
    }

    /// A steady version's states are draws from N(x̂, inflate² P∞) with P∞
    /// the Riccati solution at the belief (not the belief's covariance):
    /// their sample variances agree with it within sampling error (3000
    /// draws: relative std √(2/3000) ≈ 2.6 %; bound 5 σ).
    #[test]
    fn steady_versions_are_drawn_around_the_steady_posterior() {
        let c = cfg("steady");
        let mut r = Refiner::new(&c, 3).unwrap();
        let prior = c.prior();
        let d = prior.dim;
        let u0 = r.reference_control();
        let nu = r.model.dims().control;
        let p_inf = steady_posterior(&r.model, prior.mean(), &u0[..nu], c.sample_dt()).unwrap();
        r.work(Duration::ZERO).unwrap();
        assert_eq!(r.steady_failures, 0);
        let cov = state_cov(&r);
        let k2 = c.refine.inflate * c.refine.inflate;
        for a in 0..d {
            let (got, want) = (cov[a + a * d], k2 * p_inf.cov_at(a, a));
            assert!(
                (got / want - 1.0).abs() < 5.0 * (2.0f64 / 3000.0).sqrt(),
                "{a}: {got} vs {want}"
            );
        }
        // The test tells the placements apart: P∞'s positions are far
        // tighter than the prior's.
        for a in 0..2 {
            assert!(prior.cov_at(a, a) > 2.0 * p_inf.cov_at(a, a), "{a}");
        }
        // The belief placement draws around the belief's covariance instead.
        let mut b = Refiner::new(&cfg("belief"), 3).unwrap();
        b.work(Duration::ZERO).unwrap();
        let cb = state_cov(&b);
        assert!(cb[0] > 2.0 * cov[0], "{} vs {}", cb[0], cov[0]);
        // Rows of every version are counted.
        assert_eq!(r.rows.versions, 1);
        assert_eq!(r.rows.rows, 3000);
    }

    /// Re-publishing relabels the last snapshot: same chain, the next
    /// version, a lineage of its own (so the filter installs it afresh).
    #[test]
    fn a_recentred_snapshot_is_the_same_chain_as_a_new_version_and_lineage() {
        let c = cfg("steady");
        let mut r = Refiner::new(&c, 3).unwrap();
        assert!(r.recentres());
        r.work(Duration::ZERO).unwrap();
        let mut buf = vec![0u64; r.snapshot_words()];
        let n = r.write_snapshot(&mut buf, 7).unwrap();
        buf.truncate(n);
        let first = buf.clone();
        r.recentre(&mut buf, 9).unwrap();
        let second = buf.clone();
        r.recentre(&mut buf, 11).unwrap();
        let (a, b, e) = (
            HeldSnapshot::new(first).unwrap(),
            HeldSnapshot::new(second).unwrap(),
            HeldSnapshot::new(buf).unwrap(),
        );
        let (a, b, e) = (a.view(), b.view(), e.view());
        assert_eq!((b.version, e.version), (a.version + 1, a.version + 2));
        assert!(a.lineage != b.lineage && b.lineage != e.lineage && a.lineage != e.lineage);
        assert_eq!(b.t_pub_ns, 9);
        assert_eq!((a.states, a.probs, a.cols), (b.states, b.probs, b.cols));
        assert_eq!(r.recentred, 2);
        // Off unless steady, in the moving frame, with a period.
        assert!(!Refiner::new(&cfg("belief"), 3).unwrap().recentres());
    }
}
