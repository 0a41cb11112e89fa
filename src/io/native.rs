//! The native table format (`.bpk`), specified byte for byte in docs/format.md.
//!
//! ```text
//! magic    8 bytes   89 42 50 4B 0D 0A 1A 0A   ("\x89BPK\r\n\x1a\n")
//! version  u16 LE major (1), u16 LE minor (0)
//! count    u32 LE number of sections (2..=16)
//! crc32    u32 LE (IEEE) of the 16 bytes above, so no byte of the file is unchecked
//! sections count × { tag: 4 ASCII bytes, length: u64 LE, crc32: u32 LE (IEEE, of the payload),
//!                    payload: length bytes }
//! ```
//! Sections in order: `HEAD` (UTF-8 JSON header) or `HEAZ` (the same JSON, zstd-compressed;
//! such files are version 1.2), `DATA` (codec payload), optionally `MASK`
//! (zstd of a bitmap, LSB first, of the cells whose validity differs from the grid's geometric
//! mask; in files written before `geometric_xor`, of the validity itself),
//! optionally `F64X` (zstd of the table's exact f64 values, little-endian, same order as the
//! samples, when the table carries them; such files are version 1.1), and `END ` (empty)
//! last, so a file cut at a section boundary is still detected.

use crate::brdf::Channels;
use crate::codec::CodecSpec;
use crate::grid::{Grid, GridDesc};
use crate::io::ExactDesc;
use crate::table::{ExactValues, Provenance, Table};
use crate::{Error, Result};
use serde::{Deserialize, Serialize};
use std::borrow::Cow;
use std::path::Path;

pub const MAGIC: [u8; 8] = *b"\x89BPK\r\n\x1a\n";
pub const VERSION_MAJOR: u16 = 1;
pub const VERSION_MINOR: u16 = 0;
/// Minor version of files with an `F64X` section (1.0 readers refuse the unknown section).
pub const VERSION_MINOR_EXACT: u16 = 1;
/// Minor version of files whose header is the compressed `HEAZ` section (1.0 and 1.1
/// readers refuse the unknown section).
pub const VERSION_MINOR_HEAZ: u16 = 2;
/// zstd level of the `HEAZ` section (a header is about a kilobyte).
const HEAZ_ZSTD_LEVEL: i32 = 19;
/// zstd level of the `F64X` section: its low mantissa bits hardly compress, so a high level
/// costs seconds on a MERL-sized table for a percent or two.
const EXACT_ZSTD_LEVEL: i32 = 3;
/// Largest header accepted (a real one is a few KB).
pub(crate) const MAX_HEADER: u64 = 16 << 20;
const MAX_SECTIONS: u32 = 16;
/// Magic, version, section count and their checksum.
const PREAMBLE: usize = 20;
/// Most channels a table may have.
pub const MAX_CHANNELS: usize = 4096;

/// The JSON header: everything needed to decode with no flags.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct Header {
    /// Always `brdfpack-table`.
    pub format: String,
    pub grid: GridDesc,
    pub channels: Channels,
    pub provenance: Provenance,
    pub codec: CodecSpec,
    /// `geometric`: validity is implied by the grid (above the horizon, within θmax);
    /// `explicit`: a `MASK` section holds it; `geometric_xor`: a `MASK` section holds where it
    /// differs from the geometric one.
    pub mask: MaskKind,
    /// Number of valid cells (a consistency check).
    pub valid_cells: usize,
    /// Present when an `F64X` section holds the source's exact f64 values.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub exact: Option<ExactDesc>,
}

#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum MaskKind {
    Geometric,
    /// The `MASK` section holds every cell's validity (files written before
    /// [`MaskKind::GeometricXor`]; still read).
    Explicit,
    /// The `MASK` section holds the cells whose validity differs from the geometric mask
    /// (the holes of a measurement): two blocks of holes on the MERL grid cost 974 B, the
    /// whole mask, with the horizon's curve in it, 2,534 B.
    GeometricXor,
}

/// Encodes a table into the native format's bytes.
pub fn to_bytes(table: &Table, codec: &CodecSpec) -> Result<Vec<u8>> {
    to_bytes_with_payload(table, codec, &codec.encode(table)?)
}

