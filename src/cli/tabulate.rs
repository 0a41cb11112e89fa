//! `brdfpack tabulate`: sample a source onto a grid and write the table.

use super::common::{
    Bar, DepfileArgs, LookupArg, OutputArgs, SamplingArgs, SceneArgs, Source, write_table,
};
use crate::grid::parse_grid_spec;
use crate::tabulate::tabulate;
use clap::Args;
use std::path::PathBuf;

#[derive(Args, Debug)]
pub struct TabulateArgs {
    /// Model spec (e.g. `ggx:alpha=0.2,fresnel=au`, JSON, @file.json), table file (.bpk, .exr,
    /// MERL .binary) or RGL .bsdf file.
    pub source: String,
    /// Grid: `merl` or KIND:DIMS[,warp=..][,at=center|edge][,theta-max=DEG][,weight=none|cosine][,space=linear|log:S]
    /// [,horizon=cut|extend] (KIND spherical4|spherical3|halfdiff3|halfdiff4; see
    /// docs/parameterizations.md).
    ///
    /// Default: `merl` for an isotropic reciprocal source; otherwise the planner's default
    /// (`spherical3:90x90x180` for an isotropic non-reciprocal one such as an RGL file,
    /// `halfdiff4:64,warp=linear/linear/grazing/linear` for an anisotropic one).
    #[arg(long)]
    pub grid: Option<String>,
    /// Output file (`-` for stdout: native format unless --format says otherwise).
    #[arg(short, long)]
    pub output: PathBuf,
    /// Interpolation when the source is a table.
    #[arg(long, value_enum, default_value_t = LookupArg::Linear)]
    pub interp: LookupArg,
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
    /// A JSON report (cells, channels, bytes, time) on stdout (stderr with `-o -`).
    #[arg(long)]
    pub json: bool,
    /// Nothing but errors (no progress bar, no notes).
    #[arg(short, long, conflicts_with = "verbose")]
    pub quiet: bool,
    #[command(flatten)]
    pub depfile: DepfileArgs,
    #[command(flatten)]
    pub scene: SceneArgs,
}

pub fn run(a: TabulateArgs) -> anyhow::Result<i32> {
    let mut reads = crate::reads::ReadSet::new();
    let scene = a.scene.load(&mut reads)?;
    let given = a.grid.as_deref().map(parse_grid_spec).transpose()?;
    let src = a
        .symmetry
        .apply(Source::open_recording(&a.source, &mut reads)?)
        .into_brdf(a.interp.into())?;
    let full_channels = src.channels().clone();
    let src = scene.restrict_source(src)?;
    let grid = match given {
        Some(g) => g,
        None => crate::plan::grids::table_default_grid(src.as_ref())?,
    };
    let grid = scene.restrict_grid(&grid)?;
    let format = a.out.resolve(&a.output, &grid)?;
    let mut symmetry = a.symmetry.clone();
    if scene.isotropic == Some(true) {
        symmetry.allow_anisotropic = true;
    }
    let t0 = std::time::Instant::now();
    let bar = Bar::new(a.quiet);
    let table = tabulate(src.as_ref(), &grid, &symmetry.options(bar.cells()));
    bar.finish();
    let table = table?;
    let table = if a.to_rgb {
        crate::table::spectral_to_rgb(&table)?
    } else {
        table
    };
    let dt = t0.elapsed();
    if !a.quiet {
        for note in &table.provenance().notes {
            eprintln!("brdfpack: note: {note}");
        }
    }
    let bytes = write_table(&table, &a.output, &format)?;
    a.depfile.write(&[a.output.as_path()], &reads)?;
    if a.json {
        let scene_report = (!scene.is_empty())
            .then(|| scene.report(&full_channels, table.channels(), &grid, table.valid_count()));
        let text = serde_json::json!({
            "output": a.output.display().to_string(),
            "grid": grid.describe(),
            "cells": grid.cells(),
            "valid_cells": table.valid_count(),
            "channels": table.channels().names(),
            "bytes": bytes,
            "tabulate_s": dt.as_secs_f64(),
            "scene": scene_report,
        })
        .to_string();
        super::common::print_json_line(&text, &a.output)?;
    }
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
