//! The older exhaustive codec search, kept for the figures of docs/compression.md that were
//! measured with it (`tests/codec_figures.rs`); `pack` and `compress --max-error` use the
//! rate control of [`super::rate`]. Its [`Evaluator`] also scores `compress --codec` files.
//!
//! Every candidate is really encoded, decoded by the same code that reads files, interpolated
//! and measured with [`crate::check::metrics`] against a reference on the budget's sample set:
//! the uncompressed table ([`search`]); the reported error is that measurement. Candidates: the DCT chain with the log
//! curve (ε = 1e-3, 3e-3 and 1e-2 of each channel's mean) and KLT colour decorrelation, with the
//! quantization step found by bisection in log(step) (error grows with step); the lossless
//! chain when no lossy candidate meets the budget. Not candidates: the cosine weight
//! (`weight=cosine`), which on GGX α = 0.2 and gold-metallic-paint never made a smaller file at
//! the same log_rmse / p99_rel_core (docs/compression.md, `figures_weight`); and the Tucker
//! chain, 2–4× larger than the context-coded DCT at the same error on the MERL-grid tables
//! measured (docs/compression.md, "Truncated Tucker beside the DCT").

pub use super::budget::{Budget, MARGIN};
use crate::brdf::Brdf;
use crate::check::{Metrics, SampleSet, evaluate_set, metrics};
use crate::codec::coefcode::{self, ContextCoding, DEFAULT_DEADZONE};
use crate::codec::domain::Domain;
use crate::codec::entropy::Zstd;
use crate::codec::transform::Transform;
use crate::codec::{
    CodecRequest, CodecSpec, CurveRequest, DecodeScratch, Layout, dct, dct_coefficients,
    transform_for,
};
use crate::table::{Interp, InterpolatedTable, Stencil, Table};
use crate::{Error, Result};

/// A measured encoding.
#[derive(Clone, Debug)]
pub struct Measured {
    pub spec: CodecSpec,
    pub payload: Vec<u8>,
    /// Pooled metrics on the sample set, decoded table vs the original (both interpolated
    /// linearly).
    pub metrics: Metrics,
    /// The same on the held-out set (the search's `uniform` set with the next seed), when the
    /// evaluator has one.
    pub held_out: Option<Metrics>,
}

/// A sample set with its reference values (the uncompressed table or the source at its
/// pairs) and the table's interpolation stencil at its pairs (every candidate shares the
/// table's grid and validity).
struct Scored<'a> {
    set: &'a SampleSet,
    reference: Vec<f64>,
    stencil: Stencil,
}

/// Encodes, decodes and measures one spec.
pub struct Evaluator<'a> {
    table: &'a Table,
    main: Scored<'a>,
    held: Option<Scored<'a>>,
}

/// The table as its own reference, borrowed (a clone was a second table while the reference
/// values were evaluated).
fn linear(table: &Table) -> InterpolatedTable<&Table> {
    InterpolatedTable {
        table,
        interp: Interp::Linear,
    }
}

/// The metrics of `data` (cell-major values on the scored table's grid and validity, `c`
/// channels), linearly interpolated, against the reference on `s`.
fn score_with(s: &Scored, data: &[f32], c: usize) -> Metrics {
    let mut g = vec![0.0; s.set.pairs.len() * c];
    s.stencil.apply(data, &mut g);
    metrics(s.set, &s.reference, &g, c, None)
}

/// Encodes `table` with `spec` and measures the payload as a reader decodes it against the
/// table's own linear interpolation on `set` (what `compress --codec` reports). The decode
/// goes into the table's own samples, which the encoder no longer reads (a second
/// table-sized buffer was the peak: 188 MB for the 52 MiB table of docs/robustness.md,
/// over its bound of 168 MiB): on return the table holds what the payload decodes to,
/// whatever the outcome.
pub fn encode_and_measure(
    table: &mut Table,
    spec: &CodecSpec,
    set: &SampleSet,
) -> Result<Measured> {
    let c = table.channels().len();
    let main = Scored {
        set,
        reference: evaluate_set(&linear(table), set),
        stencil: table.stencil(&set.pairs, Interp::Linear),
    };
    let payload = spec.encode(table)?;
    let mut samples = table.lend_samples();
    let decoded = spec.decode_into_with(
        &payload,
        &Layout::of(table),
        &mut samples,
        &mut DecodeScratch::lean(),
    );
    let non_finite = samples
        .chunks_exact(c.max(1))
        .zip(table.valid())
        .position(|(v, &ok)| ok && v.iter().any(|x| !x.is_finite()));
    let metrics = decoded.is_ok().then(|| score_with(&main, &samples, c));
    table.give_back_samples(samples);
    decoded?;
    if let Some(cell) = non_finite {
        return Err(Error::Failure(format!(
            "{}: the payload decodes to a non-finite value in cell {cell}",
            spec.summary()
        )));
    }
    Ok(Measured {
        spec: spec.clone(),
        metrics: metrics.expect("decoded"),
        held_out: None,
        payload,
    })
}