/// Bytes before a section's payload: tag, length (u64) and crc32.
const SECTION_HEADER_BYTES: usize = 4 + 8 + 4;

/// The `MASK` section of a validity mask against the grid's geometric one
/// ([`MaskKind::GeometricXor`]): one bit per cell, set where the two differ (C order, least
/// significant bit first), zstd level 19.
fn mask_section(valid: &[bool], geometric: &[bool]) -> Result<Vec<u8>> {
    let mut bits = vec![0u8; valid.len().div_ceil(8)];
    for (i, (&v, &g)) in valid.iter().zip(geometric).enumerate() {
        if v != g {
            bits[i / 8] |= 1 << (i % 8);
        }
    }
    zstd::bulk::compress(&bits, 19)
        .map_err(|e| Error::Failure(format!("zstd compression failed: {e}")))
}

/// The bytes the `MASK` section of `table`'s file takes (section header included), 0 when its
/// mask is the grid's geometric one and no section is written.
pub fn mask_section_bytes(table: &Table) -> Result<usize> {
    let geometric = table.grid().geometric_mask();
    if geometric == table.valid() {
        return Ok(0);
    }
    Ok(SECTION_HEADER_BYTES + mask_section(table.valid(), &geometric)?.len())
}

/// The native file of `table` with its `DATA` section already encoded by `codec` (the
/// planner's measured candidate: the file written is the one whose error was measured, and
/// the table is not encoded a second time).
pub fn to_bytes_with_payload(table: &Table, codec: &CodecSpec, data: &[u8]) -> Result<Vec<u8>> {
    // Exact f64 values describe the f32 samples bit for bit; a lossy codec changes those
    // samples, so the exact values cannot travel with it (they would contradict the data).
    let exact = table.exact().filter(|_| codec.is_lossless());
    let geometric = table.grid().geometric_mask();
    let mask = if geometric == table.valid() {
        MaskKind::Geometric
    } else {
        MaskKind::GeometricXor
    };
    let header = Header {
        format: "brdfpack-table".into(),
        grid: table.grid().desc(),
        channels: table.channels().clone(),
        provenance: table.provenance().clone(),
        codec: codec.clone(),
        mask,
        valid_cells: table.valid_count(),
        exact: exact.map(|e| ExactDesc::new(&e.scale)),
    };
    let head = serde_json::to_vec(&header)
        .map_err(|e| Error::Failure(format!("header serialization: {e}")))?;
    let mut sections: Vec<([u8; 4], Cow<[u8]>)> =
        vec![head_section(head)?, (*b"DATA", data.into())];
    if mask == MaskKind::GeometricXor {
        sections.push((*b"MASK", mask_section(table.valid(), &geometric)?.into()));
    }
    let minor = match exact {
        Some(e) => {
            let mut raw = Vec::with_capacity(e.raw.len() * 8);
            for v in &e.raw {
                raw.extend_from_slice(&v.to_le_bytes());
            }
            let z = zstd::bulk::compress(&raw, EXACT_ZSTD_LEVEL)
                .map_err(|e| Error::Failure(format!("zstd compression failed: {e}")))?;
            sections.push((*b"F64X", z.into()));
            VERSION_MINOR_EXACT
        }
        None => VERSION_MINOR,
    };
    let minor = minor_for_head(sections[0].0, minor);
    sections.push((*b"END ", Cow::Borrowed(&[])));
    Ok(container(minor, &sections))
}

/// The header's section: `HEAZ` (zstd of the compact JSON `head`) when that is smaller, as it
/// is for every real header (a kilobyte of JSON, half of a preview-budget file, codes in
/// about 570 bytes), else `HEAD`.
pub(crate) fn head_section(head: Vec<u8>) -> Result<([u8; 4], Cow<'static, [u8]>)> {
    let z = zstd::bulk::compress(&head, HEAZ_ZSTD_LEVEL)
        .map_err(|e| Error::Failure(format!("zstd compression failed: {e}")))?;
    Ok(if z.len() < head.len() {
        (*b"HEAZ", z.into())
    } else {
        (*b"HEAD", head.into())
    })
}

