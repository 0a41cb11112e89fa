//! `pack` of an RGL `.bsdf` in its own parameterization (issue #19): the file's fields kept,
//! its VNDF left for the reader to derive from its NDF when that reproduces the source, and
//! its colour tensor coded with the largest quantization step whose file still meets the
//! budget (`io::rgl::packed`, `codec::tensor`). The packed file evaluates through the same
//! code as the source, so its error is the coding's alone; it is measured end to end, the
//! candidate evaluated at the estimation set's pairs ([`PairEstimator`]), with the upper
//! values `pack` states for every file.

use super::budget::Budget;
use super::estimate::{ESTIMATE_PAIRS, Estimate, PairEstimator, ReferenceSet};
use super::pack::PackSettings;
use super::rate::{Effort, Progress, accepts};
use crate::codec::coefcode::DEFAULT_DEADZONE;
use crate::codec::tensor::{PreparedTensor, TensorCoding};
use crate::io::rgl::RglBsdf;
use crate::io::rgl::fields::RglFields;
use crate::io::rgl::packed::{
    self, PackOptions, VndfPacking, clamp_vndf, colour_dims, colour_name, vndf_dims,
    with_derived_vndf,
};
use crate::table::Provenance;
use crate::{Error, Result};
use serde::Serialize;
use std::time::Instant;

/// One coding tried, for the report.
#[derive(Clone, Debug, Serialize)]
pub struct RglAttempt {
    /// Quantization step (log units), `None` for lossless.
    pub step: Option<f64>,
    /// ε of the log curve as a share of each channel's mean |value| (`None`: lossless).
    pub eps_share: Option<f64>,
    /// Dead zone in steps (`None`: lossless).
    pub deadzone: Option<f64>,
    /// The VNDF: `derived`, `coded` or `stored`.
    pub vndf: &'static str,
    pub payload_bytes: usize,
    pub accepted: bool,
}

/// The chosen file.
pub struct RglPlanned {
    pub bytes: Vec<u8>,
    pub options: PackOptions,
    /// The file against the source.
    pub estimate: Estimate,
    /// The form alone: the exact colour tensor with the VNDF derived (or the file's own, for a
    /// coded or stored VNDF) against the source, what the form costs before coding.
    pub floor: Estimate,
    pub attempts: Vec<RglAttempt>,
    pub timings: Vec<(String, f64)>,
    pub estimate_samples: usize,
}

/// Why an RGL source cannot be packed in its own parameterization (`None`: it can).
pub fn unsupported(source: &RglBsdf) -> Option<String> {
    if source.clamps_negative() {
        return Some(
            "--clamp-negative changes the source's values, which the packed form keeps as \
             they are"
                .into(),
        );
    }
    let fields = source.fields();
    let name = colour_name(fields);
    match fields.get(name) {
        Some(f) if colour_dims(&f.shape).is_some() => None,
        _ => Some(format!("the file has no `{name}` tensor of 5 axes")),
    }
}

/// What a candidate holds of the VNDF.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Form {
    Derived,
    Coded,
    Stored,
}

impl Form {
    /// The packing of this form (`coding`: the VNDF's, for [`Form::Coded`]).
    fn vndf(self, coding: Option<TensorCoding>) -> VndfPacking {
        match (self, coding) {
            (Form::Derived, _) => VndfPacking::Derived,
            (Form::Coded, Some(c)) => VndfPacking::Coded(c),
            (Form::Coded, None) | (Form::Stored, _) => VndfPacking::Stored,
        }
    }
}

/// A candidate: its coded bytes (colour and, when coded, VNDF payloads) and its error, its
/// tensors decoded and evaluated as its reader will.
struct Trial {
    payload_bytes: usize,
    estimate: Estimate,
}

