//! SVG plots: for each row (a path, or a core), a histogram of the values on
//! log–log axes (counts per logarithmic bin, so every decade of latency
//! gets the same width and a rare tail stays visible) and the CDF on a log
//! time axis with p50/p99 marked. Series of a row share the axes, so ours
//! and bare (or pipeline and timer) compare at a glance.

use super::LatencyError;
use crate::rt::LatencyHist;
use plotters::prelude::*;
use std::path::Path;

/// One distribution to draw.
pub struct Series<'a> {
    pub label: String,
    pub hist: &'a LatencyHist,
}

/// One row of panels.
pub struct Row<'a> {
    pub title: String,
    pub series: Vec<Series<'a>>,
}

/// Logarithmic bins per decade of the histogram panels.
const BINS_PER_DECADE: f64 = 20.0;

const COLORS: [RGBColor; 4] = [
    RGBColor(31, 119, 180),
    RGBColor(214, 39, 40),
    RGBColor(44, 160, 44),
    RGBColor(148, 103, 189),
];

/// (value in µs, count) of every recorded value.
fn points(h: &LatencyHist) -> Vec<(f64, u64)> {
    h.inner()
        .iter_recorded()
        .map(|v| (v.value_iterated_to() as f64 / 1e3, v.count_at_value()))
        .collect()
}

/// The µs range a row's panels span: [min, max] of every series, widened
/// to whole log steps.
fn x_range(rows: &[Vec<(f64, u64)>]) -> Option<(f64, f64)> {
    let mut lo = f64::INFINITY;
    let mut hi = 0.0f64;
    for r in rows {
        for &(v, _) in r {
            lo = lo.min(v);
            hi = hi.max(v);
        }
    }
    if !(hi > 0.0) {
        return None;
    }
    // Five decades below the maximum are plenty; values under the floor
    // (a jitter of a few ns) are drawn at it.
    let lo = lo.max(hi * 1e-5).max(1e-2);
    Some((lo / 1.25, (hi * 1.25).max(lo * 2.0)))
}

/// Counts per log bin: (bin lower edge, bin upper edge, count).
pub fn log_bins(pts: &[(f64, u64)], lo: f64, hi: f64) -> Vec<(f64, f64, u64)> {
    let decades = (hi / lo).log10().max(1e-9);
    let n = (decades * BINS_PER_DECADE).ceil().max(1.0) as usize;
    let step = decades / n as f64;
    let mut bins: Vec<(f64, f64, u64)> = (0..n)
        .map(|i| {
            (
                lo * 10f64.powf(i as f64 * step),
                lo * 10f64.powf((i + 1) as f64 * step),
                0,
            )
        })
        .collect();
    for &(v, c) in pts {
        // Below `lo` counts into the first bin, above `hi` into the last.
        let i = (((v.max(lo) / lo).log10() / step).floor().max(0.0) as usize).min(n - 1);
        bins[i].2 += c;
    }
    bins
}

fn quantile_of(pts: &[(f64, u64)], total: u64, q: f64) -> f64 {
    let want = ((q * total as f64).ceil() as u64).max(1);
    let mut acc = 0;
    for &(v, c) in pts {
        acc += c;
        if acc >= want {
            return v;
        }
    }
    pts.last().map(|p| p.0).unwrap_or(0.0)
}

/// An axis label: as few digits as the magnitude needs.
fn fmt_us(v: f64) -> String {
    if v >= 10.0 {
        format!("{v:.0}")
    } else if v >= 1.0 {
        format!("{v:.1}")
    } else {
        format!("{v:.2}")
    }
}

fn draw_err(e: impl std::fmt::Debug, path: &Path) -> LatencyError {
    LatencyError::Output {
        path: path.display().to_string(),
        reason: format!("{e:?}"),
    }
}

/// Draw `rows` under `title` into the SVG file `path` (drawn in memory,
/// then put in place by [`crate::rt::files::replace_file`]).
pub fn write_svg(path: &Path, title: &str, rows: &[Row]) -> Result<(), LatencyError> {
    let mut svg = String::new();
    draw_svg(&mut svg, path, title, rows)?;
    crate::rt::files::replace_file(path, svg.as_bytes()).map_err(|e| draw_err(e, path))
}

