//! The error of a candidate table against its source, as a budget means it: the metrics of
//! `spec/metrics.md` on independent `uniform` sets the planner has never seen.
//!
//! A metric measured on one seeded set is a random variable: on heavy-tailed errors (a few
//! pairs near a specular peak carry a large share of the squared error) a file that meets
//! `log_rmse ≤ 0.002` on the set it was tuned on can miss it on the next seed. The estimator
//! therefore measures every candidate on its own, larger set (uniform in solid angle and
//! stratified: scrambled Sobol points of a seed no user set uses, so that rare regions where a
//! codec's largest errors sit get their share) and states an upper confidence value of each
//! metric for an independent set of `for_samples` pairs:
//!
//! - mean-square metrics (`rmse`, `rel_rmse`, `log_rmse`, `rel_rmse_core`): with s_p the
//!   pair's squared error averaged over channels, m = mean(s_p) and v its variance over the
//!   pairs, the bound is √(m + z·√(v·(1/N_ref + 1/N))) — the spread of the mean of an
//!   independent set of N_ref pairs around the truth, plus our own estimate's spread;
//! - `p99_rel_core`: the quantile at 0.99 + z·√(0.99·0.01·(1/M_ref + 1/M)) of the core
//!   relative errors (M, M_ref: core pairs in ours and in a set of N_ref pairs), the
//!   distribution-free spread of a sample quantile;
//! - the relative metrics' ε is itself a mean over the set (1e-3 · mean |f|) and, for a
//!   bright peak over a dark body, varies by ±10% from set to set, scaling the relative error
//!   of every dark value with it: the upper values of `rel_rmse`, `rel_rmse_core` and
//!   `p99_rel_core` use a low ε, the 0.5% quantile of ε over 400 bootstrap resamples of
//!   N_ref pairs from the estimation set;
//! - `max_abs`, `max_rel`, `nonfinite`, `negative`: the values on the estimation set (a
//!   maximum has no confidence bound from a sample; a larger set only finds larger ones).
//!
//! z = 3 (one-sided, about 0.13% per set and metric for a normal spread).

use crate::brdf::Brdf;
use crate::check::{
    MetricPairs, Metrics, SampleSet, evaluate_set, in_core_cos, log_error, metric_epsilon,
    metrics_of, percentile, rel_error, uniform_pairs,
};
use crate::geometry::Vec3;
use crate::grid::Grid;
use crate::table::{CellSet, Interp, Stencil, Table};
use crate::{Error, Result};
use rayon::prelude::*;

/// Seed of the estimation set: fixed (files are deterministic) and far from the small seeds
/// users pass to `--seed`, so that a user's check set is independent of it.
pub const ESTIMATE_SEED: u64 = 0x6275_6467_6574_0001;
/// Pairs in the estimation set at the default effort.
pub const ESTIMATE_PAIRS: usize = 1 << 17;
/// One-sided confidence multiplier of the upper values.
pub const CONFIDENCE_Z: f64 = 3.0;

/// A candidate's error: the metrics on the estimation set and their upper confidence values
/// for an independent set of [`ErrorEstimator::for_samples`] pairs.
#[derive(Clone, Debug, PartialEq, serde::Serialize)]
pub struct Estimate {
    pub metrics: Metrics,
    pub upper: Metrics,
    /// The metrics on the user's check set, when the estimator has one: the very values the
    /// `check` of the written file reports (same pairs, same interpolation, same bits).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub check: Option<Metrics>,
}

/// The reference values of a source at a fixed set of pairs, and a table's interpolation
/// stencils there: measures any data on that table's grid and validity.
pub struct ErrorEstimator {
    pairs: ScoredPairs,
    reference: Vec<f64>,
    stencil: Stencil,
    check: Option<Scored>,
    /// Every cell the stencils of both sets read: a measurement needs the values of these
    /// cells only ([`ErrorEstimator::measure_cells`]). Made when first asked for (the
    /// planner compares estimators by measuring whole tables, where it is not needed).
    read: std::sync::OnceLock<CellSet>,
    /// Cells of the grid ([`ErrorEstimator::measure`] checks its data against it).
    grid_cells: usize,
    channels: usize,
    epsilon: f64,
    /// ε of the relative metrics on a set of `for_samples` pairs with fewer bright pairs than
    /// usual (see the module doc).
    epsilon_low: f64,
    /// The source is itself samples ([`ReferenceSet`]'s `sampled`).
    sampled: bool,
    for_samples: usize,
    z: f64,
}

/// The estimation set ([`ESTIMATE_SEED`], `n` pairs) with the reference values of `source`.
/// Independent of any grid: built once and shared by every grid a planner tries.
///
/// The pairs themselves are not held: they are drawn again from their seed when an
/// estimator is built ([`ReferenceSet::set`]; a few milliseconds), since each estimator keeps
/// its own copy in its own order (48 B a pair: 9 MB for the default estimation and check sets
/// that a held copy would add to the planner's peak).
pub struct ReferenceSet {
    draw: Draw,
    len: usize,
    pub values: Vec<f64>,
    pub channels: usize,
    /// Whether the source is itself samples (a measured file, a table: `Brdf::is_sampled`),
    /// whose dark tails carry the roughness of a measurement or a fit ([`curve_floor`]).
    sampled: bool,
    /// [`ReferenceSet::epsilon_low`] of the first set size asked for: it depends on the
    /// values alone, and each grid a planner tries asks again (400 resamples of 131,072
    /// pairs, ~0.25 s).
    epsilon_low: std::sync::OnceLock<(usize, f64)>,
}

/// How a [`ReferenceSet`]'s pairs are drawn (deterministic: the same pairs every time).
#[derive(Clone)]
enum Draw {
    /// `n` uniform pairs from `seed` (a user's check set).
    Uniform { n: usize, seed: u64 },
    /// The estimation set: `n` pairs uniform in solid angle, stratified over the pair space
    /// (the scrambled Sobol points of [`ESTIMATE_SEED`], [`stratified_pairs`]), inside the
    /// stored domain θi, θo ≤ θmax of `domain` when there is one.
    Stratified { n: usize, domain: Option<Box<Grid>> },
    /// `n` uniform pairs from `seed`, those inside the stored domain of `domain` kept.
    KeptIn {
        n: usize,
        seed: u64,
        domain: Box<Grid>,
    },
}

/// Pairs uniform in solid angle with cos θi, cos θo in [`z_min`, 1], from the scrambled
/// Sobol points of `seed`: (u₀, u₁, u₂, u₃) ↦ cos θi = 1 − u₀(1 − z_min), φi = 2πu₁, and so
/// for wo. Each coordinate of the first 2^m points fills its 2^m strata once, and every
/// region of the pair space (a corner beside the horizon holding 1e-5 of the pairs) gets its
/// share, where a pseudo-random set of 131,072 pairs has none one time in four.
pub fn stratified_pairs(seed: u64, z_min: f64) -> impl Iterator<Item = (Vec3, Vec3)> {
    let z_min = z_min.clamp(0.0, 1.0);
    let dir = move |u: f64, v: f64| {
        let z = 1.0 - u * (1.0 - z_min);
        let phi = 2.0 * crate::math::PI * v;
        let r = (1.0 - z * z).max(0.0).sqrt();
        Vec3::new(r * phi.cos(), r * phi.sin(), z)
    };
    crate::math::sobol::Sobol4::new(seed).map(move |u| (dir(u[0], u[1]), dir(u[2], u[3])))
}

