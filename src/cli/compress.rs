//! `brdfpack compress`: re-encode a table with a given codec or the smallest codec meeting an
//! error budget, and print the choice and its measured error.

use crate::Error;
use crate::check::SampleSet;
use crate::codec::CodecRequest;
use crate::codec::search::{Budget, Evaluator, search};
use crate::io::{atomic, native};
use crate::table::Table;
use clap::Args;
use std::path::{Path, PathBuf};

#[derive(Args, Debug)]
pub struct CompressArgs {
    /// Input table: a native `.bpk` file (or, until the readers land, a MERL `.binary`).
    pub input: PathBuf,
    /// Output native file.
    #[arg(short, long)]
    pub output: PathBuf,
    /// Codec spec, e.g. `lossless`, `dct:step=0.02`, `uniform:bits=12`, `f16` (see
    /// docs/compression.md).
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

fn read_table(path: &Path) -> anyhow::Result<Table> {
    let bytes = atomic::read_input(path)?;
    if native::is_native(&bytes) {
        return Ok(native::from_bytes(&bytes, path)?);
    }
    if path.extension().is_some_and(|e| e == "binary") {
        return Ok(crate::codec::testdata::read_merl(path)?);
    }
    Err(Error::invalid_file(
        path,
        "not a brdfpack table (expected a .bpk or MERL .binary)",
    )
    .into())
}

pub fn run(a: CompressArgs) -> anyhow::Result<i32> {
    if a.samples == 0 {
        return Err(Error::input("--samples must be at least 1").into());
    }
    let table = read_table(&a.input)?;
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
    println!("codec: {}", measured.spec.summary());
    println!("preserves: {}", measured.spec.preserves());
    println!(
        "size: {} bytes file ({} payload), {:.4} bits/stored sample, {:.1}× smaller than raw f32 ({raw} bytes)",
        bytes.len(),
        measured.payload.len(),
        8.0 * bytes.len() as f64 / table.data().len() as f64,
        raw as f64 / bytes.len() as f64
    );
    println!(
        "error vs the input table (both interpolated linearly), uniform set, {} pairs, seed {}, ε = {:.3e}:",
        a.samples, a.seed, m.epsilon
    );
    println!(
        "  log_rmse {:.4e}  p99_rel_core {:.4e}  rel_rmse_core {:.4e}  rmse {:.4e}  max_rel {:.4e}  nonfinite {}  negative {}",
        m.log_rmse, m.p99_rel_core, m.rel_rmse_core, m.rmse, m.max_rel, m.nonfinite, m.negative
    );
    Ok(0)
}