impl<'a> Evaluator<'a> {
    pub fn new(table: &'a Table, set: &'a SampleSet) -> Result<Evaluator<'a>> {
        Evaluator::against(table, &linear(table), set, None)
    }

    /// An evaluator that also measures every candidate on `held` (reported in
    /// [`Measured::held_out`]).
    pub fn with_held_out(
        table: &'a Table,
        set: &'a SampleSet,
        held: &'a SampleSet,
    ) -> Result<Evaluator<'a>> {
        Evaluator::against(table, &linear(table), set, Some(held))
    }

    /// An evaluator of encodings of `table` measured against `reference` (e.g. the model the
    /// table was tabulated from) on `set` and, when given, `held`.
    pub fn against(
        table: &'a Table,
        reference_brdf: &dyn Brdf,
        set: &'a SampleSet,
        held: Option<&'a SampleSet>,
    ) -> Result<Evaluator<'a>> {
        if reference_brdf.channels().len() != table.channels().len() {
            return Err(Error::input(format!(
                "codec search: the reference {} has {} channels, the table {}",
                reference_brdf.describe(),
                reference_brdf.channels().len(),
                table.channels().len()
            )));
        }
        let scored = |set: &'a SampleSet| Scored {
            set,
            reference: evaluate_set(reference_brdf, set),
            stencil: table.stencil(&set.pairs, Interp::Linear),
        };
        Ok(Evaluator {
            table,
            main: scored(set),
            held: held.map(scored),
        })
    }

    /// Metrics of the uncompressed table itself (linear interpolation) against the reference:
    /// the floor no encoding of it goes below, up to chance.
    pub fn measure_uncompressed(&self) -> Result<(Metrics, Option<Metrics>)> {
        let data = self.table.data();
        Ok((
            self.score(data, &self.main),
            self.held.as_ref().map(|h| self.score(data, h)),
        ))
    }

    /// Metrics of `data` (cell-major values on the evaluator's grid and validity), linearly
    /// interpolated, against the reference on `s`.
    fn score(&self, data: &[f32], s: &Scored) -> Metrics {
        score_with(s, data, self.table.channels().len())
    }

    /// Metrics of an already-encoded payload (decoded exactly as a reader would).
    pub fn measure_payload(&self, spec: &CodecSpec, payload: Vec<u8>) -> Result<Measured> {
        let t = self.table;
        let data = spec.decode(&payload, &Layout::of(t))?;
        // Table::new refuses non-finite values in valid cells, as a reader would.
        let cand = Table::new(
            t.grid().clone(),
            t.channels().clone(),
            t.provenance().clone(),
            data,
            t.valid().to_vec(),
        )?;
        Ok(Measured {
            spec: spec.clone(),
            metrics: self.score(cand.data(), &self.main),
            held_out: self.held.as_ref().map(|h| self.score(cand.data(), h)),
            payload,
        })
    }

    pub fn measure(&self, spec: &CodecSpec) -> Result<Measured> {
        let payload = spec.encode(self.table)?;
        self.measure_payload(spec, payload)
    }
}

/// One step of the search, for the report.
#[derive(Clone, Debug)]
pub struct Trial {
    pub description: String,
    pub bytes: usize,
    pub metrics: Metrics,
    pub held_out: Option<Metrics>,
    pub meets: bool,
}

/// The outcome: the chosen encoding and every trial made.
#[derive(Clone, Debug)]
pub struct SearchResult {
    pub best: Measured,
    pub trials: Vec<Trial>,
}

/// Log-curve ε (relative to each channel's mean) tried by the search.
const EPS_CANDIDATES: [f64; 3] = [1e-3, 3e-3, 1e-2];
/// Bisection range of the DCT step in the log-transformed space and its number of halvings
/// (the last interval is a factor 1.3% wide).
const STEP_RANGE: (f64, f64) = (1e-4, 64.0);
const BISECTIONS: usize = 10;
/// Phase 2: dead zones and refinement passes tried around the best phase-1 step, each with a
/// local bisection of the step over [s/2, 2s].
const REFINEMENTS: [(f64, u32); 3] = [(1.0, 0), (0.6, 0), (0.0, 4)];
const LOCAL_BISECTIONS: usize = 6;

