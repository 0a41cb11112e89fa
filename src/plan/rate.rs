//! Rate control: the largest quantization step whose file meets an error budget against the
//! source, predicted from the coefficients and confirmed by decoding.
//!
//! The codec is the context-coded DCT of the log curve with KLT colour (`dct_context`,
//! docs/compression.md). Its parameters come from the data and the metric definitions, not
//! from a list of candidates:
//!
//! - **ε of the curve** y = ln(ε + x): the metrics' own ε, 1e-3 · mean |f| over uniform
//!   directions (`spec/metrics.md`), measured on the estimation set. With that ε an error δ in
//!   y is a relative error (ε + f)/(f + ε_m)·δ = δ of `p99_rel_core`/`rel_rmse` for every
//!   value, and values far below ε_m, which no metric sees, cost nothing. (A mean over grid
//!   cells would not do: the MERL grid's sqrt θh warp crowds cells into the specular peak, so
//!   the cell mean of a chrome-like material is orders of magnitude above the uniform one.)
//! - **The step**: the DCT is orthonormal, so the mean squared error a step s leaves in y is
//!   known before decoding, D(s) = Σ (c − Q_s(c))² / N (Parseval), and is computed in one pass
//!   over the coefficients. Each bounded metric is modelled as U(s)² = F² + k²·D(s), F the
//!   grid's own error against the source (the uncompressed table), k the propagation from y to
//!   the metric. k starts from the white-noise propagation of the metric's definition and is
//!   re-fitted from each measured candidate; the next step solves D(s) = min over metrics of
//!   (B² − F²)/k² by bisection on the exact D. Two or three decodes usually settle it.
//! - Every candidate is encoded, decoded by the reader's code and measured on the estimation
//!   set ([`super::estimate`]); only a candidate whose upper confidence values meet every bound
//!   is accepted, and the smallest accepted file wins.
//! - **A raised curve** ([`raised_curve`]): when the accepted file's percentile tail sits at
//!   the dark end of the core (a measured material whose values fall to 0, a cliff under a
//!   small ε), a second curve with ε raised as far as the data allow is rate-controlled too.

use super::budget::Budget;
use super::estimate::{ErrorEstimator, Estimate};
use crate::check::Metrics;
use crate::codec::coefcode::{self, ContextCoding, ContextModel, DEFAULT_DEADZONE};
use crate::codec::domain::Domain;
use crate::codec::transform::{Curve, Transform};
use crate::codec::{
    CodecRequest, CodecSpec, DecodeScratch, FILL_RELAXATION, Layout, dct, dct_coefficients_for,
    fill_of, filled_plane, filled_planes_f32, filled_planes_f32_in_place, refine_coefficients_f32,
    refine_coefficients_from_fill, transform_with_curve_held,
};
use crate::simd::dispatch;
use crate::table::Table;
use crate::{Error, Result};
use rayon::prelude::*;
use serde::Serialize;
use std::time::Instant;

/// How much time the planner may spend for a smaller file.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize)]
#[serde(rename_all = "lowercase")]
pub enum Effort {
    /// One codec variant (the curve the default effort uses), at most 3 decodes, no refined
    /// fill.
    Fast,
    /// One codec variant (the metric-matched ε, or the budget's own curve for a bright peak
    /// over dark values; dead zone 0.75), at most 5 decodes.
    #[default]
    Default,
    /// Several ε scales and dead zones and a refined fill, each rate-controlled; a larger
    /// estimation set. (A dead zone of 0.6 was among them: on 30 materials at the production
    /// budget, 17 generated and 13 measured, it never made the smallest file.)
    Max,
}

impl Effort {
    pub fn parse(s: &str) -> Result<Effort> {
        match s {
            "fast" => Ok(Effort::Fast),
            "default" => Ok(Effort::Default),
            "max" => Ok(Effort::Max),
            _ => Err(Error::input(format!(
                "--effort {s:?}: expected fast, default or max"
            ))),
        }
    }

    /// Decodes per variant.
    fn iterations(self) -> usize {
        match self {
            Effort::Fast => 3,
            Effort::Default => 5,
            Effort::Max => 8,
        }
    }

    /// The codec variants tried on a table of `cells` cells, as (ε scale relative to the
    /// metric's ε, dead zone, refined fill passes). The refined fill builds, decodes and
    /// fills again f64 planes of every cell (134 MB each on a 64⁴ grid; with it, `max` took
    /// 683 MB and 55 s for a 67 MB table): above the f32 planes' threshold it is left out.
    ///
    /// `curve_scale` is the budget's own curve ([`ErrorEstimator::curve_scale`]): when it is
    /// below [`SECOND_CURVE_BELOW`] of the metric's ε (on tables up to the f32 planes'
    /// threshold), the fast and default efforts run that curve instead of the metric's, and
    /// `max` runs both and keeps the smaller file. Both at the default effort cost a second
    /// transform and rate control beside the estimator's stencils: 3.0 s and 137 MB on a
    /// bright peak's MERL-grid table, over issue #19's 2 s and 128 MB; the budget's curve
    /// alone made files 0–17% larger where the metric's had won (13 NBRDF fits of MERL
    /// metals and the zoo's peaks; hematite at production 18.6 → 21.8 KB) and is the one
    /// that wins by far where it matters (a bare α 0.01 peak: 88 KB against 409 KB).
    ///
    /// `has_invalid`: whether the table has invalid cells to fill. Without them a refined
    /// fill is the plain one, and its variant another run of the same (`max` on an extended
    /// grid spent 2 s on it), so no variant refines.
    fn variants(self, cells: usize, has_invalid: bool, curve_scale: f64) -> Vec<Variant> {
        let mut all = self.all_variants();
        if cells > F32_PLANE_CELLS {
            all.retain(|v| v.refine == 0);
            for v in &mut all {
                v.refine_once = 0;
            }
        }
        if cells <= F32_PLANE_CELLS && curve_scale > 0.0 && curve_scale < SECOND_CURVE_BELOW {
            match self {
                Effort::Fast | Effort::Default => all[0].eps_scale = curve_scale,
                Effort::Max => all.push(Variant {
                    eps_scale: curve_scale,
                    deadzone: DEFAULT_DEADZONE,
                    refine: 0,
                    refine_once: DEFAULT_REFINE_ONCE,
                    raise: 1.0,
                }),
            }
        }
        if !has_invalid {
            for v in &mut all {
                v.refine = 0;
                v.refine_once = 0;
            }
        }
        all
    }

    fn all_variants(self) -> Vec<Variant> {
        let v = |eps_scale, deadzone, refine| Variant {
            eps_scale,
            deadzone,
            refine,
            refine_once: 0,
            raise: 1.0,
        };
        match self {
            Effort::Fast => vec![v(1.0, DEFAULT_DEADZONE, 0)],
            Effort::Default => vec![Variant {
                refine_once: DEFAULT_REFINE_ONCE,
                ..v(1.0, DEFAULT_DEADZONE, 0)
            }],
            Effort::Max => vec![
                v(1.0, DEFAULT_DEADZONE, 0),
                v(0.5, DEFAULT_DEADZONE, 0),
                v(2.0, DEFAULT_DEADZONE, 0),
                v(1.0, 1.0, 0),
                v(1.0, DEFAULT_DEADZONE, 4),
            ],
        }
    }
}

/// The budget's own curve ([`Effort::variants`]) is used when its ε is below this share of
/// the metric's ε: closer, the two curves make files within a few percent of each other
/// (the zoo's bodies, whose low ε is 0.8–0.95 of ε).
const SECOND_CURVE_BELOW: f64 = 0.67;

/// Passes of the refined fill the default effort makes once, at its first candidate's step
/// ([`Control::run`]; `Domain::FillRefined` with `at_step`). One pass took the production
/// file of `gold-metallic-paint.binary` from 28,292 to about 24 KB (a fill made at every
/// candidate's step: 24,391 B, but 0.5 s and 73 MB more). A larger file gets more passes
/// ([`refine_passes`]); `max` effort also tries four at every step.
const DEFAULT_REFINE_ONCE: u32 = 1;

/// Passes of the refined fill for an accepted file of `payload` bytes, at least `at_least`
/// (the variant's [`Variant::refine_once`]). A pass costs the same on every file of a grid
/// (an inverse and a forward DCT of each plane, made again at each of up to
/// [`REFINED_TRIES`] steps: ~0.25 s on the MERL grid), while what it saves grows with the
/// file: on 14 MERL-grid measured tables at the production budget, 2 passes (λ 1.5) and 4
/// (λ 1.8, [`MANY_PASS_RELAXATION`]) made the files a median 0.92 and 0.85 of one pass's
/// (0.82–0.99 and 0.67–0.94; black-phenolic 27.7 → 22.7 → 18.6 KB). Made from 8 KiB, 2
/// passes cost gold-metallic-paint 0.75 s (1.92 → 2.67 s, over issue #19's 2 s) for 5% of its
/// bytes; so only a file of [`MANY_PASSES_FROM`] or more gets more passes, 4 of them, where
/// the same time buys a quarter of the file (black-phenolic 2.6 → 3.6 s).
fn refine_passes(at_least: u32, payload: usize) -> u32 {
    let by_size = if payload >= MANY_PASSES_FROM { 4 } else { 1 };
    at_least.max(by_size)
}

/// Payload bytes (of the accepted file before its refined fill) from which the refined fill
/// makes 4 passes ([`refine_passes`]).
const MANY_PASSES_FROM: usize = 24 * 1024;

/// The relaxation of a refined fill of more than one pass. One pass is made with
/// [`FILL_RELAXATION`] (λ 1.75 gained nothing over 1.5 there); over several, a longer step
/// per pass keeps gaining: at 4 passes, λ 1.8 made the production files of 14 measured
/// MERL-grid tables a median 0.966 of λ 1.5's (0.941–1.005).
const MANY_PASS_RELAXATION: f32 = 1.8;

/// Refined files measured at most after the rate control has converged: at its step, then at
/// larger ones while the refined file leaves room under every bound
/// ([`Control::refined_final`]; each costs a refinement, an encode and a decode, ~0.15 s on
/// the MERL grid).
const REFINED_TRIES: usize = 3;
/// How much larger (a factor) the refined file at the accepted step may be and still be
/// measured, for the larger step it may leave room for ([`Control::refined_final`]).
const REFINED_SLACK: f64 = 1.05;

/// One codec variant of the rate control.
#[derive(Clone, Copy, Debug, PartialEq)]
struct Variant {
    eps_scale: f64,
    deadzone: f64,
    refine: u32,
    /// Passes of the refined fill made once, at the first candidate's step, and kept for the
    /// candidates after it (0: none).
    refine_once: u32,
    /// The factor a raised curve ([`raised_curve`]) multiplies the first curve's ε by (1: not
    /// raised).
    raise: f64,
}

impl Variant {
    fn describe(&self) -> String {
        format!(
            "dct context ε×{}{} deadzone={}{}",
            self.eps_scale,
            if self.raise != 1.0 {
                format!(" raised ×{:.3}", self.raise)
            } else {
                String::new()
            },
            self.deadzone,
            if self.refine > 0 {
                format!(" refine={}", self.refine)
            } else if self.refine_once > 0 {
                format!(" refined once={}", self.refine_once)
            } else {
                String::new()
            }
        )
    }
}

