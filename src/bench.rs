//! `brdfpack bench`: timings of the hot paths (for the peer comparison of docs/benchmarks.md)
//! and a matrix of sources × grids × codecs with sizes, times and round-trip errors.
//!
//! Every timing is the median of repeated runs after one warm-up run, with min and max beside
//! it; tabulation writes into memory reused between runs (`tabulate_into`).

use crate::brdf::Brdf;
use crate::check::{CheckOptions, SampleSet, check};
use crate::codec::{CodecRequest, CodecSpec};
use crate::grid::{Grid, parse_grid_spec};
use crate::io::native;
use crate::model::Model;
use crate::table::{Interp, InterpolatedTable, Table};
use crate::tabulate::{TabulateOptions, tabulate, tabulate_into};
use crate::{Error, Result};
use serde::Serialize;
use std::path::Path;
use std::time::Instant;

/// Median, min and max of repeated runs, in seconds.
#[derive(Clone, Debug, Serialize)]
pub struct Timing {
    pub runs: usize,
    pub median_s: f64,
    pub min_s: f64,
    pub max_s: f64,
}

/// Runs `f` once to warm up, then `runs` times; the median of the timed runs.
pub fn time_runs(runs: usize, mut f: impl FnMut()) -> Timing {
    f();
    let mut t: Vec<f64> = (0..runs.max(1))
        .map(|_| {
            let t0 = Instant::now();
            f();
            t0.elapsed().as_secs_f64()
        })
        .collect();
    t.sort_by(f64::total_cmp);
    Timing {
        runs: t.len(),
        median_s: median_sorted(&t),
        min_s: t[0],
        max_s: t[t.len() - 1],
    }
}

fn median_sorted(t: &[f64]) -> f64 {
    let n = t.len();
    if n % 2 == 1 {
        t[n / 2]
    } else {
        0.5 * (t[n / 2 - 1] + t[n / 2])
    }
}

/// The machine a benchmark ran on.
#[derive(Clone, Debug, Serialize)]
pub struct Machine {
    pub cpu: String,
    pub logical_cpus: usize,
    pub threads: usize,
    pub simd: &'static str,
    pub os: &'static str,
    pub tool: &'static str,
}

impl Machine {
    pub fn detect() -> Machine {
        let cpu = std::fs::read_to_string("/proc/cpuinfo")
            .ok()
            .and_then(|s| {
                s.lines()
                    .find(|l| l.starts_with("model name"))
                    .and_then(|l| l.split(':').nth(1))
                    .map(|s| s.trim().to_string())
            })
            .unwrap_or_else(|| "unknown".into());
        Machine {
            cpu,
            logical_cpus: std::thread::available_parallelism().map_or(1, |n| n.get()),
            threads: rayon::current_num_threads(),
            simd: if crate::simd::avx2_fma() {
                "avx2+fma (runtime dispatch)"
            } else {
                "sse2 baseline"
            },
            os: std::env::consts::OS,
            tool: crate::TOOL_VERSION,
        }
    }

    pub fn describe(&self) -> String {
        format!(
            "{}; {} logical CPUs; {} rayon threads; {}; {}",
            self.cpu, self.logical_cpus, self.threads, self.simd, self.tool
        )
    }
}

/// The GGX conductor of the peer comparison (copper-like η, k of shared/peers/README.md);
/// separable Smith G like Mitsuba's `roughconductor`.
pub const PEER_GGX: &str = "ggx:alpha=0.2,shadowing=smith-separable,fresnel=conductor,\
                            eta=0.2004/0.924/1.1022,k=3.9129/2.4528/2.1421";
/// The anisotropic GGX conductor of the peer comparison (gold-like η, k).
pub const PEER_GGX_ANISO: &str = "ggx:alpha_x=0.1,alpha_y=0.4,shadowing=smith-separable,\
                                  fresnel=conductor,eta=0.1431/0.3749/1.4425,k=3.9831/2.3857/1.6032";
