//! `brdfpack compress`: re-encode a table with a given codec or the smallest codec meeting an
//! error budget, and print the choice and its measured error.

use super::common::{Bar, DepfileArgs, Lookup, SamplingArgs, SceneArgs, Source};
use crate::Error;
use crate::check::SampleSet;
use crate::codec::CodecRequest;
use crate::grid::parse_grid_spec;
use crate::io::{atomic, native};
use crate::plan::budget::Budget;
use crate::plan::pack::{PackInput, PackSettings, plan};
use crate::plan::rate::Effort;
use crate::plan::scene::Scene;
use crate::plan::search::encode_and_measure;
use crate::reads::ReadSet;
use crate::table::Table;
use crate::tabulate::tabulate;
use clap::Args;
use serde_json::json;
use std::borrow::Cow;
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
    /// zstd level of the entropy stage (`--codec` chains that use zstd).
    #[arg(long, default_value_t = 19)]
    pub level: i32,
    /// With `--max-error`: time spent for a smaller file, `fast`, `default` or `max`.
    #[arg(long, default_value = "default")]
    pub effort: String,
    /// The report (codec, size, error) as one JSON object on stdout (stderr with `-o -`).
    #[arg(long)]
    pub json: bool,
    /// Nothing but errors (no progress bar).
    #[arg(short, long, conflicts_with = "verbose")]
    pub quiet: bool,
    /// The human report on stderr.
    #[arg(short, long)]
    pub verbose: bool,
    #[command(flatten)]
    pub depfile: DepfileArgs,
    #[command(flatten)]
    pub scene: SceneArgs,
}

/// Opens the input as a table; a model or measured source is tabulated on `grid` first.
fn read_table(
    input: &str,
    grid: Option<&str>,
    symmetry: &SamplingArgs,
    scene: &Scene,
    reads: &mut ReadSet,
    bar: &Bar,
) -> anyhow::Result<Table> {
    match symmetry.apply(Source::open_recording(input, reads)?) {
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
            let src = scene.restrict_source(other.into_brdf(Lookup::Linear)?)?;
            let grid = match grid {
                Some(g) => parse_grid_spec(g)?,
                None => crate::plan::grids::table_default_grid(src.as_ref())?,
            };
            let grid = scene.restrict_grid(&grid)?;
            let t = tabulate(src.as_ref(), &grid, &symmetry.options(bar.cells()));
            bar.finish();
            Ok(t?)
        }
    }
}

pub fn run(a: CompressArgs) -> anyhow::Result<i32> {
    super::check::validate_samples(a.samples)?;
    let effort = Effort::parse(&a.effort)?;
    let mut reads = ReadSet::new();
    let scene = a.scene.load(&mut reads)?;
    let mut symmetry = a.symmetry.clone();
    if scene.isotropic == Some(true) {
        symmetry.allow_anisotropic = true;
    }
    if let Some(b) = a.max_error.as_deref().or(scene.max_error.as_deref()) {
        return run_budget(&a, Budget::parse(b)?, effort, &scene, &symmetry, reads);
    }
    let bar = Bar::new(a.quiet);
    let mut table = read_table(
        &a.input,
        a.grid.as_deref(),
        &symmetry,
        &scene,
        &mut reads,
        &bar,
    )?;
    let set = SampleSet::uniform(a.samples, a.seed);
    let req = CodecRequest::parse(a.codec.as_deref().unwrap_or("lossless"))?;
    let spec = req.resolve(&table)?;
    // The table then holds what the payload decodes to: the file's header reads only its
    // grid, channels, provenance, mask and (for a lossless codec, whose decode is the
    // samples themselves) its exact values.
    let measured = encode_and_measure(&mut table, &spec, &set)?;
    // The payload measured is the one written (encoding it again took as long again).
    let bytes = native::to_bytes_with_payload(&table, &measured.spec, &measured.payload)?;
    atomic::write_output(&a.output, &bytes)?;
    a.depfile.write(&[a.output.as_path()], &reads)?;
    let raw = table.data().len() * 4;
    let m = &measured.metrics;
    let machine = json!({
        "output": a.output.display().to_string(),
        "codec": measured.spec,
        "bytes": bytes.len(),
        "payload_bytes": measured.payload.len(),
        "raw_f32_bytes": raw,
        "samples": a.samples,
        "seed": a.seed,
        "metrics": m,
    });
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
    report(&a, &r, &machine)
}

