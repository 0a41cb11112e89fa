//! `brdfpack convert`: a table (native, EXR, MERL) or a model to a table file in another
//! format or on another grid.

use super::common::{InterpArg, Lookup, OutputArgs, SamplingArgs, Source};
use crate::grid::{Grid, parse_grid_spec};
use crate::io::mbsdf::mbsdf_dims;
use crate::io::merl::merl_dims;
use crate::io::{FormatName, OutputFormat, atomic, encode_table};
use crate::table::{Interp, InterpolatedTable, Table};
use crate::tabulate::{TabulateOptions, tabulate};
use clap::Args;
use std::path::PathBuf;

#[derive(Args, Debug)]
pub struct ConvertArgs {
    /// Input: a table file (.bpk, brdfpack .exr, MERL .binary; `-` = stdin), an RGL .bsdf
    /// measured file, or a model spec (e.g. `lambert:albedo=0.8/0.5/0.2`).
    pub input: String,
    /// Output file (`-` = stdout: native format unless --format says otherwise).
    #[arg(short, long)]
    pub output: PathBuf,
    /// Target grid (`merl` or KIND:DIMS[,...]). Default: the input table's grid; `merl` for
    /// MERL output and for model inputs; `spherical3:90x90x180` for .mbsdf output.
    #[arg(long)]
    pub grid: Option<String>,
    /// Interpolation used when a table is re-gridded.
    #[arg(long, value_enum, default_value_t = InterpArg::Linear)]
    pub interp: InterpArg,
    #[command(flatten)]
    pub out: OutputArgs,
    #[command(flatten)]
    pub symmetry: SamplingArgs,
    /// Convert spectral channels to linear sRGB (CIE 1931 2°, D65; docs/spectral.md), e.g.
    /// before writing MERL. An error when the input is not spectral.
    #[arg(long)]
    pub to_rgb: bool,
    #[command(flatten)]
    pub rgl: super::convert_rgl::RglArgs,
    /// Say on stderr how the output was made (re-gridding, notes, size).
    #[arg(short, long)]
    pub verbose: bool,
    /// A JSON report (output, format, bytes, grid) on stdout (stderr with `-o -`).
    #[arg(long)]
    pub json: bool,
    /// Nothing but errors (no progress bar).
    #[arg(short, long, conflicts_with = "verbose")]
    pub quiet: bool,
    #[command(flatten)]
    pub depfile: super::common::DepfileArgs,
}

/// The grid of an `.mbsdf` written from a model or a table on another grid: 1° bins.
pub const MBSDF_DEFAULT_GRID: &str = "spherical3:90x90x180";

/// What the input turned out to be.
pub fn run(a: ConvertArgs) -> anyhow::Result<i32> {
    let mut reads = crate::reads::ReadSet::new();
    let input = a
        .symmetry
        .apply(Source::open_recording(&a.input, &mut reads)?);
    let format = a
        .out
        .format
        .map(FormatName::from)
        .or_else(|| FormatName::from_path(&a.output));
    if format == Some(FormatName::Rgl) {
        let code = super::convert_rgl::run(&a, input)?;
        a.depfile.write(&[a.output.as_path()], &reads)?;
        return Ok(code);
    }
    let grid = match (&a.grid, &input) {
        (Some(s), _) => parse_grid_spec(s)?,
        (None, Source::Table(t))
            if match format {
                Some(FormatName::Merl) => merl_dims(t.grid()).is_some(),
                Some(FormatName::Mbsdf) => mbsdf_dims(t.grid()).is_some(),
                _ => true,
            } =>
        {
            t.grid().clone()
        }
        (None, _) if format == Some(FormatName::Mbsdf) => parse_grid_spec(MBSDF_DEFAULT_GRID)?,
        (None, _) if format == Some(FormatName::Merl) => Grid::merl(),
        (None, Source::Measured(m)) => crate::plan::grids::table_default_grid(m)?,
        (None, Source::Model(m)) => crate::plan::grids::table_default_grid(m)?,
        (None, _) => Grid::merl(),
    };
    let output = a.out.resolve(&a.output, &grid)?;
    let bar = super::common::Bar::new(a.quiet);
    let opts = a.symmetry.options(bar.cells());
    let table = match input {
        Source::Table(t) if *t.grid() == grid => Ok(t),
        Source::Table(t) => regrid(t, &grid, a.interp.into(), &opts),
        other => tabulate(other.into_brdf(Lookup::Linear)?.as_ref(), &grid, &opts),
    };
    bar.finish();
    let table = table?;
    let table = if a.to_rgb {
        crate::table::spectral_to_rgb(&table)?
    } else {
        table
    };
    let output = output.for_table(&table)?;
    let bytes = encode_table(&table, &output)?;
    atomic::write_output(&a.output, &bytes)?;
    a.depfile.write(&[a.output.as_path()], &reads)?;
    if a.json {
        let text = serde_json::json!({
            "output": a.output.display().to_string(),
            "format": format!("{:?}", output.name()),
            "bytes": bytes.len(),
            "grid": grid.describe(),
        })
        .to_string();
        super::common::print_json_line(&text, &a.output)?;
    }
    if a.verbose {
        let exact_kept = table.exact().is_some()
            && match &output {
                OutputFormat::Exr(o) => o.is_lossless(),
                OutputFormat::Native(_) | OutputFormat::Merl => true,
                OutputFormat::Mbsdf(_) => false,
            };
        for note in &table.provenance().notes {
            eprintln!("brdfpack: note: {note}");
        }
        eprintln!(
            "brdfpack: wrote {} ({:?}, {} bytes, grid {}{})",
            a.output.display(),
            output.name(),
            bytes.len(),
            grid.describe(),
            if exact_kept {
                ", exact f64 values kept"
            } else {
                ""
            }
        );
    }
    Ok(0)
}

/// Samples a table on another grid by interpolation, keeping its source and notes and adding
/// one that says how.
pub fn regrid(
    t: Table,
    grid: &Grid,
    interp: Interp,
    opts: &TabulateOptions,
) -> crate::Result<Table> {
    let from = t.grid().describe();
    let mut provenance = t.provenance().clone();
    let it = InterpolatedTable { table: t, interp };
    let mut out = tabulate(&it, grid, opts)?;
    provenance
        .notes
        .extend(out.provenance().notes.iter().cloned());
    provenance.notes.push(format!(
        "re-gridded from {from} to {} by {} interpolation",
        grid.describe(),
        match interp {
            Interp::Linear => "multilinear",
            Interp::Nearest => "nearest-sample",
        }
    ));
    provenance.tool = out.provenance().tool.clone();
    *out.provenance_mut() = provenance;
    Ok(out)
}
