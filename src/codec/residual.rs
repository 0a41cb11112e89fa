//! Stage (6c), quantized residual: after a lossy approximation (the DCT of stage 6 or the
//! Tucker decomposition of 6b), what is left, r = z − ẑ, in the transformed space of every
//! valid cell (z = M curve(w·x) the source, ẑ what the decoder reconstructs from the lossy
//! section, bit for bit the same values on both sides), quantized uniformly with step S per
//! component by [`Quantizer::Uniform`] (origin 0, round to nearest: |r − q·S| ≤ S/2),
//! predicted from grid neighbours ([`Predictor`], integer space), byte-shuffled and
//! zstd-coded ([`Zstd`]) in a section of its own.
//!
//! The decoder adds q·S to ẑ (in f64, stored as f32) before the finishing step, so every valid
//! component of z is decoded within S/2 plus the f32 rounding of the sum (relative 2⁻²⁴):
//! the per-sample bound the DCT and Tucker chains lack.
//!
//! Payload of a chain with a residual: the lossy section's length (u64 LE), the lossy section
//! (exactly the payload the chain writes without a residual), the residual section.

use super::entropy::Zstd;
use super::predict::{self, Predictor, Shape, Space};
use super::quantize::Quantizer;
use super::transform::finite_f32;
use super::unpredict;
use crate::{Error, Result};
use serde::{Deserialize, Serialize};

/// Stage parameters recorded in the header (`"residual": {...}` of the `*_residual` kinds).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct ResidualStage {
    /// Quantization step S per transformed component: every valid component is decoded within
    /// S/2 (before f32 rounding).
    pub step: Vec<f64>,
    /// Predictor of the integer residual codes.
    pub predict: Predictor,
    pub entropy: Zstd,
}

/// Bytes of the lossy section's length at the start of the payload.
const LEN_BYTES: usize = 8;

impl ResidualStage {
    /// A stage of step `step` for `components` components on a grid of `axes` axes, zstd at
    /// `level`, without prediction (the first of [`candidates`]; a resolved request has the
    /// best of them, [`best_predictor`]).
    pub fn new(step: f64, components: usize, axes: usize, level: i32) -> ResidualStage {
        ResidualStage {
            step: vec![step; components],
            predict: candidates(axes).swap_remove(0),
            entropy: Zstd { level },
        }
    }

    /// Checks the stage against the layout (parameters from a header may be hostile).
    pub fn validate(&self, axes: usize, components: usize) -> Result<()> {
        if self.step.len() != components || self.step.iter().any(|s| !(s.is_finite() && *s > 0.0)) {
            return Err(Error::input(format!(
                "residual steps {:?}: need {components} finite positive values",
                self.step
            )));
        }
        if self.predict.orders.len() != axes || self.predict.orders.iter().any(|&o| o > 2) {
            return Err(Error::input(format!(
                "residual predictor orders {:?}: expected {axes} (one per grid axis), each 0..=2",
                self.predict.orders
            )));
        }
        self.quantizer().validate(components)
    }

    fn quantizer(&self) -> Quantizer {
        Quantizer::Uniform {
            origin: vec![0.0; self.step.len()],
            step: self.step.clone(),
        }
    }

    /// The residual section: `z[k]` the source's component k over every cell (f64), `approx[k]`
    /// the decoder's reconstruction of it; only valid cells are coded.
    pub fn encode(&self, z: &[Vec<f64>], approx: &[Vec<f32>], shape: &Shape) -> Result<Vec<u8>> {
        let codes = self.codes(z, approx, shape)?;
        let res = self.predict.residuals_i32(&codes, shape)?;
        self.entropy.compress(&predict::shuffle(&res))
    }

    /// The quantized residual of every cell (cell-major, component fastest; invalid cells 0).
    pub fn codes(&self, z: &[Vec<f64>], approx: &[Vec<f32>], shape: &Shape) -> Result<Vec<i32>> {
        let c = shape.channels;
        let q = self.quantizer();
        let mut codes = vec![0i32; shape.valid.len() * c];
        for (f, &ok) in shape.valid.iter().enumerate() {
            if !ok {
                continue;
            }
            for k in 0..c {
                let r = z[k][f] - approx[k][f] as f64;
                if !r.is_finite() {
                    return Err(Error::Failure(format!(
                        "residual of cell {f} component {k}: {} − {} is not finite",
                        z[k][f], approx[k][f]
                    )));
                }
                codes[f * c + k] = q.encode(r, k).map_err(|e| {
                    Error::input(format!(
                        "residual step {:?} is too small for this table: {e}",
                        self.step[k]
                    ))
                })?;
            }
        }
        Ok(codes)
    }

