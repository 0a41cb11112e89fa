//! Tables as OpenEXR images (layout in `docs/format.md`, "EXR tables").
//!
//! One single-part scanline image: x = the grid's last (fastest) axis, y = the flat index of
//! the other axes in C order, so pixel (x, y) is cell `y · n_last + x`. Channels:
//! `brdf.<name>` (f32 or f16, f_r in 1/sr × `value_scale`), `valid` (f16, 1 = valid, 0 =
//! invalid; the `brdf.*` channels hold 0 there; NaN is never written), and, when the table
//! carries exact f64 values and the output is lossless f32, `f64hi.<name>` / `f64lo.<name>`
//! (u32: the high and low 32 bits of each f64). One text attribute `brdfpack` holds a JSON
//! header (ASCII) with everything needed to read the table back; `software` names the tool.

use crate::brdf::Channels;
use crate::grid::{Grid, GridDesc};
use crate::io::ExactDesc;
use crate::table::{ExactValues, Provenance, Table};
use crate::{Error, Result, TOOL_VERSION};
use exr::prelude::*;
use half::f16;
use serde::{Deserialize, Serialize};
use std::io::Cursor;
use std::path::Path;

/// The four bytes every OpenEXR file starts with.
pub const MAGIC: [u8; 4] = [0x76, 0x2f, 0x31, 0x01];
/// The name of the header attribute.
pub const ATTRIBUTE: &str = "brdfpack";
/// Largest finite f16.
const F16_MAX: f64 = 65504.0;
/// A decoded image larger than this many times the file is refused before decoding (ZIP's
/// ratio is bounded near 1032:1; a larger claim means a hostile or corrupt header).
const MAX_EXPANSION: u128 = 2048;

/// Storage type of the value channels.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum ExrSampleType {
    /// 32-bit float: the table's samples exactly.
    #[default]
    F32,
    /// 16-bit float: lossy (11 significant bits); values above 65504 are scaled by a power
    /// of two recorded in the header.
    F16,
}

/// EXR compression (all lossless except PXR24 on f32 channels, which must be asked for).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum ExrCompression {
    None,
    Rle,
    /// zlib, one scanline per block.
    Zips,
    /// zlib, 16 scanlines per block (the default: small and lossless).
    #[default]
    Zip,
    Piz,
    /// Lossy for f32 (rounds to 24-bit floats); lossless for f16 and u32.
    Pxr24,
}

impl ExrCompression {
    fn to_exr(self) -> Compression {
        match self {
            ExrCompression::None => Compression::Uncompressed,
            ExrCompression::Rle => Compression::RLE,
            ExrCompression::Zips => Compression::ZIP1,
            ExrCompression::Zip => Compression::ZIP16,
            ExrCompression::Piz => Compression::PIZ,
            ExrCompression::Pxr24 => Compression::PXR24,
        }
    }
}

/// Options of [`to_bytes`].
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct ExrOptions {
    pub sample_type: ExrSampleType,
    pub compression: ExrCompression,
}

impl ExrOptions {
    /// True when the value channels come back bit for bit.
    pub fn is_lossless(&self) -> bool {
        self.sample_type == ExrSampleType::F32 && self.compression != ExrCompression::Pxr24
    }
}

/// The JSON header stored in the `brdfpack` attribute.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct ExrHeader {
    /// Always `brdfpack-exr`.
    pub format: String,
    /// Layout version (1).
    pub version: u32,
    pub grid: GridDesc,
    /// Table channels in order; value channel k is named `brdf.<names[k]>`.
    pub channels: Channels,
    pub provenance: Provenance,
    /// Always `1/sr` (f_r without the cosine factor).
    pub units: String,
    /// A human description of the pixel layout.
    pub layout: String,
    pub sample_type: ExrSampleType,
    /// stored = f_r × 2^value_scale_log2 (0 unless f16 needed room; a power of two keeps the
    /// scaling exact).
    pub value_scale_log2: i32,
    /// How invalid cells are encoded.
    pub invalid: String,
    /// Present when `f64hi.*` / `f64lo.*` channels hold the source's exact f64 values.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub exact: Option<ExactDesc>,
}

