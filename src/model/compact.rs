//! The compact shell form of a model spec (grammar in `docs/models.md`), translated into the
//! canonical JSON form so that both forms share one validation path (`Model::from_json`).
//!
//! ```text
//! spec  := term ( '+' term )*                      a sum when more than one term
//! term  := name [ ':' param ( ',' param )* ]       name: canonical or alias (ggx, beckmann)
//! param := key '=' value
//! value := number ( '/' number )*                  one number per channel, or a word
//! lobe=cx:cy:cz:n[:albedo]                         lafortune, repeatable, fields as above
//! fresnel=none|schlick|dielectric|conductor|au|cu|ag|al with f0= / ior= / eta=,k= / nk=@file
//! ```

use super::fresnel::METALS;
use super::params::{ModelDecl, ParamKind};
use super::{find_decl, unknown_model};
use crate::{Error, Result};
use serde_json::{Map, Value};

/// The keys that belong to the Fresnel object, and the type each one needs.
const FRESNEL_FIELDS: &[(&str, &str)] = &[
    ("f0", "schlick"),
    ("ior", "dielectric"),
    ("eta", "conductor"),
    ("k", "conductor"),
    ("nk", "conductor"),
];

/// Translates a compact spec into canonical JSON (not yet validated beyond syntax).
pub(crate) fn compact_to_json(spec: &str) -> Result<Value> {
    let terms = split_terms(spec);
    let mut out = Vec::with_capacity(terms.len());
    for term in terms {
        let term = term.trim();
        if term.is_empty() {
            return Err(Error::input(format!(
                "model spec {spec:?}: empty term around '+' (expected e.g. lambert + ggx)"
            )));
        }
        out.push(term_to_json(term)?);
    }
    Ok(if out.len() == 1 {
        out.pop().unwrap_or(Value::Null)
    } else {
        serde_json::json!({"model": "sum", "terms": out})
    })
}

/// Splits on '+', except a '+' of an exponent (`1e+3`: after e/E that follows a digit or '.').
fn split_terms(spec: &str) -> Vec<&str> {
    let bytes = spec.as_bytes();
    let mut parts = Vec::new();
    let mut start = 0;
    for (i, &b) in bytes.iter().enumerate() {
        if b != b'+' {
            continue;
        }
        let in_exponent = i >= 2
            && matches!(bytes[i - 1], b'e' | b'E')
            && (bytes[i - 2].is_ascii_digit() || bytes[i - 2] == b'.');
        if !in_exponent {
            parts.push(&spec[start..i]);
            start = i + 1;
        }
    }
    parts.push(&spec[start..]);
    parts
}

fn term_to_json(term: &str) -> Result<Value> {
    let (name, params) = match term.split_once(':') {
        Some((n, p)) => (n.trim(), p),
        None => (term, ""),
    };
    let (decl, alias) = find_decl(name).ok_or_else(|| unknown_model(name))?;
    let ctx = decl.name;
    let mut obj = Map::new();
    // The alias name stays as the model so that from_json applies (and checks) its preset.
    obj.insert(
        "model".into(),
        Value::from(alias.map_or(decl.name, |a| a.name)),
    );
    let has_fresnel = decl.params.iter().any(|p| p.kind == ParamKind::Fresnel);
    let mut fresnel = Map::new();
    let mut lobes = Vec::new();
    for param in params.split(',') {
        let param = param.trim();
        // Tolerate an empty item (trailing comma).
        if param.is_empty() {
            continue;
        }
        let Some((key, value)) = param.split_once('=') else {
            return Err(Error::input(format!(
                "{ctx}: {param:?} is not key=value (e.g. {ctx}:{}=...)",
                decl.params.first().map_or("param", |p| p.name)
            )));
        };
        let (key, value) = (key.trim(), value.trim());
        if key == "lobe" && decl.param("lobes").is_some() {
            lobes.push(lobe_to_json(ctx, value)?);
            continue;
        }
        if has_fresnel && (key == "fresnel" || FRESNEL_FIELDS.iter().any(|f| f.0 == key)) {
            let json_key = if key == "fresnel" { "type" } else { key };
            // The type and a data-file name stay words; the other fields are numbers.
            let v = if key == "fresnel" || key == "nk" {
                Value::from(value)
            } else {
                numbers(ctx, &format!("fresnel.{key}"), value)?
            };
            if fresnel.insert(json_key.to_string(), v).is_some() {
                return Err(duplicate(ctx, key));
            }
            continue;
        }
        let v = value_for(decl, ctx, key, value)?;
        if obj.insert(key.to_string(), v).is_some() {
            return Err(duplicate(ctx, key));
        }
    }
    if !fresnel.is_empty() {
        if !fresnel.contains_key("type") {
            let (key, kind) = FRESNEL_FIELDS
                .iter()
                .find(|f| fresnel.contains_key(f.0))
                .copied()
                .unwrap_or(("?", "?"));
            return Err(Error::input(format!(
                "{ctx}: {key} = {} needs fresnel={kind} (e.g. fresnel=dielectric,ior=1.5; \
                 fresnel=schlick,f0=0.04; fresnel=conductor,eta=..,k=..; fresnel=au)",
                fresnel[key]
            )));
        }
        // A bare metal or `none` stays a word, so that the reader's messages apply unchanged.
        let is_word = fresnel.len() == 1
            && fresnel["type"]
                .as_str()
                .is_some_and(|t| t == "none" || METALS.iter().any(|m| m.0 == t));
        let v = if is_word {
            fresnel["type"].clone()
        } else {
            Value::Object(fresnel)
        };
        obj.insert("fresnel".into(), v);
    }
    if !lobes.is_empty() {
        obj.insert("lobes".into(), Value::Array(lobes));
    }
    Ok(Value::Object(obj))
}