fn draw_svg(svg: &mut String, path: &Path, title: &str, rows: &[Row]) -> Result<(), LatencyError> {
    let n = rows.len().max(1);
    let height = 50 + 300 * n as u32;
    let root = SVGBackend::with_string(svg, (1200, height)).into_drawing_area();
    root.fill(&WHITE).map_err(|e| draw_err(e, path))?;
    let root = root
        .titled(title, ("sans-serif", 22))
        .map_err(|e| draw_err(e, path))?;
    let panels = root.split_evenly((n, 2));
    for (i, row) in rows.iter().enumerate() {
        let pts: Vec<Vec<(f64, u64)>> = row.series.iter().map(|s| points(s.hist)).collect();
        let Some((lo, hi)) = x_range(&pts) else {
            continue;
        };
        // Histogram, log–log.
        let bins: Vec<Vec<(f64, f64, u64)>> = pts.iter().map(|p| log_bins(p, lo, hi)).collect();
        let cmax = bins
            .iter()
            .flat_map(|b| b.iter().map(|x| x.2))
            .max()
            .unwrap_or(1)
            .max(1) as f64;
        let floor = 0.5;
        let mut chart = ChartBuilder::on(&panels[2 * i])
            .caption(format!("{} — histogram", row.title), ("sans-serif", 16))
            .margin(10)
            .x_label_area_size(35)
            .y_label_area_size(60)
            .build_cartesian_2d((lo..hi).log_scale(), (floor..cmax * 2.0).log_scale())
            .map_err(|e| draw_err(e, path))?;
        chart
            .configure_mesh()
            .x_desc("latency (µs)")
            .y_desc("count per bin")
            .x_label_formatter(&|v| fmt_us(*v))
            .y_label_formatter(&|v| format!("{v:.0}"))
            .draw()
            .map_err(|e| draw_err(e, path))?;
        for (k, (s, b)) in row.series.iter().zip(&bins).enumerate() {
            let color = COLORS[k % COLORS.len()];
            let mut line = Vec::with_capacity(2 * b.len());
            for &(a, z, c) in b {
                let y = (c as f64).max(floor);
                line.push((a, y));
                line.push((z, y));
            }
            chart
                .draw_series(LineSeries::new(line, color.stroke_width(2)))
                .map_err(|e| draw_err(e, path))?
                .label(format!("{} (n={})", s.label, s.hist.count()))
                .legend(move |(x, y)| {
                    PathElement::new(vec![(x, y), (x + 20, y)], color.stroke_width(2))
                });
        }
        chart
            .configure_series_labels()
            .position(SeriesLabelPosition::UpperRight)
            .background_style(WHITE.mix(0.8))
            .border_style(BLACK)
            .draw()
            .map_err(|e| draw_err(e, path))?;

        // CDF, log time axis, p50 and p99 marked.
        let mut chart = ChartBuilder::on(&panels[2 * i + 1])
            .caption(format!("{} — CDF", row.title), ("sans-serif", 16))
            .margin(10)
            .x_label_area_size(35)
            .y_label_area_size(60)
            .build_cartesian_2d((lo..hi).log_scale(), 0.0..1.0)
            .map_err(|e| draw_err(e, path))?;
        chart
            .configure_mesh()
            .x_desc("latency (µs)")
            .y_desc("fraction ≤ x")
            .x_label_formatter(&|v| fmt_us(*v))
            .draw()
            .map_err(|e| draw_err(e, path))?;
        for (k, (s, p)) in row.series.iter().zip(&pts).enumerate() {
            let color = COLORS[k % COLORS.len()];
            let total: u64 = p.iter().map(|x| x.1).sum();
            if total == 0 {
                continue;
            }
            let mut acc = 0u64;
            let mut line = Vec::with_capacity(p.len() + 1);
            line.push((lo, 0.0));
            for &(v, c) in p {
                acc += c;
                line.push((v.max(lo), acc as f64 / total as f64));
            }
            let (p50, p99) = (quantile_of(p, total, 0.5), quantile_of(p, total, 0.99));
            chart
                .draw_series(LineSeries::new(line, color.stroke_width(2)))
                .map_err(|e| draw_err(e, path))?
                .label(format!("{}: p50 {p50:.2} µs, p99 {p99:.2} µs", s.label))
                .legend(move |(x, y)| {
                    PathElement::new(vec![(x, y), (x + 20, y)], color.stroke_width(2))
                });
            chart
                .draw_series(
                    [(p50, 0.5), (p99, 0.99)]
                        .into_iter()
                        .map(|(x, y)| Circle::new((x.max(lo), y), 4, color.filled())),
                )
                .map_err(|e| draw_err(e, path))?;
        }
        chart
            .configure_series_labels()
            .position(SeriesLabelPosition::LowerRight)
            .background_style(WHITE.mix(0.8))
            .border_style(BLACK)
            .draw()
            .map_err(|e| draw_err(e, path))?;
    }
    root.present().map_err(|e| draw_err(e, path))?;
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn log_bins_keep_every_count_and_cover_the_range() {
        let pts = vec![(1.0, 3), (9.99, 1), (10.0, 5), (99.0, 2)];
        let b = log_bins(&pts, 1.0, 100.0);
        assert_eq!(b.len(), 40);
        assert_eq!(b.iter().map(|x| x.2).sum::<u64>(), 11);
        assert!((b[0].0 - 1.0).abs() < 1e-12);
        assert!((b.last().unwrap().1 - 100.0).abs() < 1e-9);
        // 10 µs starts the second decade.
        assert_eq!(b[20].2, 5);
        assert_eq!(b[0].2, 3);
    }

    #[test]
    fn an_svg_is_written_with_one_row_per_path() {
        let mut a = LatencyHist::new();
        let mut b = LatencyHist::new();
        for v in 1..=2_000u64 {
            a.record(2_000 + v * 3);
            b.record(1_800 + v * 2);
        }
        let dir = std::env::temp_dir().join(format!("bb-plot-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let f = dir.join("p.svg");
        let empty = LatencyHist::new();
        let rows = vec![
            Row {
                title: "observation".into(),
                series: vec![
                    Series {
                        label: "ours".into(),
                        hist: &a,
                    },
                    Series {
                        label: "bare".into(),
                        hist: &b,
                    },
                ],
            },
            Row {
                title: "empty".into(),
                series: vec![Series {
                    label: "ours".into(),
                    hist: &empty,
                }],
            },
        ];
        write_svg(&f, "test", &rows).unwrap();
        let svg = std::fs::read_to_string(&f).unwrap();
        assert!(svg.starts_with("<svg"));
        assert!(svg.contains("observation — histogram"));
        assert!(svg.contains("observation — CDF"));
        assert!(svg.contains("ours (n=2000)"));
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