impl Draw {
    /// The pairs, in the set's order, one at a time.
    fn pairs(&self) -> Box<dyn Iterator<Item = (Vec3, Vec3)> + '_> {
        match self {
            Draw::Uniform { n, seed } => Box::new(uniform_pairs(*seed).take(*n)),
            // Drawn inside the domain's θmax (cos θ uniform in [cos θmax, 1] is solid angle
            // restricted to θ ≤ θmax); the few outside the domain's own test are skipped.
            Draw::Stratified { n, domain } => {
                let z_min = domain
                    .as_ref()
                    .and_then(|g| g.theta_max())
                    .map_or(0.0, |t| t.cos());
                // Drawn inside θmax, nearly every point passes; the scan is still bounded (64
                // points a pair) so that a domain whose own test refuses what its θmax admits
                // gives a short set, not a scan of 2³² points.
                Box::new(
                    stratified_pairs(ESTIMATE_SEED, z_min)
                        .take(n.saturating_mul(64).max(1 << 16))
                        .filter(move |&(wi, wo)| {
                            domain.as_ref().is_none_or(|g| g.in_domain(wi, wo))
                        })
                        .take(*n),
                )
            }
            Draw::KeptIn { n, seed, domain } => Box::new(
                uniform_pairs(*seed)
                    .take(*n)
                    .filter(move |&(wi, wo)| domain.in_domain(wi, wo)),
            ),
        }
    }

    fn set(&self) -> SampleSet {
        let (seed, pairs) = match self {
            Draw::Uniform { seed, .. } | Draw::KeptIn { seed, .. } => (*seed, self.pairs()),
            Draw::Stratified { .. } => (ESTIMATE_SEED, self.pairs()),
        };
        SampleSet {
            name: "uniform".into(),
            seed: Some(seed),
            pairs: pairs.collect(),
            weights: None,
        }
    }

    /// Pair `k` of the set, drawn again.
    fn pair(&self, k: usize) -> (Vec3, Vec3) {
        self.pairs()
            .nth(k)
            .expect("an estimator names only pairs of its set")
    }
}

/// What an estimator keeps of its pairs, in its own order: cos θi and cos θo (all the metrics
/// and the planner read of a pair) and each pair's place in its set, to draw it again when a
/// report names it. 20 bytes a pair instead of the directions' 48 (5.5 MB less at the
/// planner's peak with the default estimation and check sets).
struct ScoredPairs {
    cos_i: Vec<f64>,
    cos_o: Vec<f64>,
    index: Vec<u32>,
    draw: Draw,
}

impl MetricPairs for ScoredPairs {
    fn count(&self) -> usize {
        self.index.len()
    }
    fn weight(&self, _: usize) -> f64 {
        1.0
    }
    fn cos_i(&self, p: usize) -> f64 {
        self.cos_i[p]
    }
    fn core(&self, p: usize) -> bool {
        in_core_cos(self.cos_i[p], self.cos_o[p])
    }
    fn pair(&self, p: usize) -> (Vec3, Vec3) {
        self.draw.pair(self.index[p] as usize)
    }
}

/// A sample set's pairs, its reference values and a table's stencils at its pairs.
struct Scored {
    pairs: ScoredPairs,
    reference: Vec<f64>,
    stencil: Stencil,
}

impl Scored {
    /// `reference`'s pairs reordered by the first cell they read on `table`, so that
    /// measuring a candidate walks the table roughly in memory order (the metrics do not
    /// depend on pair order).
    ///
    /// `hint`, the order of another estimator of the same pairs on the same grid (the
    /// planner measures each grid with several interpolations), is tried first: the stencils
    /// made in that order are kept when it is this table's order too (each pair's first cell,
    /// then its index, strictly increasing), which saves one of the two stencil builds;
    /// otherwise the order comes from those stencils and they are made again.
    fn new(table: &Table, reference: &ReferenceSet, hint: Option<&[u32]>) -> Scored {
        let c = reference.channels;
        // The pairs in the order `order` gives, the set drawn again for each use rather than
        // held beside them (48 B a pair: 6 MB for the estimation set).
        let reordered = |order: &[u32]| -> Vec<(Vec3, Vec3)> {
            let set = reference.set();
            debug_assert!(set.weights.is_none(), "uniform draws have equal weights");
            order.iter().map(|&p| set.pairs[p as usize]).collect()
        };
        // A set holds at most MAX_SAMPLES (< 2³²) pairs.
        let (stencil, unordered, pairs) = match hint.filter(|h| h.len() == reference.len) {
            Some(h) => {
                let pairs = reordered(h);
                (
                    table.stencil(&pairs, Interp::Linear),
                    h.to_vec(),
                    Some(pairs),
                )
            }
            None => {
                let set = reference.set();
                (
                    table.stencil(&set.pairs, Interp::Linear),
                    (0..set.pairs.len() as u32).collect(),
                    None,
                )
            }
        };
        // `unordered[i]` is the pair of stencil i.
        let key = |i: usize| (stencil.first_cell(i), unordered[i]);
        let (order, stencil, pairs) = match pairs {
            Some(pairs) if (1..stencil.len()).all(|i| key(i - 1) < key(i)) => {
                (unordered, stencil, pairs)
            }
            _ => {
                // (cell, pair) is unique, so any sort gives this order. The keys are made
                // once, packed in a u64 (cell above, pair below; a cell index fits in 32
                // bits, `Table::stencil`, and "reads none" sorts last as before): a sort
                // that called `first_cell` per comparison took 0.13 s of the MERL grid's
                // 131,072 pairs. The unstable sort needs no buffer (this is the high-water
                // mark of `compress`, below).
                let mut keys: Vec<u64> = (0..stencil.len())
                    .map(|i| {
                        let (cell, pair) = key(i);
                        (cell.min(u32::MAX as usize) as u64) << 32 | pair as u64
                    })
                    .collect();
                drop(unordered);
                keys.sort_unstable();
                let order: Vec<u32> = keys.iter().map(|&k| k as u32).collect();
                drop(keys);
                // The stencils again, of the pairs in their new order, rather than a
                // reordered copy: a pair's stencil depends on that pair alone
                // (`Table::stencil`; tested in `table::tests`), and the set's two stencils are
                // not held at once (12.5 MB each for the estimation set on the 52 MiB table
                // of docs/robustness.md: the high-water mark of `compress` was reached here).
                drop(stencil);
                let pairs = reordered(&order);
                let stencil = table.stencil(&pairs, Interp::Linear);
                (order, stencil, pairs)
            }
        };
        let cos_i = pairs.iter().map(|p| p.0.z).collect();
        let cos_o = pairs.iter().map(|p| p.1.z).collect();
        drop(pairs);
        let mut values = Vec::with_capacity(reference.values.len());
        for &p in &order {
            let p = p as usize;
            values.extend_from_slice(&reference.values[p * c..(p + 1) * c]);
        }
        Scored {
            pairs: ScoredPairs {
                cos_i,
                cos_o,
                index: order,
                draw: reference.draw.clone(),
            },
            stencil,
            reference: values,
        }
    }
}

/// ε_low / ε for a budget on a relative metric (the curve of the ε its upper values use),
/// else 1: [`ErrorEstimator::curve_scale`] and [`ReferenceSet::curve_scale`].
fn curve_scale(
    budget: &crate::plan::budget::Budget,
    epsilon: f64,
    epsilon_low: impl FnOnce() -> f64,
) -> f64 {
    if budget.bounds_relative() && epsilon > 0.0 {
        (epsilon_low() / epsilon).min(1.0)
    } else {
        1.0
    }
}

/// The curve's floor as a fraction of the core's values at the budget's allowance quantile
/// ([`curve_floor`]): a core value f at that quantile then errs by at most 1 + this times its
/// share of the curve's step ((f + floor)/f ≤ 1.5), so the pairs a percentile bound weighs
/// keep nearly all their precision while the values far below them stop costing bits.
const FLOOR_FRACTION: f64 = 0.5;

/// Largest factor [`ErrorEstimator::curve_raise_limit`] considers.
pub const RAISE_MAX: f64 = 256.0;

/// Core pairs below which no floor is drawn: its 1% quantile would rest on fewer than 80
/// pairs.
const FLOOR_MIN_CORE_PAIRS: usize = 8000;

