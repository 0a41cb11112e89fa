//! Round-trip error: the sample sets and metrics of `spec/metrics.md`.
//!
//! Every report states the formula's inputs: the sample set, its size and seed, and ε.

use crate::brdf::Brdf;
use crate::geometry::Vec3;
use crate::grid::Grid;
use crate::math::{PI, SplitMix64};
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

impl SampleSet {
    /// `uniform`: wi and wo independent and uniform in solid angle.
    pub fn uniform(n: usize, seed: u64) -> SampleSet {
        let mut rng = SplitMix64::new(seed);
        let pairs = (0..n)
            .map(|_| {
                let wi = uniform_dir(&mut rng);
                (wi, uniform_dir(&mut rng))
            })
            .collect();
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
        for (f, &ok) in valid.iter().enumerate() {
            if !ok {
                continue;
            }
            grid.unflatten(f, &mut idx[..d]);
            pairs.push(grid.cell_dirs(&idx[..d]));
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
    Ok((evaluate_set(reference, set), evaluate_set(candidate, set)))
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
    let chans: Vec<usize> = match channel {
        Some(k) => vec![k],
        None => (0..c).collect(),
    };
    let weight = |p: usize| set.weights.as_ref().map_or(1.0, |w| w[p]);
    // ε = 1e-3 · mean |f| (weighted like the other means).
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
    // Avoid 0/0 when the reference is identically zero.
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
        let core = in_core(wi, wo);
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
            if core {
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

/// |g − f| / (|f| + ε): the relative error of `rel_rmse`, `max_rel` and `p99_rel_core`.
#[inline]
pub fn rel_error(f: f64, g: f64, eps: f64) -> f64 {
    (g - f).abs() / (f.abs() + eps)
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
    wi.z >= 0.1 && wo.z >= 0.1
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
    let (f, g) = evaluate_pairs(reference, candidate, set)?;
    let c = reference.channels().len();
    Ok(SetReport {
        set: set.name.clone(),
        samples: set.pairs.len(),
        seed: set.seed,
        combined: metrics(set, &f, &g, c, None),
        per_channel: (0..c).map(|k| metrics(set, &f, &g, c, Some(k))).collect(),
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

/// Bytes of the `cells` check set of `n` cells with `channels` values per source: two f64
/// direction vectors (48), a weight (8) and the two sources' f64 values.
pub fn cells_set_bytes(n: usize, channels: usize) -> u64 {
    (n as u64).saturating_mul(56 + 16 * channels as u64)
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
            // The set holds every valid cell: a pair, a weight and both sources' values.
            let n = valid.iter().filter(|&&v| v).count();
            crate::memory::require(
                &format!("the `cells` check set of {n} cells"),
                cells_set_bytes(n, candidate.channels().len()),
            )?;
            others.push(check_set(
                reference,
                candidate,
                &domain(SampleSet::cells(grid, valid)),
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
}