/// One decoded and measured candidate, for the report.
#[derive(Clone, Debug, Serialize)]
pub struct RateTrial {
    pub variant: String,
    pub step: f64,
    pub bytes: usize,
    /// Predicted mean squared error in the curve's space, D(step).
    pub predicted_mse: f64,
    pub estimate: Estimate,
    pub meets: bool,
}

/// The rate control's result.
#[derive(Clone, Debug)]
pub struct Encoded {
    pub spec: CodecSpec,
    pub payload: Vec<u8>,
    /// The chosen file's error against the source.
    pub estimate: Estimate,
    /// The uncompressed table's error against the source (the grid's own).
    pub floor: Estimate,
    pub trials: Vec<RateTrial>,
    /// (stage, seconds).
    pub timings: Vec<(String, f64)>,
}

/// What [`encode_within`] found.
#[derive(Clone, Debug)]
pub enum RateOutcome {
    Encoded(Box<Encoded>),
    /// The uncompressed table itself misses the budget: no codec can meet it on this grid.
    GridTooCoarse {
        floor: Box<Estimate>,
    },
}

/// Called with the name of each stage as it starts.
pub type Progress<'a> = &'a (dyn Fn(&str) + Sync);

/// Gives a lent table's samples back, bit for bit, when the lossless chain is chosen (a
/// re-read of the input file, a tabulation again): see [`encode_within_lending`].
pub type Again<'a> = &'a dyn Fn() -> Result<Vec<f32>>;

/// The smallest file of `table` whose error against the estimator's source meets `budget`
/// (upper confidence values, [`super::estimate`]). See the module doc.
pub fn encode_within(
    table: &Table,
    est: &ErrorEstimator,
    budget: &Budget,
    effort: Effort,
    progress: Progress,
) -> Result<RateOutcome> {
    encode(Access::Shared(table), None, est, budget, effort, progress)
}

/// [`encode_within`] with the table's samples lent (at the default and fast efforts, where
/// one transform serves every variant; `max` keeps them): once the coefficients are made
/// the samples are not needed until the end, so they are freed (tables of 1 or 3 channels,
/// whose candidates are decoded at the estimator's cells alone), or hold the decoded
/// candidates (other channel counts); a one-channel plane made in f32 is made in them. On
/// return the table holds what the chosen file decodes to: the decode of the lossy
/// candidate, or for the lossless chain the samples `again` gives (checked against a
/// fingerprint of the original ones). A table-sized array less at the peak: 50 MB of the
/// 52 MiB table of docs/robustness.md. On an error the table's samples are unspecified
/// (finite, 0 at invalid cells).
///
/// `prepared`, when given, holds the coefficients [`prepare_coefficients`] made from this
/// table before the estimator was built (so that its stencils were not held beside the
/// DCT's planes); otherwise they are made here.
pub fn encode_within_lending(
    table: &mut Table,
    again: Again,
    prepared: Option<Prepared>,
    est: &ErrorEstimator,
    budget: &Budget,
    effort: Effort,
    progress: Progress,
) -> Result<RateOutcome> {
    encode(
        Access::Lend(table, again),
        prepared,
        est,
        budget,
        effort,
        progress,
    )
}

/// The curve's transform and the DCT coefficients of one ε scale, made ahead of the
/// estimator ([`prepare_coefficients`]).
pub struct Prepared {
    scale: f64,
    epsilon: f64,
    floor: Option<Vec<f64>>,
    transform: Transform,
    coefs: Vec<Vec<f32>>,
    fills: Fills,
    max_coef: f64,
    seconds: f64,
}

/// The coefficients [`encode_within_lending`] starts from at `effort`, made from `table` and
/// the metrics' ε of the estimation set (`ReferenceSet::epsilon`, which the estimator built
/// from that set reports too) and the curve's floor (`ReferenceSet::curve_floor`); `None`
/// when several curves are tried (the budget's own curve, `ReferenceSet::curve_scale`) or
/// the fill is refined at every step.
pub fn prepare_coefficients(
    table: &Table,
    epsilon: f64,
    floor: Option<Vec<f64>>,
    curve_scale: f64,
    effort: Effort,
    progress: Progress,
) -> Option<Prepared> {
    let has_invalid = table.valid().iter().any(|&v| !v);
    let variants = effort.variants(table.grid().cells(), has_invalid, curve_scale);
    let scale = variants[0].eps_scale;
    if variants
        .iter()
        .any(|v| v.eps_scale != scale || v.refine > 0)
    {
        return None;
    }
    let t = Instant::now();
    let floor = floor_beside(floor, curve_scale);
    let eps = curve_eps(table.channels().len(), epsilon, scale, floor.as_deref());
    let (transform, coefs, fills, max_coef) =
        transform_and_coefficients(table, &eps, has_negative(table), true, progress);
    Some(Prepared {
        scale,
        epsilon,
        floor,
        transform,
        coefs,
        fills,
        max_coef,
        seconds: t.elapsed().as_secs_f64(),
    })
}

/// Whether a valid value is negative (a noisy measured fit: the curve keeps signs).
fn has_negative(table: &Table) -> bool {
    let c = table.channels().len();
    table
        .data()
        .chunks_exact(c)
        .zip(table.valid())
        .any(|(v, &ok)| ok && v.iter().any(|&x| x < 0.0))
}

/// The table as [`encode`] may use it.
enum Access<'t> {
    Shared(&'t Table),
    Lend(&'t mut Table, Again<'t>),
}

impl Access<'_> {
    fn table(&self) -> &Table {
        match self {
            Access::Shared(t) => t,
            Access::Lend(t, _) => t,
        }
    }
}

/// A fingerprint of a table's samples and validity (FNV-1a over the bits, in fixed chunks
/// combined in order): samples given back must be the ones lent.
fn fingerprint(table: &Table) -> u64 {
    const CHUNK: usize = 1 << 16;
    let parts: Vec<u64> = table
        .data()
        .par_chunks(CHUNK)
        .map(|ch| fnv1a(ch.iter().map(|x| x.to_bits())))
        .collect();
    let valid = fnv1a(table.valid().iter().map(|&v| v as u32));
    fnv1a(
        parts
            .iter()
            .chain(std::iter::once(&valid))
            .flat_map(|p| [*p as u32, (*p >> 32) as u32]),
    )
}

/// 64-bit FNV-1a over 32-bit words (generic, so that the loop over a table's samples is not
/// a dynamic call per word).
fn fnv1a(words: impl Iterator<Item = u32>) -> u64 {
    const PRIME: u64 = 0x0000_0100_0000_01b3;
    words.fold(0xcbf2_9ce4_8422_2325u64, |h, w| {
        (h ^ w as u64).wrapping_mul(PRIME)
    })
}

