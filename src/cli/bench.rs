//! `brdfpack bench`: speed of the hot paths and the sources × grids × codecs matrix
//! (docs/benchmarks.md). Writes bench.csv, bench.json, bench.md and two SVG plots.

use crate::bench::{
    Machine, MatrixOptions, SpeedResult, run_matrix, speed_suite, to_csv, to_json, to_markdown,
    to_svg,
};
use crate::io::atomic::write_output;
use clap::Args;
use std::path::PathBuf;

#[derive(Args, Debug)]
pub struct BenchArgs {
    /// Small grids, one codec, few runs: finishes in well under a minute (CI).
    #[arg(long)]
    pub quick: bool,
    /// Only the speed workloads of the peer comparison (no matrix).
    #[arg(long)]
    pub speed: bool,
    /// Only the tabulation workloads (implies --speed).
    #[arg(long)]
    pub tabulate_only: bool,
    /// Only the lookup workload (implies --speed).
    #[arg(long, conflicts_with = "tabulate_only")]
    pub lookup_only: bool,
    /// Timed runs per measurement (after one warm-up run); the median is reported.
    #[arg(long)]
    pub runs: Option<usize>,
    /// Worker threads (default: all logical CPUs).
    #[arg(long)]
    pub threads: Option<usize>,
    /// Pairs per lookup batch of the speed workload.
    #[arg(long, default_value_t = 1_000_000)]
    pub pairs: usize,
    /// Folder for the output files (`--out` is an older name).
    #[arg(
        short = 'o',
        long = "output",
        alias = "out",
        default_value = "bench-out"
    )]
    pub out: PathBuf,
    /// Nothing on stderr but errors (no progress lines).
    #[arg(short, long, conflicts_with = "verbose")]
    pub quiet: bool,
    /// Machine description and every finished row on stderr (the default).
    #[arg(short, long)]
    pub verbose: bool,
    /// The shared reference folder (its data/rgl/*.bsdf join the matrix); default
    /// $BRDFPACK_SHARED, else ../shared when it exists.
    #[arg(long)]
    pub shared: Option<PathBuf>,
    /// Print the speed results as JSON lines on stdout (for scripts/peer-compare.sh).
    #[arg(long)]
    pub json: bool,
    /// The encoder's acceptance run instead: every zoo material (and every file of the
    /// shared data folder) packed within the preview and production budgets and measured
    /// against its source on independent seeds; a Markdown table on stdout (JSON lines with
    /// --json). Only materials whose name contains FILTER with --zoo-filter.
    #[arg(long)]
    pub zoo: bool,
    #[arg(long, requires = "zoo")]
    pub zoo_filter: Option<String>,
    /// Verification seeds per material and budget (--zoo).
    #[arg(long, default_value_t = 10, requires = "zoo")]
    pub zoo_seeds: usize,
    /// Pairs per verification seed (--zoo).
    #[arg(long, default_value_t = 100_000, requires = "zoo")]
    pub zoo_pairs: usize,
    /// Planner effort (--zoo): fast, default or max.
    #[arg(long, default_value = "default", requires = "zoo")]
    pub zoo_effort: String,
    /// Add N materials drawn from the zoo's families with random parameters (--zoo;
    /// seeded by --zoo-random-seed, named randomSEED-K-FAMILY).
    #[arg(long, default_value_t = 0, requires = "zoo")]
    pub zoo_random: usize,
    #[arg(long, default_value_t = 1, requires = "zoo")]
    pub zoo_random_seed: u64,
    /// Pack each isotropic reciprocal model as its MERL-grid table instead (a MERL-format
    /// file of it, named NAME@merl), measured against that table (--zoo).
    #[arg(long, requires = "zoo")]
    pub zoo_sampled: bool,
}

/// Most worker threads `bench` starts: 100000 threads would spend minutes being created
/// (and a stack each) before any work.
const MAX_THREADS: usize = 1024;

