//! Reading a config: TOML text or file, `--set` overrides, the scenario
//! looked up in a [`Registry`], strict deserialization, validation.
//! The functions without `_in` use [`Registry::builtin`].

use super::{ConfigError, PipelineConfig, ResolvedScenario};
use crate::scenario::{BuildContext, Registry};
use std::path::Path;

/// Read `path`, apply `overrides` (`KEY=VALUE`), deserialize and validate,
/// with the built-in scenarios.
pub fn load(path: &Path, overrides: &[String]) -> Result<PipelineConfig, ConfigError> {
    load_in(&Registry::builtin(), path, overrides)
}

/// [`load`] with the scenarios of `registry`.
pub fn load_in(
    registry: &Registry,
    path: &Path,
    overrides: &[String],
) -> Result<PipelineConfig, ConfigError> {
    let text = std::fs::read_to_string(path)
        .map_err(|e| ConfigError::new("", format!("cannot read {}: {e}", path.display())))?;
    load_str_in(registry, &text, overrides)
}

/// [`load`] from the file's text.
pub fn load_str(text: &str, overrides: &[String]) -> Result<PipelineConfig, ConfigError> {
    load_str_in(&Registry::builtin(), text, overrides)
}

/// [`load_str`] with the scenarios of `registry`.
pub fn load_str_in(
    registry: &Registry,
    text: &str,
    overrides: &[String],
) -> Result<PipelineConfig, ConfigError> {
    let mut table: toml::Table = toml::from_str(text).map_err(|e| {
        let line = e
            .span()
            .map(|s| {
                format!(
                    "line {}: ",
                    text[..s.start.min(text.len())].lines().count().max(1)
                )
            })
            .unwrap_or_default();
        ConfigError::new("", format!("{line}{}", e.message()))
    })?;
    for o in overrides {
        apply_override(&mut table, o)?;
    }
    from_table_in(registry, &table)
}

/// Apply one `KEY=VALUE` to the table.
pub fn apply_override(table: &mut toml::Table, kv: &str) -> Result<(), ConfigError> {
    let (key, value) = kv
        .split_once('=')
        .ok_or_else(|| ConfigError::new(kv.trim(), "--set needs KEY=VALUE"))?;
    let key = key.trim();
    let value = value.trim();
    let parts: Vec<&str> = key.split('.').collect();
    if key.is_empty() || parts.iter().any(|p| p.is_empty()) {
        return Err(ConfigError::new(
            key,
            "--set needs a dotted KEY such as filter.backend",
        ));
    }
    let parsed: toml::Value = match toml::from_str::<toml::Table>(&format!("v = {value}")) {
        Ok(mut t) => t.remove("v").unwrap_or(toml::Value::String(value.into())),
        Err(_) => toml::Value::String(value.to_string()),
    };
    let mut cur = table;
    for (i, p) in parts[..parts.len() - 1].iter().enumerate() {
        let entry = cur
            .entry(p.to_string())
            .or_insert_with(|| toml::Value::Table(toml::Table::new()));
        cur = match entry {
            toml::Value::Table(t) => t,
            _ => {
                return Err(ConfigError::new(
                    parts[..=i].join("."),
                    "is a value, not a section",
                ))
            }
        };
    }
    cur.insert(parts[parts.len() - 1].to_string(), parsed);
    Ok(())
}

/// Deserialize and validate a table with the built-in scenarios; errors
/// carry the dotted key.
pub fn from_table(table: &toml::Table) -> Result<PipelineConfig, ConfigError> {
    from_table_in(&Registry::builtin(), table)
}