/// 64⁴ half/difference grid placed like `ref_table.py --grid aniso4d --n 64` (sqrt θh, lower
/// edges). Its φd axis spans 2π where the peer's spans π: the same number of cells.
pub const PEER_ANISO_GRID: &str = "halfdiff4:64,warp=sqrt/linear/linear/linear,at=edge";

/// One speed measurement.
#[derive(Clone, Debug, Serialize)]
pub struct SpeedResult {
    pub name: String,
    /// Cells tabulated or pairs looked up per run.
    pub items: usize,
    pub timing: Timing,
    pub items_per_s: f64,
}

/// The workloads of the peer comparison (issue 6): tabulating [`PEER_GGX`] on the MERL grid
/// and [`PEER_GGX_ANISO`] on [`PEER_ANISO_GRID`] into reused memory, and 10⁶ random
/// interpolated lookups (batches of 10⁶) in the MERL-grid table. `which` filters by name
/// prefix (`tabulate`, `lookup`); `lookup_pairs` sets the batch size.
pub fn speed_suite(runs: usize, which: &str, lookup_pairs: usize) -> Result<Vec<SpeedResult>> {
    let opts = TabulateOptions::default();
    let mut out = Vec::new();
    let mut push = |name: &str, items: usize, timing: Timing| {
        out.push(SpeedResult {
            name: name.into(),
            items,
            items_per_s: items as f64 / timing.median_s,
            timing,
        })
    };
    let merl = Grid::merl();
    let ggx = Model::parse(PEER_GGX)?;
    let mut table = tabulate(&ggx, &merl, &opts)?;
    if "tabulate_merl_ggx_conductor".starts_with(which) || which.is_empty() {
        let mut err = None;
        let t = time_runs(runs, || {
            if let Err(e) = tabulate_into(&ggx, &merl, &opts, &mut table) {
                err = Some(e);
            }
        });
        if let Some(e) = err {
            return Err(e);
        }
        push("tabulate_merl_ggx_conductor", merl.cells(), t);
    }
    if "tabulate_aniso64_ggx_conductor".starts_with(which) || which.is_empty() {
        let g = parse_grid_spec(PEER_ANISO_GRID)?;
        let m = Model::parse(PEER_GGX_ANISO)?;
        let mut t4 = tabulate(&m, &g, &opts)?;
        let mut err = None;
        let t = time_runs(runs, || {
            if let Err(e) = tabulate_into(&m, &g, &opts, &mut t4) {
                err = Some(e);
            }
        });
        if let Some(e) = err {
            return Err(e);
        }
        push("tabulate_aniso64_ggx_conductor", g.cells(), t);
    }
    if "lookup_merl_table_linear".starts_with(which) || which.is_empty() {
        let set = SampleSet::uniform(lookup_pairs, 1);
        let mut vals = vec![0.0; set.pairs.len() * 3];
        let t = time_runs(runs, || {
            table.eval_batch(&set.pairs, Interp::Linear, &mut vals);
        });
        push("lookup_merl_table_linear", set.pairs.len(), t);
    }
    Ok(out)
}

/// One source of the matrix.
pub struct MatrixSource {
    pub name: String,
    pub brdf: Box<dyn Brdf>,
    /// Grids to tabulate it on.
    pub grids: Vec<String>,
}

/// Options of [`run_matrix`].
#[derive(Clone, Debug)]
pub struct MatrixOptions {
    pub quick: bool,
    pub runs: usize,
    /// Pairs per `check` sample set and per lookup timing batch.
    pub samples: usize,
    /// `../shared/data` (or another folder with `rgl/*.bsdf`), when present.
    pub shared_data: Option<std::path::PathBuf>,
}

