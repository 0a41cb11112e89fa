//! Round-trip error: the sample sets and metrics of `spec/metrics.md`.
//!
//! Every report states the formula's inputs: the sample set, its size and seed, and ε.

use crate::brdf::Brdf;
use crate::geometry::Vec3;
use crate::grid::Grid;
use crate::math::{PI, SplitMix64};
use crate::table::Table;
use crate::{Error, Result};
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

/// A deterministic set of direction pairs (with weights for the `cells` set).
#[derive(Clone, Debug)]
pub struct SampleSet {
    pub name: String,
    pub seed: Option<u64>,
    pub pairs: Vec<(Vec3, Vec3)>,
    /// Per-pair weights (solid-angle measure); `None` = equal weights.
    pub weights: Option<Vec<f64>>,
}

/// Which sample set.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum SetKind {
    Uniform,
    Grazing,
    Specular,
    Cells,
}

/// Uniform in solid angle over the upper hemisphere: z = u1, φ = 2π u2.
fn uniform_dir(rng: &mut SplitMix64) -> Vec3 {
    let z = rng.next_f64();
    let phi = 2.0 * PI * rng.next_f64();
    let r = (1.0 - z * z).max(0.0).sqrt();
    Vec3::new(r * phi.cos(), r * phi.sin(), z)
}

/// θ uniform in [75°, 89.9°], φ uniform.
fn grazing_dir(rng: &mut SplitMix64) -> Vec3 {
    let theta = (75.0 + 14.9 * rng.next_f64()).to_radians();
    Vec3::from_spherical(theta, 2.0 * PI * rng.next_f64())
}

/// Half-angle of the cone around the mirror direction used by the `specular` set.
pub const SPECULAR_CONE_DEG: f64 = 3.0;

/// The pairs of [`SampleSet::uniform`] from `seed`, one at a time (the set's first n are its
/// pairs): a holder of a set can draw one of them again instead of keeping them all.
pub fn uniform_pairs(seed: u64) -> impl Iterator<Item = (Vec3, Vec3)> {
    let mut rng = SplitMix64::new(seed);
    std::iter::repeat_with(move || {
        let wi = uniform_dir(&mut rng);
        (wi, uniform_dir(&mut rng))
    })
}

impl SampleSet {
    /// `uniform`: wi and wo independent and uniform in solid angle.
    pub fn uniform(n: usize, seed: u64) -> SampleSet {
        let pairs = uniform_pairs(seed).take(n).collect();
        SampleSet {
            name: "uniform".into(),
            seed: Some(seed),
            pairs,
            weights: None,
        }
    }

    /// `grazing`: θ uniform in [75°, 89.9°] for wi, wo or both (a third each).
    pub fn grazing(n: usize, seed: u64) -> SampleSet {
        let mut rng = SplitMix64::new(seed ^ 0x6772_617a);
        let pairs = (0..n)
            .map(|k| match k % 3 {
                0 => (grazing_dir(&mut rng), uniform_dir(&mut rng)),
                1 => (uniform_dir(&mut rng), grazing_dir(&mut rng)),
                _ => (grazing_dir(&mut rng), grazing_dir(&mut rng)),
            })
            .collect();
        SampleSet {
            name: "grazing".into(),
            seed: Some(seed),
            pairs,
            weights: None,
        }
    }

    /// The pairs for which `keep` holds (weights kept alongside).
    pub fn restricted(&self, keep: impl Fn(Vec3, Vec3) -> bool) -> SampleSet {
        let mut pairs = Vec::new();
        let mut weights = self.weights.as_ref().map(|_| Vec::new());
        for (p, &(wi, wo)) in self.pairs.iter().enumerate() {
            if keep(wi, wo) {
                pairs.push((wi, wo));
                if let (Some(w), Some(all)) = (weights.as_mut(), self.weights.as_ref()) {
                    w.push(all[p]);
                }
            }
        }
        SampleSet {
            name: self.name.clone(),
            seed: self.seed,
            pairs,
            weights,
        }
    }

    /// `specular`: wi uniform, wo uniform in solid angle within 3° of wi's mirror direction
    /// (redrawn when that falls below the horizon).
    pub fn specular(n: usize, seed: u64) -> SampleSet {
        let mut rng = SplitMix64::new(seed ^ 0x7370_6563);
        let cos_max = SPECULAR_CONE_DEG.to_radians().cos();
        let mut pairs = Vec::with_capacity(n);
        while pairs.len() < n {
            let wi = uniform_dir(&mut rng);
            let m = wi.mirror();
            // A direction in the cone around +z, then rotated onto m.
            let cz = 1.0 - rng.next_f64() * (1.0 - cos_max);
            let phi = 2.0 * PI * rng.next_f64();
            let local = Vec3::from_spherical(cz.acos(), phi);
            let wo = local.rotate_y(m.theta()).rotate_z(m.phi());
            if wo.z > 0.0 {
                pairs.push((wi, wo));
            }
        }
        SampleSet {
            name: "specular".into(),
            seed: Some(seed),
            pairs,
            weights: None,
        }
    }

    /// `cells`: every valid cell of `grid` at its sample position, weighted by its measure.
    pub fn cells(grid: &Grid, valid: &[bool]) -> SampleSet {
        let d = grid.axes().len();
        let mut idx = [0usize; 4];
        // Exact sizes: doubling growth would hold up to twice the set while it grows.
        let n = valid.iter().filter(|&&v| v).count();
        let mut pairs = Vec::with_capacity(n);
        let mut weights = Vec::with_capacity(n);
        let dirs = grid.cell_directions();
        for (f, &ok) in valid.iter().enumerate() {
            if !ok {
                continue;
            }
            grid.unflatten(f, &mut idx[..d]);
            let (wi, wo) = dirs.at(&idx[..d]);
            // A valid cell below the horizon (an extended grid's, or a measured file's value
            // there) is read by interpolation but is no pair of the BRDF's domain: both
            // sources give 0 at it.
            if !(wi.z > 0.0 && wo.z > 0.0) {
                continue;
            }
            pairs.push((wi, wo));
            weights.push(grid.cell_measure(&idx[..d]));
        }
        SampleSet {
            name: "cells".into(),
            seed: None,
            pairs,
            weights: Some(weights),
        }
    }
}

/// A direction pair in a report.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct Pair {
    pub wi: [f64; 3],
    pub wo: [f64; 3],
}

/// The metrics of `spec/metrics.md` for one channel or all channels pooled.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct Metrics {
    pub rmse: f64,
    pub rel_rmse: f64,
    pub max_abs: f64,
    pub max_abs_at: Pair,
    pub max_rel: f64,
    pub max_rel_at: Pair,
    pub log_rmse: f64,
    pub rel_rmse_core: f64,
    pub p99_rel_core: f64,
    pub nonfinite: u64,
    pub negative: u64,
    /// ε of the relative metrics: 1e-3 · mean |f|.
    pub epsilon: f64,
}

/// Metrics of one sample set.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct SetReport {
    pub set: String,
    pub samples: usize,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub seed: Option<u64>,
    pub combined: Metrics,
    pub per_channel: Vec<Metrics>,
}