pub fn run(a: BenchArgs) -> anyhow::Result<i32> {
    super::check::validate_pairs("--pairs", a.pairs)?;
    let mut pool = rayon::ThreadPoolBuilder::new();
    if let Some(n) = a.threads {
        if n == 0 || n > MAX_THREADS {
            return Err(crate::Error::input(format!(
                "--threads {n} is out of range [1, {MAX_THREADS}]"
            ))
            .into());
        }
        pool = pool.num_threads(n);
    }
    let pool = pool
        .build()
        .map_err(|e| crate::Error::Failure(format!("thread pool: {e}")))?;
    pool.install(|| run_in_pool(a))
}

fn run_in_pool(a: BenchArgs) -> anyhow::Result<i32> {
    let quiet = a.quiet;
    // Progress and notes on stderr unless -q.
    macro_rules! say {
        ($($t:tt)*) => {
            if !quiet {
                eprintln!($($t)*)
            }
        };
    }
    if a.zoo {
        return run_zoo(&a);
    }
    let machine = Machine::detect();
    say!("machine: {}", machine.describe());
    let runs = a.runs.unwrap_or(if a.quick { 3 } else { 7 }).max(1);
    let speed_only = a.speed || a.tabulate_only || a.lookup_only;
    let which = if a.tabulate_only {
        "tabulate"
    } else if a.lookup_only {
        "lookup"
    } else if a.quick {
        // The 64⁴ workload needs 400 MB; CI runs the MERL-grid ones.
        "tabulate_merl"
    } else {
        ""
    };
    let mut speed: Vec<SpeedResult> = speed_suite(runs, which, a.pairs)?;
    if a.quick && which == "tabulate_merl" {
        speed.extend(speed_suite(runs, "lookup", a.pairs.min(100_000))?);
    }
    for r in &speed {
        say!(
            "{:<34} {:>9} items  median {:>9.3} ms  (min {:.3}, max {:.3}, {} runs)  {:.3e}/s",
            r.name,
            r.items,
            r.timing.median_s * 1e3,
            r.timing.min_s * 1e3,
            r.timing.max_s * 1e3,
            r.timing.runs,
            r.items_per_s
        );
        if a.json {
            outln!("{}", serde_json::to_string(r)?);
        }
    }
    if speed_only {
        return Ok(0);
    }
    let shared = a
        .shared
        .clone()
        .or_else(|| std::env::var_os("BRDFPACK_SHARED").map(PathBuf::from))
        .or_else(|| Some(PathBuf::from("../shared")).filter(|p| p.is_dir()));
    let data = shared.map(|s| s.join("data")).filter(|d| d.is_dir());
    match &data {
        Some(d) => say!("measured materials from {}", d.display()),
        None => say!("no shared data folder (--shared): analytic sources only"),
    }
    let opts = MatrixOptions {
        quick: a.quick,
        runs,
        samples: if a.quick { 8192 } else { 65_536 },
        shared_data: data,
    };
    let rows = run_matrix(&opts, |r| {
        say!(
            "{:<24} {:<48} {:<18} {:>10} B  {:>6.2} bit/sample  log_rmse {:.3e}  {:.3e} lookups/s",
            r.source,
            r.grid,
            r.codec,
            r.bytes,
            r.bits_per_sample,
            r.log_rmse,
            r.lookups_per_s
        )
    })?;
    std::fs::create_dir_all(&a.out).map_err(|e| crate::Error::io(&a.out, e))?;
    let files = [
        ("bench.csv", to_csv(&rows)),
        ("bench.json", to_json(&machine, &speed, &rows)),
        ("bench.md", to_markdown(&machine, &speed, &rows)),
        (
            "error_vs_bytes.svg",
            to_svg(&rows, |r| r.bytes as f64, "bytes", "error vs size")?,
        ),
        (
            "error_vs_lookup_time.svg",
            to_svg(
                &rows,
                |r| r.lookup_s * 1e9,
                "ns per lookup (batched)",
                "error vs lookup time",
            )?,
        ),
    ];
    for (name, text) in files {
        let p = a.out.join(name);
        write_output(&p, text.as_bytes())?;
        say!("wrote {}", p.display());
    }
    Ok(0)
}

