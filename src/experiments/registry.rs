//! The experiments `beliefbus experiment` knows: each with one line of
//! description, the paper figure or table it reproduces and its documented
//! `--param` keys with their defaults (printed by `--help`; the lookups
//! check in debug builds that the code's defaults are these).

use super::{
    anytime, arm, chain_closed_loop, chain_defaults, changepoint, convergence, decoding,
    degenerate, double_slit, himmelblau, inventory, localization, param_estimation, ship,
    ship_control, ship_states, smoothing, vanderpol, Experiment,
};
use super::{pomdp_light_dark, pomdp_lqg};
use beliefbus_core::experiment_params::{p, ParamDoc};

const CONFIG: ParamDoc = p(
    "config",
    "(built in) configs/default.toml",
    "pipeline config file; the built-in default is embedded in the binary",
);

const CONVERGENCE: &[ParamDoc] = &[
    p(
        "states",
        "1000,3000,10000,30000,100000",
        "chain sizes n swept",
    ),
    p(
        "horizon_s",
        "2",
        "time horizon T of the moments compared (s)",
    ),
];

const VANDERPOL: &[ParamDoc] = &[
    p("horizon_s", "10", "length of each run (s)"),
    p("obs_period_s", "1", "time between observations (s)"),
    p("obs_std", "0.1", "observation noise standard deviation"),
    p(
        "process_noise",
        "0.2",
        "diffusion e1 = e2 of both coordinates",
    ),
    p(
        "eval_period_s",
        "= min(obs_period_s, 0.1)",
        "scoring period of the error (s); divides obs_period_s",
    ),
    p(
        "lost_error",
        "1",
        "a run with mean error above this counts as lost",
    ),
    p(
        "states",
        "1000",
        "chain states n of the table's chain filter",
    ),
    p("particles", "100", "particles of the table's PF"),
    p(
        "curve_states",
        "100,200,300,500,1000,2000,3000",
        "chain sizes of the error-vs-compute curve",
    ),
    p(
        "curve_particles",
        "25,50,100,200,400,1000",
        "PF sizes of the error-vs-compute curve",
    ),
    p("knn_c", "1.5", "neighbour count constant c of k = c log n"),
    p(
        "kernel",
        "moment_matched",
        "transition kernel: moment_matched or gaussian",
    ),
    p(
        "sampling",
        "predictive_even",
        "state placement: predictive_even, predictive or uniform",
    ),
    p(
        "oversample",
        "3",
        "candidates per kept state (predictive_even)",
    ),
    p(
        "transient_fraction",
        "0",
        "share of candidates from trajectories run only to transient_s",
    ),
    p(
        "transient_s",
        "3",
        "length of those transient trajectories (s)",
    ),
    p(
        "uniform_fraction",
        "0.1",
        "share of states placed uniformly on the domain",
    ),
    p(
        "kappa_drift",
        "2",
        "drift weight of the placement's arc-length sampling",
    ),
    p(
        "filter_dt",
        "= min(eval_period_s, 0.01)",
        "integration step of PF, EKF, UKF and placement paths (s)",
    ),
    p("step_s", "= eval_period_s", "the chain's step tau (s)"),
    p(
        "flush_mass",
        "0.0001",
        "posterior mass the chain filter may flush per step",
    ),
    p(
        "flush",
        "0",
        "absolute flush threshold instead of the mass bound, if > 0",
    ),
    p("dump_runs", "0", "1: print every run's errors to stderr"),
    p("chain_draws", "5", "independent chains drawn per run"),
    p(
        "state_order",
        "hilbert",
        "slot order of the states: hilbert or placed",
    ),
    p(
        "prior_x1",
        "0.5",
        "prior mean of x1 (the truth's x(0) is drawn from the prior)",
    ),
    p("prior_x2", "0", "prior mean of x2"),
    p("prior_std1", "0.2", "prior standard deviation of x1"),
    p("prior_std2", "0.2", "prior standard deviation of x2"),
];

