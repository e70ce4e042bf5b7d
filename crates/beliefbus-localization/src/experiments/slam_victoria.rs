//! SLAM on the real Victoria Park run (Guivant & Nebot, ACFR): implicit
//! SLAM, FastSLAM 2.0 and EKF-SLAM over the whole 26 minutes, driven by the
//! recorded wheel speed and steering (every 25 ms sample is a step) and
//! the ACFR detector's tree features at their scan times, with the same
//! association and gates for every method ([`crate::slam::assoc`]). Only
//! detections within `max_range` are used (the same for all).
//!
//! The state is the laser point (the Ute model of the appendix with E10),
//! started at the first kept GPS fix with heading `start_heading_deg`
//! (the data carry none; 36° is the usual choice, fitted to the first GPS
//! track). The GPS antenna's mounting is undocumented; the data's README
//! finds it about 4 m ahead of the rear axle, i.e. near the laser point
//! (3.78 m ahead), so the laser point is compared with GPS directly.
//! Error: distance from each kept GPS fix (outliers gated at `gps_max_speed`)
//! to the estimate at the nearest odometry step; RMS and 95th percentile.
//! The dead-reckoned path (the mean model without noise) is scored alike.

use super::params::Params;
use super::slam::make_filter;
use super::slam_svg::{range, Panel, Svg, COLORS};
use super::slam_vp_data::{gate_gps, load as load_vp, GpsFix};
use super::{Report, Row};
use crate::error::LocalizationError;
use crate::geometry::{Point, Pose};
use crate::laser::LaserNoise;
use crate::mcl::newton::NewtonSettings;
use crate::slam::assoc::{AssocConfig, RangeBearing};
use crate::slam::existence::ExistenceConfig;
use crate::slam::scan_assoc::Exclusion;
use crate::slam::SlamModel;
use crate::vehicle::{Control, MotionNoise, Ute};
use crate::victoria;
use beliefbus_core::experiment_params::{p, ParamDoc};
use beliefbus_core::rng::stream;
use std::time::Instant;

/// The documented parameters.
pub const PARAMS: &[ParamDoc] = &[
    p(
        "data_dir",
        "= $BELIEFBUS_VICTORIA_PARK or ../shared/data/victoria-park",
        "Victoria Park folder (odometry.csv, gps.csv, derived/trees_detectTreesI16.csv), read in place",
    ),
    p("methods", "implicit,fastslam2,ekf", "methods to run (implicit, implicit-refine, implicit-rb, fastslam1, fastslam2, ekf)"),
    p("samples", "100", "sample sizes of the particle methods"),
    p("end_time_s", "1e9", "stop at this time on the data set's clock (s); default: the whole run"),
    p("start_heading_deg", "36", "initial heading (degrees, from east, counter-clockwise)"),
    p("p_speed", "0.5", "P11: speed noise intensity (m^2/s)"),
    p("p_steer", "0.05", "P22: steering noise intensity (rad^2 s)"),
    p("q_pos", "0.1", "Q11 = Q22: position noise intensity (m^2/s)"),
    p("q_heading", "0.0017453292519943296", "Q33: heading noise intensity (rad^2/s)"),
    p("laser_var_range", "0.25", "variance of a tree's range (m^2)"),
    p("laser_var_bearing", "0.0003046174197867086", "variance of a tree's bearing (rad^2), (1 deg)^2"),
    p("max_range", "30", "use tree detections up to this range (m)"),
    p("gate", "9.21", "association gate on d^2"),
    p("new_threshold", "13.8", "start a landmark when every d^2 exceeds this"),
    p("assoc_radius", "5", "pre-filter radius of the association (m)"),
    p("gps_max_speed", "10", "drop a GPS fix implying a higher speed (m/s) from the last kept one"),
    p("ess_threshold", "0.5", "resample when ESS < this fraction of the samples"),
    p("association", "ml", "'ml': the ML rule once per particle; 'shared': once per return for the whole particle set (slam::shared_assoc)"),
    p("exclusive", "off", "'next' or 'drop': a scan's returns are associated jointly, one landmark per return at most, a return beaten to its landmark taking its next candidate or dropped (slam::scan_assoc), by every method; 'off': each return on its own"),
    p("per_run", "(none)", "write each seed's rms_m and p95_m per method to this CSV (for paired comparisons)"),
    p("trace", "(none)", "write per scan and run the estimate and the running association counts (known, new, discarded, removed; summed over particles) to this CSV, to find where a map slips"),
    p("plot", "(none)", "write an SVG of each method's path and map over GPS and dead reckoning here"),
    p("existence", "off", "'on': landmark existence from negative information for the particle filters (slam::existence): a provisional landmark predicted in view and not seen loses existence_miss per scan, gains 1 when seen, is confirmed at existence_confirm and removed at 0 (start 1); EKF-SLAM ignores it"),
    p("existence_miss", "0.25", "evidence lost per scan in which a provisional landmark is predicted in view and not associated"),
    p("existence_confirm", "3", "evidence at which a landmark is kept for good"),
    p("existence_margin", "1", "a landmark counts as in view only this far (m) inside the field of view's edges"),
    p("interval_prior", super::slam_run::INTERVAL_PRIOR_DEFAULT, super::slam_run::INTERVAL_PRIOR_DOC),
    p("refine_assoc", super::slam_run::REFINE_ASSOC_DEFAULT, super::slam_run::REFINE_ASSOC_DOC),
    p("move", "off", "'window': after each resampling, Metropolis-Hastings moves of every particle's last move_window poses with its landmarks held (slam::path_move; implicit only, the other methods ignore it); 'off': none"),
    p("move_window", "10", "poses moved per particle by the resample-move (W)"),
    p("move_sweeps", "1", "sweeps over the window per resample-move"),
    p("move_scale", "0.5", "the resample-move's random-walk step relative to the step noise"),
];