fn encode(
    mut access: Access,
    mut prepared: Option<Prepared>,
    est: &ErrorEstimator,
    budget: &Budget,
    effort: Effort,
    progress: Progress,
) -> Result<RateOutcome> {
    let mut timings = Vec::new();
    let t0 = Instant::now();
    progress("measuring the grid's own error");
    let floor = est.measure(access.table().data());
    timings.push(("grid error".to_string(), t0.elapsed().as_secs_f64()));
    if !accepts(budget, &floor) {
        return Ok(RateOutcome::GridTooCoarse {
            floor: Box::new(floor),
        });
    }
    let values = access.table().data().len();
    let mut trials = Vec::new();
    let mut best: Option<(CodecSpec, Vec<u8>, Estimate)> = None;
    // The decode buffer is allocated when the first candidate is decoded (after the forward
    // DCT, whose planes are the larger transient), or is the lent samples.
    let mut decoded: Vec<f32> = Vec::new();
    let has_negative = has_negative(access.table());
    let curve_floor = floor_beside(est.curve_floor(budget), est.curve_scale(budget));
    let channels = access.table().channels().len();
    let eps_of = |scale: f64| curve_eps(channels, est.epsilon(), scale, curve_floor.as_deref());
    // Variants whose curves the floor makes the same are one variant.
    let has_invalid = access.table().valid().iter().any(|&v| !v);
    let mut variants = effort.variants(
        access.table().grid().cells(),
        has_invalid,
        est.curve_scale(budget),
    );
    let mut seen: Vec<(Vec<f64>, f64, u32, u32)> = Vec::new();
    variants.retain(|v| {
        let key = (eps_of(v.eps_scale), v.deadzone, v.refine, v.refine_once);
        let new = !seen.contains(&key);
        seen.push(key);
        new
    });
    let mut by_scale: Vec<f64> = Vec::new();
    for v in &variants {
        if !by_scale.iter().any(|&s| eps_of(s) == eps_of(v.eps_scale)) {
            by_scale.push(v.eps_scale);
        }
    }
    // The samples are read once per ε scale and by a refined fill: lent only when neither
    // reads them again.
    let lend = matches!(access, Access::Lend(..))
        && by_scale.len() == 1
        && variants.iter().all(|v| v.refine == 0);
    let lent_print = lend.then(|| fingerprint(access.table()));
    // The curves run, each with its variants: the effort's, then at most one raised curve
    // ([`raised_curve`]) decided from what the last one made.
    let mut curves: Vec<CurveRun> = by_scale
        .iter()
        .map(|&scale| {
            let eps = eps_of(scale);
            let variants = variants
                .iter()
                .filter(|v| eps_of(v.eps_scale) == eps)
                .copied()
                .collect();
            CurveRun {
                scale: Some(scale),
                eps,
                variants,
                resume: None,
                start: None,
            }
        })
        .collect();
    // The effort's curves; the last of them may decide a raise.
    let initial = curves.len();
    // The curve a raise followed, its accepted file (not refined) and the raise (see below).
    let mut before_raise: Option<(CurveRun, Candidate, Raise)> = None;
    // The raised curve's smallest accepted file before its refined fill (payload bytes).
    let mut raised_accepted: Option<usize> = None;
    let mut next = 0;
    while next < curves.len() {
        let CurveRun {
            scale,
            eps,
            variants: curve_variants,
            resume,
            start,
        } = curves[next].clone();
        next += 1;
        if next > 1 {
            // The decode buffer is made again after this curve's transform, as for the first:
            // held through it, it sat beside the transform's planes (`compress --max-error`
            // of a MERL-grid table peaked 26 MB higher).
            decoded = Vec::new();
            crate::memory::release_free_memory();
        }
        if next > 1
            && lend
            && let Access::Lend(t, again) = &mut access
        {
            // The lent samples were freed or held the first curve's decodes: read them again.
            progress("reading the samples again for a second curve");
            let back = again()?;
            let same_size = back.len() == values;
            t.give_back_samples(back);
            if !same_size || Some(fingerprint(t)) != lent_print {
                return Err(Error::Failure(
                    "the table's samples read again differ from the ones encoded (the input \
                     changed while it was being compressed?); no file written"
                        .to_string(),
                ));
            }
        }
        let t = Instant::now();
        let made = prepared.take().filter(|p| {
            Some(p.scale) == scale && p.epsilon == est.epsilon() && p.floor == curve_floor
        });
        let seconds_before = made.as_ref().map_or(0.0, |p| p.seconds);
        let (transform, coefs, fills, max_coef) = match made {
            Some(p) => (p.transform, p.coefs, p.fills, p.max_coef),
            None => match &mut access {
                // Lent samples read once: the plane is made in their memory.
                Access::Lend(t, _) if lend && plane_in_samples(t) => {
                    let (transform, coefs, max_coef) =
                        transform_and_coefficients_in_samples(t, &eps, has_negative, progress);
                    (transform, coefs, None, max_coef)
                }
                // A later curve (raised, or the first made again) is made beside the
                // estimator's stencils, which the first was made before: its KLT reads the
                // cells twice rather than hold their values (`compress --max-error` of a
                // MERL-grid table peaked at 147 MB with them held, 121 MB before the raise).
                _ => transform_and_coefficients(
                    access.table(),
                    &eps,
                    has_negative,
                    next == 1,
                    progress,
                ),
            },
        };
        // Candidates of a large table of 1 or 3 channels are decoded at the estimator's cells
        // alone ([`CodecSpec::decode_cells`]): no decode buffer, and lent samples are freed
        // (the chosen file's decode is given back at the end).
        if decoded.is_empty() {
            let cells_only = decodes_at_cells(access.table());
            match (&mut access, lend) {
                (Access::Lend(t, _), true) => {
                    let samples = t.lend_samples();
                    if !cells_only {
                        decoded = samples;
                    }
                }
                _ if cells_only => {}
                _ => decoded = vec![0f32; values],
            }
        }
        timings.push((
            format!("transform + DCT ({})", describe_eps(&eps, est.epsilon())),
            seconds_before + t.elapsed().as_secs_f64(),
        ));
        for v in &curve_variants {
            let t = Instant::now();
            let table = access.table();
            let layout = Layout::of(table);
            let mut ctl = Control {
                table,
                est,
                budget,
                floor: &floor,
                layout: &layout,
                transform: &transform,
                coefs: &coefs,
                fills: fills.as_deref(),
                max_coef,
                variant: *v,
                decoded: &mut decoded,
                trials: &mut trials,
                progress,
                probe_raise: (next == initial && Some(v) == curve_variants.last())
                    .then_some(effort),
                raise: None,
                start,
                accepted_unrefined: None,
                refine_below: match (&before_raise, effort) {
                    (Some((_, first, _)), Effort::Fast | Effort::Default)
                        if next > initial && resume.is_none() =>
                    {
                        Some(first.1.len())
                    }
                    _ => None,
                },
            };
            let found = match &resume {
                // The curve before a raise again: its accepted file refined after all.
                Some(b) => ctl.refined_final(b.clone()).map(Some),
                None => ctl.run(effort.iterations()),
            };
            if next > initial && resume.is_none() {
                raised_accepted = ctl.accepted_unrefined;
            }
            if let (Some(raise), Ok(Some(b))) = (ctl.raise, &found) {
                before_raise = Some((
                    CurveRun {
                        scale,
                        eps: eps.clone(),
                        variants: vec![*v],
                        resume: None,
                        start: None,
                    },
                    b.clone(),
                    raise,
                ));
            }
            let found = match found {
                Ok(f) => f,
                Err(e) => {
                    if let (Access::Lend(t, _), true) = (&mut access, lend) {
                        t.give_back_samples(decoded);
                    }
                    return Err(e);
                }
            };
            let outcome = match &found {
                Some((_, payload, _)) => format!("payload {} bytes", payload.len()),
                None => "nothing met the budget".to_string(),
            };
            if let Some((spec, payload, e)) = found
                && best.as_ref().is_none_or(|b| payload.len() < b.1.len())
            {
                best = Some((spec, payload, e));
            }
            let stage = if resume.is_some() {
                "refined fill after the raised curve"
            } else {
                "rate control"
            };
            timings.push((
                format!("{stage} ({}): {outcome}", v.describe()),
                t.elapsed().as_secs_f64(),
            ));
        }
        if next == initial {
            if let Some((_, _, Raise { factor: k, step })) = before_raise {
                let first = *curve_variants.last().expect("a curve runs a variant");
                // The raised curve's file is refined once at its step whatever the effort's
                // last variant did (`max` runs its other curves unrefined): unrefined, its
                // rate control stopped at the first accepted step and brass at `--effort
                // max` made 21,787 B against the default's 19,322 B.
                let raised_variant = Variant {
                    raise: k,
                    refine: 0,
                    refine_once: DEFAULT_REFINE_ONCE,
                    ..first
                };
                curves.push(CurveRun {
                    scale: None,
                    eps: eps.iter().map(|e| e * k).collect(),
                    variants: vec![raised_variant],
                    resume: None,
                    start: Some(step),
                });
            }
        } else if next == curves.len()
            && let Some((run, accepted, _)) = before_raise.take()
            && raise_in_vain(
                effort,
                accepted.1.len(),
                raised_accepted,
                best.as_ref().map(|b| b.1.len()),
            )
        {
            // The raised curve may not have won: the first curve's file is refined after all
            // (its transform made again), and the smaller kept.
            curves.push(CurveRun {
                resume: Some(accepted),
                ..run
            });
        }
    }
    if let (Access::Lend(t, again), true) = (&mut access, lend) {
        match &best {
            // The chosen file's decode: the last candidate decoded may be another one.
            Some((spec, payload, _)) => {
                // Freed for the candidates' decodes at cells: made again now that the
                // coefficients are gone.
                decoded.resize(values, 0.0);
                let decodes = spec.decode_into_with(
                    payload,
                    &Layout::of(t),
                    &mut decoded,
                    &mut DecodeScratch::lean(),
                );
                t.give_back_samples(decoded);
                decodes?;
            }
            None => {
                drop(decoded);
                crate::memory::release_free_memory();
                progress("reading the samples again for the lossless chain");
                let (back, read) = match again() {
                    Ok(b) => (b, Ok(())),
                    Err(e) => (Vec::new(), Err(e)),
                };
                let same_size = back.len() == values;
                t.give_back_samples(back);
                read?;
                if !same_size || Some(fingerprint(t)) != lent_print {
                    return Err(Error::Failure(
                        "the table's samples read again differ from the ones encoded (the \
                         input changed while it was being compressed?); no file written"
                            .to_string(),
                    ));
                }
            }
        }
    }
    let table = access.table();
    let (spec, payload, estimate) = match best {
        Some(b) => b,
        None => {
            // Nothing lossy met the budget within the iterations: the lossless chain decodes
            // to the table itself, whose error (the floor) meets it.
            progress("lossless fallback");
            let spec = CodecRequest::Lossless {
                level: 19,
                predict: None,
            }
            .resolve(table)?;
            let payload = spec.encode(table)?;
            (spec, payload, floor.clone())
        }
    };
    Ok(RateOutcome::Encoded(Box::new(Encoded {
        spec,
        payload,
        estimate,
        floor,
        trials,
        timings,
    })))
}

/// One curve of the rate control: its ε per channel, the variants run on it, and (for the
/// curve a raise followed, run again) the accepted file to refine instead of a rate control.
#[derive(Clone)]
struct CurveRun {
    /// The ε scale of [`Variant::eps_scale`] (`None` for a raised curve).
    scale: Option<f64>,
    eps: Vec<f64>,
    variants: Vec<Variant>,
    resume: Option<Candidate>,
    /// The first candidate's step ([`Control::start`]).
    start: Option<f64>,
}

/// A raise a rate control decided ([`raised_curve`]): the factor of ε and the step its
/// curve accepted, where the raised curve starts.
#[derive(Clone, Copy)]
struct Raise {
    factor: f64,
    step: f64,
}

/// An accepted file: its spec, payload and error estimate.
type Candidate = (CodecSpec, Vec<u8>, Estimate);

/// At `--effort max`, the raised curve's file wins outright when it is below this share of
/// the first curve's accepted file before its refined fill; above, the first curve's file is
/// refined after all and the smaller kept. The refined fill takes a file to 0.72–1.0 of its
/// size (median 0.90) in the 174 packs of the NBRDF fits where no raise is tried (both
/// budgets): below 0.7 no refined fill of the first curve could have made a smaller file.
const RAISE_WON_BELOW: f64 = 0.7;

/// Whether the first curve's accepted file (`first` payload bytes, before its refined fill)
/// must be refined after all once the raised curve has run: the raise was tried in vain, or
/// may have been. `raised` is the raised curve's smallest accepted file before its own
/// refined fill, `best` the smallest file of every curve so far (the raised one's refined).
///
/// At the fast and default efforts the two curves' files are compared as they were accepted,
/// before either refined fill: both fills fill the same invalid cells of the same grid, at
/// steps that meet the same bounds, and take their files to alike shares (on the NBRDF fits
/// whose raise was tried, the two curves' shares were 0.74–0.94 and 0.83–0.94, and the rule
/// chose the smaller file in all 13 packs). The raised curve's refined fill is a measurement
/// of this material's: the first curve's is made only when the raised file was not the
/// smaller before it, where it costs the first curve's transform again and two or three
/// refined encodes and decodes (0.5–0.7 s on the MERL grid). When the raised file is the larger, its own refined fill is left
/// out ([`Control::refine_below`]), so a raise tried in vain costs the raised curve's
/// transform and rate control. `--effort max` refines both whenever the raised file could
/// lose ([`RAISE_WON_BELOW`]).
fn raise_in_vain(effort: Effort, first: usize, raised: Option<usize>, best: Option<usize>) -> bool {
    match effort {
        Effort::Max => best.is_some_and(|b| b as f64 > RAISE_WON_BELOW * first as f64),
        Effort::Fast | Effort::Default => raised.is_none_or(|r| r >= first),
    }
}

/// The growth of the percentile bound a raised curve may cost at most, for the same error in
/// the curve's space ([`ErrorEstimator::curve_raise_limit`]).
const RAISE_GROWTH: f64 = 1.25;

/// The least factor a raised curve multiplies ε by: closer to 1 the two curves make files
/// within a few percent of each other.
const RAISE_AT_LEAST: f64 = 2.8;

/// How concentrated at the dark end of the core the percentile bound's tail must be for a
/// raised curve to be tried ([`ErrorEstimator::dark_tail_share`]: 1 when the tail is spread
/// like the values, 50 when it is all among the darkest 2%).
const DARK_TAIL_AT_LEAST: f64 = 8.0;