/// Per channel, the least ε the curve ln(ε + f) needs under `budget` (`cosines`: cos θi and
/// cos θo of each pair, `values` pair-major with `c` channels).
///
/// When the only relative bound is a core percentile (`p99_rel_core`), no bound weighs the
/// relative error of a core value below the percentile's allowance (the darkest 1% of the
/// core) nor that of any value outside the core, which the log error weighs only absolutely.
/// A curve whose ε is the metric's (1e-3 · mean |f|, far below the darkest value a render
/// shows on a fabric or a paint) spends its bits on the relative detail of exactly those
/// values: the grazing tail of a red fabric's blue channel, 1000 times darker than its core,
/// made its production file five times larger.
///
/// Only for a source that is itself samples (a measured file or a table, `sampled`): its
/// dark values carry the roughness of the measurement or of a fit, which the floor stops
/// paying for. A model's tail is as smooth as its formula and costs few bits at any ε, while
/// the floor's amplification of the core's darkest errors remains: on the zoo's models it
/// made production files up to 1.7 times larger (plastics, gold bodies); on the NBRDF fits
/// of the 100 MERL materials it made 17 production files under 0.7 times, and the larger
/// ones are at most 1.34 times (docs/compression.md).
///
/// The floor is [`FLOOR_FRACTION`] × the core's value at the allowance quantile, taken as
/// one ratio to each channel's core median (the smallest over the channels): channels in
/// proportion (a tinted material) keep curves in proportion, ln(ε_k + f_k) = ln(ε_j + f_j) +
/// const, so the colour transform still gathers them in one component; floors drawn per
/// channel on their own made brass's file 30% larger. `None` when the budget weighs every
/// pair's relative error, or the core has too few pairs.
fn curve_floor(
    budget: &crate::plan::budget::Budget,
    sampled: bool,
    cosines: impl Iterator<Item = (f64, f64)>,
    values: &[f64],
    c: usize,
) -> Option<Vec<f64>> {
    let allowance = budget.relative_allowance();
    if !sampled || allowance <= 0.0 || c == 0 {
        return None;
    }
    let mut core: Vec<Vec<f64>> = vec![Vec::new(); c];
    for ((cos_i, cos_o), v) in cosines.zip(values.chunks_exact(c)) {
        if in_core_cos(cos_i, cos_o) {
            for (k, x) in v.iter().enumerate() {
                core[k].push(if x.is_finite() { x.abs() } else { 0.0 });
            }
        }
    }
    if core[0].len() < FLOOR_MIN_CORE_PAIRS {
        return None;
    }
    let ratio = core
        .iter_mut()
        .map(|v| {
            let low = percentile(v, allowance);
            let median = percentile(v, 0.5);
            (median, if median > 0.0 { low / median } else { 0.0 })
        })
        .collect::<Vec<_>>();
    let r = ratio.iter().map(|&(_, r)| r).fold(f64::INFINITY, f64::min);
    Some(ratio.iter().map(|&(m, _)| FLOOR_FRACTION * r * m).collect())
}

impl ReferenceSet {
    /// The estimation set: `n` pairs uniform in solid angle, stratified ([`stratified_pairs`]
    /// of [`ESTIMATE_SEED`]).
    pub fn new(source: &dyn Brdf, n: usize) -> ReferenceSet {
        ReferenceSet::drawn(source, Draw::Stratified { n, domain: None })
    }

    /// `n` uniform pairs from `seed` (a user's check set).
    pub fn uniform(source: &dyn Brdf, n: usize, seed: u64) -> ReferenceSet {
        ReferenceSet::drawn(source, Draw::Uniform { n, seed })
    }

    /// The set `draw` gives, evaluated on `source`; its pairs are dropped (drawn again by
    /// [`ReferenceSet::set`]).
    fn drawn(source: &dyn Brdf, draw: Draw) -> ReferenceSet {
        let set = draw.set();
        let values = evaluate_set(source, &set);
        ReferenceSet {
            draw,
            len: set.pairs.len(),
            values,
            channels: source.channels().len(),
            sampled: source.is_sampled(),
            epsilon_low: std::sync::OnceLock::new(),
        }
    }

    /// The pairs, drawn again (the same pairs every call, in the same order).
    pub fn set(&self) -> SampleSet {
        self.draw.set()
    }

    /// [`ReferenceSet::new`] inside a table's stored domain (θi, θo ≤ θmax of `domain`),
    /// drawn there directly, so that the estimate has as many pairs as on a full hemisphere
    /// however small the domain. `None`: the whole hemisphere.
    pub fn new_in(source: &dyn Brdf, n: usize, domain: Option<&Grid>) -> Result<ReferenceSet> {
        let domain = domain
            .filter(|g| g.theta_max().is_some())
            .map(|g| Box::new(g.clone()));
        Ok(ReferenceSet::drawn(source, Draw::Stratified { n, domain }))
    }

    /// [`ReferenceSet::uniform`] restricted to a table's stored domain, as `check` restricts
    /// its sets: the user's check set of `n` pairs keeps those inside.
    pub fn uniform_in(
        source: &dyn Brdf,
        n: usize,
        seed: u64,
        domain: Option<&Grid>,
    ) -> ReferenceSet {
        let Some(g) = domain.filter(|g| g.theta_max().is_some()) else {
            return ReferenceSet::uniform(source, n, seed);
        };
        ReferenceSet::drawn(
            source,
            Draw::KeptIn {
                n,
                seed,
                domain: Box::new(g.clone()),
            },
        )
    }

    /// Pairs in the set.
    pub fn len(&self) -> usize {
        self.len
    }

    pub fn is_empty(&self) -> bool {
        self.len == 0
    }

    /// [`ErrorEstimator::curve_scale`] of an estimator of this set with upper values for
    /// `for_samples` pairs, before it is built.
    pub fn curve_scale(&self, budget: &crate::plan::budget::Budget, for_samples: usize) -> f64 {
        curve_scale(budget, self.epsilon(), || {
            self.epsilon_low(for_samples.max(1))
        })
    }

    /// [`ErrorEstimator::curve_floor`] of an estimator of this set, before it is built.
    /// The pairs are drawn lazily, not collected: a model (or a budget without a
    /// percentile) draws none.
    pub fn curve_floor(&self, budget: &crate::plan::budget::Budget) -> Option<Vec<f64>> {
        curve_floor(
            budget,
            self.sampled,
            self.draw.pairs().map(|(wi, wo)| (wi.z, wo.z)),
            &self.values,
            self.channels,
        )
    }

    /// ε of the relative metrics on this set: 1e-3 · mean |f| (`spec/metrics.md`).
    pub fn epsilon(&self) -> f64 {
        metric_epsilon(&self.values)
    }

    /// A low ε for independent sets of `n` pairs: the 0.5% quantile of 1e-3 · mean |f| over
    /// 400 bootstrap resamples of `n` pairs of this set (deterministic: a fixed seed).
    pub fn epsilon_low(&self, n: usize) -> f64 {
        let &(first, low) = self
            .epsilon_low
            .get_or_init(|| (n, self.epsilon_low_uncached(n)));
        if first == n {
            low
        } else {
            self.epsilon_low_uncached(n)
        }
    }

    fn epsilon_low_uncached(&self, n: usize) -> f64 {
        let c = self.channels.max(1);
        let per_pair: Vec<f64> = self
            .values
            .chunks_exact(c)
            .map(|v| {
                v.iter()
                    .filter(|x| x.is_finite())
                    .map(|x| x.abs())
                    .sum::<f64>()
                    / c as f64
            })
            .collect();
        if per_pair.is_empty() {
            return self.epsilon();
        }
        const RESAMPLES: u64 = 400;
        let mut means: Vec<f64> = (0..RESAMPLES)
            .into_par_iter()
            .map(|r| {
                let mut rng = crate::math::SplitMix64::new(ESTIMATE_SEED ^ ((r + 1) * 0x9E37_79B9));
                let mut sum = 0.0;
                for _ in 0..n {
                    let k = (rng.next_f64() * per_pair.len() as f64) as usize;
                    sum += per_pair[k.min(per_pair.len() - 1)];
                }
                sum / n as f64
            })
            .collect();
        let low = 1e-3 * percentile(&mut means, 0.005);
        if low > 0.0 {
            low.min(self.epsilon())
        } else {
            self.epsilon()
        }
    }
}

