//! Helpers shared by the path-integral experiments: typed
//! `--param key=value` lookup that rejects unknown keys, and summary
//! statistics.

use super::ExperimentArgs;
use anyhow::{bail, Context};
use beliefbus_core::experiment_params::debug_check_default;
use std::str::FromStr;

/// `v` comma-separated, as a list default is documented.
pub fn join<T: std::fmt::Display>(v: &[T]) -> String {
    v.iter()
        .map(|x| x.to_string())
        .collect::<Vec<_>>()
        .join(",")
}

/// Reject parameters not in `known`.
pub fn check_params(args: &ExperimentArgs, known: &[&str]) -> anyhow::Result<()> {
    for (k, _) in &args.params {
        if !known.contains(&k.as_str()) {
            bail!("unknown parameter '{k}' (known: {})", known.join(", "));
        }
    }
    Ok(())
}

/// The value of parameter `key`, or `default`.
pub fn param<T: FromStr + std::fmt::Display>(
    args: &ExperimentArgs,
    key: &str,
    default: T,
) -> anyhow::Result<T>
where
    T::Err: std::fmt::Display,
{
    debug_check_default(args.doc, key, &default.to_string());
    match args.params.iter().rev().find(|(k, _)| k == key) {
        Some((_, v)) => v
            .parse::<T>()
            .map_err(|e| anyhow::anyhow!("{e}"))
            .with_context(|| format!("parameter {key}={v}")),
        None => Ok(default),
    }
}

/// A comma-separated list parameter.
pub fn list_param<T: FromStr + Clone + std::fmt::Display>(
    args: &ExperimentArgs,
    key: &str,
    default: &[T],
) -> anyhow::Result<Vec<T>>
where
    T::Err: std::fmt::Display,
{
    debug_check_default(args.doc, key, &join(default));
    match args.params.iter().rev().find(|(k, _)| k == key) {
        Some((_, v)) => v
            .split(',')
            .map(|s| {
                s.trim()
                    .parse::<T>()
                    .map_err(|e| anyhow::anyhow!("{e}"))
                    .with_context(|| format!("parameter {key}={v}"))
            })
            .collect(),
        None => Ok(default.to_vec()),
    }
}

/// Mean and sample standard deviation.
pub fn mean_std(v: &[f64]) -> (f64, f64) {
    if v.is_empty() {
        return (f64::NAN, f64::NAN);
    }
    let n = v.len() as f64;
    let m = v.iter().sum::<f64>() / n;
    if v.len() < 2 {
        return (m, 0.0);
    }
    let var = v.iter().map(|x| (x - m).powi(2)).sum::<f64>() / (n - 1.0);
    (m, var.sqrt())
}

/// The q-quantile (0..=1) of `v` by linear interpolation (sorts a copy).
pub fn percentile(v: &[f64], q: f64) -> f64 {
    if v.is_empty() {
        return f64::NAN;
    }
    let mut s = v.to_vec();
    s.sort_by(|a, b| a.total_cmp(b));
    let pos = q.clamp(0.0, 1.0) * (s.len() - 1) as f64;
    let (i, f) = (pos.floor() as usize, pos.fract());
    if i + 1 < s.len() {
        s[i] * (1.0 - f) + s[i + 1] * f
    } else {
        s[i]
    }
}

/// CPU time of the calling thread in µs (CLOCK_THREAD_CPUTIME_ID): compute
/// time without the time the thread spent descheduled, so percentiles stay
/// meaningful on a loaded machine (wall time is reported beside it).
pub fn thread_cpu_us() -> f64 {
    crate::rt::clock::thread_cpu_ns() as f64 * 1e-3
}

/// Euclidean norm.
pub fn norm(v: &[f64]) -> f64 {
    v.iter().map(|x| x * x).sum::<f64>().sqrt()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn stats_and_params() {
        let (m, s) = mean_std(&[1.0, 2.0, 3.0, 4.0]);
        assert!((m - 2.5).abs() < 1e-15 && (s - 1.2909944487358056).abs() < 1e-12);
        assert_eq!(percentile(&[3.0, 1.0, 2.0, 4.0, 5.0], 0.5), 3.0);
        assert_eq!(percentile(&[1.0, 2.0], 0.5), 1.5);
        let args = ExperimentArgs {
            params: vec![
                ("samples".into(), "10,50".into()),
                ("x".into(), "2.5".into()),
            ],
            ..ExperimentArgs::default()
        };
        assert_eq!(
            list_param::<usize>(&args, "samples", &[1]).unwrap(),
            vec![10, 50]
        );
        assert_eq!(param(&args, "x", 0.0).unwrap(), 2.5);
        assert_eq!(param(&args, "y", 7usize).unwrap(), 7);
        assert!(check_params(&args, &["samples"]).is_err());
        assert!(check_params(&args, &["samples", "x"]).is_ok());
        // The thread clock advances with work and not with sleep.
        let t0 = thread_cpu_us();
        let mut acc = 0.0f64;
        for i in 0..2_000_000 {
            acc += (i as f64).sqrt();
        }
        std::hint::black_box(acc);
        let t1 = thread_cpu_us();
        assert!(t1 > t0, "{t0} → {t1}");
        std::thread::sleep(std::time::Duration::from_millis(50));
        assert!(thread_cpu_us() - t1 < 25_000.0, "sleep counted as CPU time");
    }
}