/// Plans the smallest packed file of `source` meeting the budget, or the lossless one
/// (`lossless`: every field stored, bit-exact evaluation).
pub fn plan_rgl(
    source: &RglBsdf,
    settings: &PackSettings,
    lossless: bool,
    provenance: &Provenance,
    progress: Progress,
) -> Result<RglPlanned> {
    if let Some(why) = unsupported(source) {
        return Err(Error::input(format!(
            "an RGL file cannot be packed in its own parameterization: {why}"
        )));
    }
    let mut timings = Vec::new();
    let fields = source.fields();
    let what = source.description();
    let cname = colour_name(fields);
    let colour_field = fields.require(cname, what)?;
    let (dims, channels) = colour_dims(&colour_field.shape).ok_or_else(|| {
        Error::input(format!(
            "field `{cname}`: shape {:?}, expected [phi_i, theta_i, channels, n, n]",
            colour_field.shape
        ))
    })?;
    let colour = fields.f32_of(cname, what)?;

    let t = Instant::now();
    progress("evaluating the source on the estimation and check sets");
    let pairs = if settings.effort == Effort::Max {
        2 * ESTIMATE_PAIRS
    } else {
        ESTIMATE_PAIRS
    };
    let reference = ReferenceSet::new(source, pairs);
    let check = ReferenceSet::uniform(source, settings.check_samples, settings.check_seed);
    let est = PairEstimator::new(&reference, Some(&check), check.len().max(1));
    timings.push(("reference values".to_string(), t.elapsed().as_secs_f64()));

    let mut attempts = Vec::new();
    // The lossless file keeps every field as it is.
    let exact_file = |opts: &PackOptions| packed::to_bytes(fields, opts, provenance);
    // `sigma`, when it is its NDF's projected area times one constant: left for the reader
    // to derive (~0.5 KB of a 2.6–3.6 KB preview file of the RGL database), if the source
    // with the derived `sigma` meets the budget with its exact colours. From here on the
    // candidates are that source's (their error against the user's source includes it).
    let derived_sigma = match (lossless, packed::sigma_scale(fields, what)?) {
        (false, Some(c)) => {
            let s = RglBsdf::from_fields(packed::with_derived_sigma(fields, c, what)?, what)?;
            let floor = est.measure(&s)?;
            accepts(&settings.budget, &floor).then_some((s, c))
        }
        _ => None,
    };
    let user_source = source;
    let (source, sigma_scale) = match &derived_sigma {
        Some((s, c)) => (s, Some(*c)),
        None => (source, None),
    };
    let fields = source.fields();
    let file = |opts: &PackOptions| packed::to_bytes(fields, opts, provenance);
    if lossless {
        let opts = PackOptions::lossless();
        let bytes = file(&opts)?;
        let estimate = est.measure(source)?;
        attempts.push(RglAttempt {
            step: None,
            eps_share: None,
            deadzone: None,
            vndf: "stored",
            payload_bytes: bytes.len(),
            accepted: true,
        });
        return Ok(RglPlanned {
            bytes,
            options: opts,
            floor: estimate.clone(),
            estimate,
            attempts,
            timings,
            estimate_samples: est.samples(),
        });
    }

    // The VNDF derived from the NDF, measured with the exact colour tensor: kept when that
    // form alone meets the budget (files brdfpack's own writer makes hold another density).
    let t = Instant::now();
    progress("measuring the derived VNDF");
    let derived = RglBsdf::from_fields(with_derived_vndf(fields, what)?, what)?;
    let derived_floor = est.measure(&derived)?;
    timings.push(("derived VNDF".to_string(), t.elapsed().as_secs_f64()));
    let mut forms = Vec::new();
    // The derived source is held only when its form is tried (a second copy of every field:
    // ~300 MB of a 72 MB anisotropic file's parsed fields, as were two clones of the source
    // for the other forms, which read the source itself).
    let derived = accepts(&settings.budget, &derived_floor).then_some(derived);
    if derived.is_some() {
        forms.push((Form::Derived, derived_floor));
    }
    // Otherwise (or when no step meets the budget with the derived one) the file's own VNDF,
    // coded with the colours; stored exactly when no coding of it meets the budget.
    let vndf = fields.f32_of("vndf", what)?;
    let vdims = vndf_dims(&fields.require("vndf", what)?.shape);
    let exact_floor = est.measure(source)?;
    if vdims.is_some() {
        forms.push((Form::Coded, exact_floor.clone()));
    }
    forms.push((Form::Stored, exact_floor));

    let t = Instant::now();
    let mut best: Option<(PackOptions, Estimate, Estimate, usize)> = None;
    let mut start = first_step(&settings.budget);
    for (form, floor) in forms {
        let base = match (form, &derived) {
            (Form::Derived, Some(d)) => d,
            _ => source,
        };
        progress(&format!(
            "coding the colour tensor (VNDF {})",
            form.vndf(None).name()
        ));
        for &(eps_share, deadzone) in variants(settings.effort, colour.len() + vndf.len()) {
            // The VNDF, when coded, with the colours' step and ε rule: both are densities or
            // values whose relative errors the log curve measures. Their curves, colour
            // transforms and DCTs do not depend on the step: made once a variant, each trial
            // then quantizes, codes and decodes (the bits of `TensorCoding::encode` and
            // `decode`).
            let colour_prep = PreparedTensor::new(&colour, &dims, channels, eps_share, deadzone)?;
            let vndf_prep = match (form, &vdims) {
                (Form::Coded, Some(d)) => {
                    Some(PreparedTensor::new(&vndf, d, 1, eps_share, deadzone)?)
                }
                _ => None,
            };
            let options_for = |step: f64| PackOptions {
                coding: colour_prep.coding(step),
                vndf: form.vndf(vndf_prep.as_ref().map(|p| p.coding(step))),
                derive_luminance: true,
                derive_sigma: sigma_scale,
            };
            let mut trial = |step: f64| -> Result<Trial> {
                let opts = options_for(step);
                let colour_codes = colour_prep.quantize(step)?;
                let vndf_codes = vndf_prep.as_ref().map(|p| p.quantize(step)).transpose()?;
                // The payloads (their sizes) are coded while the decoded values are measured.
                let ((payload, extra), estimate) = rayon::join(
                    || {
                        rayon::join(
                            || colour_codes.payload().len(),
                            || vndf_codes.as_ref().map_or(0, |q| q.payload().len()),
                        )
                    },
                    || -> Result<Estimate> {
                        let (decoded, vndf_values) = rayon::join(
                            || colour_codes.values(),
                            || vndf_codes.as_ref().map(|q| q.values()),
                        );
                        // The reader's fields: the decoded colours and VNDF (clamped as it
                        // clamps).
                        let cand = match vndf_values {
                            Some(mut v) => {
                                clamp_vndf(&mut v);
                                base.with_colour_and_vndf(&decoded, &v)?
                            }
                            None => base.with_colour(&decoded)?,
                        };
                        est.measure_within(&cand, Some(&settings.budget))
                    },
                );
                let estimate = estimate?;
                attempts.push(RglAttempt {
                    step: Some(step),
                    eps_share: Some(eps_share),
                    deadzone: Some(deadzone),
                    vndf: opts.vndf.name(),
                    payload_bytes: payload + extra,
                    accepted: accepts(&settings.budget, &estimate),
                });
                Ok(Trial {
                    payload_bytes: payload + extra,
                    estimate,
                })
            };
            // A variant whose payload at a step that misses the budget is no smaller than the best
            // file so far cannot give the smallest file: it stops there.
            let beat = best.as_ref().map(|b| b.3);
            let Some((step, tr)) = largest_step(&settings.budget, start, beat, &mut trial)? else {
                continue;
            };
            // The next variant's bracket starts here (the steps of a budget are close).
            start = step;
            if best.as_ref().is_none_or(|b| tr.payload_bytes < b.3) {
                best = Some((
                    options_for(step),
                    tr.estimate,
                    floor.clone(),
                    tr.payload_bytes,
                ));
            }
        }
        // The forms come smallest first: a derived VNDF (nothing stored) before a coded one
        // before its f32 values.
        if best.is_some() {
            break;
        }
    }
    timings.push(("colour coding".to_string(), t.elapsed().as_secs_f64()));
    let Some((options, estimate, floor, _)) = best else {
        return Err(Error::Failure(format!(
            "--max-error: no coding of the RGL file meets {} (the finest step tried misses it); \
             --codec lossless keeps it exactly",
            settings.budget.describe()
        )));
    };
    let mut bytes = file(&options)?;
    // Lossless, when it is the smaller file (a tiny tensor): exact, so within any budget.
    // Its zstd level 19 takes ~20 s on the 72 MB of an anisotropic file, so it is made only
    // when it may win: when half of a fast level's size of its two large fields is below the
    // coded file (level 19 gains some 5–20% over level 3 on f32 values, never a factor 2).
    let t = Instant::now();
    let exact = if lossless_may_win(fields, bytes.len())? {
        Some(exact_file(&PackOptions::lossless())?)
    } else {
        None
    };
    timings.push(("lossless compared".to_string(), t.elapsed().as_secs_f64()));
    let (options, estimate, floor) = if let Some(exact) = exact.filter(|e| e.len() < bytes.len()) {
        bytes = exact;
        let e = est.measure(user_source)?;
        (PackOptions::lossless(), e.clone(), e)
    } else {
        (options, estimate, floor)
    };
    Ok(RglPlanned {
        bytes,
        options,
        estimate,
        floor,
        attempts,
        timings,
        estimate_samples: est.samples(),
    })
}