const SHIP_STATES: &[ParamDoc] = &[
    p(
        "placement",
        "fixed",
        "fixed: one chain over the horizon's predictive; even: the same thinned evenly; local: rebuilt around the predicted belief every step; recentred: one chain built once in a local frame, carried with the belief and re-installed on it",
    ),
    p("states", "1000,5000,20000", "chain sizes n swept"),
    p("kernel", "moment", "moment (moment matching) or gaussian (the paper's)"),
    p("horizon_s", "5", "length of each run (s)"),
    p("obs_period_s", "0.01", "time between observations (s)"),
    p("step_s", "= obs_period_s", "the chain's step tau (s); 0: per-state holding times"),
    p("knn_c", "1.5", "neighbour count constant c of k = c log n"),
    p("spread", "2", "local/recentred: std inflation of the states' sampling law"),
    p(
        "install",
        "auto",
        "local/recentred: belief on the states by cell volume or importance weights (auto: volume for local, importance for recentred)",
    ),
    p("every", "10", "recentred: re-install the belief every this many observations"),
    p(
        "ess_fraction",
        "0",
        "recentred: re-install also when the effective states fall below this fraction of n",
    ),
    p(
        "around",
        "steady",
        "recentred: states drawn around the rotation-averaged steady posterior (steady) or the prior",
    ),
    p("ref_range", "1.5", "recentred, around=steady: range of the linearisation"),
    p("even", "1", "recentred: 1 thins 4n candidates to n by sample elimination"),
    p(
        "cov_match",
        "2",
        "recentred: corrections of each install's covariance towards the belief's",
    ),
    p(
        "uniform_fraction",
        "0.1",
        "fixed: share of states placed uniformly on the domain",
    ),
    p("particles", "100", "particles of the PF"),
];

const SHIP: &[ParamDoc] = &[
    p("horizon_s", "5", "length of each run (s)"),
    p("obs_period_s", "0.01", "time between observations (s)"),
    p("states", "20000", "chain states n"),
    p("particles", "100", "particles of the PF"),
    p("knn_c", "1.5", "neighbour count constant c of k = c log n"),
    p(
        "uniform_fraction",
        "0.1",
        "share of states placed uniformly on the domain",
    ),
    p("step_s", "= obs_period_s", "the chain's step tau (s)"),
    p(
        "flush_mass",
        "0.000000001",
        "posterior mass the chain filter may flush per step",
    ),
    p(
        "flush",
        "0",
        "absolute flush threshold instead of the mass bound, if > 0",
    ),
    p("start_x1", "0", "true start position x1"),
    p("start_x2", "0", "true start position x2"),
    p("start_v1", "0", "true start velocity v1"),
    p("start_v2", "0", "true start velocity v2"),
    p(
        "prior_pos_std",
        "0.3",
        "prior standard deviation of the position",
    ),
    p(
        "prior_vel_std",
        "0.2",
        "prior standard deviation of the velocity",
    ),
];

const PARAM_ESTIMATION: &[ParamDoc] = &[
    p("horizon_s", "10", "length of each run (s)"),
    p("obs_period_s", "0.01", "time between observations (s)"),
    p("states", "4000", "chain states n"),
    p("particles", "100", "particles of the PF"),
    p("knn_c", "1.5", "neighbour count constant c of k = c log n"),
    p("step_s", "= obs_period_s", "the chain's step tau (s)"),
];

const SMOOTHING: &[ParamDoc] = &[
    p("horizon_s", "5", "length of each run (s)"),
    p("obs_period_s", "0.01", "time between observations (s)"),
    p("states", "5000", "chain states n"),
    p("particles", "1000", "particles of the PF"),
    p("step_s", "= obs_period_s", "the chain's step tau (s)"),
];

const DECODING: &[ParamDoc] = &[
    p(
        "a",
        "1,3",
        "mean-reversion rates a swept (paper 001: 1, thesis: 3)",
    ),
    p("sigma", "0.1", "process noise sigma"),
    p("gamma", "0.1", "observation noise gamma"),
    p("horizon_s", "2", "length T of each trajectory (s)"),
    p("obs_period_s", "0.02", "time between observations (s)"),
    p(
        "states",
        "1000,2000,5000,10000,20000",
        "chain sizes n swept",
    ),
    p(
        "sigma_t",
        "0.01",
        "alg3.2 baseline: sigma_t of the time coordinate",
    ),
    p(
        "boundary_fraction",
        "0.5",
        "alg3.2 baseline: share of states on {T} x S",
    ),
    p(
        "layer_step_s",
        "0",
        "layer step tau of the layered decoders (0: tied to the state spacing)",
    ),
    p("inflate", "3", "layered_belief: covariance inflation kappa"),
    p(
        "uniform_fraction",
        "0.1",
        "layered_belief: share of uniform states per layer",
    ),
    p(
        "c_near",
        "3",
        "layered decoders: k = c ln n nearest states of the next layer",
    ),
    p(
        "normalise",
        "0",
        "1: divide by Z(x) (a proper Markov chain), 0: plain transition density",
    ),
    p(
        "baselines",
        "1",
        "1: also run the exact RTS floor and grid baselines",
    ),
];

const DOUBLE_SLIT: &[ParamDoc] = &[
    p(
        "samples",
        "10,50,100,500",
        "implicit-sampling path counts swept",
    ),
    p(
        "naive_samples",
        "5000,100000",
        "naive Monte Carlo path counts",
    ),
    p("naive_runs", "10", "repetitions of the naive estimate"),
    p(
        "noise",
        "0",
        "1: closed loop under a seeded process-noise path per run",
    ),
    p(
        "paper_variant",
        "1",
        "1: also the paper's variant (finite-difference gradient, smallest-basin gate)",
    ),
];

