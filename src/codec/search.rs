//! The codec search: the smallest file meeting an error budget (`--max-error`).
//!
//! Every candidate is really encoded, decoded by the same code that reads files, interpolated
//! and measured with [`crate::check::metrics`] against the uncompressed table on the budget's
//! sample set; the reported error is that measurement. Candidates: the DCT chain with the log
//! curve (ε = 1e-3, 3e-3 and 1e-2 of each channel's mean) and KLT colour decorrelation, with the
//! quantization step found by bisection in log(step) (error grows with step); the lossless
//! chain when no lossy candidate meets the budget.

use super::{CodecRequest, CodecSpec, CurveRequest, Layout, dct, dct_coefficients};
use crate::check::{BOUNDABLE, Metrics, SampleSet, evaluate_pairs, metrics};
use crate::table::{Interp, InterpolatedTable, Table};
use crate::{Error, Result};

/// Upper bounds on metrics of `spec/metrics.md`, all on the same sample set.
#[derive(Clone, Debug, PartialEq)]
pub struct Budget {
    pub bounds: Vec<(String, f64)>,
}

impl Budget {
    /// Parses `log_rmse=0.01[,p99_rel_core=0.2,...]`.
    pub fn parse(s: &str) -> Result<Budget> {
        let mut bounds = Vec::new();
        for part in s.split(',').filter(|p| !p.trim().is_empty()) {
            let (k, v) = part.split_once('=').ok_or_else(|| {
                Error::input(format!("--max-error {s:?}: {part:?} is not METRIC=VALUE"))
            })?;
            let k = k.trim();
            if !BOUNDABLE.contains(&k) || k == "albedo_err" {
                return Err(Error::input(format!(
                    "--max-error: unknown metric {k:?} (expected one of {})",
                    BOUNDABLE
                        .iter()
                        .filter(|n| **n != "albedo_err")
                        .copied()
                        .collect::<Vec<_>>()
                        .join(", ")
                )));
            }
            let v: f64 = v
                .trim()
                .parse()
                .ok()
                .filter(|x: &f64| x.is_finite() && *x >= 0.0)
                .ok_or_else(|| {
                    Error::input(format!(
                        "--max-error: {k} = {v:?} is not a non-negative number"
                    ))
                })?;
            bounds.push((k.to_string(), v));
        }
        if bounds.is_empty() {
            return Err(Error::input(format!("--max-error {s:?}: no bound given")));
        }
        Ok(Budget { bounds })
    }

    /// True when every bound holds.
    pub fn met_by(&self, m: &Metrics) -> bool {
        m.nonfinite == 0
            && self
                .bounds
                .iter()
                .all(|(k, v)| m.get(k).is_some_and(|x| x <= *v))
    }

    /// How far over budget (max ratio measured/bound; ≤ 1 when met).
    fn excess(&self, m: &Metrics) -> f64 {
        self.bounds
            .iter()
            .map(|(k, v)| m.get(k).unwrap_or(f64::INFINITY) / v.max(f64::MIN_POSITIVE))
            .fold(0.0, f64::max)
    }
}

/// A measured encoding.
#[derive(Clone, Debug)]
pub struct Measured {
    pub spec: CodecSpec,
    pub payload: Vec<u8>,
    /// Pooled metrics on the sample set, decoded table vs the original (both interpolated
    /// linearly).
    pub metrics: Metrics,
}

/// Encodes, decodes and measures one spec.
pub struct Evaluator<'a> {
    table: &'a Table,
    set: &'a SampleSet,
    reference: Vec<f64>,
}

