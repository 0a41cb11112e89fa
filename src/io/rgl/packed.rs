//! An RGL `.bsdf` packed in its own parameterization inside the native container (issue #19;
//! docs/format.md, "RGL files packed in their own parameterization"): the kind
//! `brdfpack-rgl` of a `.bpk`. Read back it is the RGL file again, evaluated by the same code
//! ([`super::RglBsdf`]), so the only error is the colour coding's.
//!
//! Sections `HEAD` (JSON [`PackedHeader`]), `DATA`, `END `. `DATA` is the stored fields — every
//! field of the file except the colour tensor and the fields rebuilt from the others — as a
//! tensor file (the `.bsdf` container itself) through zstd, `stored_bytes` long, then the
//! colour tensor's payload ([`TensorCoding`]). Rebuilt fields: the VNDF from the `ndf` and
//! the slices' angles ([`derived_vndf`]) when the header says `derived`, the luminance from
//! `rgb` ([`luminance_of`]) when it says `derived`.

use super::fields::{RawField, RglFields, derived_vndf, luminance_of, projected_area};
use crate::codec::tensor::TensorCoding;
use crate::io::native::{self, MAX_HEADER, VERSION_MINOR};
use crate::table::Provenance;
use crate::{Error, Result};
use serde::{Deserialize, Serialize};
use std::borrow::Cow;
use std::path::Path;

/// The header's `format` of this kind.
pub const FORMAT: &str = "brdfpack-rgl";
/// zstd level of the stored fields (a few KB: the level costs nothing).
const STORED_LEVEL: i32 = 19;

/// The fields of the RGL database's RGB files, in their order.
pub const RGL_ORDER: [&str; 11] = [
    "version",
    "description",
    "phi_i",
    "theta_i",
    "sigma",
    "ndf",
    "vndf",
    "luminance",
    "rgb",
    "jacobian",
    "valid",
];

fn rgl_order() -> Vec<String> {
    RGL_ORDER.iter().map(|s| s.to_string()).collect()
}

fn is_rgl_order(fields: &[String]) -> bool {
    fields.iter().map(String::as_str).eq(RGL_ORDER)
}

/// Whether a field is in the file or rebuilt from the others when read.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum FieldForm {
    /// Among the stored fields, exactly.
    Stored,
    /// Rebuilt by the reader (module doc).
    Derived,
    /// Coded lossily by `vndf_coding` (the VNDF alone), its payload after the colour's.
    Coded,
}

/// The colour tensor: its field name (`rgb` or `spectra`), shape `[Nφ, Nθ, C, n, n]` and coding.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ColourDesc {
    pub name: String,
    pub shape: Vec<usize>,
    pub coding: TensorCoding,
}

/// The JSON header of a packed RGL file.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PackedHeader {
    /// Always [`FORMAT`].
    pub format: String,
    pub provenance: Provenance,
    /// The RGL file's field names, in its order (the order a rebuilt `.bsdf` has); absent
    /// when it is [`RGL_ORDER`], the order of the RGL database's files.
    #[serde(default = "rgl_order", skip_serializing_if = "is_rgl_order")]
    pub fields: Vec<String>,
    pub colour: ColourDesc,
    /// The `vndf` field: stored, derived or coded, the latter two with this shape
    /// `[Nφ, Nθ, H, W]`.
    pub vndf: FieldForm,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub vndf_shape: Option<Vec<usize>>,
    /// The coding of a coded VNDF (one channel; values clamped at 0 when read: a density).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub vndf_coding: Option<TensorCoding>,
    /// Bytes of the colour payload when a coded VNDF's follows it.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub colour_bytes: Option<usize>,
    /// The `luminance` field (when the file has one): stored or derived from `rgb`.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub luminance: Option<FieldForm>,
    /// The `sigma` field, when derived from the NDF: its shape `[rows, cols]` and the constant
    /// its projected area is multiplied by ([`derived_sigma`]); stored when absent.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub sigma: Option<DerivedSigma>,
    /// Bytes of the stored fields' zstd block at the start of `DATA`, and decompressed.
    pub stored_bytes: usize,
    pub stored_raw_bytes: usize,
}

