//! Mitsuba's "tensor file" container (`.bsdf` files of the RGL material database): a header,
//! a table of named fields (name, dtype, shape, absolute offset) and the raw data blocks.
//! Layout as in `spec/rgl-evaluation.md`, "The `.bsdf` container"; little-endian throughout.
//!
//! The parser assumes hostile input: every length and offset is checked against the file
//! size before it is used, and nothing is allocated that the file could not fill.

use crate::{Error, Result};

/// The 12 magic bytes a tensor file starts with.
pub const MAGIC: &[u8; 12] = b"tensor_file\0";
/// Magic (12) + major (1) + minor (1) + n_fields (4).
pub const HEADER_LEN: usize = 18;
/// The smallest possible field record: name_len (2), empty name, ndim (2), dtype (1), offset (8).
const MIN_RECORD_LEN: usize = 13;
/// More dimensions than any RGL field has (5) with room to spare; a larger count is corrupt.
pub const MAX_NDIM: usize = 16;

/// Element type of a field (Mitsuba's `Struct::Type` codes 1..=11; 0 is "invalid").
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Dtype {
    U8,
    I8,
    U16,
    I16,
    U32,
    I32,
    U64,
    I64,
    F16,
    F32,
    F64,
}

impl Dtype {
    /// The type for a file's dtype code, `None` for 0 (invalid) and codes above 11.
    pub fn from_code(code: u8) -> Option<Dtype> {
        use Dtype::*;
        Some(match code {
            1 => U8,
            2 => I8,
            3 => U16,
            4 => I16,
            5 => U32,
            6 => I32,
            7 => U64,
            8 => I64,
            9 => F16,
            10 => F32,
            11 => F64,
            _ => return None,
        })
    }

    /// The code written in the file.
    pub fn code(self) -> u8 {
        self as u8 + 1
    }

    /// Size of one element in bytes.
    pub fn size(self) -> usize {
        use Dtype::*;
        match self {
            U8 | I8 => 1,
            U16 | I16 | F16 => 2,
            U32 | I32 | F32 => 4,
            U64 | I64 | F64 => 8,
        }
    }

    /// The conventional short name (`float32`, `uint8`, ...).
    pub fn name(self) -> &'static str {
        use Dtype::*;
        match self {
            U8 => "uint8",
            I8 => "int8",
            U16 => "uint16",
            I16 => "int16",
            U32 => "uint32",
            I32 => "int32",
            U64 => "uint64",
            I64 => "int64",
            F16 => "float16",
            F32 => "float32",
            F64 => "float64",
        }
    }
}

/// One entry of the field table. `offset..offset + byte_len` is known to lie inside the file.
#[derive(Clone, Debug, PartialEq)]
pub struct TensorField {
    pub name: String,
    pub dtype: Dtype,
    pub shape: Vec<usize>,
    offset: usize,
    byte_len: usize,
}

impl TensorField {
    /// Number of elements (product of the shape; 1 for a 0-dimensional field).
    pub fn len(&self) -> usize {
        self.byte_len / self.dtype.size()
    }
    pub fn is_empty(&self) -> bool {
        self.byte_len == 0
    }
    /// Absolute byte offset of the data.
    pub fn offset(&self) -> usize {
        self.offset
    }
}

/// A parsed tensor file borrowing its bytes.
#[derive(Debug)]
pub struct TensorFile<'a> {
    bytes: &'a [u8],
    name: String,
    fields: Vec<TensorField>,
}

/// A bounds-checked little-endian reader over the field table.
struct Cursor<'a> {
    bytes: &'a [u8],
    pos: usize,
}

impl Cursor<'_> {
    /// The next `n` bytes, or `None` when the file ends first.
    fn take(&mut self, n: usize) -> Option<&[u8]> {
        let end = self.pos.checked_add(n)?;
        let s = self.bytes.get(self.pos..end)?;
        self.pos = end;
        Some(s)
    }
    fn u16(&mut self) -> Option<u16> {
        self.take(2).map(|b| u16::from_le_bytes([b[0], b[1]]))
    }
    fn u8(&mut self) -> Option<u8> {
        self.take(1).map(|b| b[0])
    }
    fn u64(&mut self) -> Option<u64> {
        self.take(8)
            .map(|b| u64::from_le_bytes(b.try_into().expect("8 bytes")))
    }
}

