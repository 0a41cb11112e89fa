//! The grid-and-codec search of `pack --max-error` for an analytic model (issue #5): the
//! smallest file whose error against the MODEL meets the budget, over a short ladder of grid
//! resolutions and, per grid, the codec search of [`crate::plan::search`].
//!
//! For each grid of the ladder (coarse to fine): tabulate; measure the uncompressed table
//! against the model on the budget's sample sets (the tabulation + interpolation error, a
//! floor no codec goes below) and skip the grid when that alone is not accepted; otherwise run
//! the codec search with every candidate measured against the model
//! ([`search_against`]). The smallest whole file wins; equal sizes go to the finer grid.
//! Nothing is chosen when no grid meets the budget: [`search_grids`] then fails with the
//! closest values reached.

use crate::brdf::Brdf;
use crate::check::{Metrics, SampleSet};
use crate::codec::CodecSpec;
use crate::grid::{Grid, parse_grid_spec};
use crate::io::native;
use crate::plan::search::{
    Budget, Evaluator, MARGIN, accepts_metrics, held_out_set, search_against,
};
use crate::table::Table;
use crate::tabulate::{TabulateOptions, tabulate};
use crate::{Error, Result};
use serde::Serialize;
use std::time::Instant;

/// MERL's halfdiff3 layout (sqrt θh, lower edges) at other resolutions.
const HALFDIFF3_LADDER: [&str; 6] = [
    "halfdiff3:45x45x90,warp=sqrt/linear/linear,at=edge",
    "halfdiff3:64x64x128,warp=sqrt/linear/linear,at=edge",
    "merl",
    // Past MERL's resolution, θh first: a narrow specular peak lives along θh alone (θd and
    // φd carry the smooth Fresnel and shadowing factors), so doubling θh buys the most
    // interpolation accuracy per cell.
    "halfdiff3:180x90x180,warp=sqrt/linear/linear,at=edge",
    "halfdiff3:360x90x180,warp=sqrt/linear/linear,at=edge",
    "halfdiff3:360x128x256,warp=sqrt/linear/linear,at=edge",
];
const SPHERICAL3_LADDER: [&str; 4] = [
    "spherical3:45x45x90",
    "spherical3:64x64x128",
    "spherical3:90x90x180",
    "spherical3:128x128x256",
];
/// No finer step: halfdiff4:96 has 85 M cells, 5× the time and memory of 64 (whose search
/// already takes minutes and ~1.2 GB of DCT coefficients for 3 channels).
const HALFDIFF4_LADDER: [&str; 3] = ["halfdiff4:32", "halfdiff4:48", "halfdiff4:64"];

/// The default grid of a source: its symmetries at about MERL's resolution — `halfdiff4:64`
/// for anisotropic sources, `spherical3:90x90x180` for isotropic non-reciprocal ones (measured
/// data), `merl` otherwise.
pub fn default_grid_spec(src: &dyn Brdf) -> &'static str {
    if !src.is_isotropic() {
        "halfdiff4:64"
    } else if !src.is_reciprocal() {
        "spherical3:90x90x180"
    } else {
        "merl"
    }
}

/// The resolutions searched for a model: the default grid's kind and layout, coarse to fine,
/// the default among them.
pub fn grid_ladder(src: &dyn Brdf) -> Vec<&'static str> {
    match default_grid_spec(src) {
        "halfdiff4:64" => HALFDIFF4_LADDER.to_vec(),
        "spherical3:90x90x180" => SPHERICAL3_LADDER.to_vec(),
        _ => HALFDIFF3_LADDER.to_vec(),
    }
}

/// How many grids of [`grid_ladder`] are always searched: those up to the default one. The
/// finer ones are a fallback, searched only when no coarser grid met the budget: on the
/// default material the 128×128×256 step took two thirds of a 950 s search for a file 2% off
/// the coarsest grid's (docs/compression.md).
pub fn always_searched(src: &dyn Brdf) -> usize {
    let ladder = grid_ladder(src);
    let default = default_grid_spec(src);
    ladder
        .iter()
        .position(|g| *g == default)
        .map_or(ladder.len(), |i| i + 1)
}

