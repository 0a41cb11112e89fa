//! Plumbing shared by subcommands: opening sources, writing tables.

use crate::brdf::Brdf;
use crate::codec::CodecSpec;
use crate::io::{atomic, native};
use crate::model::Model;
use crate::table::{Interp, InterpolatedTable, Table};
use std::io::IsTerminal;
use std::path::Path;

/// A BRDF source opened from the command line: a table file or an analytic model.
pub enum Source {
    Table(Table),
    Model(Model),
}

impl Source {
    /// Opens `spec`: an existing file (or `-`) is read as a table; anything else is parsed
    /// as a model spec.
    pub fn open(spec: &str) -> crate::Result<Source> {
        let path = Path::new(spec);
        if spec == "-" || path.is_file() {
            let bytes = atomic::read_input(path)?;
            if native::is_native(&bytes) {
                return Ok(Source::Table(native::from_bytes(&bytes, path)?));
            }
            return Err(crate::Error::invalid_file(
                path,
                "not a recognised table format (expected a brdfpack .bpk file)",
            ));
        }
        Ok(Source::Model(Model::parse(spec)?))
    }

    /// The source as a BRDF (tables interpolated by `interp`).
    pub fn into_brdf(self, interp: Interp) -> crate::Result<Box<dyn Brdf>> {
        Ok(match self {
            Source::Table(table) => Box::new(InterpolatedTable { table, interp }),
            Source::Model(m) => {
                m.check_tabulable()?;
                Box::new(m)
            }
        })
    }
}

/// Encodes and writes a table to `path` (`-` for stdout) atomically; returns the bytes written.
pub fn write_table(table: &Table, path: &Path, codec: &CodecSpec) -> crate::Result<usize> {
    let bytes = native::to_bytes(table, codec)?;
    atomic::write_output(path, &bytes)?;
    Ok(bytes.len())
}

/// Progress bars only when a person is watching.
pub fn stderr_is_terminal() -> bool {
    std::io::stderr().is_terminal()
}