const HIMMELBLAU: &[ParamDoc] = &[
    p("samples", "50", "implicit samples per control step"),
    p("r", "0.01", "control cost weight R = r I"),
    p(
        "sigma",
        "0.01",
        "noise level of the controlled Brownian motion",
    ),
    p("t_final", "20", "horizon (s; step 1 s)"),
];

const ARM: &[ParamDoc] = &[
    p("r", "0.01", "control cost weight"),
    p("t_final", "2", "horizon (s)"),
    p("dt", "0.01", "control step (s)"),
    p("m1", "1.4", "the controller's (wrong) payload mass m1"),
    p("noise", "0", "standard deviation of the torque noise"),
    p("theta1", "1", "target angle of joint 1 (rad)"),
    p("theta2", "-0.5", "target angle of joint 2 (rad)"),
];

const ANYTIME: &[ParamDoc] = &[
    CONFIG,
    p("seconds", "20", "seconds of ship time simulated"),
    p(
        "control_amplitude",
        "0",
        "amplitude a of the known force u(t) = a (cos 0.7t, sin 0.5t)",
    ),
];

const CHAIN_CLOSED_LOOP: &[ParamDoc] = &[
    CONFIG,
    p("seconds", "20", "seconds of ship time per run"),
    p("hold_s", "0.1", "hold time of each recorded PD force (s)"),
    p(
        "drive",
        "0",
        "1: the configured controller closes the loop on each filter's belief",
    ),
    p(
        "flush_rel",
        "0.000000000001",
        "live chain: relative posterior flush threshold",
    ),
    p("two_hop", "0", "1: two-hop transport candidates"),
];

const CHAIN_DEFAULTS: &[ParamDoc] = &[
    p("particles", "300", "particles of the PF compared against"),
    p("lorenz_obs_every", "1", "observe Lorenz-63 every k-th step"),
    p("lorenz_observe_z", "0", "1: also observe z"),
    p(
        "lorenz_obs_std",
        "1",
        "Lorenz-63 observation noise standard deviation",
    ),
    p("models", "both", "both, vanderpol or lorenz"),
    p(
        "curve_percent",
        "50,200",
        "extra chains at these percentages of the derived state budget",
    ),
    p(
        "resolution",
        "0",
        "override of the derived resolution (0: derived)",
    ),
    p(
        "delta",
        "0",
        "override of the derived step delta (0: derived)",
    ),
    p(
        "states",
        "0",
        "override of the derived state count (0: derived)",
    ),
    p(
        "pf_max_dt",
        "0",
        "the PF's Euler-Maruyama step (0: the PfConfig default)",
    ),
];

const SHIP_CONTROL: &[ParamDoc] = &[
    p("duration", "20", "seconds of closed loop per run"),
    p(
        "belief",
        "truth",
        "what the controllers see: truth or noisy",
    ),
    p(
        "controllers",
        "(all)",
        "comma-separated subset of the controllers to run",
    ),
    p(
        "pi_samples",
        "8,0",
        "implicit PI samples per control (0: the MAP path alone)",
    ),
    p(
        "pi_belief",
        "mean",
        "implicit PI start: the belief's mean or sampled",
    ),
    p(
        "budget_us",
        "0",
        "implicit PI compute budget per control (us; 0: none)",
    ),
    p("mppi_samples", "2048,512", "MPPI rollouts per control"),
    p(
        "pi_limit_weight",
        "10",
        "implicit PI: weight of the control-limit penalty",
    ),
    p(
        "pi_limit_blend",
        "0",
        "implicit PI: delta of the C2 blend of the limit penalty (0: C1 kink)",
    ),
    p(
        "pi_newton_tol",
        "0.000000001",
        "implicit PI: Newton tolerance",
    ),
    p(
        "pi_gradient",
        "analytic",
        "implicit PI gradient: analytic, fd or lr",
    ),
    p(
        "pi_warm",
        "interpolate",
        "implicit PI warm start: interpolate or whole_steps",
    ),
    p(
        "pi_newton_max_iter",
        "0",
        "implicit PI: Newton iteration cap (0: default, failing at it)",
    ),
];

