//! `brdfpack convert SOURCE -o out.bsdf` (or `--format rgl`): an RGL `.bsdf` for Mitsuba 3 /
//! pbrt-v4 `measured`, written from the source as a pointwise BRDF (tables: multilinear
//! lookup). The work is `io::rgl::write`; this file maps options and prints notes.

use super::common::{Lookup, Source};
use super::convert::ConvertArgs;
use crate::io::atomic;
use crate::io::rgl::fidelity::refuse_unrepresentable;
use crate::io::rgl::write::{RglWriteOptions, write_rgl};
use clap::Args;

/// Resolutions of an RGL `.bsdf` (defaults: RGL's 128-node NDF/VNDF, a 64×64 colour grid;
/// 32 θi slices instead of the 8 of the measured files).
#[derive(Args, Debug, Clone)]
pub struct RglArgs {
    /// RGL .bsdf: incident elevation slices over [0°, 89.5°], denser towards grazing.
    #[arg(long, default_value_t = RglWriteOptions::default().theta_slices, help_heading = "RGL .bsdf output")]
    pub rgl_theta_slices: usize,
    /// RGL .bsdf: incident azimuth slices over [−180°, 180°] (anisotropic sources only;
    /// over [−180°, −90°] with --rgl-fold-phi).
    #[arg(long, default_value_t = RglWriteOptions::default().phi_slices, help_heading = "RGL .bsdf output")]
    pub rgl_phi_slices: usize,
    /// RGL .bsdf: azimuth slices over a quarter turn, which Mitsuba 3 mirrors every query
    /// into (4× denser slices at the same size). Only for sources mirror-symmetric about the
    /// x and y axes (checked); pbrt-v4 does not load such files.
    #[arg(long, help_heading = "RGL .bsdf output")]
    pub rgl_fold_phi: bool,
    /// RGL .bsdf: colour grid n×n of the warped sample square.
    #[arg(long, default_value_t = RglWriteOptions::default().colour_res, help_heading = "RGL .bsdf output")]
    pub rgl_colour_res: usize,
    /// RGL .bsdf: VNDF grid n×n over the half-vector square.
    #[arg(long, default_value_t = RglWriteOptions::default().vndf_res, help_heading = "RGL .bsdf output")]
    pub rgl_vndf_res: usize,
    /// RGL .bsdf: NDF and σ columns (u_θ).
    #[arg(long, default_value_t = RglWriteOptions::default().ndf_res, help_heading = "RGL .bsdf output")]
    pub rgl_ndf_res: usize,
    /// RGL .bsdf: NDF and σ rows (u_φ) for anisotropic sources.
    #[arg(long, default_value_t = RglWriteOptions::default().ndf_phi_res, help_heading = "RGL .bsdf output")]
    pub rgl_ndf_phi_res: usize,
    /// RGL .bsdf: share of the warp given to a flat visible-normal density, so the tail of
    /// the NDF keeps colour-grid nodes (0 = pure VNDF, as the measured RGL files).
    #[arg(long, default_value_t = RglWriteOptions::default().tail_share, help_heading = "RGL .bsdf output")]
    pub rgl_tail_share: f64,
    /// RGL .bsdf from an RGL .bsdf: resample it (NDF, warp, colour tables rebuilt) instead of
    /// writing its tables back unchanged.
    #[arg(long, help_heading = "RGL .bsdf output")]
    pub rgl_resample: bool,
}

impl RglArgs {
    pub fn options(&self) -> RglWriteOptions {
        RglWriteOptions {
            theta_slices: self.rgl_theta_slices,
            phi_slices: self.rgl_phi_slices,
            fold_phi: self.rgl_fold_phi,
            colour_res: self.rgl_colour_res,
            vndf_res: self.rgl_vndf_res,
            ndf_res: self.rgl_ndf_res,
            ndf_phi_res: self.rgl_ndf_phi_res,
            tail_share: self.rgl_tail_share,
            ..RglWriteOptions::default()
        }
    }
}

pub fn run(a: &ConvertArgs, input: Source) -> anyhow::Result<i32> {
    if a.grid.is_some() {
        return Err(crate::Error::input(
            "--grid does not apply to an RGL .bsdf (its tables are set by --rgl-* options)",
        )
        .into());
    }
    if a.to_rgb {
        return Err(crate::Error::input(
            "--to-rgb applies to tables; for an RGL .bsdf convert to an RGB table first",
        )
        .into());
    }
    // An RGL file is written back table for table (unless it is to be clamped or resampled);
    // one packed in its own parameterization (a `.bpk` of kind brdfpack-rgl) as the RGL file
    // it holds, its derived fields (VNDF, luminance) rebuilt.
    if let Source::Measured(m) = &input
        && !a.symmetry.clamp_negative
        && !a.rgl.rgl_resample
    {
        let out = m.fields().to_tensor_bytes();
        atomic::write_output(&a.output, &out)?;
        if a.verbose {
            eprintln!(
                "brdfpack: wrote {} (RGL .bsdf, {} bytes): the fields of {} {}",
                a.output.display(),
                out.len(),
                a.input,
                if m.packed().is_some() {
                    "as packed (VNDF and luminance rebuilt when the file derives them)"
                } else {
                    "unchanged"
                }
            );
        }
        return Ok(0);
    }
    let brdf = input.into_brdf(match crate::table::Interp::from(a.interp) {
        crate::table::Interp::Linear => Lookup::Linear,
        crate::table::Interp::Nearest => Lookup::Nearest,
    })?;
    let written = write_rgl(brdf.as_ref(), &a.rgl.options())?;
    // Measured before anything is written: a lobe the file's nodes cannot hold is refused.
    let fidelity = refuse_unrepresentable(
        brdf.as_ref(),
        &written.bytes,
        &a.output.display().to_string(),
    )?;
    atomic::write_output(&a.output, &written.bytes)?;
    if a.verbose {
        eprintln!(
            "brdfpack: the file's directional albedo against the source's: max |Δ| {:.2e} \
             (at θi {:.2}°, φi {:.0}°: {:.4} against {:.4}; {:.0}% of the refusal threshold)",
            fidelity.max_abs_diff,
            fidelity.theta_i_deg,
            fidelity.phi_i_deg,
            fidelity.file,
            fidelity.source,
            100.0 * fidelity.threshold_share
        );
        for note in &written.notes {
            eprintln!("brdfpack: note: {note}");
        }
        eprintln!(
            "brdfpack: wrote {} (RGL .bsdf, {} bytes; NDF after {} power iterations, last \
             change {:.1e}): {}",
            a.output.display(),
            written.bytes.len(),
            written.iterations,
            written.ndf_change,
            written.description
        );
    } else {
        for note in &written.notes {
            eprintln!("brdfpack: note: {note}");
        }
    }
    if a.json {
        let text = serde_json::json!({
            "output": a.output.display().to_string(),
            "format": "Rgl",
            "bytes": written.bytes.len(),
            "albedo_fidelity": fidelity,
        })
        .to_string();
        super::common::print_json_line(&text, &a.output)?;
    }
    Ok(0)
}