/// The minor version a file whose first section is `head_tag` needs at least.
pub(crate) fn minor_for_head(head_tag: [u8; 4], minor: u16) -> u16 {
    if head_tag == *b"HEAZ" {
        minor.max(VERSION_MINOR_HEAZ)
    } else {
        minor
    }
}

/// The JSON header of checked `sections` (their first): `HEAD` as it is, `HEAZ` decompressed
/// (at most [`MAX_HEADER`] bytes).
pub(crate) fn header_json<'a>(
    sections: &[([u8; 4], &'a [u8])],
    path: &Path,
) -> Result<Cow<'a, [u8]>> {
    let (tag, payload) = sections[0];
    if tag != *b"HEAZ" {
        return Ok(Cow::Borrowed(payload));
    }
    use std::io::Read;
    let bad = |m: String| Error::invalid_file(path, m);
    let mut out = Vec::new();
    zstd::stream::read::Decoder::new(payload)
        .and_then(|d| d.take(MAX_HEADER + 1).read_to_end(&mut out))
        .map_err(|e| bad(format!("section \"HEAZ\": not a zstd frame ({e})")))?;
    if out.len() as u64 > MAX_HEADER {
        return Err(bad("header larger than 16 MiB".into()));
    }
    Ok(Cow::Owned(out))
}

/// The container's bytes: preamble (version 1.`minor`) and `sections` in order, each with
/// its length and checksum. The caller supplies `END ` last.
pub(crate) fn container(minor: u16, sections: &[([u8; 4], Cow<[u8]>)]) -> Vec<u8> {
    let mut out = Vec::new();
    out.extend_from_slice(&MAGIC);
    out.extend_from_slice(&VERSION_MAJOR.to_le_bytes());
    out.extend_from_slice(&minor.to_le_bytes());
    out.extend_from_slice(&(sections.len() as u32).to_le_bytes());
    let pre = crc32fast::hash(&out);
    out.extend_from_slice(&pre.to_le_bytes());
    for (tag, payload) in sections {
        out.extend_from_slice(tag);
        out.extend_from_slice(&(payload.len() as u64).to_le_bytes());
        out.extend_from_slice(&crc32fast::hash(payload).to_le_bytes());
        out.extend_from_slice(payload);
    }
    out
}

/// True when `bytes` start with the native magic.
pub fn is_native(bytes: &[u8]) -> bool {
    bytes.starts_with(&MAGIC)
}

