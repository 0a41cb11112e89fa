//! Error budgets: upper bounds on the metrics of `spec/metrics.md`, shared by `check`,
//! `compress --max-error` and `pack`.

use crate::check::{BOUNDABLE, Metrics};
use crate::{Error, Result};

/// Safety margin of the exhaustive search ([`super::search`]): a candidate must meet every
/// bound × this on the search's sample set (and every bound on the held-out set).
pub const MARGIN: f64 = 0.98;

/// The named budget `preview`: a table for look development and previews.
pub const PREVIEW: &str = "log_rmse=0.01,p99_rel_core=0.2";
/// The named budget `production`: `pack`'s default.
pub const PRODUCTION: &str = "log_rmse=0.002,p99_rel_core=0.05";

/// Upper bounds on metrics of `spec/metrics.md`, all on the same sample set.
#[derive(Clone, Debug, PartialEq)]
pub struct Budget {
    pub bounds: Vec<(String, f64)>,
}

impl Budget {
    /// Whether a bound is on a metric relative to ε (`rel_rmse`, `rel_rmse_core`,
    /// `p99_rel_core`, `max_rel`): the codec's curve ε then follows the ε those bounds are
    /// measured against.
    pub fn bounds_relative(&self) -> bool {
        self.bounds.iter().any(|(k, _)| k.contains("rel"))
    }

    /// The share of the core's pairs whose relative error no bound weighs: 1 − 0.99 when the
    /// only relative bound is `p99_rel_core` (a percentile: 1% of the core may err by any
    /// amount), else 0 (`rel_rmse`, `rel_rmse_core` and `max_rel` weigh every pair).
    pub fn relative_allowance(&self) -> f64 {
        let relative: Vec<&str> = self
            .bounds
            .iter()
            .map(|(k, _)| k.as_str())
            .filter(|k| k.contains("rel"))
            .collect();
        if relative == ["p99_rel_core"] {
            0.01
        } else {
            0.0
        }
    }

    /// Parses `log_rmse=0.01[,p99_rel_core=0.2,...]`, or a named budget: `preview`
    /// (log_rmse ≤ 0.01, p99_rel_core ≤ 0.2) or `production` (log_rmse ≤ 0.002,
    /// p99_rel_core ≤ 0.05, the default of `pack`).
    pub fn parse(s: &str) -> Result<Budget> {
        match s.trim() {
            "preview" => return Budget::parse(PREVIEW),
            "production" => return Budget::parse(PRODUCTION),
            _ => {}
        }
        let mut bounds = Vec::new();
        for part in s.split(',').filter(|p| !p.trim().is_empty()) {
            let (k, v) = part.split_once('=').ok_or_else(|| {
                Error::input(format!(
                    "--max-error {s:?}: {part:?} is not METRIC=VALUE (or the whole budget \
                     `preview` or `production`)"
                ))
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
            if bounds.iter().any(|(b, _)| b == k) {
                return Err(Error::input(format!(
                    "--max-error {s:?}: {k} is given twice"
                )));
            }
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
    pub fn excess(&self, m: &Metrics) -> f64 {
        self.bounds
            .iter()
            .map(|(k, v)| m.get(k).unwrap_or(f64::INFINITY) / v.max(f64::MIN_POSITIVE))
            .fold(0.0, f64::max)
    }
}

impl Budget {
    /// Every bound × [`MARGIN`].
    pub fn margined(&self) -> Budget {
        Budget {
            bounds: self
                .bounds
                .iter()
                .map(|(k, v)| (k.clone(), v * MARGIN))
                .collect(),
        }
    }

    /// The bounds `m` exceeds, as `name value > bound` (and `nonfinite N` when there are
    /// non-finite values); empty when met.
    pub fn exceeded(&self, m: &Metrics) -> Vec<String> {
        let mut out: Vec<String> = self
            .bounds
            .iter()
            .filter_map(|(k, v)| {
                let x = m.get(k).unwrap_or(f64::INFINITY);
                (x > *v).then(|| format!("{k} {x:.4e} > {v:.4e}"))
            })
            .collect();
        if m.nonfinite > 0 {
            out.push(format!("nonfinite {}", m.nonfinite));
        }
        out
    }

    /// `log_rmse ≤ 0.01, p99_rel_core ≤ 0.2`.
    pub fn describe(&self) -> String {
        self.bounds
            .iter()
            .map(|(k, v)| format!("{k} ≤ {v}"))
            .collect::<Vec<_>>()
            .join(", ")
    }
}
