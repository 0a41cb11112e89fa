//! `pack`'s planning: the grid and the encoding of the smallest file whose error against the
//! source meets a budget.
//!
//! The grid is the one the user fixed, or the source's default grid
//! ([`super::grids::default_grid_spec`]). When the user did not fix it and the grid's own
//! error (the uncompressed table against the source: tabulation and interpolation) misses the
//! budget, or leaves the codec little of it, a finer grid is tried: every axis doubled in
//! turn, keeping the grid whose own error uses the least of the budget (measured, so a narrow
//! peak gets θh, grazing growth θd, anisotropy φ). The walk stops when a refinement does not
//! make a smaller file. On each grid the rate control of [`super::rate`] picks the codec.

use super::budget::Budget;
use super::estimate::{ESTIMATE_PAIRS, ErrorEstimator, Estimate, ReferenceSet};
use super::grids::{axis_curvature, default_grid, reallocation, within_source_domain};
use super::rate::{
    Again, Effort, Encoded, Progress, RateOutcome, accepts, encode_within, encode_within_lending,
    prepare_coefficients,
};
use crate::brdf::Brdf;
use crate::grid::{Grid, InterpSpace, InterpWeight, Quantity, Warp};
use crate::table::Table;
use crate::tabulate::{TabulateOptions, tabulate};
use crate::{Error, Result};
use serde::Serialize;
use std::borrow::Cow;
use std::time::Instant;

/// What to pack.
// One value per plan, moved once: the owned table's inline size costs nothing.
#[allow(clippy::large_enum_variant)]
pub enum PackInput<'a> {
    /// A source to tabulate: on `grid` when given, else on its default grid (finer ones when
    /// that grid cannot meet the budget).
    Source {
        source: &'a dyn Brdf,
        grid: Option<Grid>,
        options: TabulateOptions,
    },
    /// A source the caller can open again (a stored table: as large as the table planned).
    /// On a fixed grid it is opened for the reference values and the tabulation and is not
    /// held while the codec is chosen, so that it, the tabulation and the coefficients are
    /// never in memory at once; it is opened again only if the lossless chain is chosen.
    /// Without a grid it is opened once and held, as [`PackInput::Source`].
    Reopened {
        open: Reopen<'a>,
        grid: Option<Grid>,
        options: TabulateOptions,
    },
    /// A table that is its own source (`compress` of a stored table): its grid, and its error
    /// measured against its own linear interpolation. Given owned, it becomes the planned
    /// table without a copy; borrowed, it is copied once, after the planning (the planner
    /// never holds a second copy of a stored table beside its coefficients and trials).
    Table {
        table: Cow<'a, Table>,
        /// The samples again, bit for bit (a re-read of the input file): with it an owned
        /// table lends its samples' memory to the encoder's decode buffer
        /// ([`super::rate::encode_within_lending`]).
        again: Option<Again<'a>>,
    },
}

impl PackInput<'_> {
    /// The same input, borrowed (a table given owned is lent, and copied once by a plan
    /// that keeps it).
    fn borrowed(&self) -> PackInput<'_> {
        match self {
            PackInput::Source {
                source,
                grid,
                options,
            } => PackInput::Source {
                source: *source,
                grid: grid.clone(),
                options: options.clone(),
            },
            PackInput::Reopened {
                open,
                grid,
                options,
            } => PackInput::Reopened {
                open: *open,
                grid: grid.clone(),
                options: options.clone(),
            },
            PackInput::Table { table, again } => PackInput::Table {
                table: Cow::Borrowed(table.as_ref()),
                again: *again,
            },
        }
    }
}

/// Opens a [`PackInput::Reopened`] source, the same each time.
pub type Reopen<'a> = &'a (dyn Fn() -> Result<Box<dyn Brdf>> + 'a);

/// The source while planning: the caller's, or one opened for the plan.
enum Held<'a> {
    Borrowed(&'a dyn Brdf),
    Opened(Box<dyn Brdf>),
}

impl Held<'_> {
    fn get(&self) -> &dyn Brdf {
        match self {
            Held::Borrowed(b) => *b,
            Held::Opened(b) => b.as_ref(),
        }
    }
}

/// The planner's settings.
#[derive(Clone, Debug)]
pub struct PackSettings {
    pub budget: Budget,
    pub effort: Effort,
    /// The user's check set (`--samples`, `--seed`): the file must also meet the budget there,
    /// and the upper values are stated for independent sets of this size.
    pub check_samples: usize,
    pub check_seed: u64,
}

/// One grid tried, for the report.
#[derive(Clone, Debug, Serialize)]
pub struct GridAttempt {
    pub grid: String,
    pub cells: usize,
    /// The uncompressed table against the source.
    pub floor: Estimate,
    /// The encoded payload's bytes on this grid, without the file's header (`None`: the grid
    /// alone misses the budget).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub payload_bytes: Option<usize>,
    pub tabulate_s: f64,
    pub encode_s: f64,
    pub chosen: bool,
}

/// The chosen table and encoding, and every grid tried.
pub struct Planned {
    pub table: Table,
    pub grid: String,
    pub encoded: Encoded,
    pub attempts: Vec<GridAttempt>,
    /// (stage, seconds) of the whole plan.
    pub timings: Vec<(String, f64)>,
    /// Pairs of the estimation set.
    pub estimate_samples: usize,
    pub tabulate_s: f64,
    pub encode_s: f64,
}

/// At most this many refinements past the starting grid.
const MAX_REFINEMENTS: usize = 3;
/// No refined grid beyond this many cells (4× MERL's: ~70 MB of RGB f32, ~140 MB of DCT
/// coefficients).
const MAX_REFINED_CELLS: usize = 6_000_000;
/// A grid too large to double tries its cells spent otherwise (one axis doubled, another
/// halved) when [`reallocation`] predicts the interpolation error's square to fall below
/// this share of what it is.
const EXCHANGE_PREDICTED_RATIO: f64 = 0.7;

/// The grid a refinement step moves to: measured and held, or (a grid too large to hold
/// beside another) its grid only, tabulated again.
enum Candidate {
    Held(Box<Tabulated>),
    Again(Grid),
}

