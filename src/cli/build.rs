//! `brdfpack build MANIFEST`: parses the flags and calls [`crate::plan::build`].

use super::common::DepfileArgs;
use crate::plan::build::{BuildOptions, Status, build, default_cache_dir};
use crate::plan::manifest::Manifest;
use crate::reads::ReadSet;
use clap::Args;
use std::path::PathBuf;

#[derive(Args, Debug)]
pub struct BuildArgs {
    /// The manifest: TOML, or JSON (docs/build.md).
    pub manifest: PathBuf,
    /// Write the summary (per material: status, files, sizes, errors, times) as JSON to FILE.
    #[arg(short, long, value_name = "FILE")]
    pub output: Option<PathBuf>,
    /// The summary as one JSON document on stdout.
    #[arg(long)]
    pub json: bool,
    /// Nothing but errors.
    #[arg(short, long, conflicts_with = "verbose")]
    pub quiet: bool,
    /// A line per material (status, time, outputs written) on stderr.
    #[arg(short, long)]
    pub verbose: bool,
    /// Build the other materials after one fails (the exit code is still the worst one).
    #[arg(short, long)]
    pub keep_going: bool,
    /// Worker threads (default: all logical CPUs); the outputs are the same for any count.
    #[arg(short = 'j', long, value_name = "N")]
    pub threads: Option<usize>,
    /// The cache directory (default: .brdfpack-cache beside the manifest).
    #[arg(long, value_name = "DIR")]
    pub cache_dir: Option<PathBuf>,
    /// Build only this material (repeatable).
    #[arg(long, value_name = "NAME")]
    pub material: Vec<String>,
    /// Rebuild every material, ignoring the cache (outputs are still rewritten only when
    /// their bytes change).
    #[arg(long)]
    pub force: bool,
    #[command(flatten)]
    pub depfile: DepfileArgs,
}

pub fn run(a: BuildArgs) -> anyhow::Result<i32> {
    let mut reads = ReadSet::new();
    let manifest = Manifest::load(&a.manifest, &mut reads)?;
    if a.threads == Some(0) {
        return Err(crate::Error::input("--threads 0: give at least 1").into());
    }
    let opts = BuildOptions {
        threads: a.threads,
        keep_going: a.keep_going,
        cache_dir: a
            .cache_dir
            .clone()
            .unwrap_or_else(|| default_cache_dir(&a.manifest)),
        only: a.material.clone(),
        force: a.force,
    };
    let (summary, build_reads) = build(&manifest, &a.manifest, &opts)?;
    reads.extend(&build_reads);
    // The summary first: Ninja expects the depfile to name its edge's first output.
    let outputs: Vec<&std::path::Path> = a
        .output
        .as_deref()
        .into_iter()
        .chain(
            summary
                .materials
                .iter()
                .flat_map(|m| m.outputs.iter().map(|o| o.path.as_path())),
        )
        .collect();
    let json = serde_json::to_string_pretty(&summary)?;
    if let Some(p) = &a.output {
        crate::io::atomic::write_output(p, format!("{json}\n").as_bytes())?;
    }
    if summary.exit_code == 0 {
        a.depfile.write(&outputs, &reads)?;
    }
    if a.json {
        outln!("{json}");
    }
    let verbose = a.verbose && !a.quiet;
    for m in &summary.materials {
        let written = m.outputs.iter().filter(|o| o.written).count();
        if verbose {
            eprintln!(
                "brdfpack: {:<20} {:<9} {:>7.3} s  {} of {} outputs written",
                m.name,
                format!("{:?}", m.status).to_lowercase(),
                m.seconds,
                written,
                m.outputs.len()
            );
        }
        // A failed material's error is printed under -q too ("nothing but errors"): with
        // `build -q` (the Makefile and build.ninja of docs/build.md) a failure exited 2 with
        // nothing on stderr.
        if let Some(e) = &m.error
            && m.status == Status::Failed
        {
            eprintln!("brdfpack: material {}: {e}", m.name);
        }
    }
    if verbose {
        eprintln!(
            "brdfpack: {} built, {} unchanged, {} failed in {:.3} s",
            summary.built, summary.unchanged, summary.failed, summary.seconds
        );
    }
    Ok(summary.exit_code)
}