/// The held-out set of a search on `set`: a `uniform` set gets the same size with the next
/// seed; other sets have none.
fn held_out_set(set: &SampleSet) -> Option<SampleSet> {
    match set.seed {
        Some(seed) if set.name == "uniform" => {
            Some(SampleSet::uniform(set.pairs.len(), seed.wrapping_add(1)))
        }
        _ => None,
    }
}

/// True when `m` meets the budget with the margin on its set and plainly on the held-out set.
fn accepts(budget: &Budget, m: &Measured) -> bool {
    accepts_metrics(budget, &m.metrics, m.held_out.as_ref())
}

/// The search's acceptance rule on metrics: every bound × [`MARGIN`] on the search's set,
/// every bound on the held-out set (when there is one).
fn accepts_metrics(budget: &Budget, main: &Metrics, held: Option<&Metrics>) -> bool {
    budget.margined().met_by(main) && held.is_none_or(|h| budget.met_by(h))
}

/// The search state: every trial and the smallest accepted encoding so far.
struct State<'b> {
    budget: &'b Budget,
    best: Option<Measured>,
    trials: Vec<Trial>,
}

impl State<'_> {
    /// Records a trial and keeps `m` when it is accepted and the smallest so far.
    fn consider(&mut self, m: Measured, what: String) -> bool {
        let meets = accepts(self.budget, &m);
        self.trials.push(Trial {
            description: what,
            bytes: m.payload.len(),
            metrics: m.metrics.clone(),
            held_out: m.held_out.clone(),
            meets,
        });
        if meets
            && self
                .best
                .as_ref()
                .is_none_or(|b| m.payload.len() < b.payload.len())
        {
            self.best = Some(m);
        }
        meets
    }

    /// Records the trials of a [`Bisection`], in the order they were made.
    fn record(&mut self, b: Bisection) -> Option<f64> {
        for (m, what) in b.trials {
            self.consider(m, what);
        }
        b.found
    }
}

/// The trials of one bisection and the largest accepted step (`None` when even the lowest
/// step was not accepted).
struct Bisection {
    trials: Vec<(Measured, String)>,
    found: Option<f64>,
}

/// Bisection in log(step) over [lo, hi] for the largest accepted step (the error grows with
/// the step). It depends on nothing but its own trials (acceptance is a property of one
/// measurement), so independent bisections run in parallel and are recorded afterwards in a
/// fixed order: the choice and the trial list do not depend on the number of threads.
fn bisect<F>(
    budget: &Budget,
    lo: f64,
    hi: f64,
    halvings: usize,
    what: &str,
    f: F,
) -> Result<Bisection>
where
    F: Fn(f64) -> Result<Measured>,
{
    let (mut lo, mut hi) = (lo.ln(), hi.ln());
    let mut trials = Vec::with_capacity(halvings + 1);
    let m = f(lo.exp())?;
    let ok = accepts(budget, &m);
    trials.push((m, format!("{what} step={:.4e}", lo.exp())));
    if !ok {
        return Ok(Bisection {
            trials,
            found: None,
        });
    }
    for _ in 0..halvings {
        let mid = 0.5 * (lo + hi);
        let m = f(mid.exp())?;
        if accepts(budget, &m) {
            lo = mid;
        } else {
            hi = mid;
        }
        trials.push((m, format!("{what} step={:.4e}", mid.exp())));
    }
    Ok(Bisection {
        trials,
        found: Some(lo.exp()),
    })
}

/// [`bisect`] over the whole [`STEP_RANGE`] with [`BISECTIONS`] halvings (phases 1 and 1b).
fn bisect_whole_range<F>(budget: &Budget, what: &str, f: F) -> Result<Bisection>
where
    F: Fn(f64) -> Result<Measured>,
{
    bisect(budget, STEP_RANGE.0, STEP_RANGE.1, BISECTIONS, what, f)
}

