//! `brdfpack models`: every analytic model with its parameters, defaults, ranges and
//! properties, generated from the parameter declarations.

use crate::model::{Model, find_decl, listing};
use clap::Args;
use std::io::Write;

#[derive(Args, Debug)]
pub struct ModelsArgs {
    /// Show only this model (canonical name or alias, e.g. `ggx`).
    pub name: Option<String>,
    /// Print the declarations as JSON (for scripts).
    #[arg(long)]
    pub json: bool,
    /// Print the parameter tables as Markdown (the generated part of docs/models.md).
    #[arg(long, conflicts_with = "json")]
    pub markdown: bool,
    #[command(flatten)]
    pub report: super::common::ReportTarget,
}

pub fn run(args: ModelsArgs) -> anyhow::Result<i32> {
    let decls = match &args.name {
        None => Model::catalog(),
        Some(name) => match find_decl(name) {
            Some((decl, _)) => std::slice::from_ref(decl),
            None => {
                // Same message as a spec with an unknown model.
                return Err(Model::parse(name).err().map_or_else(
                    || anyhow::anyhow!("unknown model {name:?}"),
                    anyhow::Error::from,
                ));
            }
        },
    };
    let text = if args.json {
        let mut s = serde_json::to_string_pretty(&listing::catalog_json(decls))?;
        s.push('\n');
        s
    } else if args.markdown {
        listing::catalog_markdown(decls)
    } else {
        listing::catalog_text(decls)
    };
    let mut out = super::Stdout;
    out.write_all(text.as_bytes())
        .and_then(|_| out.flush())
        .map_err(super::stdout_error)?;
    Ok(0)
}