/// A grid with its table and estimator, and the table's own error.
struct Tabulated {
    spec: String,
    table: Table,
    est: ErrorEstimator,
    floor: Estimate,
    tabulate_s: f64,
}

/// A file whose explicit mask is at least this share of it has its source planned again with
/// the holes filled ([`plan`]).
const MASK_SHARE_TRY_FILLED: f64 = 0.25;

/// Plans the smallest file meeting the budget (module doc). Fails with
/// [`Error::Failure`] (exit 1) naming the grids' own errors when no grid can meet it.
///
/// A table source on its own grid keeps its holes (cells its geometry holds and its values do
/// not: MERL's negative markers) as invalid cells: the table is then the source exactly, and
/// the codec fills the holes as it likes. The price is the file's explicit mask, which
/// scattered holes make large (0.5% of a MERL table's cells at random: ~9.5 KB). Filling them
/// saves at most that mask (the filled table has the same cells to code, and beside each hole
/// its own error, which leaves the codec less of the budget), so when the mask is at least
/// [`MASK_SHARE_TRY_FILLED`] of the file the source is planned again with its holes filled,
/// on the same grid, and the smaller file is kept.
pub fn plan(input: PackInput, settings: &PackSettings, progress: Progress) -> Result<Planned> {
    if settings.effort != Effort::Max {
        return plan_filled(input, settings, progress);
    }
    // `max` makes the default effort's file too and keeps the smaller: its larger estimation
    // set gives the budget's own curve another ε, and none of its rate controls need reach
    // the default's file (the chrome-steel NBRDF fit at production: 355,178 B at `max`
    // against 345,010 B at the default). A default plan that fails leaves `max` to try.
    let default_settings = PackSettings {
        effort: Effort::Default,
        ..settings.clone()
    };
    progress("planning at the default effort first");
    let Ok(default) = plan_filled(input.borrowed(), &default_settings, progress) else {
        return plan_filled(input, settings, progress);
    };
    // Kept by its payload while `max` plans (its table's samples would sit beside max's).
    let default = KeptFile::of(default)?;
    crate::memory::release_free_memory();
    let max = plan_filled(input, settings, progress);
    let bytes = default.bytes;
    default.keep_or(
        Some(max),
        |m| Ok(file_bytes(&m.encoded, &m.table)? <= bytes),
    )
}

/// The bytes a planned file takes beyond the parts every file has: its payload, its explicit
/// mask and its codec's header entry.
fn file_bytes(encoded: &Encoded, table: &Table) -> Result<usize> {
    let spec = serde_json::to_string(&encoded.spec).map_or(0, |j| j.len());
    Ok(encoded.payload.len() + crate::io::native::mask_section_bytes(table)? + spec)
}

/// A planned file kept by its payload and its table's description while another plan is
/// made: its samples (what the payload decodes to) are decoded again if it is chosen.
struct KeptFile {
    grid_spec: String,
    encoded: Encoded,
    attempts: Vec<GridAttempt>,
    timings: Vec<(String, f64)>,
    estimate_samples: usize,
    tabulate_s: f64,
    encode_s: f64,
    bytes: usize,
    /// The mask as bits: 1.4 MB as bools on the MERL grid.
    valid: crate::codec::domain::CellBits,
    channels: crate::brdf::Channels,
    provenance: crate::table::Provenance,
    grid: Grid,
}

impl KeptFile {
    fn of(planned: Planned) -> Result<KeptFile> {
        let bytes = file_bytes(&planned.encoded, &planned.table)?;
        let Planned {
            table,
            grid: grid_spec,
            encoded,
            attempts,
            timings,
            estimate_samples,
            tabulate_s,
            encode_s,
        } = planned;
        Ok(KeptFile {
            grid_spec,
            encoded,
            attempts,
            timings,
            estimate_samples,
            tabulate_s,
            encode_s,
            bytes,
            valid: crate::codec::domain::CellBits::of(table.valid()),
            channels: table.channels().clone(),
            provenance: table.provenance().clone(),
            grid: table.grid().clone(),
        })
    }

    /// `other` when it planned a file and `wins` says so, else this file, its samples decoded
    /// again; the attempts and timings of both either way, this file's first.
    fn keep_or(
        mut self,
        other: Option<Result<Planned>>,
        wins: impl Fn(&Planned) -> Result<bool>,
    ) -> Result<Planned> {
        match other {
            Some(Ok(mut other)) if wins(&other)? => {
                self.timings.append(&mut other.timings);
                other.timings = self.timings;
                self.attempts.iter_mut().for_each(|a| a.chosen = false);
                self.attempts.append(&mut other.attempts);
                other.attempts = self.attempts;
                Ok(other)
            }
            other => {
                if let Some(Ok(mut other)) = other {
                    self.timings.append(&mut other.timings);
                    other.attempts.iter_mut().for_each(|a| a.chosen = false);
                    self.attempts.append(&mut other.attempts);
                }
                self.restore()
            }
        }
    }

    fn restore(self) -> Result<Planned> {
        let cells = self.grid.cells();
        let valid: Vec<bool> = (0..cells).map(|i| self.valid.get(i)).collect();
        let samples = decode_again(
            &self.encoded,
            &crate::codec::Layout {
                grid: &self.grid,
                valid: &valid,
                channels: self.channels.len(),
            },
        )?;
        let table = Table::new(self.grid, self.channels, self.provenance, samples, valid)?;
        Ok(Planned {
            table,
            grid: self.grid_spec,
            encoded: self.encoded,
            attempts: self.attempts,
            timings: self.timings,
            estimate_samples: self.estimate_samples,
            tabulate_s: self.tabulate_s,
            encode_s: self.encode_s,
        })
    }
}

