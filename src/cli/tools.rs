//! `brdfpack completions SHELL` and `brdfpack man [SUBCOMMAND]`: generated from the clap
//! definitions (clap_complete, clap_mangen), so they never drift from the commands.

use super::Cli;
use clap::{Args, CommandFactory};
use std::io::Write;

#[derive(Args, Debug)]
pub struct CompletionsArgs {
    /// The shell: bash, zsh, fish, elvish or powershell.
    #[arg(value_enum)]
    pub shell: clap_complete::Shell,
    /// One JSON object {"shell", "script"} instead of the script.
    #[arg(long)]
    pub json: bool,
    #[command(flatten)]
    pub report: super::common::ReportTarget,
}

#[derive(Args, Debug)]
pub struct ManArgs {
    /// The page of one subcommand (default: the tool's page, listing every subcommand).
    pub subcommand: Option<String>,
    /// One JSON object {"page", "roff"} instead of the roff text.
    #[arg(long)]
    pub json: bool,
    #[command(flatten)]
    pub report: super::common::ReportTarget,
}

pub fn completions(a: CompletionsArgs) -> anyhow::Result<i32> {
    let mut script = Vec::new();
    clap_complete::generate(a.shell, &mut Cli::command(), "brdfpack", &mut script);
    emit(a.json, &a.shell.to_string(), "shell", "script", &script)
}

pub fn man(a: ManArgs) -> anyhow::Result<i32> {
    let root = Cli::command();
    let (name, cmd) = match &a.subcommand {
        None => ("brdfpack".to_string(), root),
        Some(s) => {
            let sub = root.find_subcommand(s).cloned().ok_or_else(|| {
                crate::Error::input(format!(
                    "man {s}: no such subcommand (brdfpack --help lists them)"
                ))
            })?;
            let name = format!("brdfpack-{s}");
            (name.clone(), sub.display_name(name.clone()).bin_name(name))
        }
    };
    let mut roff = Vec::new();
    clap_mangen::Man::new(cmd).render(&mut roff)?;
    emit(a.json, &name, "page", "roff", &roff)
}

fn emit(
    json: bool,
    name: &str,
    name_key: &str,
    text_key: &str,
    text: &[u8],
) -> anyhow::Result<i32> {
    let mut out = super::Stdout;
    if json {
        let v = serde_json::json!({ name_key: name, text_key: String::from_utf8_lossy(text) });
        writeln!(out, "{v}").map_err(super::stdout_error)?;
    } else {
        out.write_all(text).map_err(super::stdout_error)?;
    }
    out.flush().map_err(super::stdout_error)?;
    Ok(0)
}
