//! One filter on one synthetic car park for the `slam` experiment: the
//! figures of Table 6 (error ‖p̂ − p‖/‖p‖ over the path, RMS, time per
//! update, map error) and the diagnostics that explain them: the mean ESS,
//! how often the set is resampled, the belief's own position spread
//! √(trace Σ_pos) against the error it makes, and how many particles alive
//! at the start, half way, 10 s and 1 s before the end still have
//! descendants at the end (path and map depletion).

use super::params::Params;
use super::slam_noise::map_error;
use crate::carpark::CarPark;
use crate::error::LocalizationError;
use crate::geometry::{Point, Pose};
use crate::mcl::newton::NewtonSettings;
use crate::slam::driver::{run_carpark_with, trajectory_error_pct, Pick, RunOptions};
use crate::slam::ekf::EkfSlam;
use crate::slam::existence::ExistenceConfig;
use crate::slam::fastslam::{FastSlam, Version};
use crate::slam::implicit::ImplicitSlam;
use crate::slam::implicit_rb::ImplicitRbSlam;
use crate::slam::implicit_refine::ImplicitRefineSlam;
use crate::slam::path_move::MoveConfig;
use crate::slam::{SlamFilter, SlamModel};
use beliefbus_core::rng::SimRng;
use std::time::Instant;

/// A filter by name and sample size.
pub fn make_filter(
    name: &str,
    m: usize,
    model: SlamModel,
    ess: f64,
    newton: NewtonSettings,
) -> Result<Box<dyn SlamFilter>, LocalizationError> {
    Ok(match name {
        "implicit" => Box::new(ImplicitSlam::new(model, m, ess, newton)?),
        "implicit-rb" => Box::new(ImplicitRbSlam::new(model, m, ess, newton)?),
        "implicit-refine" => Box::new(ImplicitRefineSlam::new(model, m, ess, newton)?),
        "fastslam1" => Box::new(FastSlam::new(model, Version::One, m, ess)?),
        "fastslam2" => Box::new(FastSlam::new(model, Version::Two, m, ess)?),
        _ => Box::new(EkfSlam::new(model)?),
    })
}

/// `interval_prior`: whether the particle filters draw the noise of the
/// whole interval since their last step with returns from their proposal
/// ([`crate::slam::SlamFilter::set_interval_prior`]).
pub fn parse_interval_prior(ps: &Params) -> Result<bool, LocalizationError> {
    match ps.raw("interval_prior").unwrap_or(INTERVAL_PRIOR_DEFAULT) {
        "on" => Ok(true),
        "off" => Ok(false),
        v => Err(LocalizationError::Param {
            key: "interval_prior".into(),
            msg: format!("'{v}': need 'on' or 'off'"),
        }),
    }
}

/// The default of `interval_prior` in `slam` and `slam-victoria-park`.
/// `refine_assoc`: where `implicit-refine` associates a return with a
/// landmark ([`crate::slam::SlamFilter::set_assoc_at_mode`]).
pub fn parse_refine_assoc(ps: &Params) -> Result<bool, LocalizationError> {
    match ps.raw("refine_assoc").unwrap_or(REFINE_ASSOC_DEFAULT) {
        "mode" => Ok(true),
        "draw" => Ok(false),
        v => Err(LocalizationError::Param {
            key: "refine_assoc".into(),
            msg: format!("'{v}': need 'mode' or 'draw'"),
        }),
    }
}

pub const REFINE_ASSOC_DEFAULT: &str = "draw";
pub const REFINE_ASSOC_DOC: &str = "implicit-refine only: 'mode' associates, gates and reports the map at each landmark's conditional mode given the particle's path with its conditional covariance (what FastSLAM's landmark EKFs hold); 'draw' at the landmark's last sampled value with its covariance marginal over that step's pose";

pub const INTERVAL_PRIOR_DEFAULT: &str = "on";

/// The documentation of `interval_prior`, shared by both experiments.
pub const INTERVAL_PRIOR_DOC: &str = "'on': between steps with returns the particle filters move each particle by the mean model and accumulate its noise (linearised, as EKF-SLAM predicts), and the next step with returns draws the whole interval's noise from its proposal and gates with it (slam::step_setup::StepPrior); 'off': every step's noise drawn from the motion model at once";