/// The factor by which to raise the ε of the curve of the accepted file `spec` (`payload`)
/// for a second rate control, or `None`.
///
/// A measured material whose values fall to 0 somewhere in the core (the NBRDF fits clamp
/// at 0: brass, hematite, phenolics) has, under a curve of small ε, a cliff of several nats
/// where they do, and the percentile bound's tail gathers there: the file pays for the
/// cliff's detail with a small step everywhere. A larger ε flattens the cliff; the
/// cost is the relative precision of the values below the new ε, which the bound weighs
/// only beyond its allowance. Both are read from the data rather than assumed: the tail's
/// place from the accepted file's errors (at least [`DARK_TAIL_AT_LEAST`] times as many of
/// its pairs at the dark end as the values), the factor as the largest whose amplification
/// of the errors below the new ε grows the bound by at most [`RAISE_GROWTH`] (and at least
/// [`RAISE_AT_LEAST`]). The raised curve is rate-controlled like the first and the smaller
/// file kept. The first curve's refined fill is left out when a raise follows, and made
/// after all when the raised file does not win by more than it could ([`RAISE_WON_BELOW`]),
/// so a wrong guess costs time, not bytes.
///
/// Only at the default and max efforts, for a percentile bound, on grids whose rate
/// control holds f64 planes (a second transform of a 64⁴ table costs seconds), and for
/// codecs that decode at the estimator's cells (1 or 3 channels).
fn raised_curve(
    table: &Table,
    est: &ErrorEstimator,
    budget: &Budget,
    effort: Effort,
    spec: &CodecSpec,
    payload: &[u8],
    decoded: &mut [f32],
) -> Result<Option<f64>> {
    let allowance = budget.relative_allowance();
    let c = table.channels().len();
    if effort == Effort::Fast
        || allowance <= 0.0
        || table.grid().cells() > F32_PLANE_CELLS
        || !spec.decodes_cells(c)
    {
        return Ok(None);
    }
    let CodecSpec::DctContext { transform, .. } = spec else {
        return Ok(None);
    };
    let Some(eps) = transform.curve.eps() else {
        return Ok(None);
    };
    let k = est.curve_raise_limit(eps, allowance, RAISE_GROWTH);
    if k < RAISE_AT_LEAST {
        return Ok(None);
    }
    // Decoded into the rate control's decode buffer when it has one (a table-sized array
    // beside it was the peak of `compress --max-error`: 147 MB for a MERL-grid table), else
    // at the estimator's cells, as its candidates are.
    let share = if decoded.is_empty() {
        let cells = est.cells();
        let mut at_cells = vec![0f32; cells.len() * c];
        spec.decode_cells(payload, &Layout::of(table), cells, &mut at_cells)?;
        est.dark_tail_share(&at_cells, allowance)
    } else {
        crate::memory::release_free_memory();
        spec.decode_into_with(
            payload,
            &Layout::of(table),
            decoded,
            &mut DecodeScratch::lean(),
        )?;
        est.dark_tail_share_of_table(decoded, allowance)
    };
    Ok((share >= DARK_TAIL_AT_LEAST).then_some(k))
}

/// Above this many cells (a plane of 64 MiB in f64) the rate control's planes are made and
/// transformed in f32 (2²³: every MERL-sized grid and its refinements up to 180³ keep f64,
/// and their files their bytes).
const F32_PLANE_CELLS: usize = 1 << 23;

/// Each plane's values at the invalid cells before its DCT ([`fill_of`]), when kept.
type Fills = Option<Vec<Vec<f32>>>;

/// The fill is kept for grids of at most this many cells (the MERL grid has 1,458,000).
const FILL_KEPT_CELLS: usize = 1 << 21;

/// The curve's transform at `scale` × the metrics' ε `epsilon` and its DCT coefficients in
/// f32, with the largest |c| of the f64 ones (of the f32 ones for a plane over
/// [`F32_PLANE_CELLS`]), and for the planes made in f64 on a grid with invalid cells their
/// fill ([`Fills`], for the refined fill).
fn transform_and_coefficients(
    table: &Table,
    eps: &[f64],
    has_negative: bool,
    hold_samples: bool,
    progress: Progress,
) -> (Transform, Vec<Vec<f32>>, Fills, f64) {
    let transform = curve_transform(table, eps, has_negative, hold_samples, progress);
    progress("forward DCT");
    let c = table.channels().len();
    let dims = table.grid().shape();
    // The coefficients are kept in f32 for the rate control (half the memory: 17.5 MB
    // instead of 35 MB on the MERL grid): the quantizer widens each back to f64 exactly, so
    // a code differs from the f64 coefficient's only where the f32 rounding (a relative 6e-8)
    // crosses a rounding or dead-zone boundary. The largest magnitude, which sets the
    // bisection's range of steps, is taken from the f64 values. Each plane is made,
    // transformed in its own array and narrowed one at a time.
    // A plane over F32_PLANE_CELLS is made and transformed in f32 storage instead
    // ([`dct::forward_owned_f32`]): in f64 it alone would be twice a one-channel table.
    // Its planes are made together (each cell's curve and colour once) and transformed in
    // place: at the last plane the table and every plane are held, as the table and the
    // coefficients of the others and the last plane were before.
    let mut max_coef = 0.0f64;
    if table.grid().cells() > F32_PLANE_CELLS {
        let (coefs, max_coef) = forward_f32(filled_planes_f32(table, &transform), &dims);
        return (transform, coefs, None, max_coef);
    }
    // The fill of the invalid cells is kept for the refined fill (a pass then transforms
    // only its change; 1.4 MB a plane on the MERL grid), up to FILL_KEPT_CELLS: a larger
    // table's fill would raise the peak of a planner bounded by twice the table plus 64 MB
    // (`compress` of a 128×128×256 RGB table: 165 → 172 MiB, tests/hostile.rs).
    let valid = table.valid();
    let keep_fill = valid.len() <= FILL_KEPT_CELLS && valid.iter().any(|&v| !v);
    let mut fills = Vec::new();
    let coefs: Vec<Vec<f32>> = (0..c)
        .map(|k| {
            let plane = filled_plane(table, &transform, k);
            if keep_fill {
                fills.push(fill_of(&plane, valid));
            }
            let f = dct::forward_owned(plane, &dims);
            max_coef = f.iter().fold(max_coef, |m, c| m.max(c.abs()));
            f.iter().map(|&c| c as f32).collect()
        })
        .collect();
    (transform, coefs, keep_fill.then_some(fills), max_coef)
}

/// Whether the candidates of `table` are decoded at the estimator's cells alone: 1 or 3
/// channels (the chains [`CodecSpec::decodes_cells`] takes) and more than 2²³ values (32 MiB
/// of f32). A smaller table's whole decode (the MERL grid's, tiled) is faster than one at
/// its cells, and its decode buffer is no peak.
fn decodes_at_cells(table: &Table) -> bool {
    let c = table.channels().len();
    matches!(c, 1 | 3) && table.grid().cells() * c > 1 << 23
}

/// Whether [`transform_and_coefficients_in_samples`] serves `table`: planes made in f32
/// ([`F32_PLANE_CELLS`]).
fn plane_in_samples(table: &Table) -> bool {
    table.grid().cells() > F32_PLANE_CELLS
}

/// [`transform_and_coefficients`] of a table whose samples it may take: the planes are made
/// in the samples' own memory ([`filled_planes_f32_in_place`]) and each transformed in its
/// own, so the table and its planes are never held together (a 64⁴ table's 67 MB a
/// channel). The same bits; the table is left without samples (lent,
/// [`encode_within_lending`]).
fn transform_and_coefficients_in_samples(
    table: &mut Table,
    eps: &[f64],
    has_negative: bool,
    progress: Progress,
) -> (Transform, Vec<Vec<f32>>, f64) {
    debug_assert!(plane_in_samples(table));
    let transform = curve_transform(table, eps, has_negative, true, progress);
    progress("forward DCT");
    let dims = table.grid().shape();
    let samples = table.lend_samples();
    let (coefs, max_coef) = forward_f32(
        filled_planes_f32_in_place(table, &transform, samples),
        &dims,
    );
    (transform, coefs, max_coef)
}

/// The DCT of each f32 plane, in its own memory, and the largest |coefficient|.
fn forward_f32(planes: Vec<Vec<f32>>, dims: &[usize]) -> (Vec<Vec<f32>>, f64) {
    let mut max_coef = 0.0f64;
    let coefs = planes
        .into_iter()
        .map(|p| {
            let f = dct::forward_owned_f32(p, dims);
            max_coef = f.iter().fold(max_coef, |m, c| m.max(c.abs() as f64));
            f
        })
        .collect();
    (coefs, max_coef)
}

/// The curve's floor ([`ErrorEstimator::curve_floor`]) when the budget's own curve
/// (`curve_scale`, [`ErrorEstimator::curve_scale`]) is not used: a bright peak over dark
/// values runs a curve whose ε is below the metric's, to keep the relative precision of
/// exactly the dark values a floor would give up (with a floor over both curves, a bare
/// silver peak's production file went from 11.9 to 139 KB).
fn floor_beside(floor: Option<Vec<f64>>, curve_scale: f64) -> Option<Vec<f64>> {
    floor.filter(|_| !(curve_scale > 0.0 && curve_scale < SECOND_CURVE_BELOW))
}

/// The ε of each channel's curve: `scale` × the metrics' ε `epsilon`, or the channel's
/// floor ([`ErrorEstimator::curve_floor`]) when larger.
fn curve_eps(channels: usize, epsilon: f64, scale: f64, floor: Option<&[f64]>) -> Vec<f64> {
    (0..channels)
        .map(|k| {
            let at_floor = floor.and_then(|f| f.get(k)).copied().unwrap_or(0.0);
            (scale * epsilon).max(at_floor).max(f64::MIN_POSITIVE)
        })
        .collect()
}

/// `eps` for the stage timings: its ratios to the metrics' ε.
fn describe_eps(eps: &[f64], epsilon: f64) -> String {
    let ratios: Vec<String> = eps.iter().map(|e| format!("{:.3}", e / epsilon)).collect();
    let first = &ratios[0];
    if ratios.iter().all(|r| r == first) {
        format!("ε×{first}")
    } else {
        format!("ε×[{}]", ratios.join(", "))
    }
}

/// The curve (and colour) transform with curve ε `eps` per channel; the colour transform's
/// samples held while it is made when `hold_samples` ([`transform_with_curve_held`]).
fn curve_transform(
    table: &Table,
    eps: &[f64],
    has_negative: bool,
    hold_samples: bool,
    progress: Progress,
) -> Transform {
    progress("transforming (log curve, colour)");
    // A table with negative values (a noisy measured fit) keeps their sign: the metrics
    // compare them with the source's like any other value, and the log curve would decode
    // them as 0 (a relative error of 1 at each).
    let curve = if has_negative {
        Curve::SignedLog { eps: eps.to_vec() }
    } else {
        Curve::Log { eps: eps.to_vec() }
    };
    let transform = transform_with_curve_held(table, curve, true, None, hold_samples);
    // The colour transform's samples (every valid value in f64: 27 MB on the MERL grid) and
    // the estimator's construction are freed: handed back before the DCT's planes.
    crate::memory::release_free_memory();
    transform
}