/// A `sigma` field the reader derives: [`projected_area`] of the NDF on a grid of `shape`,
/// times `scale`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct DerivedSigma {
    pub shape: Vec<usize>,
    pub scale: f64,
}

/// What a packed file holds of the VNDF.
#[derive(Clone, Debug, PartialEq)]
pub enum VndfPacking {
    /// Its values, exactly.
    Stored,
    /// Nothing: the reader derives it from the NDF.
    Derived,
    /// Its values coded lossily.
    Coded(TensorCoding),
}

impl VndfPacking {
    /// `stored`, `derived` or `coded` (reports).
    pub fn name(&self) -> &'static str {
        match self {
            VndfPacking::Stored => "stored",
            VndfPacking::Derived => "derived",
            VndfPacking::Coded(_) => "coded",
        }
    }
}

/// How to pack: the colour coding and which fields to leave out.
#[derive(Clone, Debug, PartialEq)]
pub struct PackOptions {
    pub coding: TensorCoding,
    pub vndf: VndfPacking,
    /// Leave the luminance out (the reader derives it from `rgb`).
    pub derive_luminance: bool,
    /// Leave `sigma` out: the reader derives it from the NDF times this constant
    /// ([`sigma_scale`]).
    pub derive_sigma: Option<f64>,
}

impl PackOptions {
    /// Everything stored, the colour tensor lossless: the file read back is the source's
    /// fields bit for bit.
    pub fn lossless() -> PackOptions {
        PackOptions {
            coding: TensorCoding::Lossless,
            vndf: VndfPacking::Stored,
            derive_luminance: false,
            derive_sigma: None,
        }
    }
}

/// The VNDF of a coded payload, as the reader has it: decoded, clamped at 0 (a density; the
/// curve's inverse can return a hair below 0 next to a zero node).
pub fn decode_vndf(coding: &TensorCoding, payload: &[u8], dims: &[usize]) -> Result<Vec<f32>> {
    let mut v = coding.decode(payload, dims, 1)?;
    clamp_vndf(&mut v);
    Ok(v)
}

/// A decoded VNDF as its reader holds it: a density, clamped at 0 (the signed log curve's
/// inverse can dip below 0 next to a node of 0).
pub fn clamp_vndf(v: &mut [f32]) {
    v.iter_mut().for_each(|x| *x = x.max(0.0));
}

/// The coded axes of a VNDF `[Nφ, Nθ, H, W]` as a one-channel tensor (as [`colour_dims`]).
pub fn vndf_dims(shape: &[usize]) -> Option<Vec<usize>> {
    match *shape {
        [p, t, h, w] => colour_dims(&[p, t, 1, h, w]).map(|(d, _)| d),
        _ => None,
    }
}

/// The colour field of an RGL file: `spectra` when it has `wavelengths` (Mitsuba's rule),
/// else `rgb`.
pub fn colour_name(fields: &RglFields) -> &'static str {
    if fields.get("wavelengths").is_some() {
        "spectra"
    } else {
        "rgb"
    }
}

/// The coded axes and channel count of a colour tensor `[Nφ, Nθ, C, ny, nx]`: `[Nθ, ny, nx]`
/// for one φi slice, `[Nφ, Nθ, ny, nx]` otherwise.
pub fn colour_dims(shape: &[usize]) -> Option<(Vec<usize>, usize)> {
    match *shape {
        [p, t, c, ny, nx] if p >= 1 && t >= 1 && c >= 1 && ny >= 1 && nx >= 1 => Some((
            if p == 1 {
                vec![t, ny, nx]
            } else {
                vec![p, t, ny, nx]
            },
            c,
        )),
        _ => None,
    }
}

/// The fields with the VNDF replaced by its derivation from their NDF ([`derived_vndf`]):
/// what a reader of a file packed with `derive_vndf` evaluates.
pub fn with_derived_vndf(fields: &RglFields, what: &str) -> Result<RglFields> {
    let shape = fields.require("vndf", what)?.shape.clone();
    let vndf = derive(fields, &shape, what)?;
    let mut out = fields.clone();
    out.put(RawField::f32("vndf", shape, &vndf), usize::MAX);
    Ok(out)
}