/// The codecs of the matrix. New codecs (branch `codec`) are added here.
pub fn bench_codecs(quick: bool) -> Vec<&'static str> {
    if quick {
        vec!["lossless", "dct:step=0.05"]
    } else {
        vec![
            "zstd-f32",
            "lossless",
            "f16",
            "uniform:bits=12",
            "dct:step=0.01",
            "dct:step=0.03",
            "dct:step=0.1",
        ]
    }
}

/// The family of a codec label (`dct`, `lossless`, `f16`, …): what a plot marker shows.
pub fn codec_family(label: &str) -> &str {
    label.split(':').next().unwrap_or(label)
}

/// The sources of the matrix: a diffuse, a glossy conductor, an anisotropic model, and the
/// RGL measured materials of `shared_data` when present.
pub fn matrix_sources(opts: &MatrixOptions) -> Result<Vec<MatrixSource>> {
    let (iso_grids, aniso_grids): (Vec<&str>, Vec<&str>) = if opts.quick {
        (
            vec!["halfdiff3:16x16x32,warp=sqrt/linear/linear"],
            vec!["halfdiff4:8x8x8x16,warp=sqrt/linear/linear/linear"],
        )
    } else {
        (
            vec![
                "halfdiff3:32x32x64,warp=sqrt/linear/linear",
                "merl",
                "spherical3:32x32x32",
            ],
            vec![
                "halfdiff4:16x16x16x32,warp=sqrt/linear/linear/linear",
                "halfdiff4:32x32x32x64,warp=sqrt/linear/linear/linear",
            ],
        )
    };
    let own = |v: &[&str]| v.iter().map(|s| s.to_string()).collect::<Vec<_>>();
    let mut out = vec![
        MatrixSource {
            name: "lambert".into(),
            brdf: Box::new(Model::parse("lambert:albedo=0.8/0.5/0.2")?),
            grids: own(&iso_grids[..1]),
        },
        MatrixSource {
            name: "ggx-conductor".into(),
            brdf: Box::new(Model::parse(PEER_GGX)?),
            grids: own(&iso_grids),
        },
        MatrixSource {
            name: "ward-aniso".into(),
            brdf: Box::new(Model::parse(
                "ward:alpha_x=0.1,alpha_y=0.3,rho_s=0.3,rho_d=0.1",
            )?),
            grids: own(&aniso_grids),
        },
    ];
    if let Some(dir) = &opts.shared_data {
        let mut files: Vec<_> = std::fs::read_dir(dir.join("rgl"))
            .map(|d| {
                d.filter_map(|e| e.ok().map(|e| e.path()))
                    .filter(|p| p.extension().is_some_and(|x| x == "bsdf"))
                    .collect()
            })
            .unwrap_or_default();
        files.sort();
        // One measured material is enough to keep --quick under a minute.
        let take = if opts.quick { 1 } else { files.len() };
        for f in files.into_iter().take(take) {
            let b = crate::io::rgl::RglBsdf::open(&f)?;
            // Measured data are not reciprocal: no φd fold (halfdiff3 refuses them).
            let grids = if opts.quick {
                own(&["spherical3:16x16x32"])
            } else {
                own(&["spherical3:32x32x32", "spherical3:64x64x64"])
            };
            out.push(MatrixSource {
                name: f
                    .file_stem()
                    .map_or("rgl".into(), |s| s.to_string_lossy().into_owned()),
                brdf: Box::new(b),
                grids,
            });
        }
        // The MERL-format materials, on their own grid (the table reproduces itself there).
        if !opts.quick {
            let mut merl: Vec<_> = std::fs::read_dir(dir.join("merl"))
                .map(|d| {
                    d.filter_map(|e| e.ok().map(|e| e.path()))
                        .filter(|p| p.extension().is_some_and(|x| x == "binary"))
                        .collect()
                })
                .unwrap_or_default();
            merl.sort();
            for f in merl {
                let table = crate::io::read_table(&f)?.without_exact();
                out.push(MatrixSource {
                    name: f
                        .file_stem()
                        .map_or("merl".into(), |s| s.to_string_lossy().into_owned()),
                    brdf: Box::new(crate::table::InterpolatedTable {
                        table,
                        interp: crate::table::Interp::Linear,
                    }),
                    grids: own(&["merl"]),
                });
            }
        }
    }
    Ok(out)
}

