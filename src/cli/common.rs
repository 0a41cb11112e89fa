//! Plumbing shared by subcommands: opening sources, writing tables.

use crate::codec::CodecSpec;
use crate::io::{atomic, native};
use crate::table::Table;
use std::io::IsTerminal;
use std::path::Path;

pub use crate::source::Source;

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
