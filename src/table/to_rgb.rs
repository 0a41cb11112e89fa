//! A spectral table as linear sRGB (the table-level use of `spectral::SpectrumToRgb`; it
//! lives with tables so that `spectral` stays below the models that use it).

use super::{Provenance, Table};
use crate::brdf::Channels;
use crate::spectral::{SpectrumToRgb, summarize_names};
use crate::{Error, Result};

/// A spectral table converted to linear sRGB (R, G, B channels), cell by cell (see the
/// module doc for the definition). Values below 0 (spectra outside the sRGB gamut, e.g.
/// narrow-band ones) are clamped to 0, since a BRDF cannot be negative; the provenance
/// records the conversion and how many values were clamped.
pub fn spectral_to_rgb(table: &Table) -> Result<Table> {
    let ch = table.channels();
    let Some(wavelengths) = ch.wavelengths_nm() else {
        return Err(Error::input(format!(
            "spectral to RGB: the table's channels ({}) are not spectral (they carry no \
             wavelengths)",
            summarize_names(ch.names())
        )));
    };
    let conv = SpectrumToRgb::new(wavelengths)?;
    let c = ch.len();
    let mut data = vec![0f32; table.valid().len() * 3];
    let mut spectrum = vec![0.0f64; c];
    let mut clamped = 0usize;
    for (cell, &ok) in table.valid().iter().enumerate() {
        if !ok {
            continue;
        }
        for (s, &v) in spectrum.iter_mut().zip(table.cell(cell)) {
            *s = v as f64;
        }
        for (k, v) in conv.convert(&spectrum).into_iter().enumerate() {
            // Outside the gamut a primary goes negative; a BRDF value cannot.
            if v < 0.0 {
                clamped += 1;
            }
            data[cell * 3 + k] = v.max(0.0) as f32;
        }
    }
    let (lo, hi) = wavelengths
        .iter()
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), &w| {
            (a.min(w), b.max(w))
        });
    let mut provenance: Provenance = table.provenance().clone();
    provenance.notes.push(format!(
        "converted from {c} spectral channels ({lo}–{hi} nm) to linear sRGB: CIE 1931 2° \
         observer, illuminant D65, 5 nm summation over 380–780 nm, piecewise-linear spectrum \
         held constant beyond its end samples (docs/spectral.md)"
    ));
    if clamped > 0 {
        provenance.notes.push(format!(
            "{clamped} RGB values below 0 (spectra outside the sRGB gamut) were clamped to 0"
        ));
    }
    Table::new(
        table.grid().clone(),
        Channels::default_for(3),
        provenance,
        data,
        table.valid().to_vec(),
    )
}
