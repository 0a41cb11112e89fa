//! File formats and output handling: format detection, reading any table file, writing a
//! table in the format its name (or an explicit choice) asks for.

pub mod atomic;
pub mod cleanup;
pub mod exr;
pub mod mbsdf;
pub mod merl;
pub mod model_files;
pub mod native;
pub mod rgl;

use crate::codec::CodecSpec;
use crate::table::Table;
use crate::{Error, Result};
use serde::{Deserialize, Serialize};
use std::path::Path;

/// What a file is, judged by its content.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Format {
    /// brdfpack's own `.bpk` (magic `\x89BPK\r\n\x1a\n`).
    Native,
    /// OpenEXR (magic 76 2f 31 01).
    Exr,
    /// MERL `.binary` (no magic: dims header whose product accounts for the size).
    Merl,
    /// RGL `.bsdf` tensor file (`tensor_file` header): a measured BRDF, not a table.
    Rgl,
    /// MDL `.mbsdf` (magic `NVIDIA ARC MBSDF V1\n`).
    Mbsdf,
    Unknown,
}

impl Format {
    pub fn name(self) -> &'static str {
        match self {
            Format::Native => "native",
            Format::Exr => "exr",
            Format::Merl => "merl",
            Format::Rgl => "rgl",
            Format::Mbsdf => "mbsdf",
            Format::Unknown => "unknown",
        }
    }
}

/// The format of `bytes`. Content decides; the path only helps a damaged MERL file (which
/// has no magic) get MERL's precise error instead of "unknown format", as do MERL's standard
/// dims at the start of a stream (a truncated MERL file on stdin).
pub fn detect(bytes: &[u8], path: &Path) -> Format {
    if rgl::packed::is_packed_rgl(bytes) {
        // A measured RGL file packed in its own parameterization: read as the RGL file.
        Format::Rgl
    } else if native::is_native(bytes) {
        Format::Native
    } else if exr::is_exr(bytes) {
        Format::Exr
    } else if bytes.starts_with(b"tensor_file") {
        Format::Rgl
    } else if mbsdf::is_mbsdf(bytes) {
        Format::Mbsdf
    } else if merl::looks_like_merl(bytes)
        || merl::has_standard_dims(bytes)
        || has_extension(path, "binary")
    {
        Format::Merl
    } else {
        Format::Unknown
    }
}

fn has_extension(path: &Path, ext: &str) -> bool {
    path.extension()
        .is_some_and(|e| e.eq_ignore_ascii_case(ext))
}

/// Decodes a table from bytes of a known format.
pub fn decode_table(bytes: &[u8], path: &Path) -> Result<Table> {
    match detect(bytes, path) {
        Format::Native => native::from_bytes(bytes, path),
        Format::Exr => exr::from_bytes(bytes, path),
        Format::Merl => merl::from_bytes(bytes, path),
        Format::Mbsdf => mbsdf::from_bytes(bytes, path),
        Format::Rgl if native::is_native(bytes) => Err(Error::invalid_file(
            path,
            format!(
                "holds an RGL tensor (an RGL .bsdf packed in its own parameterization, format \
                 {:?}), not a grid table: open it as a measured source (eval, check, plot, \
                 convert -o x.bsdf), or tabulate it on a grid",
                rgl::packed::FORMAT
            ),
        )),
        Format::Rgl => Err(Error::invalid_file(
            path,
            "an RGL .bsdf file is a measured BRDF, not a table (tabulate it on a grid instead)",
        )),
        Format::Unknown => Err(unknown_format(bytes, path, false)),
    }
}

/// The error for bytes of no known format, listing what the caller reads: tables, and RGL
/// `.bsdf` files too when `measured` (a source: `eval`, `check`, `pack`...).
pub fn unknown_format(bytes: &[u8], path: &Path, measured: bool) -> Error {
    Error::invalid_file(
        path,
        format!(
            "unknown format ({} bytes): expected a brdfpack table (.bpk), a brdfpack EXR, a \
             MERL .binary{} or an MDL .mbsdf file",
            bytes.len(),
            if measured { ", an RGL .bsdf" } else { "" }
        ),
    )
}

/// Reads a table file (native, EXR or MERL; `-` = stdin).
pub fn read_table(path: &Path) -> Result<Table> {
    if path.as_os_str() != "-"
        && let Some(t) = merl::read_regular_file(path)?
    {
        return Ok(t);
    }
    let bytes = atomic::read_input(path)?;
    decode_table(&bytes, path)
}

/// A format name, as `--format` takes it.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum FormatName {
    /// brdfpack's native `.bpk`.
    Native,
    /// OpenEXR image (`.exr`).
    Exr,
    /// MERL `.binary` (90×90×180 halfdiff grid, RGB).
    Merl,
    /// MDL `.mbsdf` (spherical3 grid, scalar or RGB).
    Mbsdf,
    /// RGL `.bsdf` for Mitsuba 3 / pbrt-v4 `measured` (written by `convert` only).
    Rgl,
}

