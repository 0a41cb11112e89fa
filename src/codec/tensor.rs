//! A dense f32 tensor of channels, `[outer…][C][ny][nx]` (an RGL file's colour tables:
//! `[Nφ, Nθ, 3, n, n]`), coded on its own axes rather than as a table on a grid (issue #19):
//!
//! - `lossless`: the f32 values, little-endian, through zstd (bit-exact);
//! - `dct`: per node the signed log curve y_c = sign(x)·ln(1 + |x|/ε_c) (values may be
//!   negative: measured RGL tables dip below 0), the colour KLT z = M y, then per component
//!   an orthonormal DCT over all the other axes, dead-zone quantization with one step and
//!   the context coder of `dct_context` (the stages of [`super::transform`], [`super::dct`]
//!   and [`super::coefcode`], reused as they are). Errors in y are relative errors of
//!   ε_c + |x|; the decoder returns curve⁻¹(Mᵀ z) as a finite f32.
//!
//! `dims` are the coded axes without the channel axis (`[outer…, ny, nx]`); the values are
//! stored planar, channel planes of ny·nx inside each outer index.

use super::coefcode::{self, ContextModel};
use super::dct::{self, Coefficients};
use super::transform::{Colour, Curve, finite_f32};
use crate::{Error, Result};
use serde::{Deserialize, Serialize};

/// zstd level of the lossless form (a few hundred KB at most: the level costs milliseconds).
pub const LOSSLESS_LEVEL: i32 = 19;

/// How a tensor is coded (recorded in the file's header).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(tag = "kind", rename_all = "snake_case")]
pub enum TensorCoding {
    /// f32 little-endian + zstd: the values bit for bit; about 0.7–0.9 of the raw size on
    /// measured data (low mantissa bits do not compress).
    Lossless,
    /// Signed log curve, colour KLT, DCT and context-coded quantized coefficients: lossy,
    /// errors ≈ step/√12 in the log domain spread over the nodes (relative errors of
    /// ε + |x|); 20–100× smaller than the f32 values at the budgets of `pack`.
    Dct {
        /// ε_c of the signed log curve per channel.
        eps: Vec<f64>,
        /// The c×c orthonormal colour transform (row-major).
        colour: Colour,
        /// Quantization step of every component's coefficients (log units).
        step: f64,
        /// Dead zone in steps (coefficients with |c| < deadzone·step are coded as 0).
        deadzone: f64,
        /// The source held no negative value: decoded values are clamped at 0 (the signed
        /// curve's inverse can dip below 0 next to a node of 0, where a reader would get a
        /// negative BRDF the source never had).
        #[serde(default, skip_serializing_if = "std::ops::Not::not")]
        nonnegative: bool,
        /// The context coder's model of the coefficients: `line_ends2` for files written
        /// since 2026-12-07; absent (`line_ends`) in those written before, which still read.
        #[serde(default = "line_ends", skip_serializing_if = "is_line_ends")]
        model: ContextModel,
    },
}

/// The model of packed tensors written before `line_ends2` (a header without `model`).
fn line_ends() -> ContextModel {
    ContextModel::LineEnds
}

fn is_line_ends(m: &ContextModel) -> bool {
    *m == ContextModel::LineEnds
}

impl TensorCoding {
    pub fn is_lossless(&self) -> bool {
        matches!(self, TensorCoding::Lossless)
    }