/// Reads the sections of a native file, checking magic, version, lengths and checksums.
pub(crate) fn sections<'a>(bytes: &'a [u8], path: &Path) -> Result<Vec<([u8; 4], &'a [u8])>> {
    let bad = |m: String| Error::invalid_file(path, m);
    if bytes.len() < PREAMBLE {
        return Err(bad(format!(
            "{} bytes is too short for a brdfpack table (truncated?)",
            bytes.len()
        )));
    }
    if !is_native(bytes) {
        return Err(bad("not a brdfpack table (wrong magic)".into()));
    }
    let major = u16::from_le_bytes([bytes[8], bytes[9]]);
    let minor = u16::from_le_bytes([bytes[10], bytes[11]]);
    if major != VERSION_MAJOR {
        return Err(bad(format!(
            "format version {major}.{minor} is not supported (this build reads {VERSION_MAJOR}.x)"
        )));
    }
    let pre = u32::from_le_bytes([bytes[16], bytes[17], bytes[18], bytes[19]]);
    if crc32fast::hash(&bytes[..16]) != pre {
        return Err(bad(
            "preamble checksum mismatch (the file is corrupt)".into()
        ));
    }
    let count = u32::from_le_bytes([bytes[12], bytes[13], bytes[14], bytes[15]]);
    if !(2..=MAX_SECTIONS).contains(&count) {
        return Err(bad(format!(
            "section count {count} is out of range [2, {MAX_SECTIONS}]"
        )));
    }
    let mut pos = PREAMBLE;
    let mut out = Vec::with_capacity(count as usize);
    for s in 0..count {
        if bytes.len() - pos < 16 {
            return Err(bad(format!(
                "truncated: section {s} header at byte {pos} runs past the end ({} bytes)",
                bytes.len()
            )));
        }
        let tag: [u8; 4] = bytes[pos..pos + 4].try_into().expect("4 bytes");
        let len = u64::from_le_bytes(bytes[pos + 4..pos + 12].try_into().expect("8 bytes"));
        let crc = u32::from_le_bytes(bytes[pos + 12..pos + 16].try_into().expect("4 bytes"));
        pos += 16;
        let tag_s = String::from_utf8_lossy(&tag).into_owned();
        if len > (bytes.len() - pos) as u64 {
            return Err(bad(format!(
                "truncated: section {tag_s:?} declares {len} bytes but {} remain",
                bytes.len() - pos
            )));
        }
        let payload = &bytes[pos..pos + len as usize];
        pos += len as usize;
        if crc32fast::hash(payload) != crc {
            return Err(bad(format!(
                "section {tag_s:?}: checksum mismatch (the file is corrupt)"
            )));
        }
        out.push((tag, payload));
    }
    if pos != bytes.len() {
        return Err(bad(format!(
            "{} unexpected bytes after the last section",
            bytes.len() - pos
        )));
    }
    let tags: Vec<[u8; 4]> = out.iter().map(|(t, _)| *t).collect();
    // Optional sections between DATA and END, in this order.
    let middle: &[[u8; 4]] = if tags.len() >= 3 {
        &tags[2..tags.len() - 1]
    } else {
        &[]
    };
    let allowed: [&[[u8; 4]]; 4] = [&[], &[*b"MASK"], &[*b"F64X"], &[*b"MASK", *b"F64X"]];
    let ok = matches!(tags.first(), Some(b"HEAD" | b"HEAZ"))
        && tags.get(1) == Some(b"DATA")
        && tags.last() == Some(b"END ")
        && allowed.contains(&middle);
    if !ok {
        let names: Vec<String> = tags
            .iter()
            .map(|t| String::from_utf8_lossy(t).into_owned())
            .collect();
        return Err(bad(format!(
            "sections {names:?}: expected HEAD (or HEAZ), DATA, [MASK,] [F64X,] END"
        )));
    }
    Ok(out)
}

/// The kind of a native file: its header's `format` alone.
#[derive(Deserialize)]
struct Kind {
    format: String,
}

/// The header's `format` of a native file (`brdfpack-table`, `brdfpack-rgl`), its sections
/// checked; `None` when `bytes` are not a readable native file (its reader then says why).
pub fn kind_of(bytes: &[u8]) -> Option<String> {
    let secs = sections(bytes, Path::new("")).ok()?;
    let head = header_json(&secs, Path::new("")).ok()?;
    if head.len() as u64 > MAX_HEADER {
        return None;
    }
    serde_json::from_slice::<Kind>(&head).ok().map(|k| k.format)
}

/// Parses only the header (for `inspect`).
pub fn read_header(bytes: &[u8], path: &Path) -> Result<Header> {
    let secs = sections(bytes, path)?;
    parse_header(&header_json(&secs, path)?, path)
}

fn parse_header(head: &[u8], path: &Path) -> Result<Header> {
    if head.len() as u64 > MAX_HEADER {
        return Err(Error::invalid_file(path, "header larger than 16 MiB"));
    }
    crate::text::reject_duplicate_json_keys(head)
        .map_err(|e| Error::invalid_file(path, format!("header JSON: {e}")))?;
    // The kind first: another kind's header lacks the table's fields, and "missing field
    // `grid`" would not say what the file is.
    if let Ok(Kind { format }) = serde_json::from_slice::<Kind>(head)
        && format == crate::io::rgl::packed::FORMAT
    {
        return Err(Error::invalid_file(
            path,
            format!(
                "holds an RGL .bsdf packed in its own parameterization (header `format` = \
                 {format:?}), not a grid table: open it as a measured source (eval, check, \
                 plot, inspect, convert to .bsdf), or tabulate it on a grid"
            ),
        ));
    }
    let h: Header = serde_json::from_slice(head)
        .map_err(|e| Error::invalid_file(path, format!("header JSON: {e}")))?;
    if h.format != "brdfpack-table" {
        return Err(Error::invalid_file(
            path,
            format!(
                "header field `format` = {:?}, expected \"brdfpack-table\"",
                h.format
            ),
        ));
    }
    Ok(h)
}

