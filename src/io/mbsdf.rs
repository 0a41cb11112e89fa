//! MDL measured BSDF files (`.mbsdf`, NVIDIA MDL specification, appendix "MBSDF file format",
//! version 1; IANA `application/vnd.mdl-mbsdf`): what Iray, Omniverse, V-Ray and Substance
//! load as a measured BSDF.
//!
//! ```text
//! "NVIDIA ARC MBSDF V1\n"                 magic (20 bytes)
//! meta-data lines, each ending in '\n'    e.g. description="..." (printable ASCII)
//! "MBSDF_DATA_REFLECTION=\n"              BRDF block identifier ("MBSDF_DATA=\n" also read)
//! u32 type                                0 = scalar, 1 = RGB
//! u32 resolution_theta                    nθ ≥ 1
//! u32 resolution_phi                      nφ ≥ 1
//! f32 values[nθ][nθ][nφ][1 or 3]          [θin][θout][Δφ][channel], f_r in 1/sr
//! optionally "MBSDF_DATA_TRANSMISSION=\n" and a BTDF block of the same layout
//! ```
//! All numbers little-endian. Bin k of a θ axis covers [k, k+1)·(π/2)/nθ, of the Δφ axis
//! [k, k+1)·π/nφ (Δφ = |φout − φin| folded into [0, π]); brdfpack puts the sample at the bin
//! centre, which is a `spherical3` grid with linear warps and centred samples. A file read
//! and written back through that grid is bit-exact.

use crate::brdf::Channels;
use crate::grid::{Grid, GridKind, Placement, Warp};
use crate::table::{Provenance, Table};
use crate::{Error, Result, TOOL_VERSION};
use std::path::Path;

/// The magic line, version included.
pub const MAGIC: &[u8] = b"NVIDIA ARC MBSDF V1\n";
/// Identifier of a BRDF block (what NVIDIA's own exporter writes, and what we write).
pub const REFLECTION_TAG: &[u8] = b"MBSDF_DATA_REFLECTION=\n";
/// The older identifier of a BRDF block, read as a synonym.
pub const DATA_TAG: &[u8] = b"MBSDF_DATA=\n";
/// Identifier of a BTDF block.
pub const TRANSMISSION_TAG: &[u8] = b"MBSDF_DATA_TRANSMISSION=\n";
/// Longest meta-data line accepted; the MDL SDK reads lines into a 1024-byte buffer.
pub const MAX_LINE: usize = 1023;
/// Rec. 709 luminance weights, for scalar files written from RGB tables.
pub const LUMINANCE: [f64; 3] = [0.2126, 0.7152, 0.0722];

/// One BSDF block: `values[((θin·nθ + θout)·nφ + Δφ)·channels + c]`.
#[derive(Clone, Debug, PartialEq)]
pub struct MbsdfPart {
    /// 3 channels (type 1) or 1 (type 0).
    pub rgb: bool,
    pub n_theta: usize,
    pub n_phi: usize,
    pub values: Vec<f32>,
}

impl MbsdfPart {
    pub fn channels(&self) -> usize {
        if self.rgb { 3 } else { 1 }
    }
}

/// A whole file: its meta-data lines (without '\n') and its blocks.
#[derive(Clone, Debug, PartialEq)]
pub struct MbsdfFile {
    pub metadata: Vec<String>,
    pub reflection: Option<MbsdfPart>,
    pub transmission: Option<MbsdfPart>,
}

/// Options of the writer.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct MbsdfOptions {
    /// Write a scalar file (type 0) from an RGB table: the Rec. 709 luminance.
    pub scalar: bool,
}

/// True when `bytes` start with the MBSDF magic line.
pub fn is_mbsdf(bytes: &[u8]) -> bool {
    bytes.starts_with(MAGIC)
}

/// The (nθ, nφ) of a grid an MBSDF file can hold: `spherical3` with nθi = nθo, linear warps,
/// centred samples and no θ limit; `None` otherwise.
pub fn mbsdf_dims(grid: &Grid) -> Option<[usize; 2]> {
    let a = grid.axes();
    let ok = grid.kind() == GridKind::Spherical3
        && grid.theta_max().is_none()
        && a[0].n == a[1].n
        && a.iter()
            .all(|x| x.warp == Warp::Linear && x.placement == Placement::Center);
    ok.then(|| [a[0].n, a[2].n])
}