/// [`plan`] at one effort.
fn plan_filled(input: PackInput, settings: &PackSettings, progress: Progress) -> Result<Planned> {
    let filled = |options: &TabulateOptions| TabulateOptions {
        fill_own_holes: true,
        ..options.clone()
    };
    let again = match &input {
        PackInput::Source {
            source, options, ..
        } if !options.fill_own_holes => Some(PackInput::Source {
            source: *source,
            grid: None,
            options: filled(options),
        }),
        PackInput::Reopened { open, options, .. } if !options.fill_own_holes => {
            Some(PackInput::Reopened {
                open: *open,
                grid: None,
                options: filled(options),
            })
        }
        _ => None,
    };
    let first = plan_once(input, settings, progress)?;
    let Some(mut again) = again else {
        return Ok(first);
    };
    let mask = crate::io::native::mask_section_bytes(&first.table)?;
    let first_bytes = first.encoded.payload.len() + mask;
    // A lossless file carries the exact values, which the first file would have to keep
    // through the second plan; its mask is a small share of it anyway.
    if mask == 0
        || (mask as f64) < MASK_SHARE_TRY_FILLED * first_bytes as f64
        || first.encoded.spec.is_lossless()
    {
        return Ok(first);
    }
    // The first file is kept by its payload and its table's description from here on: its
    // samples (what the payload decodes to) and the table's caches would sit beside the
    // source opened again and the second plan's peak.
    let first = KeptFile::of(first)?;
    let grid = first.grid.clone();
    // What the first plan freed goes back to the kernel before the second reaches its peak.
    crate::memory::release_free_memory();
    // Only holes of a table on this very grid are filled; other invalid cells (beyond a
    // θmax table's domain) stay, and a second plan would make the same file.
    let own =
        |s: &dyn Brdf| Table::behind(s, &grid).is_some_and(|t| t.valid() != grid.geometric_mask());
    let fillable = match &mut again {
        PackInput::Source {
            source, grid: g, ..
        } => {
            *g = Some(grid.clone());
            own(*source)
        }
        PackInput::Reopened { open, grid: g, .. } => {
            *g = Some(grid.clone());
            own(open()?.as_ref())
        }
        PackInput::Table { .. } => false,
    };
    let second = if fillable {
        progress("planning again with the source's holes filled");
        Some(plan_once(again, settings, progress))
    } else {
        None
    };
    // A larger file, or a grid that the filled holes' own error puts over the budget, or
    // holes that are not the source's: the first file.
    first.keep_or(second, |s| {
        Ok(
            s.encoded.payload.len() + crate::io::native::mask_section_bytes(&s.table)?
                < first_bytes,
        )
    })
}