/// The EXR channel holding table channel `name`.
pub fn value_channel(name: &str) -> String {
    format!("brdf.{name}")
}

/// Encodes a table as an EXR image.
pub fn to_bytes(table: &Table, opts: &ExrOptions) -> Result<Vec<u8>> {
    let grid = table.grid();
    let shape = grid.shape();
    let width = *shape.last().expect("grids have axes");
    let height = grid.cells() / width;
    let nch = table.channels().len();
    let cells = grid.cells();
    let mut provenance = table.provenance().clone();
    // f16 needs every valid value within ±65504; scale by a power of two when it is not.
    let mut scale_log2 = 0i32;
    if opts.sample_type == ExrSampleType::F16 {
        let max = table
            .data()
            .iter()
            .fold(0f64, |m, &v| m.max((v as f64).abs()));
        while max * 2f64.powi(scale_log2) > F16_MAX
            || !f16::from_f64(max * 2f64.powi(scale_log2)).is_finite()
        {
            scale_log2 -= 1;
        }
        provenance.notes.push(format!(
            "stored as f16 (11 significant bits){}",
            if scale_log2 != 0 {
                format!(", values × 2^{scale_log2} to fit the f16 range")
            } else {
                String::new()
            }
        ));
    } else if opts.compression == ExrCompression::Pxr24 {
        provenance
            .notes
            .push("values rounded to 24-bit floats by PXR24 compression (lossy)".into());
    }
    let keep_exact = opts.is_lossless() && table.exact().is_some();
    let header = ExrHeader {
        format: "brdfpack-exr".into(),
        version: 1,
        grid: grid.desc(),
        channels: table.channels().clone(),
        provenance,
        units: "1/sr".into(),
        layout: layout_text(grid),
        sample_type: opts.sample_type,
        value_scale_log2: scale_log2,
        invalid: "channel `valid` = 0 (f16); the brdf.* channels hold 0 there".into(),
        exact: table
            .exact()
            .filter(|_| keep_exact)
            .map(|e| ExactDesc::new(&e.scale)),
    };
    let json = serde_json::to_string(&header)
        .map_err(|e| Error::Failure(format!("EXR header serialization: {e}")))?;

    let mut list: SmallVec<[AnyChannel<FlatSamples>; 4]> = SmallVec::new();
    let factor = 2f64.powi(scale_log2);
    for (k, name) in table.channels().names().iter().enumerate() {
        let values = (0..cells).map(|cell| table.data()[cell * nch + k]);
        let samples = match opts.sample_type {
            ExrSampleType::F32 => FlatSamples::F32(values.collect()),
            ExrSampleType::F16 => FlatSamples::F16(
                values
                    .map(|v| {
                        // 11 significant bits round a value within 2^-12 of f32's largest
                        // (3.4028235e38) up to 2^128, which the reader's f32 cannot hold: such
                        // a value is stored one f16 step toward 0 (the file read back).
                        let h = f16::from_f64(v as f64 * factor);
                        if ((h.to_f64() / factor) as f32).is_finite() {
                            h
                        } else {
                            f16::from_bits(h.to_bits() - 1)
                        }
                    })
                    .collect::<Vec<_>>(),
            ),
        };
        list.push(channel(&value_channel(name), samples)?);
    }
    let valid: Vec<f16> = table
        .valid()
        .iter()
        .map(|&v| if v { f16::ONE } else { f16::ZERO })
        .collect();
    list.push(channel("valid", FlatSamples::F16(valid))?);
    if let Some(e) = table.exact().filter(|_| keep_exact) {
        for (k, name) in table.channels().names().iter().enumerate() {
            let bits = || (0..cells).map(|cell| e.raw[cell * nch + k].to_bits());
            let hi = bits().map(|b| (b >> 32) as u32).collect();
            let lo = bits().map(|b| b as u32).collect();
            list.push(channel(&format!("f64hi.{name}"), FlatSamples::U32(hi))?);
            list.push(channel(&format!("f64lo.{name}"), FlatSamples::U32(lo))?);
        }
    }
    let mut other = std::collections::HashMap::new();
    // One custom attribute only: the writer emits custom attributes in HashMap order, so a
    // second one would make the bytes differ between runs.
    other.insert(
        text("attribute", ATTRIBUTE)?,
        AttributeValue::Text(text("header", &json)?),
    );
    let attributes = LayerAttributes {
        software_name: Some(text("software", TOOL_VERSION)?),
        comments: Some(text(
            "comments",
            &format!(
                "BRDF table (f_r in 1/sr) on grid {}; see the brdfpack attribute",
                grid.describe()
            ),
        )?),
        other,
        ..LayerAttributes::default()
    };
    let encoding = Encoding {
        compression: opts.compression.to_exr(),
        blocks: Blocks::ScanLines,
        // Increasing order makes the writer sort its parallel output: reproducible bytes.
        line_order: LineOrder::Increasing,
    };
    let layer = Layer::new(
        (width, height),
        attributes,
        encoding,
        AnyChannels::sort(list),
    );
    let mut out = Vec::new();
    Image::from_layer(layer)
        .write()
        .to_buffered(Cursor::new(&mut out))
        .map_err(|e| Error::Failure(format!("EXR encoding failed: {e}")))?;
    Ok(out)
}

