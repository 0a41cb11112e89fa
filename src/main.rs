//! The `brdfpack` command. The CLI (`src/cli/`: clap definitions, progress bars, messages,
//! exit codes) is compiled into the binary only; the library knows nothing of it. The
//! library's modules are imported here under their own names, so that the CLI names them
//! `crate::io`, `crate::table`, … as the library's own modules do.

#[allow(unused_imports)]
use brdfpack::{
    Error, Result, TOOL_VERSION, bench, brdf, check, codec, error, geometry, grid, io, math,
    memory, model, pairs, plan, plot, props, reads, source, spectral, table, tabulate, text,
};

mod cli;

fn main() {
    std::process::exit(cli::main());
}