/// The names of the metrics that `--max-*` bounds can refer to.
pub const BOUNDABLE: &[&str] = &[
    "rmse",
    "rel_rmse",
    "max_abs",
    "max_rel",
    "log_rmse",
    "rel_rmse_core",
    "p99_rel_core",
    "albedo_err",
];

impl Metrics {
    /// The value of a metric by name (see [`BOUNDABLE`]).
    pub fn get(&self, name: &str) -> Option<f64> {
        Some(match name {
            "rmse" => self.rmse,
            "rel_rmse" => self.rel_rmse,
            "max_abs" => self.max_abs,
            "max_rel" => self.max_rel,
            "log_rmse" => self.log_rmse,
            "rel_rmse_core" => self.rel_rmse_core,
            "p99_rel_core" => self.p99_rel_core,
            "nonfinite" => self.nonfinite as f64,
            "negative" => self.negative as f64,
            _ => return None,
        })
    }
}

/// Evaluates both sources on a sample set: (reference f, candidate g), pair-major.
pub fn evaluate_pairs(
    reference: &dyn Brdf,
    candidate: &dyn Brdf,
    set: &SampleSet,
) -> Result<(Vec<f64>, Vec<f64>)> {
    comparable(reference, candidate)?;
    Ok((evaluate_set(reference, set), evaluate_set(candidate, set)))
}

/// Refuses two sources whose values cannot be compared channel by channel.
fn comparable(reference: &dyn Brdf, candidate: &dyn Brdf) -> Result<()> {
    let c = reference.channels().len();
    if candidate.channels().len() != c {
        return Err(Error::input(format!(
            "the candidate has {} channels ({}) but the reference has {c} ({})",
            candidate.channels().len(),
            candidate.channels().names().join(","),
            reference.channels().names().join(",")
        )));
    }
    // Same count is not enough: RGB against spectral samples (or spectral samples at other
    // wavelengths) would be compared channel by channel, a number with no meaning.
    let (wr, wc) = (
        reference.channels().wavelengths_nm(),
        candidate.channels().wavelengths_nm(),
    );
    if wr != wc {
        let describe = |w: Option<&[f64]>, ch: &crate::brdf::Channels| match w {
            Some(w) => format!("spectral at {w:?} nm"),
            None => format!("not spectral ({})", ch.names().join(",")),
        };
        return Err(Error::input(format!(
            "the candidate is {} but the reference is {}: convert the spectral one to RGB first \
             (--to-rgb of tabulate and convert)",
            describe(wc, candidate.channels()),
            describe(wr, reference.channels())
        )));
    }
    Ok(())
}

/// The values of one BRDF at every pair of `set` (pair-major): one side of
/// [`evaluate_pairs`]. The codec search computes its reference values once with it.
pub fn evaluate_set(brdf: &dyn Brdf, set: &SampleSet) -> Vec<f64> {
    let c = brdf.channels().len();
    let mut f = vec![0.0; set.pairs.len() * c];
    const CHUNK: usize = 1024;
    f.par_chunks_mut(CHUNK * c).enumerate().for_each(|(k, fc)| {
        let pairs = &set.pairs[k * CHUNK..(k * CHUNK + fc.len() / c)];
        for (j, &(wi, wo)) in pairs.iter().enumerate() {
            brdf.eval(wi, wo, &mut fc[j * c..(j + 1) * c]);
        }
    });
    f
}

/// Computes the metrics of `g` against `f` over `set` (pair-major, `c` channels).
/// `channel`: `Some(k)` for one channel, `None` for all pooled.
pub fn metrics(set: &SampleSet, f: &[f64], g: &[f64], c: usize, channel: Option<usize>) -> Metrics {
    metrics_of(set, f, g, c, channel)
}

/// What [`metrics_of`] reads of a set's pairs besides the values: a holder of many pairs
/// (the planner's estimators) can keep these few numbers instead of the directions.
pub trait MetricPairs {
    /// Pairs in the set.
    fn count(&self) -> usize;
    /// Pair `p`'s weight (solid-angle measure); 1 for equal weights.
    fn weight(&self, p: usize) -> f64;
    /// cos θi of pair `p` (the log error's cosine).
    fn cos_i(&self, p: usize) -> f64;
    /// Whether pair `p` is in the core region ([`in_core`]).
    fn core(&self, p: usize) -> bool;
    /// Pair `p` itself: asked only for the pairs where the maxima are.
    fn pair(&self, p: usize) -> (Vec3, Vec3);
}

impl MetricPairs for SampleSet {
    fn count(&self) -> usize {
        self.pairs.len()
    }
    fn weight(&self, p: usize) -> f64 {
        self.weights.as_ref().map_or(1.0, |w| w[p])
    }
    fn cos_i(&self, p: usize) -> f64 {
        self.pairs[p].0.z
    }
    fn core(&self, p: usize) -> bool {
        let (wi, wo) = self.pairs[p];
        in_core(wi, wo)
    }
    fn pair(&self, p: usize) -> (Vec3, Vec3) {
        self.pairs[p]
    }
}

/// [`metrics`] of any [`MetricPairs`]: the same numbers, summed in the same order.
pub fn metrics_of(
    set: &impl MetricPairs,
    f: &[f64],
    g: &[f64],
    c: usize,
    channel: Option<usize>,
) -> Metrics {
    let chans: Vec<usize> = match channel {
        Some(k) => vec![k],
        None => (0..c).collect(),
    };
    let n = set.count();
    // ε = 1e-3 · mean |f| (weighted like the other means).
    let mut eps = EpsilonSum::default();
    for p in 0..n {
        for &k in &chans {
            eps.add(set.weight(p), f[p * c + k]);
        }
    }
    let eps = eps.epsilon();
    let core_values = (0..n).filter(|&p| set.core(p)).count() * chans.len();
    let mut row = Row::new(eps, core_values);
    for p in 0..n {
        let (w, core, cos_i) = (set.weight(p), set.core(p), set.cos_i(p));
        for &k in &chans {
            let t = Term::new(f[p * c + k], g[p * c + k], cos_i, eps, eps);
            row.add(w, p, core, &t, t.rel);
        }
    }
    row.finish(|p| set.pair(p))
}

/// The weighted sum of |f| that ε of the relative metrics is made of.
#[derive(Clone, Copy, Debug, Default)]
struct EpsilonSum {
    sf: f64,
    sw: f64,
}

impl EpsilonSum {
    /// One reference value of weight `w` (non-finite values do not count).
    #[inline]
    fn add(&mut self, w: f64, v: f64) {
        if v.is_finite() {
            self.sf += w * v.abs();
            self.sw += w;
        }
    }

    /// ε = 1e-3 · mean |f|, never 0 (that would make 0/0 of an identically zero reference).
    fn epsilon(&self) -> f64 {
        let eps = if self.sw > 0.0 {
            1e-3 * self.sf / self.sw
        } else {
            0.0
        };
        if eps > 0.0 { eps } else { f64::MIN_POSITIVE }
    }
}

/// What one (pair, channel) value contributes, computed where the values are evaluated (in
/// parallel) and summed in the set's order elsewhere: the same numbers either way.
#[derive(Clone, Copy, Debug)]
struct Term {
    /// |g − f|.
    abs: f64,
    /// The relative error with ε of the row of all channels pooled.
    rel: f64,
    /// The relative error with ε of the value's own channel.
    rel_own: f64,
    /// [`log_error`].
    log: f64,
    /// g is finite (otherwise only counted as `nonfinite`).
    finite: bool,
    /// g < 0.
    negative: bool,
}