/// [`plan`] with the source tabulated as `input`'s options say.
fn plan_once(input: PackInput, settings: &PackSettings, progress: Progress) -> Result<Planned> {
    let mut timings = Vec::new();
    let (held, grid, options, reopen) = match input {
        PackInput::Table { table, again } => return plan_table(table, again, settings, progress),
        PackInput::Source {
            source,
            grid,
            options,
        } => (Held::Borrowed(source), grid, options, None),
        PackInput::Reopened {
            open,
            grid,
            options,
        } => {
            let t = Instant::now();
            progress("reading the source");
            let held = Held::Opened(open()?);
            timings.push(("read source".to_string(), t.elapsed().as_secs_f64()));
            (held, grid, options, Some(open))
        }
    };
    let source = held.get();
    if let Some(t) = source.as_any().and_then(|a| a.downcast_ref::<Table>()) {
        refuse_without_values(t)?;
    }
    let (start, refine) = match grid {
        Some(g) => (g, false),
        None => {
            // A table starts on its own grid, whatever that grid is: on another one its
            // interpolation adds to the new grid's, and the 16×16×32 table of a GGX lobe
            // was resampled to the 1.46 M cells of the models' default (4.4 s, a file with
            // the grid's own error against its source), as a MERL file would be on any grid
            // but MERL's ([`default_grid_spec`]).
            let g = match source.as_any().and_then(|a| a.downcast_ref::<Table>()) {
                Some(t) => within_source_domain(t.grid().clone(), source)?,
                None => default_grid(source)?,
            };
            // A table on its own grid tabulates to itself (its own error 0, its holes kept):
            // a finer grid would only re-sample its interpolation. So the grid is fixed, and
            // a source that can be opened again is not held while the codec is chosen
            // (a MERL file's 17.5 MB).
            let own = Table::behind(source, &g).is_some() && !options.fill_own_holes;
            (g, !own)
        }
    };
    let t = Instant::now();
    progress("evaluating the source on the estimation and check sets");
    let pairs = estimate_pairs(settings.effort);
    // A table stored up to θmax is measured inside that domain only, as `check` measures it:
    // beyond it the table holds no values, and errors there are errors no one asked for. So
    // is a source seen within θmax on a grid that covers more (a user's `--grid` without
    // θmax for a θmax table): beyond the source's domain there is nothing to compare with.
    let domain: Option<Grid> =
        Some(within_source_domain(start.clone(), source)?).filter(|g| g.theta_max().is_some());
    let reference = ReferenceSet::new_in(source, pairs, domain.as_ref())?;
    let check = ReferenceSet::uniform_in(
        source,
        settings.check_samples,
        settings.check_seed,
        domain.as_ref(),
    );
    // The upper values are for independent sets the size of the user's check set inside
    // the domain.
    let for_samples = check.len().max(1);
    timings.push(("reference values".to_string(), t.elapsed().as_secs_f64()));
    let tabulate_on = |source: &dyn Brdf,
                       grid: &Grid,
                       timings: &mut Vec<(String, f64)>|
     -> Result<(Table, f64)> {
        let t = Instant::now();
        progress(&format!("tabulating on {}", grid.describe()));
        let table = tabulate(source, grid, &options)?;
        let tabulate_s = t.elapsed().as_secs_f64();
        timings.push((format!("tabulate {}", grid.describe()), tabulate_s));
        Ok((table, tabulate_s))
    };
    let measure = |table: Table,
                   tabulate_s: f64,
                   try_variants: bool,
                   timings: &mut Vec<(String, f64)>|
     -> Result<Tabulated> {
        let spec = table.grid().describe();
        let t = Instant::now();
        progress(&format!("interpolation stencils on {spec}"));
        let mut table = table;
        // The estimators are compared by their upper values (the estimation set's) alone:
        // the check set's stencils are made once, for the interpolation kept (beside two
        // estimators they were the 64⁴ packs' peak).
        let mut est = ErrorEstimator::new(&table, &reference, None, for_samples)?;
        let mut floor = est.measure(table.data());
        // What is interpolated between the samples is measured too, when the planner owns
        // the grid: f itself, or f·cos θi·cos θo (a source growing like 1/cos θ at the
        // horizon is smooth only in the latter). Tried when the grid's own error is a real
        // share of the budget; the other stencils cost a fraction of a tabulation.
        let mut spec = spec;
        if refine && try_variants && floor_share(&settings.budget, &floor) > WEIGHT_TRY_SHARE {
            // The table's grid as it now interpolates, measured; kept when its own error uses
            // less of the budget than the best so far.
            let closer = |table: &Table, est: &mut ErrorEstimator, floor: &mut Estimate| {
                let e = ErrorEstimator::new_following(table, &reference, None, for_samples, est)?;
                let f = e.measure(table.data());
                let better =
                    floor_share(&settings.budget, &f) < floor_share(&settings.budget, floor);
                if better {
                    (*est, *floor) = (e, f);
                }
                Ok::<bool, Error>(better)
            };
            let table = &mut table;
            let plain = table.grid().weight();
            table.set_interp_weight(match plain {
                InterpWeight::None => InterpWeight::Cosine,
                InterpWeight::Cosine => InterpWeight::None,
            });
            if !closer(table, &mut est, &mut floor)? {
                table.set_interp_weight(plain);
            }
            // Then the log space ([`InterpSpace`]) for the weight kept: a narrow peak's
            // flanks fall by decades between samples, which linear interpolation
            // overestimates and a geometric mean follows.
            let mut kept = table.grid().space();
            for log in log_spaces_of(table, &est) {
                table.set_interp_space(log);
                if closer(table, &mut est, &mut floor)? {
                    kept = log;
                }
            }
            table.set_interp_space(kept);
            spec = table.grid().describe();
        }
        est.add_check(&table, &check)?;
        floor.check = est.measure_check(table.data());
        timings.push((
            format!("stencils and grid error {spec}"),
            t.elapsed().as_secs_f64(),
        ));
        Ok(Tabulated {
            spec,
            table,
            est,
            floor,
            tabulate_s,
        })
    };
    let mut attempts: Vec<GridAttempt> = Vec::new();
    let mut best: Option<(usize, Table, String, Encoded, f64, f64)> = None;
    let prepare = |source: &dyn Brdf, grid: &Grid, timings: &mut Vec<(String, f64)>| {
        let (table, tabulate_s) = tabulate_on(source, grid, timings)?;
        measure(table, tabulate_s, true, timings)
    };
    // A candidate measured before: its grid exactly as measured (weight and space included),
    // tabulated and measured again.
    let prepare_again = |source: &dyn Brdf, grid: &Grid, timings: &mut Vec<(String, f64)>| {
        let (table, tabulate_s) = tabulate_on(source, grid, timings)?;
        measure(table, tabulate_s, false, timings)
    };
    let (table, tabulate_s) = tabulate_on(source, &start, &mut timings)?;
    // On a fixed grid, a source that can be opened again is not held beside the
    // coefficients: only the lossless chain needs it again. The coefficients are then made
    // before the estimator's stencils, as for a stored table ([`plan_table`]).
    let held = (reopen.is_none() || refine).then_some(held);
    let mut prepared = match held {
        None => prepare_coefficients(
            &table,
            reference.epsilon(),
            reference.curve_floor(&settings.budget),
            reference.curve_scale(&settings.budget, for_samples),
            settings.effort,
            progress,
        ),
        Some(_) => None,
    };
    let mut current = measure(table, tabulate_s, true, &mut timings)?;
    let mut refinements = 0;
    let mut tight_tried = false;
    loop {
        // A grid no doubling may follow (the 64⁴ default of an anisotropic source) can still
        // spend its cells where the source needs them: which axis gains and which can give
        // is read from the tabulated values before the encoder replaces them by its decode.
        // Only while no file has met the budget (an exchange is for reach: once a file is
        // written, another 64⁴ encode costs seconds for a few bytes), and only for a grid that
        // misses it (whose encode then writes nothing either).
        let too_large_to_double =
            current.table.grid().cells().saturating_mul(2) > MAX_REFINED_CELLS;
        let exchange = if refine
            && too_large_to_double
            && best.is_none()
            && !accepts(&settings.budget, &current.floor)
        {
            let t = Instant::now();
            progress("axis curvature");
            let scale = match current.table.grid().space() {
                InterpSpace::Log { scale } => scale,
                InterpSpace::Linear => reference.epsilon(),
            };
            let shares = axis_curvature(&current.table, scale);
            timings.push(("axis curvature".to_string(), t.elapsed().as_secs_f64()));
            reallocation(&current.table.grid().desc(), &shares)
                .filter(|&(_, _, ratio)| ratio < EXCHANGE_PREDICTED_RATIO)
        } else {
            None
        };
        let t = Instant::now();
        // The tabulation again when the lossless chain is chosen: the rate control decodes
        // into the table's own memory meanwhile.
        let g = current.table.grid().clone();
        let again = || {
            with_source(held.as_ref(), reopen, |s| {
                tabulate(s, &g, &options).map(Table::into_samples)
            })
        };
        // `max` runs its codec variants on the first grid, and on a finer grid tried
        // once a file is written (at `max` a finer grid is always tried) the default's: the
        // finer grid is tried for its own error, and the variants, each a rate control of
        // seconds on 2.9 M cells, made `max` 66 s for a narrow peak over a dark body (the
        // zoo's gold α 0.01 over 0.002) against the 30 s issue #19 allows, for 62 bytes.
        let effort = match settings.effort {
            Effort::Max if best.is_some() => Effort::Default,
            e => e,
        };
        let outcome = encode_within_lending(
            &mut current.table,
            &again,
            prepared.take(),
            &current.est,
            &settings.budget,
            effort,
            progress,
        )?;
        let encode_s = t.elapsed().as_secs_f64();
        let share = floor_share(&settings.budget, &current.floor);
        let Tabulated {
            spec,
            table,
            est,
            floor,
            tabulate_s,
        } = current;
        // Neither this grid's stencils nor (unless it is the best so far) its table are held
        // while finer grids are tabulated (a 64⁴ grid: 67 MB of samples, 40 MB of stencils).
        drop(est);
        // The grid a refinement starts from (the table itself may become the best so far).
        let base = table.grid().desc();
        let met = match outcome {
            RateOutcome::GridTooCoarse { .. } => {
                attempts.push(GridAttempt {
                    grid: spec,
                    cells: table.grid().cells(),
                    floor,
                    payload_bytes: None,
                    tabulate_s,
                    encode_s,
                    chosen: false,
                });
                drop(table);
                false
            }
            RateOutcome::Encoded(e) => {
                timings.extend(e.timings.iter().cloned());
                attempts.push(GridAttempt {
                    grid: spec.clone(),
                    cells: table.grid().cells(),
                    floor,
                    payload_bytes: Some(e.payload.len()),
                    tabulate_s,
                    encode_s,
                    chosen: false,
                });
                let k = attempts.len() - 1;
                let smaller = best
                    .as_ref()
                    .is_none_or(|b| e.payload.len() < b.3.payload.len());
                let had_best = best.is_some();
                if smaller {
                    best = Some((k, table, spec, *e, tabulate_s, encode_s));
                } else {
                    drop(table);
                }
                // A refinement that did not make a smaller file ends the walk.
                !had_best || smaller
            }
        };
        // Refine while the grid alone misses the budget, or once more when it leaves the
        // codec little room (a finer grid then often makes a smaller file); stop when a
        // refinement did not make a smaller file.
        let more = match (&best, met) {
            (None, _) => true,
            (Some(_), false) => false,
            (Some(_), true) => {
                let tight = if settings.effort == Effort::Max {
                    TIGHT_FLOOR_MAX
                } else {
                    TIGHT_FLOOR
                };
                share > tight && !tight_tried
            }
        };
        if best.is_some() && met {
            tight_tried = true;
        }
        if !refine || !more || refinements >= MAX_REFINEMENTS {
            break;
        }
        // The best file so far is kept by its payload while finer grids are tabulated and
        // encoded: its table's samples (what that payload decodes to, below `max` effort,
        // whose encoder does not lend them) are made again at the end if it stays the best
        // (a 64⁴ RGB table is 201 MB).
        if settings.effort != Effort::Max
            && let Some(b) = best.as_mut()
        {
            drop(b.1.lend_samples());
        }
        // Which axis to refine is measured, not assumed: every axis doubled in turn, and the
        // grid whose own error uses the least of the budget is kept (a narrow peak wants θh,
        // the grazing 1/(cos θi cos θo) growth wants θd, anisotropy wants φ).
        let mut next: Option<(f64, Candidate)> = None;
        // Candidates of a grid too large to double are the size of the grid itself (a 64⁴ RGB
        // table and its stencils: 240 MB): only the best one's grid is kept while the next
        // is measured, and it is tabulated again once chosen.
        let consider = |sh: f64, cand: Tabulated, next: &mut Option<(f64, Candidate)>| {
            if next.as_ref().is_none_or(|(b, _)| sh < *b) {
                *next = Some((
                    sh,
                    if too_large_to_double {
                        Candidate::Again(cand.table.grid().clone())
                    } else {
                        Candidate::Held(Box::new(cand))
                    },
                ));
            }
        };
        for a in 0..base.axes.len() {
            let mut d = base.clone();
            d.axes[a].n *= 2;
            let Ok(g) = Grid::from_desc(&d) else { continue };
            if g.cells() > MAX_REFINED_CELLS {
                continue;
            }
            let cand = with_source(held.as_ref(), reopen, |s| prepare(s, &g, &mut timings))?;
            let sh = floor_share(&settings.budget, &cand.floor);
            consider(sh, cand, &mut next);
        }
        // The same cells with the θ axes that reach the horizon warped toward it (θi and θo
        // together, or θd): a source that changes fastest in the last degrees before the
        // horizon gains more from there than from any doubling.
        if base.theta_max_deg.is_none() {
            let mut d = base.clone();
            let mut changed = false;
            for a in d.axes.iter_mut() {
                if matches!(
                    a.quantity,
                    Quantity::ThetaI | Quantity::ThetaO | Quantity::ThetaD
                ) && a.warp == Warp::Linear
                {
                    a.warp = Warp::Grazing;
                    changed = true;
                }
            }
            if changed && let Ok(g) = Grid::from_desc(&d) {
                let cand = with_source(held.as_ref(), reopen, |s| prepare(s, &g, &mut timings))?;
                let sh = floor_share(&settings.budget, &cand.floor);
                consider(sh, cand, &mut next);
            }
        }
        // The same cells exchanged between two axes, as the curvature predicts; kept only when
        // its own error, measured, uses less of the budget than this grid's.
        if let Some((a, b, _)) = exchange {
            let mut d = base.clone();
            d.axes[a].n *= 2;
            d.axes[b].n /= 2;
            if let Ok(g) = Grid::from_desc(&d) {
                let cand = with_source(held.as_ref(), reopen, |s| prepare(s, &g, &mut timings))?;
                let sh = floor_share(&settings.budget, &cand.floor);
                if sh < share {
                    consider(sh, cand, &mut next);
                }
            }
        }
        let Some((_, cand)) = next else { break };
        let cand = match cand {
            Candidate::Held(t) => *t,
            Candidate::Again(g) => with_source(held.as_ref(), reopen, |s| {
                prepare_again(s, &g, &mut timings)
            })?,
        };
        current = cand;
        refinements += 1;
    }
    let Some((k, mut table, grid, encoded, tabulate_s, encode_s)) = best else {
        return Err(Error::Failure(no_grid_message(&settings.budget, &attempts)));
    };
    if table.data().is_empty() && table.grid().cells() > 0 {
        // Its samples were dropped during the refinements: the chosen file's decode again,
        // as the encoder left them.
        let samples = decode_again(&encoded, &crate::codec::Layout::of(&table))?;
        table.give_back_samples(samples);
    }
    attempts[k].chosen = true;
    Ok(Planned {
        table,
        grid,
        encoded,
        attempts,
        timings,
        estimate_samples: pairs,
        tabulate_s,
        encode_s,
    })
}

