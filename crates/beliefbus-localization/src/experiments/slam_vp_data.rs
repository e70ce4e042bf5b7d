//! The rest of the Victoria Park run for SLAM on the real data: the GPS
//! fixes (`gps.csv`: `time_s,x_m,y_m`, x = Lo_m east, y = La_m north) and
//! the ACFR tree detections (`derived/trees_detectTreesI16.csv`:
//! `time_s,scan_index,range_m,bearing_rad,diameter_m`, laser frame with
//! π/2 straight ahead), read in place. GPS outliers are gated as the data's
//! README describes: a fix implying a speed above `max_speed` from the last
//! accepted fix is dropped.

use crate::error::LocalizationError;
use crate::slam::assoc::RangeBearing;
use crate::victoria::{parse_rows, read};
use std::path::Path;

/// One GPS fix.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct GpsFix {
    pub time: f64,
    pub x: f64,
    pub y: f64,
}

/// The tree detections of one scan.
#[derive(Clone, Debug, PartialEq)]
pub struct TreeScan {
    pub time: f64,
    pub obs: Vec<RangeBearing>,
}

/// Parse `gps.csv`; times must not decrease.
pub fn parse_gps(text: &str) -> Result<Vec<GpsFix>, LocalizationError> {
    let mut out: Vec<GpsFix> = Vec::new();
    parse_rows("gps.csv", text, "time_s,x_m,y_m", |line, r| {
        if out.last().is_some_and(|f| r[0] < f.time) {
            return Err(LocalizationError::Parse {
                file: "gps.csv",
                line,
                msg: format!("time {} decreases", r[0]),
            });
        }
        out.push(GpsFix {
            time: r[0],
            x: r[1],
            y: r[2],
        });
        Ok(())
    })?;
    Ok(out)
}

/// Parse the tree detections, grouped by scan (rows of a scan are
/// consecutive; scan times must increase).
pub fn parse_trees(text: &str) -> Result<Vec<TreeScan>, LocalizationError> {
    const FILE: &str = "trees_detectTreesI16.csv";
    let mut out: Vec<TreeScan> = Vec::new();
    let mut last_index = f64::NAN;
    parse_rows(
        FILE,
        text,
        "time_s,scan_index,range_m,bearing_rad,diameter_m",
        |line, r| {
            if !(r[2] > 0.0) {
                return Err(LocalizationError::Parse {
                    file: FILE,
                    line,
                    msg: format!("range {} not > 0", r[2]),
                });
            }
            let z = RangeBearing {
                range: r[2],
                bearing: r[3],
            };
            if r[1] == last_index {
                out.last_mut().expect("a scan was started").obs.push(z);
            } else {
                if out.last().is_some_and(|s| !(r[0] > s.time)) {
                    return Err(LocalizationError::Parse {
                        file: FILE,
                        line,
                        msg: format!("scan time {} does not increase", r[0]),
                    });
                }
                out.push(TreeScan {
                    time: r[0],
                    obs: vec![z],
                });
                last_index = r[1];
            }
            Ok(())
        },
    )?;
    Ok(out)
}

/// Drop fixes implying more than `max_speed` (m/s) from the last accepted
/// one; returns the kept fixes and the number dropped.
pub fn gate_gps(fixes: &[GpsFix], max_speed: f64) -> (Vec<GpsFix>, usize) {
    let mut kept: Vec<GpsFix> = Vec::with_capacity(fixes.len());
    let mut dropped = 0;
    for f in fixes {
        match kept.last() {
            Some(l) if f.time > l.time => {
                let v = (f.x - l.x).hypot(f.y - l.y) / (f.time - l.time);
                if v > max_speed {
                    dropped += 1;
                    continue;
                }
            }
            Some(_) => {
                dropped += 1;
                continue;
            }
            None => {}
        }
        kept.push(*f);
    }
    (kept, dropped)
}

/// Read `gps.csv` and the tree detections from the data folder.
pub fn load(dir: &Path) -> Result<(Vec<GpsFix>, Vec<TreeScan>), LocalizationError> {
    Ok((
        parse_gps(&read(dir, "gps.csv")?)?,
        parse_trees(&read(dir, "derived/trees_detectTreesI16.csv")?)?,
    ))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn trees_group_by_scan_and_gps_outliers_are_gated() {
        let t = parse_trees(
            "time_s,scan_index,range_m,bearing_rad,diameter_m\n22.0,1,10.5,1.2,0.4\n22.0,1,20.0,0.3,0.5\n22.2,2,7.0,2.0,0.3\n",
        )
        .unwrap();
        assert_eq!(t.len(), 2);
        assert_eq!(t[0].obs.len(), 2);
        assert_eq!(
            t[0].obs[1],
            RangeBearing {
                range: 20.0,
                bearing: 0.3
            }
        );
        assert_eq!(t[1].time, 22.2);
        assert!(
            parse_trees("time_s,scan_index,range_m,bearing_rad,diameter_m\n1,1,0,1,1\n").is_err()
        );
        let g = parse_gps("time_s,x_m,y_m\n0,0,0\n1,3,4\n2,60,4\n3,8,4\n").unwrap();
        // 5 m/s kept; the jump of 57 m in 1 s dropped; the next fix is
        // 5 m from the last kept one over 2 s: kept.
        let (kept, dropped) = gate_gps(&g, 10.0);
        assert_eq!(dropped, 1);
        assert_eq!(
            kept.iter().map(|f| f.time).collect::<Vec<_>>(),
            vec![0.0, 1.0, 3.0]
        );
    }
}