/// The resample-move settings from the parameters (`None`: off).
pub fn parse_move(ps: &Params) -> Result<Option<MoveConfig>, LocalizationError> {
    match ps.raw("move").unwrap_or("off") {
        "off" => Ok(None),
        "window" => {
            let c = MoveConfig {
                window: ps.get("move_window", 10usize)?,
                sweeps: ps.get("move_sweeps", 1usize)?,
                scale: ps.get("move_scale", 0.5)?,
            };
            c.validate()?;
            Ok(Some(c))
        }
        v => Err(LocalizationError::Param {
            key: "move".into(),
            msg: format!("'{v}': need 'off' or 'window'"),
        }),
    }
}

/// The existence rule from the parameters (`None`: off), with the
/// experiment's field of view `fov` and the rule's defaults.
pub fn parse_existence(
    ps: &Params,
    fov: ExistenceConfig,
) -> Result<Option<ExistenceConfig>, LocalizationError> {
    match ps.raw("existence").unwrap_or("off") {
        "off" => Ok(None),
        "on" => {
            let c = ExistenceConfig {
                miss: ps.get("existence_miss", fov.miss)?,
                confirm: ps.get("existence_confirm", fov.confirm)?,
                margin: ps.get("existence_margin", fov.margin)?,
                ..fov
            };
            c.validate()?;
            Ok(Some(c))
        }
        v => Err(LocalizationError::Param {
            key: "existence".into(),
            msg: format!("'{v}': need 'off' or 'on'"),
        }),
    }
}

/// The existence rule on the synthetic car park (a forward half circle
/// of radius `max_range`); it needs per-particle association.
pub fn carpark_existence(
    ps: &Params,
    assoc: AssocMode,
    max_range: f64,
) -> Result<Option<ExistenceConfig>, LocalizationError> {
    let existence = parse_existence(ps, ExistenceConfig::half_circle(max_range))?;
    if existence.is_some() && assoc != AssocMode::PerParticle {
        return Err(LocalizationError::Param {
            key: "existence".into(),
            msg: "removing landmarks renumbers a particle's map: needs association=ml".into(),
        });
    }
    Ok(existence)
}

/// The existence setting as reported.
pub fn existence_name(c: Option<ExistenceConfig>) -> String {
    c.map_or("off".into(), |c| {
        format!(
            "on start={} hit={} miss={} confirm={} range=[{}, {}] m bearing=[{:.4}, {:.4}] rad margin={} m",
            c.start, c.hit, c.miss, c.confirm, c.min_range, c.max_range, c.min_bearing, c.max_bearing, c.margin
        )
    })
}

/// The resample-move setting as reported.
pub fn move_name(c: Option<MoveConfig>) -> String {
    c.map_or("off".into(), |c| {
        format!(
            "window W={} sweeps={} scale={}",
            c.window, c.sweeps, c.scale
        )
    })
}

/// How the filters associate returns with landmarks.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum AssocMode {
    /// The ML rule, once per particle (FastSLAM's per-particle association).
    PerParticle,
    /// The ML rule once per return for the whole particle set.
    Shared,
    /// The true association (ablation).
    Known,
}

impl AssocMode {
    pub fn parse(s: &str) -> Result<Self, LocalizationError> {
        match s {
            "ml" => Ok(Self::PerParticle),
            "shared" => Ok(Self::Shared),
            "known" => Ok(Self::Known),
            v => Err(LocalizationError::Param {
                key: "association".into(),
                msg: format!("'{v}': need 'ml', 'shared' or 'known'"),
            }),
        }
    }

    pub fn name(self) -> &'static str {
        match self {
            Self::PerParticle => "ml",
            Self::Shared => "shared",
            Self::Known => "known",
        }
    }
}