/// What happened to one grid of the ladder.
// A handful per run, in a report: the size difference between variants costs nothing.
#[allow(clippy::large_enum_variant)]
#[derive(Clone, Debug, Serialize)]
#[serde(rename_all = "snake_case", tag = "status")]
pub enum GridOutcome {
    /// The codec search found an accepted encoding: its whole file.
    Packed {
        bytes: usize,
        codec: CodecSpec,
        /// Decoded table vs the model on the search's set.
        metrics: Metrics,
        /// The same on the held-out set.
        #[serde(skip_serializing_if = "Option::is_none")]
        held_out: Option<Metrics>,
        search_s: f64,
    },
    /// Not searched (or the search found nothing), and why.
    Skipped { reason: String },
}

/// One grid of the ladder, for the report.
#[derive(Clone, Debug, Serialize)]
pub struct GridTrial {
    /// The grid spec (`tabulate --grid` syntax).
    pub grid: String,
    pub cells: usize,
    /// The uncompressed table (linear interpolation) vs the model on the search's set.
    pub tabulation: Metrics,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub tabulation_held_out: Option<Metrics>,
    pub tabulate_s: f64,
    #[serde(flatten)]
    pub outcome: GridOutcome,
    pub chosen: bool,
}

/// The winner: its table, codec, error against the model and the file's bytes.
pub struct GridChoice {
    pub table: Table,
    pub grid: String,
    pub codec: CodecSpec,
    pub metrics: Metrics,
    pub held_out: Option<Metrics>,
    pub file: Vec<u8>,
    pub tabulate_s: f64,
    pub search_s: f64,
}

/// The outcome of [`search_grids`]: every trial (ladder order) and the winner.
pub struct GridSearch {
    pub trials: Vec<GridTrial>,
    pub choice: GridChoice,
}

/// Searches `ladder` (grid specs, coarse to fine) for the smallest file of `model` whose
/// error against `model` is accepted by the codec search's rule (every bound × [`MARGIN`] on
/// `set`, every bound on its held-out set) — see the module doc. The grids after the first
/// `always` are searched only while no grid has met the budget. Fails ([`Error::Failure`],
/// exit 1) when no grid meets the budget, naming the closest values.
#[allow(clippy::too_many_arguments)] // The search's whole configuration, each one plain.
pub fn search_grids(
    model: &dyn Brdf,
    ladder: &[&str],
    always: usize,
    budget: &Budget,
    set: &SampleSet,
    level: i32,
    opts: &TabulateOptions,
) -> Result<GridSearch> {
    if ladder.is_empty() {
        return Err(Error::input("grid search: the ladder of grids is empty"));
    }
    let grids: Vec<Grid> = ladder
        .iter()
        .map(|s| parse_grid_spec(s))
        .collect::<Result<_>>()?;
    let held = held_out_set(set);
    let mut trials = Vec::with_capacity(grids.len());
    let mut best: Option<(usize, GridChoice)> = None;
    for (k, (spec, grid)) in ladder.iter().zip(&grids).enumerate() {
        if k >= always && best.is_some() {
            break;
        }
        let t0 = Instant::now();
        let table = tabulate(model, grid, opts)?;
        let tabulate_s = t0.elapsed().as_secs_f64();
        let ev = Evaluator::against(&table, model, set, held.as_ref())?;
        let (tab, tab_held) = ev.measure_uncompressed()?;
        let outcome = if !accepts_metrics(budget, &tab, tab_held.as_ref()) {
            GridOutcome::Skipped {
                reason: floor_reason(budget, &tab, tab_held.as_ref()),
            }
        } else {
            let t1 = Instant::now();
            match search_against(&table, model, budget, set, level) {
                Ok(r) => {
                    let file = native::to_bytes(&table, &r.best.spec)?;
                    let search_s = t1.elapsed().as_secs_f64();
                    let outcome = GridOutcome::Packed {
                        bytes: file.len(),
                        codec: r.best.spec.clone(),
                        metrics: r.best.metrics.clone(),
                        held_out: r.best.held_out.clone(),
                        search_s,
                    };
                    // Ladder order is coarse to fine, so `<=` hands ties to the finer grid.
                    if best
                        .as_ref()
                        .is_none_or(|(_, b)| file.len() <= b.file.len())
                    {
                        best = Some((
                            k,
                            GridChoice {
                                table,
                                grid: spec.to_string(),
                                codec: r.best.spec,
                                metrics: r.best.metrics,
                                held_out: r.best.held_out,
                                file,
                                tabulate_s,
                                search_s,
                            },
                        ));
                    }
                    outcome
                }
                // The lossless fallback reproduces the accepted floor, so this is unexpected;
                // a report entry rather than an abort keeps the other grids.
                Err(Error::Failure(msg)) => GridOutcome::Skipped { reason: msg },
                Err(e) => return Err(e),
            }
        };
        trials.push(GridTrial {
            grid: spec.to_string(),
            cells: grid.cells(),
            tabulation: tab,
            tabulation_held_out: tab_held,
            tabulate_s,
            outcome,
            chosen: false,
        });
    }
    match best {
        Some((k, choice)) => {
            trials[k].chosen = true;
            Ok(GridSearch { trials, choice })
        }
        None => Err(Error::Failure(no_grid_message(budget, set, &trials))),
    }
}