    /// The lossy coding of `values` with `step` and `deadzone`: ε_c = `eps_share` · mean |x_c|
    /// (10⁻³: the metrics' ε rule of `spec/metrics.md` per channel, below which relative
    /// precision is not asked for), and the KLT of the curved values.
    pub fn dct_for(
        values: &[f32],
        dims: &[usize],
        channels: usize,
        eps_share: f64,
        step: f64,
        deadzone: f64,
    ) -> TensorCoding {
        let plane = plane_of(dims);
        let mut eps = vec![0.0; channels];
        let mut count = vec![0usize; channels];
        for (i, &v) in values.iter().enumerate() {
            let c = (i / plane) % channels;
            eps[c] += f64::from(v).abs();
            count[c] += 1;
        }
        for (e, n) in eps.iter_mut().zip(&count) {
            let mean = *e / (*n).max(1) as f64;
            // A channel of zeros still needs a positive ε (any: its values code as 0). Three
            // significant digits: ε is a choice, not a measurement, and the header is a
            // tenth of a preview file.
            *e = if mean > 0.0 {
                round_digits(eps_share * mean, 3)
            } else {
                1e-30
            };
        }
        let curve = Curve::SignedLog { eps: eps.clone() };
        let mut curved = Vec::with_capacity(values.len());
        for_each_node(values, dims, channels, |node| {
            curved.extend(node.iter().enumerate().map(|(c, &x)| curve.forward(x, c)));
        });
        TensorCoding::Dct {
            eps,
            colour: Colour::klt(&curved, channels),
            step,
            deadzone,
            nonnegative: values.iter().all(|&v| v >= 0.0),
            model: ContextModel::CURRENT,
        }
    }

    /// Checks the parameters against the channel count (a header is hostile input).
    pub fn validate(&self, channels: usize) -> Result<()> {
        match self {
            TensorCoding::Lossless => Ok(()),
            TensorCoding::Dct {
                eps,
                colour,
                step,
                deadzone,
                ..
            } => {
                Curve::SignedLog { eps: eps.clone() }.validate(channels)?;
                colour.validate(channels)?;
                if !(step.is_finite() && *step > 0.0) {
                    return Err(Error::input(format!(
                        "tensor dct: step {step} is not a positive finite number"
                    )));
                }
                if !(deadzone.is_finite() && *deadzone >= 0.0) {
                    return Err(Error::input(format!(
                        "tensor dct: dead zone {deadzone} is not a finite number ≥ 0"
                    )));
                }
                Ok(())
            }
        }
    }

    /// The payload of `values` (`[outer…][C][ny][nx]`, `dims` = `[outer…, ny, nx]`).
    pub fn encode(&self, values: &[f32], dims: &[usize], channels: usize) -> Result<Vec<u8>> {
        self.validate(channels)?;
        check_len(values.len(), dims, channels)?;
        match self {
            TensorCoding::Lossless => {
                let raw: Vec<u8> = values.iter().flat_map(|v| v.to_le_bytes()).collect();
                zstd::bulk::compress(&raw, LOSSLESS_LEVEL)
                    .map_err(|e| Error::Failure(format!("zstd compression failed: {e}")))
            }
            TensorCoding::Dct {
                step,
                deadzone,
                model,
                ..
            } => {
                let coef = self.coefficients(values, dims, channels);
                let quantized = quantize_checked(&coef, dims, *step, *deadzone)?;
                Ok(coefcode::encode_model(&quantized, *model))
            }
        }
    }

    /// The DCT coefficients of every colour component of `values` (a [`TensorCoding::Dct`]:
    /// curve, colour transform, DCT; what does not depend on the step).
    fn coefficients(&self, values: &[f32], dims: &[usize], channels: usize) -> Vec<Vec<f64>> {
        let TensorCoding::Dct { eps, colour, .. } = self else {
            unreachable!("coefficients of a lossless coding")
        };
        let curve = Curve::SignedLog { eps: eps.clone() };
        let n: usize = dims.iter().product();
        let mut comps = vec![Vec::with_capacity(n); channels];
        let (mut y, mut z) = (vec![0.0; channels], vec![0.0; channels]);
        for_each_node(values, dims, channels, |node| {
            for (c, &x) in node.iter().enumerate() {
                y[c] = curve.forward(x, c);
            }
            colour.forward(&y, &mut z);
            for (comp, &v) in comps.iter_mut().zip(&z) {
                comp.push(v);
            }
        });
        comps
            .into_iter()
            .map(|comp| dct::forward_owned(comp, dims))
            .collect()
    }

