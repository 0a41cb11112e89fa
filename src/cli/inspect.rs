//! `brdfpack inspect`: what a table file holds — format, grid, channels, provenance and value
//! statistics over the valid cells.

use crate::io::{Format, atomic, decode_table, detect};
use crate::table::Table;
use crate::text::sanitize;
use clap::Args;
use serde::Serialize;
use std::path::PathBuf;

#[derive(Args, Debug)]
pub struct InspectArgs {
    /// A table file: native .bpk, brdfpack .exr or MERL .binary (`-` = stdin).
    pub file: PathBuf,
    /// Print one JSON object instead of text.
    #[arg(long)]
    pub json: bool,
    #[command(flatten)]
    pub report: super::common::ReportTarget,
}

/// Statistics of one channel over the valid cells.
#[derive(Serialize, Debug, Clone, PartialEq)]
pub struct ChannelStats {
    pub name: String,
    pub min: f64,
    pub max: f64,
    pub mean: f64,
    /// Valid cells whose value is negative (fitted data can hold small negatives).
    pub negative: usize,
}

/// The report `inspect` prints.
#[derive(Serialize, Debug)]
pub struct Report {
    pub file: String,
    pub format: &'static str,
    pub bytes: usize,
    pub grid: String,
    pub grid_desc: crate::grid::GridDesc,
    pub channels: Vec<String>,
    pub source: String,
    pub tool: String,
    pub notes: Vec<String>,
    pub cells: usize,
    pub valid_cells: usize,
    pub invalid_cells: usize,
    /// Negative values over all channels of the valid cells.
    pub negative_values: usize,
    /// True when the table carries its source's exact f64 values (e.g. from MERL).
    pub exact_f64: bool,
    pub stats: Vec<ChannelStats>,
}

/// Per-channel min/max/mean (f64 sums) and negative counts over valid cells; all zero when
/// no cell is valid.
pub fn channel_stats(t: &Table) -> Vec<ChannelStats> {
    let nch = t.channels().len();
    let mut s: Vec<ChannelStats> = t
        .channels()
        .names()
        .iter()
        .map(|n| ChannelStats {
            name: n.clone(),
            min: f64::INFINITY,
            max: f64::NEG_INFINITY,
            mean: 0.0,
            negative: 0,
        })
        .collect();
    let mut count = 0usize;
    for (cell, &ok) in t.valid().iter().enumerate() {
        if !ok {
            continue;
        }
        count += 1;
        for (k, &v) in t.cell(cell).iter().enumerate() {
            let v = v as f64;
            s[k].min = s[k].min.min(v);
            s[k].max = s[k].max.max(v);
            s[k].mean += v;
            if v < 0.0 {
                s[k].negative += 1;
            }
        }
    }
    for c in s.iter_mut().take(nch) {
        if count == 0 {
            // No valid cell: report zeros rather than ±Inf (never printed as non-finite).
            c.min = 0.0;
            c.max = 0.0;
        } else {
            c.mean /= count as f64;
        }
    }
    s
}

