//! `brdfpack tabulate`: sample a source onto a grid and write the table.

use super::common::{Lookup, OutputArgs, SamplingArgs, Source, stderr_is_terminal, write_table};
use crate::grid::parse_grid_spec;
use crate::tabulate::tabulate;
use clap::Args;
use std::path::PathBuf;

#[derive(Args, Debug)]
pub struct TabulateArgs {
    /// Model spec (e.g. `ggx:alpha=0.2,fresnel=au`, JSON, @file.json), table file (.bpk, .exr,
    /// MERL .binary) or RGL .bsdf file.
    pub source: String,
    /// Grid: `merl` or KIND:DIMS[,warp=..][,at=center|edge][,theta-max=DEG]
    /// (KIND spherical4|spherical3|halfdiff3|halfdiff4; see docs/parameterizations.md).
    #[arg(long, default_value = "merl")]
    pub grid: String,
    /// Output file (`-` for stdout: native format unless --format says otherwise).
    #[arg(short, long)]
    pub output: PathBuf,
    /// Interpolation when the source is a table.
    #[arg(long, value_enum, default_value_t = Lookup::Linear)]
    pub interp: Lookup,
    #[command(flatten)]
    pub symmetry: SamplingArgs,
    /// Convert spectral channels to linear sRGB before writing (CIE 1931 2°, D65; see
    /// docs/spectral.md). An error when the source is not spectral.
    #[arg(long)]
    pub to_rgb: bool,
    #[command(flatten)]
    pub out: OutputArgs,
    /// Print one line of statistics on stderr.
    #[arg(short, long)]
    pub verbose: bool,
}

pub fn run(a: TabulateArgs) -> anyhow::Result<i32> {
    let grid = parse_grid_spec(&a.grid)?;
    let format = a.out.resolve(&a.output, &grid)?;
    let src = a
        .symmetry
        .apply(Source::open(&a.source)?)
        .into_brdf(a.interp)?;
    let t0 = std::time::Instant::now();
    let table = tabulate(
        src.as_ref(),
        &grid,
        &a.symmetry.options(stderr_is_terminal()),
    )?;
    let table = if a.to_rgb {
        crate::spectral::spectral_to_rgb(&table)?
    } else {
        table
    };
    let dt = t0.elapsed();
    for note in &table.provenance().notes {
        eprintln!("brdfpack: note: {note}");
    }
    let bytes = write_table(&table, &a.output, &format)?;
    if a.verbose {
        eprintln!(
            "tabulated {} cells ({} valid) × {} channels in {:.3} s; wrote {} bytes",
            grid.cells(),
            table.valid_count(),
            table.channels().len(),
            dt.as_secs_f64(),
            bytes
        );
    }
    Ok(0)
}