impl<'a> TensorFile<'a> {
    /// Parses the header and field table of `bytes`; `name` (a path or label) is used in
    /// error messages. Every field's data range is checked to lie inside `bytes`.
    pub fn parse(bytes: &'a [u8], name: &str) -> Result<TensorFile<'a>> {
        let bad = |msg: String| Error::invalid_file(name, msg);
        if bytes.len() < HEADER_LEN {
            return Err(bad(format!(
                "file is {} bytes, shorter than the {HEADER_LEN}-byte tensor-file header",
                bytes.len()
            )));
        }
        if &bytes[..12] != MAGIC {
            return Err(bad(format!(
                "not a tensor file: starts with {:?}, expected \"tensor_file\\0\"",
                String::from_utf8_lossy(&bytes[..12])
            )));
        }
        let (major, minor) = (bytes[12], bytes[13]);
        // powitacq and Mitsuba's Python reader require exactly 1.0; so do we.
        if (major, minor) != (1, 0) {
            return Err(bad(format!(
                "tensor-file version {major}.{minor}, expected 1.0"
            )));
        }
        let n_fields = u32::from_le_bytes(bytes[14..18].try_into().expect("4 bytes")) as usize;
        // Cap before allocating: each record takes at least MIN_RECORD_LEN bytes.
        let room = (bytes.len() - HEADER_LEN) / MIN_RECORD_LEN;
        if n_fields > room {
            return Err(bad(format!(
                "header declares {n_fields} fields, but the file ({} bytes) has room for at most {room} field records",
                bytes.len()
            )));
        }
        let mut cur = Cursor {
            bytes,
            pos: HEADER_LEN,
        };
        let mut fields: Vec<TensorField> = Vec::with_capacity(n_fields);
        for index in 0..n_fields {
            let truncated = |what: &str, pos: usize| {
                bad(format!(
                    "field table truncated: record #{index} is cut inside its {what}, which starts at byte {pos} (file is {} bytes)",
                    bytes.len()
                ))
            };
            let name_len = cur.u16().ok_or_else(|| truncated("name length", cur.pos))? as usize;
            let start = cur.pos;
            let name_bytes = cur.take(name_len).ok_or_else(|| truncated("name", start))?;
            let field_name = std::str::from_utf8(name_bytes)
                .map_err(|_| bad(format!("field record #{index}: name is not valid UTF-8")))?
                .to_string();
            let ndim = cur.u16().ok_or_else(|| truncated("ndim", cur.pos))? as usize;
            if ndim > MAX_NDIM {
                return Err(bad(format!(
                    "field `{field_name}`: ndim = {ndim}, expected at most {MAX_NDIM}"
                )));
            }
            let code = cur.u8().ok_or_else(|| truncated("dtype", cur.pos))?;
            let dtype = Dtype::from_code(code).ok_or_else(|| {
                bad(format!(
                    "field `{field_name}`: dtype code {code} is not a known type (expected 1..=11)"
                ))
            })?;
            let offset = cur.u64().ok_or_else(|| truncated("offset", cur.pos))?;
            let mut shape = Vec::with_capacity(ndim);
            for _ in 0..ndim {
                let d = cur.u64().ok_or_else(|| truncated("shape", cur.pos))?;
                shape.push(d);
            }
            // Checked products: a hostile shape must not overflow into a small size.
            let byte_len = shape
                .iter()
                .try_fold(dtype.size() as u64, |acc, &d| acc.checked_mul(d))
                .filter(|&n| n <= bytes.len() as u64)
                .ok_or_else(|| {
                    bad(format!(
                        "field `{field_name}`: shape {shape:?} of {} needs more bytes than the whole file ({} bytes)",
                        dtype.name(),
                        bytes.len()
                    ))
                })?;
            let end = offset.checked_add(byte_len);
            if end.is_none_or(|e| e > bytes.len() as u64) {
                return Err(bad(format!(
                    "field `{field_name}`: data at offset {offset} with {byte_len} bytes runs past the end of the file ({} bytes)",
                    bytes.len()
                )));
            }
            if fields.iter().any(|f| f.name == field_name) {
                return Err(bad(format!("field `{field_name}` appears twice")));
            }
            fields.push(TensorField {
                name: field_name,
                dtype,
                // Each dimension is ≤ the file size (checked above), so it fits in usize.
                shape: shape.iter().map(|&d| d as usize).collect(),
                offset: offset as usize,
                byte_len: byte_len as usize,
            });
        }
        Ok(TensorFile {
            bytes,
            name: name.to_string(),
            fields,
        })
    }

    /// All fields in file order.
    pub fn fields(&self) -> &[TensorField] {
        &self.fields
    }

    /// The field called `name`, if present.
    pub fn get(&self, name: &str) -> Option<&TensorField> {
        self.fields.iter().find(|f| f.name == name)
    }

    /// The field called `name`, or an error naming the file and the field.
    pub fn require(&self, name: &str) -> Result<&TensorField> {
        self.get(name).ok_or_else(|| {
            Error::invalid_file(&self.name, format!("required field `{name}` is missing"))
        })
    }

    /// The raw data bytes of `field` (in range by construction).
    pub fn raw(&self, field: &TensorField) -> &'a [u8] {
        &self.bytes[field.offset..field.offset + field.byte_len]
    }