fn duplicate(ctx: &str, key: &str) -> Error {
    Error::input(format!("{ctx}: parameter {key} is given twice"))
}

/// The JSON value of `key=value` according to the parameter's declared kind. Unknown keys
/// pass through as strings; `from_json` reports them with the accepted names.
fn value_for(decl: &ModelDecl, ctx: &str, key: &str, value: &str) -> Result<Value> {
    match decl.param(key).map(|p| p.kind) {
        Some(ParamKind::Number { .. }) => numbers(ctx, key, value),
        Some(ParamKind::Terms) => Err(Error::input(format!(
            "{ctx}: {key} cannot be given as key=value; join the terms with + (e.g. lambert + ggx)"
        ))),
        Some(ParamKind::Lobes) => Err(Error::input(format!(
            "{ctx}: give lobes one at a time as lobe=cx:cy:cz:n[:albedo]"
        ))),
        _ => Ok(Value::from(value)),
    }
}

/// `a/b/c` → a number or a list of numbers; every value must parse and be finite.
fn numbers(ctx: &str, key: &str, value: &str) -> Result<Value> {
    let mut out = Vec::new();
    for part in value.split('/') {
        let part = part.trim();
        let x: f64 = part.parse().map_err(|_| {
            Error::input(format!(
                "{ctx}: {key} = {part:?} is not a number (per-channel lists are written a/b/c)"
            ))
        })?;
        if !x.is_finite() {
            return Err(Error::input(format!(
                "{ctx}: {key} = {part} is not a finite number"
            )));
        }
        out.push(x);
    }
    Ok(if out.len() == 1 {
        Value::from(out[0])
    } else {
        Value::from(out)
    })
}

/// `cx:cy:cz:n[:albedo]`, each field a number or an a/b/c list.
fn lobe_to_json(ctx: &str, value: &str) -> Result<Value> {
    const FIELDS: [&str; 5] = ["cx", "cy", "cz", "n", "albedo"];
    let parts: Vec<&str> = value.split(':').collect();
    if parts.len() != 4 && parts.len() != 5 {
        return Err(Error::input(format!(
            "{ctx}: lobe = {value:?} has {} fields; expected cx:cy:cz:n or cx:cy:cz:n:albedo",
            parts.len()
        )));
    }
    let mut obj = Map::new();
    for (field, part) in FIELDS.iter().zip(parts) {
        obj.insert(
            (*field).to_string(),
            numbers(ctx, &format!("lobe.{field}"), part)?,
        );
    }
    Ok(Value::Object(obj))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn exponent_plus_is_not_a_term_separator() {
        assert_eq!(
            split_terms("phong:exponent=1e+3"),
            vec!["phong:exponent=1e+3"]
        );
        assert_eq!(split_terms("lambert+phong:norm=none+ward").len(), 3);
        assert_eq!(split_terms("lambert:albedo=0.5 + ggx").len(), 2);
    }
}
