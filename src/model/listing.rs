//! Human- and machine-readable listings of the model catalog, generated from the parameter
//! declarations (used by `brdfpack models` and for the tables of `docs/models.md`).

use super::fresnel::{FRESNEL_TYPES, METALS};
use super::lafortune::LOBE_PARAMS;
use super::params::{ModelDecl, ParamDecl, fmt_num};
use serde_json::{Value, json};

fn yes_no(b: bool) -> &'static str {
    if b { "yes" } else { "no" }
}

fn param_lines(out: &mut String, params: &[ParamDecl], indent: &str) {
    let width = |v: &[String]| v.iter().map(|s| s.chars().count()).max().unwrap_or(0);
    let names: Vec<String> = params.iter().map(|p| p.name.to_string()).collect();
    let defaults: Vec<String> = params
        .iter()
        .map(|p| {
            format!(
                "{}{}",
                p.default_text(),
                if p.per_channel { " (per ch.)" } else { "" }
            )
        })
        .collect();
    let ranges: Vec<String> = params.iter().map(ParamDecl::range_text).collect();
    let (wn, wd, wr) = (width(&names), width(&defaults), width(&ranges));
    let pad = |s: &str, w: usize| format!("{s}{}", " ".repeat(w - s.chars().count()));
    for (i, p) in params.iter().enumerate() {
        out.push_str(&format!(
            "{indent}{}  {}  {}  {}\n",
            pad(&names[i], wn),
            pad(&defaults[i], wd),
            pad(&ranges[i], wr),
            p.description
        ));
    }
}

/// Plain-text listing of `decls` (every model when given the whole catalog).
pub fn catalog_text(decls: &[ModelDecl]) -> String {
    let mut out = String::new();
    for d in decls {
        let aliases: Vec<&str> = d.aliases.iter().map(|a| a.name).collect();
        out.push_str(d.name);
        if !aliases.is_empty() {
            out.push_str(&format!(" (aliases: {})", aliases.join(", ")));
        }
        out.push_str(&format!(" — {}\n  f = {}\n", d.summary, d.formula));
        out.push_str(&format!(
            "  isotropic: {}; reciprocal: {}; tabulable: {}\n",
            d.isotropic,
            yes_no(d.reciprocal),
            yes_no(d.tabulable)
        ));
        param_lines(&mut out, d.params, "  ");
        if d.params.iter().any(|p| p.name == "fresnel") {
            out.push_str("  fresnel types:\n");
            for (name, params, what) in FRESNEL_TYPES {
                out.push_str(&format!("    {name}: {what}\n"));
                param_lines(&mut out, params, "      ");
            }
        }
        if d.params.iter().any(|p| p.name == "lobes") {
            out.push_str("  lobe fields:\n");
            param_lines(&mut out, LOBE_PARAMS, "    ");
        }
        if !d.citation.is_empty() {
            out.push_str(&format!("  ref: {}\n", d.citation));
        }
        out.push('\n');
    }
    out
}

fn md_rows(out: &mut String, params: &[ParamDecl]) {
    out.push_str(
        "| parameter | symbol | unit | accepted | default | per channel | meaning | source |\n",
    );
    out.push_str("|---|---|---|---|---|---|---|---|\n");
    for p in params {
        out.push_str(&format!(
            "| `{}` | {} | {} | {} | {} | {} | {} | {} |\n",
            p.name,
            p.symbol,
            p.unit,
            p.range_text().replace('|', "\\|"),
            p.default_text().replace('|', "\\|"),
            yes_no(p.per_channel),
            p.description.replace('|', "\\|"),
            p.citation
        ));
    }
}

/// Markdown tables of every model's parameters: the generated section of `docs/models.md`.
pub fn catalog_markdown(decls: &[ModelDecl]) -> String {
    let mut out = String::new();
    for d in decls {
        let aliases: Vec<String> = d
            .aliases
            .iter()
            .map(|a| {
                let preset: Vec<String> =
                    a.preset.iter().map(|(k, v)| format!("{k}={v}")).collect();
                format!("`{}` (= {} {})", a.name, d.name, preset.join(","))
            })
            .collect();
        out.push_str(&format!(
            "### `{}`\n\n{}: f = {}",
            d.name, d.summary, d.formula
        ));
        if !d.citation.is_empty() {
            out.push_str(&format!(" ({})", d.citation));
        }
        out.push_str(".\n\n");
        if !aliases.is_empty() {
            out.push_str(&format!("Aliases: {}.\n", aliases.join(", ")));
        }
        out.push_str(&format!(
            "Isotropic: {}. Reciprocal: {}. Tabulable: {}.\n\n",
            d.isotropic,
            yes_no(d.reciprocal),
            yes_no(d.tabulable)
        ));
        md_rows(&mut out, d.params);
        out.push('\n');
        if d.params.iter().any(|p| p.name == "lobes") {
            out.push_str("Lobe fields:\n\n");
            md_rows(&mut out, LOBE_PARAMS);
            out.push('\n');
        }
    }
    out.push_str("### Fresnel types\n\n");
    for (name, _, what) in FRESNEL_TYPES {
        out.push_str(&format!("- `{name}`: {what}\n"));
    }
    out.push('\n');
    for (name, params, _) in FRESNEL_TYPES {
        if !params.is_empty() {
            out.push_str(&format!("`{name}` fields:\n\n"));
            md_rows(&mut out, params);
            out.push('\n');
        }
    }
    out.push_str("Named metals (RGB η; k):\n\n");
    for (name, eta, k) in METALS {
        let f = |v: &[f64; 3]| v.iter().map(|x| fmt_num(*x)).collect::<Vec<_>>().join(", ");
        out.push_str(&format!("- `{name}`: η = ({}); k = ({})\n", f(eta), f(k)));
    }
    out
}

/// The catalog as JSON (for `models --json`): models, Fresnel types, lobe fields, metals.
pub fn catalog_json(decls: &[ModelDecl]) -> Value {
    json!({
        "models": decls.iter().map(ModelDecl::to_json).collect::<Vec<_>>(),
        "fresnel_types": FRESNEL_TYPES.iter().map(|(name, params, what)| json!({
            "type": name,
            "formula": what,
            "params": params.iter().map(ParamDecl::to_json).collect::<Vec<_>>(),
        })).collect::<Vec<_>>(),
        "metals": METALS.iter().map(|(name, eta, k)| json!({"name": name, "eta": eta, "k": k}))
            .collect::<Vec<_>>(),
        "lobe_fields": LOBE_PARAMS.iter().map(ParamDecl::to_json).collect::<Vec<_>>(),
    })
}