/// The state of one variant's rate control.
struct Control<'a> {
    table: &'a Table,
    est: &'a ErrorEstimator,
    budget: &'a Budget,
    floor: &'a Estimate,
    layout: &'a Layout<'a>,
    transform: &'a Transform,
    /// The DCT coefficients in f32 (see [`encode_within`]) and the largest |c| of the f64
    /// ones.
    coefs: &'a [Vec<f32>],
    /// Each plane's values at the invalid cells before its DCT ([`fill_of`]), when kept.
    fills: Option<&'a [Vec<f32>]>,
    max_coef: f64,
    variant: Variant,
    decoded: &'a mut Vec<f32>,
    trials: &'a mut Vec<RateTrial>,
    progress: Progress<'a>,
    /// The effort when this run decides whether a raised curve follows ([`raised_curve`],
    /// from its accepted file, before its refined fill).
    probe_raise: Option<Effort>,
    /// The raise this run decided, if any.
    raise: Option<Raise>,
    /// The first candidate's step (a raised curve starts from the step the first curve
    /// accepted, where its files usually meet the budget too).
    start: Option<f64>,
    /// The payload length of the smallest file [`Control::run`] accepted before its refined
    /// fill.
    accepted_unrefined: Option<usize>,
    /// The refined fill is made only for an accepted file of fewer payload bytes than this (a
    /// raised curve at the default effort: larger, it lost to the first curve,
    /// [`raise_in_vain`]).
    refine_below: Option<usize>,
}

/// Aim a little inside each bound, so that the first prediction usually lands on an accepted
/// file (a miss costs a decode); acceptance itself is on the bound.
const AIM: f64 = 0.97;

impl Control<'_> {
    /// The rate control of one variant: the smallest accepted candidate, if any.
    fn run(&mut self, iterations: usize) -> Result<Option<(CodecSpec, Vec<u8>, Estimate)>> {
        let bounds = &self.budget.bounds;
        // Each bound's metric as U² = F² + k²·D^γ: k from white noise in y (a first guess),
        // γ = 1; after two decodes both are fitted to the last two (a secant in log-log).
        let mut fits: Vec<Fit> = bounds
            .iter()
            .map(|(name, _)| Fit {
                k2: initial_k(name).powi(2),
                gamma: 1.0,
                history: Vec::new(),
            })
            .collect();
        let mse_max = mse(self.coefs, f64::INFINITY, self.variant.deadzone);
        let max_coef = self.max_coef;
        // Steps below this would need more than 2^29 levels for the largest coefficient.
        let s_min = (max_coef / (1u64 << 29) as f64).max(1e-9);
        let s_max = (4.0 * max_coef).max(s_min * 2.0);
        let mut best: Option<(CodecSpec, Vec<u8>, Estimate)> = None;
        let mut ok_step: Option<f64> = None;
        let mut fail_step: Option<f64> = None;
        for _ in 0..iterations {
            // The largest D that every bound's model allows.
            let target = bounds
                .iter()
                .zip(&fits)
                .map(|((name, b), fit)| {
                    let f = self.floor.upper.get(name).unwrap_or(0.0);
                    let room = (AIM * b).powi(2) - f * f;
                    if room <= 0.0 {
                        0.0
                    } else {
                        (room / fit.k2).powf(1.0 / fit.gamma)
                    }
                })
                .fold(f64::INFINITY, f64::min);
            let mut s = if let Some(start) = self.start.take() {
                start.clamp(s_min, s_max)
            } else if target >= mse_max {
                s_max
            } else {
                step_for_mse(self.coefs, self.variant.deadzone, target, s_min, s_max)
            };
            if let Some(f) = fail_step
                && s >= f * 0.99
            {
                // The model has not moved below a step that failed: step down geometrically,
                // or halfway (in log) to the last accepted one.
                s = match ok_step {
                    Some(o) => (o * f).sqrt(),
                    None => f * 0.7,
                };
            }
            if s < s_min {
                // Below the finest step (2^29 levels for the largest coefficient), where the
                // f32 decode's own rounding is the error: no smaller step does better, and each
                // try of a nearly full box costs a plane of codes and seconds.
                break;
            }
            if let Some(o) = ok_step {
                if s <= o * 1.02 {
                    break;
                }
                if let Some(f) = fail_step
                    && f / o < 1.04
                {
                    break;
                }
            }
            let (d, spec, payload, e, meets) = self.trial(s)?;
            // Re-fit each metric's model with this decode.
            for ((name, _), fit) in bounds.iter().zip(fits.iter_mut()) {
                let u = e.upper.get(name).unwrap_or(0.0);
                let f = self.floor.upper.get(name).unwrap_or(0.0);
                fit.add(d, (u * u - f * f).max(0.0));
            }
            // Close enough: the binding bound is used to within 5%.
            let used = bounds
                .iter()
                .map(|(name, b)| e.upper.get(name).unwrap_or(0.0) / b.max(f64::MIN_POSITIVE))
                .fold(0.0, f64::max);
            let done = meets && used >= 0.95;
            if meets {
                ok_step = Some(ok_step.map_or(s, |o: f64| o.max(s)));
                if best.as_ref().is_none_or(|b| payload.len() < b.1.len()) {
                    best = Some((spec, payload, e));
                }
            } else {
                fail_step = Some(fail_step.map_or(s, |f: f64| f.min(s)));
            }
            if done {
                break;
            }
        }
        // Nothing accepted yet: keep halving below the smallest failing step before the
        // caller falls back to the lossless chain.
        let mut s = fail_step.unwrap_or(s_max);
        for _ in 0..10 {
            if best.is_some() {
                break;
            }
            s *= 0.5;
            if s < s_min {
                break;
            }
            let (_, spec, payload, e, meets) = self.trial(s)?;
            if meets {
                best = Some((spec, payload, e));
            }
        }
        if let (Some(effort), Some(b)) = (self.probe_raise, &best)
            && let Some(k) = raised_curve(
                self.table,
                self.est,
                self.budget,
                effort,
                &b.0,
                &b.1,
                self.decoded,
            )?
        {
            // The raised curve is rate-controlled next and its refined fill made there: where
            // it is tried it wins by far (docs/compression.md), so this curve's refinement
            // (two or three encodes and decodes) is left out.
            let step = match &b.0 {
                CodecSpec::DctContext { dct, .. } => dct.step[0],
                _ => 0.0,
            };
            self.raise = Some(Raise { factor: k, step });
            return Ok(best);
        }
        self.accepted_unrefined = best.as_ref().map(|b| b.1.len());
        match best {
            Some(b)
                if self.variant.refine_once > 0
                    && self.refine_below.is_none_or(|limit| b.1.len() < limit) =>
            {
                self.refined_final(b).map(Some)
            }
            b => Ok(b),
        }
    }

    /// The accepted candidate `best` again with its invalid cells' fill refined at its own
    /// step ([`refine_passes`] passes, `codec::planes::refine_coefficients_f32`, one
    /// plane at a time in f32), decoded and measured: kept when it is accepted and smaller.
    /// The refinement moves the fill towards what that step reconstructs, so fewer
    /// coefficients survive the dead zone, and the decode's error falls with them; when the
    /// refined file leaves room under every bound, one larger step (scaled by the room of the
    /// tightest bound, as the metrics grow about in proportion to the step there) is refined
    /// and measured too. Made at the converged step, it costs one or two refinements, encodes
    /// and decodes; at every candidate's step (`Variant::refine`) it cost 0.5 s and 73 MB
    /// more on the MERL grid.
    fn refined_final(
        &mut self,
        best: (CodecSpec, Vec<u8>, Estimate),
    ) -> Result<(CodecSpec, Vec<u8>, Estimate)> {
        let CodecSpec::DctContext { dct: stage, .. } = &best.0 else {
            return Ok(best);
        };
        let s = stage.step[0];
        if self.table.valid().iter().all(|&v| v) || stage.step.iter().any(|&x| x != s) {
            return Ok(best);
        }
        // The whole file: the header names the refined domain in ~20 more bytes.
        let header = |s: &CodecSpec| serde_json::to_string(s).map_or(0, |j| j.len());
        let size = |b: &(CodecSpec, Vec<u8>, Estimate)| b.1.len() + header(&b.0);
        let unrefined = best.clone();
        let passes = refine_passes(self.variant.refine_once, best.1.len());
        let mut best = best;
        let mut step = s;
        let mut relaxation = if passes > 1 {
            MANY_PASS_RELAXATION
        } else {
            FILL_RELAXATION
        };
        for k in 0..REFINED_TRIES {
            let (mut spec, mut payload, mut codes) =
                self.refined_at(&best.0, step, relaxation, passes);
            // At the accepted step the refined file may be a little larger and still pay:
            // its error is lower, so the larger step it leaves room for can win. Later
            // tries must be smaller than what they replace.
            let slack = if k == 0 { REFINED_SLACK } else { 1.0 };
            let too_large = |spec: &CodecSpec, payload: &[u8], best: &Candidate| {
                (payload.len() + header(spec)) as f64 >= slack * size(best) as f64
            };
            if k == 0 && too_large(&spec, &payload, &best) {
                // The relaxed pass overshot at this step (a MERL-grid table of a
                // Torrance–Sparrow lobe: 3,460 → 3,525 B, past the slack, so its file stayed
                // unrefined at 4,185 B against the plain pass's 3,208 B): the plain pass
                // instead, for this file's tries.
                relaxation = 1.0;
                (spec, payload, codes) = self.refined_at(&best.0, step, relaxation, passes);
            }
            if too_large(&spec, &payload, &best) {
                break;
            }
            let e = self.measure_boxes(&spec, &codes, step)?;
            drop(codes);
            let meets = accepts(self.budget, &e);
            self.trials.push(RateTrial {
                variant: format!("{} refined", self.variant.describe()),
                step,
                bytes: payload.len(),
                predicted_mse: mse(self.coefs, step, self.variant.deadzone),
                estimate: e.clone(),
                meets,
            });
            if !meets {
                break;
            }
            // The room the refined file leaves under its tightest bound.
            let room = self
                .budget
                .bounds
                .iter()
                .map(|(k, b)| AIM * b / e.upper.get(k).unwrap_or(0.0).max(f64::MIN_POSITIVE))
                .fold(f64::INFINITY, f64::min);
            best = (spec, payload, e);
            if room < 1.02 {
                break;
            }
            step *= room.min(1.25);
        }
        // The slack of the first try can leave a larger file than the unrefined one.
        Ok(if size(&best) <= size(&unrefined) {
            best
        } else {
            unrefined
        })
    }

    /// `spec` (a context-coded DCT) at step `s` with the fill refined at `s`, its payload and
    /// its quantized boxes.
    fn refined_at(
        &self,
        spec: &CodecSpec,
        s: f64,
        relaxation: f32,
        passes: u32,
    ) -> (CodecSpec, Vec<u8>, Vec<dct::Coefficients>) {
        let dims = self.table.grid().shape();
        let v = self.variant;
        let codes: Vec<_> = self
            .coefs
            .iter()
            .enumerate()
            .map(|(k, plane)| {
                let refined = match self.fills {
                    Some(fills) => refine_coefficients_from_fill(
                        plane.clone(),
                        &dims,
                        self.table.valid(),
                        &fills[k],
                        s,
                        v.deadzone,
                        passes,
                        relaxation,
                    ),
                    None => refine_coefficients_f32(
                        plane.clone(),
                        &dims,
                        self.table.valid(),
                        s,
                        v.deadzone,
                        passes,
                        relaxation,
                    ),
                };
                coefcode::quantize_deadzone(&refined, &dims, s, v.deadzone)
            })
            .collect();
        (self.progress)(&format!("refining the fill at step {s:.4e}"));
        let (model, payload) = coefcode::encode_smaller(&codes);
        let mut spec = spec.clone();
        if let CodecSpec::DctContext {
            domain,
            dct,
            coding,
            ..
        } = &mut spec
        {
            *domain = Domain::FillRefined { iterations: passes };
            dct.step.iter_mut().for_each(|x| *x = s);
            coding.model = model;
        }
        (spec, payload, codes)
    }

    /// [`Control::measure`] at step `s`, recorded in the trials with the step's predicted
    /// mean squared error; returns (predicted MSE, spec, payload, estimate, accepted).
    fn trial(&mut self, s: f64) -> Result<(f64, CodecSpec, Vec<u8>, Estimate, bool)> {
        let d = mse(self.coefs, s, self.variant.deadzone);
        let (spec, payload, e) = self.measure(s)?;
        let meets = accepts(self.budget, &e);
        self.trials.push(RateTrial {
            variant: self.variant.describe(),
            step: s,
            bytes: payload.len(),
            predicted_mse: d,
            estimate: e.clone(),
            meets,
        });
        Ok((d, spec, payload, e, meets))
    }

    /// Encodes at step `s`, decodes as a reader would and measures against the source.
    fn measure(&mut self, s: f64) -> Result<(CodecSpec, Vec<u8>, Estimate)> {
        let c = self.table.channels().len();
        let dims = self.table.grid().shape();
        let v = self.variant;
        (self.progress)(&format!("trying step {s:.4e} ({})", v.describe()));
        let codes = if v.refine > 0 {
            let coefs = dct_coefficients_for(
                self.table,
                self.transform,
                Domain::FillRefined {
                    iterations: v.refine,
                },
                &vec![s; c],
                &ContextCoding::new(v.deadzone),
            )?;
            coefcode::quantize_all(&coefs, &dims, &vec![s; c], v.deadzone)
        } else {
            coefcode::quantize_all(self.coefs, &dims, &vec![s; c], v.deadzone)
        };
        let spec = CodecSpec::DctContext {
            domain: if v.refine > 0 {
                Domain::FillRefined {
                    iterations: v.refine,
                }
            } else {
                Domain::FillInvalid
            },
            transform: self.transform.clone(),
            dct: dct::DctStage { step: vec![s; c] },
            coding: ContextCoding {
                deadzone: v.deadzone,
                // Set below (no value depends on it).
                model: ContextModel::CURRENT,
            },
            residual: None,
        };
        // The payload in whichever line-end model codes it smaller; the spec records it.
        // (The codes measured beside the encode, in `rayon::join`, were 0.1 s faster on
        // chrome-steel, but glibc's heaps of the worker threads then kept 15–25 MB more
        // resident: 147 MB peak RSS on color-changing-paint1. One heap for all threads,
        // `M_ARENA_MAX` 1, made other packs up to 15% slower.)
        let (model, payload) = coefcode::encode_smaller(&codes);
        let mut spec = spec;
        if let CodecSpec::DctContext { coding, .. } = &mut spec {
            coding.model = model;
        }
        let e = self.measure_boxes(&spec, &codes, s)?;
        Ok((spec, payload, e))
    }

    /// The candidate of quantized boxes `codes` (of `spec`, at step `s`) decoded as a reader
    /// decodes its payload, at the estimator's cells or into the decode buffer, and measured
    /// against the source. The boxes are what a reader's range decoder gives back from the
    /// payload, so the payload itself is not decoded: that serial decode was ~0.2 s of the
    /// chrome-steel fit's 2.1 s production pack (docs/benchmarks.md). The written file is
    /// still read back from its bytes and checked after the choice.
    fn measure_boxes(
        &mut self,
        spec: &CodecSpec,
        codes: &[dct::Coefficients],
        s: f64,
    ) -> Result<Estimate> {
        let c = self.table.channels().len();
        let nonfinite = || {
            Error::Failure(format!(
                "rate control: step {s:e} decoded to a non-finite value"
            ))
        };
        if decodes_at_cells(self.table) && spec.decodes_cells(c) {
            let cells = self.est.cells();
            let mut at_cells = vec![0f32; cells.len() * c];
            crate::memory::release_free_memory();
            spec.decode_cells_of(codes, self.layout, cells, &mut at_cells)?;
            if at_cells.iter().any(|v| !v.is_finite()) {
                return Err(nonfinite());
            }
            return Ok(self.est.measure_cells(&at_cells));
        }
        if self.decoded.is_empty() {
            self.decoded.resize(self.table.grid().cells() * c, 0.0);
        }
        // A scratch of its own, freed after the decode: kept across candidates, its 16 MB
        // (MERL grid) would sit beside the next candidate's quantized codes and the
        // measurement's arrays.
        let mut scratch = DecodeScratch::lean();
        // The decode is the rate control's peak (the table, the coefficients, the decode
        // buffer and the decoder's scratch): what earlier stages freed (the DCT's planes, the
        // transform's samples, the last candidate's measurement) must not stay resident
        // beside it.
        crate::memory::release_free_memory();
        spec.decode_of(codes, self.layout, self.decoded, &mut scratch)?;
        drop(scratch);
        if self.decoded.iter().any(|v| !v.is_finite()) {
            return Err(nonfinite());
        }
        Ok(self.est.measure(self.decoded))
    }
}

