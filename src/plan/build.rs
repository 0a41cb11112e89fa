//! `brdfpack build`: every material of a [`Manifest`] built in parallel (rayon; each
//! material's bytes are independent of the thread count), outputs rewritten only when their
//! bytes change, and a content-keyed cache so that unchanged materials are not even rebuilt.
//!
//! The cache (docs/build.md) lives in a directory (default `.brdfpack-cache/` beside the
//! manifest): `entries/NAME.json` holds a material's key and the hash of each output,
//! `objects/HASH` the outputs' bytes. The key is a BLAKE3 hash of the tool version, the
//! material's options (canonical JSON, scene included) and the name and bytes of every file
//! the material reads (source, `@spec.json`, optical-constant CSVs, scene file). A material
//! whose key matches and whose outputs still hold the recorded bytes is left alone (mtimes
//! unchanged, so Ninja's `restat` prunes what depends on it); a deleted output is restored
//! from `objects/`.

use super::budget::Budget;
use super::grids::default_grid;
use super::manifest::{Manifest, Material, SceneRef};
use super::pack::{PackInput, PackSettings, plan};
use super::rate::Effort;
use super::scene::Scene;
use crate::codec::CodecRequest;
use crate::grid::parse_grid_spec;
use crate::io::{FormatName, OutputFormat, atomic, encode_table};
use crate::model::Model;
use crate::reads::ReadSet;
use crate::source::{Lookup, Source};
use crate::table::Table;
use crate::tabulate::{TabulateOptions, tabulate};
use crate::{Error, Result};
use rayon::prelude::*;
use serde::{Deserialize, Serialize};
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::Instant;

/// How to run a build.
#[derive(Clone, Debug, Default)]
pub struct BuildOptions {
    /// Worker threads (default: rayon's, all logical CPUs).
    pub threads: Option<usize>,
    /// Build every material even after one failed (default: stop starting new ones).
    pub keep_going: bool,
    pub cache_dir: PathBuf,
    /// Only these materials (default: all).
    pub only: Vec<String>,
    /// Ignore the cache (still compare bytes before rewriting an output).
    pub force: bool,
}

/// What happened to one material.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
#[serde(rename_all = "lowercase")]
pub enum Status {
    /// Built from its source (outputs whose bytes changed were rewritten).
    Built,
    /// Its key matched the cache and its outputs held the recorded bytes: nothing done.
    Unchanged,
    /// Its key matched; missing or changed outputs were restored from the cache.
    Restored,
    Failed,
    /// Not started: an earlier material failed (without `--keep-going`).
    Skipped,
}

/// One output of a material in the summary.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
pub struct OutputResult {
    pub path: PathBuf,
    pub bytes: u64,
    /// BLAKE3 of the bytes (hex).
    pub hash: String,
    /// True when this run wrote the file (its bytes had changed or it was missing).
    #[serde(default)]
    pub written: bool,
}

/// One material in the summary.
#[derive(Clone, Debug, Serialize)]
pub struct MaterialResult {
    pub name: String,
    pub status: Status,
    /// 0 ok, 1 failure, 2 bad input.
    pub exit_code: i32,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub error: Option<String>,
    pub outputs: Vec<OutputResult>,
    /// Every file the material read.
    pub reads: Vec<PathBuf>,
    pub key: String,
    pub seconds: f64,
}

/// The machine-readable summary of a build.
#[derive(Clone, Debug, Serialize)]
pub struct BuildSummary {
    pub tool: &'static str,
    pub manifest: PathBuf,
    pub cache_dir: PathBuf,
    pub threads: usize,
    /// The worst material's exit code.
    pub exit_code: i32,
    pub built: usize,
    pub unchanged: usize,
    pub failed: usize,
    pub seconds: f64,
    pub materials: Vec<MaterialResult>,
}

/// A cache entry: the key a material's outputs were made from, and those outputs.
#[derive(Serialize, Deserialize)]
struct Entry {
    key: String,
    outputs: Vec<OutputResult>,
}

/// The default cache directory: `.brdfpack-cache` beside the manifest.
pub fn default_cache_dir(manifest: &Path) -> PathBuf {
    manifest
        .parent()
        .filter(|p| !p.as_os_str().is_empty())
        .map_or_else(
            || PathBuf::from(".brdfpack-cache"),
            |p| p.join(".brdfpack-cache"),
        )
}

