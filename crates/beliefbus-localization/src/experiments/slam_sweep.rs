//! A sweep of one `slam` setting in one command: any scalar parameter given
//! as a comma-separated list (`gap_len_s=0,2,4`, `laser_reading=sigma,variance`)
//! runs Table 6 once per value and returns one report whose rows carry the
//! swept setting under its own key (the experiment JSON convention: one row
//! per method and setting).
//!
//! Every value runs the whole `slam` experiment with the same `runs` and
//! `seed`, so data set r of every setting is drawn from the same random
//! streams and every method and setting sees the same filter seeds: the
//! settings are paired as the methods are. A setting that changes the data
//! (gaps, laser noise, rate) changes what those streams produce, not which
//! streams are used.

use super::{Report, Row, RunFn};
use crate::error::LocalizationError;
use serde_json::Value;

/// Parameters that take a list of their own (the sample sizes) or a path:
/// never a sweep.
const NOT_SWEPT: &[&str] = &[
    "implicit_samples",
    "implicit_refine_samples",
    "implicit_rb_samples",
    "fastslam1_samples",
    "fastslam2_samples",
    "data_dir",
    "per_run",
    "plot",
];

/// The swept key and its values, if one scalar parameter is given as a list;
/// an error naming the keys if more than one is.
pub fn swept(kv: &[(String, String)]) -> Result<Option<(String, Vec<String>)>, LocalizationError> {
    let mut found: Vec<(String, Vec<String>)> = Vec::new();
    for (i, (k, v)) in kv.iter().enumerate() {
        // The last occurrence of a key is the one that counts.
        let last = kv[i + 1..].iter().all(|(k2, _)| k2 != k);
        if !last || NOT_SWEPT.contains(&k.as_str()) || !v.contains(',') {
            continue;
        }
        let vals: Vec<String> = v.split(',').map(|s| s.trim().to_string()).collect();
        if vals.iter().any(String::is_empty) {
            return Err(LocalizationError::Param {
                key: k.clone(),
                msg: format!("'{v}': an empty value in the swept list"),
            });
        }
        found.push((k.clone(), vals));
    }
    match found.len() {
        0 => Ok(None),
        1 => Ok(found.pop()),
        _ => Err(LocalizationError::Param {
            key: found[1].0.clone(),
            msg: format!(
                "only one setting can be swept at a time; lists given for {}",
                found
                    .iter()
                    .map(|f| f.0.as_str())
                    .collect::<Vec<_>>()
                    .join(" and ")
            ),
        }),
    }
}

/// `path` with `-key=value` before its extension: each setting's per-run CSV
/// or figure gets its own file.
pub fn per_setting_path(path: &str, key: &str, value: &str) -> String {
    let p = std::path::Path::new(path);
    let tag = format!("{key}={value}");
    match (p.file_stem(), p.extension()) {
        (Some(stem), Some(ext)) => p
            .with_file_name(format!(
                "{}-{tag}.{}",
                stem.to_string_lossy(),
                ext.to_string_lossy()
            ))
            .display()
            .to_string(),
        _ => format!("{path}-{tag}"),
    }
}

/// The swept value as JSON: an integer, a number, or the text as given.
fn value_of(v: &str) -> Value {
    if let Ok(u) = v.parse::<u64>() {
        Value::from(u)
    } else if let Ok(f) = v.parse::<f64>() {
        Value::from(f)
    } else {
        Value::from(v)
    }
}

