//! The command-line interface: parses arguments into plain values, calls the library, maps
//! errors to exit codes (0 ok, 1 a check failed or an operation failed, 2 bad input).

use clap::{Parser, Subcommand};
use std::io::Write;

/// `print!` that returns a write failure (full disk, closed pipe) as an error naming
/// `<stdout>` instead of panicking as `print!` does; use inside a function returning a
/// `Result` whose error converts from [`crate::Error`].
macro_rules! out {
    ($($arg:tt)*) => {
        $crate::cli::write_stdout(format_args!($($arg)*), false)?
    };
}

/// `println!` with the error handling of [`out!`].
macro_rules! outln {
    () => {
        $crate::cli::write_stdout(format_args!(""), true)?
    };
    ($($arg:tt)*) => {
        $crate::cli::write_stdout(format_args!($($arg)*), true)?
    };
}

mod bench;
mod check;
mod common;
mod compress;
mod convert;
mod convert_rgl;
mod eval;
mod inspect;
mod models;
mod pack;
mod plot;
mod props;
mod tabulate;

#[doc(hidden)]
pub use eval::{
    InputFormat as EvalInputFormat, OutputFormat as EvalOutputFormat, eval_stream_text,
};

/// brdfpack: turn BRDFs into compact tables and back.
#[derive(Parser, Debug)]
#[command(name = "brdfpack", version, about, long_about = None, propagate_version = true)]
pub struct Cli {
    #[command(subcommand)]
    command: Command,
    /// Memory budget, e.g. 512M or 8G (default: $BRDFPACK_MAX_MEMORY, else 2G). Work that
    /// would need more (a huge grid, sample count or a file's declared size) is refused up
    /// front with the memory it needs (exit 2).
    #[arg(long, global = true, value_name = "SIZE")]
    max_memory: Option<String>,
    /// Write binary output (`-o -`) to stdout even when it is a terminal.
    #[arg(long, global = true)]
    force_terminal: bool,
}

#[derive(Subcommand, Debug)]
enum Command {
    /// The whole job: tabulate, encode, write, read back and check; prints sizes, times, errors.
    Pack(pack::PackArgs),
    /// Sample a model (or table) onto a grid and write the table.
    Tabulate(tabulate::TabulateArgs),
    /// Measure a table's error against a reference (exit 1 when a --max-* bound is exceeded).
    Check(check::CheckArgs),
    /// Re-encode a table with a codec, or the smallest codec meeting an error budget.
    Compress(compress::CompressArgs),
    /// Convert a table (native .bpk, brdfpack .exr, MERL .binary), an RGL file or a model to
    /// another format or grid; re-grids by interpolation when the grid changes.
    Convert(convert::ConvertArgs),
    /// Describe a file: format, grid, channels, provenance, value statistics, invalid and
    /// negative counts (tables; RGL files too).
    Inspect(inspect::InspectArgs),
    /// Evaluate a model or table at direction pairs (one pair, or a stream on stdin).
    #[command(long_about = eval::LONG_ABOUT)]
    Eval(eval::EvalArgs),
    /// Report positivity, reciprocity, isotropy and directional albedo of a model or table.
    #[command(long_about = props::LONG_ABOUT)]
    Props(props::PropsArgs),
    /// List the analytic models with their parameters, defaults, ranges and properties.
    Models(models::ModelsArgs),
    /// Pictures: a lit sphere, lobes, a θh × θd slice or albedo curves, with the error
    /// against a reference (PNG or SVG; docs/plots.md).
    Plot(plot::PlotArgs),
    /// Benchmarks: speed of tabulation and lookups, and a matrix of sources × grids × codecs
    /// with sizes, times and errors (CSV, JSON, Markdown, SVG).
    Bench(bench::BenchArgs),
}

/// Writes to stdout (line-buffered by std); an I/O error is returned naming `<stdout>`.
#[doc(hidden)]
pub fn write_stdout(args: std::fmt::Arguments, newline: bool) -> crate::Result<()> {
    let mut out = std::io::stdout().lock();
    out.write_fmt(args)
        .and_then(|_| {
            if newline {
                out.write_all(b"\n")
            } else {
                Ok(())
            }
        })
        .map_err(stdout_error)
}

/// An I/O error on stdout, as the library's error naming `<stdout>`.
pub(crate) fn stdout_error(e: std::io::Error) -> crate::Error {
    crate::Error::io("<stdout>", e)
}

/// Runs the CLI and returns the process exit code.
pub fn main() -> i32 {
    let cli = match Cli::try_parse() {
        Ok(c) => c,
        Err(e) => {
            // clap prints help/version to stdout (exit 0) and usage errors to stderr (exit 2).
            let _ = e.print();
            return if e.use_stderr() { 2 } else { 0 };
        }
    };
    let budget = match &cli.max_memory {
        Some(s) => crate::memory::parse_size(s)
            .map(Some)
            .map_err(|e| crate::Error::input(format!("--max-memory {e}"))),
        None => crate::memory::budget_from_env(),
    };
    match budget {
        Ok(Some(b)) => crate::memory::set_budget(b),
        Ok(None) => {}
        Err(e) => return report_error(&e.into()),
    }
    if let Err(e) = crate::memory::check_thread_env() {
        return report_error(&e.into());
    }
    crate::io::atomic::allow_binary_to_terminal(cli.force_terminal);
    let result = match cli.command {
        Command::Eval(a) => eval::run(a),
        Command::Tabulate(a) => tabulate::run(a),
        Command::Check(a) => check::run(a),
        Command::Pack(a) => pack::run(a),
        Command::Models(a) => models::run(a),
        Command::Props(a) => props::run(a),
        Command::Convert(a) => convert::run(a),
        Command::Inspect(a) => inspect::run(a),
        Command::Compress(a) => compress::run(a),
        Command::Bench(a) => bench::run(a),
        Command::Plot(a) => plot::run(a),
    };
    // Whatever is still buffered (a `print!` without a newline) is written now, so that
    // its failure is reported too: std ignores errors of the flush at exit.
    let result = result.and_then(|code| {
        std::io::stdout().flush().map_err(stdout_error)?;
        Ok(code)
    });
    match result {
        Ok(code) => code,
        Err(e) => report_error(&e),
    }
}

/// Prints `brdfpack: <message>` (with the chain of causes) and returns the exit code.
/// A closed stdout (e.g. `| head`) is not an error.
fn report_error(e: &anyhow::Error) -> i32 {
    for cause in e.chain() {
        if let Some(io) = cause.downcast_ref::<std::io::Error>()
            && io.kind() == std::io::ErrorKind::BrokenPipe
        {
            return 0;
        }
    }
    let code = e
        .chain()
        .find_map(|c| {
            c.downcast_ref::<brdfpack_error::Error>()
                .map(|e| e.exit_code())
        })
        .unwrap_or(1);
    let mut msg = e.to_string();
    for cause in e.chain().skip(1) {
        let cause = cause.to_string();
        // An error that prints its source (`{path}: {source}`) has said it already.
        if !msg.ends_with(&cause) {
            msg.push_str(": ");
            msg.push_str(&cause);
        }
    }
    // Messages quote file text and arguments: no terminal controls, and no 100 KB lines.
    let msg = crate::text::sanitize_line(&msg);
    let _ = writeln!(std::io::stderr().lock(), "brdfpack: {msg}");
    code
}

use crate::error as brdfpack_error;