impl Term {
    #[inline]
    fn new(f: f64, g: f64, cos_i: f64, eps_pooled: f64, eps_own: f64) -> Term {
        if !g.is_finite() {
            return Term {
                abs: 0.0,
                rel: 0.0,
                rel_own: 0.0,
                log: 0.0,
                finite: false,
                negative: false,
            };
        }
        Term {
            abs: (g - f).abs(),
            rel: rel_error(f, g, eps_pooled),
            rel_own: rel_error(f, g, eps_own),
            log: log_error(f, g, cos_i),
            finite: true,
            negative: g < 0.0,
        }
    }
}

/// One row of a report (all channels pooled, or one channel), fed value by value in the set's
/// order: the weighted sums and maxima of the metrics, and the largest core relative errors,
/// as many as the 99th percentile can need. Nothing else is held, however large the set.
struct Row<A: Copy> {
    m: Metrics,
    /// Where `max_abs` and `max_rel` are (as the caller names a pair; `None` before any).
    max_abs_at: Option<A>,
    max_rel_at: Option<A>,
    se: SumOfSquares,
    sre: SumOfSquares,
    sle: f64,
    sw: f64,
    sre_core: SumOfSquares,
    sw_core: f64,
    n_core: usize,
    top: Largest,
}

/// The quantile of `p99_rel_core`.
const P99: f64 = 0.99;

impl<A: Copy> Row<A> {
    /// A row with ε `eps` that will see at most `core_values` values in the core region.
    fn new(eps: f64, core_values: usize) -> Row<A> {
        Row {
            m: Metrics {
                epsilon: eps,
                ..Default::default()
            },
            max_abs_at: None,
            max_rel_at: None,
            se: SumOfSquares::default(),
            sre: SumOfSquares::default(),
            sle: 0.0,
            sw: 0.0,
            sre_core: SumOfSquares::default(),
            sw_core: 0.0,
            n_core: 0,
            top: Largest::new(Largest::needed(core_values, P99)),
        }
    }

    /// One value of weight `w` at `pair`; `rel` is `t`'s relative error with this row's ε.
    #[inline]
    fn add(&mut self, w: f64, at: A, core: bool, t: &Term, rel: f64) {
        let m = &mut self.m;
        if !t.finite {
            m.nonfinite += 1;
            return;
        }
        if t.negative {
            m.negative += 1;
        }
        let abs = t.abs;
        self.se.add(w, abs);
        self.sre.add(w, rel);
        self.sle += w * t.log * t.log;
        self.sw += w;
        if abs > m.max_abs {
            m.max_abs = abs;
            self.max_abs_at = Some(at);
        }
        if rel > m.max_rel {
            m.max_rel = rel;
            self.max_rel_at = Some(at);
        }
        if core {
            self.sre_core.add(w, rel);
            self.sw_core += w;
            self.n_core += 1;
            self.top.push(rel);
        }
    }

    /// The metrics, the maxima's pairs named by `pair`.
    fn finish(self, pair: impl Fn(A) -> (Vec3, Vec3)) -> Metrics {
        let mut m = self.m;
        let named = |at: Option<A>| {
            at.map_or_else(Pair::default, |a| {
                let (wi, wo) = pair(a);
                Pair {
                    wi: wi.to_array(),
                    wo: wo.to_array(),
                }
            })
        };
        m.max_abs_at = named(self.max_abs_at);
        m.max_rel_at = named(self.max_rel_at);
        if self.sw > 0.0 {
            m.rmse = self.se.rms(self.sw);
            m.rel_rmse = self.sre.rms(self.sw);
            m.log_rmse = (self.sle / self.sw).sqrt();
        }
        if self.sw_core > 0.0 {
            m.rel_rmse_core = self.sre_core.rms(self.sw_core);
            m.p99_rel_core = self.top.nearest_rank(self.n_core, P99);
        }
        m
    }
}

/// A weighted sum of squares for a root mean square that stays finite whenever its values
/// are: Σ w·x² in plain f64 (the bits every report has always had), and beside it the same
/// sum of (x·2⁻⁶⁰⁰)², used only when the plain one overflows. A relative error beyond 1e154
/// (a candidate against a reference of 1e-300 or of 0, whose ε is that small) used to square
/// to infinity and print `rel_rmse inf`; the root mean square of finite values is at most
/// their maximum, so it is representable.
#[derive(Clone, Copy, Debug, Default)]
struct SumOfSquares {
    plain: f64,
    scaled: f64,
}

impl SumOfSquares {
    /// 2⁻⁶⁰⁰: x·2⁻⁶⁰⁰ squared stays below 2⁸⁵⁰ for any finite x.
    const DOWN: f64 = f64::from_bits((1023 - 600) << 52);
    /// 2⁶⁰⁰.
    const UP: f64 = f64::from_bits((1023 + 600) << 52);

    #[inline]
    fn add(&mut self, w: f64, x: f64) {
        self.plain += w * x * x;
        let s = x * Self::DOWN;
        self.scaled += w * s * s;
    }

    /// sqrt(Σ w·x² / `sw`): the plain sum's when finite, else the scaled one's (values
    /// small enough to vanish in it are negligible beside a sum over 1e308), never beyond
    /// the largest finite f64.
    fn rms(&self, sw: f64) -> f64 {
        let r = (self.plain / sw).sqrt();
        if r.is_finite() {
            r
        } else {
            ((self.scaled / sw).sqrt() * Self::UP).min(f64::MAX)
        }
    }
}

/// The largest values pushed, at most `cap` of them: enough for a high quantile by the
/// nearest-rank method ([`percentile`]) of a count known only at the end but bounded up front.
struct Largest {
    cap: usize,
    /// The kept values' [`order_key`]s, smallest on top.
    heap: std::collections::BinaryHeap<std::cmp::Reverse<u64>>,
}

impl Largest {
    /// How many of the largest of at most `n` values the q-quantile by [`percentile`] can
    /// need: the rank counted from the top is n − ⌈q·n⌉ + 1 ≤ (1 − q)·n + 2 (the product's
    /// rounding moves ⌈q·n⌉ by less than 1 for n < 2⁵²), with a margin.
    fn needed(n: usize, q: f64) -> usize {
        ((((1.0 - q) * n as f64).ceil() as usize).saturating_add(4)).min(n)
    }

    fn new(cap: usize) -> Largest {
        Largest {
            cap,
            heap: std::collections::BinaryHeap::with_capacity(cap.min(1 << 16)),
        }
    }

    #[inline]
    fn push(&mut self, x: f64) {
        let k = std::cmp::Reverse(order_key(x));
        if self.heap.len() < self.cap {
            self.heap.push(k);
        } else if let Some(mut min) = self.heap.peek_mut()
            && k < *min
        {
            *min = k;
        }
    }

