//! Paper 003 §4.1 (Monte Carlo localization with implicit sampling): the
//! experiment lives in the `beliefbus-localization` crate; this module
//! registers it as `beliefbus experiment mcl` and, with `--param
//! plot=FILE.svg`, draws the figure the paper's claim rests on (Fig. 6
//! right): time per update against error, ours beside the paper's.

use super::{ExperimentArgs, ExperimentReport, Row};
use anyhow::Context;
use beliefbus_localization::experiments as loc;
use plotters::prelude::*;
use std::path::Path;

/// `mcl` (Table 5).
pub fn mcl(args: &ExperimentArgs) -> anyhow::Result<ExperimentReport> {
    let exp = loc::find("mcl")
        .ok_or_else(|| anyhow::anyhow!("experiment mcl missing from beliefbus-localization"))?;
    let mut rep = (exp.run)(args.runs, args.seed, &args.params)?;
    let plot = args
        .params
        .iter()
        .rev()
        .find(|(k, _)| k == "plot")
        .map(|(_, v)| v.clone());
    if let Some(p) = plot {
        write_plot(Path::new(&p), &rep).with_context(|| format!("writing the plot {p}"))?;
        rep.notes.push(format!("plot: {p}"));
    }
    Ok(rep)
}

/// An experiment of the crate run as is (it writes its own plot).
fn run_named(name: &str, args: &ExperimentArgs) -> anyhow::Result<ExperimentReport> {
    let exp = loc::find(name)
        .ok_or_else(|| anyhow::anyhow!("experiment {name} missing from beliefbus-localization"))?;
    Ok((exp.run)(args.runs, args.seed, &args.params)?)
}

/// `slam` (Table 6).
pub fn slam(args: &ExperimentArgs) -> anyhow::Result<ExperimentReport> {
    run_named("slam", args)
}

/// `slam-victoria-park` (the real run).
pub fn slam_victoria_park(args: &ExperimentArgs) -> anyhow::Result<ExperimentReport> {
    run_named("slam-victoria-park", args)
}

/// A registry entry point.
type Entry = fn(&ExperimentArgs) -> anyhow::Result<ExperimentReport>;

/// The registry entries, with the crate's descriptions.
pub fn experiments() -> Vec<super::Experiment> {
    let entries: [(&str, Entry); 3] = [
        ("mcl", mcl),
        ("slam", slam),
        ("slam-victoria-park", slam_victoria_park),
    ];
    entries
        .into_iter()
        .filter_map(|(name, run)| {
            loc::find(name).map(|e| super::Experiment {
                name: e.name,
                about: e.about,
                reproduces: e.reproduces,
                params: e.params,
                run,
            })
        })
        .collect()
}

const COLORS: [RGBColor; 2] = [RGBColor(214, 39, 40), RGBColor(31, 119, 180)];

/// One method's points: (error %, time per update ms, samples).
type Curve = (String, Vec<(f64, f64, u64)>);

/// (error %, time per update ms) of each method's rows, in sample order.
fn curves(rows: &[Row]) -> Vec<Curve> {
    let mut out: Vec<Curve> = Vec::new();
    for r in rows {
        let (Some(e), Some(t)) = (r.get("error_pct"), r.get("time_ms")) else {
            continue;
        };
        let m = r
            .metrics
            .get("samples")
            .and_then(|v| v.as_u64())
            .unwrap_or(0);
        match out.iter_mut().find(|(n, _)| *n == r.method) {
            Some((_, pts)) => pts.push((e, t, m)),
            None => out.push((r.method.clone(), vec![(e, t, m)])),
        }
    }
    for (_, pts) in out.iter_mut() {
        pts.sort_by_key(|p| p.2);
    }
    out
}

