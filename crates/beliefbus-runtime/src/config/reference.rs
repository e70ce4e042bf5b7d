//! The configuration reference, generated from the code: every key of
//! [`PipelineConfig`] and of each registered scenario's parameter section,
//! with its type, its default and the doc comment of its field (the JSON
//! schema `schemars` derives from the serde types, so a default or a
//! comment changed in the code changes the reference). `docs/configuration.md`
//! holds the generated table between two markers; a test fails when the
//! committed table differs from the code's (`BELIEFBUS_BLESS=1 cargo test
//! config::reference` rewrites it).

use super::PipelineConfig;
use crate::scenario::Registry;
use serde_json::{Map, Value};

/// The line before the generated table in `docs/configuration.md`.
pub const BEGIN: &str = "<!-- generated from the code: do not edit below -->";
/// The line after it.
pub const END: &str = "<!-- end of the generated reference -->";

fn schema_of<T: schemars::JsonSchema>() -> Value {
    schemars::generate::SchemaSettings::draft2020_12()
        .with(|s| s.inline_subschemas = true)
        .into_generator()
        .into_root_schema_for::<T>()
        .to_value()
}

/// The reference as Markdown: one table of the pipeline's keys, then one
/// per registered scenario's section.
pub fn markdown(registry: &Registry) -> String {
    let mut out = String::new();
    out.push_str("| key | type | default | meaning |\n|---|---|---|---|\n");
    rows(&schema_of::<PipelineConfig>(), "", &mut out);
    for e in registry.entries() {
        let Some(schema) = e.params_schema() else {
            continue;
        };
        out.push_str(&format!(
            "\n**`[{}]`** — scenario `{}`: {} (absent keys: the scenario's defaults)\n\n",
            e.name, e.name, e.summary
        ));
        out.push_str("| key | type | meaning |\n|---|---|---|\n");
        let mut sub = String::new();
        rows(&schema.to_value(), e.name, &mut sub);
        // Scenario defaults depend on the run (the ship's noise on the
        // sensor rate): no default column.
        for line in sub.lines() {
            let cells: Vec<&str> = line.split(" | ").collect();
            if cells.len() == 4 {
                out.push_str(&format!("{} | {} | {}\n", cells[0], cells[1], cells[3]));
            }
        }
    }
    out
}

/// The rows of the object schema `s` under the dotted `prefix`.
fn rows(s: &Value, prefix: &str, out: &mut String) {
    let Some(props) = s.get("properties").and_then(Value::as_object) else {
        return;
    };
    let required: Vec<&str> = s
        .get("required")
        .and_then(Value::as_array)
        .map(|r| r.iter().filter_map(Value::as_str).collect())
        .unwrap_or_default();
    // Sections of one shape (`stages.ingest`, `stages.filter`, ...) are
    // listed once, as `stages.<ingest|filter|...>`.
    let first = props.values().next();
    if props.len() > 1
        && props
            .values()
            .all(|p| Some(p) == first && p.get("properties").is_some())
    {
        let names: Vec<&str> = props.keys().map(String::as_str).collect();
        let key = format!("{prefix}.<{}>", names.join("\\|"));
        rows(first.unwrap(), &key, out);
        return;
    }
    for (name, p) in props {
        let key = if prefix.is_empty() {
            name.clone()
        } else {
            format!("{prefix}.{name}")
        };
        let item = p.get("items").filter(|i| i.get("properties").is_some());
        if p.get("properties").is_some() || item.is_some() {
            // A section (or an array of sections): its keys follow.
            let (inner, key) = match item {
                Some(i) => (i, format!("{key}[]")),
                None => (p, key),
            };
            rows(inner, &key, out);
            continue;
        }
        let default = match p.get("default") {
            Some(v) => format!("`{}`", render_value(v)),
            None if required.contains(&name.as_str()) => "required".into(),
            None => "—".into(),
        };
        out.push_str(&format!(
            "| `{key}` | {} | {default} | {} |\n",
            type_of(p),
            cell(&description(p))
        ));
    }
}

fn description(p: &Value) -> String {
    let mut d = p
        .get("description")
        .and_then(Value::as_str)
        .unwrap_or("")
        .to_string();
    if let Some(alts) = p.get("oneOf").and_then(Value::as_array) {
        let named: Vec<String> = alts
            .iter()
            .filter_map(|a| {
                let c = a.get("const")?.as_str()?;
                Some(match a.get("description").and_then(Value::as_str) {
                    Some(t) => format!("`{c}`: {}", t.trim_end_matches('.')),
                    None => format!("`{c}`"),
                })
            })
            .collect();
        if !named.is_empty() {
            d = format!("{d} {}", named.join("; "));
        }
    }
    d
}

/// One table cell: one line, no bare `|`.
fn cell(s: &str) -> String {
    // Intra-doc links ([`Foo`]) read as plain code in the book.
    s.split_whitespace()
        .collect::<Vec<_>>()
        .join(" ")
        .replace("[`", "`")
        .replace("`]", "`")
        .replace('|', "\\|")
}