    /// The q-quantile by the nearest-rank method of the `n` values pushed: the value
    /// [`percentile`] returns for them.
    fn nearest_rank(self, n: usize, q: f64) -> f64 {
        if n == 0 {
            return 0.0;
        }
        let rank = ((q * n as f64).ceil() as usize).clamp(1, n) - 1;
        // Descending: the rank-th smallest of n is the (n − 1 − rank)-th largest.
        let top = self.heap.into_sorted_vec();
        let from_top = n - 1 - rank;
        debug_assert!(from_top < top.len(), "{from_top} of {} kept", top.len());
        // `needed` keeps enough for every n up to the bound; should it not, the smallest
        // value kept is the nearest upper bound there is.
        let std::cmp::Reverse(k) = top[from_top.min(top.len() - 1)];
        from_order_key(k)
    }
}

/// A u64 that orders like `f64::total_cmp` (sign bit flipped for positives, all bits for
/// negatives).
#[inline]
fn order_key(x: f64) -> u64 {
    let b = x.to_bits();
    if b >> 63 == 1 { !b } else { b | 1 << 63 }
}

/// The inverse of [`order_key`].
#[inline]
fn from_order_key(k: u64) -> f64 {
    f64::from_bits(if k >> 63 == 1 { k & !(1 << 63) } else { !k })
}

/// |g − f| / (|f| + ε): the relative error of `rel_rmse`, `max_rel` and `p99_rel_core`.
///
/// A quotient beyond f64's range (a reference of 0 or nearly, where ε is as small as
/// 2.2e-308, and a candidate that is not) is the largest finite f64, 1.7977e308, not
/// infinity: reports hold no infinity (docs/metrics.md), and any bound still fails on it.
#[inline]
pub fn rel_error(f: f64, g: f64, eps: f64) -> f64 {
    let r = (g - f).abs() / (f.abs() + eps);
    if r == f64::INFINITY { f64::MAX } else { r }
}

/// ln(1 + g cos θi) − ln(1 + f cos θi): the cosine-weighted log error of `log_rmse`.
///
/// The spec's ln(1 + x) is undefined for x ≤ −1, and measured sources do hold negative
/// values (RGL files' RGB tables dip below 0 near grazing, where the spectral-to-RGB
/// conversion rings): a clamp there turned one pair into an error of ~700 and a whole
/// table's log_rmse into 1.6. Negative x therefore uses the odd extension −ln(1 − x)
/// (sign(x)·ln(1 + |x|)): the same value for every x ≥ 0, continuous, finite everywhere.
#[inline]
pub fn log_error(f: f64, g: f64, cos_i: f64) -> f64 {
    signed_log1p(g * cos_i) - signed_log1p(f * cos_i)
}

/// sign(x)·ln(1 + |x|) ([`log_error`]).
#[inline]
fn signed_log1p(x: f64) -> f64 {
    if x >= 0.0 { x.ln_1p() } else { -(-x).ln_1p() }
}

/// The `_core` metrics' region: cos θi ≥ 0.1 and cos θo ≥ 0.1 (where renders look).
#[inline]
pub fn in_core(wi: Vec3, wo: Vec3) -> bool {
    in_core_cos(wi.z, wo.z)
}

/// [`in_core`] from cos θi and cos θo.
#[inline]
pub fn in_core_cos(cos_i: f64, cos_o: f64) -> bool {
    cos_i >= 0.1 && cos_o >= 0.1
}

/// ε of the relative metrics for reference values `f` (pair-major, all channels pooled,
/// equal weights): 1e-3 · mean |f| over the finite values, never 0.
pub fn metric_epsilon(f: &[f64]) -> f64 {
    let (mut s, mut n) = (0.0, 0usize);
    for v in f.iter().filter(|v| v.is_finite()) {
        s += v.abs();
        n += 1;
    }
    let eps = if n > 0 { 1e-3 * s / n as f64 } else { 0.0 };
    if eps > 0.0 { eps } else { f64::MIN_POSITIVE }
}

/// The q-quantile by the nearest-rank method (unweighted).
pub fn percentile(v: &mut [f64], q: f64) -> f64 {
    if v.is_empty() {
        return 0.0;
    }
    let rank = ((q * v.len() as f64).ceil() as usize).clamp(1, v.len()) - 1;
    let (_, x, _) = v.select_nth_unstable_by(rank, |a, b| a.total_cmp(b));
    *x
}

/// Runs a sample set and reports combined and per-channel metrics.
pub fn check_set(reference: &dyn Brdf, candidate: &dyn Brdf, set: &SampleSet) -> Result<SetReport> {
    check_pairs(reference, candidate, &Pairs::Set(set), &set.name, set.seed)
}

/// Where a check takes its pairs from, chunk by chunk: a sample set held in memory, or the
/// valid cells of a grid (at their sample positions, weighted by their measure) that `keep`
/// accepts, generated as they are evaluated.
enum Pairs<'a> {
    Set(&'a SampleSet),
    Cells {
        grid: &'a Grid,
        valid: &'a [bool],
        keep: &'a (dyn Fn(Vec3, Vec3) -> bool + Sync),
    },
}

/// Values (pairs × channels) per chunk of a streamed check.
const CHUNK_VALUES: usize = 1 << 14;

impl Pairs<'_> {
    /// Chunks of `per` pairs (of `per` cells for a grid: fewer pairs where cells are invalid
    /// or not kept).
    fn chunks(&self, per: usize) -> usize {
        let n = match self {
            Pairs::Set(s) => s.pairs.len(),
            Pairs::Cells { valid, .. } => valid.len(),
        };
        n.div_ceil(per)
    }

    /// What a grid's cells need of its geometry ([`Pairs::chunk`]): the per-axis tables of
    /// the cells' directions and measures, made once per check instead of per-cell
    /// trigonometry (the same bits: `grid::dirs`' test, and a product in the same order).
    fn geometry(&self) -> Option<CellGeometry> {
        match self {
            Pairs::Set(_) => None,
            Pairs::Cells { grid, .. } => Some(CellGeometry {
                dirs: grid.cell_directions(),
                measure: grid.cell_measure_factors(),
            }),
        }
    }

    /// The pairs and weights of chunk `k` of `per`, in the set's order, and for a grid's
    /// cells their flat indices (`geo`: [`Pairs::geometry`]).
    fn chunk(&self, k: usize, per: usize, geo: Option<&CellGeometry>) -> Chunk {
        match self {
            Pairs::Set(s) => {
                let r = k * per..((k + 1) * per).min(s.pairs.len());
                let w = match &s.weights {
                    Some(w) => w[r.clone()].to_vec(),
                    None => vec![1.0; r.len()],
                };
                Chunk {
                    pairs: s.pairs[r].to_vec(),
                    weights: w,
                    cells: Vec::new(),
                }
            }
            Pairs::Cells { grid, valid, keep } => {
                let geo = geo.expect("Pairs::chunk: the cells' geometry");
                let d = grid.axes().len();
                let mut idx = [0usize; 4];
                let mut out = Chunk {
                    pairs: Vec::new(),
                    weights: Vec::new(),
                    cells: Vec::new(),
                };
                let end = ((k + 1) * per).min(valid.len());
                for (f, _) in valid[k * per..end]
                    .iter()
                    .enumerate()
                    .filter(|(_, ok)| **ok)
                    .map(|(j, ok)| (k * per + j, ok))
                {
                    grid.unflatten(f, &mut idx[..d]);
                    let (wi, wo) = geo.dirs.at(&idx[..d]);
                    // As in [`SampleSet::cells`]: a valid cell below the horizon is no pair
                    // of the BRDF's domain.
                    if wi.z > 0.0 && wo.z > 0.0 && keep(wi, wo) {
                        out.pairs.push((wi, wo));
                        // Grid::cell_measure's product, factor by factor in the same order.
                        out.weights.push(
                            idx[..d]
                                .iter()
                                .enumerate()
                                .map(|(a, &i)| geo.measure[a][i])
                                .product(),
                        );
                        out.cells.push(f);
                    }
                }
                out
            }
        }
    }

    /// The table behind `brdf` when these are the cells of its own grid ([`Table::behind`]).
    fn own_table<'a>(&self, brdf: &'a dyn Brdf) -> Option<&'a Table> {
        match self {
            Pairs::Set(_) => None,
            Pairs::Cells { grid, .. } => Table::behind(brdf, grid),
        }
    }
}

