//! Stage (3), quantize: f32 (lossless), f16 (with a scale that keeps every value finite) or
//! k-bit uniform in the transformed space (max error step/2 per component).

use crate::{Error, Result};
use half::f16;
use serde::{Deserialize, Serialize};

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(tag = "quantize", rename_all = "snake_case")]
pub enum Quantizer {
    /// y · scale stored as f16 (round to nearest). The scale is chosen so max |y| · scale ≤
    /// 32768: GGX peaks above 65504 (α < 1e-3) never become Inf.
    F16 { scale: f64 },
    /// q = round((y − origin_k) / step_k) per component k: |y − (origin + q step)| ≤ step/2.
    Uniform { origin: Vec<f64>, step: Vec<f64> },
}

/// Largest |q| a uniform quantizer produces (keeps predictor arithmetic far from i32 overflow).
const MAX_Q: f64 = (1u32 << 30) as f64;

/// Largest magnitude stored in f16 after scaling (half of f16::MAX: room for rounding).
const F16_LIMIT: f64 = 32768.0;

impl Quantizer {
    /// An f16 quantizer for components whose largest magnitude is `max_abs`.
    pub fn f16_for(max_abs: f64) -> Quantizer {
        let scale = if max_abs > F16_LIMIT {
            F16_LIMIT / max_abs
        } else {
            1.0
        };
        Quantizer::F16 { scale }
    }

    /// A k-bit uniform quantizer over the per-component ranges [lo, hi].
    pub fn bits_for(bits: u32, lo: &[f64], hi: &[f64]) -> Result<Quantizer> {
        if !(2..=24).contains(&bits) {
            return Err(Error::input(format!(
                "quantizer bits {bits}: expected 2..=24"
            )));
        }
        let levels = ((1u64 << bits) - 1) as f64;
        Ok(Quantizer::Uniform {
            origin: lo.to_vec(),
            step: lo
                .iter()
                .zip(hi)
                // A constant component: any step represents it exactly.
                .map(|(l, h)| if h > l { (h - l) / levels } else { 1.0 })
                .collect(),
        })
    }

    pub fn validate(&self, components: usize) -> Result<()> {
        match self {
            Quantizer::F16 { scale } if !(scale.is_finite() && *scale > 0.0) => Err(Error::input(
                format!("f16 quantizer: scale {scale} must be finite and > 0"),
            )),
            Quantizer::Uniform { origin, step }
                if step.len() != components
                    || origin.len() != components
                    || origin.iter().any(|o| !o.is_finite())
                    || step.iter().any(|s| !(s.is_finite() && *s > 0.0)) =>
            {
                Err(Error::input(format!(
                    "uniform quantizer: steps {step:?} need {components} finite positive values"
                )))
            }
            _ => Ok(()),
        }
    }

    /// The largest error in the transformed space per component (f16: relative 2^-11).
    pub fn max_error(&self, component: usize, magnitude: f64) -> f64 {
        match self {
            Quantizer::F16 { scale } => magnitude * 2f64.powi(-11) + 2f64.powi(-25) / scale,
            Quantizer::Uniform { step, .. } => step[component] / 2.0,
        }
    }

    /// Integer code of one transformed value of component `k`.
    #[inline]
    pub fn encode(&self, y: f64, k: usize) -> Result<i32> {
        match self {
            Quantizer::F16 { scale } => {
                let h = f16::from_f64(y * scale);
                if !h.is_finite() {
                    return Err(Error::Failure(format!(
                        "f16 quantizer: {y} × {scale} overflows f16"
                    )));
                }
                Ok(f16_key(h))
            }
            Quantizer::Uniform { origin, step } => {
                let q = ((y - origin[k]) / step[k]).round();
                if q.abs() > MAX_Q {
                    return Err(Error::input(format!(
                        "uniform quantizer: value {y:e} / step {:e} exceeds 2^30 levels",
                        step[k]
                    )));
                }
                Ok(q as i32)
            }
        }
    }

    /// The transformed value of an integer code.
    #[inline]
    pub fn decode(&self, q: i32, k: usize) -> f64 {
        match self {
            Quantizer::F16 { scale } => {
                let v = f16_of_key(q).to_f64();
                // A hostile code could name Inf/NaN bit patterns: read them as 0.
                if v.is_finite() { v / scale } else { 0.0 }
            }
            Quantizer::Uniform { origin, step } => origin[k] + q as f64 * step[k],
        }
    }

    /// [`Quantizer::decode`] of many codes (component = index mod `c`), rounded to f32, in
    /// place: `buf` holds each code's bits (`f32::from_bits(q as u32)`) and gets its value
    /// (f16 codes through `half`'s bulk conversion, F16C when the CPU has it), so that a
    /// decoder needs no array of codes beside its output.
    pub fn decode_bits_in_place(&self, buf: &mut [f32], c: usize) {
        match self {
            Quantizer::F16 { scale } => {
                use half::slice::HalfFloatSliceExt;
                const CHUNK: usize = 4096;
                let mut h = [f16::ZERO; CHUNK];
                for block in buf.chunks_mut(CHUNK) {
                    let h = &mut h[..block.len()];
                    for (h, v) in h.iter_mut().zip(block.iter()) {
                        *h = f16_of_key(v.to_bits() as i32);
                    }
                    h.convert_to_f32_slice(block);
                    for v in block.iter_mut() {
                        // As `decode`: hostile Inf/NaN codes read as 0; the division in f64.
                        *v = if v.is_finite() {
                            (*v as f64 / scale) as f32
                        } else {
                            0.0
                        };
                    }
                }
            }
            Quantizer::Uniform { .. } => {
                for (i, v) in buf.iter_mut().enumerate() {
                    *v = self.decode(v.to_bits() as i32, i % c) as f32;
                }
            }
        }
    }
}

/// Order-preserving integer of an f16 (−0 maps with +0).
fn f16_key(h: f16) -> i32 {
    let b = h.to_bits() as i32;
    if b & 0x8000 != 0 { -(b & 0x7fff) } else { b }
}

fn f16_of_key(k: i32) -> f16 {
    let k = k.clamp(-0x7fff, 0x7fff);
    if k < 0 {
        f16::from_bits(0x8000 | (-k) as u16)
    } else {
        f16::from_bits(k as u16)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    #[test]
    fn f16_never_overflows_on_huge_peaks() {
        // GGX α = 5e-4 peaks at 1/(π α²) ≈ 1.3e6 > 65504.
        let q = Quantizer::f16_for(1.3e6);
        let code = q.encode(1.3e6, 0).unwrap();
        let back = q.decode(code, 0);
        assert!(
            back.is_finite() && (back / 1.3e6 - 1.0).abs() < 1e-3,
            "{back}"
        );
    }

    proptest! {
        #[test]
        fn uniform_error_is_at_most_half_a_step(y in -1e3f64..1e3, bits in 4u32..20) {
            let q = Quantizer::bits_for(bits, &[-1e3], &[1e3]).unwrap();
            let back = q.decode(q.encode(y, 0).unwrap(), 0);
            prop_assert!((back - y).abs() <= q.max_error(0, y.abs()) * (1.0 + 1e-12));
        }

        #[test]
        fn f16_error_is_within_its_bound(y in -6e4f64..6e4) {
            let q = Quantizer::f16_for(6e4);
            let back = q.decode(q.encode(y, 0).unwrap(), 0);
            prop_assert!((back - y).abs() <= q.max_error(0, y.abs()) * (1.0 + 1e-9));
        }
    }
}