/// Why a grid's own table is not accepted.
fn floor_reason(budget: &Budget, main: &Metrics, held: Option<&Metrics>) -> String {
    let mut parts = budget.margined().exceeded(main);
    if let Some(h) = held {
        parts.extend(
            budget
                .exceeded(h)
                .into_iter()
                .map(|e| format!("{e} on the held-out set")),
        );
    }
    format!(
        "the uncompressed table alone misses the budget ({}; bounds × {MARGIN} on the search set)",
        parts.join(", ")
    )
}

/// The failure message: the budget, the sets, and per grid the closest values reached (the
/// uncompressed table's, which no codec beats).
fn no_grid_message(budget: &Budget, set: &SampleSet, trials: &[GridTrial]) -> String {
    let closest = trials
        .iter()
        .min_by(|a, b| {
            budget
                .excess(&a.tabulation)
                .total_cmp(&budget.excess(&b.tabulation))
        })
        .expect("the ladder is not empty");
    let values = |m: &Metrics| {
        budget
            .bounds
            .iter()
            .map(|(k, _)| format!("{k} {:.4e}", m.get(k).unwrap_or(f64::NAN)))
            .collect::<Vec<_>>()
            .join(", ")
    };
    let per_grid: Vec<String> = trials
        .iter()
        .map(|t| format!("{}: {}", t.grid, values(&t.tabulation)))
        .collect();
    format!(
        "--max-error: no grid meets {} against the model ({} pairs of the {} set, seed {}; \
         bounds × {MARGIN} there and plain on the held-out set); best reached: {} on {} \
         ({:.2}× over; uncompressed tables: {}); no file written",
        budget.describe(),
        set.pairs.len(),
        set.name,
        set.seed.map_or("-".to_string(), |s| s.to_string()),
        values(&closest.tabulation),
        closest.grid,
        budget.excess(&closest.tabulation),
        per_grid.join("; ")
    )
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::check::check_set;
    use crate::model::Model;
    use crate::table::{Interp, InterpolatedTable};

    #[test]
    fn ladders_parse_and_contain_the_default_grid() {
        for m in ["ggx:alpha=0.2", "ward:alpha_x=0.1,alpha_y=0.3", "lambert"] {
            let model = Model::parse(m).unwrap();
            let ladder = grid_ladder(&model);
            assert!(ladder.len() <= 6);
            let default = parse_grid_spec(default_grid_spec(&model)).unwrap();
            let grids: Vec<Grid> = ladder.iter().map(|s| parse_grid_spec(s).unwrap()).collect();
            assert!(grids.contains(&default), "{m}: {ladder:?}");
            assert!(
                grids.windows(2).all(|w| w[0].cells() < w[1].cells()),
                "{m}: coarse to fine"
            );
        }
    }

    const SMALL_LADDER: [&str; 3] = [
        "halfdiff3:8x8x16,warp=sqrt/linear/linear,at=edge",
        "halfdiff3:16x16x32,warp=sqrt/linear/linear,at=edge",
        "halfdiff3:32x32x64,warp=sqrt/linear/linear,at=edge",
    ];

    fn run(model: &Model, budget: &str) -> Result<GridSearch> {
        run_always(model, budget, SMALL_LADDER.len())
    }

    fn run_always(model: &Model, budget: &str, always: usize) -> Result<GridSearch> {
        search_grids(
            model,
            &SMALL_LADDER,
            always,
            &Budget::parse(budget).unwrap(),
            &SampleSet::uniform(2048, 1),
            19,
            &TabulateOptions::default(),
        )
    }

    fn summary(g: &GridSearch) -> String {
        g.trials
            .iter()
            .map(|t| {
                let o = match &t.outcome {
                    GridOutcome::Packed { bytes, metrics, .. } => format!(
                        "{bytes} B log_rmse {:.3e} p99 {:.3e}",
                        metrics.log_rmse, metrics.p99_rel_core
                    ),
                    GridOutcome::Skipped { reason } => reason.clone(),
                };
                format!(
                    "{} tab {:.3e}/{:.3e}: {o}{}\n",
                    t.grid,
                    t.tabulation.log_rmse,
                    t.tabulation.p99_rel_core,
                    if t.chosen { " *" } else { "" }
                )
            })
            .collect()
    }

    #[test]
    fn a_coarser_grid_wins_when_the_budget_allows_and_its_error_is_the_checks() {
        let model = Model::parse("ggx:alpha=0.5").unwrap();
        // Loose budget: 8x8x16's own table misses it, 16x16x32 and 32x32x64 both meet it and
        // the coarser file is the smaller (1,285 vs 1,296 bytes when written).
        let g = run(&model, "log_rmse=0.01,p99_rel_core=0.2").unwrap();
        let chosen: Vec<bool> = g.trials.iter().map(|t| t.chosen).collect();
        assert_eq!(chosen, [false, true, false], "{}", summary(&g));
        assert!(matches!(g.trials[0].outcome, GridOutcome::Skipped { .. }));
        let bytes: Vec<usize> = g
            .trials
            .iter()
            .filter_map(|t| match t.outcome {
                GridOutcome::Packed { bytes, .. } => Some(bytes),
                GridOutcome::Skipped { .. } => None,
            })
            .collect();
        assert_eq!(bytes.len(), 2);
        assert!(bytes[0] < bytes[1], "{}", summary(&g));
        assert_eq!(g.choice.file.len(), bytes[0]);
        assert_eq!(g.choice.grid, SMALL_LADDER[1]);
        // Independent recompute: read the bytes back as a reader would and check them
        // against the model on the same set.
        let back = native::from_bytes(&g.choice.file, std::path::Path::new("mem")).unwrap();
        assert_eq!(back.grid(), &parse_grid_spec(SMALL_LADDER[1]).unwrap());
        let cand = InterpolatedTable {
            table: back,
            interp: Interp::Linear,
        };
        let r = check_set(&model, &cand, &SampleSet::uniform(2048, 1)).unwrap();
        assert_eq!(r.combined, g.choice.metrics);
        let budget = Budget::parse("log_rmse=0.01,p99_rel_core=0.2").unwrap();
        assert!(budget.margined().met_by(&r.combined));
        // A tighter budget that 16x16x32's own table misses moves the choice to 32x32x64.
        let g = run(&model, "log_rmse=0.005,p99_rel_core=0.1").unwrap();
        let chosen: Vec<bool> = g.trials.iter().map(|t| t.chosen).collect();
        assert_eq!(chosen, [false, false, true], "{}", summary(&g));
        // Same inputs, same bytes; with 32x32x64 as a fallback grid it is still searched
        // here (no coarser grid met the budget) and gives the same file.
        let again = run_always(&model, "log_rmse=0.005,p99_rel_core=0.1", 2).unwrap();
        assert_eq!(again.trials.len(), 3);
        assert_eq!(again.choice.file, g.choice.file);
        // ... but not once a coarser grid has met the budget.
        let g = run_always(&model, "log_rmse=0.01,p99_rel_core=0.2", 2).unwrap();
        assert_eq!(g.trials.len(), 2, "{}", summary(&g));
        assert_eq!(g.choice.grid, SMALL_LADDER[1]);
    }

    #[test]
    fn only_grids_finer_than_the_default_are_a_fallback() {
        for m in ["ggx:alpha=0.2", "ward:alpha_x=0.1,alpha_y=0.3"] {
            let model = Model::parse(m).unwrap();
            let ladder = grid_ladder(&model);
            let always = always_searched(&model);
            assert_eq!(ladder[always - 1], default_grid_spec(&model), "{m}");
        }
    }

    #[test]
    fn an_unmeetable_budget_fails_naming_the_closest_values() {
        let model = Model::parse("ggx:alpha=0.5").unwrap();
        let e = run(&model, "log_rmse=0.002,p99_rel_core=0.05")
            .err()
            .expect("32x32x64's own table has log_rmse 2.76e-3");
        assert_eq!(e.exit_code(), 1);
        let msg = e.to_string();
        for needle in [
            "no grid meets log_rmse ≤ 0.002, p99_rel_core ≤ 0.05 against the model",
            "best reached: log_rmse 2.7591e-3, p99_rel_core 3.9300e-2 on halfdiff3:32x32x64",
            "no file written",
        ] {
            assert!(msg.contains(needle), "{needle}: {msg}");
        }
    }
}