/// The grid of an MBSDF block of nθ × nφ bins.
pub fn mbsdf_grid(n_theta: usize, n_phi: usize) -> Result<Grid> {
    Grid::new(
        GridKind::Spherical3,
        &[
            (n_theta, Warp::Linear, Placement::Center),
            (n_theta, Warp::Linear, Placement::Center),
            (n_phi, Warp::Linear, Placement::Center),
        ],
        None,
    )
}

impl MbsdfFile {
    /// Parses a file: the magic, meta-data lines up to a block identifier, one or two blocks
    /// whose sizes must account for the bytes exactly, finite values.
    pub fn parse(bytes: &[u8], path: &Path) -> Result<MbsdfFile> {
        let bad = |m: String| Error::invalid_file(path, m);
        if !is_mbsdf(bytes) {
            return Err(bad(
                "not an MBSDF file: it does not start with \"NVIDIA ARC MBSDF V1\\n\"".into(),
            ));
        }
        let mut pos = MAGIC.len();
        let mut metadata = Vec::new();
        // Meta-data lines until the first block identifier.
        let first_tag = loop {
            let line = next_line(bytes, pos).ok_or_else(|| {
                bad(format!(
                    "byte {pos}: no block identifier (MBSDF_DATA_REFLECTION=, MBSDF_DATA= or \
                     MBSDF_DATA_TRANSMISSION=) before the end of the file"
                ))
            })?;
            let full = &bytes[pos..pos + line];
            if full == REFLECTION_TAG || full == DATA_TAG || full == TRANSMISSION_TAG {
                pos += line;
                break full;
            }
            if line > MAX_LINE + 1 {
                return Err(bad(format!(
                    "byte {pos}: meta-data line of {} bytes, longer than {MAX_LINE}",
                    line - 1
                )));
            }
            let text = &full[..line - 1];
            if let Some(b) = text.iter().find(|b| !(0x20..0x7f).contains(*b)) {
                return Err(bad(format!(
                    "byte {pos}: meta-data line holds byte 0x{b:02x}; only printable ASCII is \
                     allowed"
                )));
            }
            metadata.push(String::from_utf8_lossy(text).into_owned());
            pos += line;
        };
        let mut file = MbsdfFile {
            metadata,
            reflection: None,
            transmission: None,
        };
        let mut tag = first_tag;
        loop {
            let what = if tag == TRANSMISSION_TAG {
                "transmission"
            } else {
                "reflection"
            };
            let (part, end) = parse_part(bytes, pos, what).map_err(bad)?;
            let slot = if tag == TRANSMISSION_TAG {
                &mut file.transmission
            } else {
                &mut file.reflection
            };
            if slot.is_some() {
                return Err(bad(format!(
                    "byte {pos}: a second {what} block (a file holds at most one BRDF block \
                     followed by at most one BTDF block)"
                )));
            }
            *slot = Some(part);
            pos = end;
            if pos == bytes.len() {
                break;
            }
            match next_line(bytes, pos) {
                Some(l) if &bytes[pos..pos + l] == TRANSMISSION_TAG => {
                    tag = TRANSMISSION_TAG;
                    pos += l;
                }
                _ => {
                    return Err(bad(format!(
                        "{} bytes after the {what} block at byte {pos}, which are no \
                         MBSDF_DATA_TRANSMISSION= block",
                        bytes.len() - pos
                    )));
                }
            }
        }
        Ok(file)
    }

    /// The file's bytes: magic, meta-data lines, the reflection block (identifier
    /// `MBSDF_DATA_REFLECTION=`), the transmission block if any.
    pub fn to_bytes(&self) -> Vec<u8> {
        let mut out = MAGIC.to_vec();
        for line in &self.metadata {
            out.extend_from_slice(line.as_bytes());
            out.push(b'\n');
        }
        for (tag, part) in [
            (REFLECTION_TAG, &self.reflection),
            (TRANSMISSION_TAG, &self.transmission),
        ] {
            if let Some(p) = part {
                out.extend_from_slice(tag);
                out.extend_from_slice(&u32::from(p.rgb).to_le_bytes());
                out.extend_from_slice(&(p.n_theta as u32).to_le_bytes());
                out.extend_from_slice(&(p.n_phi as u32).to_le_bytes());
                for v in &p.values {
                    out.extend_from_slice(&v.to_le_bytes());
                }
            }
        }
        out
    }