    /// Adds the dequantized residual of `section` to every valid cell of `planes` (component
    /// planes over every cell, as the lossy decoder returned them): ẑ + q·S in f64, stored as
    /// a finite f32.
    pub fn add(&self, section: &[u8], planes: &mut [Vec<f32>], shape: &Shape) -> Result<()> {
        let c = shape.channels;
        let n_valid = shape.valid.iter().filter(|&&v| v).count();
        let want = n_valid
            .checked_mul(c * 4)
            .ok_or_else(|| Error::input("table too large"))?;
        let raw = self
            .entropy
            .decompress(section, want)
            .map_err(|e| Error::input(format!("residual section: {e}")))?;
        let codes = unpredict::reconstruct_i32(&self.predict, &raw, shape)?;
        if planes.len() != c || planes.iter().any(|p| p.len() != shape.valid.len()) {
            return Err(Error::Failure(format!(
                "residual: {} component planes for {c} components of {} cells",
                planes.len(),
                shape.valid.len()
            )));
        }
        let q = self.quantizer();
        for (f, &ok) in shape.valid.iter().enumerate() {
            if ok {
                for (k, p) in planes.iter_mut().enumerate() {
                    p[f] = finite_f32(p[f] as f64 + q.decode(codes[f * c + k], k));
                }
            }
        }
        Ok(())
    }
}

/// The predictors a residual stage chooses from, in integer space without the cross-channel
/// term (the colour transform already decorrelates the components): none, the delta along
/// the fastest axis, the Lorenzo predictor. Which is smallest depends on S against the lossy
/// stage's error: a coarse residual is close to white noise, which a difference only makes
/// wider; a fine one follows the smooth error of the lossy stage, which prediction removes
/// (docs/compression.md, "The quantized residual").
pub fn candidates(axes: usize) -> Vec<Predictor> {
    let mut delta = vec![0u8; axes];
    if let Some(last) = delta.last_mut() {
        *last = 1;
    }
    [vec![0u8; axes], delta, vec![1u8; axes]]
        .into_iter()
        .map(|orders| Predictor {
            orders,
            space: Space::Integer,
            cross_channel: false,
        })
        .collect()
}

/// The candidate whose shuffled residuals of `codes` zstd compresses smallest at level
/// [`TRIAL_LEVEL`] (fast, an estimate: on the 18 residual rows of the figures it picks the
/// level-19 smallest 15 times, the other three 0.7–7.8% larger); ties go to the earlier
/// (simpler) one. Not the order-0 entropy of the byte planes that the lossless
/// chain chooses by: on residuals that proxy picked a larger candidate in 12 of 18 figures rows,
/// by up to 15% (docs/compression.md, "The quantized residual").
pub fn best_predictor(codes: &[i32], shape: &Shape) -> Result<Predictor> {
    let mut best: Option<(usize, Predictor)> = None;
    for p in candidates(shape.dims.len()) {
        let bytes = Zstd { level: TRIAL_LEVEL }
            .compress(&predict::shuffle(&p.residuals_i32(codes, shape)?))?
            .len();
        if best.as_ref().is_none_or(|(b, _)| bytes < *b) {
            best = Some((bytes, p));
        }
    }
    best.map(|(_, p)| p)
        .ok_or_else(|| Error::Failure("no residual predictor candidates".into()))
}

/// zstd level of the predictor trial in [`best_predictor`].
pub const TRIAL_LEVEL: i32 = 3;

/// The payload of a chain with a residual: the lossy section's length, it, the residual.
pub fn join(lossy: &[u8], residual: &[u8]) -> Vec<u8> {
    let mut out = Vec::with_capacity(LEN_BYTES + lossy.len() + residual.len());
    out.extend_from_slice(&(lossy.len() as u64).to_le_bytes());
    out.extend_from_slice(lossy);
    out.extend_from_slice(residual);
    out
}