    /// An error about `field` in this file.
    pub fn field_error(&self, field: &str, msg: impl std::fmt::Display) -> Error {
        Error::invalid_file(&self.name, format!("field `{field}`: {msg}"))
    }

    /// The data of `field` as float32 values; errors unless its dtype is float32.
    pub fn f32_values(&self, field: &TensorField) -> Result<Vec<f32>> {
        self.expect_dtype(field, Dtype::F32)?;
        Ok(self
            .raw(field)
            .chunks_exact(4)
            .map(|b| f32::from_le_bytes(b.try_into().expect("4 bytes")))
            .collect())
    }

    /// The data of `field` as bytes; errors unless its dtype is uint8.
    pub fn u8_values(&self, field: &TensorField) -> Result<&'a [u8]> {
        self.expect_dtype(field, Dtype::U8)?;
        Ok(self.raw(field))
    }

    fn expect_dtype(&self, field: &TensorField, dtype: Dtype) -> Result<()> {
        if field.dtype != dtype {
            return Err(self.field_error(
                &field.name,
                format!("dtype {}, expected {}", field.dtype.name(), dtype.name()),
            ));
        }
        Ok(())
    }

    /// Checks that `field` has exactly `expected` as its shape; `what` explains the
    /// expectation (e.g. "[phi_i, theta_i, 3, n, n]").
    pub fn expect_shape(&self, field: &TensorField, expected: &[usize], what: &str) -> Result<()> {
        if field.shape != expected {
            return Err(self.field_error(
                &field.name,
                format!(
                    "shape {:?} does not match {what} = {expected:?}",
                    field.shape
                ),
            ));
        }
        Ok(())
    }
}

/// A field to write with [`encode`]: name, dtype, shape and the little-endian data bytes.
pub struct FieldData<'a> {
    pub name: &'a str,
    pub dtype: Dtype,
    pub shape: Vec<usize>,
    pub data: Vec<u8>,
}

impl<'a> FieldData<'a> {
    /// A float32 field.
    pub fn f32(name: &'a str, shape: Vec<usize>, values: &[f32]) -> FieldData<'a> {
        FieldData {
            name,
            dtype: Dtype::F32,
            shape,
            data: values.iter().flat_map(|v| v.to_le_bytes()).collect(),
        }
    }
    /// A uint8 field.
    pub fn u8(name: &'a str, shape: Vec<usize>, values: &[u8]) -> FieldData<'a> {
        FieldData {
            name,
            dtype: Dtype::U8,
            shape,
            data: values.to_vec(),
        }
    }
}

/// Serialises fields as a version-1.0 tensor file, each data block starting at an 8-byte
/// aligned offset like Mitsuba's Python writer. The caller keeps data length and shape
/// consistent (`debug_assert`ed); used for synthetic test files.
pub fn encode(fields: &[FieldData]) -> Vec<u8> {
    let table_len: usize = fields
        .iter()
        .map(|f| 2 + f.name.len() + 2 + 1 + 8 + 8 * f.shape.len())
        .sum();
    let align = |x: usize| x.div_ceil(8) * 8;
    let mut offset = align(HEADER_LEN + table_len);
    let mut out =
        Vec::with_capacity(offset + fields.iter().map(|f| align(f.data.len())).sum::<usize>());
    out.extend_from_slice(MAGIC);
    out.extend_from_slice(&[1, 0]);
    out.extend_from_slice(&(fields.len() as u32).to_le_bytes());
    for f in fields {
        debug_assert_eq!(
            f.data.len(),
            f.shape.iter().product::<usize>() * f.dtype.size(),
            "field {}",
            f.name
        );
        out.extend_from_slice(&(f.name.len() as u16).to_le_bytes());
        out.extend_from_slice(f.name.as_bytes());
        out.extend_from_slice(&(f.shape.len() as u16).to_le_bytes());
        out.push(f.dtype.code());
        out.extend_from_slice(&(offset as u64).to_le_bytes());
        for &d in &f.shape {
            out.extend_from_slice(&(d as u64).to_le_bytes());
        }
        offset += align(f.data.len());
    }
    for f in fields {
        out.resize(align(out.len()), 0);
        out.extend_from_slice(&f.data);
    }
    // No padding after the last block (as in the RGL files), so any truncation cuts data.
    out
}
