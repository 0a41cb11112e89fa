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
mod build;
mod check;
mod common;
mod compress;
mod convert;
mod convert_rgl;
mod eval;
mod inspect;
mod models;
mod oom;
mod pack;
mod pack_rgl;
mod plot;
mod props;
mod tabulate;
mod tools;
mod values;
#[cfg(test)]
mod vocabulary_tests;

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
    /// The whole job: tabulate, encode, write, read back and check; quiet unless -v/--json.
    #[command(after_help = "Examples:
  brdfpack pack -o gold.bpk                      # the built-in material, default budget
  brdfpack pack 'ward:alpha_x=0.1,alpha_y=0.3' -o ward.bpk --max-error log_rmse=0.01,p99_rel_core=0.2
  brdfpack pack material.binary -o m.bpk --effort max -v
  brdfpack pack 'ggx:alpha=0.2,fresnel=au' -o y60.bpk --theta-i-max 60 --theta-o-max 60 --channels luminance
  brdfpack pack @gold.json -o gold.bpk --depfile gold.bpk.d --json")]
    Pack(pack::PackArgs),
    /// Sample a model (or table) onto a grid and write the table.
    #[command(after_help = "Examples:
  brdfpack tabulate 'ggx:alpha=0.2,fresnel=au' -o gold.bpk
  brdfpack tabulate 'ward:alpha_x=0.1,alpha_y=0.3' --grid halfdiff4:64 -o ward.exr
  brdfpack tabulate gold.binary --grid 'merl,theta-max=60' --channels luminance -o y.bpk")]
    Tabulate(tabulate::TabulateArgs),
    /// Measure a table's error against a reference (exit 1 when a --max-* bound is exceeded).
    #[command(after_help = "Examples:
  brdfpack check gold.bpk --against 'ggx:alpha=0.2,fresnel=au' --max-log-rmse 0.01
  brdfpack check y60.bpk --against 'ggx:alpha=0.2,fresnel=au' --scene y60.toml --samples 100000 --json
  brdfpack check ward.bpk --against ward.exr -q && echo ok")]
    Check(check::CheckArgs),
    /// Re-encode a table with a codec, or the smallest codec meeting an error budget.
    #[command(after_help = "Examples:
  brdfpack compress gold.bpk -o small.bpk --max-error log_rmse=0.01,p99_rel_core=0.2 -v
  brdfpack compress gold.bpk -o f16.bpk --codec f16 --json")]
    Compress(compress::CompressArgs),
    /// Convert a table (native .bpk, brdfpack .exr, MERL .binary), an RGL file or a model to
    /// another format or grid; re-grids by interpolation when the grid changes.
    #[command(after_help = "Examples:
  brdfpack convert material.binary -o material.exr
  brdfpack convert gold.bpk -o gold.mbsdf --grid spherical3:90x90x180
  brdfpack convert 'ggx:alpha=0.2' -o ggx.bsdf")]
    Convert(convert::ConvertArgs),
    /// Describe a file: format, grid, channels, provenance, value statistics, invalid and
    /// negative counts (tables; RGL files too).
    #[command(after_help = "Examples:
  brdfpack inspect gold.bpk
  brdfpack inspect gold.bpk --json -o gold.json")]
    Inspect(inspect::InspectArgs),
    /// Evaluate a model or table at direction pairs (one pair, or a stream on stdin).
    #[command(long_about = eval::LONG_ABOUT, after_help = "Examples:
  brdfpack eval 'ggx:alpha=0.2,fresnel=au' --wi-deg 30,0 --wo-deg 30,180
  printf '0 0 1 0.6 0 0.8\\n' | brdfpack eval ward.bpk --json -o rows.jsonl")]
    Eval(eval::EvalArgs),
    /// Report positivity, reciprocity, isotropy and directional albedo of a model or table.
    #[command(long_about = props::LONG_ABOUT, after_help = "Examples:
  brdfpack props 'phong:albedo=0.8,exponent=100'
  brdfpack props gold.bpk --json -o gold-props.json")]
    Props(props::PropsArgs),
    /// List the analytic models with their parameters, defaults, ranges and properties.
    #[command(after_help = "Examples:
  brdfpack models
  brdfpack models ggx --json")]
    Models(models::ModelsArgs),
    /// Pictures: a lit sphere, lobes, a θh × θd slice or albedo curves, with the error
    /// against a reference (PNG or SVG; docs/plots.md).
    #[command(after_help = "Examples:
  brdfpack plot small.bpk --against gold.bpk --view sphere -o sphere.png
  brdfpack plot 'ggx:alpha=0.2' --view lobe -o lobe.svg")]
    Plot(plot::PlotArgs),
    /// Benchmarks: speed of tabulation and lookups, and a matrix of sources × grids × codecs
    /// with sizes, times and errors (CSV, JSON, Markdown, SVG).
    #[command(after_help = "Examples:
  brdfpack bench --quick -o bench-out
  brdfpack bench --speed --json -q")]
    Bench(bench::BenchArgs),
    /// Build every material of a manifest (TOML or JSON) in parallel, rewriting only outputs
    /// whose inputs changed (docs/build.md).
    #[command(after_help = "Examples:
  brdfpack build materials.toml                       # outputs as the manifest names them
  brdfpack build materials.toml -o summary.json --depfile build.d --keep-going
  brdfpack build materials.toml --material gold -j 1")]
    Build(build::BuildArgs),
    /// Shell completions generated from the command definitions.
    #[command(after_help = "Examples:
  brdfpack completions bash > /etc/bash_completion.d/brdfpack
  brdfpack completions zsh -o _brdfpack")]
    Completions(tools::CompletionsArgs),
    /// A man page (roff) generated from the command definitions.
    #[command(after_help = "Examples:
  brdfpack man -o brdfpack.1 && man ./brdfpack.1
  brdfpack man pack -o brdfpack-pack.1")]
    Man(tools::ManArgs),
}