/// Inverse of [`join`]: (lossy section, residual section), lengths checked.
pub fn split(payload: &[u8]) -> Result<(&[u8], &[u8])> {
    let Some((len, rest)) = payload.split_first_chunk::<LEN_BYTES>() else {
        return Err(Error::input(format!(
            "payload with a residual: {} bytes, shorter than its {LEN_BYTES}-byte section length",
            payload.len()
        )));
    };
    let n = u64::from_le_bytes(*len);
    match usize::try_from(n) {
        Ok(n) if n <= rest.len() => Ok(rest.split_at(n)),
        _ => Err(Error::input(format!(
            "payload with a residual: lossy section of {n} bytes, only {} follow",
            rest.len()
        ))),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    #[test]
    fn sections_split_back_and_short_payloads_are_errors() {
        let p = join(b"abc", b"defg");
        assert_eq!(split(&p).unwrap(), (&b"abc"[..], &b"defg"[..]));
        assert_eq!(split(&join(b"", b"")).unwrap(), (&b""[..], &b""[..]));
        for cut in 0..LEN_BYTES + 3 {
            let e = split(&p[..cut]).unwrap_err().to_string();
            assert!(e.contains("payload with a residual"), "{cut}: {e}");
        }
        let mut huge = p.clone();
        huge[..8].copy_from_slice(&u64::MAX.to_le_bytes());
        assert!(
            split(&huge)
                .unwrap_err()
                .to_string()
                .contains("lossy section")
        );
    }

    fn shape_of<'a>(dims: &'a [usize], valid: &'a [bool], c: usize) -> Shape<'a> {
        Shape {
            dims,
            valid,
            channels: c,
        }
    }

    proptest! {
        /// Random planes and approximations, every predictor order, 1–3 components: each valid
        /// value comes back within S/2 of z, plus the f32 rounding of the stored sum (2⁻²⁴ of
        /// its magnitude); invalid cells are left as they were.
        #[test]
        fn every_valid_value_is_within_half_a_step(
            a in 1usize..7, b in 1usize..7, c in 1usize..4, seed in any::<u64>(),
            log_step in -6.0f64..1.0, order in 0u8..3, level in 1i32..20,
        ) {
            let dims = [a, b];
            let n = a * b;
            let mut rng = crate::math::SplitMix64::new(seed);
            let valid: Vec<bool> = (0..n).map(|_| rng.next_f64() < 0.8).collect();
            let z: Vec<Vec<f64>> = (0..c)
                .map(|_| (0..n).map(|_| rng.next_f64() * 40.0 - 20.0).collect())
                .collect();
            let approx: Vec<Vec<f32>> = z
                .iter()
                .map(|p| p.iter().map(|&v| (v + rng.next_f64() - 0.5) as f32).collect())
                .collect();
            let step = 10f64.powf(log_step);
            let mut stage = ResidualStage::new(step, c, 2, level);
            stage.predict.orders = vec![order, 1];
            stage.validate(2, c).unwrap();
            let shape = shape_of(&dims, &valid, c);
            let section = stage.encode(&z, &approx, &shape).unwrap();
            let mut planes = approx.clone();
            stage.add(&section, &mut planes, &shape).unwrap();
            for f in 0..n {
                for k in 0..c {
                    let got = planes[k][f] as f64;
                    if valid[f] {
                        let tol = step / 2.0 * (1.0 + 1e-12) + got.abs() * 2f64.powi(-24);
                        prop_assert!((got - z[k][f]).abs() <= tol,
                            "cell {f} comp {k}: {got} vs {} (S {step})", z[k][f]);
                    } else {
                        prop_assert_eq!(planes[k][f].to_bits(), approx[k][f].to_bits());
                    }
                }
            }
        }
    }

    #[test]
    fn the_predictor_follows_the_residual() {
        let dims = [16, 24];
        let valid = vec![true; 16 * 24];
        let shape = shape_of(&dims, &valid, 1);
        // White noise: any difference widens it; no prediction.
        let mut rng = crate::math::SplitMix64::new(3);
        let noise: Vec<i32> = (0..16 * 24)
            .map(|_| (rng.next_f64() * 9.0) as i32 - 4)
            .collect();
        assert_eq!(best_predictor(&noise, &shape).unwrap().orders, vec![0, 0]);
        // A smooth slope in both axes (what a fine step sees of the lossy stage's error):
        // Lorenzo leaves nothing.
        let smooth: Vec<i32> = (0..16 * 24)
            .map(|f: i32| 40 * (f / 24) + 7 * (f % 24))
            .collect();
        assert_eq!(best_predictor(&smooth, &shape).unwrap().orders, vec![1, 1]);
    }

    #[test]
    fn hostile_sections_and_stages_are_errors() {
        let dims = [3, 4];
        let valid = vec![true; 12];
        let shape = shape_of(&dims, &valid, 1);
        let z = vec![(0..12).map(|i| i as f64 * 0.37).collect::<Vec<_>>()];
        let approx = vec![vec![0f32; 12]];
        let stage = ResidualStage::new(0.01, 1, 2, 3);
        let section = stage.encode(&z, &approx, &shape).unwrap();
        for cut in [0, 1, section.len() / 2, section.len() - 1] {
            let mut p = approx.clone();
            let e = stage.add(&section[..cut], &mut p, &shape).unwrap_err();
            assert!(e.to_string().contains("residual section"), "{cut}: {e}");
        }
        // Too fine a step for the values: more than 2^30 levels, an error naming the step.
        let e = ResidualStage::new(1e-12, 1, 2, 3)
            .encode(&z, &approx, &shape)
            .unwrap_err()
            .to_string();
        assert!(e.contains("residual step 1e-12 is too small"), "{e}");
        for bad in [
            ResidualStage::new(0.0, 1, 2, 3),
            ResidualStage::new(f64::NAN, 1, 2, 3),
            ResidualStage::new(0.1, 2, 2, 3),
            ResidualStage::new(0.1, 1, 3, 3),
        ] {
            assert!(bad.validate(2, 1).is_err(), "{bad:?}");
        }
    }
}