    /// The reflection block as a table on its `spherical3` grid (all cells valid: every bin
    /// centre is above the horizon). A transmission block is not a BRDF and is left out, with
    /// a note.
    pub fn to_table(&self, source: &str) -> Result<Table> {
        let part = self.reflection.as_ref().ok_or_else(|| {
            Error::input("the file holds only a transmission (BTDF) block; brdfpack reads BRDFs")
        })?;
        let grid = mbsdf_grid(part.n_theta, part.n_phi)?;
        let mut notes = Vec::new();
        if self.transmission.is_some() {
            notes.push("the file's transmission (BTDF) block was left out".to_string());
        }
        if let Some(d) = self.metadata.iter().find(|l| l.starts_with("description=")) {
            notes.push(format!("MBSDF meta-data: {d}"));
        }
        let provenance = Provenance {
            source: source.to_string(),
            tool: TOOL_VERSION.to_string(),
            notes,
        };
        let cells = grid.cells();
        Table::new(
            grid,
            Channels::default_for(part.channels()),
            provenance,
            part.values.clone(),
            vec![true; cells],
        )
    }

    /// A file holding `table` (on an MBSDF grid, 1 or 3 non-spectral channels) as its
    /// reflection block. Invalid cells are written as 0 (the format has no validity).
    pub fn from_table(table: &Table, opts: &MbsdfOptions) -> Result<MbsdfFile> {
        let [n_theta, n_phi] = mbsdf_dims(table.grid()).ok_or_else(|| {
            Error::input(format!(
                "an MDL .mbsdf file needs a spherical3 grid with nθi = nθo, linear warps and \
                 centred samples (e.g. --grid spherical3:90x90x180); the table's grid is {}",
                table.grid().describe()
            ))
        })?;
        if crate::spectral::is_spectral(table.channels()) {
            crate::spectral::require_rgb(table.channels(), "MDL .mbsdf")?;
        }
        let c = table.channels().len();
        if c != 1 && c != 3 {
            return Err(Error::input(format!(
                "an MDL .mbsdf file holds 1 (scalar) or 3 (RGB) channels; the table has {c} ({})",
                table.channels().names().join(", ")
            )));
        }
        let rgb = c == 3 && !opts.scalar;
        let out_c = if rgb { 3 } else { 1 };
        let mut values = Vec::with_capacity(table.grid().cells() * out_c);
        for cell in 0..table.grid().cells() {
            let v = table.cell(cell);
            if !table.valid()[cell] {
                values.extend(std::iter::repeat_n(0.0f32, out_c));
            } else if c == 3 && !rgb {
                let y: f64 = (0..3).map(|k| LUMINANCE[k] * v[k] as f64).sum();
                values.push(y as f32);
            } else {
                values.extend_from_slice(v);
            }
        }
        let mut metadata = vec![format!(
            "description=\"{}\"",
            quote(&table.provenance().source)
        )];
        metadata.push(format!("generator=\"{}\"", quote(TOOL_VERSION)));
        if c == 3 && !rgb {
            metadata.push("channels=\"Rec. 709 luminance of RGB\"".to_string());
        }
        Ok(MbsdfFile {
            metadata,
            reflection: Some(MbsdfPart {
                rgb,
                n_theta,
                n_phi,
                values,
            }),
            transmission: None,
        })
    }
}

/// A meta-data value as printable ASCII inside double quotes: `"` and `\` escaped, other
/// bytes outside 0x20..0x7e replaced by `?`, at most 900 characters.
fn quote(s: &str) -> String {
    let mut out = String::new();
    for ch in s.chars() {
        if out.len() > 900 {
            out.push_str("...");
            break;
        }
        match ch {
            '"' => out.push_str("\\\""),
            '\\' => out.push_str("\\\\"),
            ' '..='~' => out.push(ch),
            _ => out.push('?'),
        }
    }
    out
}

/// The length of the line at `pos`, its '\n' included; `None` when there is no '\n'.
fn next_line(bytes: &[u8], pos: usize) -> Option<usize> {
    bytes[pos..].iter().position(|&b| b == b'\n').map(|i| i + 1)
}