/// Runs `jobs` in parallel and returns their results in order (the first error in order, so
/// that a failure reads the same for any number of threads).
fn in_parallel<J: Sync>(
    jobs: &[J],
    run: impl Fn(&J) -> Result<Bisection> + Sync + Send,
) -> Result<Vec<Bisection>> {
    use rayon::prelude::*;
    jobs.par_iter()
        .map(run)
        .collect::<Vec<_>>()
        .into_iter()
        .collect()
}

/// One ε of the log curve: its transform and the plain-fill DCT coefficients.
struct EpsCandidate {
    eps_rel: f64,
    transform: Transform,
    coefs: Vec<Vec<f64>>,
}

/// Finds the smallest encoding of `table` meeting `budget` on `set` (and, for a `uniform` set,
/// on the held-out set with the next seed; see [`MARGIN`]).
///
/// - Phase 1: DCT with context coding (dead zone 0.75) for every ε, bisection of the step.
/// - Phase 1b: DCT with zstd coding (varints) at the best ε of phase 1 (every ε when none met
///   the budget): on very peaky tables (GGX α < 1e-3) it is the smaller one.
/// - Phase 2: around the best context-coded step, other dead zones and refined fills, each
///   with a local bisection of the step.
/// - Phase 3: the lossless chain when nothing lossy is accepted.
pub fn search(table: &Table, budget: &Budget, set: &SampleSet, level: i32) -> Result<SearchResult> {
    search_against(table, &linear(table), budget, set, level)
}

/// [`search`] with every candidate measured against `reference` instead of the uncompressed
/// table: for a table tabulated from a model, the budget then bounds tabulation,
/// interpolation and codec error together. The bisections assume that error grows with the
/// step, which holds above the floor of the table's own error ([`Evaluator::measure_uncompressed`]).
fn search_against(
    table: &Table,
    reference: &dyn Brdf,
    budget: &Budget,
    set: &SampleSet,
    level: i32,
) -> Result<SearchResult> {
    let held = held_out_set(set);
    let ev = Evaluator::against(table, reference, set, held.as_ref())?;
    search_with(table, &ev, budget, level)
}