/// One row of the matrix.
#[derive(Clone, Debug, Serialize)]
pub struct MatrixRow {
    pub source: String,
    pub grid: String,
    pub codec: String,
    pub cells: usize,
    pub valid_cells: usize,
    pub channels: usize,
    /// The whole file as written (header + payload).
    pub bytes: usize,
    /// bytes · 8 / (valid cells × channels).
    pub bits_per_sample: f64,
    /// Raw f32 size of every cell (cells × channels × 4) / bytes.
    pub compression_ratio: f64,
    pub tabulate_s: f64,
    pub encode_s: f64,
    pub decode_s: f64,
    pub lookups_per_s: f64,
    /// Seconds per lookup (1 / lookups_per_s).
    pub lookup_s: f64,
    /// `crate::check` metrics of the decoded table against the source (uniform set, pooled).
    pub rmse: f64,
    pub rel_rmse: f64,
    pub log_rmse: f64,
    pub max_rel: f64,
    pub p99_rel_core: f64,
    /// Worst log_rmse over the grazing, specular and cells sets.
    pub worst_other_log_rmse: f64,
    pub runs: usize,
}

/// Runs the matrix; `progress` is called with a line per finished row.
pub fn run_matrix(
    opts: &MatrixOptions,
    mut progress: impl FnMut(&MatrixRow),
) -> Result<Vec<MatrixRow>> {
    let sources = matrix_sources(opts)?;
    let codecs = bench_codecs(opts.quick);
    let topts = TabulateOptions::default();
    let mut rows = Vec::new();
    let lookups = SampleSet::uniform(opts.samples, 2);
    for src in &sources {
        for gspec in &src.grids {
            let grid = parse_grid_spec(gspec)?;
            let mut table = tabulate(src.brdf.as_ref(), &grid, &topts)?;
            let mut err = None;
            let tab_t = time_runs(opts.runs, || {
                if let Err(e) = tabulate_into(src.brdf.as_ref(), &grid, &topts, &mut table) {
                    err = Some(e);
                }
            });
            if let Some(e) = err {
                return Err(e);
            }
            for request in &codecs {
                // Data-derived parameters (scales, ε, colour transform) are fitted per table;
                // rows and plots name the codec by the request as typed (`dct:step=0.03`),
                // the fitted values being in the file's header.
                let label = request.to_string();
                let codec = CodecRequest::parse(request)?.resolve(&table)?;
                let row = matrix_row(src, gspec, &table, (&label, &codec), &tab_t, &lookups, opts)?;
                progress(&row);
                rows.push(row);
            }
        }
    }
    Ok(rows)
}