/// Figures of one filter run.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct RunMetrics {
    pub error_pct: f64,
    pub rms_m: f64,
    pub time_ms: f64,
    pub time_s: f64,
    pub ess_fraction: f64,
    /// Landmarks in the estimate's map per landmark truly seen.
    pub map_ratio: f64,
    /// Mean distance of the estimate's landmarks to the nearest true one (m).
    pub map_err_m: f64,
    /// Resamplings per update with returns.
    pub resample_rate: f64,
    /// RMS over the steps of the belief's position spread (m).
    pub spread_m: f64,
    /// Particles of the start, the middle, 10 s and 1 s before the end with
    /// descendants at the end (NaN for a Gaussian filter).
    pub ancestors: [f64; 4],
    /// Accepted fraction of the resample-move's proposals (NaN: no move).
    pub move_accept: f64,
    /// Per particle and return taken in: fallbacks to the motion-model
    /// proposal, Newton steps, and returns that started a landmark.
    pub fallback_rate: f64,
    pub newton_per_return: f64,
    pub new_rate: f64,
    /// Per association scored against the truth (per particle for the
    /// particle filters): returns given to another true landmark's entry,
    /// and returns that started a duplicate ([`crate::slam::assoc_audit`]);
    /// NaN where not scored.
    pub wrong_rate: f64,
    pub missed_rate: f64,
}

/// The `per_run` CSV's header and one data set's row.
pub const PER_RUN_HEADER: &str = "method,samples,run,error_pct,rms_m,spread_m,ess_fraction,resample_rate,map_ratio,fallback_rate,newton_per_return,new_rate,wrong_rate,missed_rate\n";

pub fn per_run_row(name: &str, m: usize, r: u64, met: &RunMetrics) -> String {
    format!(
        "{name},{m},{r},{},{},{},{},{},{},{},{},{},{},{}\n",
        met.error_pct,
        met.rms_m,
        met.spread_m,
        met.ess_fraction,
        met.resample_rate,
        met.map_ratio,
        met.fallback_rate,
        met.newton_per_return,
        met.new_rate,
        met.wrong_rate,
        met.missed_rate
    )
}

/// The steps at which the ancestor slots 1–3 are labelled (slot 0: the
/// start, labelled by the reset): half way, 400 and 40 steps (10 s and 1 s
/// at 40 Hz) before the end.
pub fn mark_steps(steps: usize) -> Vec<(usize, usize)> {
    vec![
        (steps / 2, 1),
        (steps.saturating_sub(400).max(1), 2),
        (steps.saturating_sub(40).max(1), 3),
    ]
}

