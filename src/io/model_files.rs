//! The files model specs name, read from disk: `@spec.json` and optical constants
//! (`nk = @file.csv`). The models parse text (`model::SpecFiles`); `Model::parse`,
//! `Model::parse_recording`, `Model::from_json` and `OpticalConstants::read_csv` are defined
//! here, in the layer that opens files.

use crate::model::{Model, SpecFiles};
use crate::spectral::OpticalConstants;
use crate::{Error, Result};
use serde_json::Value;
use std::path::Path;

/// Size limit of a `@file.json` model spec.
const MAX_SPEC_FILE_BYTES: u64 = 1 << 20;
/// Size limit of an optical-constants file (a few thousand rows are plenty).
const MAX_NK_FILE_BYTES: u64 = 4 << 20;

/// The files of a model spec, read from disk (paths as written, relative to the working
/// directory).
pub struct ModelFiles;

impl SpecFiles for ModelFiles {
    fn spec_json(&self, path: &str) -> Result<Value> {
        read_spec_file(path)
    }
    fn optical_constants(&self, path: &str) -> Result<OpticalConstants> {
        OpticalConstants::read_csv(Path::new(path))
    }
}

impl Model {
    /// Parses a model from the compact shell form (`ggx:alpha=0.2,fresnel=au`, see
    /// `docs/models.md`), inline JSON (`{...}`) or a JSON file (`@file.json`), reading the
    /// files it names ([`Model::parse_with`] with [`ModelFiles`]).
    pub fn parse(spec: &str) -> Result<Model> {
        Model::parse_with(spec, &ModelFiles)
    }

    /// [`Model::parse`], recording the files the spec reads in `reads`: the `@file.json`
    /// and every data file it names (`nk = @table.csv`), as named (relative stays relative).
    pub fn parse_recording(spec: &str, reads: &mut crate::reads::ReadSet) -> Result<Model> {
        let model = Model::parse(spec)?;
        let spec = spec.trim();
        let value = if let Some(path) = spec.strip_prefix('@') {
            reads.record(path);
            read_spec_file(path)?
        } else if spec.starts_with('{') {
            serde_json::from_str(spec).unwrap_or(Value::Null)
        } else {
            crate::model::compact::compact_to_json(spec)?
        };
        let mut files = Vec::new();
        crate::model::data_files(&value, &mut files);
        for f in &files {
            reads.record(f);
        }
        Ok(model)
    }

    /// Builds a model from the canonical JSON form of `spec/models.md`
    /// (`{"model": "microfacet", "alpha": 0.2, ...}`); aliases (`ggx`) are accepted as names.
    /// The data files it names are read from disk.
    pub fn from_json(v: &Value) -> Result<Model> {
        Model::from_json_with(v, &ModelFiles)
    }
}

impl OpticalConstants {
    /// Reads a CSV file: a header `wavelength_nm,n,k` (or `wavelength_um,n,k`), then one row
    /// per wavelength, strictly increasing; `#` starts a comment line.
    pub fn read_csv(path: &Path) -> Result<OpticalConstants> {
        use std::io::Read;
        let file = std::fs::File::open(path).map_err(|e| Error::io(path, e))?;
        let mut text = String::new();
        // Cap the read: a table of optical constants is small; a huge file is a mistake.
        file.take(MAX_NK_FILE_BYTES + 1)
            .read_to_string(&mut text)
            .map_err(|e| Error::invalid_file(path, format!("not a UTF-8 CSV file: {e}")))?;
        if text.len() as u64 > MAX_NK_FILE_BYTES {
            return Err(Error::invalid_file(
                path,
                format!("larger than {MAX_NK_FILE_BYTES} bytes; expected a small CSV of λ, n, k"),
            ));
        }
        Self::parse_csv(&text, path)
    }
}

fn read_spec_file(path: &str) -> Result<Value> {
    use std::io::Read;
    let file = std::fs::File::open(path).map_err(|e| Error::io(path, e))?;
    let mut text = String::new();
    // Cap the read: a model spec is small; a huge file is a mistake, not a model.
    file.take(MAX_SPEC_FILE_BYTES + 1)
        .read_to_string(&mut text)
        .map_err(|e| Error::invalid_file(path, format!("not a UTF-8 model spec: {e}")))?;
    if text.len() as u64 > MAX_SPEC_FILE_BYTES {
        return Err(Error::invalid_file(
            path,
            format!("model spec larger than {MAX_SPEC_FILE_BYTES} bytes"),
        ));
    }
    crate::text::reject_duplicate_json_keys(text.as_bytes())
        .map_err(|e| Error::invalid_file(path, format!("model JSON: {e}")))?;
    serde_json::from_str(&text).map_err(|e| Error::invalid_file(path, format!("model JSON: {e}")))
}