/// Builds the manifest's materials. Returns the summary and every file read (the manifest,
/// and each material's inputs) for a depfile. Errors only for problems of the whole build
/// (a bad `--material` name, an unusable cache directory); a material's failure is in its
/// result.
pub fn build(
    manifest: &Manifest,
    manifest_path: &Path,
    opts: &BuildOptions,
) -> Result<(BuildSummary, ReadSet)> {
    let t0 = Instant::now();
    for name in &opts.only {
        if !manifest.materials.iter().any(|m| &m.name == name) {
            return Err(Error::input(format!(
                "--material {name}: no such material in {}",
                manifest_path.display()
            )));
        }
    }
    let chosen: Vec<&Material> = manifest
        .materials
        .iter()
        .filter(|m| opts.only.is_empty() || opts.only.contains(&m.name))
        .collect();
    for sub in ["entries", "objects"] {
        let d = opts.cache_dir.join(sub);
        std::fs::create_dir_all(&d).map_err(|e| Error::io(&d, e))?;
    }
    let stop = AtomicBool::new(false);
    let run = || -> Vec<MaterialResult> {
        chosen
            .par_iter()
            .map(|m| {
                if stop.load(Ordering::SeqCst) {
                    return MaterialResult {
                        name: m.name.clone(),
                        status: Status::Skipped,
                        exit_code: 1,
                        error: Some("not started: an earlier material failed".into()),
                        outputs: Vec::new(),
                        reads: Vec::new(),
                        key: String::new(),
                        seconds: 0.0,
                    };
                }
                let r = build_material(m, opts);
                if r.status == Status::Failed && !opts.keep_going {
                    stop.store(true, Ordering::SeqCst);
                }
                r
            })
            .collect()
    };
    let (materials, threads) = match opts.threads {
        Some(n) => {
            let pool = rayon::ThreadPoolBuilder::new()
                .num_threads(n)
                .build()
                .map_err(|e| Error::Failure(format!("--threads {n}: {e}")))?;
            (pool.install(run), n)
        }
        None => (run(), rayon::current_num_threads()),
    };
    let mut reads = ReadSet::new();
    reads.record(manifest_path);
    for m in &materials {
        for p in &m.reads {
            reads.record(p);
        }
    }
    let count = |s: Status| materials.iter().filter(|m| m.status == s).count();
    let summary = BuildSummary {
        tool: crate::TOOL_VERSION,
        manifest: manifest_path.to_path_buf(),
        cache_dir: opts.cache_dir.clone(),
        threads,
        exit_code: materials.iter().map(|m| m.exit_code).max().unwrap_or(0),
        built: count(Status::Built),
        unchanged: count(Status::Unchanged) + count(Status::Restored),
        failed: count(Status::Failed) + count(Status::Skipped),
        seconds: t0.elapsed().as_secs_f64(),
        materials,
    };
    Ok((summary, reads))
}

fn build_material(m: &Material, opts: &BuildOptions) -> MaterialResult {
    let t0 = Instant::now();
    let mut reads = ReadSet::new();
    let mut key = String::new();
    let result = (|| -> Result<(Status, Vec<OutputResult>)> {
        let scene = match &m.scene {
            None => Scene::default(),
            Some(SceneRef::Inline(s)) => s.clone(),
            Some(SceneRef::File(p)) => Scene::load(p, &mut reads)?,
        };
        source_reads(&m.source, &mut reads)?;
        refuse_outputs_that_are_inputs(m, &reads)?;
        key = content_key(m, &scene, &reads)?;
        let entry_path = opts
            .cache_dir
            .join("entries")
            .join(format!("{}.json", m.name));
        if !opts.force
            && let Some(entry) = read_entry(&entry_path)
            && entry.key == key
            && let Some((status, outputs)) = reuse(&entry, opts)?
        {
            return Ok((status, outputs));
        }
        let outputs = make_outputs(m, &scene)?;
        let mut results = Vec::new();
        for (path, bytes) in outputs {
            let hash = blake3::hash(&bytes).to_hex().to_string();
            let object = opts.cache_dir.join("objects").join(&hash);
            if !object.exists() {
                atomic::write_output(&object, &bytes)?;
            }
            let written = write_if_changed(&path, &bytes)?;
            results.push(OutputResult {
                path,
                bytes: bytes.len() as u64,
                hash,
                written,
            });
        }
        let entry = Entry {
            key: key.clone(),
            outputs: results.clone(),
        };
        let text = serde_json::to_vec_pretty(&entry).map_err(|e| Error::Failure(e.to_string()))?;
        atomic::write_output(&entry_path, &text)?;
        Ok((Status::Built, results))
    })();
    let (status, exit_code, error, outputs) = match result {
        Ok((s, o)) => (s, 0, None, o),
        Err(e) => (
            Status::Failed,
            e.exit_code(),
            Some(crate::text::sanitize_line(&e.to_string())),
            Vec::new(),
        ),
    };
    MaterialResult {
        name: m.name.clone(),
        status,
        exit_code,
        error,
        outputs,
        reads: reads.paths().map(Path::to_path_buf).collect(),
        key,
        seconds: t0.elapsed().as_secs_f64(),
    }
}