/// A grid's per-axis tables for its cells' pairs and weights ([`Pairs::geometry`]).
struct CellGeometry {
    dirs: crate::grid::CellDirections,
    measure: Vec<Vec<f64>>,
}

/// One chunk of a streamed check.
struct Chunk {
    pairs: Vec<(Vec3, Vec3)>,
    weights: Vec<f64>,
    /// Flat cell indices of the pairs (a grid's cells), else empty.
    cells: Vec<usize>,
}

/// Makes chunks `0..n` in parallel, a few at a time, and hands them to `sink` in order: what
/// `sink` sums is summed in the same order however many threads there are, and only a batch
/// of chunks is held at once.
fn for_each_chunk<T: Send>(n: usize, make: impl Fn(usize) -> T + Sync, mut sink: impl FnMut(T)) {
    let batch = (2 * rayon::current_num_threads()).clamp(8, 32);
    let mut k = 0;
    while k < n {
        let end = (k + batch).min(n);
        let made: Vec<T> = (k..end).into_par_iter().map(&make).collect();
        made.into_iter().for_each(&mut sink);
        k = end;
    }
}

/// Combined and per-channel metrics of `candidate` against `reference` over `pairs`, in two
/// streamed passes: ε from the reference's values, then the sums, maxima and the largest core
/// errors. Memory: a batch of chunks and the few values the 99th percentile needs, not the
/// set; the numbers are those of [`metrics`] on the whole set, bit for bit (same terms, summed
/// in the same order).
fn check_pairs(
    reference: &dyn Brdf,
    candidate: &dyn Brdf,
    pairs: &Pairs,
    name: &str,
    seed: Option<u64>,
) -> Result<SetReport> {
    comparable(reference, candidate)?;
    let c = reference.channels().len();
    let per = (CHUNK_VALUES / c.max(1)).max(1);
    let chunks = pairs.chunks(per);
    let (own_reference, own_candidate) = (pairs.own_table(reference), pairs.own_table(candidate));
    let geo = pairs.geometry();
    // A chunk's values: a table's own valid cells read at its nodes, every other pair
    // through one `eval_pairs` (a table's batched lookups; the bits of `eval` per pair).
    let eval = |brdf: &dyn Brdf, own: Option<&Table>, chunk: &Chunk| {
        let mut v = vec![0.0; chunk.pairs.len() * c];
        let Some(t) = own else {
            brdf.eval_pairs(&chunk.pairs, &mut v);
            return v;
        };
        let mut rest = Vec::new();
        for (j, &pair) in chunk.pairs.iter().enumerate() {
            let cell = chunk.cells[j];
            if t.valid()[cell] {
                let out = &mut v[j * c..(j + 1) * c];
                for (o, &x) in out.iter_mut().zip(&t.data()[cell * c..(cell + 1) * c]) {
                    *o = x as f64;
                }
            } else {
                rest.push((j, pair));
            }
        }
        if !rest.is_empty() {
            let pairs: Vec<(Vec3, Vec3)> = rest.iter().map(|r| r.1).collect();
            let mut g = vec![0.0; pairs.len() * c];
            brdf.eval_pairs(&pairs, &mut g);
            for ((j, _), g) in rest.iter().zip(g.chunks_exact(c.max(1))) {
                v[j * c..(j + 1) * c].copy_from_slice(g);
            }
        }
        v
    };
    // Pass 1: ε of every row (row 0: all channels pooled; row 1 + k: channel k), the count of
    // pairs and of those in the core region.
    let mut eps = vec![EpsilonSum::default(); c + 1];
    let (mut n, mut n_core) = (0usize, 0usize);
    for_each_chunk(
        chunks,
        |k| {
            let chunk = pairs.chunk(k, per, geo.as_ref());
            let f = eval(reference, own_reference, &chunk);
            let core = chunk
                .pairs
                .iter()
                .filter(|&&(wi, wo)| in_core(wi, wo))
                .count();
            (chunk.weights, f, core)
        },
        |(w, f, core)| {
            n += w.len();
            n_core += core;
            for (p, &wp) in w.iter().enumerate() {
                for k in 0..c {
                    eps[0].add(wp, f[p * c + k]);
                }
            }
            for (p, &wp) in w.iter().enumerate() {
                for k in 0..c {
                    eps[1 + k].add(wp, f[p * c + k]);
                }
            }
        },
    );
    let eps: Vec<f64> = eps.iter().map(EpsilonSum::epsilon).collect();
    let mut rows: Vec<Row<(Vec3, Vec3)>> = (0..=c)
        .map(|r| Row::new(eps[r], if r == 0 { n_core * c } else { n_core }))
        .collect();
    // Pass 2: the terms of every value, summed row by row in the set's order.
    for_each_chunk(
        chunks,
        |k| {
            let chunk = pairs.chunk(k, per, geo.as_ref());
            let (f, g) = (
                eval(reference, own_reference, &chunk),
                eval(candidate, own_candidate, &chunk),
            );
            let (set, w) = (chunk.pairs, chunk.weights);
            let terms: Vec<Term> = (0..set.len() * c)
                .map(|v| Term::new(f[v], g[v], set[v / c].0.z, eps[0], eps[1 + v % c]))
                .collect();
            (set, w, terms)
        },
        |(set, w, terms)| {
            for (p, (&pair, &wp)) in set.iter().zip(&w).enumerate() {
                let core = in_core(pair.0, pair.1);
                for k in 0..c {
                    let t = &terms[p * c + k];
                    rows[0].add(wp, pair, core, t, t.rel);
                    rows[1 + k].add(wp, pair, core, t, t.rel_own);
                }
            }
        },
    );
    let mut rows = rows.into_iter().map(|r| r.finish(|pair| pair));
    let combined = rows.next().unwrap_or_default();
    Ok(SetReport {
        set: name.to_string(),
        samples: n,
        seed,
        combined,
        per_channel: rows.collect(),
    })
}

/// Options of [`check`].
#[derive(Clone, Debug)]
pub struct CheckOptions {
    pub samples: usize,
    pub seed: u64,
    /// Also run `grazing`, `specular` (and `cells` when a grid is given).
    pub all_sets: bool,
}

impl Default for CheckOptions {
    fn default() -> Self {
        CheckOptions {
            samples: 65_536,
            seed: 1,
            all_sets: true,
        }
    }
}