/// Figures of one run: RMS, p95, landmarks, ms per step, seconds, counters.
type Figures = (f64, f64, f64, f64, f64, crate::slam::SlamStats);

/// One method's path and map, for the plot.
struct Track {
    name: String,
    path: Vec<Pose>,
    map: Vec<Point>,
}

/// Distances from kept GPS fixes to a path sampled at `times`.
fn gps_errors(times: &[f64], path: &[Pose], gps: &[GpsFix]) -> Vec<f64> {
    gps.iter()
        .filter(|g| g.time >= times[0] && g.time <= times[times.len() - 1])
        .map(|g| {
            let i = times.partition_point(|&t| t < g.time).min(times.len() - 1);
            let j = if i > 0 && (g.time - times[i - 1]) < (times[i] - g.time) {
                i - 1
            } else {
                i
            };
            (path[j][0] - g.x).hypot(path[j][1] - g.y)
        })
        .collect()
}

/// RMS and 95th percentile.
fn rms_p95(e: &[f64]) -> (f64, f64) {
    if e.is_empty() {
        return (f64::NAN, f64::NAN);
    }
    let rms = (e.iter().map(|x| x * x).sum::<f64>() / e.len() as f64).sqrt();
    let mut s = e.to_vec();
    s.sort_by(f64::total_cmp);
    let k = ((0.95 * s.len() as f64).ceil() as usize).clamp(1, s.len()) - 1;
    (rms, s[k])
}