impl ErrorEstimator {
    /// An estimator of tables on `table`'s grid and validity against the source of
    /// `reference`, with upper values stated for independent sets of `for_samples` pairs.
    /// The pairs are reordered by the first cell they read, so that measuring a candidate
    /// walks the table roughly in memory order (the metrics do not depend on pair order).
    /// With `check`, every measurement also gives the metrics on that set (the user's check
    /// set), in [`Estimate::check`].
    pub fn new(
        table: &Table,
        reference: &ReferenceSet,
        check: Option<&ReferenceSet>,
        for_samples: usize,
    ) -> Result<Self> {
        Self::build(table, reference, check, for_samples, None)
    }

    /// [`ErrorEstimator::new`] for the same sets on `previous`'s grid with another
    /// interpolation (weight or space): `previous`'s pair orders are tried first, which
    /// usually saves a stencil build per set. The same estimator as `new` gives.
    pub fn new_following(
        table: &Table,
        reference: &ReferenceSet,
        check: Option<&ReferenceSet>,
        for_samples: usize,
        previous: &ErrorEstimator,
    ) -> Result<Self> {
        Self::build(table, reference, check, for_samples, Some(previous))
    }

    /// Adds the check set `check` (on `table`, the estimator's grid and validity; an
    /// estimator made without one): the estimator `new` would have made with it.
    pub fn add_check(&mut self, table: &Table, check: &ReferenceSet) -> Result<()> {
        if check.channels != self.channels {
            return Err(Error::input(format!(
                "error estimate: the source has {} channels, the table {}",
                check.channels, self.channels
            )));
        }
        let scored = Scored::new(table, check, None);
        self.check = Some(scored);
        self.read = std::sync::OnceLock::new();
        Ok(())
    }

    fn build(
        table: &Table,
        reference: &ReferenceSet,
        check: Option<&ReferenceSet>,
        for_samples: usize,
        previous: Option<&ErrorEstimator>,
    ) -> Result<Self> {
        let c = table.channels().len();
        for r in std::iter::once(reference).chain(check) {
            if r.channels != c {
                return Err(Error::input(format!(
                    "error estimate: the source has {} channels, the table {c}",
                    r.channels
                )));
            }
        }
        let Scored {
            pairs,
            reference: values,
            stencil,
        } = Scored::new(table, reference, previous.map(|p| &p.pairs.index[..]));
        let check_hint = previous
            .and_then(|p| p.check.as_ref())
            .map(|s| &s.pairs.index[..]);
        let check = check.map(|r| Scored::new(table, r, check_hint));
        let epsilon_low = reference.epsilon_low(for_samples.max(1));
        Ok(ErrorEstimator {
            pairs,
            stencil,
            reference: values,
            check,
            read: std::sync::OnceLock::new(),
            grid_cells: table.grid().cells(),
            channels: c,
            epsilon: reference.epsilon(),
            epsilon_low,
            sampled: reference.sampled,
            for_samples: for_samples.max(1),
            z: CONFIDENCE_Z,
        })
    }

    /// Pairs of the estimation set.
    pub fn samples(&self) -> usize {
        self.pairs.count()
    }

    /// The size of the independent sets the upper values are stated for.
    pub fn for_samples(&self) -> usize {
        self.for_samples
    }

    /// ε of the relative metrics on the estimation set.
    pub fn epsilon(&self) -> f64 {
        self.epsilon
    }

    /// The ε of the budget's own curve ln(ε + f) the rate control uses, relative to the estimation
    /// set's: when `budget` bounds a relative metric, the low ε its upper values are measured
    /// against (a step δ of that curve is then a relative error of at most δ for every value,
    /// down to the darkest the bound weighs); else 1. A bright peak over dark values has ε far
    /// above that low ε (ε follows the rare pairs that hit the peak) and a curve of ε spends
    /// its error where the bound is tightest. The same value as
    /// [`ReferenceSet::curve_scale`] of this estimator's sets.
    pub fn curve_scale(&self, budget: &crate::plan::budget::Budget) -> f64 {
        curve_scale(budget, self.epsilon, || self.epsilon_low)
    }

    /// Per channel, the least ε of the rate control's curves under `budget` (the curve's ε is
    /// the larger of this and its scale × [`ErrorEstimator::epsilon`]): see [`curve_floor`].
    /// The same values as [`ReferenceSet::curve_floor`] of this estimator's set.
    pub fn curve_floor(&self, budget: &crate::plan::budget::Budget) -> Option<Vec<f64>> {
        curve_floor(
            budget,
            self.sampled,
            self.pairs
                .cos_i
                .iter()
                .copied()
                .zip(self.pairs.cos_o.iter().copied()),
            &self.reference,
            self.channels,
        )
    }

    /// cos θi and cos θo of the pairs and the reference values (pair-major), in the
    /// estimator's order.
    pub fn reference(&self) -> (&[f64], &[f64], &[f64]) {
        (&self.pairs.cos_i, &self.pairs.cos_o, &self.reference)
    }

    /// The cells a measurement reads: [`ErrorEstimator::measure_cells`] takes their values
    /// alone.
    pub fn cells(&self) -> &CellSet {
        self.read.get_or_init(|| {
            CellSet::read_by(
                self.grid_cells,
                std::iter::once(&self.stencil).chain(self.check.as_ref().map(|s| &s.stencil)),
            )
        })
    }

    /// The error of `data` (cell-major values on the estimator's grid and validity, linearly
    /// interpolated) against the source.
    ///
    /// # Panics
    /// When `data` is not a table's values on the estimator's grid (a caller bug).
    pub fn measure(&self, data: &[f32]) -> Estimate {
        assert_eq!(
            data.len(),
            self.grid_cells * self.channels,
            "ErrorEstimator::measure: data length"
        );
        self.measure_by(|s, g| s.apply(data, g))
    }

    /// The estimation pairs in the core (cos θi ≥ 0.1 and cos θo ≥ 0.1), by index.
    fn core_pairs(&self) -> Vec<usize> {
        (0..self.pairs.count())
            .filter(|&i| in_core_cos(self.pairs.cos_i[i], self.pairs.cos_o[i]))
            .collect()
    }

    /// The largest factor K (on a ladder of √2 steps, at most [`RAISE_MAX`]) by which the
    /// curve's ε per channel `eps` may be multiplied while a percentile bound with
    /// `allowance` (0.01 for p99) grows by at most `growth` for the same error in the curve's
    /// space; 1 when even √2 grows it more.
    ///
    /// An error δ of the curve ln(ε + f) is a relative error δ·(ε + f)/(f + ε_m) of f: raising
    /// ε to K·ε multiplies it by A = (K·ε + f)/(ε + f), which is near 1 for the values far
    /// above ε and K for those far below. Modelling δ as Gaussian and alike everywhere, the
    /// bound's quantile t solves mean over the core's values of P(|δ|·A > t) = allowance,
    /// and the growth is t(K)/t(1). A diffuse body whose darkest core values sit near ε
    /// grows at once; a material whose dark values are few (fewer than the allowance) and
    /// far below the rest grows little until K·ε reaches the bulk of its values.
    pub fn curve_raise_limit(&self, eps: &[f64], allowance: f64, growth: f64) -> f64 {
        let c = self.channels;
        if eps.len() != c || allowance <= 0.0 || allowance >= 0.5 || growth <= 1.0 {
            return 1.0;
        }
        // A depends on f/ε alone: the core's values as a histogram of x = f/ε in bins of
        // ln x a tenth wide (x < 1e-6 counted as 0, x > 1e9 as 1e9).
        let core = self.core_pairs();
        if core.len() * c < 100 {
            return 1.0;
        }
        const LOW: f64 = -13.8; // ln 1e-6
        const BINS: usize = 345; // up to ln 1e9 ≈ 20.7
        let mut counts = vec![0usize; BINS + 1];
        for &i in &core {
            for (k, &e) in eps.iter().enumerate() {
                let x = self.reference[i * c + k].abs() / e.max(f64::MIN_POSITIVE);
                let b = if x > 0.0 {
                    (((x.ln() - LOW) * 10.0).floor().max(-1.0) + 1.0).min(BINS as f64) as usize
                } else {
                    0
                };
                counts[b] += 1;
            }
        }
        let n = (core.len() * c) as f64;
        let bins: Vec<(f64, f64)> = counts
            .iter()
            .enumerate()
            .filter(|&(_, &m)| m > 0)
            .map(|(b, &m)| {
                let x = if b == 0 {
                    0.0
                } else {
                    (LOW + (b as f64 - 0.5) / 10.0).exp()
                };
                (x, m as f64 / n)
            })
            .collect();
        // t with mean P(|N(0,1)|·A > t) = allowance, by bisection in log t.
        let quantile = |k: f64| {
            let share = |t: f64| {
                bins.iter()
                    .map(|&(x, w)| {
                        let a = (k + x) / (1.0 + x);
                        w * crate::math::erfc(t / (a * std::f64::consts::SQRT_2))
                    })
                    .sum::<f64>()
            };
            let (mut lo, mut hi) = (1e-3f64.ln(), (100.0 * k.max(1.0)).ln());
            for _ in 0..40 {
                let mid = 0.5 * (lo + hi);
                if share(mid.exp()) > allowance {
                    lo = mid;
                } else {
                    hi = mid;
                }
            }
            (0.5 * (lo + hi)).exp()
        };
        let t1 = quantile(1.0);
        let mut k_ok = 1.0;
        for j in 1.. {
            let k = (j as f64 / 2.0).exp2();
            if k > RAISE_MAX || quantile(k) > growth * t1 {
                break;
            }
            k_ok = k;
        }
        k_ok
    }