    /// The values of a payload (the inverse of [`TensorCoding::encode`], exactly what the
    /// encoder's own decode gives). Errors name what is wrong with a corrupt payload.
    pub fn decode(&self, payload: &[u8], dims: &[usize], channels: usize) -> Result<Vec<f32>> {
        self.validate(channels)?;
        let n: usize = dims.iter().product();
        let total = n
            .checked_mul(channels)
            .ok_or_else(|| Error::input("tensor size overflows"))?;
        match self {
            TensorCoding::Lossless => {
                let raw = zstd::bulk::decompress(payload, total * 4)
                    .map_err(|e| Error::input(format!("tensor payload: {e}")))?;
                if raw.len() != total * 4 {
                    return Err(Error::input(format!(
                        "tensor payload holds {} bytes, expected {}",
                        raw.len(),
                        total * 4
                    )));
                }
                let values: Vec<f32> = raw
                    .chunks_exact(4)
                    .map(|b| f32::from_le_bytes(b.try_into().expect("4 bytes")))
                    .collect();
                if let Some(i) = values.iter().position(|v| !v.is_finite()) {
                    return Err(Error::input(format!(
                        "tensor payload: value #{i} is {}, expected finite",
                        values[i]
                    )));
                }
                Ok(values)
            }
            TensorCoding::Dct { model, .. } => {
                let quantized = coefcode::decode(payload, dims, channels, *model)?;
                Ok(self.values_of(&quantized, dims, channels))
            }
        }
    }

    /// The values of quantized coefficients (a [`TensorCoding::Dct`]): what
    /// [`TensorCoding::decode`] makes of the codes it reads.
    fn values_of(&self, quantized: &[Coefficients], dims: &[usize], channels: usize) -> Vec<f32> {
        let TensorCoding::Dct {
            eps,
            colour,
            step,
            nonnegative,
            ..
        } = self
        else {
            unreachable!("values of a lossless coding")
        };
        let curve = Curve::SignedLog { eps: eps.clone() };
        let floor = if *nonnegative { 0.0 } else { f32::NEG_INFINITY };
        let n: usize = dims.iter().product();
        let planes: Vec<Vec<f32>> = quantized
            .iter()
            .map(|q| dct::inverse(q, dims, *step))
            .collect();
        let plane = plane_of(dims);
        let mut out = vec![0f32; n * channels];
        let (mut y, mut z) = (vec![0.0; channels], vec![0.0; channels]);
        for node in 0..n {
            let (s, p) = (node / plane, node % plane);
            for (zc, pl) in z.iter_mut().zip(&planes) {
                *zc = f64::from(pl[node]);
            }
            colour.inverse(&z, &mut y);
            for (c, &yc) in y.iter().enumerate() {
                out[(s * channels + c) * plane + p] = finite_f32(curve.inverse(yc, c)).max(floor);
            }
        }
        out
    }
}

/// Every component's coefficients quantized with `step` and `deadzone`, after the encoder's
/// range check.
fn quantize_checked(
    coef: &[Vec<f64>],
    dims: &[usize],
    step: f64,
    deadzone: f64,
) -> Result<Vec<Coefficients>> {
    let mut quantized = Vec::with_capacity(coef.len());
    for c in coef {
        dct::check_range(c, step)?;
        quantized.push(coefcode::quantize_deadzone(c, dims, step, deadzone));
    }
    Ok(quantized)
}

/// A tensor made ready for lossy codings that differ in their step alone (the planner's
/// search for the largest step, `plan::rgl`): the parameters of [`TensorCoding::dct_for`]
/// and the DCT coefficients, made once; each step then quantizes, codes and decodes them.
pub struct PreparedTensor {
    /// The coding at the step it was prepared with (replaced by [`PreparedTensor::coding`]).
    coding: TensorCoding,
    dims: Vec<usize>,
    channels: usize,
    coef: Vec<Vec<f64>>,
}