/// Every experiment, in the order `beliefbus experiment --list` shows them.
pub fn all() -> Vec<Experiment> {
    let e = |name, about, reproduces, params, run| Experiment {
        name,
        about,
        reproduces,
        params,
        run,
    };
    vec![
        e("convergence",
            "moments of chain trajectories vs the OU process of eq. 2.9 as n grows",
            "thesis (000) Fig. 2-4",
            CONVERGENCE, convergence::run),
        e("vanderpol",
            "chain filter vs PF/EKF/UKF on Van der Pol, error-vs-compute curve",
            "paper 001 eq. 12 and its error table; thesis 3.5",
            VANDERPOL, vanderpol::run),
        e("ship",
            "chain filter vs PF-100/EKF/UKF on the drifting ship",
            "paper 001 eq. 10-11 (ship tracking)",
            SHIP, ship::run),
        e("ship-states",
            "chain-filter error vs states on the ship, one factor at a time (placement, kernel, step), PF-100 on the same records",
            "paper 001 Fig. 3 (100 states)",
            SHIP_STATES, ship_states::run),
        e("degenerate",
            "chain filter vs Kalman/EKF/UKF/PF-300/1000 on a rigid body with noise on the velocities only (attitude-held planar quadrotor)",
            "none (acceptance of the degenerate-diffusion work; docs/degenerate-chains.md)",
            degenerate::PARAMS, degenerate::run),
        e("param-estimation",
            "joint state/parameter estimation: chain filter vs PF-100",
            "paper 001 eq. 13",
            PARAM_ESTIMATION, param_estimation::run),
        e("smoothing",
            "forward-backward smoother vs chain filter vs PF-1000 on Van der Pol",
            "thesis (000) 3.5.3",
            SMOOTHING, smoothing::run),
        e("decoding",
            "MAP trajectory decoding on chains vs exact RTS",
            "thesis Alg. 3.2 and Fig. 3-8; paper 001 Fig. 6",
            DECODING, decoding::run),
        e("double-slit",
            "implicit-sampling path-integral control of the double slit vs the analytic solution and naive MC",
            "paper 003 Table 2",
            DOUBLE_SLIT, double_slit::run),
        e("himmelblau",
            "minimising Himmelblau's function by stochastic optimal control vs undamped Newton",
            "paper 003 Table 4",
            HIMMELBLAU, himmelblau::run),
        e("arm",
            "path-integral control of the two-link arm with a wrong payload (m1 = 1.4) vs the exact optimal controller",
            "paper 003 Fig. 4",
            ARM, arm::run),
        e("anytime",
            "the live chain grown by refine while the chain backend filters the ship: error per second vs the offline chain filter and the PF",
            "no paper figure (beliefbus's anytime refinement, thesis ch. 3's incremental chains)",
            ANYTIME, anytime::run),
        e("chain-closed-loop",
            "the live chain filter vs the PF under strong recorded PD forces on the ship",
            "no paper figure (closed-loop use of paper 001's filter)",
            CHAIN_CLOSED_LOOP, chain_closed_loop::run),
        e("chain-defaults",
            "the chain filter built from ChainFilterSpec's defaults vs PF-300 on Van der Pol and stochastic Lorenz-63",
            "no paper figure (evidence for the library's defaults)",
            CHAIN_DEFAULTS, chain_defaults::run),
        e("inventory-average",
            "inventory control, average cost of one 10^5-period run per sigma: projected-belief MDP vs CE / CE-MLE / greedy",
            "paper 004 Table I",
            beliefbus_projection::experiments::inventory::PARAMS, inventory::run_average),
        e("inventory-discounted",
            "inventory control, discounted cost over 1000 runs of horizon 40 per sigma: projected-belief MDP vs CE / CE-MLE / greedy",
            "paper 004 Table II",
            beliefbus_projection::experiments::inventory::PARAMS, inventory::run_discounted),
        e("pomdp-lqg",
            "scalar LQG as a sequence of chain POMDPs (Alg. 4.4) solved by our point-based solver, closed-loop cost vs states and the Riccati optimum",
            "thesis (000) Fig. 4-4",
            pomdp_lqg::PARAMS, pomdp_lqg::run),
        e("pomdp-light-dark",
            "light-dark 1-D (belief trajectory) and 2-D (reward vs states, anytime curve) as chain POMDPs",
            "thesis (000) Figs. 4-6, 4-7, 4-8",
            pomdp_light_dark::PARAMS, pomdp_light_dark::run),
        e("ship-control",
            "closed-loop ship: implicit path-integral control vs MPPI-2048/512, cost and compute per control",
            "paper 003 sec. 3 (ship), no table: cost and compute per control",
            SHIP_CONTROL, ship_control::run),
    ]
    .into_iter()
    // Paper 002, from the beliefbus-changepoint crate.
    .chain(changepoint::experiments())
    // Paper 003 sec. 4.1, from the beliefbus-localization crate.
    .chain(localization::experiments())
    .collect()
}

#[cfg(test)]
#[path = "registry_tests.rs"]
mod tests;