    /// How much of the percentile bound's tail sits at the dark end of the core, for a table
    /// given by the values of [`ErrorEstimator::cells`] alone: of the core values whose
    /// relative error exceeds the `1 − allowance` quantile, the share that lies among the
    /// darkest `2·allowance` of the core's values (each value taken relative to its
    /// channel's core median), divided by that fraction. 1 when the tail is spread like the
    /// values; up to 1/(2·allowance) when it is all at the dark end, where the curve's small
    /// ε makes a cliff of values that fall to 0 (the NBRDF fits clamp at 0) and the error
    /// gathers at the cliff. 0 without core values or without a tail.
    pub fn dark_tail_share(&self, values: &[f32], allowance: f64) -> f64 {
        let read = self.cells();
        self.dark_tail_share_by(allowance, |g| {
            self.stencil.apply_at_cells(values, g, |f| read.position(f))
        })
    }

    /// [`ErrorEstimator::dark_tail_share`] of a whole table's values (`data`, every cell).
    pub fn dark_tail_share_of_table(&self, data: &[f32], allowance: f64) -> f64 {
        self.dark_tail_share_by(allowance, |g| self.stencil.apply(data, g))
    }

    /// The dark tail's share of the values `apply` interpolates at the estimation pairs.
    fn dark_tail_share_by(&self, allowance: f64, apply: impl FnOnce(&mut [f64])) -> f64 {
        let c = self.channels;
        if allowance <= 0.0 || allowance >= 0.5 || c == 0 {
            return 0.0;
        }
        let mut g = vec![0.0; self.pairs.count() * c];
        apply(&mut g);
        // Core values: (f relative to its channel's core median, relative error).
        let core = self.core_pairs();
        if core.len() * c < 100 {
            return 0.0;
        }
        let medians: Vec<f64> = (0..c)
            .map(|k| {
                let mut v: Vec<f64> = core
                    .iter()
                    .map(|&i| self.reference[i * c + k].abs())
                    .collect();
                percentile(&mut v, 0.5)
            })
            .collect();
        let eps = self.epsilon_low.max(f64::MIN_POSITIVE);
        let mut darkness = Vec::with_capacity(core.len() * c);
        let mut rel = Vec::with_capacity(core.len() * c);
        for &i in &core {
            for k in 0..c {
                let f = self.reference[i * c + k];
                darkness.push(f.abs() / medians[k].max(f64::MIN_POSITIVE));
                rel.push((g[i * c + k] - f).abs() / (f.abs() + eps));
            }
        }
        drop(g);
        let dark_end = percentile(&mut darkness.clone(), 2.0 * allowance);
        let tail = percentile(&mut rel.clone(), 1.0 - allowance);
        let (mut exceeding, mut dark) = (0usize, 0usize);
        for (&d, &r) in darkness.iter().zip(&rel) {
            if r > tail {
                exceeding += 1;
                if d <= dark_end {
                    dark += 1;
                }
            }
        }
        if exceeding == 0 {
            return 0.0;
        }
        dark as f64 / exceeding as f64 / (2.0 * allowance)
    }

    /// [`ErrorEstimator::measure`] of a table given by the values of
    /// [`ErrorEstimator::cells`] alone (`values[i·C..]` those of the cell at place i): the
    /// same bits.
    ///
    /// # Panics
    /// When `values` is not the listed cells' size (a caller bug).
    pub fn measure_cells(&self, values: &[f32]) -> Estimate {
        assert_eq!(
            values.len(),
            self.cells().len() * self.channels,
            "ErrorEstimator::measure_cells: values length"
        );
        let read = self.cells();
        self.measure_by(|s, g| s.apply_at_cells(values, g, |f| read.position(f)))
    }

    /// The metrics of `data` on the check set alone (`None` without one): what
    /// [`ErrorEstimator::measure`] gives in [`Estimate::check`], for an estimate made before
    /// [`ErrorEstimator::add_check`].
    pub fn measure_check(&self, data: &[f32]) -> Option<Metrics> {
        assert_eq!(
            data.len(),
            self.grid_cells * self.channels,
            "ErrorEstimator::measure_check: data length"
        );
        self.check_by(&|s, g| s.apply(data, g))
    }

    /// The check set's metrics from the values `apply` gives of its stencils.
    fn check_by(&self, apply: &impl Fn(&Stencil, &mut [f64])) -> Option<Metrics> {
        let c = self.channels;
        self.check.as_ref().map(|s| {
            let mut g = vec![0.0; s.pairs.count() * c];
            apply(&s.stencil, &mut g);
            metrics_of(&s.pairs, &s.reference, &g, c, None)
        })
    }

    /// The estimate from the interpolated values `apply` gives of each set's stencils.
    fn measure_by(&self, apply: impl Fn(&Stencil, &mut [f64])) -> Estimate {
        let c = self.channels;
        let mut g = vec![0.0; self.pairs.count() * c];
        apply(&self.stencil, &mut g);
        let check = self.check_by(&apply);
        upper_estimate(
            &self.pairs,
            &self.reference,
            &g,
            c,
            self.epsilon_low,
            self.for_samples,
            self.z,
            check,
        )
    }
}