impl<'a> Evaluator<'a> {
    pub fn new(table: &'a Table, set: &'a SampleSet) -> Result<Evaluator<'a>> {
        let r = InterpolatedTable {
            table: table.clone(),
            interp: Interp::Linear,
        };
        let (reference, _) = evaluate_pairs(&r, &r, set)?;
        Ok(Evaluator {
            table,
            set,
            reference,
        })
    }

    /// Metrics of an already-encoded payload (decoded exactly as a reader would).
    pub fn measure_payload(&self, spec: &CodecSpec, payload: Vec<u8>) -> Result<Measured> {
        let t = self.table;
        let data = spec.decode(&payload, &Layout::of(t))?;
        let cand = InterpolatedTable {
            table: Table::new(
                t.grid().clone(),
                t.channels().clone(),
                t.provenance().clone(),
                data,
                t.valid().to_vec(),
            )?,
            interp: Interp::Linear,
        };
        let (_, g) = evaluate_pairs(&cand, &cand, self.set)?;
        let c = t.channels().len();
        Ok(Measured {
            spec: spec.clone(),
            payload,
            metrics: metrics(self.set, &self.reference, &g, c, None),
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
/// Bisection range of the DCT step in the log-transformed space and its number of halvings.
const STEP_RANGE: (f64, f64) = (1e-4, 64.0);
const BISECTIONS: usize = 12;

/// Records a trial and keeps `m` when it meets the budget and is the smallest so far.
fn consider(
    budget: &Budget,
    best: &mut Option<Measured>,
    m: Measured,
    what: String,
    trials: &mut Vec<Trial>,
) -> bool {
    let meets = budget.met_by(&m.metrics);
    trials.push(Trial {
        description: what,
        bytes: m.payload.len(),
        metrics: m.metrics.clone(),
        meets,
    });
    if meets
        && best
            .as_ref()
            .is_none_or(|b| m.payload.len() < b.payload.len())
    {
        *best = Some(m);
    }
    meets
}

/// Finds the smallest encoding of `table` meeting `budget` on `set`.
pub fn search(table: &Table, budget: &Budget, set: &SampleSet, level: i32) -> Result<SearchResult> {
    let ev = Evaluator::new(table, set)?;
    let mut trials = Vec::new();
    let mut best: Option<Measured> = None;
    let dims = table.grid().shape();
    for eps_rel in EPS_CANDIDATES {
        let req = CodecRequest::Dct {
            curve: CurveRequest::Log { eps_rel },
            step: 1.0,
            colour: true,
            level,
        };
        let CodecSpec::Dct {
            domain,
            transform,
            entropy,
            ..
        } = req.resolve(table)?
        else {
            unreachable!("a DCT request resolves to a DCT spec")
        };
        // The forward transform is the expensive part: once per ε, reused for every step.
        let coefs = dct_coefficients(table, &transform)?;
        let c = coefs.len();
        let try_step = |step: f64| -> Result<Measured> {
            let spec = CodecSpec::Dct {
                domain,
                transform: transform.clone(),
                dct: dct::DctStage {
                    step: vec![step; c],
                },
                entropy,
            };
            let comps: Vec<_> = coefs
                .iter()
                .map(|p| dct::quantize(p, &dims, step))
                .collect();
            let payload = entropy.compress(&dct::serialize(&comps))?;
            ev.measure_payload(&spec, payload)
        };
        let (mut lo, mut hi) = (STEP_RANGE.0.ln(), STEP_RANGE.1.ln());
        let m = try_step(lo.exp())?;
        let ok = budget.met_by(&m.metrics);
        consider(
            budget,
            &mut best,
            m,
            format!("dct eps={eps_rel} step={:.3e}", lo.exp()),
            &mut trials,
        );
        if !ok {
            continue;
        }
        for _ in 0..BISECTIONS {
            let mid = 0.5 * (lo + hi);
            let m = try_step(mid.exp())?;
            let ok = consider(
                budget,
                &mut best,
                m,
                format!("dct eps={eps_rel} step={:.3e}", mid.exp()),
                &mut trials,
            );
            if ok {
                lo = mid;
            } else {
                hi = mid;
            }
        }
    }
    if best.is_none() {
        let spec = CodecRequest::Lossless {
            level,
            predict: None,
        }
        .resolve(table)?;
        let m = ev.measure(&spec)?;
        consider(budget, &mut best, m, "lossless".into(), &mut trials);
    }
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
        let src = super::super::testdata::GgxConductor::new(0.3);
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