/// What a file kept by its payload alone (while other grids or a second plan were made)
/// decodes to on `layout`: the samples the encoder leaves in a planned table.
fn decode_again(encoded: &Encoded, layout: &crate::codec::Layout) -> Result<Vec<f32>> {
    let values = layout.grid.cells() * layout.channels;
    let mut samples = crate::memory::try_filled(values, 0f32, "the chosen table")?;
    encoded.spec.decode_into_with(
        &encoded.payload,
        layout,
        &mut samples,
        &mut crate::codec::DecodeScratch::lean(),
    )?;
    Ok(samples)
}

/// `f` of the source: the one held, or the [`PackInput::Reopened`] one opened again.
fn with_source<T>(
    held: Option<&Held>,
    reopen: Option<Reopen>,
    f: impl FnOnce(&dyn Brdf) -> Result<T>,
) -> Result<T> {
    match (held, reopen) {
        (Some(h), _) => f(h.get()),
        (None, Some(open)) => f(open()?.as_ref()),
        (None, None) => Err(Error::Failure(
            "internal: the planner holds no source and cannot open it again".to_string(),
        )),
    }
}

/// Pairs of the estimation set: twice as many at `--effort max`.
fn estimate_pairs(effort: Effort) -> usize {
    if effort == Effort::Max {
        2 * ESTIMATE_PAIRS
    } else {
        ESTIMATE_PAIRS
    }
}