/// `slam-victoria-park`. `runs` repeats the particle methods with different
/// seeds (default 1); the EKF is deterministic.
pub fn run(
    runs: Option<usize>,
    seed: u64,
    kv: &[(String, String)],
) -> Result<Report, LocalizationError> {
    let ps = Params::new(kv, PARAMS)?;
    let dir = victoria::resolve_dir(ps.raw("data_dir"));
    let methods: Vec<String> = ps.list(
        "methods",
        &["implicit".to_string(), "fastslam2".into(), "ekf".into()],
    )?;
    for m in &methods {
        if ![
            "implicit",
            "implicit-refine",
            "implicit-rb",
            "fastslam1",
            "fastslam2",
            "ekf",
        ]
        .contains(&m.as_str())
        {
            return Err(LocalizationError::Param {
                key: "methods".into(),
                msg: format!("unknown method '{m}'"),
            });
        }
    }
    let samples: Vec<usize> = ps.list("samples", &[100])?;
    if samples.contains(&0) {
        return Err(LocalizationError::Param {
            key: "samples".into(),
            msg: "must be ≥ 1".into(),
        });
    }
    let end_time: f64 = ps.get("end_time_s", 1e9)?;
    let heading = ps.get("start_heading_deg", 36.0f64)?.to_radians();
    let ld = AssocConfig::default();
    let motion = MotionNoise {
        p: [ps.get("p_speed", 0.5)?, ps.get("p_steer", 0.05)?],
        q: [
            ps.get("q_pos", 0.1)?,
            ps.get("q_pos", 0.1)?,
            ps.get("q_heading", MotionNoise::default().q[2])?,
        ],
    };
    let model = SlamModel {
        ute: Ute::default(),
        motion,
        laser: LaserNoise {
            var_range: ps.get("laser_var_range", 0.25)?,
            var_bearing: ps.get("laser_var_bearing", 1f64.to_radians().powi(2))?,
        },
        assoc: AssocConfig {
            gate: ps.get("gate", ld.gate)?,
            new_threshold: ps.get("new_threshold", ld.new_threshold)?,
            radius: ps.get("assoc_radius", ld.radius)?,
        },
        max_range: ps.get("max_range", 30.0)?,
    };
    model.validate()?;
    let gps_max_speed: f64 = ps.get("gps_max_speed", 10.0)?;
    let ess: f64 = ps.get("ess_threshold", 0.5)?;
    let shared = match super::slam_run::AssocMode::parse(ps.raw("association").unwrap_or("ml"))? {
        super::slam_run::AssocMode::PerParticle => false,
        super::slam_run::AssocMode::Shared => true,
        super::slam_run::AssocMode::Known => {
            return Err(LocalizationError::Param {
                key: "association".into(),
                msg: "the real run has no known association: 'ml' or 'shared'".into(),
            })
        }
    };
    let exclusive = ps.raw("exclusive").unwrap_or("off");
    let exclusive = Exclusion::parse(exclusive).ok_or_else(|| LocalizationError::Param {
        key: "exclusive".into(),
        msg: format!("'{exclusive}': need off, next or drop"),
    })?;
    let path_move = super::slam_run::parse_move(&ps)?;
    let interval_prior = super::slam_run::parse_interval_prior(&ps)?;
    let refine_assoc_mode = super::slam_run::parse_refine_assoc(&ps)?;
    // The detector's field of view (data README): trees between 1 m and
    // the range cut, centre bearings inside the 2.9° edge bands it rejects.
    let edge = 5.0 * std::f64::consts::PI / 306.0;
    let existence = super::slam_run::parse_existence(
        &ps,
        ExistenceConfig {
            min_range: 1.0,
            min_bearing: edge,
            max_bearing: std::f64::consts::PI - edge,
            ..ExistenceConfig::half_circle(model.max_range)
        },
    )?;
    let per_run_path = ps.raw("per_run").map(str::to_string);
    let trace_path = ps.raw("trace").map(str::to_string);
    let mut trace = String::new();
    if trace_path.is_some() {
        trace.push_str("method,samples,run,time_s,x,y,known,new,discarded,removed\n");
    }
    let mut per_run = String::from("method,samples,run,rms_m,p95_m,landmarks,move_accept\n");
    let plot = ps.raw("plot").map(str::to_string);
    let runs = runs.unwrap_or(1).max(1);

    let rec = victoria::load(&dir)?;
    let (gps_raw, trees) = load_vp(&dir)?;
    let (gps, gps_dropped) = gate_gps(&gps_raw, gps_max_speed);
    let odo: Vec<_> = rec.odometry.iter().filter(|o| o.time <= end_time).collect();
    if odo.len() < 2 || gps.is_empty() {
        return Err(LocalizationError::Invalid {
            name: "end_time_s",
            value: end_time,
            need: "leaves fewer than two odometry samples or no GPS fix",
        });
    }
    let times: Vec<f64> = odo.iter().map(|o| o.time).collect();
    let mut controls = Vec::with_capacity(odo.len() - 1);
    for o in &odo[1..] {
        controls.push(Control {
            v: model.ute.centre_speed(o.speed, o.steering)?,
            alpha: o.steering,
        });
    }
    // Scans: each to the first step at or after its time; detections
    // beyond max_range dropped.
    let mut scan_at: Vec<Option<usize>> = vec![None; times.len()];
    let mut scan_obs: Vec<Vec<RangeBearing>> = Vec::new();
    let mut n = 1;
    let mut used = 0usize;
    for s in trees
        .iter()
        .filter(|s| s.time > times[0] && s.time <= times[times.len() - 1])
    {
        while times[n] < s.time {
            n += 1;
        }
        let obs: Vec<RangeBearing> = s
            .obs
            .iter()
            .copied()
            .filter(|z| z.range <= model.max_range)
            .collect();
        if obs.is_empty() {
            continue;
        }
        used += obs.len();
        match scan_at[n] {
            Some(k) => scan_obs[k].extend(obs),
            None => {
                scan_at[n] = Some(scan_obs.len());
                scan_obs.push(obs);
            }
        }
    }
    let start = Pose::new(gps[0].x, gps[0].y, heading);
    // Dead reckoning: the mean model.
    let mut dr = vec![start; times.len()];
    for k in 1..times.len() {
        let ute = Ute {
            dt: times[k] - times[k - 1],
            ..model.ute
        };
        dr[k] = ute.predict_mean(&dr[k - 1], controls[k - 1]);
    }
    let mut rep = Report::new("slam-victoria-park");
    rep.param("association_given", if shared { "shared" } else { "ml" });
    rep.param("exclusive", exclusive.name());
    rep.param("move", super::slam_run::move_name(path_move));
    rep.param("interval_prior", if interval_prior { "on" } else { "off" });
    rep.param(
        "refine_assoc",
        if refine_assoc_mode { "mode" } else { "draw" },
    );
    rep.param("existence", super::slam_run::existence_name(existence));
    rep.lead_columns(&["samples", "rms_m", "p95_m", "landmarks", "time_ms"]);
    let (dr_rms, dr_p95) = rms_p95(&gps_errors(&times, &dr, &gps));
    rep.results.push(
        Row::new("dead-reckoning")
            .int("samples", 0)
            .num("rms_m", dr_rms)
            .num("p95_m", dr_p95),
    );
    let mut tracks = vec![Track {
        name: "dead reckoning".into(),
        path: dr,
        map: vec![],
    }];
    let empty: [RangeBearing; 0] = [];
    for name in &methods {
        let sizes: Vec<usize> = if name == "ekf" {
            vec![1]
        } else {
            samples.clone()
        };
        for &m in &sizes {
            let reps = if name == "ekf" { 1 } else { runs };
            let mut figs: Vec<Figures> = Vec::with_capacity(reps);
            for r in 0..reps as u64 {
                let mut f = make_filter(name, m, model, ess, NewtonSettings::default())?;
                f.set_shared_association(shared);
                f.set_exclusion(exclusive);
                f.set_interval_prior(interval_prior);
                f.set_assoc_at_mode(refine_assoc_mode);
                f.set_path_move(path_move)?;
                f.set_existence(existence)?;
                f.reset(&start);
                let mut rng = stream(seed, r);
                let mut path = vec![start; times.len()];
                let t0 = Instant::now();
                for k in 1..times.len() {
                    let obs = scan_at[k].map_or(&empty[..], |i| &scan_obs[i][..]);
                    path[k] = f.step(controls[k - 1], times[k] - times[k - 1], obs, &mut rng)?;
                    if trace_path.is_some() && !obs.is_empty() {
                        let st = f.stats();
                        trace.push_str(&format!(
                            "{name},{m},{r},{},{},{},{},{},{},{}\n",
                            times[k],
                            path[k][0],
                            path[k][1],
                            st.known,
                            st.new,
                            st.discarded,
                            st.removed
                        ));
                    }
                }
                let time_s = t0.elapsed().as_secs_f64();
                let (rms, p95) = rms_p95(&gps_errors(&times, &path, &gps));
                let map = f.map();
                let st = f.stats();
                let (mp, ma) = f.move_counts();
                per_run.push_str(&format!(
                    "{name},{m},{r},{rms},{p95},{},{}\n",
                    map.len(),
                    ma as f64 / mp.max(1) as f64
                ));
                figs.push((
                    rms,
                    p95,
                    map.len() as f64,
                    1e3 * time_s / (times.len() - 1) as f64,
                    time_s,
                    st,
                ));
                if r == 0 {
                    tracks.push(Track {
                        name: format!("{name} ({m})"),
                        path,
                        map,
                    });
                }
            }
            let k = figs.len() as f64;
            let avg = |g: fn(&Figures) -> f64| figs.iter().map(g).sum::<f64>() / k;
            let st = figs[0].5;
            rep.results.push(
                Row::new(name)
                    .int("samples", m as u64)
                    .num("rms_m", avg(|x| x.0))
                    .num("rms_m_se", {
                        let v: Vec<f64> = figs.iter().map(|x| x.0).collect();
                        super::params::mean_se(&v).1
                    })
                    .num("p95_m", avg(|x| x.1))
                    .num("landmarks", avg(|x| x.2))
                    .num("removed", avg(|x| x.5.removed as f64))
                    .num("time_ms", avg(|x| x.3))
                    .num("time_s", avg(|x| x.4))
                    .int("runs", figs.len() as u64)
                    .num(
                        "ess_fraction",
                        st.ess_fraction_sum / st.updates.max(1) as f64,
                    )
                    .num(
                        "known_per_update",
                        st.known as f64 / st.updates.max(1) as f64,
                    )
                    .num("new_per_update", st.new as f64 / st.updates.max(1) as f64),
            );
        }
    }
    rep.param("data_dir", dir.display().to_string());
    rep.param("seed", seed);
    rep.param("runs", runs);
    rep.param("steps", times.len() - 1);
    rep.param("scans_used", scan_obs.len());
    rep.param("detections_used", used);
    rep.param("gps_fixes_kept", gps.len());
    rep.param("gps_fixes_dropped", gps_dropped);
    rep.param("p", format!("{:?}", motion.p));
    rep.param("q", format!("{:?}", motion.q));
    rep.param(
        "laser_var",
        format!("[{}, {}]", model.laser.var_range, model.laser.var_bearing),
    );
    rep.param("max_range", model.max_range);
    rep.param("start_heading_deg", heading.to_degrees());
    rep.notes.push(format!(
        "{} odometry steps, {} scans with {} tree detections within {} m; GPS: {} fixes kept, {} dropped as outliers (speed > {} m/s)",
        times.len() - 1,
        scan_obs.len(),
        used,
        model.max_range,
        gps.len(),
        gps_dropped,
        gps_max_speed
    ));
    rep.notes.extend(acceptance(&rep.results));
    rep.notes.push("errors are against GPS (itself metres off at times, the unit was failing) at the laser point; no paper figure exists for this run (the paper used the University Car Park)".into());
    rep.notes.push(
        "times are wall-clock on a shared 2-core machine under load from other builds".into(),
    );
    if let Some(path) = &trace_path {
        std::fs::write(path, &trace).map_err(|e| LocalizationError::Io {
            path: path.clone(),
            cause: e,
        })?;
    }
    if let Some(path) = &per_run_path {
        std::fs::write(path, &per_run).map_err(|e| LocalizationError::Param {
            key: "per_run".into(),
            msg: format!("{path}: {e}"),
        })?;
    }
    if let Some(path) = &plot {
        write_plot(path, &tracks, &gps)?;
        rep.notes.push(format!("plot: {path}"));
    }
    Ok(rep)
}