fn matrix_row(
    src: &MatrixSource,
    gspec: &str,
    table: &Table,
    // The codec as requested (the rows' label) and as resolved for this table.
    (label, codec): (&str, &CodecSpec),
    tab_t: &Timing,
    lookups: &SampleSet,
    opts: &MatrixOptions,
) -> Result<MatrixRow> {
    let path = Path::new("<bench>");
    let bytes = native::to_bytes(table, codec)?;
    let enc_t = time_runs(opts.runs, || {
        let _ = native::to_bytes(table, codec);
    });
    let decoded = native::from_bytes(&bytes, path)?;
    let dec_t = time_runs(opts.runs, || {
        let _ = native::from_bytes(&bytes, path);
    });
    let c = decoded.channels().len();
    let mut vals = vec![0.0; lookups.pairs.len() * c];
    let look_t = time_runs(opts.runs, || {
        decoded.eval_batch(&lookups.pairs, Interp::Linear, &mut vals);
    });
    let cand = InterpolatedTable {
        table: decoded,
        interp: Interp::Linear,
    };
    let report = check(
        src.brdf.as_ref(),
        &cand,
        Some((cand.table.grid(), cand.table.valid())),
        &CheckOptions {
            samples: opts.samples,
            seed: 1,
            all_sets: true,
        },
    )?;
    let u = &report.uniform.combined;
    let valid = cand.table.valid_count();
    let cells = cand.table.grid().cells();
    let lookups_per_s = lookups.pairs.len() as f64 / look_t.median_s;
    Ok(MatrixRow {
        source: src.name.clone(),
        grid: gspec.to_string(),
        codec: label.to_string(),
        cells,
        valid_cells: valid,
        channels: c,
        bytes: bytes.len(),
        bits_per_sample: bytes.len() as f64 * 8.0 / (valid.max(1) * c) as f64,
        compression_ratio: (cells * c * 4) as f64 / bytes.len() as f64,
        tabulate_s: tab_t.median_s,
        encode_s: enc_t.median_s,
        decode_s: dec_t.median_s,
        lookups_per_s,
        lookup_s: 1.0 / lookups_per_s,
        rmse: u.rmse,
        rel_rmse: u.rel_rmse,
        log_rmse: u.log_rmse,
        max_rel: u.max_rel,
        p99_rel_core: u.p99_rel_core,
        worst_other_log_rmse: report.worst_other.as_ref().map_or(0.0, |w| w.log_rmse),
        runs: opts.runs,
    })
}

/// The CSV columns, in order (the header line of `bench.csv`).
pub const CSV_COLUMNS: &[&str] = &[
    "source",
    "grid",
    "codec",
    "cells",
    "valid_cells",
    "channels",
    "bytes",
    "bits_per_sample",
    "compression_ratio",
    "tabulate_s",
    "encode_s",
    "decode_s",
    "lookups_per_s",
    "lookup_s",
    "rmse",
    "rel_rmse",
    "log_rmse",
    "max_rel",
    "p99_rel_core",
    "worst_other_log_rmse",
    "runs",
    "pareto_bytes",
    "pareto_lookup",
];

/// Indices of the rows on the Pareto front of (x, y), both minimized: no other row is at
/// least as good in both and better in one.
pub fn pareto_front(points: &[(f64, f64)]) -> Vec<bool> {
    points
        .iter()
        .map(|&(x, y)| {
            !points
                .iter()
                .any(|&(a, b)| a <= x && b <= y && (a < x || b < y))
        })
        .collect()
}

fn csv_field(s: &str) -> String {
    if s.contains([',', '"', '\n']) {
        format!("\"{}\"", s.replace('"', "\"\""))
    } else {
        s.to_string()
    }
}

/// Pareto flags computed within each source (comparing codecs and grids of one material;
/// a front across materials would only say which material is easiest).
pub fn pareto_by_source(rows: &[MatrixRow], x: impl Fn(&MatrixRow) -> f64) -> Vec<bool> {
    let mut out = vec![false; rows.len()];
    let mut names: Vec<&str> = rows.iter().map(|r| r.source.as_str()).collect();
    names.sort_unstable();
    names.dedup();
    for n in names {
        let idx: Vec<usize> = (0..rows.len()).filter(|&i| rows[i].source == n).collect();
        let pts: Vec<(f64, f64)> = idx
            .iter()
            .map(|&i| (x(&rows[i]), plot_error(&rows[i])))
            .collect();
        for (k, f) in pareto_front(&pts).into_iter().enumerate() {
            out[idx[k]] = f;
        }
    }
    out
}

/// The error on the plots' y axes and the Pareto fronts: log_rmse (metrics.md), floored so
/// that lossless-exact rows still have a place on a log axis.
fn plot_error(r: &MatrixRow) -> f64 {
    r.log_rmse.max(1e-12)
}