/// [`plan`] of a table that is its own source (`compress` of a stored table): its own grid,
/// no refinement, the error measured against its own linear interpolation (its exact f64
/// values, when it has them, are not read).
/// A table without one valid cell has no value to compress or to measure a file against: a
/// budget would be met vacuously by a file of zeros (an all-invalid MERL file packed to 590
/// bytes of black, exit 0). Refused as bad input.
fn refuse_without_values(table: &Table) -> Result<()> {
    if table.valid().iter().any(|&v| v) {
        return Ok(());
    }
    Err(Error::input(format!(
        "{}: every one of its {} cells is marked invalid (for a MERL file, a negative stored \
         value), so there is no value to compress; no file written",
        table.provenance().source,
        table.valid().len()
    )))
}

fn plan_table(
    table: Cow<'_, Table>,
    again: Option<Again>,
    settings: &PackSettings,
    progress: Progress,
) -> Result<Planned> {
    refuse_without_values(&table)?;
    let mut timings = Vec::new();
    let t = Instant::now();
    progress("evaluating the source on the estimation and check sets");
    let pairs = estimate_pairs(settings.effort);
    // A table stored up to θmax is measured inside that domain only, as `check` measures it.
    let domain = Some(table.grid().clone()).filter(|g| g.theta_max().is_some());
    let spec = table.grid().describe();
    let (reference, check) = {
        let source = crate::table::InterpolatedTable {
            table: &*table,
            interp: crate::table::Interp::Linear,
        };
        (
            ReferenceSet::new_in(&source, pairs, domain.as_ref())?,
            ReferenceSet::uniform_in(
                &source,
                settings.check_samples,
                settings.check_seed,
                domain.as_ref(),
            ),
        )
    };
    timings.push(("reference values".to_string(), t.elapsed().as_secs_f64()));
    // When the encoder may lend the table's samples, its coefficients are made first: the
    // estimator's stencils (35 MB for the 52 MiB table of docs/robustness.md) are not held
    // beside the DCT's planes, the peak of the encode.
    let prepared = match (&table, again) {
        (Cow::Owned(t), Some(_)) => prepare_coefficients(
            t,
            reference.epsilon(),
            reference.curve_floor(&settings.budget),
            reference.curve_scale(&settings.budget, check.len().max(1)),
            settings.effort,
            progress,
        ),
        _ => None,
    };
    let (est, floor) = {
        let t = Instant::now();
        progress(&format!("interpolation stencils on {spec}"));
        let est = ErrorEstimator::new(&table, &reference, Some(&check), check.len().max(1))?;
        // The estimator keeps what it needs of the sets (reordered copies).
        drop((reference, check));
        let floor = est.measure(table.data());
        timings.push((
            format!("stencils and grid error {spec}"),
            t.elapsed().as_secs_f64(),
        ));
        (est, floor)
    };
    let t = Instant::now();
    let mut table = table;
    let outcome = match (&mut table, again) {
        (Cow::Owned(t), Some(again)) => encode_within_lending(
            t,
            again,
            prepared,
            &est,
            &settings.budget,
            settings.effort,
            progress,
        )?,
        (t, _) => encode_within(t, &est, &settings.budget, settings.effort, progress)?,
    };
    let encode_s = t.elapsed().as_secs_f64();
    let mut attempt = GridAttempt {
        grid: spec.clone(),
        cells: table.grid().cells(),
        floor,
        payload_bytes: None,
        tabulate_s: 0.0,
        encode_s,
        chosen: false,
    };
    let encoded = match outcome {
        RateOutcome::GridTooCoarse { .. } => {
            return Err(Error::Failure(no_grid_message(
                &settings.budget,
                &[attempt],
            )));
        }
        RateOutcome::Encoded(e) => *e,
    };
    timings.extend(encoded.timings.iter().cloned());
    attempt.payload_bytes = Some(encoded.payload.len());
    attempt.chosen = true;
    // A borrowed input is copied once, now that the planner's arrays are freed. A lossless
    // file carries the input's exact f64 values, as `compress --codec` writes it; a lossy one
    // does not.
    let table = table.into_owned();
    let table = if encoded.spec.is_lossless() {
        table
    } else {
        table.without_exact()
    };
    Ok(Planned {
        table,
        grid: spec,
        encoded,
        attempts: vec![attempt],
        timings,
        estimate_samples: pairs,
        tabulate_s: 0.0,
        encode_s,
    })
}

/// A grid whose own error uses more than this share of a bound has the other interpolation
/// weight measured ([`InterpWeight`]). Half: below it the codec has most of the budget and a
/// better grid changes the file little (the MERL-grid gold default uses 31% and keeps f; the
/// try would cost it a second set of stencils, ~0.2 s and ~10 MB); the sources the weight is
/// for (RGL files: 70% to 10× the budget on the default grid) are far above it.
const WEIGHT_TRY_SHARE: f64 = 0.5;