/// Whether the lossless file of `fields` may be smaller than a coded file of `coded` bytes:
/// its colour tensor and VNDF (all but a few KB of it) compressed at zstd's fast level 3 and
/// halved (level 19, which the lossless file uses, never halves level 3's size on f32
/// values) fall below `coded`.
fn lossless_may_win(fields: &RglFields, coded: usize) -> Result<bool> {
    let mut fast = 0usize;
    for name in [colour_name(fields), "vndf"] {
        // The field's little-endian bytes: what the lossless coding compresses (f32 fields).
        if let Some(f) = fields.get(name) {
            fast += zstd::bulk::compress(&f.data, 3)
                .map_err(|e| Error::Failure(format!("zstd compression failed: {e}")))?
                .len();
        }
    }
    Ok(fast / 2 < coded)
}

/// The first step tried when no variant has been measured yet: the coding error of a step s
/// is about s/√12 in the log domain per node (uniform quantization of orthonormal
/// coefficients), a relative error of the colour values; `p99_rel_core` asks for about 2.58
/// RMS of a normal error below its bound b (s = √12·b/2.58), the relative RMS metrics for an
/// RMS below b (s = √12·b), and `log_rmse` alone, which shrinks relative errors of dark
/// values, for the same. Only where the bracket starts: every step is measured.
fn first_step(budget: &Budget) -> f64 {
    let s12 = 12f64.sqrt();
    let of = |k: &str| budget.bounds.iter().find(|(n, _)| n == k).map(|(_, b)| *b);
    let guess = of("p99_rel_core")
        .map(|b| s12 * b / 2.58)
        .or(of("rel_rmse_core").map(|b| s12 * b))
        .or(of("rel_rmse").map(|b| s12 * b))
        .or(of("log_rmse").map(|b| s12 * b))
        .unwrap_or(0.01);
    if guess > 0.0 {
        guess.min(MAX_STEP)
    } else {
        0.01
    }
}

