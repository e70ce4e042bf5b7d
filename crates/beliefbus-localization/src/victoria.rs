//! Reader for the Victoria Park run (Guivant & Nebot, ACFR): the odometry
//! (`odometry.csv`: `time_s,speed_mps,steering_rad`, 40 Hz, wheel speed of
//! the rear left wheel, steering + = left) and the laser scan times
//! (`laser_times.csv`: `scan_index,time_s`), both on the data set's own
//! clock in seconds. The data are third-party and read in place: nothing is
//! copied. [`parse_odometry`] and [`parse_laser_times`] read text (pure);
//! [`load`] reads the two files of a folder.

use crate::error::LocalizationError;
use std::path::{Path, PathBuf};

/// The environment variable naming the data folder.
pub const DATA_ENV: &str = "BELIEFBUS_VICTORIA_PARK";
/// The default data folder, relative to the repository root.
pub const DEFAULT_DIR: &str = "../shared/data/victoria-park";

/// One odometry sample.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct OdometrySample {
    pub time: f64,
    /// Wheel speed v_l (m/s).
    pub speed: f64,
    /// Steering α (rad).
    pub steering: f64,
}

/// The odometry and the laser scan times of the run.
#[derive(Clone, Debug, Default)]
pub struct Recording {
    pub odometry: Vec<OdometrySample>,
    pub laser_times: Vec<f64>,
}

fn parse_err(file: &'static str, line: usize, msg: impl Into<String>) -> LocalizationError {
    LocalizationError::Parse {
        file,
        line,
        msg: msg.into(),
    }
}

/// Parse CSV rows of `ncol` finite numbers after a header that must equal
/// `header`; `f` receives each row.
pub(crate) fn parse_rows(
    file: &'static str,
    text: &str,
    header: &str,
    mut f: impl FnMut(usize, &[f64]) -> Result<(), LocalizationError>,
) -> Result<(), LocalizationError> {
    let ncol = header.split(',').count();
    let mut lines = text.lines().enumerate();
    match lines.next() {
        Some((_, h)) if h.trim() == header => {}
        Some((_, h)) => {
            return Err(parse_err(
                file,
                1,
                format!("header '{h}', expected '{header}'"),
            ))
        }
        None => return Err(parse_err(file, 1, "empty file")),
    }
    let mut row = vec![0.0; ncol];
    for (i, line) in lines {
        let line = line.trim();
        if line.is_empty() {
            continue;
        }
        let mut n = 0;
        for cell in line.split(',') {
            if n == ncol {
                return Err(parse_err(file, i + 1, format!("more than {ncol} columns")));
            }
            let v: f64 = cell
                .trim()
                .parse()
                .map_err(|e| parse_err(file, i + 1, format!("'{cell}': {e}")))?;
            if !v.is_finite() {
                return Err(parse_err(file, i + 1, format!("non-finite value '{cell}'")));
            }
            row[n] = v;
            n += 1;
        }
        if n != ncol {
            return Err(parse_err(
                file,
                i + 1,
                format!("{n} columns, expected {ncol}"),
            ));
        }
        f(i + 1, &row)?;
    }
    Ok(())
}

/// Parse `odometry.csv`; times must increase strictly.
pub fn parse_odometry(text: &str) -> Result<Vec<OdometrySample>, LocalizationError> {
    const FILE: &str = "odometry.csv";
    let mut out: Vec<OdometrySample> = Vec::new();
    parse_rows(FILE, text, "time_s,speed_mps,steering_rad", |line, r| {
        if let Some(last) = out.last() {
            if !(r[0] > last.time) {
                return Err(parse_err(
                    FILE,
                    line,
                    format!("time {} does not increase", r[0]),
                ));
            }
        }
        out.push(OdometrySample {
            time: r[0],
            speed: r[1],
            steering: r[2],
        });
        Ok(())
    })?;
    Ok(out)
}

/// Parse `laser_times.csv`; times must increase strictly.
pub fn parse_laser_times(text: &str) -> Result<Vec<f64>, LocalizationError> {
    const FILE: &str = "laser_times.csv";
    let mut out: Vec<f64> = Vec::new();
    parse_rows(FILE, text, "scan_index,time_s", |line, r| {
        if out.last().is_some_and(|&t| !(r[1] > t)) {
            return Err(parse_err(
                FILE,
                line,
                format!("time {} does not increase", r[1]),
            ));
        }
        out.push(r[1]);
        Ok(())
    })?;
    Ok(out)
}