/// The log interpolation spaces to measure on `table` (none when its space is already set,
/// or the source is 0 everywhere). Scales from the ε of the metrics' relative errors
/// (spec/metrics.md), 1e-3 × the mean |value| over the estimator's uniform pairs (its
/// reference values; on a cosine-weighted grid the value is f·cos θi·cos θo, the quantity
/// interpolated): S = ε combines the values the relative metrics weigh as logs and those below
/// their floor linearly; S = ε/1000 also follows a lobe's tail down through the floor, where
/// a pure lobe's relative error is measured (Ward 0.1 × 0.3 on halfdiff4:32: p99_rel_core 1.6
/// at S = ε, 0.30 at ε/1000). No grid-sized array is made: the reference values are at hand.
fn log_spaces_of(table: &Table, est: &ErrorEstimator) -> Vec<InterpSpace> {
    if !table.grid().space().is_linear() {
        return Vec::new();
    }
    let cosine = table.grid().weight() == InterpWeight::Cosine;
    let (cos_i, cos_o, values) = est.reference();
    let c = table.channels().len();
    let sum: f64 = cos_i
        .iter()
        .zip(cos_o)
        .zip(values.chunks_exact(c))
        .map(|((ci, co), v)| {
            let m = if cosine {
                ci.max(0.0) * co.max(0.0)
            } else {
                1.0
            };
            v.iter().map(|f| (m * f).abs()).sum::<f64>()
        })
        .sum();
    let eps = 1e-3 * sum / (cos_i.len() * c).max(1) as f64;
    [eps, eps * 1e-3]
        .into_iter()
        .filter_map(|s| InterpSpace::log(s).ok())
        .collect()
}

/// A grid whose own error uses more than this share of a bound gets one finer grid tried.
const TIGHT_FLOOR: f64 = 0.6;
/// The same at `--effort max`: any share, so one finer grid is always tried. With the
/// default grid extended below the horizon its own error uses 14% of the default material's
/// p99_rel_core bound, under the 25% this was, and `max` wrote 6,019 B against the default
/// effort's 5,943 B (its larger estimation set accepts a slightly finer step); with the
/// finer grid tried it writes 5,822 B in 15.5 s.
const TIGHT_FLOOR_MAX: f64 = 0.0;

/// The largest share of a bound the grid's own error uses (upper values).
fn floor_share(budget: &Budget, floor: &Estimate) -> f64 {
    budget
        .bounds
        .iter()
        .map(|(k, b)| floor.upper.get(k).unwrap_or(0.0) / b.max(f64::MIN_POSITIVE))
        .fold(0.0, f64::max)
}