/// A full check: every metric on `uniform`, and the worst of the other sets beside it.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct CheckReport {
    pub reference: String,
    pub candidate: String,
    pub uniform: SetReport,
    pub others: Vec<SetReport>,
    /// Per metric, the worst value over the non-uniform sets.
    pub worst_other: Option<Metrics>,
    /// max over 16 θi of |a_g(θi) − a_f(θi)| (directional albedo), when computed.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub albedo_err: Option<f64>,
    /// The θ limit in degrees the sets were restricted to (the smaller stored domain of the
    /// two sources), when one of them is a table stored up to θmax.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub theta_max_deg: Option<f64>,
}

/// Checks `candidate` against `reference`. `cells`: the candidate table's grid and validity,
/// for the `cells` set.
pub fn check(
    reference: &dyn Brdf,
    candidate: &dyn Brdf,
    cells: Option<(&Grid, &[bool])>,
    opts: &CheckOptions,
) -> Result<CheckReport> {
    // Only where both sources hold values: beyond a table's θmax there is nothing to compare
    // (its 0 there is no value), so errors there would be errors no one asked for.
    let theta_max_deg = match (reference.theta_max_deg(), candidate.theta_max_deg()) {
        (Some(a), Some(b)) => Some(a.min(b)),
        (a, b) => a.or(b),
    };
    let domain = |set: SampleSet| -> SampleSet {
        if theta_max_deg.is_none() {
            return set;
        }
        set.restricted(|wi, wo| reference.in_domain(wi, wo) && candidate.in_domain(wi, wo))
    };
    let uniform = check_set(
        reference,
        candidate,
        &domain(SampleSet::uniform(opts.samples, opts.seed)),
    )?;
    let mut others = Vec::new();
    if opts.all_sets {
        let n = (opts.samples / 4).max(1);
        others.push(check_set(
            reference,
            candidate,
            &domain(SampleSet::grazing(n, opts.seed)),
        )?);
        others.push(check_set(
            reference,
            candidate,
            &domain(SampleSet::specular(n, opts.seed)),
        )?);
        if let Some((grid, valid)) = cells {
            // Streamed: the cells are generated chunk by chunk as they are evaluated, never
            // held as a set (a 4 M-cell table would need 100 bytes per cell more).
            let keep = |wi: Vec3, wo: Vec3| {
                theta_max_deg.is_none()
                    || reference.in_domain(wi, wo) && candidate.in_domain(wi, wo)
            };
            others.push(check_pairs(
                reference,
                candidate,
                &Pairs::Cells {
                    grid,
                    valid,
                    keep: &keep,
                },
                "cells",
                None,
            )?);
        }
    }
    let worst_other = others
        .iter()
        .map(|r| r.combined.clone())
        .reduce(|a, b| worst(&a, &b));
    Ok(CheckReport {
        reference: reference.describe(),
        candidate: candidate.describe(),
        uniform,
        others,
        worst_other,
        albedo_err: opts.all_sets.then(|| albedo_error(reference, candidate)),
        theta_max_deg,
    })
}

/// max over the 16 incidence angles of `props::albedo_angles_deg` (at φi = 0) and over
/// channels of |a_g(θi) − a_f(θi)|, both albedos by the same quadrature (docs/props.md).
pub fn albedo_error(reference: &dyn Brdf, candidate: &dyn Brdf) -> f64 {
    crate::props::albedo_angles_deg()
        .par_iter()
        .map(|deg| {
            let t = deg.to_radians();
            let a = crate::props::directional_albedo(reference, t);
            let b = crate::props::directional_albedo(candidate, t);
            a.iter()
                .zip(&b)
                .map(|(x, y)| (x - y).abs())
                .fold(0.0, f64::max)
        })
        .collect::<Vec<f64>>()
        .into_iter()
        .fold(0.0, f64::max)
}

/// Per metric, the larger of two.
fn worst(a: &Metrics, b: &Metrics) -> Metrics {
    let pick = |x: f64, y: f64| x.max(y);
    Metrics {
        rmse: pick(a.rmse, b.rmse),
        rel_rmse: pick(a.rel_rmse, b.rel_rmse),
        max_abs: pick(a.max_abs, b.max_abs),
        max_abs_at: if a.max_abs >= b.max_abs {
            a.max_abs_at
        } else {
            b.max_abs_at
        },
        max_rel: pick(a.max_rel, b.max_rel),
        max_rel_at: if a.max_rel >= b.max_rel {
            a.max_rel_at
        } else {
            b.max_rel_at
        },
        log_rmse: pick(a.log_rmse, b.log_rmse),
        rel_rmse_core: pick(a.rel_rmse_core, b.rel_rmse_core),
        p99_rel_core: pick(a.p99_rel_core, b.p99_rel_core),
        nonfinite: a.nonfinite.max(b.nonfinite),
        negative: a.negative.max(b.negative),
        epsilon: pick(a.epsilon, b.epsilon),
    }
}

impl CheckReport {
    /// The value a `--max-NAME` bound is compared with: the `uniform` set's combined value
    /// (albedo_err from its own computation).
    pub fn bounded_value(&self, name: &str) -> Option<f64> {
        if name == "albedo_err" {
            return self.albedo_err;
        }
        self.uniform.combined.get(name)
    }

    /// An aligned human table: uniform metrics, the worst of the other sets, per channel.
    pub fn to_table(&self) -> String {
        use std::fmt::Write;
        let mut s = String::new();
        let _ = writeln!(s, "reference: {}", crate::text::sanitize(&self.reference));
        let _ = writeln!(s, "candidate: {}", crate::text::sanitize(&self.candidate));
        let u = &self.uniform;
        let _ = writeln!(
            s,
            "sample set: uniform, {} pairs, seed {}; ε = 1e-3·mean|f| = {:.3e}",
            u.samples,
            u.seed.unwrap_or(0),
            u.combined.epsilon
        );
        if let Some(t) = self.theta_max_deg {
            let _ = writeln!(
                s,
                "domain: θi, θo ≤ {t}° only (the stored domain of the table); pairs beyond it \
                 are not sampled"
            );
        }
        let mut header = format!("{:<14} {:>12}", "metric", "uniform");
        if self.worst_other.is_some() {
            let names: Vec<&str> = self.others.iter().map(|o| o.set.as_str()).collect();
            header.push_str(&format!(" {:>12}", "worst other"));
            let _ = writeln!(s, "other sets: {}", names.join(", "));
        }
        for ch in 0..u.per_channel.len() {
            header.push_str(&format!(" {:>12}", format!("uniform[{ch}]")));
        }
        let _ = writeln!(s, "{header}");
        for name in [
            "rmse",
            "rel_rmse",
            "max_abs",
            "max_rel",
            "log_rmse",
            "rel_rmse_core",
            "p99_rel_core",
            "nonfinite",
            "negative",
        ] {
            let mut line = format!("{:<14} {:>12}", name, fmt_num(u.combined.get(name)));
            if let Some(w) = &self.worst_other {
                line.push_str(&format!(" {:>12}", fmt_num(w.get(name))));
            }
            for m in &u.per_channel {
                line.push_str(&format!(" {:>12}", fmt_num(m.get(name))));
            }
            let _ = writeln!(s, "{line}");
        }
        if let Some(a) = self.albedo_err {
            let _ = writeln!(s, "{:<14} {:>12}", "albedo_err", fmt_num(Some(a)));
        }
        let _ = writeln!(
            s,
            "worst relative error {} at wi = {:?}, wo = {:?}",
            fmt_num(Some(u.combined.max_rel)),
            u.combined.max_rel_at.wi,
            u.combined.max_rel_at.wo
        );
        s
    }
}