/// The metrics of candidate values `g` against `reference` at `pairs` (pair-major, `c`
/// channels) and their upper confidence values for an independent set of `for_samples`
/// pairs (module doc), with `check`, the check set's metrics, passed through. The statistics
/// of [`ErrorEstimator`] and [`PairEstimator`] alike: only where the candidate's values come
/// from differs.
#[allow(clippy::too_many_arguments)]
fn upper_estimate(
    pairs: &ScoredPairs,
    reference: &[f64],
    g: &[f64],
    c: usize,
    epsilon_low: f64,
    for_samples: usize,
    z: f64,
    check: Option<Metrics>,
) -> Estimate {
    let n = pairs.count();
    let point = metrics_of(pairs, reference, g, c, None);
    let eps_low = epsilon_low.min(point.epsilon);
    // Per pair: squared errors averaged over channels (abs, rel, log) and whether the pair
    // is in the core; the core relative errors of every channel.
    struct PairTerms {
        abs2: f64,
        rel2: f64,
        log2: f64,
        core: bool,
    }
    let terms: Vec<PairTerms> = (0..n)
        .into_par_iter()
        .with_min_len(4096)
        .map(|p| {
            let cos_i = pairs.cos_i[p];
            let (mut abs2, mut rel2, mut log2) = (0.0, 0.0, 0.0);
            for k in 0..c {
                let (f, gv) = (reference[p * c + k], g[p * c + k]);
                let a = gv - f;
                let r = rel_error(f, gv, eps_low);
                let l = log_error(f, gv, cos_i);
                abs2 += a * a;
                rel2 += r * r;
                log2 += l * l;
            }
            let k = c as f64;
            PairTerms {
                abs2: abs2 / k,
                rel2: rel2 / k,
                log2: log2 / k,
                core: pairs.core(p),
            }
        })
        .collect();
    let spread = |n_own: usize, n_ref: f64| {
        if n_own < 2 || n_ref <= 0.0 {
            f64::INFINITY
        } else {
            1.0 / n_ref + 1.0 / n_own as f64
        }
    };
    // √(mean + z·√(var·spread)) of one per-pair term over the selected pairs.
    let upper_rms = |pick: &dyn Fn(&PairTerms) -> Option<f64>, n_ref: f64| {
        let vals: Vec<f64> = terms.iter().filter_map(pick).collect();
        if vals.is_empty() {
            return 0.0;
        }
        let m = vals.iter().sum::<f64>() / vals.len() as f64;
        let var = if vals.len() > 1 {
            vals.iter().map(|v| (v - m) * (v - m)).sum::<f64>() / (vals.len() - 1) as f64
        } else {
            0.0
        };
        (m + z * (var * spread(vals.len(), n_ref)).sqrt()).sqrt()
    };
    let n_ref = for_samples as f64;
    let core_pairs = terms.iter().filter(|t| t.core).count();
    let core_ref = n_ref * core_pairs as f64 / n.max(1) as f64;
    let mut upper = point.clone();
    upper.rmse = upper_rms(&|t| Some(t.abs2), n_ref);
    upper.rel_rmse = upper_rms(&|t| Some(t.rel2), n_ref);
    upper.log_rmse = upper_rms(&|t| Some(t.log2), n_ref);
    upper.rel_rmse_core = upper_rms(&|t| t.core.then_some(t.rel2), core_ref);
    if core_pairs > 0 {
        let q = 0.99 + z * (0.99 * 0.01 * spread(core_pairs, core_ref)).sqrt();
        let mut rel: Vec<f64> = Vec::with_capacity(core_pairs * c);
        for (p, t) in terms.iter().enumerate() {
            if t.core {
                for k in 0..c {
                    rel.push(rel_error(reference[p * c + k], g[p * c + k], eps_low));
                }
            }
        }
        upper.p99_rel_core = percentile(&mut rel, q.min(1.0));
    }
    // Never below the point value (the bound states "at most").
    for (u, m) in [
        (&mut upper.rmse, point.rmse),
        (&mut upper.rel_rmse, point.rel_rmse),
        (&mut upper.log_rmse, point.log_rmse),
        (&mut upper.rel_rmse_core, point.rel_rmse_core),
        (&mut upper.p99_rel_core, point.p99_rel_core),
    ] {
        *u = u.max(m);
    }
    Estimate {
        metrics: point,
        upper,
        check,
    }
}

/// The estimator of candidates that are not tables on a grid (an RGL file packed in its own
/// parameterization, `super::rgl`): the same sets, statistics and upper values as
/// [`ErrorEstimator`], the candidate evaluated pointwise at the sets' pairs instead of
/// interpolated through stencils. The pairs are held (48 B a pair), in set order.
pub struct PairEstimator {
    set: SampleSet,
    pairs: ScoredPairs,
    reference: Vec<f64>,
    check: Option<(SampleSet, ScoredPairs, Vec<f64>)>,
    channels: usize,
    epsilon_low: f64,
    for_samples: usize,
    z: f64,
}

impl PairEstimator {
    /// Candidates against the source of `reference` (and, with `check`, on the user's check
    /// set too), with upper values stated for independent sets of `for_samples` pairs.
    pub fn new(
        reference: &ReferenceSet,
        check: Option<&ReferenceSet>,
        for_samples: usize,
    ) -> PairEstimator {
        let scored = |r: &ReferenceSet| {
            let set = r.set();
            let pairs = ScoredPairs {
                cos_i: set.pairs.iter().map(|p| p.0.z).collect(),
                cos_o: set.pairs.iter().map(|p| p.1.z).collect(),
                // A set holds at most MAX_SAMPLES (< 2³²) pairs.
                index: (0..set.pairs.len() as u32).collect(),
                draw: r.draw.clone(),
            };
            (set, pairs)
        };
        let (set, pairs) = scored(reference);
        PairEstimator {
            set,
            pairs,
            reference: reference.values.clone(),
            check: check.map(|r| {
                let (s, p) = scored(r);
                (s, p, r.values.clone())
            }),
            channels: reference.channels,
            epsilon_low: reference.epsilon_low(for_samples.max(1)),
            for_samples,
            z: CONFIDENCE_Z,
        }
    }

    /// Pairs of the estimation set.
    pub fn samples(&self) -> usize {
        self.pairs.count()
    }

    /// The error of `candidate` against the source, evaluated at every pair of both sets.
    pub fn measure(&self, candidate: &dyn Brdf) -> Result<Estimate> {
        self.measure_within(candidate, None)
    }