/// Run `f` on data set `cp` with returns `picks`; the path estimate is
/// written to `est` (steps 0..=N).
pub fn run_one(
    f: &mut dyn SlamFilter,
    cp: &CarPark,
    picks: &[Pick],
    seen: usize,
    rng: &mut SimRng,
    assoc: AssocMode,
    est: &mut [Pose],
) -> Result<(RunMetrics, Vec<Point>), LocalizationError> {
    let opt = RunOptions {
        known_association: assoc == AssocMode::Known,
        shared_association: assoc == AssocMode::Shared,
        marks: mark_steps(cp.steps()),
    };
    let mut spread2 = 0.0;
    let t0 = Instant::now();
    run_carpark_with(f, cp, picks, rng, &opt, |n, e, fl| {
        est[n] = *e;
        spread2 += fl.position_spread().powi(2);
    })?;
    let time_s = t0.elapsed().as_secs_f64();
    let n = cp.steps() as f64;
    let se: f64 = cp
        .truth
        .iter()
        .zip(est.iter())
        .skip(1)
        .map(|(t, e)| (e[0] - t[0]).powi(2) + (e[1] - t[1]).powi(2))
        .sum();
    let st = f.stats();
    let map = f.map();
    let anc = |slot| f.distinct_ancestors(slot).map_or(f64::NAN, |a| a as f64);
    let returns = (st.known + st.new + st.discarded).max(1) as f64;
    Ok((
        RunMetrics {
            map_err_m: map_error(&map, &cp.landmarks),
            error_pct: trajectory_error_pct(&cp.truth, est),
            rms_m: (se / n).sqrt(),
            time_ms: 1e3 * time_s / n,
            time_s,
            ess_fraction: st.ess_fraction_sum / st.updates.max(1) as f64,
            map_ratio: map.len() as f64 / seen.max(1) as f64,
            resample_rate: st.resamplings as f64 / st.updates.max(1) as f64,
            spread_m: (spread2 / n).sqrt(),
            ancestors: [anc(0), anc(1), anc(2), anc(3)],
            fallback_rate: st.fallbacks as f64 / returns,
            newton_per_return: st.newton_iters as f64 / returns,
            new_rate: st.new as f64 / returns,
            wrong_rate: st.audit.rates().0,
            missed_rate: st.audit.rates().1,
            move_accept: {
                let (p, a) = f.move_counts();
                if p == 0 {
                    f64::NAN
                } else {
                    a as f64 / p as f64
                }
            },
        },
        map,
    ))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn kv(v: &str) -> Vec<(String, String)> {
        vec![("interval_prior".to_string(), v.to_string())]
    }

    #[test]
    fn interval_prior_parses_on_off_and_names_the_key_on_bad_input() {
        let doc = super::super::slam::PARAMS;
        let none: Vec<(String, String)> = vec![];
        assert!(parse_interval_prior(&Params::new(&none, doc).unwrap()).unwrap());
        assert!(parse_interval_prior(&Params::new(&kv("on"), doc).unwrap()).unwrap());
        assert!(!parse_interval_prior(&Params::new(&kv("off"), doc).unwrap()).unwrap());
        match parse_interval_prior(&Params::new(&kv("maybe"), doc).unwrap()) {
            Err(LocalizationError::Param { key, msg }) => {
                assert_eq!(key, "interval_prior");
                assert!(msg.contains("maybe"), "{msg}");
            }
            other => panic!("{other:?}"),
        }
    }

    /// The vehicle's and motion noise's defaults with a 0.1 m / 0.01 rad laser.
    fn small_model() -> crate::slam::SlamModel {
        crate::slam::SlamModel {
            ute: Default::default(),
            motion: Default::default(),
            laser: crate::laser::LaserNoise {
                var_range: 0.01,
                var_bearing: 1e-4,
            },
            assoc: Default::default(),
            max_range: 15.0,
        }
    }

    #[test]
    fn refine_assoc_parses_mode_and_draw_and_names_the_key_on_bad_input() {
        let doc = super::super::slam::PARAMS;
        let kv = |v: &str| vec![("refine_assoc".to_string(), v.to_string())];
        let none: Vec<(String, String)> = vec![];
        assert!(!parse_refine_assoc(&Params::new(&none, doc).unwrap()).unwrap());
        assert!(parse_refine_assoc(&Params::new(&kv("mode"), doc).unwrap()).unwrap());
        assert!(!parse_refine_assoc(&Params::new(&kv("draw"), doc).unwrap()).unwrap());
        match parse_refine_assoc(&Params::new(&kv("mean"), doc).unwrap()) {
            Err(LocalizationError::Param { key, msg }) => {
                assert_eq!(key, "refine_assoc");
                assert!(msg.contains("mean"), "{msg}");
            }
            other => panic!("{other:?}"),
        }
        // Only implicit-refine has the setting.
        let model = small_model();
        for (name, has) in [
            ("implicit-refine", true),
            ("fastslam2", false),
            ("implicit", false),
            ("ekf", false),
        ] {
            let mut f = make_filter(name, 4, model, 0.5, NewtonSettings::default()).unwrap();
            assert_eq!(f.set_assoc_at_mode(true), has, "{name}");
        }
    }

    /// Every particle filter takes the prior, EKF-SLAM does not need it,
    /// and the path-window move (which needs every pose drawn) is refused
    /// with it.
    #[test]
    fn every_particle_filter_takes_the_interval_prior_and_the_move_is_refused_with_it() {
        let model = small_model();
        for name in [
            "implicit",
            "implicit-rb",
            "implicit-refine",
            "fastslam1",
            "fastslam2",
        ] {
            let mut f = make_filter(name, 4, model, 0.5, NewtonSettings::default()).unwrap();
            assert!(f.set_interval_prior(true), "{name}");
        }
        let mut ekf = make_filter("ekf", 1, model, 0.5, NewtonSettings::default()).unwrap();
        assert!(!ekf.set_interval_prior(true));
        let mut f = make_filter("implicit", 4, model, 0.5, NewtonSettings::default()).unwrap();
        f.set_interval_prior(true);
        let mv = crate::slam::path_move::MoveConfig {
            window: 5,
            sweeps: 1,
            scale: 0.5,
        };
        assert!(matches!(
            f.set_path_move(Some(mv)),
            Err(LocalizationError::Param { key, .. }) if key == "move"
        ));
        f.set_interval_prior(false);
        assert!(f.set_path_move(Some(mv)).unwrap());
    }
}