pub fn run(a: InspectArgs) -> anyhow::Result<i32> {
    // A MERL file on disk is read in chunks: its 35 MB of bytes are not held beside the
    // table's samples and exact values (93.8 → 60 MB peak RSS on a standard file).
    if a.file.as_os_str() != "-"
        && let Some(t) = crate::io::merl::read_regular_file(&a.file)?
    {
        let len = std::fs::metadata(&a.file)
            .map_err(|e| crate::Error::io(&a.file, e))?
            .len() as usize;
        return report_table(&a, &t, Format::Merl, len);
    }
    let bytes = atomic::read_input(&a.file)?;
    let format = detect(&bytes, &a.file);
    if format == Format::Rgl {
        // Not a table: a measured BRDF with its own layout (docs/rgl.md).
        let rgl = crate::io::rgl::RglBsdf::from_bytes(&bytes, &a.file.display().to_string())?;
        let info = rgl.info();
        let packed = rgl.packed();
        if a.json {
            outln!(
                "{}",
                serde_json::json!({"file": a.file.display().to_string(), "format": "rgl",
                    "bytes": bytes.len(), "table": false, "rgl": info, "packed": packed})
            );
        } else {
            outln!("file: {}", sanitize(&a.file.display().to_string()));
            outln!(
                "format: rgl ({} bytes; a measured BRDF, not a table)",
                bytes.len()
            );
            if let Some(p) = packed {
                use crate::codec::tensor::TensorCoding;
                outln!(
                    "packed: {} (a .bpk holding the RGL file in its own parameterization): \
                     {} {}; VNDF {}{}",
                    p.format,
                    p.colour.name,
                    match &p.colour.coding {
                        TensorCoding::Lossless => "lossless (f32 + zstd)".to_string(),
                        TensorCoding::Dct { step, eps, .. } => format!(
                            "signed log (eps {eps:?}), colour KLT, DCT, context-coded, step {step:.4e}"
                        ),
                    },
                    match p.vndf {
                        crate::io::rgl::packed::FieldForm::Derived => "derived from the NDF",
                        crate::io::rgl::packed::FieldForm::Stored => "stored",
                        crate::io::rgl::packed::FieldForm::Coded => "coded (signed log, DCT)",
                    },
                    match &p.sigma {
                        Some(d) => format!("; sigma derived from the NDF (× {})", d.scale),
                        None => String::new(),
                    }
                );
                outln!("source: {}", sanitize(&p.provenance.source));
                outln!("tool: {}", sanitize(&p.provenance.tool));
            }
            outln!("description: {}", sanitize(&info.description));
            outln!(
                "resolution: {}x{} samples per slice, {} θi slices, {} φi slice(s), VNDF {}x{}",
                info.resolution[0],
                info.resolution[1],
                info.theta_i.len(),
                info.phi_slices,
                info.vndf_resolution[0],
                info.vndf_resolution[1]
            );
            if info.phi_slices > 1 {
                outln!(
                    "anisotropic: reduction {} ({})",
                    info.reduction,
                    match info.reduction {
                        2 => "queries turned by π into the half turn the slices span",
                        4 => "queries mirrored into the quadrant the slices span",
                        _ => "no folding",
                    }
                );
            }
            outln!(
                "values: {} entries per channel, range {:e} .. {:e}",
                info.entries_per_channel,
                // The file's values are f32: their shortest f32 form (-1.5e-1, not
                // -1.5000000596046448e-1).
                info.value_range[0] as f32,
                info.value_range[1] as f32
            );
            outln!(
                "negative entries per channel: {:?} (passed through by eval, as the reference \
                 does; --clamp-negative clamps them)",
                info.negative_counts
            );
        }
        return Ok(0);
    }
    if format == Format::Unknown {
        // `inspect` reads RGL files too: the list says so.
        return Err(crate::io::unknown_format(&bytes, &a.file, true).into());
    }
    let t = decode_table(&bytes, &a.file)?;
    report_table(&a, &t, format, bytes.len())
}

/// The report of a table read from a file of `bytes` bytes in `format`.
fn report_table(a: &InspectArgs, t: &Table, format: Format, bytes: usize) -> anyhow::Result<i32> {
    let stats = channel_stats(t);
    let r = Report {
        file: a.file.display().to_string(),
        format: format.name(),
        bytes,
        grid: t.grid().describe(),
        grid_desc: t.grid().desc(),
        channels: t.channels().names().to_vec(),
        source: t.provenance().source.clone(),
        tool: t.provenance().tool.clone(),
        notes: t.provenance().notes.clone(),
        cells: t.grid().cells(),
        valid_cells: t.valid_count(),
        invalid_cells: t.grid().cells() - t.valid_count(),
        negative_values: stats.iter().map(|s| s.negative).sum(),
        exact_f64: t.exact().is_some(),
        stats,
    };
    if a.json {
        outln!("{}", serde_json::to_string_pretty(&r)?);
        return Ok(0);
    }
    outln!("file: {}", sanitize(&r.file));
    outln!("format: {} ({} bytes)", r.format, r.bytes);
    outln!("grid: {}", r.grid);
    outln!("channels: {}", sanitize(&r.channels.join(" ")));
    outln!("source: {}", sanitize(&r.source));
    outln!("tool: {}", sanitize(&r.tool));
    for n in &r.notes {
        outln!("note: {}", sanitize(n));
    }
    outln!(
        "cells: {} (valid {}, invalid {})",
        r.cells,
        r.valid_cells,
        r.invalid_cells
    );
    outln!("negative values in valid cells: {}", r.negative_values);
    outln!(
        "exact f64 values: {}",
        if r.exact_f64 { "yes" } else { "no" }
    );
    for s in &r.stats {
        outln!(
            "channel {}: min {:.6e} max {:.6e} mean {:.6e} (1/sr)",
            sanitize(&s.name),
            s.min,
            s.max,
            s.mean
        );
    }
    Ok(0)
}