fn search_with(table: &Table, ev: &Evaluator, budget: &Budget, level: i32) -> Result<SearchResult> {
    let mut st = State {
        budget,
        best: None,
        trials: Vec::new(),
    };
    let dims = table.grid().shape();
    let c = table.channels().len();
    let mut cands = Vec::new();
    for eps_rel in EPS_CANDIDATES {
        let transform = transform_for(table, CurveRequest::Log { eps_rel }, true, None);
        // The forward transform is the expensive part: once per ε, reused for every step.
        let coefs = dct_coefficients(table, &transform)?;
        cands.push(EpsCandidate {
            eps_rel,
            transform,
            coefs,
        });
    }
    let context_spec =
        |e: &EpsCandidate, step: f64, deadzone: f64, refine: u32| CodecSpec::DctContext {
            domain: if refine > 0 {
                Domain::FillRefined { iterations: refine }
            } else {
                Domain::FillInvalid
            },
            transform: e.transform.clone(),
            dct: dct::DctStage {
                step: vec![step; c],
            },
            coding: ContextCoding::new(deadzone),
            residual: None,
        };
    // Phase 1: every ε at once.
    let phase1 = in_parallel(&cands, |e| {
        let what = format!("dct context eps={} deadzone={DEFAULT_DEADZONE}", e.eps_rel);
        bisect_whole_range(budget, &what, |step| {
            let spec = context_spec(e, step, DEFAULT_DEADZONE, 0);
            let payload = coefcode::encode(&coefcode::quantize_all(
                &e.coefs,
                &dims,
                &vec![step; c],
                DEFAULT_DEADZONE,
            ));
            ev.measure_payload(&spec, payload)
        })
    })?;
    let mut best_context: Option<(usize, f64, usize)> = None;
    for (i, b) in phase1.into_iter().enumerate() {
        if let Some(step) = st.record(b) {
            let bytes = st.best.as_ref().map_or(usize::MAX, |b| b.payload.len());
            if best_context.is_none_or(|(_, _, b)| bytes < b) {
                best_context = Some((i, step, bytes));
            }
        }
    }
    // Phases 1b and 2 depend on phase 1 only: all their bisections at once, recorded 1b first.
    enum Job {
        Zstd(usize),
        Refine(usize, f64, f64, u32),
    }
    // Only the best ε's coefficients are used from here on (every ε's when none met the
    // budget): free the others (2 × 400 MB for a 3-channel halfdiff4:64 table).
    if let Some((i, step, bytes)) = best_context {
        let best = cands.swap_remove(i);
        cands = vec![best];
        best_context = Some((0, step, bytes));
    }
    let mut jobs: Vec<Job> = match best_context {
        Some((i, _, _)) => vec![Job::Zstd(i)],
        None => (0..cands.len()).map(Job::Zstd).collect(),
    };
    if let Some((i, step, _)) = best_context {
        for (deadzone, refine) in REFINEMENTS {
            let deadzone = if deadzone > 0.0 {
                deadzone
            } else {
                DEFAULT_DEADZONE
            };
            jobs.push(Job::Refine(i, step, deadzone, refine));
        }
    }
    let later = in_parallel(&jobs, |job| match *job {
        // Phase 1b.
        Job::Zstd(i) => {
            let e = &cands[i];
            let entropy = Zstd { level };
            let what = format!("dct zstd eps={}", e.eps_rel);
            bisect_whole_range(budget, &what, |step| {
                let spec = CodecSpec::Dct {
                    domain: Domain::FillInvalid,
                    transform: e.transform.clone(),
                    dct: dct::DctStage {
                        step: vec![step; c],
                    },
                    entropy,
                    residual: None,
                };
                let comps: Vec<_> = e
                    .coefs
                    .iter()
                    .map(|p| dct::quantize(p, &dims, step))
                    .collect();
                let payload = entropy.compress(&dct::serialize(&comps))?;
                ev.measure_payload(&spec, payload)
            })
        }
        // Phase 2.
        Job::Refine(i, step, deadzone, refine) => {
            let e = &cands[i];
            let what = format!(
                "dct context eps={} deadzone={deadzone} refine={refine}",
                e.eps_rel
            );
            bisect(
                budget,
                step / 2.0,
                step * 2.0,
                LOCAL_BISECTIONS,
                &what,
                |s| {
                    let spec = context_spec(e, s, deadzone, refine);
                    let payload = if refine == 0 {
                        coefcode::encode(&coefcode::quantize_all(
                            &e.coefs,
                            &dims,
                            &vec![s; c],
                            deadzone,
                        ))
                    } else {
                        spec.encode(table)?
                    };
                    ev.measure_payload(&spec, payload)
                },
            )
        }
    })?;
    for b in later {
        st.record(b);
    }
    if st.best.is_none() {
        let spec = CodecRequest::Lossless {
            level,
            predict: None,
        }
        .resolve(table)?;
        let m = ev.measure(&spec)?;
        st.consider(m, "lossless".into());
    }
    let State { best, trials, .. } = st;
    let best = best.ok_or_else(|| {
        let closest = trials
            .iter()
            .map(|t| budget.excess(&t.metrics))
            .fold(f64::INFINITY, f64::min);
        Error::Failure(format!(
            "no codec meets the budget (closest trial is {closest:.2}× over)"
        ))
    })?;
    Ok(SearchResult { best, trials })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::grid::parse_grid_spec;

    #[test]
    fn budgets_parse_and_refuse_unknown_metrics() {
        let b = Budget::parse("log_rmse=0.01,p99_rel_core=0.2").unwrap();
        assert_eq!(b.bounds.len(), 2);
        assert!(Budget::parse("bogus=1").is_err());
        assert!(Budget::parse("log_rmse=-1").is_err());
        assert!(Budget::parse("").is_err());
    }

    #[test]
    fn search_meets_the_budget_and_reports_what_it_measured() {
        let g = parse_grid_spec("halfdiff3:16x16x24").unwrap();
        let src = crate::testing::GgxConductor::new(0.3);
        let t = crate::tabulate::tabulate(&src, &g, &Default::default()).unwrap();
        let set = SampleSet::uniform(4096, 1);
        let budget = Budget::parse("log_rmse=0.005,p99_rel_core=0.1").unwrap();
        let r = search(&t, &budget, &set, 19).unwrap();
        assert!(budget.met_by(&r.best.metrics));
        assert!(
            !r.best.spec.is_lossless(),
            "a loose budget should not need lossless"
        );
        // Re-measuring the chosen payload gives the same figures.
        let again = Evaluator::new(&t, &set)
            .unwrap()
            .measure_payload(&r.best.spec, r.best.payload.clone())
            .unwrap();
        assert_eq!(again.metrics, r.best.metrics);
        // A budget of 0 forces the lossless chain.
        let exact = search(&t, &Budget::parse("max_abs=0").unwrap(), &set, 3).unwrap();
        assert!(exact.best.spec.is_lossless());
    }
}