/// One block at `pos`: its type, resolutions and values; returns the block and its end.
fn parse_part(
    bytes: &[u8],
    pos: usize,
    what: &str,
) -> std::result::Result<(MbsdfPart, usize), String> {
    let u32_at = |p: usize| -> Option<u32> {
        bytes
            .get(p..p + 4)
            .map(|b| u32::from_le_bytes(b.try_into().expect("4 bytes")))
    };
    let (Some(ty), Some(nt), Some(np)) = (u32_at(pos), u32_at(pos + 4), u32_at(pos + 8)) else {
        return Err(format!(
            "byte {pos}: the {what} block is truncated ({} bytes left, its header needs 12)",
            bytes.len() - pos
        ));
    };
    let rgb = match ty {
        0 => false,
        1 => true,
        t => {
            return Err(format!(
                "byte {pos}: {what} block type {t}; expected 0 (scalar) or 1 (RGB)"
            ));
        }
    };
    let max = crate::grid::MAX_AXIS_RESOLUTION as u32;
    for (name, n, at) in [
        ("resolution_theta", nt, pos + 4),
        ("resolution_phi", np, pos + 8),
    ] {
        if n == 0 || n > max {
            return Err(format!(
                "byte {at}: {what} block {name} = {n} is not in [1, {max}]"
            ));
        }
    }
    let channels: u128 = if rgb { 3 } else { 1 };
    let count = nt as u128 * nt as u128 * np as u128 * channels;
    let start = pos + 12;
    let need = count * 4;
    if ((bytes.len() - start) as u128) < need {
        return Err(format!(
            "byte {start}: the {what} block ({} × {nt} × {np}{}) needs {need} bytes of values, \
             {} are left (truncated?)",
            nt,
            if rgb { " × 3" } else { "" },
            bytes.len() - start
        ));
    }
    let count = count as usize;
    let end = start + 4 * count;
    let mut values = Vec::with_capacity(count);
    for (i, b) in bytes[start..end].chunks_exact(4).enumerate() {
        let v = f32::from_le_bytes(b.try_into().expect("4 bytes"));
        if !v.is_finite() {
            return Err(format!(
                "byte {}: {what} value {i} is {v}; values must be finite",
                start + 4 * i
            ));
        }
        values.push(v);
    }
    Ok((
        MbsdfPart {
            rgb,
            n_theta: nt as usize,
            n_phi: np as usize,
            values,
        },
        end,
    ))
}

/// Reads an `.mbsdf` file's reflection block into a table.
pub fn from_bytes(bytes: &[u8], path: &Path) -> Result<Table> {
    let file = MbsdfFile::parse(bytes, path)?;
    let name = path
        .file_name()
        .map(|f| f.to_string_lossy().into_owned())
        .unwrap_or_else(|| "<stdin>".into());
    file.to_table(&format!("MDL .mbsdf file {name}"))
        .map_err(|e| Error::invalid_file(path, e.to_string()))
}

/// Writes a table (on an MBSDF grid) as `.mbsdf` bytes.
pub fn to_bytes(table: &Table, opts: &MbsdfOptions) -> Result<Vec<u8>> {
    Ok(MbsdfFile::from_table(table, opts)?.to_bytes())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn part(rgb: bool, nt: usize, np: usize) -> MbsdfPart {
        let c = if rgb { 3 } else { 1 };
        MbsdfPart {
            rgb,
            n_theta: nt,
            n_phi: np,
            values: (0..nt * nt * np * c)
                .map(|i| i as f32 * 0.25 - 1.0)
                .collect(),
        }
    }

    #[test]
    fn file_round_trips_through_bytes() {
        let f = MbsdfFile {
            metadata: vec!["description=\"x\"".into(), "a=b".into()],
            reflection: Some(part(true, 3, 4)),
            transmission: Some(part(false, 2, 5)),
        };
        let bytes = f.to_bytes();
        assert_eq!(MbsdfFile::parse(&bytes, Path::new("t")).unwrap(), f);
        // Every truncation is an error, except the one right after the reflection block,
        // which is a valid reflection-only file.
        let boundary = bytes.len() - TRANSMISSION_TAG.len() - 12 - 2 * 2 * 5 * 4;
        for cut in 0..bytes.len() {
            let r = MbsdfFile::parse(&bytes[..cut], Path::new("t"));
            if cut == boundary {
                assert_eq!(r.unwrap().transmission, None);
            } else {
                assert!(r.is_err(), "cut {cut}");
            }
        }
    }

    #[test]
    fn grid_test_accepts_only_centred_linear_spherical3() {
        assert_eq!(mbsdf_dims(&mbsdf_grid(5, 7).unwrap()), Some([5, 7]));
        assert_eq!(mbsdf_dims(&Grid::merl()), None);
        let g = Grid::new(
            GridKind::Spherical3,
            &[
                (5, Warp::Linear, Placement::Center),
                (6, Warp::Linear, Placement::Center),
                (7, Warp::Linear, Placement::Center),
            ],
            None,
        )
        .unwrap();
        assert_eq!(mbsdf_dims(&g), None);
    }

    #[test]
    fn quoting_escapes_and_keeps_ascii() {
        assert_eq!(quote("a\"b\\c\u{e9}"), "a\\\"b\\\\c?");
    }
}