fn channel(name: &str, samples: FlatSamples) -> Result<AnyChannel<FlatSamples>> {
    Ok(AnyChannel {
        name: text("channel name", name)?,
        sample_data: samples,
        // Linear data: no perceptual quantization in lossy schemes.
        quantize_linearly: true,
        sampling: Vec2(1, 1),
    })
}

/// EXR text is bytes; non-ASCII characters are escaped as JSON `\uXXXX` (valid inside the
/// JSON strings where they occur) so every reader decodes the same text.
fn text(what: &str, s: &str) -> Result<Text> {
    let ascii = ascii_json(s);
    Text::new_or_none(&ascii).ok_or_else(|| Error::Failure(format!("EXR {what}: not encodable")))
}

/// `s` with every non-ASCII character replaced by its JSON `\uXXXX` escape (UTF-16 pairs
/// above the BMP).
pub fn ascii_json(s: &str) -> String {
    let mut out = String::with_capacity(s.len());
    for ch in s.chars() {
        if ch.is_ascii() {
            out.push(ch);
        } else {
            let mut buf = [0u16; 2];
            for u in ch.encode_utf16(&mut buf) {
                out.push_str(&format!("\\u{u:04x}"));
            }
        }
    }
    out
}

fn layout_text(grid: &Grid) -> String {
    let axes = grid.axes();
    let (last, rest) = axes.split_last().expect("grids have axes");
    let rest_s: Vec<String> = rest
        .iter()
        .map(|a| format!("{} ({})", a.quantity.name(), a.n))
        .collect();
    format!(
        "x = {} ({}); y = C-order flat index of [{}]; pixel (x, y) = cell y*{} + x",
        last.quantity.name(),
        last.n,
        rest_s.join(", "),
        last.n
    )
}

/// True when `bytes` start with the EXR magic.
pub fn is_exr(bytes: &[u8]) -> bool {
    bytes.starts_with(&MAGIC)
}