/// implicit@100 vs FastSLAM 2.0@100 and 1.5 × EKF-SLAM.
fn acceptance(rows: &[Row]) -> Vec<String> {
    let get = |name: &str, m: u64| {
        rows.iter()
            .find(|r| {
                r.method == name && r.metrics.get("samples").and_then(|v| v.as_u64()) == Some(m)
            })
            .and_then(|r| r.get("rms_m"))
    };
    let mut out = vec![];
    for name in ["implicit", "implicit-refine", "implicit-rb"] {
        if let (Some(i), Some(f), Some(e)) = (get(name, 100), get("fastslam2", 100), get("ekf", 1))
        {
            out.push(format!(
                "{name} at 100: RMS {i:.2} m; FastSLAM 2.0 at 100: {f:.2} m; EKF-SLAM: {e:.2} m (1.5x = {:.2} m): {name} ≤ FastSLAM 2.0 {}, ≤ 1.5x EKF {}",
                1.5 * e,
                if i <= f { "yes" } else { "NO" },
                if i <= 1.5 * e { "yes" } else { "NO" }
            ));
        }
    }
    out
}

/// One panel per track: GPS (grey), dead reckoning (light), the path and
/// the map.
fn write_plot(path: &str, tracks: &[Track], gps: &[GpsFix]) -> Result<(), LocalizationError> {
    let cols = tracks.len().max(1);
    let pw = 420.0;
    let mut svg = Svg::new(40.0 + cols as f64 * (pw + 90.0), pw + 140.0);
    svg.text(20.0, 24.0, 18.0, "Victoria Park: estimated path (colour) and map (black) over GPS (grey) and dead reckoning (orange)");
    let (x0, x1) = range(gps.iter().map(|g| g.x), 0.05);
    let (y0, y1) = range(gps.iter().map(|g| g.y), 0.05);
    let half = (x1 - x0).max(y1 - y0) / 2.0;
    let (cx, cy) = ((x0 + x1) / 2.0, (y0 + y1) / 2.0);
    let thin =
        |p: &[Pose]| -> Vec<(f64, f64)> { p.iter().step_by(20).map(|q| (q[0], q[1])).collect() };
    for (k, t) in tracks.iter().enumerate() {
        let panel = Panel {
            x0: 90.0 + k as f64 * (pw + 90.0),
            y0: 70.0,
            w: pw,
            h: pw,
            xr: (cx - half, cx + half),
            yr: (cy - half, cy + half),
            ylog: false,
        };
        svg.axes(&panel, &t.name, "x (m, east)", "y (m, north)");
        for g in gps.iter().step_by(2) {
            svg.dot(&panel, g.x, g.y, 1.0, "#b0b0b0", "");
        }
        svg.line(&panel, &thin(&tracks[0].path), "#ff7f0e", 1.0);
        svg.line(&panel, &thin(&t.path), COLORS[k % COLORS.len()], 1.5);
        for m in &t.map {
            svg.dot(&panel, m[0], m[1], 1.5, "black", "");
        }
    }
    svg.write(path)
}