/// [`from_table`] with the scenarios of `registry`: the section named after
/// `run.scenario` goes to that scenario's constructor, the rest is
/// deserialized strictly, then what the config leaves out is taken from
/// the scenario and everything is validated.
pub fn from_table_in(
    registry: &Registry,
    table: &toml::Table,
) -> Result<PipelineConfig, ConfigError> {
    let mut table = table.clone();
    let name = match table
        .get("run")
        .and_then(|r| r.as_table())
        .and_then(|r| r.get("scenario"))
    {
        Some(toml::Value::String(s)) => Some(s.clone()),
        Some(_) => {
            return Err(ConfigError::new(
                "run.scenario",
                "must be the name of a registered scenario (a string)",
            ))
        }
        // The strict deserialization below reports the missing key.
        None => None,
    };
    let entry = match &name {
        Some(n) => Some(registry.get(n).ok_or_else(|| {
            ConfigError::new(
                "run.scenario",
                format!(
                    "unknown scenario `{n}`; registered: {}",
                    registry.names().join(", ")
                ),
            )
        })?),
        None => None,
    };
    let params = match entry.map(|e| (e.name, table.remove(e.name))) {
        Some((_, Some(toml::Value::Table(t)))) => Some(t),
        Some((n, Some(_))) => {
            return Err(ConfigError::new(
                n,
                format!("must be a section ([{n}]) of the scenario's parameters"),
            ))
        }
        _ => None,
    };
    // The path of the failing key comes from the deserializer itself (a
    // nested struct's unknown or mistyped field is named in full).
    let mut cfg: PipelineConfig = serde_path_to_error::deserialize(toml::Value::Table(table))
        .map_err(|e: serde_path_to_error::Error<toml::de::Error>| {
            let path = e.path().to_string();
            let key = if path == "." { String::new() } else { path };
            ConfigError::new(key, e.inner().message())
        })?;
    let entry = entry.ok_or_else(|| ConfigError::new("run.scenario", "is required"))?;
    super::validate::positive("plant.sensor_rate_hz", cfg.plant.sensor_rate_hz)?;
    let ctx = BuildContext {
        sample_dt: cfg.sample_dt(),
    };
    let system = entry.build(params.as_ref(), &ctx).map_err(|p| {
        let key = if p.key.is_empty() {
            entry.name.to_string()
        } else {
            format!("{}.{}", entry.name, p.key)
        };
        ConfigError::new(key, p.problem)
    })?;
    cfg.scenario = Some(ResolvedScenario {
        params,
        system,
        registry: registry.clone(),
    });
    cfg.fill_from_scenario();
    cfg.validate()?;
    Ok(cfg)
}

/// Where a run's config comes from: a TOML file, or the config a registered
/// scenario embeds (`beliefbus run --scenario NAME`; no name: the
/// registry's default scenario). The launcher hands the same source to
/// every stage ([`ConfigSource::stage_args`]).
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum ConfigSource {
    File(std::path::PathBuf),
    Scenario(Option<String>),
}

impl Default for ConfigSource {
    fn default() -> Self {
        ConfigSource::Scenario(None)
    }
}

impl ConfigSource {
    /// From the command line's `[CONFIG]` and `--scenario NAME` (at most
    /// one of them).
    pub fn from_args(
        config: Option<std::path::PathBuf>,
        scenario: Option<String>,
    ) -> Result<Self, ConfigError> {
        match (config, scenario) {
            (Some(_), Some(_)) => Err(ConfigError::new(
                "--scenario",
                "give a CONFIG file or --scenario NAME, not both (a file names its scenario in run.scenario)",
            )),
            (Some(p), None) => Ok(ConfigSource::File(p)),
            (None, s) => Ok(ConfigSource::Scenario(s)),
        }
    }

    /// The config's text and where it came from (for messages).
    pub fn text(&self, registry: &Registry) -> Result<(String, String), ConfigError> {
        match self {
            ConfigSource::File(p) => std::fs::read_to_string(p)
                .map(|t| (t, p.display().to_string()))
                .map_err(|e| ConfigError::new("", format!("cannot read {}: {e}", p.display()))),
            ConfigSource::Scenario(name) => {
                let entry = match name {
                    Some(n) => registry.get(n).ok_or_else(|| {
                        ConfigError::new(
                            "--scenario",
                            format!(
                                "unknown scenario `{n}`; registered: {}",
                                registry.names().join(", ")
                            ),
                        )
                    })?,
                    None => registry.default_entry().ok_or_else(|| {
                        ConfigError::new("--scenario", "no scenario is registered")
                    })?,
                };
                Ok((entry.config.to_string(), format!("built-in {}", entry.name)))
            }
        }
    }

    /// Read, override, deserialize and validate.
    pub fn load(
        &self,
        registry: &Registry,
        overrides: &[String],
    ) -> Result<PipelineConfig, ConfigError> {
        let (text, _) = self.text(registry)?;
        load_str_in(registry, &text, overrides)
    }

    /// The arguments that make a stage process load the same config.
    pub fn stage_args(&self) -> Vec<std::ffi::OsString> {
        match self {
            ConfigSource::File(p) => vec![p.clone().into_os_string()],
            ConfigSource::Scenario(None) => Vec::new(),
            ConfigSource::Scenario(Some(n)) => vec!["--scenario".into(), n.into()],
        }
    }
}
