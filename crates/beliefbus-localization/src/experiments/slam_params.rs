//! The `--param` keys of `beliefbus experiment slam` with their defaults
//! (printed by `--help`; the experiment itself: [`super::slam`]).

use beliefbus_core::experiment_params::{p, ParamDoc};

/// The documented parameters.
pub const PARAMS: &[ParamDoc] = &[
    p(
        "data_dir",
        "= $BELIEFBUS_VICTORIA_PARK or ../shared/data/victoria-park",
        "Victoria Park folder (odometry.csv, laser_times.csv), read in place",
    ),
    p(
        "implicit_samples",
        "10,20,50,100,200,400,500",
        "sample sizes of implicit SLAM ('none': skip)",
    ),
    p(
        "implicit_refine_samples",
        "",
        "sample sizes of implicit SLAM with re-observed features drawn again from their exact sightings; none by default",
    ),
    p(
        "implicit_rb_samples",
        "",
        "sample sizes of the Rao-Blackwellised implicit variant (Gaussian landmarks, not the paper's); none by default",
    ),
    p(
        "fastslam1_samples",
        "20,50,100,200,400,500,800,1000",
        "sample sizes of FastSLAM 1.0 ('none': skip)",
    ),
    p(
        "fastslam2_samples",
        "20,50,100,200,400,500",
        "sample sizes of FastSLAM 2.0 ('none': skip)",
    ),
    p(
        "start_time_s",
        "40",
        "start of the odometry stretch (s, data-set clock)",
    ),
    p("duration_s", "120", "length of the stretch (s)"),
    p(
        "scan_every",
        "1",
        "synthetic laser at every k-th odometry step; 0: at the recorded scan times",
    ),
    p(
        "ess_threshold",
        "0.5",
        "resample when ESS < this fraction of the samples",
    ),
    p(
        "noise_reading",
        "sigma",
        "how Table 7's numbers are read: 'variance' (P, Q, sigma_1, sigma_2 are covariance entries) or 'sigma' (they are standard deviations: Sigma_1 takes P P^T and Q Q^T, Sigma_2 = diag(sigma_1^2, sigma_2^2))",
    ),
    p(
        "laser_reading",
        "= noise_reading",
        "how sigma_1, sigma_2 alone are read: 'sigma' (standard deviations: 5 cm, 0.05 deg) or 'variance' (variances: 0.22 m, 1.7 deg); the motion noise keeps noise_reading",
    ),
    p(
        "motion_scale",
        "1",
        "multiplies every P and Q intensity of Table 7 (filters and truth)",
    ),
    p(
        "truth_noise",
        "0.1",
        "scale of the true path's noise standard deviations vs the filters' model",
    ),
    p(
        "laser_var_range",
        "0.05",
        "variance of the range (m^2); default sigma_1 = 0.05 read by laser_reading (0.05 or 0.0025)",
    ),
    p(
        "laser_var_bearing",
        "0.0008726646259971648",
        "variance of the bearing (rad^2); default sigma_2 = 0.05 pi/180 read by laser_reading (8.7e-4 or 7.6e-7)",
    ),
    p(
        "max_range",
        "15",
        "radius of the laser's forward half circle (m)",
    ),
    p(
        "landmark_spacing",
        "8",
        "arc length between landmarks along the path (m)",
    ),
    p(
        "landmark_offset",
        "2-10",
        "lateral distance of a landmark from the path, uniform in lo-hi (m), either side; one number: every landmark at that distance; 0 < lo <= hi <= max_range",
    ),
    p(
        "gap_every_s",
        "30",
        "one laser gap per window of this length (s); 0: none",
    ),
    p("gap_len_s", "2", "length of each laser gap (s)"),
    p(
        "gate",
        "9.21",
        "association gate on the Mahalanobis d^2 (chi^2_2 99 %)",
    ),
    p(
        "new_threshold",
        "13.8",
        "start a landmark when every d^2 exceeds this (chi^2_2 99.9 %)",
    ),
    p(
        "assoc_radius",
        "5",
        "only landmarks this close to the return's point are scored (m)",
    ),
    p(
        "newton_max_iter",
        "20",
        "Newton steps per particle and update, at most",
    ),
    p("newton_tol", "0.001", "Newton decrement tolerance"),
    p(
        "dead_reckoning",
        "0",
        "1: add a 'dead-reckoning' row (EKF-SLAM handed no return: the noise-free prediction from the controls)",
    ),
    p(
        "association",
        "ml",
        "'ml': the shared maximum-likelihood rule, once per particle; 'shared': once per return for the whole particle set (slam::shared_assoc); 'known': every filter is handed the true association (ablation)",
    ),
    p(
        "per_run",
        "(none)",
        "write each data set's error_pct, rms_m, spread_m, ESS, resampling rate, map size, fallbacks, Newton steps, new landmarks and the association scored against the truth (wrong and missed rates, slam::assoc_audit) per method to this CSV (for paired comparisons)",
    ),
    p(
        "plot",
        "(none)",
        "write an SVG of time per update against error (ours and the paper's) here, and one of data set 0's paths and maps beside it (<name>-paths.svg)",
    ),
    p("existence", "off", "'on': landmark existence from negative information for the particle filters (slam::existence): a provisional landmark predicted in view and not seen loses existence_miss per scan, gains 1 when seen, is confirmed at existence_confirm and removed at 0 (start 1); EKF-SLAM ignores it"),
    p("existence_miss", "0.25", "evidence lost per scan in which a provisional landmark is predicted in view and not associated"),
    p("existence_confirm", "3", "evidence at which a landmark is kept for good"),
    p("existence_margin", "1", "a landmark counts as in view only this far (m) inside the field of view's edges"),
    p("move", "off", "'window': after each resampling, Metropolis-Hastings moves of every particle's last move_window poses with its landmarks held (slam::path_move; implicit only, the other methods ignore it); 'off': none"),
    p("interval_prior", super::slam_run::INTERVAL_PRIOR_DEFAULT, super::slam_run::INTERVAL_PRIOR_DOC),
    p("refine_assoc", super::slam_run::REFINE_ASSOC_DEFAULT, super::slam_run::REFINE_ASSOC_DOC),
    p("move_window", "10", "poses moved per particle by the resample-move (W)"),
    p("move_sweeps", "1", "sweeps over the window per resample-move"),
    p("move_scale", "0.5", "the resample-move's random-walk step relative to the step noise"),
];