impl PreparedTensor {
    /// [`TensorCoding::dct_for`] of `values` (any step) and its coefficients.
    pub fn new(
        values: &[f32],
        dims: &[usize],
        channels: usize,
        eps_share: f64,
        deadzone: f64,
    ) -> Result<PreparedTensor> {
        check_len(values.len(), dims, channels)?;
        let coding = TensorCoding::dct_for(values, dims, channels, eps_share, 1.0, deadzone);
        coding.validate(channels)?;
        let coef = coding.coefficients(values, dims, channels);
        Ok(PreparedTensor {
            coding,
            dims: dims.to_vec(),
            channels,
            coef,
        })
    }

    /// The coding with `step`: [`TensorCoding::dct_for`]'s with the same arguments.
    pub fn coding(&self, step: f64) -> TensorCoding {
        let mut c = self.coding.clone();
        if let TensorCoding::Dct { step: s, .. } = &mut c {
            *s = step;
        }
        c
    }

    /// The coefficients quantized with `step` (the encoder's range check first).
    pub fn quantize(&self, step: f64) -> Result<QuantizedTensor<'_>> {
        let coding = self.coding(step);
        coding.validate(self.channels)?;
        let TensorCoding::Dct { deadzone, .. } = &coding else {
            unreachable!("a prepared tensor is lossy")
        };
        let codes = quantize_checked(&self.coef, &self.dims, step, *deadzone)?;
        Ok(QuantizedTensor {
            prepared: self,
            coding,
            codes,
        })
    }

    /// The payload of the coding with `step` and the values its decoder reads from it, the
    /// bits of [`TensorCoding::encode`] and [`TensorCoding::decode`].
    pub fn encode_and_decode(&self, step: f64) -> Result<(Vec<u8>, Vec<f32>)> {
        let q = self.quantize(step)?;
        Ok(rayon::join(|| q.payload(), || q.values()))
    }
}

/// A prepared tensor's codes at one step.
pub struct QuantizedTensor<'a> {
    prepared: &'a PreparedTensor,
    coding: TensorCoding,
    codes: Vec<Coefficients>,
}

impl QuantizedTensor<'_> {
    /// The payload: [`TensorCoding::encode`]'s bytes.
    pub fn payload(&self) -> Vec<u8> {
        let TensorCoding::Dct { model, .. } = &self.coding else {
            unreachable!("a prepared tensor is lossy")
        };
        coefcode::encode_model(&self.codes, *model)
    }

    /// The values the payload decodes to, made from the codes (which the context coder
    /// returns as they were given): [`TensorCoding::decode`]'s bits.
    pub fn values(&self) -> Vec<f32> {
        let p = self.prepared;
        self.coding.values_of(&self.codes, &p.dims, p.channels)
    }
}

/// `x` rounded to `digits` significant decimal digits (x > 0 finite).
fn round_digits(x: f64, digits: usize) -> f64 {
    format!("{x:.*e}", digits.saturating_sub(1))
        .parse()
        .unwrap_or(x)
}

/// ny·nx: the last two coded axes (the whole of a 1-axis tensor).
fn plane_of(dims: &[usize]) -> usize {
    dims.iter().rev().take(2).product::<usize>().max(1)
}

fn check_len(len: usize, dims: &[usize], channels: usize) -> Result<()> {
    let want = dims.iter().product::<usize>() * channels;
    if len != want {
        return Err(Error::input(format!(
            "tensor of {len} values, expected {want} ({dims:?} × {channels} channels)"
        )));
    }
    Ok(())
}