/// The acceptance rule: every bound on the upper values and, when the estimator has the
/// user's check set, on its metrics too (so that the report's check agrees with the budget).
pub fn accepts(budget: &Budget, e: &Estimate) -> bool {
    budget.met_by(&e.upper) && e.check.as_ref().is_none_or(|c| budget.met_by(c))
}

/// One metric's model U² − F² = k²·D^γ and the decodes it was fitted to.
struct Fit {
    k2: f64,
    gamma: f64,
    /// (D, U² − F²) of each decode.
    history: Vec<(f64, f64)>,
}

impl Fit {
    fn add(&mut self, d: f64, excess2: f64) {
        if !(d > 0.0 && excess2 > 0.0 && d.is_finite() && excess2.is_finite()) {
            return;
        }
        self.history.push((d, excess2));
        let n = self.history.len();
        if n >= 2 {
            let (d1, e1) = self.history[n - 2];
            let (d2, e2) = self.history[n - 1];
            let span = (d2 / d1).ln();
            if span.abs() > 1e-3 {
                self.gamma = ((e2 / e1).ln() / span).clamp(0.3, 1.5);
            }
        }
        self.k2 = excess2 / d.powf(self.gamma);
    }
}

/// A first guess of how an RMS error σ in the curve's space shows in a metric: about σ for
/// the relative metrics (the curve's ε is theirs), 2.6σ for a 99th percentile of a normal
/// spread, less for `log_rmse` (its cos θi·f/(1 + cos θi·f) weight is below 1), more for
/// maxima. Only the first step depends on it.
fn initial_k(metric: &str) -> f64 {
    match metric {
        "p99_rel_core" => 2.6,
        "max_rel" | "max_abs" => 10.0,
        "log_rmse" => 0.1,
        _ => 1.0,
    }
}

/// D(s): the mean squared error the dead-zone quantizer of step `s` leaves in the
/// coefficients, which (orthonormal DCT) is that of the curve-space planes over all cells.
/// Deterministic: fixed chunks, each summed in [`LANES`] fixed lanes, the chunks in order.
fn mse(coefs: &[Vec<f32>], s: f64, deadzone: f64) -> f64 {
    const CHUNK: usize = 1 << 15;
    let threshold = deadzone.max(0.5) * s;
    let mut total = 0.0;
    let mut n = 0usize;
    for plane in coefs {
        let parts: Vec<f64> = plane
            .par_chunks(CHUNK)
            .map(|ch| quantization_error(ch, s, threshold))
            .collect();
        total += parts.iter().sum::<f64>();
        n += plane.len();
    }
    total / n.max(1) as f64
}

/// Independent sums per chunk in [`quantization_error`]: the bisection of [`step_for_mse`]
/// evaluates D over every coefficient a dozen times per rate-control step, and one serial
/// sum was a fifth of a 64⁴ RGB `pack`; lanes let the divisions and roundings run as
/// vectors (the same lanes, so the same bits, on every CPU).
const LANES: usize = 8;

dispatch!(fn quantization_error / quantization_error_avx2 => quantization_error_lanes(ch: &[f32], s: f64, threshold: f64) -> f64);

/// Σ e² over `ch`, e = c below `threshold` (the dead zone) and c − round(c/s)·s above it (or
/// every c when `s` is infinite); value j goes to lane j mod [`LANES`], the lanes summed
/// pairwise.
#[inline(always)]
fn quantization_error_lanes(ch: &[f32], s: f64, threshold: f64) -> f64 {
    let finite = s.is_finite();
    let error = |c: f32| {
        let c = c as f64;
        if c.abs() < threshold || !finite {
            c
        } else {
            c - (c / s).round() * s
        }
    };
    // A block's eight values in separate passes with the choice made last (no branch), so
    // that the division and the rounding run as vectors: with a branch they were scalar, a
    // tenth of a `pack`'s time in the bisection's sums. The value chosen is the same as
    // `error`'s, bit for bit.
    let keep = if finite { threshold } else { f64::INFINITY };
    let s_or_1 = if finite { s } else { 1.0 };
    let mut acc = [0.0f64; LANES];
    let body = ch.len() - ch.len() % LANES;
    for blk in ch[..body].chunks_exact(LANES) {
        let mut x = [0.0f64; LANES];
        for (x, &c) in x.iter_mut().zip(blk) {
            *x = c as f64;
        }
        let mut e = [0.0f64; LANES];
        for (e, &x) in e.iter_mut().zip(&x) {
            *e = x - (x / s_or_1).round() * s_or_1;
        }
        for ((a, &x), &e) in acc.iter_mut().zip(&x).zip(&e) {
            let v = if x.abs() < keep { x } else { e };
            *a += v * v;
        }
    }
    for (a, &c) in acc.iter_mut().zip(&ch[body..]) {
        let e = error(c);
        *a += e * e;
    }
    ((acc[0] + acc[1]) + (acc[2] + acc[3])) + ((acc[4] + acc[5]) + (acc[6] + acc[7]))
}

/// The coefficients of [`mse`] split for the bisection of [`step_for_mse`], which evaluates
/// D a dozen times per rate-control step: a coefficient below a step's dead zone contributes
/// its own square whatever the step, so the small ones (all but about
/// 1/[`LARGE_SHARE`] of them) are summed once and only the large ones are quantized at each
/// step. Steps whose dead zone starts below the small ones' bound are measured in full.
struct LargeCoefficients<'a> {
    coefs: &'a [Vec<f32>],
    /// Every coefficient of magnitude below this is one of the small ones.
    small_below: f64,
    /// Σ c² of the small ones.
    small_sq: f64,
    /// The others, in plane and coefficient order.
    large: Vec<f32>,
    count: usize,
}

/// About one coefficient in this many is kept as a large one.
const LARGE_SHARE: usize = 16;