/// Reads only the brdfpack header of an EXR (for `inspect` and the reader).
pub fn read_header(bytes: &[u8], path: &Path) -> Result<ExrHeader> {
    let bad = |m: String| Error::invalid_file(path, m);
    if !is_exr(bytes) {
        return Err(bad("not an OpenEXR file (wrong magic)".into()));
    }
    let meta = exr::meta::MetaData::read_from_buffered(Cursor::new(bytes), false)
        .map_err(|e| bad(format!("EXR header: {e}")))?;
    if meta.headers.len() != 1 {
        return Err(bad(format!(
            "{} parts; a brdfpack EXR has exactly one",
            meta.headers.len()
        )));
    }
    let h = &meta.headers[0];
    if h.deep {
        return Err(bad("deep EXR data is not a brdfpack table".into()));
    }
    let key = text("attribute", ATTRIBUTE)?;
    let attr = h
        .own_attributes
        .other
        .get(&key)
        .or_else(|| h.shared_attributes.other.get(&key))
        .ok_or_else(|| {
            bad(format!(
                "no `{ATTRIBUTE}` attribute: not a brdfpack table (other EXR images cannot be \
                 read as BRDF tables)"
            ))
        })?;
    let AttributeValue::Text(t) = attr else {
        return Err(bad(format!("attribute `{ATTRIBUTE}` is not text")));
    };
    crate::text::reject_duplicate_json_keys(t.as_slice())
        .map_err(|e| bad(format!("attribute `{ATTRIBUTE}` JSON: {e}")))?;
    let header: ExrHeader = serde_json::from_slice(t.as_slice())
        .map_err(|e| bad(format!("attribute `{ATTRIBUTE}` JSON: {e}")))?;
    if header.format != "brdfpack-exr" || header.version != 1 {
        return Err(bad(format!(
            "attribute `{ATTRIBUTE}`: format {:?} version {}, expected \"brdfpack-exr\" version 1",
            header.format, header.version
        )));
    }
    // Checked against the pixels in `from_bytes`; here only what `inspect` needs.
    let grid = Grid::from_desc(&header.grid).map_err(|e| bad(e.to_string()))?;
    let width = *grid.shape().last().expect("grids have axes");
    let want = Vec2(width, grid.cells() / width);
    if h.layer_size != want {
        return Err(bad(format!(
            "image is {}×{} but grid {} needs {}×{}",
            h.layer_size.0,
            h.layer_size.1,
            grid.describe(),
            want.0,
            want.1
        )));
    }
    let decoded = grid.cells() as u128 * h.channels.list.len() as u128 * 4;
    if decoded > MAX_EXPANSION * bytes.len() as u128 {
        return Err(bad(format!(
            "header claims {decoded} bytes of pixels in a {}-byte file (corrupt?)",
            bytes.len()
        )));
    }
    Ok(header)
}