/// Why no file was written: the budget and each grid's own error.
fn no_grid_message(budget: &Budget, attempts: &[GridAttempt]) -> String {
    let per_grid: Vec<String> = attempts
        .iter()
        .map(|a| {
            let vals: Vec<String> = budget
                .bounds
                .iter()
                .map(|(k, _)| {
                    format!(
                        "{k} {}",
                        crate::check::fmt_num(a.floor.upper.get(k).map(|v| {
                            v.max(a.floor.check.as_ref().and_then(|c| c.get(k)).unwrap_or(0.0))
                        }))
                    )
                })
                .collect();
            format!("{}: {}", a.grid, vals.join(", "))
        })
        .collect();
    format!(
        "the budget {} cannot be met: the grid's own error (the uncompressed table against the \
         source, before any compression) is already over it ({}); give a finer --grid or a \
         looser --max-error; no file written",
        budget.describe(),
        per_grid.join("; ")
    )
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::grid::parse_grid_spec;
    use crate::model::Model;
    use crate::table::{Interp, InterpolatedTable};
    use std::sync::atomic::{AtomicUsize, Ordering};

    #[test]
    fn a_source_opened_again_plans_the_file_of_a_source_held() {
        // `pack TABLE --grid G` opens its table source for the reference values and the
        // tabulation, frees it while the codec is chosen, and opens it again only for the
        // lossless chain: the file, its measurement and the table must be those of the plan
        // that held the source throughout.
        let m = Model::parse("lambert:albedo=0.1+ggx:alpha=0.2,fresnel=au").unwrap();
        let stored = parse_grid_spec("halfdiff3:16x12x24,warp=sqrt/linear/linear").unwrap();
        let source = InterpolatedTable {
            table: tabulate(&m, &stored, &Default::default()).unwrap(),
            interp: Interp::Linear,
        };
        let opens = AtomicUsize::new(0);
        let open = || -> Result<Box<dyn Brdf>> {
            opens.fetch_add(1, Ordering::Relaxed);
            Ok(Box::new(source.clone()))
        };
        let grid = parse_grid_spec("halfdiff3:20x12x24,warp=sqrt/linear/linear").unwrap();
        for (bounds, opened) in [
            // A lossy file: the source is read once.
            ("log_rmse=0.1,p99_rel_core=0.8", 1),
            // On its own grid the table meets a budget no lossy step reaches: the lossless
            // chain takes the tabulation again, from the source read again.
            ("log_rmse=1e-12", 2),
        ] {
            let grid = if opened == 2 {
                stored.clone()
            } else {
                grid.clone()
            };
            let settings = PackSettings {
                budget: Budget::parse(bounds).unwrap(),
                effort: Effort::Fast,
                check_samples: 4096,
                check_seed: 7,
            };
            let held = plan(
                PackInput::Source {
                    source: &source,
                    grid: Some(grid.clone()),
                    options: Default::default(),
                },
                &settings,
                &|_| {},
            )
            .unwrap();
            opens.store(0, Ordering::Relaxed);
            let reopened = plan(
                PackInput::Reopened {
                    open: &open,
                    grid: Some(grid),
                    options: Default::default(),
                },
                &settings,
                &|_| {},
            )
            .unwrap();
            assert_eq!(opens.load(Ordering::Relaxed), opened, "{bounds}");
            assert_eq!(reopened.encoded.spec.is_lossless(), opened == 2, "{bounds}");
            assert_eq!(reopened.encoded.payload, held.encoded.payload, "{bounds}");
            assert_eq!(reopened.encoded.estimate, held.encoded.estimate, "{bounds}");
            assert_eq!(reopened.table.valid(), held.table.valid());
            assert!(
                reopened
                    .table
                    .data()
                    .iter()
                    .zip(held.table.data())
                    .all(|(a, b)| a.to_bits() == b.to_bits()),
                "{bounds}"
            );
        }
    }

    #[test]
    fn a_table_sources_holes_are_kept_or_filled_whichever_file_is_smaller() {
        let m = Model::parse("lambert:albedo=0.1+ggx:alpha=0.2,fresnel=au").unwrap();
        let grid = parse_grid_spec("halfdiff3:16x12x24,warp=sqrt/linear/linear").unwrap();
        let full = tabulate(&m, &grid, &Default::default()).unwrap();
        let settings = |bounds: &str| PackSettings {
            budget: Budget::parse(bounds).unwrap(),
            effort: Effort::Fast,
            check_samples: 4096,
            check_seed: 7,
        };
        let plan_with = |source: &InterpolatedTable, fill_own_holes: bool, bounds: &str| {
            plan(
                PackInput::Source {
                    source,
                    grid: Some(grid.clone()),
                    options: TabulateOptions {
                        fill_own_holes,
                        ..Default::default()
                    },
                },
                &settings(bounds),
                &|_| {},
            )
            .unwrap()
        };
        let bytes = |p: &Planned| {
            p.encoded.payload.len() + crate::io::native::mask_section_bytes(&p.table).unwrap()
        };
        let holed = |hole: &dyn Fn(usize, &[usize]) -> bool| {
            let mut t = full.clone();
            let mut idx = [0usize; 3];
            let (_, valid) = t.buffers_mut();
            for (cell, v) in valid.iter_mut().enumerate() {
                grid.unflatten(cell, &mut idx);
                if *v && hole(cell, &idx) {
                    *v = false;
                }
            }
            InterpolatedTable {
                table: t,
                interp: Interp::Linear,
            }
        };
        // A block of holes under a tight budget (a file of kilobytes, a mask of tens of
        // bytes): kept, so the table is the source exactly (its own error 0).
        let block = holed(&|_, i| i[1] >= 9 && i[2] < 6);
        let kept = plan_with(&block, false, "log_rmse=0.002,p99_rel_core=0.05");
        assert!(kept.table.valid() == block.table.valid());
        assert_eq!(kept.attempts.len(), 1);
        assert_eq!(kept.attempts[0].floor.upper.log_rmse, 0.0);
        // Scattered holes, whose mask is a large share of a small file: planned both ways,
        // and the smaller file is the one kept.
        let scattered = holed(&|cell, _| cell % 7 == 3);
        let loose = "log_rmse=0.05,p99_rel_core=0.8";
        let either = plan_with(&scattered, false, loose);
        let filled = plan_with(&scattered, true, loose);
        assert!(filled.table.valid() != scattered.table.valid());
        let kept_bytes = either.attempts[0].payload_bytes.unwrap()
            + crate::io::native::mask_section_bytes(&scattered.table).unwrap();
        assert!(
            either.attempts.len() == 2,
            "{} attempts",
            either.attempts.len()
        );
        assert_eq!(bytes(&either), kept_bytes.min(bytes(&filled)));
    }

    #[test]
    fn a_table_source_without_a_grid_is_planned_on_its_own_grid() {
        // Not resampled to the models' default (1.46 M cells, and the default grid's own
        // error against the table): the table is the source exactly, its own error 0.
        let m = Model::parse("lambert:albedo=0.1+ggx:alpha=0.2,fresnel=au").unwrap();
        let stored = parse_grid_spec("halfdiff3:16x12x24,warp=sqrt/linear/linear").unwrap();
        assert_ne!(stored, default_grid(&m).unwrap());
        let source = InterpolatedTable {
            table: tabulate(&m, &stored, &Default::default()).unwrap(),
            interp: Interp::Linear,
        };
        let planned = plan(
            PackInput::Source {
                source: &source,
                grid: None,
                options: TabulateOptions::default(),
            },
            &PackSettings {
                budget: Budget::parse("log_rmse=0.01,p99_rel_core=0.2").unwrap(),
                effort: Effort::Fast,
                check_samples: 4096,
                check_seed: 5,
            },
            &|_| {},
        )
        .unwrap();
        assert_eq!(planned.table.grid(), &stored);
        assert_eq!(planned.attempts.len(), 1);
        assert_eq!(planned.attempts[0].floor.upper.log_rmse, 0.0);
        assert!(planned.encoded.estimate.upper.log_rmse <= 0.01);
    }

    #[test]
    fn max_effort_keeps_the_default_efforts_file_when_that_is_smaller() {
        // `max` plans at the default effort too: its file is never larger than the default's,
        // and when both are the same size or the default's is smaller it is the default's
        // file, bit for bit, its samples decoded again from the payload.
        let m = Model::parse("lambert:albedo=0.1+ggx:alpha=0.2,fresnel=au").unwrap();
        let grid = parse_grid_spec("halfdiff3:24x16x32,warp=sqrt/linear/linear").unwrap();
        let settings = |effort| PackSettings {
            budget: Budget::parse("log_rmse=0.05,p99_rel_core=0.8").unwrap(),
            effort,
            check_samples: 4096,
            check_seed: 3,
        };
        let input = || PackInput::Source {
            source: &m,
            grid: Some(grid.clone()),
            options: Default::default(),
        };
        let default = plan(input(), &settings(Effort::Default), &|_| {}).unwrap();
        let max = plan(input(), &settings(Effort::Max), &|_| {}).unwrap();
        let bytes = |p: &Planned| file_bytes(&p.encoded, &p.table).unwrap();
        assert!(
            bytes(&max) <= bytes(&default),
            "{} > {}",
            bytes(&max),
            bytes(&default)
        );
        // Both plans' grids are reported, one of them chosen.
        assert_eq!(max.attempts.len(), 2 * default.attempts.len());
        assert_eq!(max.attempts.iter().filter(|a| a.chosen).count(), 1);
        if max.attempts[0].chosen {
            assert_eq!(max.encoded.payload, default.encoded.payload);
            assert!(
                max.table
                    .data()
                    .iter()
                    .zip(default.table.data())
                    .all(|(a, b)| a.to_bits() == b.to_bits())
            );
        }
    }
}