/// The input table read again, with its exact f64 values, after a plan on its samples chose
/// the lossless codec; refused when the file no longer holds the samples that were planned.
fn exact_again(
    a: &CompressArgs,
    symmetry: &SamplingArgs,
    reads: &mut ReadSet,
    planned: &Table,
) -> anyhow::Result<Table> {
    let again = match symmetry.apply(Source::open_recording(&a.input, reads)?) {
        Source::Table(t) => Some(t),
        _ => None,
    };
    let same = again.as_ref().is_some_and(|again| {
        again.data().len() == planned.data().len()
            && again
                .data()
                .iter()
                .zip(planned.data())
                .all(|(x, y)| x.to_bits() == y.to_bits())
            && again.valid() == planned.valid()
    });
    let (true, Some(again)) = (same, again) else {
        return Err(Error::Failure(format!(
            "{}: the file changed while it was being compressed; no file written",
            a.input
        ))
        .into());
    };
    Ok(again)
}

/// `--max-error`: the smallest file whose error against the input (a table against itself,
/// a model or measured file against the source) meets the budget ([`crate::plan::pack`]).
fn run_budget(
    a: &CompressArgs,
    budget: Budget,
    effort: Effort,
    scene: &Scene,
    symmetry: &SamplingArgs,
    mut reads: ReadSet,
) -> anyhow::Result<i32> {
    let bar = Bar::new(a.quiet);
    let progress = |stage: &str| bar.stage(stage);
    let settings = PackSettings {
        budget: budget.clone(),
        effort,
        check_samples: a.samples,
        check_seed: a.seed,
    };
    let source = symmetry.apply(Source::open_recording(&a.input, &mut reads)?);
    // An RGL file without --grid: packed in its own parameterization (issue #19), as `pack`.
    if let Source::Measured(m) = &source
        && a.grid.is_none()
        && scene.is_empty()
        && crate::plan::rgl::unsupported(m).is_none()
    {
        return compress_rgl(a, m, &budget, &settings, &progress, &bar, &reads);
    }
    let planned = match source {
        Source::Table(t) => {
            if let Some(g) = &a.grid {
                return Err(Error::input(format!(
                    "--grid {g}: {} is already a table (use `convert --grid` to re-grid it)",
                    a.input
                ))
                .into());
            }
            // A regular file's exact f64 values (a MERL file's: twice its f32 samples) are not
            // held while planning, which reads only the samples: they are read again from the
            // file when the lossless codec is chosen (a pipe or device is read once, so its
            // table keeps them).
            let regular = std::fs::metadata(&a.input).is_ok_and(|m| m.is_file()) && a.input != "-";
            let reread = t.exact().is_some() && regular;
            let t = if reread { t.without_exact() } else { t };
            // A regular file's samples are read again if the lossless chain is chosen, so the
            // encoder can decode its candidates into their memory meanwhile.
            let again = || -> crate::Result<Vec<f32>> {
                match symmetry.apply(Source::open(&a.input)?) {
                    Source::Table(t) => Ok(t.into_samples()),
                    _ => Err(Error::Failure(format!(
                        "{}: the file changed while it was being compressed; no file written",
                        a.input
                    ))),
                }
            };
            let mut planned = plan(
                PackInput::Table {
                    table: Cow::Owned(t),
                    again: regular.then_some(&again as crate::plan::rate::Again),
                },
                &settings,
                &progress,
            );
            if let Ok(p) = &mut planned
                && reread
                && p.encoded.spec.is_lossless()
            {
                p.table = exact_again(a, symmetry, &mut reads, &p.table)?;
            }
            planned
        }
        other => {
            let src = scene.restrict_source(other.into_brdf(Lookup::Linear)?)?;
            let grid = match a.grid.as_deref() {
                Some(g) => parse_grid_spec(g)?,
                None => crate::plan::grids::table_default_grid(src.as_ref())?,
            };
            let grid = scene.restrict_grid(&grid)?;
            plan(
                PackInput::Source {
                    source: src.as_ref(),
                    grid: Some(grid),
                    options: symmetry.options(None),
                },
                &settings,
                &progress,
            )
        }
    };
    bar.finish();
    let planned = planned?;
    // The planner's estimation sets, stencils and coefficients are freed: handed back before
    // the read-back and the check, they do not add to the peak.
    crate::memory::release_free_memory();
    let e = &planned.encoded;
    let bytes = native::to_bytes_with_payload(&planned.table, &e.spec, &e.payload)?;
    atomic::write_output(&a.output, &bytes)?;
    a.depfile.write(&[a.output.as_path()], &reads)?;
    let raw = planned.table.data().len() * 4;
    let machine = json!({
        "output": a.output.display().to_string(),
        "codec": e.spec,
        "bytes": bytes.len(),
        "payload_bytes": e.payload.len(),
        "raw_f32_bytes": raw,
        "budget": budget.bounds,
        "file": e.estimate,
        "grid_alone": e.floor,
        "samples": a.samples,
        "seed": a.seed,
    });
    let values = |m: &crate::check::Metrics| super::pack::budget_values(&budget.bounds, m);
    use std::fmt::Write as _;
    let mut r = String::new();
    writeln!(r, "output: {}", a.output.display())?;
    writeln!(r, "codec: {}", e.spec.summary())?;
    writeln!(r, "preserves: {}", e.spec.preserves())?;
    writeln!(
        r,
        "size: {} bytes file ({} payload), {:.4} bits/stored sample, {:.1}× smaller than raw f32 ({raw} bytes)",
        bytes.len(),
        e.payload.len(),
        8.0 * bytes.len() as f64 / planned.table.data().len() as f64,
        raw as f64 / bytes.len() as f64
    )?;
    writeln!(
        r,
        "budget {}: met by the written file against the input ({} decodes, {:.2} s)",
        budget.describe(),
        e.trials.len(),
        planned.encode_s
    )?;
    if let Some(c) = &e.estimate.check {
        writeln!(
            r,
            "  file: {} on the uniform set of {} pairs, seed {}",
            values(c),
            a.samples,
            a.seed
        )?;
    }
    writeln!(
        r,
        "        {} at most on any independent uniform set of {} pairs (3σ upper values from {} stratified pairs)",
        values(&e.estimate.upper),
        a.samples,
        planned.estimate_samples
    )?;
    writeln!(
        r,
        "  grid alone: {} (the uncompressed table against the input)",
        values(e.floor.check.as_ref().unwrap_or(&e.floor.metrics))
    )?;
    report(a, &r, &machine)
}