/// The files a source spec reads, found without decoding them (as [`Source::open`] decides:
/// a model spec first, unless the name is an explicit path).
fn source_reads(spec: &str, reads: &mut ReadSet) -> Result<()> {
    let explicit = spec.starts_with("./") || spec.starts_with("../") || spec.starts_with('/');
    if !explicit {
        let mut model_reads = ReadSet::new();
        if Model::parse_recording(spec, &mut model_reads).is_ok() {
            reads.extend(&model_reads);
            return Ok(());
        }
    }
    if Path::new(spec).exists() {
        reads.record(spec);
        return Ok(());
    }
    // Not a model and no file: opening it gives the error that says which.
    Source::open(spec).map(|_| ())
}

/// Refuses (bad input) a material one of whose outputs is a file it reads (its source, a
/// `@spec.json`, an optical-constant CSV, its scene file): writing it would replace the
/// input with its own encoding, lossy under a codec or a budget, before the next build reads
/// it again. Compared as the file system resolves them (symbolic links, `./`, `..`).
fn refuse_outputs_that_are_inputs(m: &Material, reads: &ReadSet) -> Result<()> {
    let same = |a: &Path, b: &Path| match (std::fs::canonicalize(a), std::fs::canonicalize(b)) {
        (Ok(a), Ok(b)) => a == b,
        _ => false,
    };
    for out in &m.outputs {
        if let Some(input) = reads.paths().find(|r| same(out, r)) {
            return Err(Error::input(format!(
                "material {:?}: output {} is {}, which the material reads; writing it would                  replace its own input (choose another output path)",
                m.name,
                crate::text::sanitize(&out.display().to_string()),
                crate::text::sanitize(&input.display().to_string())
            )));
        }
    }
    Ok(())
}

/// The content key: tool version, options and every read file's name and bytes.
fn content_key(m: &Material, scene: &Scene, reads: &ReadSet) -> Result<String> {
    let mut h = blake3::Hasher::new();
    h.update(crate::TOOL_VERSION.as_bytes());
    h.update(b"\0");
    let options = serde_json::json!({"material": m, "scene": scene});
    h.update(options.to_string().as_bytes());
    for p in reads.paths() {
        h.update(b"\0file\0");
        h.update(p.as_os_str().as_encoded_bytes());
        h.update(b"\0");
        let bytes = atomic::read_input(p)?;
        h.update(blake3::hash(&bytes).as_bytes());
    }
    Ok(h.finalize().to_hex().to_string())
}

fn read_entry(path: &Path) -> Option<Entry> {
    let bytes = std::fs::read(path).ok()?;
    serde_json::from_slice(&bytes).ok()
}

/// With a matching key: `Unchanged` when every output holds its recorded bytes, `Restored`
/// when missing or altered ones could be put back from the objects; `None` (rebuild) when an
/// object is gone.
fn reuse(entry: &Entry, opts: &BuildOptions) -> Result<Option<(Status, Vec<OutputResult>)>> {
    let mut status = Status::Unchanged;
    let mut outputs = Vec::new();
    for o in &entry.outputs {
        let current = std::fs::read(&o.path).ok();
        let intact = current.as_ref().is_some_and(|b| {
            b.len() as u64 == o.bytes && blake3::hash(b).to_hex().as_str() == o.hash
        });
        let mut o = o.clone();
        o.written = false;
        if !intact {
            let Ok(bytes) = std::fs::read(opts.cache_dir.join("objects").join(&o.hash)) else {
                return Ok(None);
            };
            if blake3::hash(&bytes).to_hex().as_str() != o.hash {
                return Ok(None);
            }
            atomic::write_output(&o.path, &bytes)?;
            o.written = true;
            status = Status::Restored;
        }
        outputs.push(o);
    }
    Ok(Some((status, outputs)))
}

/// Writes `bytes` unless the file already holds exactly them (its mtime then stays).
fn write_if_changed(path: &Path, bytes: &[u8]) -> Result<bool> {
    if let Ok(old) = std::fs::read(path)
        && old == bytes
    {
        return Ok(false);
    }
    if let Some(dir) = path.parent().filter(|d| !d.as_os_str().is_empty()) {
        std::fs::create_dir_all(dir).map_err(|e| Error::io(dir, e))?;
    }
    atomic::write_output(path, bytes)?;
    Ok(true)
}