/// The VNDF of `shape` `[Nφ, Nθ, H, W]` derived from the fields' `phi_i`, `theta_i`, `ndf`.
fn derive(fields: &RglFields, shape: &[usize], what: &str) -> Result<Vec<f32>> {
    let bad = |m: String| Error::invalid_file(what, m);
    let phi_i = fields.f32_of("phi_i", what)?;
    let theta_i = fields.f32_of("theta_i", what)?;
    let ndf_field = fields.require("ndf", what)?;
    let ndf = fields.f32_of("ndf", what)?;
    let [rows, cols] = match ndf_field.shape[..] {
        [r, c] if r >= 2 && c >= 2 => [r, c],
        _ => {
            return Err(bad(format!(
                "field `ndf`: shape {:?}, expected [rows ≥ 2, columns ≥ 2]",
                ndf_field.shape
            )));
        }
    };
    let [h, w] = match *shape {
        [p, t, h, w] if p == phi_i.len() && t == theta_i.len() && h >= 2 && w >= 2 => [h, w],
        _ => {
            return Err(bad(format!(
                "derived `vndf` shape {shape:?} does not match [phi_i, theta_i, ≥2, ≥2] = [{}, {}, ..]",
                phi_i.len(),
                theta_i.len()
            )));
        }
    };
    if let Some(v) = phi_i
        .iter()
        .chain(&theta_i)
        .chain(&ndf)
        .find(|v| !v.is_finite())
    {
        return Err(bad(format!(
            "a value {v} of `phi_i`, `theta_i` or `ndf` is not finite"
        )));
    }
    // The shape is the header's word alone (no stored byte bounds it): its product is checked
    // (`h * w` wrapped to 0 for H = W = 2^32, passed the budget, and the loop below ran until
    // memory ran out), capped at an RGL file's VNDF, and counted with the reader's copies.
    let cells = [phi_i.len(), theta_i.len(), h, w]
        .iter()
        .try_fold(1u64, |a, &d| a.checked_mul(d as u64))
        .filter(|&n| n <= super::MAX_FILE_BYTES / 4)
        .ok_or_else(|| {
            bad(format!(
                "derived `vndf` shape {shape:?} is larger than any RGL file's VNDF"
            ))
        })?;
    crate::memory::require(
        "the derived `vndf`",
        cells.saturating_mul(VNDF_READ_BYTES_PER_VALUE),
    )
    .map_err(|e| bad(e.to_string()))?;
    Ok(derived_vndf(&phi_i, &theta_i, &ndf, [rows, cols], h, w))
}

/// Bytes a rebuilt VNDF value costs the reader at its peak: the f32 value, its field's bytes,
/// the tensor file [`super::RglBsdf::from_fields`] makes of the fields, the validated copy
/// and the warp's tables (measured: 21.5 bytes a value for a derived VNDF of 2^26 and 2^28
/// values; 4 bytes were counted, so a 2 KB file declaring 2^28 values took 5.8 GB).
const VNDF_READ_BYTES_PER_VALUE: u64 = 24;

/// Bytes a colour value costs the reader at its peak: the decoded f32 values and the coder's
/// planes, the field's bytes, a derived `luminance` (a third of a value), the tensor file
/// [`super::RglBsdf::from_fields`] makes of the fields and the validated copies. Measured
/// (peak RSS of `inspect` over packed files of zeros, `[1, 4, 3, N, N]` for N = 1024, 1448,
/// 2048): 18.9 bytes a value; 16 were counted, so `[1, 4, 3, 2048, 2048]` (a 9 KB file) took
/// 915 MiB for 768 MiB counted.
const COLOUR_READ_BYTES_PER_VALUE: u64 = 20;

/// Largest relative deviation between a file's `sigma` and its NDF's projected area times
/// one constant for which `sigma` is left for the reader to derive. The four public files
/// deviate by at most 1.5e-4; the planner also measures the derived form against the source.
pub const SIGMA_TOLERANCE: f64 = 1e-3;