/// `bench --zoo`: the encoder's acceptance run (docs/compression.md, "The material zoo").
fn run_zoo(a: &BenchArgs) -> anyhow::Result<i32> {
    let quiet = a.quiet;
    // Progress and notes on stderr unless -q.
    macro_rules! say {
        ($($t:tt)*) => {
            if !quiet {
                eprintln!($($t)*)
            }
        };
    }
    use crate::plan::budget::Budget;
    use crate::plan::zoo;
    let effort = crate::plan::rate::Effort::parse(&a.zoo_effort)?;
    if a.zoo_seeds == 0 || a.zoo_pairs == 0 || a.zoo_pairs > 10_000_000 {
        return Err(crate::Error::input("--zoo-seeds and --zoo-pairs must be in 1..=1e7").into());
    }
    if a.zoo_random > 10_000 {
        return Err(crate::Error::input("--zoo-random must be in 0..=10000").into());
    }
    let mut materials: Vec<(String, String)> = zoo::materials()
        .into_iter()
        .chain(zoo::random_materials(a.zoo_random, a.zoo_random_seed))
        .map(|m| (m.name, m.spec))
        .collect();
    let shared = a
        .shared
        .clone()
        .or_else(|| std::env::var_os("BRDFPACK_SHARED").map(PathBuf::from))
        .unwrap_or_else(|| PathBuf::from("../shared"));
    for sub in ["data/merl", "data/rgl"] {
        if let Ok(rd) = std::fs::read_dir(shared.join(sub)) {
            let mut files: Vec<PathBuf> = rd.filter_map(|e| e.ok().map(|e| e.path())).collect();
            files.sort();
            for f in files {
                if matches!(
                    f.extension().and_then(|e| e.to_str()),
                    Some("binary" | "bsdf")
                ) {
                    let name = f
                        .file_name()
                        .unwrap_or_default()
                        .to_string_lossy()
                        .to_string();
                    materials.push((name, f.display().to_string()));
                }
            }
        }
    }
    if let Some(filter) = &a.zoo_filter {
        materials.retain(|(n, _)| n.contains(filter.as_str()));
    }
    let budgets = [
        ("preview", Budget::parse("log_rmse=0.01,p99_rel_core=0.2")?),
        (
            "production",
            Budget::parse("log_rmse=0.002,p99_rel_core=0.05")?,
        ),
    ];
    let mut rows = Vec::new();
    for (name, spec) in &materials {
        let (src, tabulated) = zoo::zoo_source(spec, a.zoo_sampled)?;
        let name = if tabulated {
            format!("{name}@merl")
        } else {
            name.clone()
        };
        for (bname, budget) in &budgets {
            let mut r = zoo::run_one(
                &name,
                src.as_ref(),
                bname,
                budget,
                effort,
                a.zoo_seeds,
                a.zoo_pairs,
            )?;
            r.spec = spec.clone();
            say!(
                "zoo: {name} {bname}: {} bytes, {:.2} s, holds {}",
                r.bytes,
                r.plan_s,
                r.holds
            );
            if a.json {
                println!("{}", serde_json::to_string(&r)?);
            }
            rows.push(r);
        }
    }
    if !a.json {
        print!("{}", zoo::to_markdown(&rows));
        // What the drawn materials are (the fixed ones are listed in docs/compression.md).
        let drawn: Vec<&(String, String)> = materials
            .iter()
            .filter(|(n, _)| n.starts_with("random"))
            .collect();
        if !drawn.is_empty() {
            println!();
            for (n, s) in drawn {
                println!("- {n}: `{s}`");
            }
        }
        for (bname, _) in &budgets {
            if let Some(m) = zoo::median_bytes(&rows, bname) {
                println!("\nmedian {bname} file: {m} bytes");
            }
        }
    }
    Ok(if rows.iter().all(|r| r.holds) { 0 } else { 1 })
}