impl FormatName {
    /// The format an output path's extension names: `.bpk`, `.exr`, `.binary`.
    pub fn from_path(path: &Path) -> Option<FormatName> {
        if has_extension(path, "bpk") {
            Some(FormatName::Native)
        } else if has_extension(path, "exr") {
            Some(FormatName::Exr)
        } else if has_extension(path, "binary") {
            Some(FormatName::Merl)
        } else if has_extension(path, "mbsdf") {
            Some(FormatName::Mbsdf)
        } else if has_extension(path, "bsdf") {
            Some(FormatName::Rgl)
        } else {
            None
        }
    }
}

/// An output format with its options.
#[derive(Clone, Debug, PartialEq)]
pub enum OutputFormat {
    Native(CodecSpec),
    Exr(exr::ExrOptions),
    Merl,
    Mbsdf(mbsdf::MbsdfOptions),
}

impl OutputFormat {
    pub fn name(&self) -> FormatName {
        match self {
            OutputFormat::Native(_) => FormatName::Native,
            OutputFormat::Exr(_) => FormatName::Exr,
            OutputFormat::Merl => FormatName::Merl,
            OutputFormat::Mbsdf(_) => FormatName::Mbsdf,
        }
    }
}

/// Encodes a table in `format`. MERL needs a MERL-shaped grid and 3 channels (re-grid first).
pub fn encode_table(table: &Table, format: &OutputFormat) -> Result<Vec<u8>> {
    match format {
        OutputFormat::Native(codec) => native::to_bytes(table, codec),
        OutputFormat::Exr(opts) => exr::to_bytes(table, opts),
        OutputFormat::Merl => merl::to_bytes(table),
        OutputFormat::Mbsdf(opts) => mbsdf::to_bytes(table, opts),
    }
}

/// Writes a table atomically (`-` = stdout).
pub fn write_table(table: &Table, path: &Path, format: &OutputFormat) -> Result<()> {
    let bytes = encode_table(table, format)?;
    atomic::write_output(path, &bytes)
}

/// How a file header records a table's exact f64 scales: the bit patterns are authoritative
/// (JSON decimal parsing is not guaranteed to round-trip an f64), the decimals are for people.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct ExactDesc {
    pub scale: Vec<f64>,
    /// `0x` + 16 hex digits of each scale's IEEE-754 bits.
    pub scale_bits: Vec<String>,
}

impl ExactDesc {
    pub fn new(scale: &[f64]) -> ExactDesc {
        ExactDesc {
            scale: scale.to_vec(),
            scale_bits: scale
                .iter()
                .map(|s| format!("0x{:016x}", s.to_bits()))
                .collect(),
        }
    }

    /// The scales from their bit patterns.
    pub fn scale(&self) -> Result<Vec<f64>> {
        self.scale_bits
            .iter()
            .map(|b| {
                b.strip_prefix("0x")
                    .filter(|h| h.len() == 16)
                    .and_then(|h| u64::from_str_radix(h, 16).ok())
                    .map(f64::from_bits)
                    .ok_or_else(|| {
                        Error::input(format!(
                            "exact scale bits {b:?}: expected 0x and 16 hex digits"
                        ))
                    })
            })
            .collect()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn formats_are_detected_by_content() {
        let p = Path::new("x");
        assert_eq!(detect(&native::MAGIC, p), Format::Native);
        assert_eq!(detect(&[0x76, 0x2f, 0x31, 0x01, 2, 0], p), Format::Exr);
        assert_eq!(detect(b"tensor_file\0\x01\x00", p), Format::Rgl);
        let m = merl::MerlTable {
            dims: [2, 1, 3],
            raw: vec![0.5; 18],
        };
        assert_eq!(detect(&m.to_bytes(), p), Format::Merl);
        assert_eq!(detect(&m.to_bytes()[..20], p), Format::Unknown);
        assert_eq!(
            detect(&m.to_bytes()[..20], Path::new("a.binary")),
            Format::Merl
        );
        assert_eq!(detect(b"hello", p), Format::Unknown);
        assert_eq!(
            detect(b"NVIDIA ARC MBSDF V1\nMBSDF_DATA=\n", p),
            Format::Mbsdf
        );
    }

    #[test]
    fn exact_scales_round_trip_through_json() {
        let d = ExactDesc::new(&merl::SCALE);
        let j = serde_json::to_string(&d).unwrap();
        let back: ExactDesc = serde_json::from_str(&j).unwrap();
        let s = back.scale().unwrap();
        for (a, b) in s.iter().zip(merl::SCALE) {
            assert_eq!(a.to_bits(), b.to_bits());
        }
    }
}