/// `bench.csv`: one line per row, header [`CSV_COLUMNS`].
pub fn to_csv(rows: &[MatrixRow]) -> String {
    let fb = pareto_by_source(rows, |r| r.bytes as f64);
    let fl = pareto_by_source(rows, |r| r.lookup_s);
    let mut s = CSV_COLUMNS.join(",");
    s.push('\n');
    for (i, r) in rows.iter().enumerate() {
        let f = [
            csv_field(&r.source),
            csv_field(&r.grid),
            csv_field(&r.codec),
            r.cells.to_string(),
            r.valid_cells.to_string(),
            r.channels.to_string(),
            r.bytes.to_string(),
            format!("{:.4}", r.bits_per_sample),
            format!("{:.4}", r.compression_ratio),
            format!("{:.6e}", r.tabulate_s),
            format!("{:.6e}", r.encode_s),
            format!("{:.6e}", r.decode_s),
            format!("{:.6e}", r.lookups_per_s),
            format!("{:.6e}", r.lookup_s),
            format!("{:.6e}", r.rmse),
            format!("{:.6e}", r.rel_rmse),
            format!("{:.6e}", r.log_rmse),
            format!("{:.6e}", r.max_rel),
            format!("{:.6e}", r.p99_rel_core),
            format!("{:.6e}", r.worst_other_log_rmse),
            r.runs.to_string(),
            fb[i].to_string(),
            fl[i].to_string(),
        ];
        s.push_str(&f.join(","));
        s.push('\n');
    }
    s
}

/// `bench.json`: `{"schema": "brdfpack-bench/1", "machine": .., "speed": [..], "rows": [..]}`.
pub fn to_json(machine: &Machine, speed: &[SpeedResult], rows: &[MatrixRow]) -> String {
    let v = serde_json::json!({
        "schema": "brdfpack-bench/1",
        "machine": machine,
        "speed": speed,
        "rows": rows,
    });
    serde_json::to_string_pretty(&v).unwrap_or_else(|_| "{}".into())
}

/// `bench.md`: the machine, the speed results and the matrix as Markdown tables.
pub fn to_markdown(machine: &Machine, speed: &[SpeedResult], rows: &[MatrixRow]) -> String {
    use std::fmt::Write;
    let mut s = String::new();
    let _ = writeln!(s, "Machine: {}\n", machine.describe());
    if !speed.is_empty() {
        let _ = writeln!(s, "| workload | items | median | min | max | items/s |");
        let _ = writeln!(s, "|---|---:|---:|---:|---:|---:|");
        for r in speed {
            let _ = writeln!(
                s,
                "| {} | {} | {:.2} ms | {:.2} ms | {:.2} ms | {:.3e} |",
                r.name,
                r.items,
                r.timing.median_s * 1e3,
                r.timing.min_s * 1e3,
                r.timing.max_s * 1e3,
                r.items_per_s
            );
        }
        s.push('\n');
    }
    if !rows.is_empty() {
        let fb = pareto_by_source(rows, |r| r.bytes as f64);
        let _ = writeln!(
            s,
            "| source | grid | codec | bytes | bits/sample | ratio | tabulate | encode | decode | lookups/s | log_rmse | rel_rmse | max_rel | Pareto (bytes) |"
        );
        let _ = writeln!(
            s,
            "|---|---|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---|"
        );
        for (r, f) in rows.iter().zip(fb) {
            let _ = writeln!(
                s,
                "| {} | `{}` | {} | {} | {:.2} | {:.2} | {:.1} ms | {:.1} ms | {:.1} ms | {:.3e} | {:.3e} | {:.3e} | {:.3e} | {} |",
                r.source,
                r.grid,
                r.codec,
                r.bytes,
                r.bits_per_sample,
                r.compression_ratio,
                r.tabulate_s * 1e3,
                r.encode_s * 1e3,
                r.decode_s * 1e3,
                r.lookups_per_s,
                r.log_rmse,
                r.rel_rmse,
                r.max_rel,
                if f { "yes" } else { "" }
            );
        }
    }
    s
}

