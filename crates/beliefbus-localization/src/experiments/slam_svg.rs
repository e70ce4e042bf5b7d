//! A small SVG writer for the SLAM experiments' figures: panels with linear
//! or logarithmic axes, polylines, markers and labels. Plain text, no
//! dependency; the figures are written where the `plot` parameter says.

use crate::error::LocalizationError;
use std::fmt::Write;

/// A drawing of `w` × `h` pixels.
pub struct Svg {
    body: String,
    w: f64,
    h: f64,
    /// Clip region of the last panel drawn by [`Svg::axes`].
    clip: usize,
}

/// A rectangle of the drawing mapped to data coordinates.
#[derive(Clone, Copy, Debug)]
pub struct Panel {
    pub x0: f64,
    pub y0: f64,
    pub w: f64,
    pub h: f64,
    pub xr: (f64, f64),
    pub yr: (f64, f64),
    pub ylog: bool,
}

impl Panel {
    /// Pixel position of a data point.
    pub fn at(&self, x: f64, y: f64) -> (f64, f64) {
        let fx = (x - self.xr.0) / (self.xr.1 - self.xr.0);
        let fy = if self.ylog {
            (y.max(1e-300).ln() - self.yr.0.ln()) / (self.yr.1.ln() - self.yr.0.ln())
        } else {
            (y - self.yr.0) / (self.yr.1 - self.yr.0)
        };
        (self.x0 + fx * self.w, self.y0 + (1.0 - fy) * self.h)
    }
}

/// Distinct colours for series.
pub const COLORS: [&str; 6] = [
    "#d62728", "#1f77b4", "#2ca02c", "#9467bd", "#ff7f0e", "#7f7f7f",
];

impl Svg {
    pub fn new(w: f64, h: f64) -> Self {
        Self {
            body: String::new(),
            w,
            h,
            clip: 0,
        }
    }

    /// Text at a pixel position.
    pub fn text(&mut self, x: f64, y: f64, size: f64, s: &str) {
        let s = s.replace('&', "&amp;").replace('<', "&lt;");
        let _ = writeln!(
            self.body,
            r#"<text x="{x:.1}" y="{y:.1}" font-family="sans-serif" font-size="{size}">{s}</text>"#
        );
    }

    /// Axes with a frame, ticks and labels.
    pub fn axes(&mut self, p: &Panel, title: &str, xlabel: &str, ylabel: &str) {
        // Series drawn after this are clipped to the panel.
        self.clip += 1;
        let _ = writeln!(
            self.body,
            r#"<clipPath id="c{}"><rect x="{:.1}" y="{:.1}" width="{:.1}" height="{:.1}"/></clipPath>"#,
            self.clip, p.x0, p.y0, p.w, p.h
        );
        let _ = writeln!(
            self.body,
            r#"<rect x="{:.1}" y="{:.1}" width="{:.1}" height="{:.1}" fill="none" stroke="black"/>"#,
            p.x0, p.y0, p.w, p.h
        );
        self.text(p.x0, p.y0 - 8.0, 14.0, title);
        self.text(p.x0 + p.w / 2.0 - 40.0, p.y0 + p.h + 36.0, 12.0, xlabel);
        self.text(p.x0 - 60.0, p.y0 - 22.0, 12.0, ylabel);
        for k in 0..=4 {
            let x = p.xr.0 + (p.xr.1 - p.xr.0) * k as f64 / 4.0;
            let (px, py) = p.at(x, p.yr.0);
            self.text(px - 12.0, py + 16.0, 11.0, &format!("{x:.3}"));
            let y = if p.ylog {
                (p.yr.0.ln() + (p.yr.1.ln() - p.yr.0.ln()) * k as f64 / 4.0).exp()
            } else {
                p.yr.0 + (p.yr.1 - p.yr.0) * k as f64 / 4.0
            };
            let (qx, qy) = p.at(p.xr.0, y);
            self.text(qx - 56.0, qy + 4.0, 11.0, &format!("{y:.3}"));
        }
    }

    /// A polyline through data points.
    pub fn line(&mut self, p: &Panel, pts: &[(f64, f64)], color: &str, width: f64) {
        if pts.is_empty() {
            return;
        }
        let mut d = String::new();
        for &(x, y) in pts {
            let (a, b) = p.at(x, y);
            let _ = write!(d, "{a:.1},{b:.1} ");
        }
        let _ = writeln!(
            self.body,
            r#"<polyline points="{d}" fill="none" stroke="{color}" stroke-width="{width}" clip-path="url(#c{})"/>"#,
            self.clip
        );
    }

    /// A marker with an optional label.
    pub fn dot(&mut self, p: &Panel, x: f64, y: f64, r: f64, color: &str, label: &str) {
        let (a, b) = p.at(x, y);
        let _ = writeln!(
            self.body,
            r#"<circle cx="{a:.1}" cy="{b:.1}" r="{r}" fill="{color}" clip-path="url(#c{})"/>"#,
            self.clip
        );
        if !label.is_empty() {
            self.text(a + 5.0, b - 5.0, 10.0, label);
        }
    }

    /// A legend entry at a pixel position.
    pub fn legend(&mut self, x: f64, y: f64, color: &str, label: &str) {
        let _ = writeln!(
            self.body,
            r#"<line x1="{x:.1}" y1="{y:.1}" x2="{:.1}" y2="{y:.1}" stroke="{color}" stroke-width="3"/>"#,
            x + 20.0
        );
        self.text(x + 26.0, y + 4.0, 12.0, label);
    }

    /// The document.
    pub fn finish(&self) -> String {
        format!(
            "<svg xmlns=\"http://www.w3.org/2000/svg\" width=\"{}\" height=\"{}\">\n<rect width=\"100%\" height=\"100%\" fill=\"white\"/>\n{}</svg>\n",
            self.w, self.h, self.body
        )
    }

    /// Write the document to `path`.
    pub fn write(&self, path: &str) -> Result<(), LocalizationError> {
        std::fs::write(path, self.finish()).map_err(|cause| LocalizationError::Io {
            path: path.to_string(),
            cause,
        })
    }
}

/// Data range of values with a margin, never empty.
pub fn range(v: impl Iterator<Item = f64>, margin: f64) -> (f64, f64) {
    let (mut lo, mut hi) = (f64::INFINITY, f64::NEG_INFINITY);
    for x in v.filter(|x| x.is_finite()) {
        lo = lo.min(x);
        hi = hi.max(x);
    }
    if !(hi > lo) {
        return (lo.min(0.0) - 1.0, hi.max(0.0) + 1.0);
    }
    let m = (hi - lo) * margin;
    (lo - m, hi + m)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn panels_map_corners_and_clip_their_series() {
        let p = Panel {
            x0: 10.0,
            y0: 20.0,
            w: 100.0,
            h: 50.0,
            xr: (0.0, 2.0),
            yr: (1.0, 100.0),
            ylog: true,
        };
        assert_eq!(p.at(0.0, 1.0), (10.0, 70.0));
        let (x, y) = p.at(2.0, 10.0);
        assert!((x - 110.0).abs() < 1e-12 && (y - 45.0).abs() < 1e-9);
        let mut s = Svg::new(200.0, 100.0);
        s.axes(&p, "t", "x", "y");
        s.line(&p, &[(0.0, 1.0), (2.0, 100.0)], "red", 1.0);
        let doc = s.finish();
        assert!(doc.starts_with("<svg") && doc.contains(r#"clip-path="url(#c1)""#));
        assert!(doc.contains("10.0,70.0 110.0,20.0"));
    }
}