/// The data folder: `explicit` if given, else `$BELIEFBUS_VICTORIA_PARK`,
/// else [`DEFAULT_DIR`] relative to the working directory (the repository
/// root under `cargo run`), else relative to this crate's repository.
pub fn resolve_dir(explicit: Option<&str>) -> PathBuf {
    if let Some(d) = explicit {
        return PathBuf::from(d);
    }
    if let Ok(d) = std::env::var(DATA_ENV) {
        if !d.is_empty() {
            return PathBuf::from(d);
        }
    }
    let cwd = PathBuf::from(DEFAULT_DIR);
    if cwd.exists() {
        return cwd;
    }
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../..")
        .join(DEFAULT_DIR)
}

pub(crate) fn read(dir: &Path, name: &str) -> Result<String, LocalizationError> {
    let p = dir.join(name);
    if !p.exists() {
        return Err(LocalizationError::DataMissing {
            path: p.display().to_string(),
        });
    }
    std::fs::read_to_string(&p).map_err(|cause| LocalizationError::Io {
        path: p.display().to_string(),
        cause,
    })
}

/// Read `odometry.csv` and `laser_times.csv` from `dir`.
pub fn load(dir: &Path) -> Result<Recording, LocalizationError> {
    if !dir.exists() {
        return Err(LocalizationError::DataMissing {
            path: dir.display().to_string(),
        });
    }
    Ok(Recording {
        odometry: parse_odometry(&read(dir, "odometry.csv")?)?,
        laser_times: parse_laser_times(&read(dir, "laser_times.csv")?)?,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    const ODO: &str = "time_s,speed_mps,steering_rad\n21.94,0.0,-0.0034717200000000006\n21.965,1.5,0.25\n\n21.99,-0.059,-0.5\n";

    #[test]
    fn odometry_rows_parse_exactly() {
        let o = parse_odometry(ODO).unwrap();
        assert_eq!(o.len(), 3);
        assert_eq!(o[0].time, 21.94);
        assert_eq!(o[0].steering, -0.0034717200000000006);
        assert_eq!(o[1].speed, 1.5);
        assert_eq!(
            o[2],
            OdometrySample {
                time: 21.99,
                speed: -0.059,
                steering: -0.5
            }
        );
    }

    #[test]
    fn laser_times_parse_and_keep_order() {
        let t = parse_laser_times("scan_index,time_s\n0,21.819\n1,22.033\n2,22.247\n").unwrap();
        assert_eq!(t, vec![21.819, 22.033, 22.247]);
    }

    #[test]
    fn bad_files_give_the_line() {
        let e = parse_odometry("time_s,speed_mps,steering_rad\n1,2,3\n2,x,3\n").unwrap_err();
        assert!(matches!(e, LocalizationError::Parse { line: 3, .. }), "{e}");
        let e = parse_odometry("time_s,speed_mps,steering_rad\n1,2\n").unwrap_err();
        assert!(matches!(e, LocalizationError::Parse { line: 2, .. }), "{e}");
        let e = parse_odometry("time,speed\n1,2\n").unwrap_err();
        assert!(matches!(e, LocalizationError::Parse { line: 1, .. }), "{e}");
        let e = parse_odometry("time_s,speed_mps,steering_rad\n1,2,3\n1,2,3\n").unwrap_err();
        assert!(e.to_string().contains("does not increase"), "{e}");
        let e = parse_laser_times("scan_index,time_s\n0,1\n1,NaN\n").unwrap_err();
        assert!(
            e.to_string().contains("non-finite") || e.to_string().contains("NaN"),
            "{e}"
        );
        let e = parse_laser_times("scan_index,time_s\n0,1,2\n").unwrap_err();
        assert!(e.to_string().contains("columns"), "{e}");
    }

    #[test]
    fn a_missing_folder_says_where_to_get_the_data() {
        let e = load(Path::new("/nonexistent/victoria-park")).unwrap_err();
        let s = e.to_string();
        assert!(matches!(e, LocalizationError::DataMissing { .. }));
        assert!(
            s.contains("victoria_park.htm") && s.contains("data_dir"),
            "{s}"
        );
    }
}