/// The constant c with `sigma` = c × [`projected_area`] of the NDF at every node within
/// [`SIGMA_TOLERANCE`] (c: the geometric mean of the ratios), or `None`: an anisotropic NDF,
/// or a `sigma` made another way.
pub fn sigma_scale(fields: &RglFields, what: &str) -> Result<Option<f64>> {
    let Some(sigma) = fields.get("sigma") else {
        return Ok(None);
    };
    if fields.get("ndf").is_none() || sigma.shape.len() != 2 {
        return Ok(None);
    }
    let Some(d) = sigma_of(fields, &sigma.shape, 1.0, what)? else {
        return Ok(None);
    };
    let s = fields.f32_of("sigma", what)?;
    if s.len() != d.len()
        || !s.iter().all(|v| v.is_finite() && *v > 0.0)
        || !d.iter().all(|v| v.is_finite() && *v > 0.0)
    {
        return Ok(None);
    }
    let c = (s
        .iter()
        .zip(&d)
        .map(|(&s, &d)| (f64::from(s) / d).ln())
        .sum::<f64>()
        / s.len() as f64)
        .exp();
    let fits = s
        .iter()
        .zip(&d)
        .all(|(&s, &d)| (c * d / f64::from(s) - 1.0).abs() <= SIGMA_TOLERANCE);
    Ok(fits.then_some(c))
}

/// The projected area of the fields' NDF on a `sigma` grid of `shape`, times `scale`: `None`
/// unless the NDF is isotropic and `shape` is its own `[rows, cols]` with 2 ≤ cols ≤
/// [`MAX_DERIVED_SIGMA_COLUMNS`] (the measured files' shape; a larger grid is refused rather
/// than integrated: the work grows as cols², and a header could ask for any shape).
fn sigma_of(
    fields: &RglFields,
    shape: &[usize],
    scale: f64,
    what: &str,
) -> Result<Option<Vec<f64>>> {
    let ndf_field = fields.require("ndf", what)?;
    let [rows, cols] = match (&ndf_field.shape[..], shape) {
        (&[r, c], &[sr, sc])
            if r == sr && c == sc && r >= 1 && (2..=MAX_DERIVED_SIGMA_COLUMNS).contains(&c) =>
        {
            [r, c]
        }
        _ => return Ok(None),
    };
    let ndf = fields.f32_of("ndf", what)?;
    if let Some(v) = ndf.iter().find(|v| !v.is_finite()) {
        return Err(Error::invalid_file(
            what,
            format!("a value {v} of `ndf` is not finite"),
        ));
    }
    Ok(projected_area(&ndf, [rows, cols], [rows, cols])
        .map(|d| d.into_iter().map(|v| v * scale).collect()))
}

/// Widest NDF whose `sigma` is derived ([`sigma_of`]): the RGL database's files have 128
/// columns.
pub const MAX_DERIVED_SIGMA_COLUMNS: usize = 4096;

/// The fields with `sigma` replaced by its derivation from their NDF times `scale`: what a
/// reader of a file packed with `derive_sigma` evaluates.
pub fn with_derived_sigma(fields: &RglFields, scale: f64, what: &str) -> Result<RglFields> {
    let shape = fields.require("sigma", what)?.shape.clone();
    let v = derived_sigma(fields, &shape, scale, what)?;
    let mut out = fields.clone();
    out.put(RawField::f32("sigma", shape, &v), usize::MAX);
    Ok(out)
}

/// The derived `sigma` of `shape`, in f32 (as stored).
fn derived_sigma(fields: &RglFields, shape: &[usize], scale: f64, what: &str) -> Result<Vec<f32>> {
    let v = sigma_of(fields, shape, scale, what)?.ok_or_else(|| {
        Error::invalid_file(
            what,
            format!(
                "`sigma` of shape {shape:?} is derived, but the NDF is not isotropic, not of that \
                 shape, or wider than {MAX_DERIVED_SIGMA_COLUMNS} columns"
            ),
        )
    })?;
    Ok(v.into_iter().map(|x| x as f32).collect())
}

