//! The recorded Victoria Park run (Guivant & Nebot, ACFR) as the plant
//! streams it, read in place from the data folder: the odometry
//! (`odometry.csv`), the ACFR detector's tree features with their trunk
//! diameters (`derived/trees_detectTreesI16.csv`) and the GPS fixes
//! (`gps.csv`, outliers gated as the folder's README describes: a fix
//! implying more than `gps_max_speed` from the last kept one is dropped).
//!
//! Steps are the odometry samples: step k ≥ 1 moves by sample k's (v_l, α)
//! over (t_{k−1}, t_k] (as the offline `slam-victoria-park` experiment). A
//! scan belongs to the first step whose time is at or after it; scans at or
//! before t_0 are skipped. Tree detections beyond `max_range` are dropped,
//! and a scan left empty publishes nothing.

use beliefbus_localization::error::DATA_SOURCE;
use beliefbus_localization::experiments::slam_vp_data::{gate_gps, parse_gps, GpsFix};
use beliefbus_localization::geometry::Pose;
use beliefbus_localization::victoria;
use std::path::Path;

/// One tree detection: range (m), bearing (rad, laser frame, π/2 ahead),
/// trunk diameter (m).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Tree {
    pub range: f64,
    pub bearing: f64,
    pub diameter: f64,
}

/// A scan's detections: `trees[first..first + len]`, published before the
/// odometry sample of `step`, measured at `time` (data-set clock).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Scan {
    pub step: usize,
    pub time: f64,
    pub first: usize,
    pub len: usize,
}

/// The run, from its first odometry sample to `end_time`.
#[derive(Clone, Debug, Default)]
pub struct Run {
    /// Odometry times t_0..t_N (data-set clock, s).
    pub times: Vec<f64>,
    /// (v_l, α) of each odometry sample (index 0: the start, not a step).
    pub odometry: Vec<[f64; 2]>,
    pub scans: Vec<Scan>,
    pub trees: Vec<Tree>,
    /// Kept GPS fixes and how many were gated out.
    pub gps: Vec<GpsFix>,
    pub gps_dropped: usize,
}

impl Run {
    /// Steps N.
    pub fn steps(&self) -> usize {
        self.times.len().saturating_sub(1)
    }

    /// The detections of a scan.
    pub fn scan_trees(&self, s: &Scan) -> &[Tree] {
        &self.trees[s.first..s.first + s.len]
    }

    /// The start: the first kept GPS fix with `heading` (rad), the pose of
    /// the laser point at t_0 (the offline experiment's start).
    pub fn start(&self, heading: f64) -> Pose {
        let g = self.gps.first().copied().unwrap_or(GpsFix {
            time: 0.0,
            x: 0.0,
            y: 0.0,
        });
        Pose::new(g.x, g.y, heading)
    }
}

/// Why the run cannot be read.
fn missing(what: &str, dir: &Path) -> String {
    format!(
        "Victoria Park data not found: {what} in {} does not exist. The data set is third-party and not \
         shipped with beliefbus: get it from {DATA_SOURCE}; the tree features come from \
         github.com/kykleung/RFS-SLAM (data/VictoriaPark/measurements.dat, see the data folder's README). \
         Point victoria-park.data_dir at the folder, or set {}",
        dir.display(),
        victoria::DATA_ENV
    )
}

/// Parse the tree detections with their diameters, rows of a scan
/// consecutive (`time_s,scan_index,range_m,bearing_rad,diameter_m`);
/// returns (scan time, tree) per row.
pub fn parse_trees(text: &str) -> Result<Vec<(f64, Tree)>, String> {
    const HEADER: &str = "time_s,scan_index,range_m,bearing_rad,diameter_m";
    let mut lines = text.lines().enumerate();
    match lines.next() {
        Some((_, h)) if h.trim() == HEADER => {}
        _ => return Err(format!("tree features: line 1 is not '{HEADER}'")),
    }
    let mut out: Vec<(f64, Tree)> = Vec::new();
    for (i, line) in lines {
        let line = line.trim();
        if line.is_empty() {
            continue;
        }
        let mut v = [0.0; 5];
        let mut n = 0;
        for cell in line.split(',') {
            if n == 5 {
                return Err(format!(
                    "tree features: line {}: more than 5 columns",
                    i + 1
                ));
            }
            v[n] = cell
                .trim()
                .parse::<f64>()
                .ok()
                .filter(|x| x.is_finite())
                .ok_or_else(|| {
                    format!("tree features: line {}: '{cell}' is not a number", i + 1)
                })?;
            n += 1;
        }
        if n != 5 || !(v[2] > 0.0) || out.last().is_some_and(|l| v[0] < l.0) {
            return Err(format!(
                "tree features: line {}: need 5 columns, range > 0 and times in order",
                i + 1
            ));
        }
        out.push((
            v[0],
            Tree {
                range: v[2],
                bearing: v[3],
                diameter: v[4],
            },
        ));
    }
    Ok(out)
}

/// Assemble the run from parsed pieces (pure; [`load`] reads the files).
pub fn assemble(
    odometry: &[victoria::OdometrySample],
    trees: &[(f64, Tree)],
    gps_raw: &[GpsFix],
    end_time: f64,
    max_range: f64,
    gps_max_speed: f64,
) -> Result<Run, String> {
    let odo: Vec<_> = odometry.iter().filter(|o| o.time <= end_time).collect();
    if odo.len() < 2 {
        return Err(format!(
            "end_time_s = {end_time} leaves fewer than two odometry samples"
        ));
    }
    let (gps, gps_dropped) = gate_gps(gps_raw, gps_max_speed);
    if gps.is_empty() {
        return Err("the GPS file has no fix (the start pose is the first fix)".into());
    }
    let times: Vec<f64> = odo.iter().map(|o| o.time).collect();
    let mut run = Run {
        odometry: odo.iter().map(|o| [o.speed, o.steering]).collect(),
        gps,
        gps_dropped,
        ..Run::default()
    };
    let (t0, tn) = (times[0], times[times.len() - 1]);
    let mut step = 1;
    let mut last_time = f64::NAN;
    for &(t, tree) in trees.iter().filter(|(t, _)| *t > t0 && *t <= tn) {
        if tree.range > max_range {
            continue;
        }
        if t != last_time {
            while times[step] < t {
                step += 1;
            }
            run.scans.push(Scan {
                step,
                time: t,
                first: run.trees.len(),
                len: 0,
            });
            last_time = t;
        }
        run.trees.push(tree);
        if let Some(s) = run.scans.last_mut() {
            s.len += 1;
        }
    }
    run.times = times;
    Ok(run)
}

/// Read the run from `dir` (the odometry, tree features and GPS files).
pub fn load(dir: &Path, end_time: f64, max_range: f64, gps_max_speed: f64) -> Result<Run, String> {
    let read = |name: &str| -> Result<String, String> {
        let p = dir.join(name);
        if !p.exists() {
            return Err(missing(name, dir));
        }
        std::fs::read_to_string(&p).map_err(|e| format!("reading {}: {e}", p.display()))
    };
    let odometry = victoria::parse_odometry(&read("odometry.csv")?).map_err(|e| e.to_string())?;
    let trees = parse_trees(&read("derived/trees_detectTreesI16.csv")?)?;
    let gps = parse_gps(&read("gps.csv")?).map_err(|e| e.to_string())?;
    assemble(&odometry, &trees, &gps, end_time, max_range, gps_max_speed)
}