/// Run `one` (the single-setting experiment) once per value of `key` and
/// merge the reports: every row tagged with `key`, the notes prefixed with
/// the setting, the paper's rows once, the parameters of the first setting
/// with `key` replaced by the list.
pub fn run_sweep(
    runs: Option<usize>,
    seed: u64,
    kv: &[(String, String)],
    key: &str,
    values: &[String],
    one: RunFn,
) -> Result<Report, LocalizationError> {
    let mut out: Option<Report> = None;
    for v in values {
        let mut kv1: Vec<(String, String)> = kv.iter().filter(|(k, _)| k != key).cloned().collect();
        for (k, x) in kv1.iter_mut() {
            if k == "per_run" || k == "plot" {
                *x = per_setting_path(x, key, v);
            }
        }
        kv1.push((key.to_string(), v.clone()));
        let rep = one(runs, seed, &kv1)?;
        let tag = value_of(v);
        let merged = out.get_or_insert_with(|| {
            let mut m = Report::new(&rep.experiment);
            let mut cols = vec![key.to_string()];
            cols.extend(rep.columns.iter().cloned());
            m.columns = cols;
            m.params = rep.params.clone();
            m.paper = rep.paper.clone();
            m
        });
        for r in rep.results {
            let mut row = Row::new(&r.method);
            row.metrics.insert(key.to_string(), tag.clone());
            row.metrics.extend(r.metrics);
            merged.results.push(row);
        }
        for n in rep.notes {
            merged.notes.push(format!("{key}={v}: {n}"));
        }
    }
    let mut rep = out.ok_or_else(|| LocalizationError::Param {
        key: key.to_string(),
        msg: "an empty sweep".into(),
    })?;
    rep.param(key, values.join(","));
    rep.param("swept", key);
    Ok(rep)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn kv(pairs: &[(&str, &str)]) -> Vec<(String, String)> {
        pairs
            .iter()
            .map(|(k, v)| (k.to_string(), v.to_string()))
            .collect()
    }

    #[test]
    fn one_scalar_list_is_the_sweep_and_sample_lists_are_not() {
        assert_eq!(
            swept(&kv(&[("fastslam2_samples", "100,400"), ("gap_len_s", "2")])).unwrap(),
            None
        );
        assert_eq!(
            swept(&kv(&[
                ("fastslam2_samples", "100,400"),
                ("gap_len_s", "0, 2,4")
            ]))
            .unwrap(),
            Some(("gap_len_s".into(), vec!["0".into(), "2".into(), "4".into()]))
        );
        // The last value of a key counts, as for every parameter.
        assert_eq!(
            swept(&kv(&[("gap_len_s", "2,4"), ("gap_len_s", "4")])).unwrap(),
            None
        );
        match swept(&kv(&[("gap_len_s", "2,4"), ("scan_every", "1,4")])) {
            Err(LocalizationError::Param { key, msg }) => {
                assert_eq!(key, "scan_every");
                assert!(msg.contains("gap_len_s and scan_every"), "{msg}");
            }
            other => panic!("{other:?}"),
        }
        match swept(&kv(&[("gap_len_s", "2,")])) {
            Err(LocalizationError::Param { key, .. }) => assert_eq!(key, "gap_len_s"),
            other => panic!("{other:?}"),
        }
    }

    #[test]
    fn each_setting_writes_its_own_file() {
        assert_eq!(
            per_setting_path("out/C.csv", "gap_len_s", "4"),
            "out/C-gap_len_s=4.csv"
        );
        assert_eq!(per_setting_path("C", "scan_every", "0"), "C-scan_every=0");
        assert_eq!(value_of("4"), Value::from(4u64));
        assert_eq!(value_of("0.5"), Value::from(0.5));
        assert_eq!(value_of("sigma"), Value::from("sigma"));
    }

    /// A 40 Hz recording of 30 s (3 m/s, a slowly swinging steering) with
    /// scans every 0.2 s, written as the two Victoria Park files.
    fn synthetic_recording(dir: &std::path::Path) {
        std::fs::create_dir_all(dir).unwrap();
        let mut odo = String::from("time_s,speed_mps,steering_rad\n");
        for i in 0..1200 {
            let t = i as f64 * 0.025;
            odo += &format!("{t},3,{}\n", 0.2 * (0.3 * t).sin());
        }
        let mut scans = String::from("scan_index,time_s\n");
        for i in 0..150 {
            scans += &format!("{i},{}\n", 0.01 + i as f64 * 0.2);
        }
        std::fs::write(dir.join("odometry.csv"), odo).unwrap();
        std::fs::write(dir.join("laser_times.csv"), scans).unwrap();
    }

    #[test]
    fn a_two_setting_sweep_is_the_two_single_runs_on_the_same_data_sets() {
        use crate::experiments::slam;
        let dir = std::env::temp_dir().join(format!("beliefbus-slam-sweep-{}", std::process::id()));
        synthetic_recording(&dir);
        let d = dir.display().to_string();
        let csv = |name: &str| dir.join(name).display().to_string();
        let base = |per_run: String| {
            kv(&[
                ("data_dir", &d),
                ("start_time_s", "1"),
                ("duration_s", "12"),
                ("scan_every", "0"),
                ("implicit_samples", "none"),
                ("fastslam1_samples", "none"),
                ("fastslam2_samples", "8"),
                ("implicit_refine_samples", "8"),
                ("gap_every_s", "5"),
                ("per_run", &per_run),
            ])
        };
        let (runs, seed) = (3, 5);
        let mut sweep_kv = base(csv("sweep.csv"));
        sweep_kv.push(("gap_len_s".into(), "1,3".into()));
        let sweep = slam::run(Some(runs), seed, &sweep_kv).unwrap();
        assert_eq!(sweep.params["swept"], Value::from("gap_len_s"));
        assert_eq!(sweep.params["gap_len_s"], Value::from("1,3"));
        // fastslam2, implicit-refine and ekf at each setting, in order.
        assert_eq!(sweep.results.len(), 6);
        let mut errors = Vec::new();
        for (k, v) in ["1", "3"].into_iter().enumerate() {
            let mut one_kv = base(csv(&format!("one-{v}.csv")));
            one_kv.push(("gap_len_s".into(), v.into()));
            let one = slam::run(Some(runs), seed, &one_kv).unwrap();
            assert!(one.params.get("swept").is_none());
            let rows = &sweep.results[3 * k..3 * k + 3];
            assert_eq!(rows.len(), one.results.len());
            for (s, o) in rows.iter().zip(&one.results) {
                assert_eq!(
                    s.metrics["gap_len_s"],
                    Value::from(v.parse::<u64>().unwrap())
                );
                assert_eq!(s.method, o.method);
                for key in ["samples", "error_pct", "error_pct_se", "rms_m", "map_err_m"] {
                    assert_eq!(s.metrics[key], o.metrics[key], "{} {key} at {v}", s.method);
                }
                errors.push(s.get("error_pct").unwrap());
            }
            // The per-data-set figures, run by run: the same data sets.
            let swept_csv =
                std::fs::read_to_string(csv(&format!("sweep-gap_len_s={v}.csv"))).unwrap();
            let one_csv = std::fs::read_to_string(csv(&format!("one-{v}.csv"))).unwrap();
            assert_eq!(swept_csv, one_csv);
            assert_eq!(swept_csv.lines().count(), 1 + 3 * runs);
        }
        // The setting did change the data: the gaps move the errors.
        assert!(errors[..3] != errors[3..], "{errors:?}");
        std::fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn the_gap_length_leaves_the_true_path_and_landmarks_of_a_data_set_alone() {
        use crate::carpark::{CarPark, CarParkConfig};
        use beliefbus_core::rng::stream;
        let dir =
            std::env::temp_dir().join(format!("beliefbus-slam-sweep-cp-{}", std::process::id()));
        synthetic_recording(&dir);
        let rec = crate::victoria::load(&dir).unwrap();
        let cfg = |gap_len: f64| CarParkConfig {
            start_time: 1.0,
            duration: 12.0,
            gap_every: 5.0,
            gap_len,
            ..CarParkConfig::default()
        };
        for r in 0..3 {
            let a = CarPark::generate(&rec, &cfg(1.0), &mut stream(5, r)).unwrap();
            let b = CarPark::generate(&rec, &cfg(3.0), &mut stream(5, r)).unwrap();
            assert_eq!(a.truth, b.truth);
            assert_eq!(a.landmarks, b.landmarks);
            assert!(b.dropped_scans > a.dropped_scans);
        }
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
