//! `brdfpack compress`: re-encode a table with a given codec or the smallest codec meeting an
//! error budget, and print the choice and its measured error.

use super::common::{Lookup, SamplingArgs, Source, stderr_is_terminal};
use crate::Error;
use crate::check::SampleSet;
use crate::codec::CodecRequest;
use crate::codec::search::{Budget, Evaluator, search};
use crate::grid::parse_grid_spec;
use crate::io::{atomic, native};
use crate::table::Table;
use crate::tabulate::tabulate;
use clap::Args;
use std::path::PathBuf;

#[derive(Args, Debug)]
pub struct CompressArgs {
    /// Input: a table (.bpk, .exr, MERL .binary; `-` = stdin), an RGL .bsdf file or a model
    /// spec (tabulated on --grid first).
    pub input: String,
    /// Grid for a model or measured input (default `merl`).
    #[arg(long)]
    pub grid: Option<String>,
    #[command(flatten)]
    pub symmetry: SamplingArgs,
    /// Output native file.
    #[arg(short, long)]
    pub output: PathBuf,
    /// Codec spec, e.g. `lossless`, `dct:step=0.02`, `uniform:bits=12`, `f16` (see
    /// docs/compression.md). Default `lossless` (bit-exact) unless `--max-error` is given;
    /// `pack` searches by default instead.
    #[arg(long, conflicts_with = "max_error")]
    pub codec: Option<String>,
    /// Error budget on the `uniform` sample set, e.g. `log_rmse=0.01,p99_rel_core=0.2`: the
    /// smallest codec meeting it is chosen.
    #[arg(long)]
    pub max_error: Option<String>,
    /// Pairs in the `uniform` sample set the error is measured on.
    #[arg(long, default_value_t = 65_536)]
    pub samples: usize,
    /// Seed of the sample set.
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    /// zstd level of the entropy stage during the search.
    #[arg(long, default_value_t = 19)]
    pub level: i32,
}

/// Opens the input as a table; a model or measured source is tabulated on `grid` first.
fn read_table(input: &str, grid: Option<&str>, symmetry: &SamplingArgs) -> anyhow::Result<Table> {
    match symmetry.apply(Source::open(input)?) {
        Source::Table(t) => {
            if let Some(g) = grid {
                return Err(Error::input(format!(
                    "--grid {g}: {input} is already a table (use `convert --grid` to re-grid it)"
                ))
                .into());
            }
            Ok(t)
        }
        other => {
            let src = other.into_brdf(Lookup::Linear)?;
            let grid = parse_grid_spec(grid.unwrap_or("merl"))?;
            Ok(tabulate(
                src.as_ref(),
                &grid,
                &symmetry.options(stderr_is_terminal()),
            )?)
        }
    }
}

pub fn run(a: CompressArgs) -> anyhow::Result<i32> {
    if a.samples == 0 {
        return Err(Error::input("--samples must be at least 1").into());
    }
    let table = read_table(&a.input, a.grid.as_deref(), &a.symmetry)?;
    let set = SampleSet::uniform(a.samples, a.seed);
    let t0 = std::time::Instant::now();
    let measured = match (&a.codec, &a.max_error) {
        (_, Some(b)) => {
            let budget = Budget::parse(b)?;
            let r = search(&table, &budget, &set, a.level)?;
            eprintln!(
                "searched {} candidates in {:.1} s",
                r.trials.len(),
                t0.elapsed().as_secs_f64()
            );
            r.best
        }
        (c, None) => {
            let req = CodecRequest::parse(c.as_deref().unwrap_or("lossless"))?;
            let spec = req.resolve(&table)?;
            Evaluator::new(&table, &set)?.measure(&spec)?
        }
    };
    let bytes = native::to_bytes(&table, &measured.spec)?;
    atomic::write_output(&a.output, &bytes)?;
    let raw = table.data().len() * 4;
    let m = &measured.metrics;
    use std::fmt::Write as _;
    let mut r = String::new();
    writeln!(r, "codec: {}", measured.spec.summary())?;
    writeln!(r, "preserves: {}", measured.spec.preserves())?;
    writeln!(
        r,
        "size: {} bytes file ({} payload), {:.4} bits/stored sample, {:.1}× smaller than raw f32 ({raw} bytes)",
        bytes.len(),
        measured.payload.len(),
        8.0 * bytes.len() as f64 / table.data().len() as f64,
        raw as f64 / bytes.len() as f64
    )?;
    writeln!(
        r,
        "error vs the input table (both interpolated linearly), uniform set, {} pairs, seed {}, ε = {:.3e}:",
        a.samples, a.seed, m.epsilon
    )?;
    writeln!(
        r,
        "  log_rmse {:.4e}  p99_rel_core {:.4e}  rel_rmse_core {:.4e}  rmse {:.4e}  max_rel {:.4e}  nonfinite {}  negative {}",
        m.log_rmse, m.p99_rel_core, m.rel_rmse_core, m.rmse, m.max_rel, m.nonfinite, m.negative
    )?;
    if let Some(h) = &measured.held_out {
        writeln!(
            r,
            "held-out set (uniform, {} pairs, seed {}; the search accepts a candidate only when \
             it meets every bound × {} on seed {} and every bound here):",
            a.samples,
            a.seed.wrapping_add(1),
            crate::codec::search::MARGIN,
            a.seed
        )?;
        writeln!(
            r,
            "  log_rmse {:.4e}  p99_rel_core {:.4e}  rel_rmse_core {:.4e}  rmse {:.4e}  max_rel {:.4e}",
            h.log_rmse, h.p99_rel_core, h.rel_rmse_core, h.rmse, h.max_rel
        )?;
    }
    // With `-o -` the file's bytes are stdout: the report must not follow them there.
    if a.output.as_os_str() == "-" {
        eprint!("{r}");
    } else {
        out!("{r}");
    }
    Ok(0)
}