/// Formats a metric for the human tables: integers plainly, others in 4-digit scientific.
pub fn fmt_num(v: Option<f64>) -> String {
    match v {
        None => "-".into(),
        Some(0.0) => "0".into(),
        Some(x) if x.fract() == 0.0 && x.abs() < 1e9 => format!("{x}"),
        // f64::MAX (a relative error beyond f64's range, `rel_error`) rounds to 1.7977e308,
        // which reads back as infinity: cut instead.
        Some(x) if x.abs() >= 1.79765e308 => {
            format!("{}1.7976e308", if x < 0.0 { "-" } else { "" })
        }
        Some(x) => format!("{x:.4e}"),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn log_error_is_the_spec_formula_for_non_negative_values_and_finite_below() {
        // ln(1 + g c) − ln(1 + f c) as metrics.md writes it, for f, g ≥ 0.
        for (f, g, c) in [
            (0.5f64, 0.7f64, 0.3f64),
            (1e4, 2e4, 0.01),
            (0.0, 3.0, 1.0),
            (2.0, 2.0, 0.5),
        ] {
            let want = (1.0 + g * c).ln() - (1.0 + f * c).ln();
            assert!((log_error(f, g, c) - want).abs() <= 1e-15 * want.abs().max(1.0));
        }
        // A negative source value beyond −1/c: finite, the odd extension, and antisymmetric.
        let e = log_error(-500.0, 0.0, 0.01);
        assert!((e - 6f64.ln()).abs() < 1e-15, "{e}");
        assert_eq!(log_error(0.0, -500.0, 0.01), -e);
    }
    use crate::brdf::Channels;

    /// A constant BRDF, optionally with a NaN region, for hand-computable cases.
    struct Const {
        v: f64,
        nan_above: Option<f64>,
        ch: Channels,
    }
    impl Brdf for Const {
        fn channels(&self) -> &Channels {
            &self.ch
        }
        fn eval(&self, wi: Vec3, _wo: Vec3, out: &mut [f64]) {
            let nan = self.nan_above.is_some_and(|z| wi.z > z);
            out.fill(if nan { f64::NAN } else { self.v });
        }
        fn is_isotropic(&self) -> bool {
            true
        }
        fn describe(&self) -> String {
            format!("const {}", self.v)
        }
    }
    fn konst(v: f64) -> Const {
        Const {
            v,
            nan_above: None,
            ch: Channels::default_for(3),
        }
    }

    #[test]
    fn constant_against_itself_is_all_zero() {
        let r = check(
            &konst(0.3),
            &konst(0.3),
            None,
            &CheckOptions {
                samples: 4096,
                ..Default::default()
            },
        )
        .unwrap();
        let m = &r.uniform.combined;
        for name in BOUNDABLE.iter().filter(|n| **n != "albedo_err") {
            assert_eq!(m.get(name), Some(0.0), "{name}");
        }
        assert_eq!(r.worst_other.unwrap().rmse, 0.0);
    }

    #[test]
    fn albedo_error_of_a_constant_offset_is_pi_times_it() {
        // a(θi) = ∫ f cos θo dωo = π f for a constant f: an offset of 0.05 gives 0.05 π.
        let e = albedo_error(&konst(0.3), &konst(0.35));
        assert!((e - 0.05 * PI).abs() < 1e-6, "{e}");
        assert_eq!(albedo_error(&konst(0.3), &konst(0.3)), 0.0);
    }

    #[test]
    fn known_offset_gives_rmse_equal_to_it() {
        let r = check(
            &konst(0.3),
            &konst(0.35),
            None,
            &CheckOptions {
                samples: 4096,
                ..Default::default()
            },
        )
        .unwrap();
        let m = &r.uniform.combined;
        assert!((m.rmse - 0.05).abs() < 1e-12, "{}", m.rmse);
        assert!((m.max_abs - 0.05).abs() < 1e-12);
        let eps = 1e-3 * 0.3;
        assert!((m.rel_rmse - 0.05 / (0.3 + eps)).abs() < 1e-12);
        assert!((m.p99_rel_core - 0.05 / (0.3 + eps)).abs() < 1e-12);
        // log_rmse = rms over samples of ln(1 + 0.35 c) − ln(1 + 0.3 c): bounded by c = 0 and 1.
        assert!(m.log_rmse > 0.0 && m.log_rmse < (1.35f64 / 1.3).ln());
    }

    #[test]
    fn nan_in_the_candidate_is_counted_not_propagated() {
        let mut cand = konst(0.3);
        cand.nan_above = Some(0.5);
        let r = check(
            &konst(0.3),
            &cand,
            None,
            &CheckOptions {
                samples: 4000,
                all_sets: false,
                ..Default::default()
            },
        )
        .unwrap();
        let m = &r.uniform.combined;
        assert!(m.nonfinite > 0);
        // wi.z uniform in [0, 1): about half the pairs, 3 channels each.
        assert!(
            (m.nonfinite as f64 / 12000.0 - 0.5).abs() < 0.05,
            "{}",
            m.nonfinite
        );
        assert_eq!(m.rmse, 0.0);
        assert!(serde_json::to_string(&r).unwrap().contains("\"nonfinite\""));
    }

    #[test]
    fn sample_sets_are_deterministic_and_in_range() {
        let a = SampleSet::specular(1000, 9);
        let b = SampleSet::specular(1000, 9);
        assert_eq!(a.pairs, b.pairs);
        for (wi, wo) in &a.pairs {
            let ang = wi.mirror().dot(*wo).clamp(-1.0, 1.0).acos().to_degrees();
            assert!(ang <= SPECULAR_CONE_DEG + 1e-9 && wo.z > 0.0);
        }
        for (wi, wo) in &SampleSet::grazing(999, 9).pairs {
            let in_band = |v: &Vec3| (75.0..=89.9 + 1e-9).contains(&v.theta().to_degrees());
            assert!(in_band(wi) || in_band(wo));
        }
    }

    /// The metrics as `metrics` computed them before the check streamed its sets (the whole
    /// set's values held, the core errors collected and selected): the reference the
    /// streamed rows must equal bit for bit.
    fn held_metrics(
        set: &SampleSet,
        f: &[f64],
        g: &[f64],
        c: usize,
        channel: Option<usize>,
    ) -> Metrics {
        let chans: Vec<usize> = match channel {
            Some(k) => vec![k],
            None => (0..c).collect(),
        };
        let weight = |p: usize| set.weights.as_ref().map_or(1.0, |w| w[p]);
        let (mut sf, mut sw) = (0.0, 0.0);
        for p in 0..set.pairs.len() {
            for &k in &chans {
                let v = f[p * c + k];
                if v.is_finite() {
                    sf += weight(p) * v.abs();
                    sw += weight(p);
                }
            }
        }
        let eps = if sw > 0.0 { 1e-3 * sf / sw } else { 0.0 };
        let eps = if eps > 0.0 { eps } else { f64::MIN_POSITIVE };
        let mut m = Metrics {
            epsilon: eps,
            ..Default::default()
        };
        let (mut se, mut sre, mut sle, mut sw) = (0.0, 0.0, 0.0, 0.0);
        let (mut sre_core, mut sw_core) = (0.0, 0.0);
        let mut core_rel = Vec::new();
        for (p, &(wi, wo)) in set.pairs.iter().enumerate() {
            let w = weight(p);
            for &k in &chans {
                let (fv, gv) = (f[p * c + k], g[p * c + k]);
                if !gv.is_finite() {
                    m.nonfinite += 1;
                    continue;
                }
                if gv < 0.0 {
                    m.negative += 1;
                }
                let abs = (gv - fv).abs();
                let rel = rel_error(fv, gv, eps);
                se += w * abs * abs;
                sre += w * rel * rel;
                let le = log_error(fv, gv, wi.z);
                sle += w * le * le;
                sw += w;
                let at = Pair {
                    wi: wi.to_array(),
                    wo: wo.to_array(),
                };
                if abs > m.max_abs {
                    m.max_abs = abs;
                    m.max_abs_at = at;
                }
                if rel > m.max_rel {
                    m.max_rel = rel;
                    m.max_rel_at = at;
                }
                if in_core(wi, wo) {
                    sre_core += w * rel * rel;
                    sw_core += w;
                    core_rel.push(rel);
                }
            }
        }
        if sw > 0.0 {
            m.rmse = (se / sw).sqrt();
            m.rel_rmse = (sre / sw).sqrt();
            m.log_rmse = (sle / sw).sqrt();
        }
        if sw_core > 0.0 {
            m.rel_rmse_core = (sre_core / sw_core).sqrt();
            m.p99_rel_core = percentile(&mut core_rel, 0.99);
        }
        m
    }

    /// Bit-for-bit equality (NaN included), field by field.
    fn same_bits(a: &Metrics, b: &Metrics) -> bool {
        let bits = |m: &Metrics| {
            [
                m.rmse,
                m.rel_rmse,
                m.max_abs,
                m.max_rel,
                m.log_rmse,
                m.rel_rmse_core,
                m.p99_rel_core,
                m.epsilon,
            ]
            .map(f64::to_bits)
        };
        bits(a) == bits(b)
            && a.max_abs_at == b.max_abs_at
            && a.max_rel_at == b.max_rel_at
            && (a.nonfinite, a.negative) == (b.nonfinite, b.negative)
    }

    #[test]
    fn the_streamed_cells_set_equals_the_held_one_bit_for_bit_on_any_thread_count() {
        use crate::grid::parse_grid_spec;
        use crate::model::Model;
        use crate::table::{Interp, InterpolatedTable};
        // A lossy candidate (f16 of a sharp lobe) against the model, on a θmax grid so that
        // the domain restriction is part of the stream, on a full one, and on one extended
        // below the horizon (valid cells there are no pairs of the set). The candidate is a
        // table on the set's grid, whose values the stream reads from its samples.
        let m = Model::parse("lambert:albedo=0.2+ggx:alpha=0.15,fresnel=au").unwrap();
        for spec in [
            "halfdiff3:18x20x24,theta-max=70",
            "spherical4:9x10x9x12",
            "halfdiff3:18x20x24,horizon=extend",
        ] {
            let g = parse_grid_spec(spec).unwrap();
            let t = crate::tabulate::tabulate(&m, &g, &Default::default()).unwrap();
            // Values the metrics must count: negative ones and large errors.
            let mut data = t.data().to_vec();
            let v = data.len();
            for k in [v / 3, v / 2, v / 2 + 7, 2 * v / 3] {
                data[k] = -0.25 * data[k] - 0.01;
            }
            let t = crate::table::Table::new(
                t.grid().clone(),
                t.channels().clone(),
                t.provenance().clone(),
                data,
                t.valid().to_vec(),
            )
            .unwrap();
            let cand = InterpolatedTable {
                table: t.clone(),
                interp: Interp::Linear,
            };
            let keep = |wi: Vec3, wo: Vec3| m.in_domain(wi, wo) && cand.in_domain(wi, wo);
            let held = SampleSet::cells(t.grid(), t.valid()).restricted(keep);
            let (f, gv) = evaluate_pairs(&m, &cand, &held).unwrap();
            let c = 3;
            assert!(held.pairs.len() > 1000, "{spec}: {}", held.pairs.len());
            for threads in [1, 2, 5] {
                let pool = rayon::ThreadPoolBuilder::new()
                    .num_threads(threads)
                    .build()
                    .unwrap();
                let streamed = pool
                    .install(|| {
                        check_pairs(
                            &m,
                            &cand,
                            &Pairs::Cells {
                                grid: t.grid(),
                                valid: t.valid(),
                                keep: &keep,
                            },
                            "cells",
                            None,
                        )
                    })
                    .unwrap();
                assert_eq!(streamed.samples, held.pairs.len());
                let want = held_metrics(&held, &f, &gv, c, None);
                assert!(want.negative > 0 && want.p99_rel_core > 0.0, "{want:?}");
                assert!(
                    same_bits(&streamed.combined, &want),
                    "{spec}, {threads} threads: {:?}\nvs {want:?}",
                    streamed.combined
                );
                for k in 0..c {
                    let want = held_metrics(&held, &f, &gv, c, Some(k));
                    assert!(same_bits(&streamed.per_channel[k], &want), "channel {k}");
                }
                // The held path (`metrics`) is the same computation.
                let want = held_metrics(&held, &f, &gv, c, None);
                assert!(same_bits(&metrics(&held, &f, &gv, c, None), &want));
            }
        }
    }

    #[test]
    fn the_largest_values_give_the_nearest_rank_percentile() {
        // Ties, NaN of both signs, ±0, infinities and negatives, for counts below and at the
        // bound the row was made for.
        let mut rng = SplitMix64::new(5);
        let mut pool: Vec<f64> = (0..20).map(|k| k as f64 * 0.25).collect();
        pool.extend([f64::NAN, -f64::NAN, 0.0, -0.0, f64::INFINITY, -1.0, 1e-310]);
        for n in [1usize, 2, 3, 99, 100, 101, 199, 200, 201, 1000, 4321] {
            for bound in [n, n + 1, 3 * n] {
                for q in [0.99, 0.5, 0.999, 0.01] {
                    let v: Vec<f64> = (0..n)
                        .map(|_| pool[(rng.next_f64() * pool.len() as f64) as usize % pool.len()])
                        .collect();
                    let mut top = Largest::new(Largest::needed(bound, q));
                    v.iter().for_each(|&x| top.push(x));
                    let mut all = v.clone();
                    let want = percentile(&mut all, q);
                    let got = top.nearest_rank(n, q);
                    assert_eq!(got.to_bits(), want.to_bits(), "n {n} bound {bound} q {q}");
                }
            }
        }
        for x in [
            0.0,
            -0.0,
            1.5,
            -2.0,
            f64::NAN,
            -f64::NAN,
            f64::INFINITY,
            f64::MIN_POSITIVE,
        ] {
            assert_eq!(from_order_key(order_key(x)).to_bits(), x.to_bits());
        }
        assert_eq!(Largest::new(0).nearest_rank(0, 0.99), 0.0);
    }
}