/// The coding variants measured, (ε share, dead zone): ε at the metrics' own 10⁻³ of the mean
/// and one and 1.5 decades above, with plain rounding; `--effort max` also the coders' default
/// dead zone; `fast` the middle ε alone. Which makes the smallest file depends on the file
/// (how much a dark node's relative error reaches the metrics depends on how many pairs the
/// warp sends to it and on the bright nodes it is blended with), so it is measured, not set.
///
/// At the default effort a tensor and VNDF of more than [`HEAVY_VALUES`] values measure the
/// middle ε alone, as `fast`: each trial codes, decodes and evaluates them (~2 s for the 72 MB
/// file `convert` writes from an anisotropic GGX, ~7 trials a variant), and the three variants
/// took 41 s there for a file 0.35% smaller than the middle one's (15 s).
fn variants(effort: Effort, values: usize) -> &'static [(f64, f64)] {
    match effort {
        Effort::Default if values > HEAVY_VALUES => variants(Effort::Fast, values),
        Effort::Fast => &[(1e-2, 0.5)],
        Effort::Default => &[(1e-2, 0.5), (1e-3, 0.5), (3e-2, 0.5)],
        Effort::Max => &[
            (1e-2, 0.5),
            (1e-3, 0.5),
            (3e-2, 0.5),
            (1e-2, DEFAULT_DEADZONE),
            (3e-2, DEFAULT_DEADZONE),
        ],
    }
}

/// Values (colour tensor and VNDF) above which the default effort measures one coding variant
/// ([`variants`]): 2²³, 32 MB of f32. The four RGL files in `../shared` hold 0.16 M, the
/// default isotropic file `convert` writes ~1 M.
const HEAVY_VALUES: usize = 1 << 23;

/// Steps are tried down to this (log units: a relative 3e-7, f32's own precision) before the
/// coding is given up.
const MIN_STEP: f64 = 1e-6;
/// Above this the log-domain coding holds hardly more than the mean (a factor e^8 per node).
const MAX_STEP: f64 = 8.0;
/// Bisection halvings of the bracket (a factor 2 at the start: 2^(1/16) at the end, a few
/// percent of size).
const BISECTIONS: usize = 4;