/// Makes a material's output bytes: one table (planned within the budget, or tabulated on the
/// grid), encoded in each output's format.
fn make_outputs(m: &Material, scene: &Scene) -> Result<Vec<(PathBuf, Vec<u8>)>> {
    let source = Source::open(&m.source)?.clamp_negative(m.clamp_negative);
    source.require_valid_cells()?;
    // An RGL file with native outputs only and no grid: packed in its own parameterization
    // (issue #19), as `pack` packs it.
    if let Source::Measured(r) = &source
        && m.grid.is_none()
        && scene.is_empty()
        && super::rgl::unsupported(r).is_none()
        && m.outputs
            .iter()
            .all(|p| FormatName::from_path(p) == Some(FormatName::Native))
    {
        let budget = m.max_error.as_deref().or(scene.max_error.as_deref());
        let lossless = m.codec.as_deref().map(str::trim) == Some("lossless");
        if lossless || (budget.is_some() && m.codec.is_none()) {
            let effort = Effort::parse(m.effort.as_deref().unwrap_or("default"))?;
            let settings = PackSettings {
                budget: Budget::parse(budget.unwrap_or(super::budget::PRODUCTION))?,
                effort,
                check_samples: 65_536,
                check_seed: 1,
            };
            let provenance = crate::table::Provenance {
                source: crate::brdf::Brdf::describe(r),
                tool: crate::TOOL_VERSION.to_string(),
                notes: Vec::new(),
            };
            let planned = super::rgl::plan_rgl(r, &settings, lossless, &provenance, &|_| {})?;
            return Ok(m
                .outputs
                .iter()
                .map(|p| (p.clone(), planned.bytes.clone()))
                .collect());
        }
    }
    let src = scene.restrict_source(source.into_brdf(Lookup::Linear)?)?;
    let options = TabulateOptions {
        allow_anisotropic: m.allow_anisotropic || scene.isotropic == Some(true),
        allow_nonreciprocal: m.allow_nonreciprocal,
        fill_own_holes: false,
        progress: None,
    };
    let grid = match &m.grid {
        Some(g) => Some(parse_grid_spec(g)?),
        None => None,
    };
    let grid = match (grid, scene.theta_max_deg()) {
        (Some(g), _) => Some(scene.restrict_grid(&g)?),
        (None, Some(_)) => Some(scene.restrict_grid(&default_grid(src.as_ref())?)?),
        (None, None) => None,
    };
    let budget = m
        .max_error
        .as_deref()
        .or(scene.max_error.as_deref())
        .filter(|_| m.codec.is_none());
    let (table, native): (Table, _) = match budget {
        Some(b) => {
            let effort = Effort::parse(m.effort.as_deref().unwrap_or("default"))?;
            let planned = plan(
                PackInput::Source {
                    source: src.as_ref(),
                    grid,
                    options,
                },
                &PackSettings {
                    budget: Budget::parse(b)?,
                    effort,
                    check_samples: 65_536,
                    check_seed: 1,
                },
                &|_| {},
            )?;
            // The measured candidate's own bytes are written, as `pack` writes them.
            let encoded = planned.encoded;
            (planned.table, Some((encoded.spec, encoded.payload)))
        }
        None => {
            let grid = match grid {
                Some(g) => g,
                None => default_grid(src.as_ref())?,
            };
            (tabulate(src.as_ref(), &grid, &options)?, None)
        }
    };
    let mut out = Vec::new();
    for path in &m.outputs {
        let format = match (FormatName::from_path(path), &native) {
            // The planned candidate's own bytes, as `pack` writes them.
            (Some(FormatName::Native), Some((spec, payload))) => {
                let bytes = crate::io::native::to_bytes_with_payload(&table, spec, payload)?;
                out.push((path.clone(), bytes));
                continue;
            }
            (Some(FormatName::Native), None) => OutputFormat::Native(
                CodecRequest::parse(m.codec.as_deref().unwrap_or("lossless"))?.resolve(&table)?,
            ),
            (Some(FormatName::Exr), _) => OutputFormat::Exr(Default::default()),
            (Some(FormatName::Merl), _) => OutputFormat::Merl,
            (Some(FormatName::Mbsdf), _) => OutputFormat::Mbsdf(Default::default()),
            _ => {
                return Err(Error::input(format!(
                    "output {}: use .bpk, .exr, .binary or .mbsdf",
                    path.display()
                )));
            }
        };
        let bytes = encode_table(&table, &format)
            .map_err(|e| Error::input(format!("output {}: {e}", path.display())))?;
        out.push((path.clone(), bytes));
    }
    Ok(out)
}
