//! The documented `--param key=value` settings of an experiment: one table
//! per experiment gives each key, its default and its meaning. The command
//! line prints the table for `beliefbus experiment <name> --help` and
//! refuses keys that are not in it before any work starts; the experiments'
//! own lookups check, in debug builds, that the key they read is in the
//! table with the same default, so the help cannot drift from the code.

use std::fmt::Write;

/// One documented parameter.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct ParamDoc {
    /// The key of `--param key=value`.
    pub key: &'static str,
    /// The default as the user would type it (a list comma-separated). A
    /// default computed from other parameters starts with `=` and names
    /// them (e.g. `= obs_period_s`); it is shown but not checked.
    pub default: &'static str,
    /// What it sets, in a few words (units included).
    pub help: &'static str,
}

/// Shorthand for a table row.
pub const fn p(key: &'static str, default: &'static str, help: &'static str) -> ParamDoc {
    ParamDoc { key, default, help }
}

/// The keys of `doc`, for "unknown parameter" messages.
pub fn keys(doc: &[ParamDoc]) -> Vec<&'static str> {
    doc.iter().map(|d| d.key).collect()
}

/// The first key of `given` that `doc` does not list, if any.
pub fn unknown_key<'a>(doc: &[ParamDoc], given: &'a [(String, String)]) -> Option<&'a str> {
    given
        .iter()
        .map(|(k, _)| k.as_str())
        .find(|k| !doc.iter().any(|d| d.key == *k))
}

/// Whether `default` (as the code has it, rendered by `Display`) agrees with
/// the table: the key is listed and, unless the table's default is computed
/// (`= ...`), equal as a number list or else as text.
pub fn default_agrees(doc: &[ParamDoc], key: &str, default: &str) -> Result<(), String> {
    let Some(d) = doc.iter().find(|d| d.key == key) else {
        return Err(format!("parameter '{key}' is read but not documented"));
    };
    if d.default.starts_with('=') {
        return Ok(());
    }
    let nums = |s: &str| -> Option<Vec<f64>> {
        s.split(',')
            .map(|x| x.trim().replace('_', "").parse::<f64>().ok())
            .collect()
    };
    let same = match (nums(d.default), nums(default)) {
        (Some(a), Some(b)) => {
            a.len() == b.len()
                && a.iter()
                    .zip(&b)
                    .all(|(x, y)| (x - y).abs() <= 1e-12 * x.abs().max(y.abs()))
        }
        _ => d.default == default,
    };
    if same {
        Ok(())
    } else {
        Err(format!(
            "parameter '{key}': the code's default {default} differs from the documented {}",
            d.default
        ))
    }
}

/// Panics in debug builds when [`default_agrees`] fails on a non-empty
/// table (an empty table means the caller did not come through the
/// registry, e.g. a unit test building its own arguments).
pub fn debug_check_default(doc: &[ParamDoc], key: &str, default: &str) {
    if cfg!(debug_assertions) && !doc.is_empty() {
        if let Err(e) = default_agrees(doc, key, default) {
            panic!("{e}");
        }
    }
}

/// The text of `beliefbus experiment <name> --help`.
pub fn render_help(name: &str, about: &str, reproduces: &str, doc: &[ParamDoc]) -> String {
    let mut s = String::new();
    let _ = writeln!(s, "beliefbus experiment {name}: {about}\n");
    let _ = writeln!(s, "Reproduces: {reproduces}\n");
    let _ = writeln!(
        s,
        "Usage: beliefbus experiment {name} [--runs N] [--seed S] [--json FILE] [--quiet] [--param KEY=VALUE]...\n"
    );
    if doc.is_empty() {
        let _ = writeln!(s, "Parameters: none");
        return s;
    }
    let _ = writeln!(s, "Parameters (--param KEY=VALUE):");
    let kw = doc.iter().map(|d| d.key.len()).max().unwrap_or(0);
    let dw = doc
        .iter()
        .map(|d| d.default.len())
        .max()
        .unwrap_or(0)
        .max(7);
    let _ = writeln!(s, "  {:<kw$}  {:<dw$}  meaning", "key", "default");
    for d in doc {
        let _ = writeln!(s, "  {:<kw$}  {:<dw$}  {}", d.key, d.default, d.help);
    }
    s
}

#[cfg(test)]
mod tests {
    use super::*;

    const DOC: &[ParamDoc] = &[
        p("r", "0.01", "control cost weight"),
        p("sizes", "1000,3000", "state counts"),
        p("step_s", "= obs_period_s", "chain step"),
        p("kernel", "gauss", "kernel name"),
    ];

    #[test]
    fn defaults_agree_by_value_and_disagree_otherwise() {
        assert!(default_agrees(DOC, "r", "0.01").is_ok());
        assert!(default_agrees(DOC, "r", "0.010000000000000000").is_ok());
        assert!(default_agrees(DOC, "r", "0.02").is_err());
        assert!(default_agrees(DOC, "sizes", "1000,3000").is_ok());
        assert!(default_agrees(DOC, "sizes", "1000").is_err());
        assert!(default_agrees(DOC, "step_s", "0.123").is_ok());
        assert!(default_agrees(DOC, "kernel", "gauss").is_ok());
        assert!(default_agrees(DOC, "kernel", "lp").is_err());
        assert!(default_agrees(DOC, "missing", "1").is_err());
    }

    #[test]
    fn unknown_keys_are_found() {
        let given = vec![("r".to_string(), "1".to_string()), ("q".into(), "2".into())];
        assert_eq!(unknown_key(DOC, &given), Some("q"));
        assert_eq!(unknown_key(DOC, &given[..1]), None);
    }

    #[test]
    fn help_lists_every_key_with_its_default() {
        let h = render_help("x", "about", "Table 1", DOC);
        for d in DOC {
            let line = h
                .lines()
                .find(|l| l.trim_start().starts_with(d.key))
                .unwrap();
            assert!(line.contains(d.default) && line.contains(d.help), "{line}");
        }
        assert!(h.contains("Reproduces: Table 1"));
    }
}