fn type_of(p: &Value) -> String {
    if let Some(alts) = p.get("oneOf").and_then(Value::as_array) {
        // Variants with doc comments come as `const`, the rest as `enum`.
        let mut names = Vec::new();
        for a in alts {
            match (a.get("const"), a.get("enum").and_then(Value::as_array)) {
                (Some(c), _) => names.push(format!("`{}`", render_value(c))),
                (None, Some(e)) => names.extend(e.iter().map(|v| format!("`{}`", render_value(v)))),
                _ => {}
            }
        }
        if !names.is_empty() {
            return names.join(" \\| ");
        }
    }
    if let Some(e) = p.get("enum").and_then(Value::as_array) {
        let v: Vec<String> = e
            .iter()
            .filter(|v| !v.is_null())
            .map(|v| format!("`{}`", render_value(v)))
            .collect();
        return v.join(" \\| ");
    }
    let mut types: Vec<&str> = match p.get("type") {
        Some(Value::String(t)) => vec![t.as_str()],
        Some(Value::Array(a)) => a.iter().filter_map(Value::as_str).collect(),
        _ => vec![],
    };
    let optional = types.contains(&"null");
    types.retain(|t| *t != "null");
    let base = match types.first().copied() {
        Some("array") => match (p.get("items"), p.get("prefixItems")) {
            (Some(i), _) => format!("array of {}", type_of(i)),
            (None, Some(Value::Array(v))) => {
                format!("[{}]", v.iter().map(type_of).collect::<Vec<_>>().join(", "))
            }
            _ => "array".into(),
        },
        Some(t) => simple(t, p),
        None => p
            .get("anyOf")
            .and_then(Value::as_array)
            .and_then(|a| {
                a.iter()
                    .find(|x| x.get("type") != Some(&Value::from("null")))
            })
            .map(type_of)
            .unwrap_or_else(|| "any".into()),
    };
    if optional {
        format!("{base} (optional)")
    } else {
        base
    }
}

fn simple(t: &str, p: &Value) -> String {
    match (t, p.get("format").and_then(Value::as_str)) {
        ("number", _) => "number".into(),
        ("integer", Some(f)) if f.starts_with('u') => "integer ≥ 0".into(),
        ("integer", _) => "integer".into(),
        (t, _) => t.into(),
    }
}

fn render_value(v: &Value) -> String {
    match v {
        Value::String(s) => format!("\"{s}\""),
        Value::Array(a) => format!(
            "[{}]",
            a.iter().map(render_value).collect::<Vec<_>>().join(", ")
        ),
        Value::Object(o) if o.is_empty() => "{}".into(),
        Value::Object(o) => render_object(o),
        other => other.to_string(),
    }
}

fn render_object(o: &Map<String, Value>) -> String {
    let kv: Vec<String> = o
        .iter()
        .map(|(k, v)| format!("{k} = {}", render_value(v)))
        .collect();
    format!("{{ {} }}", kv.join(", "))
}

/// `text` with the part between [`BEGIN`] and [`END`] replaced by
/// `generated` (`None` when the markers are missing).
pub fn splice(text: &str, generated: &str) -> Option<String> {
    let b = text.find(BEGIN)? + BEGIN.len();
    let e = text[b..].find(END)? + b;
    Some(format!(
        "{}\n\n{}\n{}",
        &text[..b],
        generated.trim_end(),
        &text[e..]
    ))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_committed_reference_is_the_codes() {
        let path =
            std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../../docs/configuration.md");
        let text = std::fs::read_to_string(&path).unwrap();
        let want = splice(&text, &markdown(&Registry::builtin()))
            .expect("docs/configuration.md lacks the generated-reference markers");
        if want != text {
            if std::env::var_os("BELIEFBUS_BLESS").is_some() {
                std::fs::write(&path, want).unwrap();
                return;
            }
            panic!(
                "docs/configuration.md differs from the code's reference: run \
                 `BELIEFBUS_BLESS=1 cargo test config::reference` and commit the result"
            );
        }
    }

    #[test]
    fn every_key_of_the_default_config_is_in_the_reference() {
        let r = markdown(&Registry::builtin());
        let text = include_str!("../../../../configs/default.toml");
        let table: toml::Table = toml::from_str(text).unwrap();
        fn keys(t: &toml::Table, prefix: &str, out: &mut Vec<String>) {
            for (k, v) in t {
                let key = if prefix.is_empty() {
                    k.clone()
                } else {
                    format!("{prefix}.{k}")
                };
                match v {
                    toml::Value::Table(inner) => keys(inner, &key, out),
                    toml::Value::Array(a) if a.iter().all(|x| x.is_table()) && !a.is_empty() => {
                        for x in a {
                            keys(x.as_table().unwrap(), &format!("{key}[]"), out);
                        }
                    }
                    _ => out.push(key),
                }
            }
        }
        let mut all = Vec::new();
        keys(&table, "", &mut all);
        assert!(all.len() > 60, "{}", all.len());
        for k in all {
            // The five stages' sections share one shape, listed once.
            let k = match k.strip_prefix("stages.").and_then(|r| r.split_once('.')) {
                Some((_, rest)) => {
                    format!("stages.<control\\|filter\\|ingest\\|plant\\|refine>.{rest}")
                }
                None => k,
            };
            assert!(
                r.contains(&format!("`{k}`")),
                "{k} missing from the reference"
            );
        }
        // Defaults come from the code: the refine period's is 10 ms.
        assert!(
            r.contains("| `refine.period_ms` | number | `10.0` |"),
            "{r}"
        );
    }

    #[test]
    fn splice_replaces_only_the_generated_part() {
        let t = format!("intro\n{BEGIN}\nold\n{END}\nafter\n");
        assert_eq!(
            splice(&t, "new").unwrap(),
            format!("intro\n{BEGIN}\n\nnew\n{END}\nafter\n")
        );
        assert!(splice("no markers", "x").is_none());
    }
}