/// An SVG scatter plot (log–log) of `plot_error` against `x` of every row, one colour per
/// source and one marker per codec family, each point labelled with its grid's dimensions, each
/// source's Pareto front drawn as a line through its (circled) points.
pub fn to_svg(
    rows: &[MatrixRow],
    x: impl Fn(&MatrixRow) -> f64,
    x_label: &str,
    title: &str,
) -> Result<String> {
    use plotters::prelude::*;
    let pts: Vec<(f64, f64)> = rows
        .iter()
        .map(|r| (x(r).max(1e-300), plot_error(r)))
        .collect();
    let front = pareto_by_source(rows, |r| x(r).max(1e-300));
    let bounds = |v: &mut dyn Iterator<Item = f64>| {
        let (lo, hi) = v.fold((f64::INFINITY, 0f64), |(a, b), x| (a.min(x), b.max(x)));
        if lo.is_finite() && hi > 0.0 {
            (lo / 2.0, hi * 2.0)
        } else {
            (1e-3, 1.0)
        }
    };
    let (x0, x1) = bounds(&mut pts.iter().map(|p| p.0));
    let (y0, y1) = bounds(&mut pts.iter().map(|p| p.1));
    let mut svg = String::new();
    {
        let root = SVGBackend::with_string(&mut svg, (900, 600)).into_drawing_area();
        let e = |e: &dyn std::fmt::Display| Error::Failure(format!("plot {title}: {e}"));
        root.fill(&WHITE).map_err(|x| e(&x))?;
        let mut chart = ChartBuilder::on(&root)
            .caption(
                format!("{title} (circled and joined: each source's Pareto front)"),
                ("sans-serif", 18),
            )
            .margin(15)
            .x_label_area_size(45)
            .y_label_area_size(70)
            .build_cartesian_2d((x0..x1).log_scale(), (y0..y1).log_scale())
            .map_err(|x| e(&x))?;
        chart
            .configure_mesh()
            .x_desc(x_label)
            .y_desc("log_rmse (uniform set)")
            .x_label_formatter(&|v| format!("{v:.0e}"))
            .y_label_formatter(&|v| format!("{v:.0e}"))
            .draw()
            .map_err(|x| e(&x))?;
        let palette = [
            RGBColor(31, 119, 180),
            RGBColor(255, 127, 14),
            RGBColor(44, 160, 44),
            RGBColor(214, 39, 40),
            RGBColor(148, 103, 189),
            RGBColor(140, 86, 75),
            RGBColor(227, 119, 194),
            RGBColor(127, 127, 127),
            RGBColor(188, 189, 34),
            RGBColor(23, 190, 207),
        ];
        let mut families: Vec<&str> = Vec::new();
        for r in rows {
            let f = codec_family(&r.codec);
            if !families.contains(&f) {
                families.push(f);
            }
        }
        let mut seen: Vec<&str> = Vec::new();
        for r in rows {
            if !seen.contains(&r.source.as_str()) {
                seen.push(r.source.as_str());
            }
        }
        for (k, n) in seen.iter().enumerate() {
            let col = palette[k % palette.len()];
            let mine: Vec<usize> = (0..rows.len()).filter(|&i| rows[i].source == *n).collect();
            let series: Vec<(f64, f64)> = mine.iter().map(|&i| pts[i]).collect();
            // This source's Pareto front: a line through its undominated points, circled.
            let mut fp: Vec<(f64, f64)> = mine
                .iter()
                .filter(|&&i| front[i])
                .map(|&i| pts[i])
                .collect();
            fp.sort_by(|a, b| a.0.total_cmp(&b.0));
            chart
                .draw_series(LineSeries::new(fp.clone(), col.stroke_width(1)))
                .map_err(|x| e(&x))?;
            chart
                .draw_series(
                    fp.into_iter()
                        .map(|p| Circle::new(p, 7, col.stroke_width(2))),
                )
                .map_err(|x| e(&x))?;
            // Each point: its codec family's marker in the source's colour, and the grid's
            // dimensions beside it, so a point says which file it is.
            for (&i, p) in mine.iter().zip(series) {
                let family = family_index(&families, codec_family(&rows[i].codec));
                let label = grid_dims(&rows[i].grid).to_string();
                draw_marker(chart.plotting_area(), p, family, col).map_err(|x| e(&x))?;
                chart
                    .draw_series(std::iter::once(
                        EmptyElement::at(p)
                            + Text::new(label, (6, -12), ("sans-serif", 10).into_font()),
                    ))
                    .map_err(|x| e(&x))?;
            }
            chart
                .draw_series(std::iter::empty::<Circle<(f64, f64), i32>>())
                .map_err(|x| e(&x))?
                .label(*n)
                .legend(move |(x, y)| {
                    Rectangle::new([(x + 4, y - 4), (x + 14, y + 4)], col.filled())
                });
        }
        // The codec families' markers, in black, along the bottom edge.
        for (k, f) in families.iter().enumerate() {
            let at = (90 + 130 * k as i32, 590);
            draw_marker(&root, at, k, BLACK).map_err(|x| e(&x))?;
            root.draw(&Text::new(
                format!("codec {f}"),
                (at.0 + 8, at.1 - 6),
                ("sans-serif", 12).into_font(),
            ))
            .map_err(|x| e(&x))?;
        }
        chart
            .configure_series_labels()
            .border_style(BLACK)
            .background_style(WHITE.mix(0.8))
            .draw()
            .map_err(|x| e(&x))?;
        root.present().map_err(|x| e(&x))?;
    }
    Ok(svg)
}