/// Two panels, ours and the paper's: time per update (log) against error.
fn write_plot(path: &Path, rep: &ExperimentReport) -> anyhow::Result<()> {
    let mut svg = String::new();
    {
        let root = SVGBackend::with_string(&mut svg, (1200, 520)).into_drawing_area();
        let err = |e: &dyn std::fmt::Debug| anyhow::anyhow!("{e:?}");
        root.fill(&WHITE).map_err(|e| err(&e))?;
        let root = root
            .titled(
                "MCL: time per update vs relative trajectory error (paper 003 Table 5 / Fig. 6 right)",
                ("sans-serif", 20),
            )
            .map_err(|e| err(&e))?;
        let panels = root.split_evenly((1, 2));
        for (panel, (title, rows)) in panels.iter().zip([
            (
                "ours: synthetic car park on Victoria Park odometry",
                &rep.results,
            ),
            ("paper: University Car Park", &rep.paper),
        ]) {
            let cs = curves(rows);
            let pts = cs.iter().flat_map(|c| c.1.iter());
            let (mut emax, mut tmin, mut tmax) = (0.0f64, f64::INFINITY, 0.0f64);
            for &(e, t, _) in pts {
                emax = emax.max(e);
                tmin = tmin.min(t);
                tmax = tmax.max(t);
            }
            if !(tmax > 0.0) {
                continue;
            }
            let mut chart = ChartBuilder::on(panel)
                .caption(title, ("sans-serif", 16))
                .margin(12)
                .x_label_area_size(40)
                .y_label_area_size(70)
                .build_cartesian_2d(0.0..emax * 1.1, (tmin / 1.5..tmax * 1.5).log_scale())
                .map_err(|e| err(&e))?;
            chart
                .configure_mesh()
                .x_desc("error (%)")
                .y_desc("time per update (ms)")
                .y_label_formatter(&|v| format!("{v:.3}"))
                .draw()
                .map_err(|e| err(&e))?;
            for (k, (name, p)) in cs.iter().enumerate() {
                let color = COLORS[k % COLORS.len()];
                let line: Vec<(f64, f64)> = p.iter().map(|&(e, t, _)| (e, t)).collect();
                chart
                    .draw_series(LineSeries::new(line.clone(), color.stroke_width(2)))
                    .map_err(|e| err(&e))?
                    .label(name.clone())
                    .legend(move |(x, y)| {
                        PathElement::new(vec![(x, y), (x + 20, y)], color.stroke_width(2))
                    });
                chart
                    .draw_series(p.iter().map(|&(e, t, m)| {
                        EmptyElement::at((e, t))
                            + Circle::new((0, 0), 4, color.filled())
                            + Text::new(format!("{m}"), (6, -14), ("sans-serif", 12))
                    }))
                    .map_err(|e| err(&e))?;
            }
            chart
                .configure_series_labels()
                .position(SeriesLabelPosition::UpperRight)
                .background_style(WHITE.mix(0.8))
                .border_style(BLACK)
                .draw()
                .map_err(|e| err(&e))?;
        }
        root.present().map_err(|e| err(&e))?;
    }
    beliefbus_rt::files::replace_file(path, svg.as_bytes())
        .with_context(|| format!("writing {}", path.display()))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_plot_has_a_curve_per_method_in_both_panels() {
        let mut rep = ExperimentReport::new("mcl");
        for (m, e, t) in [(10u64, 3.0, 0.01), (40, 2.0, 0.03)] {
            rep.results.push(
                Row::new("implicit")
                    .int("samples", m)
                    .num("error_pct", e)
                    .num("time_ms", t),
            );
            rep.results.push(
                Row::new("standard")
                    .int("samples", m)
                    .num("error_pct", e * 2.0)
                    .num("time_ms", t / 2.0),
            );
        }
        rep.paper.push(
            Row::new("standard")
                .int("samples", 10)
                .num("error_pct", 6.91)
                .num("time_ms", 0.81),
        );
        let c = curves(&rep.results);
        assert_eq!(c.len(), 2);
        assert_eq!(c[0].1, vec![(3.0, 0.01, 10), (2.0, 0.03, 40)]);
        let dir = std::env::temp_dir().join(format!("beliefbus-mcl-plot-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let p = dir.join("mcl.svg");
        write_plot(&p, &rep).unwrap();
        let s = std::fs::read_to_string(&p).unwrap();
        assert!(s.starts_with("<svg") && s.contains("implicit") && s.contains("standard"));
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