impl Command {
    /// Where a report command's stdout goes, and its -q/-v (`None` for commands whose `-o`
    /// is the file they make).
    fn report_target(&self) -> Option<&common::ReportTarget> {
        match self {
            Command::Check(a) => Some(&a.report),
            Command::Inspect(a) => Some(&a.report),
            Command::Eval(a) => Some(&a.report),
            Command::Props(a) => Some(&a.report),
            Command::Models(a) => Some(&a.report),
            Command::Completions(a) => Some(&a.report),
            Command::Man(a) => Some(&a.report),
            _ => None,
        }
    }
}

/// What the report commands' stdout text goes to: stdout, a buffer for `-o FILE`, or
/// nowhere (`-q`).
enum Capture {
    Pass,
    Buffer(Vec<u8>),
    Discard,
}

static CAPTURE: std::sync::Mutex<Capture> = std::sync::Mutex::new(Capture::Pass);

/// Stdout as the report commands see it: the real stdout, or `-o FILE`'s buffer, or nothing
/// with `-q`.
pub(crate) struct Stdout;

impl Write for Stdout {
    fn write(&mut self, buf: &[u8]) -> std::io::Result<usize> {
        match &mut *CAPTURE.lock().unwrap_or_else(|e| e.into_inner()) {
            Capture::Pass => std::io::stdout().lock().write(buf),
            Capture::Buffer(v) => {
                v.extend_from_slice(buf);
                Ok(buf.len())
            }
            Capture::Discard => Ok(buf.len()),
        }
    }
    fn flush(&mut self) -> std::io::Result<()> {
        match &*CAPTURE.lock().unwrap_or_else(|e| e.into_inner()) {
            Capture::Pass => std::io::stdout().lock().flush(),
            _ => Ok(()),
        }
    }
}

/// Writes to stdout (line-buffered by std); an I/O error is returned naming `<stdout>`.
#[doc(hidden)]
pub fn write_stdout(args: std::fmt::Arguments, newline: bool) -> crate::Result<()> {
    let mut out = Stdout;
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
    crate::memory::return_large_blocks();
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
    if let Err(e) = crate::memory::start_worker_threads() {
        return report_error(&e.into());
    }
    crate::io::atomic::allow_binary_to_terminal(cli.force_terminal);
    let target = cli.command.report_target().cloned();
    let report_file = target
        .as_ref()
        .and_then(|t| t.output.clone())
        .filter(|p| p.as_os_str() != "-");
    if let Some(t) = &target {
        let mode = if t.quiet {
            Capture::Discard
        } else if report_file.is_some() {
            Capture::Buffer(Vec::new())
        } else {
            Capture::Pass
        };
        *CAPTURE.lock().unwrap_or_else(|e| e.into_inner()) = mode;
    }
    let started = std::time::Instant::now();
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
        Command::Build(a) => build::run(a),
        Command::Completions(a) => tools::completions(a),
        Command::Man(a) => tools::man(a),
    };
    // `-o FILE` of a report command: the text, written once the command has finished.
    let result = result.and_then(|code| {
        if let Some(path) = &report_file {
            let text = match std::mem::replace(
                &mut *CAPTURE.lock().unwrap_or_else(|e| e.into_inner()),
                Capture::Pass,
            ) {
                Capture::Buffer(v) => v,
                _ => Vec::new(),
            };
            crate::io::atomic::write_output(path, &text)?;
        }
        if target.as_ref().is_some_and(|t| t.verbose) {
            eprintln!(
                "brdfpack: finished in {:.3} s",
                started.elapsed().as_secs_f64()
            );
        }
        Ok(code)
    });
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