/// `compress FILE.bsdf --max-error B`: the RGL file packed in its own parameterization.
fn compress_rgl(
    a: &CompressArgs,
    source: &crate::io::rgl::RglBsdf,
    budget: &Budget,
    settings: &PackSettings,
    progress: crate::plan::rate::Progress,
    bar: &Bar,
    reads: &ReadSet,
) -> anyhow::Result<i32> {
    use crate::brdf::Brdf;
    let provenance = crate::table::Provenance {
        source: source.describe(),
        tool: crate::TOOL_VERSION.to_string(),
        notes: Vec::new(),
    };
    let planned = crate::plan::rgl::plan_rgl(source, settings, false, &provenance, progress);
    bar.finish();
    let planned = planned?;
    atomic::write_output(&a.output, &planned.bytes)?;
    a.depfile.write(&[a.output.as_path()], reads)?;
    let machine = json!({
        "output": a.output.display().to_string(),
        "form": crate::io::rgl::packed::FORMAT,
        "coding": planned.options.coding,
        "vndf": planned.options.vndf.name(),
        "bytes": planned.bytes.len(),
        "budget": budget.bounds,
        "file": planned.estimate,
        "form_alone": planned.floor,
        "samples": a.samples,
        "seed": a.seed,
    });
    let values = |m: &crate::check::Metrics| super::pack::budget_values(&budget.bounds, m);
    use std::fmt::Write as _;
    let mut r = String::new();
    writeln!(r, "output: {}", a.output.display())?;
    writeln!(
        r,
        "form: {} (the RGL file in its own parameterization; VNDF {})",
        crate::io::rgl::packed::FORMAT,
        planned.options.vndf.name()
    )?;
    writeln!(r, "size: {} bytes", planned.bytes.len())?;
    writeln!(
        r,
        "budget {}: met by the written file against the input ({} codings tried)",
        budget.describe(),
        planned.attempts.len()
    )?;
    if let Some(c) = &planned.estimate.check {
        writeln!(
            r,
            "  file: {} on the uniform set of {} pairs, seed {}",
            values(c),
            a.samples,
            a.seed
        )?;
    }
    writeln!(
        r,
        "        {} at most on any independent uniform set of {} pairs (3σ upper values from {} pairs)",
        values(&planned.estimate.upper),
        a.samples,
        planned.estimate_samples
    )?;
    report(a, &r, &machine)
}

/// Quiet by default: the human report with -v (stderr), JSON with --json (stdout; stderr
/// with `-o -`, whose stdout holds the file's bytes).
fn report(a: &CompressArgs, human: &str, machine: &serde_json::Value) -> anyhow::Result<i32> {
    if a.verbose {
        eprint!("{human}");
    }
    if a.json {
        let text = format!("{}\n", serde_json::to_string(machine)?);
        if a.output.as_os_str() == "-" {
            eprint!("{text}");
        } else {
            out!("{text}");
        }
    }
    Ok(0)
}