/// Decodes a native file.
/// `n` little-endian f64 values from the zstd frame `z`, decoded in blocks straight into
/// the values (the decompressed bytes were a second array of the values' size: 35 MB for a
/// MERL-grid table, at the peak of a `compress --max-error` that reads its input again).
/// `Err(Ok(bytes))` when the frame holds another number of bytes (at most `8n + 1` read),
/// `Err(Err(e))` when it does not decode.
fn decompress_f64(z: &[u8], n: usize) -> std::result::Result<Vec<f64>, std::io::Result<usize>> {
    use std::io::Read;
    let mut dec = zstd::stream::read::Decoder::new(z).map_err(Err)?;
    let mut out = Vec::with_capacity(n);
    let mut block = vec![0u8; 1 << 16];
    let mut have = 0usize;
    while out.len() < n {
        let want = ((n - out.len()) * 8).min(block.len());
        let got = dec.read(&mut block[have..want]).map_err(Err)?;
        if got == 0 {
            return Err(Ok(out.len() * 8 + have));
        }
        have += got;
        let whole = have / 8 * 8;
        out.extend(
            block[..whole]
                .chunks_exact(8)
                .map(|b| f64::from_le_bytes(b.try_into().expect("8 bytes"))),
        );
        block.copy_within(whole..have, 0);
        have -= whole;
    }
    // Nothing may follow the values.
    match dec.read(&mut block[..1]) {
        Ok(0) => Ok(out),
        Ok(_) => Err(Ok(n * 8 + 1)),
        Err(e) => Err(Err(e)),
    }
}