/// Calls `f` with each node's channel values (f64), nodes in C order of `dims`.
fn for_each_node(values: &[f32], dims: &[usize], channels: usize, mut f: impl FnMut(&[f64])) {
    let plane = plane_of(dims);
    let n: usize = dims.iter().product();
    let mut node = vec![0.0; channels];
    for k in 0..n {
        let (s, p) = (k / plane, k % plane);
        for (c, v) in node.iter_mut().enumerate() {
            *v = f64::from(values[(s * channels + c) * plane + p]);
        }
        f(&node);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A smooth signed tensor [2 slices][3 channels][8][8].
    fn sample() -> (Vec<f32>, Vec<usize>) {
        let dims = vec![2, 8, 8];
        let mut v = Vec::new();
        for s in 0..2 {
            for c in 0..3 {
                for y in 0..8 {
                    for x in 0..8 {
                        let t = (x as f64 * 0.4 + y as f64 * 0.2 + s as f64).sin();
                        v.push((0.5 + c as f64 * 0.2 + t) as f32 - 0.3);
                    }
                }
            }
        }
        (v, dims)
    }

    /// New codings are in the current context model and say so; a header without `model`
    /// (every packed file written before it) reads as the line-end model, and a stream
    /// decodes only in the model it was written in.
    #[test]
    fn the_context_model_is_recorded_and_old_headers_read_as_line_ends() {
        let (v, dims) = sample();
        let c = TensorCoding::dct_for(&v, &dims, 3, 1e-3, 0.05, 0.5);
        let json = serde_json::to_value(&c).unwrap();
        assert_eq!(json["model"], "line_ends2");
        let mut old = json.clone();
        old.as_object_mut().unwrap().remove("model");
        let old: TensorCoding = serde_json::from_value(old).unwrap();
        let TensorCoding::Dct { model, .. } = &old else {
            panic!("{old:?}")
        };
        assert_eq!(*model, ContextModel::LineEnds);
        assert!(!serde_json::to_string(&old).unwrap().contains("model"));
        let (new_bytes, old_bytes) = (
            c.encode(&v, &dims, 3).unwrap(),
            old.encode(&v, &dims, 3).unwrap(),
        );
        assert_ne!(new_bytes, old_bytes);
        assert_eq!(
            c.decode(&new_bytes, &dims, 3).unwrap(),
            old.decode(&old_bytes, &dims, 3).unwrap()
        );
        assert!(old.decode(&new_bytes, &dims, 3).is_err());
    }

    /// A tensor with no negative value (zeros beside bright nodes) decodes with none at a
    /// coarse step, where the signed curve's inverse dips below 0 without the clamp; a
    /// tensor that has negative values keeps them.
    #[test]
    fn a_nonnegative_tensor_decodes_nonnegative() {
        let (v, dims) = sample();
        let v: Vec<f32> = v
            .iter()
            .map(|&x| if x < 0.2 { 0.0 } else { x * 30.0 })
            .collect();
        let c = TensorCoding::dct_for(&v, &dims, 3, 1e-3, 1.5, 0.5);
        assert!(matches!(
            c,
            TensorCoding::Dct {
                nonnegative: true,
                ..
            }
        ));
        let back = c
            .decode(&c.encode(&v, &dims, 3).unwrap(), &dims, 3)
            .unwrap();
        assert!(back.iter().all(|&x| x >= 0.0));
        let TensorCoding::Dct {
            eps,
            colour,
            step,
            deadzone,
            ..
        } = c.clone()
        else {
            unreachable!()
        };
        let unclamped = TensorCoding::Dct {
            eps,
            colour,
            step,
            deadzone,
            nonnegative: false,
            model: ContextModel::CURRENT,
        };
        let raw = unclamped
            .decode(&unclamped.encode(&v, &dims, 3).unwrap(), &dims, 3)
            .unwrap();
        assert!(
            raw.iter().any(|&x| x < 0.0),
            "the clamp is what keeps them ≥ 0"
        );
        let (signed, dims) = sample();
        assert!(signed.iter().any(|&x| x < 0.0));
        let c = TensorCoding::dct_for(&signed, &dims, 3, 1e-3, 0.01, 0.5);
        assert!(matches!(
            c,
            TensorCoding::Dct {
                nonnegative: false,
                ..
            }
        ));
    }

    #[test]
    fn lossless_is_bit_exact() {
        let (v, dims) = sample();
        let c = TensorCoding::Lossless;
        let p = c.encode(&v, &dims, 3).unwrap();
        let back = c.decode(&p, &dims, 3).unwrap();
        assert_eq!(
            back.iter().map(|x| x.to_bits()).collect::<Vec<_>>(),
            v.iter().map(|x| x.to_bits()).collect::<Vec<_>>()
        );
    }

    #[test]
    fn dct_errors_follow_the_step_and_keep_signs() {
        let (v, dims) = sample();
        assert!(v.iter().any(|&x| x < 0.0));
        let mut last = 0.0;
        for step in [0.001, 0.01, 0.1] {
            let c = TensorCoding::dct_for(&v, &dims, 3, 1e-3, step, 0.5);
            let p = c.encode(&v, &dims, 3).unwrap();
            let back = c.decode(&p, &dims, 3).unwrap();
            let TensorCoding::Dct { eps, .. } = &c else {
                unreachable!()
            };
            // The error in the curve's domain is at most about step/2 per coefficient,
            // spread by the orthonormal transforms: its RMS is below step/2.
            let curve = Curve::SignedLog { eps: eps.clone() };
            let plane = 64;
            let rms = (v
                .iter()
                .zip(&back)
                .enumerate()
                .map(|(i, (&a, &b))| {
                    let c = (i / plane) % 3;
                    let d = curve.forward(a.into(), c) - curve.forward(b.into(), c);
                    d * d
                })
                .sum::<f64>()
                / v.len() as f64)
                .sqrt();
            assert!(rms < step / 2.0, "step {step}: rms {rms}");
            assert!(rms >= last, "errors grow with the step");
            last = rms;
            if step == 0.001 {
                for (&a, &b) in v.iter().zip(&back) {
                    assert!(a.abs() < 1e-3 || a.signum() == b.signum(), "{a} {b}");
                }
            }
        }
    }

    #[test]
    fn corrupt_payloads_are_errors() {
        let (v, dims) = sample();
        let c = TensorCoding::dct_for(&v, &dims, 3, 1e-3, 0.01, 0.75);
        let p = c.encode(&v, &dims, 3).unwrap();
        for cut in [0, 1, p.len() / 2] {
            assert!(c.decode(&p[..cut], &dims, 3).is_err(), "cut {cut}");
        }
        assert!(TensorCoding::Lossless.decode(&p, &dims, 3).is_err());
        let bad = TensorCoding::Dct {
            eps: vec![0.0; 3],
            colour: Colour {
                matrix: vec![1.0; 9],
            },
            step: 0.1,
            deadzone: 0.5,
            nonnegative: false,
            model: ContextModel::CURRENT,
        };
        assert!(bad.decode(&p, &dims, 3).is_err());
    }

    /// A prepared tensor's payload and decoded values at any step are the bits of
    /// `dct_for` + `encode` + `decode`: signed and nonnegative tensors, one and three
    /// channels, plain rounding and a dead zone, steps from fine to coarse.
    #[test]
    fn a_prepared_tensor_codes_and_decodes_as_the_coding_does() {
        let (signed, dims) = sample();
        let nonneg: Vec<f32> = signed.iter().map(|v| v.abs() * 3.0).collect();
        let one: Vec<f32> = signed[..dims.iter().product::<usize>()].to_vec();
        for (values, channels) in [(&signed, 3), (&nonneg, 3), (&one, 1)] {
            for (eps_share, deadzone) in [(1e-2, 0.5), (1e-3, 0.75)] {
                let prepared =
                    PreparedTensor::new(values, &dims, channels, eps_share, deadzone).unwrap();
                for step in [1e-4, 3.7e-3, 0.05, 0.8] {
                    let coding =
                        TensorCoding::dct_for(values, &dims, channels, eps_share, step, deadzone);
                    assert_eq!(prepared.coding(step), coding);
                    let payload = coding.encode(values, &dims, channels).unwrap();
                    let decoded = coding.decode(&payload, &dims, channels).unwrap();
                    let (p, d) = prepared.encode_and_decode(step).unwrap();
                    assert_eq!(p, payload, "payload at step {step}");
                    let bits = |v: &[f32]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
                    assert_eq!(bits(&d), bits(&decoded), "values at step {step}");
                }
            }
        }
    }
}