/// The packed file of `fields` (an RGL file's, validated by its reader).
pub fn to_bytes(
    fields: &RglFields,
    opts: &PackOptions,
    provenance: &Provenance,
) -> Result<Vec<u8>> {
    let what = "the RGL source";
    let colour_name = colour_name(fields);
    let colour = fields.require(colour_name, what)?;
    let (dims, channels) = colour_dims(&colour.shape).ok_or_else(|| {
        Error::input(format!(
            "field `{colour_name}`: shape {:?}, expected [phi_i, theta_i, channels, n, n]",
            colour.shape
        ))
    })?;
    let values = fields.f32_of(colour_name, what)?;
    let payload = opts.coding.encode(&values, &dims, channels)?;
    let derive_luminance = opts.derive_luminance
        && colour_name == "rgb"
        && channels == 3
        && fields.get("luminance").is_some();
    let mut stored = fields.clone();
    stored.take(colour_name);
    let mut vndf_payload = None;
    let vndf_shape = match &opts.vndf {
        VndfPacking::Stored => None,
        VndfPacking::Derived => stored.take("vndf").map(|(_, f)| f.shape),
        VndfPacking::Coded(coding) => {
            let v = fields.f32_of("vndf", what)?;
            let shape = stored
                .take("vndf")
                .map(|(_, f)| f.shape)
                .unwrap_or_default();
            let dims = vndf_dims(&shape).ok_or_else(|| {
                Error::input(format!(
                    "field `vndf`: shape {shape:?}, expected [phi_i, theta_i, H, W]"
                ))
            })?;
            vndf_payload = Some(coding.encode(&v, &dims, 1)?);
            Some(shape)
        }
    };
    if derive_luminance {
        stored.take("luminance");
    }
    let sigma = match opts.derive_sigma {
        Some(scale) => stored.take("sigma").map(|(_, f)| DerivedSigma {
            shape: f.shape,
            scale,
        }),
        None => None,
    };
    let raw = stored.to_tensor_bytes();
    let z = zstd::bulk::compress(&raw, STORED_LEVEL)
        .map_err(|e| Error::Failure(format!("zstd compression failed: {e}")))?;
    let header = PackedHeader {
        format: FORMAT.to_string(),
        provenance: provenance.clone(),
        fields: fields.fields.iter().map(|f| f.name.clone()).collect(),
        colour: ColourDesc {
            name: colour_name.to_string(),
            shape: colour.shape.clone(),
            coding: opts.coding.clone(),
        },
        vndf: match opts.vndf {
            VndfPacking::Stored => FieldForm::Stored,
            VndfPacking::Derived => FieldForm::Derived,
            VndfPacking::Coded(_) => FieldForm::Coded,
        },
        vndf_shape,
        vndf_coding: match &opts.vndf {
            VndfPacking::Coded(c) => Some(c.clone()),
            _ => None,
        },
        colour_bytes: vndf_payload.as_ref().map(|_| payload.len()),
        luminance: fields.get("luminance").map(|_| {
            if derive_luminance {
                FieldForm::Derived
            } else {
                FieldForm::Stored
            }
        }),
        sigma,
        stored_bytes: z.len(),
        stored_raw_bytes: raw.len(),
    };
    let head = serde_json::to_vec(&header)
        .map_err(|e| Error::Failure(format!("header serialization: {e}")))?;
    let head = native::head_section(head)?;
    let mut data = z;
    data.extend_from_slice(&payload);
    if let Some(v) = &vndf_payload {
        data.extend_from_slice(v);
    }
    Ok(native::container(
        native::minor_for_head(head.0, VERSION_MINOR),
        &[
            head,
            (*b"DATA", Cow::from(data)),
            (*b"END ", Cow::Borrowed(&[])),
        ],
    ))
}

/// True when `bytes` are a native file of this kind.
pub fn is_packed_rgl(bytes: &[u8]) -> bool {
    native::is_native(bytes) && native::kind_of(bytes).as_deref() == Some(FORMAT)
}

/// Only the header of a packed file (for `inspect`).
pub fn read_header(bytes: &[u8], path: &Path) -> Result<PackedHeader> {
    let secs = native::sections(bytes, path)?;
    parse_header(&native::header_json(&secs, path)?, path)
}

fn parse_header(head: &[u8], path: &Path) -> Result<PackedHeader> {
    let bad = |m: String| Error::invalid_file(path, m);
    if head.len() as u64 > MAX_HEADER {
        return Err(bad("header larger than 16 MiB".into()));
    }
    crate::text::reject_duplicate_json_keys(head).map_err(|e| bad(format!("header JSON: {e}")))?;
    let h: PackedHeader =
        serde_json::from_slice(head).map_err(|e| bad(format!("header JSON: {e}")))?;
    if h.format != FORMAT {
        return Err(bad(format!(
            "header field `format` = {:?}, expected {FORMAT:?}",
            h.format
        )));
    }
    Ok(h)
}