pub fn from_bytes(bytes: &[u8], path: &Path) -> Result<Table> {
    let secs = sections(bytes, path)?;
    let h = parse_header(&header_json(&secs, path)?, path)?;
    let in_file = |e: Error| Error::invalid_file(path, e.to_string());
    let grid = Grid::from_desc(&h.grid).map_err(in_file)?;
    let declared = h.channels.names().len();
    if declared > MAX_CHANNELS {
        return Err(Error::invalid_file(
            path,
            format!("{declared} channels exceed the limit {MAX_CHANNELS}"),
        ));
    }
    let channels = Channels::named(
        h.channels.names().to_vec(),
        h.channels.wavelengths_nm().map(|w| w.to_vec()),
    )
    .map_err(in_file)?;
    let cells = grid.cells();
    // Before the mask or any sample is allocated: the decoded table plus the decoder's
    // scratch (and the exact f64 values, raw bytes and parsed), against the budget.
    let exact_bytes = match h.exact {
        Some(_) => (cells as u64).saturating_mul(channels.len() as u64 * 16),
        None => 0,
    };
    crate::memory::require(
        &format!(
            "the declared {} table with {} channel(s)",
            grid.describe(),
            channels.len()
        ),
        crate::memory::table_bytes(cells, channels.len())
            .saturating_mul(2)
            .saturating_add(exact_bytes),
    )
    .map_err(in_file)?;
    let valid = match h.mask {
        MaskKind::Geometric => grid.geometric_mask(),
        MaskKind::Explicit | MaskKind::GeometricXor => {
            let z = secs
                .iter()
                .find(|(t, _)| t == b"MASK")
                .ok_or_else(|| {
                    Error::invalid_file(
                        path,
                        format!(
                            "header says mask {} but there is no MASK section",
                            if h.mask == MaskKind::Explicit {
                                "explicit"
                            } else {
                                "geometric_xor"
                            }
                        ),
                    )
                })?
                .1;
            let bits = zstd::bulk::decompress(z, cells.div_ceil(8))
                .map_err(|e| Error::invalid_file(path, format!("MASK section: {e}")))?;
            if bits.len() != cells.div_ceil(8) {
                return Err(Error::invalid_file(
                    path,
                    format!(
                        "MASK section holds {} bytes, expected {}",
                        bits.len(),
                        cells.div_ceil(8)
                    ),
                ));
            }
            let set = |i: usize| bits[i / 8] >> (i % 8) & 1 == 1;
            if h.mask == MaskKind::GeometricXor {
                let geometric = grid.geometric_mask();
                (0..cells).map(|i| set(i) != geometric[i]).collect()
            } else {
                (0..cells).map(set).collect()
            }
        }
    };
    let valid_count = valid.iter().filter(|&&v| v).count();
    if valid_count != h.valid_cells {
        return Err(Error::invalid_file(
            path,
            format!(
                "header field `valid_cells` = {} but the mask has {valid_count}",
                h.valid_cells
            ),
        ));
    }
    let values = cells
        .checked_mul(channels.len())
        .ok_or_else(|| Error::invalid_file(path, "table size overflows"))?;
    let layout = crate::codec::Layout {
        grid: &grid,
        valid: &valid,
        channels: channels.len(),
    };
    let data = h.codec.decode(secs[1].1, &layout).map_err(in_file)?;
    let table = Table::new(grid, channels, h.provenance, data, valid).map_err(in_file)?;
    let f64x = secs.iter().find(|(t, _)| t == b"F64X").map(|s| s.1);
    match (&h.exact, f64x) {
        (None, None) => Ok(table),
        (Some(desc), Some(z)) => {
            let scale = desc.scale().map_err(in_file)?;
            let want = values
                .checked_mul(8)
                .ok_or_else(|| Error::invalid_file(path, "table size overflows"))?;
            let raw = decompress_f64(z, values).map_err(|got| {
                Error::invalid_file(
                    path,
                    match got {
                        Ok(n) => format!("F64X section holds {n} bytes, expected {want}"),
                        Err(e) => format!("F64X section: {e}"),
                    },
                )
            })?;
            table
                .with_exact(ExactValues { scale, raw })
                .map_err(in_file)
        }
        (Some(_), None) => Err(Error::invalid_file(
            path,
            "header field `exact` is set but there is no F64X section",
        )),
        (None, Some(_)) => Err(Error::invalid_file(
            path,
            "an F64X section is present but the header has no `exact` field",
        )),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::grid::parse_grid_spec;

    fn small_table() -> Table {
        let g = parse_grid_spec("halfdiff3:4x4x6").unwrap();
        let valid = g.geometric_mask();
        let n = g.cells();
        let data: Vec<f32> = (0..n * 3).map(|i| (i as f32).sqrt() * 0.37).collect();
        Table::new(
            g,
            Channels::default_for(3),
            Provenance {
                source: "test".into(),
                tool: "t".into(),
                notes: vec![],
            },
            data,
            valid,
        )
        .unwrap()
    }

    #[test]
    fn the_exact_values_decode_in_blocks_and_refuse_another_length() {
        // More values than one block holds (8192 f64), and an odd tail.
        let values: Vec<f64> = (0..20_001).map(|i| (i as f64).sqrt() * -1.5e-7).collect();
        let bytes: Vec<u8> = values.iter().flat_map(|v| v.to_le_bytes()).collect();
        let z = zstd::bulk::compress(&bytes, 3).unwrap();
        let back = decompress_f64(&z, values.len()).unwrap();
        assert!(
            back.iter()
                .zip(&values)
                .all(|(a, b)| a.to_bits() == b.to_bits())
        );
        assert_eq!(back.len(), values.len());
        // A frame of fewer values, of more, and no frame at all.
        assert!(matches!(
            decompress_f64(&z, values.len() + 1),
            Err(Ok(160_008))
        ));
        assert!(matches!(
            decompress_f64(&z, values.len() - 1),
            Err(Ok(160_001))
        ));
        assert!(matches!(decompress_f64(b"not zstd", 4), Err(Err(_))));
    }

    #[test]
    fn round_trips_bit_exactly() {
        let t = small_table();
        let bytes = to_bytes(&t, &CodecSpec::default()).unwrap();
        let back = from_bytes(&bytes, Path::new("x.bpk")).unwrap();
        assert_eq!(back, t);
        assert_eq!(to_bytes(&back, &CodecSpec::default()).unwrap(), bytes);
    }

    #[test]
    fn every_flipped_byte_and_every_truncation_is_detected() {
        let t = small_table();
        let bytes = to_bytes(&t, &CodecSpec::default()).unwrap();
        for i in 0..bytes.len() {
            let mut b = bytes.clone();
            b[i] ^= 0x20;
            assert!(
                from_bytes(&b, Path::new("x")).is_err(),
                "flip at {i} undetected"
            );
        }
        for n in 0..bytes.len() {
            let e = from_bytes(&bytes[..n], Path::new("x")).unwrap_err();
            assert_eq!(e.exit_code(), 2, "{e}");
        }
    }

    #[test]
    fn masks_of_holes_cost_what_the_holes_do_and_whole_masks_still_read() {
        // Two blocks of holes on the MERL grid: the mask against the geometric one holds only
        // the blocks' edges (974 B); the whole mask holds the horizon's curve too (2,534 B).
        let g = parse_grid_spec("merl").unwrap();
        let mut valid = g.geometric_mask();
        let mut idx = [0usize; 3];
        for (cell, v) in valid.iter_mut().enumerate() {
            g.unflatten(cell, &mut idx);
            if (idx[1] >= 80 && (60..120).contains(&idx[2])) || (idx[0] >= 70 && idx[2] < 20) {
                *v = false;
            }
        }
        let n = g.cells();
        let t = Table::new(
            g.clone(),
            Channels::default_for(1),
            Provenance {
                source: "test".into(),
                tool: "t".into(),
                notes: vec![],
            },
            vec![0.25; n],
            valid,
        )
        .unwrap();
        let bytes = mask_section_bytes(&t).unwrap();
        let whole = SECTION_HEADER_BYTES + mask_section(t.valid(), &vec![false; n]).unwrap().len();
        assert!(2 * bytes < whole, "{bytes} B against {whole} B");
        let file = to_bytes(&t, &CodecSpec::ZstdF32 { level: 3 }).unwrap();
        assert_eq!(from_bytes(&file, Path::new("x")).unwrap(), t);
        // The form written before `geometric_xor`: every cell's bit, `"mask": "explicit"`.
        let old = {
            let header = Header {
                format: "brdfpack-table".into(),
                grid: t.grid().desc(),
                channels: t.channels().clone(),
                provenance: t.provenance().clone(),
                codec: CodecSpec::ZstdF32 { level: 3 },
                mask: MaskKind::Explicit,
                valid_cells: t.valid_count(),
                exact: None,
            };
            let data = CodecSpec::ZstdF32 { level: 3 }.encode(&t).unwrap();
            let sections: Vec<([u8; 4], Cow<[u8]>)> = vec![
                (*b"HEAD", serde_json::to_vec(&header).unwrap().into()),
                (*b"DATA", data.into()),
                (
                    *b"MASK",
                    mask_section(t.valid(), &vec![false; n]).unwrap().into(),
                ),
                (*b"END ", Cow::Borrowed(&[])),
            ];
            container(VERSION_MINOR, &sections)
        };
        assert_eq!(from_bytes(&old, Path::new("old")).unwrap(), t);
    }

    #[test]
    fn explicit_masks_round_trip() {
        let t = small_table();
        let mut valid = t.valid().to_vec();
        valid[5] = !valid[5];
        let t2 = Table::new(
            t.grid().clone(),
            t.channels().clone(),
            t.provenance().clone(),
            t.data().to_vec(),
            valid,
        )
        .unwrap();
        let bytes = to_bytes(&t2, &CodecSpec::default()).unwrap();
        assert_eq!(from_bytes(&bytes, Path::new("x")).unwrap(), t2);
    }

    /// A table extended below the horizon keeps its grid and, through the geometric mask
    /// alone (no MASK section), its valid cells below the horizon.
    #[test]
    fn extended_grids_round_trip_with_a_geometric_mask() {
        let m = crate::model::Model::parse("ggx:alpha=0.3,fresnel=au").unwrap();
        let g = parse_grid_spec("halfdiff3:6x8x10,warp=sqrt/linear/linear,horizon=extend").unwrap();
        let t = crate::tabulate::tabulate(&m, &g, &Default::default()).unwrap();
        assert!(t.valid().iter().all(|&v| v));
        let bytes = to_bytes(&t, &CodecSpec::default()).unwrap();
        let secs = sections(&bytes, Path::new("x")).unwrap();
        let head = header_json(&secs, Path::new("x")).unwrap();
        let text = String::from_utf8_lossy(&head);
        assert!(text.contains(r#""mask":"geometric""#), "{text}");
        assert!(text.contains(r#""horizon":"extend""#));
        assert_eq!(from_bytes(&bytes, Path::new("x")).unwrap(), t);
        let h = read_header(&bytes, Path::new("x")).unwrap();
        assert_eq!(h.valid_cells, g.cells());
    }

    #[test]
    fn unknown_versions_are_refused() {
        let mut bytes = to_bytes(&small_table(), &CodecSpec::default()).unwrap();
        bytes[8] = 2;
        let pre = crc32fast::hash(&bytes[..16]);
        bytes[16..20].copy_from_slice(&pre.to_le_bytes());
        let e = from_bytes(&bytes, Path::new("x")).unwrap_err().to_string();
        assert!(e.contains("version 2.2 is not supported"), "{e}");
    }

    /// The header is written compressed (`HEAZ`, version 1.2) and smaller than its JSON; the
    /// same file with the plain `HEAD` of earlier versions (1.0) reads the same table.
    #[test]
    fn compressed_and_plain_headers_read_the_same() {
        let t = small_table();
        let bytes = to_bytes(&t, &CodecSpec::default()).unwrap();
        assert_eq!(
            u16::from_le_bytes([bytes[10], bytes[11]]),
            VERSION_MINOR_HEAZ
        );
        let secs = sections(&bytes, Path::new("x")).unwrap();
        assert_eq!(&secs[0].0, b"HEAZ");
        let json = header_json(&secs, Path::new("x")).unwrap().into_owned();
        assert!(secs[0].1.len() < json.len());
        let plain: Vec<([u8; 4], Cow<[u8]>)> = std::iter::once((*b"HEAD", Cow::from(&json[..])))
            .chain(secs[1..].iter().map(|(t, p)| (*t, Cow::from(*p))))
            .collect();
        let old = container(VERSION_MINOR, &plain);
        assert!(old.len() > bytes.len());
        assert_eq!(from_bytes(&old, Path::new("x")).unwrap(), t);
        assert_eq!(kind_of(&old).as_deref(), Some("brdfpack-table"));
        assert_eq!(kind_of(&bytes).as_deref(), Some("brdfpack-table"));
    }

    /// A `HEAZ` section that is not a zstd frame, or inflates past the header limit, is an
    /// error naming the file (exit 2), with correct checksums around it.
    #[test]
    fn a_hostile_compressed_header_is_an_error() {
        let t = small_table();
        let bytes = to_bytes(&t, &CodecSpec::default()).unwrap();
        let secs = sections(&bytes, Path::new("x")).unwrap();
        let bomb = zstd::bulk::compress(&vec![b' '; (MAX_HEADER + 10) as usize], 3).unwrap();
        for head in [b"{\"format\": 1}".to_vec(), bomb] {
            let rest = secs[1..].iter().map(|(t, p)| (*t, Cow::from(*p)));
            let file = container(
                VERSION_MINOR_HEAZ,
                &std::iter::once((*b"HEAZ", Cow::from(head)))
                    .chain(rest)
                    .collect::<Vec<_>>(),
            );
            let e = from_bytes(&file, Path::new("h.bpk")).unwrap_err();
            assert_eq!(e.exit_code(), 2, "{e}");
            assert!(e.to_string().contains("h.bpk"), "{e}");
            assert!(kind_of(&file).is_none());
        }
    }
}
