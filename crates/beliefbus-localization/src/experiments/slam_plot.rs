//! The `slam` experiment's figure: error against time per update, ours
//! beside the paper's (paper 003 Table 6 / Fig. 7 right).

use super::slam_svg::{range, Panel, Svg, COLORS};
use super::Report;
use crate::error::LocalizationError;

/// Two panels, ours and the paper's: error against time per update (log).
pub fn write_plot(path: &str, rep: &Report) -> Result<(), LocalizationError> {
    let mut svg = Svg::new(1200.0, 560.0);
    svg.text(
        20.0,
        24.0,
        18.0,
        "SLAM: time per update vs trajectory error (paper 003 Table 6 / Fig. 7 right)",
    );
    let methods = [
        "implicit",
        "fastslam1",
        "fastslam2",
        "ekf",
        "implicit-rb",
        "implicit-refine",
    ];
    for (k, (title, rows)) in [
        (
            "ours: synthetic car park on Victoria Park odometry",
            &rep.results,
        ),
        (
            "paper: synthetic data on the University Car Park run",
            &rep.paper,
        ),
    ]
    .into_iter()
    .enumerate()
    {
        let pts = |name: &str| -> Vec<(f64, f64, u64)> {
            let mut v: Vec<(f64, f64, u64)> = rows
                .iter()
                .filter(|r| r.method == name)
                .filter_map(|r| {
                    let m = r
                        .metrics
                        .get("samples")
                        .and_then(|v| v.as_u64())
                        .unwrap_or(0);
                    Some((r.get("error_pct")?, r.get("time_ms")?, m))
                })
                .collect();
            v.sort_by_key(|p| p.2);
            v
        };
        let all: Vec<(f64, f64, u64)> = methods.iter().flat_map(|m| pts(m)).collect();
        if all.is_empty() {
            continue;
        }
        let (_, emax) = range(all.iter().map(|p| p.0), 0.1);
        let tmin = all
            .iter()
            .map(|p| p.1)
            .fold(f64::INFINITY, f64::min)
            .max(1e-6);
        let tmax = all.iter().map(|p| p.1).fold(0.0, f64::max).max(tmin * 2.0);
        let panel = Panel {
            x0: 90.0 + 600.0 * k as f64,
            y0: 70.0,
            w: 470.0,
            h: 420.0,
            xr: (0.0, emax.max(1e-9)),
            yr: (tmin / 1.5, tmax * 1.5),
            ylog: true,
        };
        svg.axes(&panel, title, "error (%)", "time per update (ms, log)");
        for (c, name) in methods.iter().enumerate() {
            let p = pts(name);
            if p.is_empty() {
                continue;
            }
            let line: Vec<(f64, f64)> = p.iter().map(|q| (q.0, q.1)).collect();
            svg.line(&panel, &line, COLORS[c], 2.0);
            for q in &p {
                let lab = if *name == "ekf" {
                    "EKF".to_string()
                } else {
                    q.2.to_string()
                };
                svg.dot(&panel, q.0, q.1, 4.0, COLORS[c], &lab);
            }
            svg.legend(
                panel.x0 + panel.w - 130.0,
                panel.y0 + 20.0 + 18.0 * c as f64,
                COLORS[c],
                name,
            );
        }
    }
    svg.write(path)
}

/// One method's run on a data set: its name, estimated path and map.
pub struct PathMap {
    pub name: String,
    pub path: Vec<crate::geometry::Pose>,
    pub map: Vec<crate::geometry::Point>,
}

/// Paper 003 Fig. 7 (left): one data set, a panel per method: the true
/// path (grey) and landmarks (grey rings), the estimated path (colour) and
/// map (black).
pub fn write_paths(
    path: &str,
    truth: &[crate::geometry::Pose],
    landmarks: &[crate::geometry::Point],
    runs: &[PathMap],
) -> Result<(), LocalizationError> {
    let cols = runs.len().clamp(1, 3);
    let rows = runs.len().div_ceil(cols).max(1);
    let pw = 380.0;
    let mut svg = Svg::new(
        40.0 + cols as f64 * (pw + 90.0),
        60.0 + rows as f64 * (pw + 90.0),
    );
    svg.text(
        20.0,
        24.0,
        18.0,
        "SLAM on one synthetic car park: estimated path (colour) and map (black) over the truth (grey)",
    );
    let (x0, x1) = range(truth.iter().map(|p| p[0]), 0.1);
    let (y0, y1) = range(truth.iter().map(|p| p[1]), 0.1);
    let half = (x1 - x0).max(y1 - y0) / 2.0 + 10.0;
    let (cx, cy) = ((x0 + x1) / 2.0, (y0 + y1) / 2.0);
    let thin = |p: &[crate::geometry::Pose]| -> Vec<(f64, f64)> {
        p.iter().step_by(5).map(|q| (q[0], q[1])).collect()
    };
    for (k, r) in runs.iter().enumerate() {
        let panel = Panel {
            x0: 90.0 + (k % cols) as f64 * (pw + 90.0),
            y0: 70.0 + (k / cols) as f64 * (pw + 90.0),
            w: pw,
            h: pw,
            xr: (cx - half, cx + half),
            yr: (cy - half, cy + half),
            ylog: false,
        };
        svg.axes(&panel, &r.name, "x (m)", "y (m)");
        svg.line(&panel, &thin(truth), "#b0b0b0", 2.0);
        for m in landmarks {
            svg.dot(&panel, m[0], m[1], 3.0, "#c8c8c8", "");
        }
        svg.line(&panel, &thin(&r.path), COLORS[k % COLORS.len()], 1.2);
        for m in &r.map {
            svg.dot(&panel, m[0], m[1], 1.5, "black", "");
        }
    }
    svg.write(path)
}

/// `a/b.svg` → `a/b-paths.svg`.
pub fn paths_file(plot: &str) -> String {
    match plot.strip_suffix(".svg") {
        Some(stem) => format!("{stem}-paths.svg"),
        None => format!("{plot}-paths.svg"),
    }
}