/// The RGL file's fields from a packed file (in the file's order, rebuilt fields included).
/// Errors name the file and the field or section at fault; the fields are not yet validated
/// as an RGL BSDF ([`super::RglBsdf::from_bytes`] does that).
pub fn from_bytes(bytes: &[u8], path: &Path) -> Result<(PackedHeader, RglFields)> {
    let secs = native::sections(bytes, path)?;
    if secs.len() != 3 {
        return Err(Error::invalid_file(
            path,
            format!(
                "{} sections, expected HEAD (or HEAZ), DATA, END for a {FORMAT} file",
                secs.len()
            ),
        ));
    }
    let h = parse_header(&native::header_json(&secs, path)?, path)?;
    let bad = |m: String| Error::invalid_file(path, m);
    let what = path.display().to_string();
    let data = secs[1].1;
    if h.stored_bytes > data.len() {
        return Err(bad(format!(
            "header field `stored_bytes` = {} exceeds the DATA section's {} bytes",
            h.stored_bytes,
            data.len()
        )));
    }
    // Capped before the decompression allocates it: the stored fields of an RGL file are at
    // most its size, which the RGL reader caps.
    if h.stored_raw_bytes as u64 > super::MAX_FILE_BYTES {
        return Err(bad(format!(
            "header field `stored_raw_bytes` = {} exceeds the {}-byte limit of an RGL file",
            h.stored_raw_bytes,
            super::MAX_FILE_BYTES
        )));
    }
    crate::memory::require(
        "the packed RGL file's stored fields",
        h.stored_raw_bytes as u64,
    )
    .map_err(|e| bad(e.to_string()))?;
    let raw = zstd::bulk::decompress(&data[..h.stored_bytes], h.stored_raw_bytes)
        .map_err(|e| bad(format!("DATA section, stored fields: {e}")))?;
    if raw.len() != h.stored_raw_bytes {
        return Err(bad(format!(
            "DATA section: the stored fields hold {} bytes, the header says {}",
            raw.len(),
            h.stored_raw_bytes
        )));
    }
    let stored = RglFields::parse(&raw, &format!("{what} (stored fields)"))?;
    // The colour tensor.
    let (dims, channels) = colour_dims(&h.colour.shape).ok_or_else(|| {
        bad(format!(
            "header field `colour.shape` = {:?}, expected [phi_i, theta_i, channels, n, n] (all ≥ 1)",
            h.colour.shape
        ))
    })?;
    let values = h
        .colour
        .shape
        .iter()
        .try_fold(1u64, |a, &d| a.checked_mul(d as u64))
        .filter(|&n| n <= super::MAX_FILE_BYTES / 4)
        .ok_or_else(|| {
            bad(format!(
                "header field `colour.shape` = {:?} is larger than any RGL file",
                h.colour.shape
            ))
        })?;
    crate::memory::require(
        "the packed RGL colour tensor",
        values.saturating_mul(COLOUR_READ_BYTES_PER_VALUE),
    )
    .map_err(|e| bad(e.to_string()))?;
    let rest = &data[h.stored_bytes..];
    let (colour_payload, vndf_payload) = match h.colour_bytes {
        Some(n) if n <= rest.len() => rest.split_at(n),
        Some(n) => {
            return Err(bad(format!(
                "header field `colour_bytes` = {n} exceeds the {} bytes after the stored fields",
                rest.len()
            )));
        }
        None => (rest, &[][..]),
    };
    let colour = h
        .colour
        .coding
        .decode(colour_payload, &dims, channels)
        .map_err(|e| bad(format!("field `{}`: {e}", h.colour.name)))?;
    // A coded VNDF: one channel, clamped at 0 (a density; the curve's inverse can return a
    // value a hair below 0 next to a zero node).
    let coded_vndf = match (h.vndf, &h.vndf_coding, &h.vndf_shape) {
        (FieldForm::Coded, Some(coding), Some(shape)) => {
            let dims = vndf_dims(shape)
                .filter(|d| {
                    d.iter()
                        .try_fold(1u64, |a, &x| a.checked_mul(x as u64))
                        .is_some_and(|n| n <= super::MAX_FILE_BYTES / 4)
                })
                .ok_or_else(|| {
                    bad(format!(
                        "header field `vndf_shape` = {shape:?}: expected [phi_i, theta_i, H, W] \
                         within an RGL file's size"
                    ))
                })?;
            let n: usize = dims.iter().product();
            crate::memory::require(
                "the packed RGL VNDF",
                (n as u64).saturating_mul(VNDF_READ_BYTES_PER_VALUE),
            )
            .map_err(|e| bad(e.to_string()))?;
            let v = decode_vndf(coding, vndf_payload, &dims)
                .map_err(|e| bad(format!("field `vndf`: {e}")))?;
            Some(RawField::f32("vndf", shape.clone(), &v))
        }
        (FieldForm::Coded, _, _) => {
            return Err(bad(
                "header says `vndf` coded but gives no `vndf_coding` or `vndf_shape`".into(),
            ));
        }
        _ if !vndf_payload.is_empty() => {
            return Err(bad(format!(
                "{} bytes follow the colour payload, but the VNDF is not coded",
                vndf_payload.len()
            )));
        }
        _ => None,
    };
    // Every field from exactly one place, in the file's order.
    let mut out = Vec::with_capacity(h.fields.len());
    for (k, name) in h.fields.iter().enumerate() {
        if h.fields[..k].contains(name) {
            return Err(bad(format!(
                "header field `fields`: `{name}` is listed twice"
            )));
        }
        let from_stored = stored.get(name);
        let rebuilt = if *name == h.colour.name {
            Some(RawField::f32(name, h.colour.shape.clone(), &colour))
        } else if name == "vndf" && h.vndf == FieldForm::Coded {
            coded_vndf.clone()
        } else if name == "vndf" && h.vndf == FieldForm::Derived {
            let shape = h.vndf_shape.clone().ok_or_else(|| {
                bad("header says `vndf` derived but gives no `vndf_shape`".into())
            })?;
            let v = derive(&stored, &shape, &what)?;
            Some(RawField::f32(name, shape, &v))
        } else if let (true, Some(d)) = (name == "sigma", &h.sigma) {
            let scale = crate::model::params::fmt_num(d.scale);
            if !d.scale.is_finite() || d.scale <= 0.0 {
                return Err(bad(format!(
                    "header field `sigma.scale` = {scale} is not a positive number"
                )));
            }
            let v = derived_sigma(&stored, &d.shape, d.scale, &what)?;
            // The scale is the header's word: one that takes the NDF's projected area out of
            // f32's positive range makes every value 0 (or inf), which the RGL reader then
            // reported as "field `sigma`: value #0 is 0e0" without naming the scale.
            if let Some((i, x)) = v
                .iter()
                .enumerate()
                .find(|(_, x)| !(x.is_finite() && **x > 0.0))
            {
                return Err(bad(format!(
                    "header field `sigma.scale` = {scale} makes the derived `sigma` value #{i} \
                     {x:e} in f32 (the NDF's projected area times the scale); expected a \
                     scale that keeps it finite and > 0"
                )));
            }
            Some(RawField::f32(name, d.shape.clone(), &v))
        } else if name == "luminance" && h.luminance == Some(FieldForm::Derived) {
            if h.colour.name != "rgb" || channels != 3 {
                return Err(bad(
                    "header says `luminance` derived, but the colour tensor is not rgb".into(),
                ));
            }
            let [p, t, _, ny, nx] = h.colour.shape[..] else {
                unreachable!("colour_dims checked five axes")
            };
            let l = luminance_of(&colour, p * t, ny * nx);
            Some(RawField::f32(name, vec![p, t, ny, nx], &l))
        } else {
            None
        };
        match (from_stored, rebuilt) {
            (Some(_), Some(_)) => {
                return Err(bad(format!("field `{name}` is both stored and rebuilt")));
            }
            (None, None) => {
                return Err(bad(format!(
                    "field `{name}` is listed but neither stored nor rebuilt"
                )));
            }
            (Some(f), None) => out.push(f.clone()),
            (None, Some(f)) => out.push(f),
        }
    }
    if let Some(f) = stored.fields.iter().find(|f| !h.fields.contains(&f.name)) {
        return Err(bad(format!(
            "stored field `{}` is not listed in the header's `fields`",
            f.name
        )));
    }
    Ok((h, RglFields { fields: out }))
}
