//! `brdfpack convert`: a table (native, EXR, MERL) or a model to a table file in another
//! format or on another grid.

use crate::grid::{Grid, parse_grid_spec};
use crate::io::exr::{ExrCompression, ExrOptions, ExrSampleType};
use crate::io::merl::merl_dims;
use crate::io::{FormatName, OutputFormat, atomic, decode_table, encode_table};
use crate::model::Model;
use crate::table::{Interp, InterpolatedTable, Table};
use crate::tabulate::{TabulateOptions, tabulate};
use crate::{Error, codec::CodecSpec};
use clap::Args;
use std::io::IsTerminal;
use std::path::{Path, PathBuf};

#[derive(Args, Debug)]
pub struct ConvertArgs {
    /// Input: a table file (.bpk, brdfpack .exr, MERL .binary; `-` = stdin) or a model spec
    /// (e.g. `lambert:albedo=0.8/0.5/0.2`).
    pub input: String,
    /// Output file (`-` = stdout, which needs --format).
    #[arg(short, long)]
    pub output: PathBuf,
    /// Output format; by default from the output's extension (.bpk, .exr, .binary).
    #[arg(long, value_enum)]
    pub format: Option<FormatName>,
    /// Target grid (`merl` or KIND:DIMS[,...]). Default: the input table's grid; `merl` for
    /// MERL output and for model inputs.
    #[arg(long)]
    pub grid: Option<String>,
    /// Interpolation used when a table is re-gridded.
    #[arg(long, value_enum, default_value_t = Interp::Linear)]
    pub interp: Interp,
    /// EXR sample type of the value channels (f16 is lossy).
    #[arg(long, value_enum, default_value_t = ExrSampleType::F32)]
    pub exr_type: ExrSampleType,
    /// EXR compression; pxr24 is lossy for f32 and is only used when named here.
    #[arg(long, value_enum, default_value_t = ExrCompression::Zip)]
    pub exr_compression: ExrCompression,
    /// zstd level of native output (1–22).
    #[arg(long, default_value_t = 19, value_parser = clap::value_parser!(i32).range(1..=22))]
    pub zstd_level: i32,
    /// Sample an anisotropic source on an isotropic grid anyway (at φh = 0); recorded in the file.
    #[arg(long)]
    pub allow_anisotropic: bool,
    /// Say on stderr how the output was made (re-gridding, notes, size).
    #[arg(short, long)]
    pub verbose: bool,
}

/// What the input turned out to be.
enum Input {
    Table(Table),
    Model(Model),
}

fn open(spec: &str) -> crate::Result<Input> {
    let path = Path::new(spec);
    if spec == "-" || path.is_file() {
        let bytes = atomic::read_input(path)?;
        return Ok(Input::Table(decode_table(&bytes, path)?));
    }
    match Model::parse(spec) {
        Ok(m) => Ok(Input::Model(m)),
        // A name with a table extension that is not a file: say so rather than "unknown model".
        Err(_) if FormatName::from_path(path).is_some() || spec.contains('/') => Err(Error::io(
            path,
            std::io::Error::new(std::io::ErrorKind::NotFound, "no such file"),
        )),
        Err(e) => Err(e),
    }
}

pub fn run(a: ConvertArgs) -> anyhow::Result<i32> {
    let format = a
        .format
        .or_else(|| FormatName::from_path(&a.output))
        .ok_or_else(|| {
            Error::input(format!(
                "-o {}: cannot tell the output format from the name; use .bpk, .exr or .binary, \
                 or --format native|exr|merl",
                a.output.display()
            ))
        })?;
    let output = match format {
        FormatName::Native => OutputFormat::Native(CodecSpec::ZstdF32 {
            level: a.zstd_level,
        }),
        FormatName::Exr => OutputFormat::Exr(ExrOptions {
            sample_type: a.exr_type,
            compression: a.exr_compression,
        }),
        FormatName::Merl => OutputFormat::Merl,
    };
    let input = open(&a.input)?;
    let grid = match (&a.grid, &input) {
        (Some(s), _) => parse_grid_spec(s)?,
        (None, Input::Table(t)) if format != FormatName::Merl || merl_dims(t.grid()).is_some() => {
            t.grid().clone()
        }
        (None, _) => Grid::merl(),
    };
    if format == FormatName::Merl && merl_dims(&grid).is_none() {
        return Err(Error::input(format!(
            "--grid {}: MERL .binary needs a halfdiff3 grid with warps sqrt/linear/linear at \
             the lower bin edges (e.g. `merl`)",
            grid.describe()
        ))
        .into());
    }
    let opts = TabulateOptions {
        allow_anisotropic: a.allow_anisotropic,
        progress: std::io::stderr().is_terminal(),
    };
    let table = match input {
        Input::Table(t) if *t.grid() == grid => t,
        Input::Table(t) => regrid(t, &grid, a.interp, &opts)?,
        Input::Model(m) => {
            m.check_tabulable()?;
            tabulate(&m, &grid, &opts)?
        }
    };
    let bytes = encode_table(&table, &output)?;
    atomic::write_output(&a.output, &bytes)?;
    if a.verbose {
        let exact_kept = table.exact().is_some()
            && match &output {
                OutputFormat::Exr(o) => o.is_lossless(),
                OutputFormat::Native(_) | OutputFormat::Merl => true,
            };
        for note in &table.provenance().notes {
            eprintln!("brdfpack: note: {note}");
        }
        eprintln!(
            "brdfpack: wrote {} ({:?}, {} bytes, grid {}{})",
            a.output.display(),
            format,
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