/// The largest step (to a factor 2^(1/16)) whose trial meets the budget, with that trial;
/// `None` when none down to [`MIN_STEP`] does, or when the variant cannot give the smallest
/// file: a trial that misses the budget with a payload no smaller than `beat` (the best file
/// so far) ends the search, since every smaller step makes a larger payload (the
/// coefficients' codes only grow as the step shrinks). The error grows with the step (not
/// strictly: the bracket's accepted end is always a measured, accepted step).
///
/// Not a prediction of the step from the trials' errors: on `convert`'s GGX file the
/// binding `log_rmse` is carried by a few outlying pairs and is not monotone in the step
/// (a step meets the budget where a smaller one misses it), and a search that jumped to the
/// predicted step found larger accepted steps than this one, files that missed `log_rmse`
/// on an independent set (tests/rgl_packed.rs `a_writers_vndf_is_coded_and_meets_the_budget`).
fn largest_step(
    budget: &Budget,
    start: f64,
    beat: Option<usize>,
    trial: &mut impl FnMut(f64) -> Result<Trial>,
) -> Result<Option<(f64, Trial)>> {
    let hopeless = |t: &Trial| beat.is_some_and(|b| t.payload_bytes >= b);
    let mut step = start;
    let first = trial(step)?;
    let (mut good, mut bad) = if accepts(budget, &first.estimate) {
        // Grow until a step misses.
        let mut good = (step, first);
        let mut bad = None;
        while step < MAX_STEP {
            step *= 2.0;
            let t = trial(step)?;
            if accepts(budget, &t.estimate) {
                good = (step, t);
            } else {
                if hopeless(&t) {
                    return Ok(None);
                }
                bad = Some(step);
                break;
            }
        }
        match bad {
            Some(b) => (good, b),
            None => return Ok(Some(good)),
        }
    } else {
        if hopeless(&first) {
            return Ok(None);
        }
        // Shrink until a step meets it.
        let mut bad = step;
        loop {
            step /= 2.0;
            if step < MIN_STEP {
                return Ok(None);
            }
            let t = trial(step)?;
            if accepts(budget, &t.estimate) {
                break ((step, t), bad);
            }
            if hopeless(&t) {
                return Ok(None);
            }
            bad = step;
        }
    };
    for _ in 0..BISECTIONS {
        let mid = (good.0 * bad).sqrt();
        let t = trial(mid)?;
        if accepts(budget, &t.estimate) {
            good = (mid, t);
        } else {
            if hopeless(&t) {
                return Ok(None);
            }
            bad = mid;
        }
    }
    Ok(Some(good))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::check::Metrics;

    /// A trial whose upper `log_rmse` grows as the step, with a payload that shrinks as the
    /// step grows.
    fn synthetic(k: f64) -> impl FnMut(f64) -> Result<Trial> {
        move |s: f64| {
            let upper = Metrics {
                log_rmse: k * s,
                ..Metrics::default()
            };
            Ok(Trial {
                payload_bytes: (1e5 / (1.0 + 50.0 * s)) as usize,
                estimate: Estimate {
                    metrics: upper.clone(),
                    upper,
                    check: None,
                },
            })
        }
    }

    /// A variant that cannot beat the file so far stops at its first trial that misses the
    /// budget with a payload no smaller than that file's; one that can ends where it ended
    /// without a file to beat.
    #[test]
    fn a_variant_that_cannot_win_stops() {
        let budget = Budget {
            bounds: vec![("log_rmse".into(), 2e-3)],
        };
        let mut n = 0;
        let mut t = synthetic(0.1);
        // At 0.05 the error is 5e-3 (missed) and the payload 28,571 B.
        let r = largest_step(&budget, 0.05, Some(20_000), &mut |s| {
            n += 1;
            t(s)
        })
        .unwrap();
        assert!(r.is_none() && n == 1, "{n} trials");
        let free = largest_step(&budget, 0.05, None, &mut t).unwrap().unwrap();
        let (mut n, mut m) = (0, 0);
        let beaten = largest_step(&budget, 0.05, Some(60_000), &mut |s| {
            n += 1;
            t(s)
        })
        .unwrap()
        .unwrap();
        largest_step(&budget, 0.05, None, &mut |s| {
            m += 1;
            t(s)
        })
        .unwrap();
        assert_eq!(free.0.to_bits(), beaten.0.to_bits());
        assert!(free.0 < 0.02 && free.0 > 0.018, "{}", free.0);
        assert_eq!(n, m);
    }
}