impl<'a> LargeCoefficients<'a> {
    fn of(coefs: &'a [Vec<f32>]) -> LargeCoefficients<'a> {
        // The bound is a power of two, from a histogram of the magnitudes' binary exponents:
        // the smallest one above which at most 1/LARGE_SHARE of the coefficients lie.
        let exponent = |c: f32| ((c.to_bits() >> 23) & 0xff) as usize;
        let mut counts = [0usize; 256];
        let count: usize = coefs.iter().map(Vec::len).sum();
        for c in coefs.iter().flatten() {
            counts[exponent(*c)] += 1;
        }
        let mut cut = 256;
        let mut above = 0;
        while cut > 1 && above + counts[cut - 1] <= count / LARGE_SHARE {
            above += counts[cut - 1];
            cut -= 1;
        }
        // Exponent `cut` and above are large (255: infinities and NaNs, which a finite
        // table's coefficients never are, would be large too).
        let small_below = f32::from_bits((cut.min(255) as u32) << 23) as f64;
        let mut small_sq = 0.0;
        let mut large = Vec::with_capacity(above);
        for &c in coefs.iter().flatten() {
            if exponent(c) >= cut {
                large.push(c);
            } else {
                small_sq += c as f64 * c as f64;
            }
        }
        LargeCoefficients {
            coefs,
            small_below,
            small_sq,
            large,
            count,
        }
    }

    /// [`mse`] at step `s`: the same value up to the order of the sum.
    fn mse(&self, s: f64, deadzone: f64) -> f64 {
        const CHUNK: usize = 1 << 15;
        let threshold = deadzone.max(0.5) * s;
        if threshold.is_nan() || threshold < self.small_below {
            return mse(self.coefs, s, deadzone);
        }
        let parts: Vec<f64> = self
            .large
            .par_chunks(CHUNK)
            .map(|ch| quantization_error(ch, s, threshold))
            .collect();
        (self.small_sq + parts.iter().sum::<f64>()) / self.count.max(1) as f64
    }
}

/// An upper bound of D(s) that needs no coefficient: each one's error is at most the dead
/// zone's threshold (inside it) or half a step (outside), and the threshold is at least that.
fn mse_bound(s: f64, deadzone: f64) -> f64 {
    let threshold = deadzone.max(0.5) * s;
    threshold * threshold
}

/// The largest step in [lo, hi] with D(step) ≤ `target` (bisection in log step; D grows with
/// the step up to quantization's ripples, which 30 halvings resolve well below 1%).
fn step_for_mse(coefs: &[Vec<f32>], deadzone: f64, target: f64, lo: f64, hi: f64) -> f64 {
    // Made for this bisection alone (two passes over the coefficients against its dozen),
    // so that the large ones are not held beside the candidates' decodes, the rate
    // control's peak.
    let coefs = LargeCoefficients::of(coefs);
    let (mut lo, mut hi) = (lo.ln(), hi.ln());
    let within = |s: f64| mse_bound(s, deadzone) <= target || coefs.mse(s, deadzone) <= target;
    if !within(lo.exp()) {
        return lo.exp();
    }
    for _ in 0..30 {
        let mid = 0.5 * (lo + hi);
        if within(mid.exp()) {
            lo = mid;
        } else {
            hi = mid;
        }
        if hi - lo < 1e-3 {
            break;
        }
    }
    lo.exp()
}

/// The metric values of `m` named by `budget`, as `name value` pairs.
pub fn bounded_values(budget: &Budget, m: &Metrics) -> Vec<(String, f64)> {
    budget
        .bounds
        .iter()
        .map(|(k, _)| (k.clone(), m.get(k).unwrap_or(f64::NAN)))
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::grid::parse_grid_spec;
    use crate::model::Model;
    use crate::plan::estimate::ReferenceSet;
    use crate::tabulate::tabulate;

    /// The lanes of D(s) give one sum on every CPU (the AVX2 copy against the portable one)
    /// and the serial sum's value; the dead zone and an infinite step as defined.
    #[test]
    fn the_bisections_error_of_the_large_coefficients_is_the_whole_one() {
        // Heavy-tailed coefficients over many octaves in two planes: D(s) from the small
        // ones' sum and the large ones is D(s) over all of them to the order of the sums, at
        // steps whose dead zone lies above the small ones' bound and (measured in full)
        // below it; the bound needing no coefficient is never below D.
        let mut rng = crate::math::SplitMix64::new(5);
        let planes: Vec<Vec<f32>> = (0..2)
            .map(|_| {
                (0..50_001)
                    .map(|_| {
                        let m = (rng.next_f64() * 30.0 - 20.0).exp2();
                        (if rng.next_f64() < 0.5 { -m } else { m }) as f32
                    })
                    .collect()
            })
            .collect();
        let large = LargeCoefficients::of(&planes);
        let count = 2 * 50_001;
        assert!(large.large.len() <= count / LARGE_SHARE && large.large.len() > count / 64);
        let mut below = 0;
        for k in -24..12 {
            let s = (k as f64).exp2() * 1.3;
            let whole = mse(&planes, s, 0.75);
            let split = large.mse(s, 0.75);
            below += (0.75 * s < large.small_below) as usize;
            assert!(
                (split - whole).abs() <= 1e-12 * whole,
                "step {s}: {split} {whole}"
            );
            assert!(mse_bound(s, 0.75) >= whole, "step {s}");
        }
        assert!(below > 3, "steps measured in full: {below}");
        let inf = large.mse(f64::INFINITY, 0.75);
        assert!((inf - mse(&planes, f64::INFINITY, 0.75)).abs() <= 1e-12 * inf);
    }

    #[test]
    fn the_quantization_error_in_lanes_is_the_serial_sum() {
        let mut rng = crate::math::SplitMix64::new(3);
        let ch: Vec<f32> = (0..10_007)
            .map(|_| ((rng.next_f64() - 0.5) * 200.0).powi(3) as f32)
            .collect();
        for (s, t) in [(0.37, 0.3), (5.0, 3.75), (f64::INFINITY, f64::INFINITY)] {
            let serial: f64 = ch
                .iter()
                .map(|&c| {
                    let c = c as f64;
                    let e = if c.abs() < t || !s.is_finite() {
                        c
                    } else {
                        c - (c / s).round() * s
                    };
                    e * e
                })
                .sum();
            let lanes = quantization_error(&ch, s, t);
            assert_eq!(
                lanes.to_bits(),
                quantization_error_lanes(&ch, s, t).to_bits()
            );
            assert!((lanes - serial).abs() <= 1e-12 * serial, "{lanes} {serial}");
        }
        // Below the dead zone a coefficient is its own error; above it, at most s/2.
        assert_eq!(quantization_error(&[0.25, -0.5], 1.0, 0.75), 0.3125);
        assert!(quantization_error(&[10.4, -7.6], 1.0, 0.75) <= 2.0 * 0.25);
    }

    #[test]
    fn a_plane_made_alone_has_the_bits_of_all_planes_at_once() {
        // The rate control and `dct_coefficients` make one component plane at a time; the
        // colour transform mixes the channels and the fill reads the validity mask, so the
        // plane made alone must still be the same numbers.
        let m = Model::parse("lambert:albedo=0.2/0.4/0.05+ggx:alpha=0.1,fresnel=cu").unwrap();
        let g = parse_grid_spec("halfdiff3:12x10x16").unwrap();
        let t = tabulate(&m, &g, &Default::default()).unwrap();
        assert!(t.valid().iter().any(|v| !v), "the grid has cells to fill");
        let tr =
            crate::codec::transform_with_curve(&t, Curve::Log { eps: vec![1e-3; 3] }, true, None);
        assert!(
            tr.colour.is_some(),
            "the colour transform mixes the channels"
        );
        let all = crate::codec::filled_planes(&t, &tr);
        let coefs = crate::codec::dct_coefficients(&t, &tr).unwrap();
        for (k, p) in all.iter().enumerate() {
            let alone = filled_plane(&t, &tr, k);
            assert!(
                p.iter()
                    .zip(&alone)
                    .all(|(a, b)| a.to_bits() == b.to_bits())
            );
            let f = dct::forward(p, &g.shape());
            assert!(
                f.iter()
                    .zip(&coefs[k])
                    .all(|(a, b)| a.to_bits() == b.to_bits())
            );
        }
    }

    #[test]
    fn the_predicted_mse_is_the_decoded_mse() {
        // Parseval: D(s) from the coefficients equals the mean squared error of the decoded
        // planes in the curve's space over all cells (the fill included).
        let m = Model::parse("ggx:alpha=0.25,fresnel=au").unwrap();
        let g = parse_grid_spec("halfdiff3:12x10x16").unwrap();
        let t = tabulate(&m, &g, &Default::default()).unwrap();
        let tr =
            crate::codec::transform_with_curve(&t, Curve::Log { eps: vec![1e-3; 3] }, true, None);
        let dims = g.shape();
        let planes = crate::codec::filled_planes(&t, &tr);
        let coefs: Vec<Vec<f32>> = planes
            .iter()
            .map(|p| dct::forward(p, &dims).iter().map(|&c| c as f32).collect())
            .collect();
        for s in [0.01, 0.1, 0.7] {
            let d = mse(&coefs, s, 0.75);
            let mut direct = 0.0;
            for (p, c) in planes.iter().zip(&coefs) {
                let q = coefcode::quantize_deadzone(c, &dims, s, 0.75);
                let back = dct::inverse(&q, &dims, s);
                direct += p
                    .iter()
                    .zip(&back)
                    .map(|(a, b)| (a - *b as f64).powi(2))
                    .sum::<f64>();
            }
            direct /= (planes.len() * planes[0].len()) as f64;
            assert!(
                (d - direct).abs() <= 1e-3 * direct + 1e-12,
                "step {s}: predicted {d}, decoded {direct}"
            );
        }
    }

    #[test]
    fn a_table_with_negative_values_keeps_them_within_the_budget() {
        // A measured fit to noisy data: a diffuse + glossy table with values shifted so that
        // the dark ones go below 0 (cc_ibiza_sunset_rgb.bsdf holds 19% negative values). The
        // source is the table itself, so the budget is the codec's alone.
        let m = Model::parse("lambert:albedo=0.3+ggx:alpha=0.2,fresnel=au").unwrap();
        let g = parse_grid_spec("halfdiff3:24x24x32,warp=sqrt/linear/linear").unwrap();
        let t = tabulate(&m, &g, &Default::default()).unwrap();
        let shift = 0.12f32;
        let data: Vec<f32> = t
            .data()
            .iter()
            .enumerate()
            .map(|(i, &v)| if t.valid()[i / 3] { v - shift } else { 0.0 })
            .collect();
        let t = Table::new(
            g,
            t.channels().clone(),
            t.provenance().clone(),
            data,
            t.valid().to_vec(),
        )
        .unwrap();
        let negative = t.data().iter().filter(|&&v| v < 0.0).count();
        assert!(negative * 20 > t.data().len(), "{negative} negative values");
        let source = crate::table::InterpolatedTable {
            table: t.clone(),
            interp: crate::table::Interp::Linear,
        };
        let reference = ReferenceSet::new(&source, 1 << 15);
        let est = ErrorEstimator::new(&t, &reference, None, 1 << 14).unwrap();
        let budget = Budget::parse("log_rmse=0.01,p99_rel_core=0.2").unwrap();
        let RateOutcome::Encoded(e) =
            encode_within(&t, &est, &budget, Effort::Default, &|_| {}).unwrap()
        else {
            panic!("the table is its own source: the grid costs nothing");
        };
        assert!(budget.met_by(&e.estimate.upper), "{:?}", e.estimate.upper);
        assert!(!e.spec.is_lossless(), "{:?}", e.spec);
        assert!(e.spec.transform().unwrap().curve.is_signed());
        let back = e.spec.decode(&e.payload, &Layout::of(&t)).unwrap();
        let kept = back.iter().filter(|&&v| v < 0.0).count();
        assert!(
            kept * 10 > negative * 9,
            "{kept} of {negative} negative values kept"
        );
        assert_eq!(est.measure(&back), e.estimate);
    }

    #[test]
    fn a_lent_table_gets_back_what_the_chosen_file_decodes_to() {
        // A table that is its own source (`compress`): lending its samples to the decode
        // buffer changes neither the file nor its measurement, and afterwards the table holds
        // the chosen file's decode. With a budget no lossy step meets, the lossless chain
        // takes the samples `again` gives, and refuses ones that differ from those lent.
        let m = Model::parse("lambert:albedo=0.1+ggx:alpha=0.2,fresnel=au").unwrap();
        let g = parse_grid_spec("halfdiff3:16x12x24,warp=sqrt/linear/linear").unwrap();
        let t = tabulate(&m, &g, &Default::default()).unwrap();
        let source = crate::table::InterpolatedTable {
            table: t.clone(),
            interp: crate::table::Interp::Linear,
        };
        let reference = ReferenceSet::new(&source, 1 << 14);
        let est = ErrorEstimator::new(&t, &reference, None, 1 << 14).unwrap();
        let original = t.data().to_vec();
        let again = || -> Result<Vec<f32>> { Ok(original.clone()) };
        let budget = Budget::parse("log_rmse=0.01,p99_rel_core=0.2").unwrap();
        let RateOutcome::Encoded(shared) =
            encode_within(&t, &est, &budget, Effort::Default, &|_| {}).unwrap()
        else {
            panic!("the table is its own source");
        };
        // The floor the prepared coefficients use is the estimator's (same values, another
        // order), or they would be made again.
        assert!(est.curve_floor(&budget).is_some());
        assert_eq!(reference.curve_floor(&budget), est.curve_floor(&budget));
        for prepared in [
            None,
            prepare_coefficients(
                &t,
                reference.epsilon(),
                reference.curve_floor(&budget),
                reference.curve_scale(&budget, 1 << 14),
                Effort::Default,
                &|_| {},
            ),
        ] {
            let mut lent = t.clone();
            let RateOutcome::Encoded(e) = encode_within_lending(
                &mut lent,
                &again,
                prepared,
                &est,
                &budget,
                Effort::Default,
                &|_| {},
            )
            .unwrap() else {
                panic!("the table is its own source");
            };
            assert_eq!(e.payload, shared.payload);
            assert_eq!(e.estimate, shared.estimate);
            assert!(!e.spec.is_lossless());
            let back = e.spec.decode(&e.payload, &Layout::of(&t)).unwrap();
            assert!(
                lent.data()
                    .iter()
                    .zip(&back)
                    .all(|(a, b)| a.to_bits() == b.to_bits())
            );
            assert_eq!(lent.valid(), t.valid());
        }
        // Below anything a lossy step reaches: the lossless chain, with the samples again.
        let tight = Budget::parse("log_rmse=1e-12").unwrap();
        let mut lent = t.clone();
        let RateOutcome::Encoded(e) =
            encode_within_lending(&mut lent, &again, None, &est, &tight, Effort::Fast, &|_| {})
                .unwrap()
        else {
            panic!("the table meets any budget against itself");
        };
        assert!(e.spec.is_lossless(), "{:?}", e.spec);
        assert_eq!(lent, t);
        assert_eq!(e.payload, e.spec.encode(&t).unwrap());
        let changed = || -> Result<Vec<f32>> {
            let mut v = original.clone();
            let k = t.valid().iter().position(|&ok| ok).unwrap() * 3;
            v[k] *= 1.5;
            Ok(v)
        };
        let mut lent = t.clone();
        let err = encode_within_lending(
            &mut lent,
            &changed,
            None,
            &est,
            &tight,
            Effort::Fast,
            &|_| {},
        )
        .unwrap_err();
        assert!(err.to_string().contains("differ"), "{err}");
        assert_eq!(lent.data().len(), t.data().len());
    }

    #[test]
    fn a_budget_is_met_against_the_source_and_a_coarse_grid_is_refused() {
        let m = Model::parse("lambert:albedo=0.02+ggx:alpha=0.15,fresnel=au").unwrap();
        let g = parse_grid_spec("halfdiff3:32x32x48,warp=sqrt/linear/linear,at=edge").unwrap();
        let t = tabulate(&m, &g, &Default::default()).unwrap();
        let reference = ReferenceSet::new(&m, 1 << 15);
        let est = ErrorEstimator::new(&t, &reference, None, 1 << 14).unwrap();
        let loose = Budget::parse("log_rmse=0.02,p99_rel_core=0.3").unwrap();
        let RateOutcome::Encoded(e) =
            encode_within(&t, &est, &loose, Effort::Default, &|_| {}).unwrap()
        else {
            panic!("a loose budget on a fine-enough grid must encode");
        };
        assert!(loose.met_by(&e.estimate.upper));
        assert!(!e.spec.is_lossless());
        // The file decodes to what was measured.
        let back = e.spec.decode(&e.payload, &Layout::of(&t)).unwrap();
        assert_eq!(est.measure(&back), e.estimate);
        // A budget far below the grid's own error is refused with that error.
        let tight = Budget::parse("log_rmse=1e-7").unwrap();
        match encode_within(&t, &est, &tight, Effort::Fast, &|_| {}).unwrap() {
            RateOutcome::GridTooCoarse { floor } => assert!(floor.upper.log_rmse > 1e-7),
            RateOutcome::Encoded(_) => panic!("a budget below the grid's error was met"),
        }
    }

    /// On a table with invalid cells (cut at the horizon), the default effort's refined fill
    /// makes a smaller file than the plain fill (`fast` refines nothing), within the budget,
    /// named as refined in its spec, and decoding to what was measured.
    #[test]
    fn the_refined_fill_makes_a_smaller_file_within_the_budget() {
        let m = Model::parse("lambert:albedo=0.05+ggx:alpha=0.1,fresnel=au").unwrap();
        let g = parse_grid_spec("halfdiff3:32x32x48,warp=sqrt/linear/linear,at=edge").unwrap();
        let t = tabulate(&m, &g, &Default::default()).unwrap();
        assert!(t.valid().iter().any(|v| !v));
        let reference = ReferenceSet::new(&m, 1 << 15);
        let est = ErrorEstimator::new(&t, &reference, None, 1 << 14).unwrap();
        let budget = Budget::parse("log_rmse=0.01,p99_rel_core=0.1").unwrap();
        let encode = |effort| match encode_within(&t, &est, &budget, effort, &|_| {}).unwrap() {
            RateOutcome::Encoded(e) => e,
            RateOutcome::GridTooCoarse { .. } => panic!("the grid meets the budget"),
        };
        let (plain, refined) = (encode(Effort::Fast), encode(Effort::Default));
        assert!(
            refined.payload.len() < plain.payload.len(),
            "{} vs {}",
            refined.payload.len(),
            plain.payload.len()
        );
        let CodecSpec::DctContext { domain, .. } = &refined.spec else {
            panic!("a context-coded DCT: {:?}", refined.spec);
        };
        assert_eq!(*domain, Domain::FillRefined { iterations: 1 });
        assert!(accepts(&budget, &refined.estimate));
        let back = refined
            .spec
            .decode(&refined.payload, &Layout::of(&t))
            .unwrap();
        assert_eq!(est.measure(&back), refined.estimate);
    }

    /// The premise of [`refine_passes`] and [`MANY_PASS_RELAXATION`]: at one step, more passes
    /// of the refined fill (at the longer relaxation) code a table with invalid cells in fewer
    /// bytes; the pass counts follow the accepted file's payload.
    #[test]
    fn more_passes_of_the_refined_fill_code_fewer_bytes() {
        let m = Model::parse("lambert:albedo=0.05+ggx:alpha=0.1,fresnel=au").unwrap();
        let g = parse_grid_spec("halfdiff3:32x32x48,warp=sqrt/linear/linear,at=edge").unwrap();
        let t = tabulate(&m, &g, &Default::default()).unwrap();
        let valid = t.valid().to_vec();
        assert!(valid.iter().any(|v| !v));
        let eps = vec![1e-3 * 0.05; t.channels().len()];
        let (_, coefs, fills, _) = transform_and_coefficients(&t, &eps, false, false, &|_| {});
        let fills = fills.expect("the fill of a table with invalid cells is kept");
        let dims = g.shape();
        let step = 0.05;
        let coded = |passes: u32, relaxation: f32| {
            let codes: Vec<_> = coefs
                .iter()
                .zip(&fills)
                .map(|(c, f)| {
                    let refined = refine_coefficients_from_fill(
                        c.clone(),
                        &dims,
                        &valid,
                        f,
                        step,
                        DEFAULT_DEADZONE,
                        passes,
                        relaxation,
                    );
                    coefcode::quantize_deadzone(&refined, &dims, step, DEFAULT_DEADZONE)
                })
                .collect();
            coefcode::encode_smaller(&codes).1.len()
        };
        let plain = coded(0, FILL_RELAXATION);
        let one = coded(1, FILL_RELAXATION);
        let two = coded(2, MANY_PASS_RELAXATION);
        let four = coded(4, MANY_PASS_RELAXATION);
        assert!(one < plain, "{one} vs {plain}");
        assert!(two < one, "{two} vs {one}");
        assert!(four < two, "{four} vs {two}");
        assert_eq!(refine_passes(1, MANY_PASSES_FROM - 1), 1);
        assert_eq!(refine_passes(1, MANY_PASSES_FROM), 4);
        assert_eq!(refine_passes(8, 1), 8);
    }

    /// The first curve is refined after a raise at the default effort exactly when the raised
    /// curve's file was not the smaller before either refined fill (or it accepted none),
    /// whatever the raised file became once refined; at `max` whenever the best file is above
    /// RAISE_WON_BELOW of the first curve's.
    #[test]
    fn a_raise_is_in_vain_by_the_files_before_their_refined_fills() {
        for effort in [Effort::Fast, Effort::Default] {
            assert!(!raise_in_vain(effort, 1000, Some(999), Some(990)));
            assert!(!raise_in_vain(effort, 1000, Some(999), Some(600)));
            assert!(raise_in_vain(effort, 1000, Some(1000), Some(600)));
            assert!(raise_in_vain(effort, 1000, Some(1200), Some(1000)));
            assert!(raise_in_vain(effort, 1000, None, Some(1000)));
        }
        assert!(raise_in_vain(Effort::Max, 1000, Some(600), Some(701)));
        assert!(!raise_in_vain(Effort::Max, 1000, Some(600), Some(699)));
        assert!(!raise_in_vain(Effort::Max, 1000, None, None));
    }
}