    /// [`PairEstimator::measure`], the check set left out (`check: None`) when the upper
    /// values already miss `budget`: a candidate the check could only reject again costs the
    /// estimation set alone.
    pub fn measure_within(
        &self,
        candidate: &dyn Brdf,
        budget: Option<&super::budget::Budget>,
    ) -> Result<Estimate> {
        if candidate.channels().len() != self.channels {
            return Err(Error::input(format!(
                "error estimate: the source has {} channels, the candidate {}",
                self.channels,
                candidate.channels().len()
            )));
        }
        let c = self.channels;
        let g = evaluate_set(candidate, &self.set);
        let mut e = upper_estimate(
            &self.pairs,
            &self.reference,
            &g,
            c,
            self.epsilon_low,
            self.for_samples,
            self.z,
            None,
        );
        if budget.is_none_or(|b| b.met_by(&e.upper)) {
            e.check = self.check.as_ref().map(|(set, pairs, reference)| {
                let g = evaluate_set(candidate, set);
                metrics_of(pairs, reference, &g, c, None)
            });
        }
        Ok(e)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::check::metrics;
    use crate::grid::parse_grid_spec;
    use crate::model::Model;
    use crate::tabulate::tabulate;

    #[test]
    fn the_upper_value_covers_independent_sets() {
        // A coarse table of a glossy lobe: heavy-tailed interpolation error. Its error on
        // 12 independent sets of 4096 pairs must stay below the estimator's upper value for
        // 4096-pair sets (z = 3: a miss on any of them would be a ~1.5% event per metric).
        let m = Model::parse("ggx:alpha=0.08,fresnel=au").unwrap();
        let g = parse_grid_spec("halfdiff3:24x24x32,warp=sqrt/linear/linear,at=edge").unwrap();
        let t = tabulate(&m, &g, &Default::default()).unwrap();
        let reference = ReferenceSet::new(&m, 1 << 15);
        let est = ErrorEstimator::new(&t, &reference, None, 4096).unwrap();
        let e = est.measure(t.data());
        assert!(e.upper.log_rmse > e.metrics.log_rmse);
        assert!(e.upper.p99_rel_core >= e.metrics.p99_rel_core);
        let cand = crate::table::InterpolatedTable {
            table: t.clone(),
            interp: Interp::Linear,
        };
        let mut worst_log: f64 = 0.0;
        let mut worst_p99: f64 = 0.0;
        for seed in 1..=12 {
            let set = SampleSet::uniform(4096, seed);
            let (f, gv) = crate::check::evaluate_pairs(&m, &cand, &set).unwrap();
            let mm = metrics(&set, &f, &gv, 3, None);
            worst_log = worst_log.max(mm.log_rmse);
            worst_p99 = worst_p99.max(mm.p99_rel_core);
        }
        assert!(
            worst_log <= e.upper.log_rmse,
            "log_rmse {worst_log} above the upper value {}",
            e.upper.log_rmse
        );
        assert!(
            worst_p99 <= e.upper.p99_rel_core,
            "p99_rel_core {worst_p99} above the upper value {}",
            e.upper.p99_rel_core
        );
    }

    #[test]
    fn reordering_the_pairs_keeps_the_metrics() {
        let m = Model::parse("lambert:albedo=0.5+ggx:alpha=0.3").unwrap();
        let g = parse_grid_spec("halfdiff3:16x16x24").unwrap();
        let t = tabulate(&m, &g, &Default::default()).unwrap();
        let reference = ReferenceSet::new(&m, 5000);
        let check = ReferenceSet::uniform(&m, 3000, 7);
        let est = ErrorEstimator::new(&t, &reference, Some(&check), 5000).unwrap();
        let e = est.measure(t.data());
        let cand_check = crate::table::InterpolatedTable {
            table: t.clone(),
            interp: Interp::Linear,
        };
        let direct_check = crate::check::check_set(&m, &cand_check, &check.set()).unwrap();
        // Same pairs, summed in another order (the estimator sorts them by stencil cell):
        // equal up to the sums' rounding.
        let (a, b) = (e.check.as_ref().unwrap(), &direct_check.combined);
        for (x, y) in [
            (a.log_rmse, b.log_rmse),
            (a.rmse, b.rmse),
            (a.rel_rmse, b.rel_rmse),
            (a.rel_rmse_core, b.rel_rmse_core),
            (a.epsilon, b.epsilon),
        ] {
            assert!((x - y).abs() <= 1e-12 * y.abs(), "{x} vs {y}");
        }
        assert_eq!(a.p99_rel_core, b.p99_rel_core);
        assert_eq!(a.max_abs, b.max_abs);
        // The estimator keeps cosines, not directions: the pairs it names are drawn again.
        assert_eq!(a.max_abs_at, b.max_abs_at);
        assert_eq!(a.max_rel_at, b.max_rel_at);
        let cand = crate::table::InterpolatedTable {
            table: t,
            interp: Interp::Linear,
        };
        let g = evaluate_set(&cand, &reference.set());
        let direct = metrics(
            &reference.set(),
            &reference.values,
            &g,
            reference.channels,
            None,
        );
        let close = |a: f64, b: f64| (a - b).abs() <= 1e-9 * a.abs().max(b.abs()).max(1e-30);
        assert!(close(e.metrics.log_rmse, direct.log_rmse));
        assert!(close(e.metrics.rmse, direct.rmse));
        assert_eq!(e.metrics.p99_rel_core, direct.p99_rel_core);
        assert_eq!(e.metrics.max_abs, direct.max_abs);
        assert_eq!(e.metrics.max_abs_at, direct.max_abs_at);
    }

    /// An estimator following another (same sets and grid, another interpolation) is the
    /// one `new` makes: the same pair orders and the same estimates, bit for bit, whether
    /// the previous order is kept (a change of space) or not (the cosine weight, whose
    /// stencils read other cells near the horizon), and on a θmax grid; and when the
    /// previous order is not this table's (another grid's estimator), rejected and remade.
    #[test]
    fn an_estimator_following_another_is_the_new_one() {
        let m = Model::parse("lambert:albedo=0.05+ggx:alpha=0.1,fresnel=au").unwrap();
        for spec in [
            "halfdiff3:16x16x24,warp=sqrt/linear/linear",
            "spherical3:12x12x24,theta-max=70",
        ] {
            let g = parse_grid_spec(spec).unwrap();
            let mut t = tabulate(&m, &g, &Default::default()).unwrap();
            let reference = ReferenceSet::new_in(&m, 6000, Some(&g)).unwrap();
            let check = ReferenceSet::uniform_in(&m, 3000, 7, Some(&g));
            let first = ErrorEstimator::new(&t, &reference, Some(&check), 3000).unwrap();
            let mut previous = first;
            for step in 0..3 {
                match step {
                    0 => t.set_interp_space(crate::grid::InterpSpace::log(1e-3).unwrap()),
                    1 => t.set_interp_weight(crate::grid::InterpWeight::Cosine),
                    _ => t.set_interp_space(crate::grid::InterpSpace::Linear),
                }
                let fresh = ErrorEstimator::new(&t, &reference, Some(&check), 3000).unwrap();
                let following =
                    ErrorEstimator::new_following(&t, &reference, Some(&check), 3000, &previous)
                        .unwrap();
                assert_eq!(fresh.pairs.index, following.pairs.index, "{spec} {step}");
                let check_order =
                    |e: &ErrorEstimator| e.check.as_ref().unwrap().pairs.index.clone();
                assert_eq!(
                    check_order(&fresh),
                    check_order(&following),
                    "{spec} {step}"
                );
                let (a, b) = (fresh.measure(t.data()), following.measure(t.data()));
                assert_eq!(format!("{a:?}"), format!("{b:?}"), "{spec} {step}");
                previous = following;
            }
            // An order that is not this table's (another grid's): rejected, remade.
            let other = parse_grid_spec("halfdiff3:9x13x20").unwrap();
            let o = tabulate(&m, &other, &Default::default()).unwrap();
            let foreign = ErrorEstimator::new(&o, &reference, Some(&check), 3000).unwrap();
            assert_ne!(foreign.pairs.index, previous.pairs.index);
            let fresh = ErrorEstimator::new(&t, &reference, Some(&check), 3000).unwrap();
            let following =
                ErrorEstimator::new_following(&t, &reference, Some(&check), 3000, &foreign)
                    .unwrap();
            assert_eq!(fresh.pairs.index, following.pairs.index, "{spec}");
            let (a, b) = (fresh.measure(t.data()), following.measure(t.data()));
            assert_eq!(format!("{a:?}"), format!("{b:?}"), "{spec}");
        }
    }

    /// The estimation set gives a rare corner of the pair space its exact share: both
    /// directions within cos θ < 1/32 of the horizon holds 1/1024 of uniform pairs, and of
    /// 2¹⁷ stratified pairs exactly 128 fall there (a pseudo-random set: 128 ± 11). Inside a
    /// θmax domain every pair is within it, and the set is as large.
    #[test]
    fn the_estimation_set_holds_its_share_of_a_rare_corner() {
        let n = 1usize << 17;
        let corner = stratified_pairs(ESTIMATE_SEED, 0.0)
            .take(n)
            .filter(|(wi, wo)| wi.z < 1.0 / 32.0 && wo.z < 1.0 / 32.0)
            .count();
        assert_eq!(corner, 128);
        let domain = parse_grid_spec("halfdiff3:8x8x8,theta-max=5").unwrap();
        let draw = Draw::Stratified {
            n: 5000,
            domain: Some(Box::new(domain.clone())),
        };
        let set = draw.set();
        assert_eq!(set.pairs.len(), 5000);
        assert!(set.pairs.iter().all(|&(wi, wo)| domain.in_domain(wi, wo)));
        assert!(
            set.pairs
                .iter()
                .all(|(wi, wo)| wi.z >= 5f64.to_radians().cos() - 1e-12
                    && wo.z >= 5f64.to_radians().cos() - 1e-12)
        );
    }

    /// The budget's own curve: a bare conductor peak, whose ε follows the few pairs that hit
    /// the peak, gets a low ε far below ε (a second curve is tried); a body under a broad lobe
    /// keeps ε; a budget without relative metrics keeps ε.
    #[test]
    fn the_curve_scale_follows_the_low_epsilon_of_relative_budgets() {
        let budget = crate::plan::budget::Budget::parse("preview").unwrap();
        let log_only = crate::plan::budget::Budget::parse("log_rmse=0.01").unwrap();
        let scale = |spec: &str| {
            let m = Model::parse(spec).unwrap();
            let r = ReferenceSet::new(&m, 1 << 15);
            (
                r.curve_scale(&budget, 65536),
                r.curve_scale(&log_only, 65536),
            )
        };
        let (peak, peak_log) = scale("ggx:alpha=0.005,fresnel=al");
        assert!(peak < 0.67, "bare peak: {peak}");
        assert_eq!(peak_log, 1.0);
        let (body, _) = scale("lambert:albedo=0.5+ggx:alpha=0.3,fresnel=au");
        assert!(body > 0.8 && body <= 1.0, "body: {body}");
    }

    /// The curve's floor: under a core-percentile budget a table of a Lambertian surface has
    /// FLOOR_FRACTION × its (constant) value, channels in proportion keep floors in
    /// proportion (one ratio to the core median), and a budget that weighs every pair's
    /// relative error, or none, has no floor; nor has a model (its tail is smooth).
    #[test]
    fn the_curve_floor_follows_the_core_quantile_in_proportion() {
        use crate::plan::budget::Budget;
        let preview = Budget::parse("preview").unwrap();
        let g = parse_grid_spec("halfdiff3:8x8x12").unwrap();
        let table_of = |spec: &str| {
            let m = Model::parse(spec).unwrap();
            let t = crate::tabulate::tabulate(&m, &g, &Default::default()).unwrap();
            (m, t)
        };
        let sampled = |t: &crate::table::Table| crate::table::InterpolatedTable {
            table: t.clone(),
            interp: crate::table::Interp::Linear,
        };
        let (grey, grey_t) = table_of("lambert:albedo=0.5");
        assert_eq!(
            ReferenceSet::new(&grey, 1 << 15).curve_floor(&preview),
            None
        );
        let r = ReferenceSet::new(&sampled(&grey_t), 1 << 15);
        let f = r.curve_floor(&preview).unwrap();
        for (k, fl) in f.iter().enumerate() {
            let want = FLOOR_FRACTION * 0.5 / std::f64::consts::PI;
            assert!(
                (fl / want - 1.0).abs() < 1e-6,
                "channel {k}: {fl} vs {want}"
            );
        }
        // A tinted body under a lobe: its channels are in proportion only roughly; the floor
        // keeps one ratio to each channel's core median, so the channels' floors are in the
        // proportion of their medians, none above half its own 1% quantile.
        let (_, tinted_t) = table_of("lambert:albedo=0.6/0.3/0.1+ggx:alpha=0.3,fresnel=au");
        let tinted = sampled(&tinted_t);
        let r = ReferenceSet::new(&tinted, 1 << 15);
        let f = r.curve_floor(&preview).unwrap();
        let set = r.set();
        let mut median = Vec::new();
        for k in 0..3 {
            let mut core: Vec<f64> = set
                .pairs
                .iter()
                .zip(r.values.chunks_exact(3))
                .filter(|((wi, wo), _)| in_core_cos(wi.z, wo.z))
                .map(|(_, v)| v[k])
                .collect();
            let low = percentile(&mut core.clone(), 0.01);
            median.push(percentile(&mut core, 0.5));
            assert!(
                f[k] <= FLOOR_FRACTION * low * (1.0 + 1e-12),
                "{k}: {} > {low}",
                f[k]
            );
        }
        assert!((f[0] / f[2] - median[0] / median[2]).abs() < 1e-9 * f[0] / f[2]);
        for spec in [
            "log_rmse=0.01",
            "p99_rel_core=0.2,rel_rmse_core=0.5",
            "max_rel=1",
        ] {
            assert_eq!(r.curve_floor(&Budget::parse(spec).unwrap()), None, "{spec}");
        }
        // The estimator built from the set draws the same floor.
        let est = ErrorEstimator::new(&tinted_t, &r, None, 1 << 15).unwrap();
        assert_eq!(est.curve_floor(&preview), Some(f));
    }

    /// A table of model `spec` on grid `grid`, and the estimator of `n` pairs of that table
    /// against itself as a sampled source (a measured file's case: the grid error is 0).
    fn table_source_estimator(spec: &str, grid: &str, n: usize) -> (Table, ErrorEstimator) {
        let g = parse_grid_spec(grid).unwrap();
        let m = Model::parse(spec).unwrap();
        let t = crate::tabulate::tabulate(&m, &g, &Default::default()).unwrap();
        let source = crate::table::InterpolatedTable {
            table: t.clone(),
            interp: crate::table::Interp::Linear,
        };
        let r = ReferenceSet::new(&source, n);
        let est = ErrorEstimator::new(&t, &r, None, n).unwrap();
        (t, est)
    }

    /// The raised curve's limit on a Lambertian table, whose core values are all f: every
    /// value's amplification is A = (K·ε + f)/(ε + f), so the percentile grows by exactly
    /// A and the limit is the last √2 step with A ≤ the growth allowed.
    #[test]
    fn a_raised_curve_stops_where_the_percentile_grows_by_the_limit() {
        // Extended below the horizon: no pair near it interpolates an empty cell.
        let (_, est) = table_source_estimator(
            "lambert:albedo=0.5",
            "halfdiff3:8x8x12,horizon=extend",
            1 << 14,
        );
        let f = 0.5 / std::f64::consts::PI;
        // One channel (grey).
        let limit = |x: f64| est.curve_raise_limit(&[f / x], 0.01, 1.25);
        // f = 100 ε: A ≤ 1.25 for K ≤ 26.25 (the histogram's bins move x by < 5%).
        assert!(
            (limit(100.0) - 2f64.powf(4.5)).abs() < 1e-9,
            "{}",
            limit(100.0)
        );
        // f = ε: A(√2) = 1.21, A(2) = 1.5.
        assert!((limit(1.0) - 2f64.sqrt()).abs() < 1e-12, "{}", limit(1.0));
        // f far below ε: even √2 nearly multiplies the error by √2.
        assert_eq!(limit(0.01), 1.0);
        // Far above ε the ladder ends at RAISE_MAX.
        assert_eq!(limit(1e7), RAISE_MAX);
        // No percentile (allowance 0) or no growth allowed: no raise.
        assert_eq!(est.curve_raise_limit(&[f], 0.0, 1.25), 1.0);
        assert_eq!(est.curve_raise_limit(&[f], 0.01, 1.0), 1.0);
        // An ε per channel of another table: no raise.
        assert_eq!(est.curve_raise_limit(&[f; 3], 0.01, 1.25), 1.0);
    }

    /// The dark tail's share: none without errors, about 1 for errors in proportion to the
    /// values, near its maximum 1/(2·allowance) = 50 for an absolute offset (whose relative
    /// error is largest at the darkest values).
    #[test]
    fn the_dark_tail_share_finds_errors_at_the_dark_end() {
        let (t, est) = table_source_estimator(
            "lambert:albedo=0.6/0.3/0.1+ggx:alpha=0.3,fresnel=au",
            "halfdiff3:8x8x12",
            1 << 15,
        );
        let cells = est.cells();
        let at_cells = |change: &dyn Fn(f32, usize) -> f32| {
            let mut v = vec![0f32; cells.len() * 3];
            cells.for_each_in(0..t.grid().cells(), |f, place| {
                for k in 0..3 {
                    let x = t.data()[f as usize * 3 + k];
                    v[place * 3 + k] = change(x, f as usize * 3 + k);
                }
            });
            v
        };
        assert_eq!(est.dark_tail_share(&at_cells(&|x, _| x), 0.01), 0.0);
        // A deterministic ±1% relative error per value.
        let wobble = |i: usize| ((i as f64 * 0.618_034).fract() * 2.0 - 1.0) * 0.01;
        let spread = est.dark_tail_share(&at_cells(&|x, i| x * (1.0 + wobble(i)) as f32), 0.01);
        assert!(spread > 0.2 && spread < 4.0, "spread: {spread}");
        let offset = est.dark_tail_share(&at_cells(&|x, _| x + 1e-3), 0.01);
        assert!(offset > 40.0 && offset <= 50.0, "offset: {offset}");
    }

    /// Every draw gives pair k again as its set holds it, bit for bit.
    #[test]
    fn a_pair_drawn_again_is_the_set_s_pair() {
        let domain = Box::new(parse_grid_spec("spherical3:8x8x8,theta-max=40").unwrap());
        for draw in [
            Draw::Uniform { n: 4000, seed: 3 },
            Draw::Stratified {
                n: 4000,
                domain: Some(domain.clone()),
            },
            Draw::KeptIn {
                n: 4000,
                seed: 5,
                domain,
            },
        ] {
            let set = draw.set();
            assert!(set.pairs.len() > 100);
            let bits = |(a, b): (Vec3, Vec3)| [a.x, a.y, a.z, b.x, b.y, b.z].map(f64::to_bits);
            for k in [0, 1, 57, set.pairs.len() - 1] {
                assert_eq!(bits(draw.pair(k)), bits(set.pairs[k]));
            }
            assert_eq!(draw.pairs().count(), set.pairs.len());
        }
    }
}