/// The position of `family` in `families` (0 when absent, which the caller never asks).
fn family_index(families: &[&str], family: &str) -> usize {
    families.iter().position(|f| *f == family).unwrap_or(0)
}

/// The grid's dimensions from its spec (`halfdiff3:16x16x32,warp=…` → `16x16x32`; `merl`
/// stays `merl`).
fn grid_dims(spec: &str) -> &str {
    let body = spec.split_once(':').map_or(spec, |(_, b)| b);
    body.split(',').next().unwrap_or(body)
}

/// Draws the marker of codec family `family` at `at`: circle, triangle, square, cross, then
/// the same hollow.
fn draw_marker<DB: plotters::prelude::DrawingBackend, CT: plotters::coord::CoordTranslate>(
    area: &plotters::prelude::DrawingArea<DB, CT>,
    at: CT::From,
    family: usize,
    col: plotters::style::RGBColor,
) -> std::result::Result<(), plotters::drawing::DrawingAreaErrorKind<DB::ErrorType>>
where
    CT::From: Clone,
{
    use plotters::prelude::*;
    let style = if (family / 4).is_multiple_of(2) {
        col.filled()
    } else {
        col.stroke_width(2)
    };
    match family % 4 {
        0 => area.draw(&Circle::new(at, 4, style)),
        1 => area.draw(&TriangleMarker::new(at, 5, style)),
        2 => area.draw(&(EmptyElement::at(at) + Rectangle::new([(-4, -4), (4, 4)], style))),
        _ => area.draw(&Cross::new(at, 4, col.stroke_width(2))),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn pareto_front_keeps_the_undominated_points() {
        let p = [(1.0, 5.0), (2.0, 2.0), (3.0, 3.0), (4.0, 1.0), (2.0, 2.0)];
        assert_eq!(pareto_front(&p), vec![true, true, false, true, true]);
    }

    #[test]
    fn timing_is_the_median() {
        let mut k = 0;
        let t = time_runs(3, || {
            k += 1;
            std::thread::sleep(std::time::Duration::from_millis(if k == 3 {
                20
            } else {
                1
            }));
        });
        assert_eq!(k, 4);
        assert!(t.max_s >= 0.019 && t.median_s < 0.015, "{t:?}");
    }
}