/// Decodes a brdfpack EXR into a table.
pub fn from_bytes(bytes: &[u8], path: &Path) -> Result<Table> {
    let bad = |m: String| Error::invalid_file(path, m);
    let header = read_header(bytes, path)?;
    let grid = Grid::from_desc(&header.grid).map_err(|e| bad(e.to_string()))?;
    let channels = Channels::named(
        header.channels.names().to_vec(),
        header.channels.wavelengths_nm().map(|w| w.to_vec()),
    )
    .map_err(|e| bad(e.to_string()))?;
    if channels.len() > crate::io::native::MAX_CHANNELS {
        return Err(bad(format!("{} channels exceed the limit", channels.len())));
    }
    // Before the exr crate decodes anything: every pixel channel of the file in memory,
    // then the table (and its exact values) built from them.
    let file_channels = 1 + channels.len() * if header.exact.is_some() { 3 } else { 1 };
    crate::memory::require(
        &format!(
            "the EXR pixels of {} with {file_channels} channel(s)",
            grid.describe()
        ),
        (grid.cells() as u64)
            .saturating_mul(file_channels as u64 * 4)
            .saturating_add(crate::memory::table_bytes(grid.cells(), channels.len()))
            .saturating_add(if header.exact.is_some() {
                (grid.cells() as u64).saturating_mul(channels.len() as u64 * 8)
            } else {
                0
            }),
    )
    .map_err(|e| bad(e.to_string()))?;
    let image = read()
        .no_deep_data()
        .largest_resolution_level()
        .all_channels()
        .first_valid_layer()
        .all_attributes()
        .from_buffered(Cursor::new(bytes))
        .map_err(|e| bad(format!("EXR pixels: {e}")))?;
    let list = &image.layer_data.channel_data.list;
    let find = |name: &str| -> Result<&FlatSamples> {
        list.iter()
            .find(|c| c.name.as_slice() == name.as_bytes())
            .map(|c| &c.sample_data)
            .ok_or_else(|| bad(format!("channel `{name}` is missing")))
    };
    let cells = grid.cells();
    let nch = channels.len();
    let expected_channels = 1 + nch * if header.exact.is_some() { 3 } else { 1 };
    if list.len() != expected_channels {
        let names: Vec<String> = list.iter().map(|c| c.name.to_string()).collect();
        return Err(bad(format!(
            "channels {names:?}: expected {expected_channels} (brdf.* for {:?}, valid{})",
            channels.names(),
            if header.exact.is_some() {
                ", f64hi.*, f64lo.*"
            } else {
                ""
            }
        )));
    }
    let valid: Vec<bool> = match find("valid")? {
        FlatSamples::F16(v) => v
            .iter()
            .enumerate()
            .map(|(i, x)| match x.to_f32() {
                1.0 => Ok(true),
                0.0 => Ok(false),
                other => Err(bad(format!(
                    "channel `valid` holds {other} at cell {i}; expected 0 or 1"
                ))),
            })
            .collect::<Result<_>>()?,
        _ => return Err(bad("channel `valid` is not f16".into())),
    };
    // stored = value × 2^k  ⇒  value = stored × 2^−k (exact: a power of two).
    if !(-1000..=1000).contains(&header.value_scale_log2) {
        return Err(bad(format!(
            "value_scale_log2 = {} is out of range",
            header.value_scale_log2
        )));
    }
    let unscale = 2f64.powi(-header.value_scale_log2);
    let mut data = vec![0f32; cells * nch];
    for (k, name) in channels.names().iter().enumerate() {
        let cname = value_channel(name);
        let samples = find(&cname)?;
        let mut put = |cell: usize, v: f64| data[cell * nch + k] = v as f32;
        match (header.sample_type, samples) {
            (ExrSampleType::F32, FlatSamples::F32(v)) => {
                for (cell, &x) in v.iter().enumerate() {
                    put(cell, x as f64 * unscale);
                }
            }
            (ExrSampleType::F16, FlatSamples::F16(v)) => {
                for (cell, &x) in v.iter().enumerate() {
                    put(cell, x.to_f64() * unscale);
                }
            }
            _ => {
                return Err(bad(format!(
                    "channel `{cname}` is not {:?} as the header says",
                    header.sample_type
                )));
            }
        }
    }
    for (cell, &ok) in valid.iter().enumerate() {
        if let Some(x) = data[cell * nch..(cell + 1) * nch]
            .iter()
            .find(|x| ok && !x.is_finite())
        {
            return Err(bad(format!(
                "cell {cell} (pixel x = {}, y = {}) holds the non-finite value {x}",
                cell % grid.shape().last().copied().unwrap_or(1),
                cell / grid.shape().last().copied().unwrap_or(1)
            )));
        }
    }
    let table = Table::new(grid, channels.clone(), header.provenance, data, valid)
        .map_err(|e| bad(e.to_string()))?;
    let Some(desc) = header.exact else {
        return Ok(table);
    };
    let scale = desc.scale().map_err(|e| bad(e.to_string()))?;
    let mut raw = vec![0f64; cells * nch];
    for (k, name) in channels.names().iter().enumerate() {
        let (FlatSamples::U32(hi), FlatSamples::U32(lo)) = (
            find(&format!("f64hi.{name}"))?,
            find(&format!("f64lo.{name}"))?,
        ) else {
            return Err(bad(format!(
                "channels f64hi.{name} / f64lo.{name} are not u32"
            )));
        };
        for cell in 0..cells {
            raw[cell * nch + k] = f64::from_bits((hi[cell] as u64) << 32 | lo[cell] as u64);
        }
    }
    table
        .with_exact(ExactValues { scale, raw })
        .map_err(|e| bad(e.to_string()))
}
