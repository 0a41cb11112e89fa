//! Codecs: how a table's samples become the payload of a file and back.
//!
//! A codec is a chain of stages, each a small type with its own encode/decode and tests:
//! (1) [`domain`] — which cells are coded (invalid cells cost no bytes: the mask is implied by
//! the grid or stored beside the data); (2) [`transform`] — an optional cosine weight, a curve
//! (linear or log(ε + x)) and an optional colour decorrelation; (3) [`quantize`] — f32 (lossless), f16 or k-bit uniform;
//! (4) [`predict`] — residuals from grid neighbours, byte-plane shuffle; (5) [`entropy`] —
//! zstd, or for DCT coefficients [`coefcode`], a context-adaptive range coder; (6) [`dct`] —
//! transform coding of the whole table with quantized coefficients; (6b) [`tucker`] — a
//! truncated Tucker (HOSVD) low-rank decomposition with quantized factors and core; (6c)
//! [`residual`] — optionally after either, the quantized difference between the table and
//! what the decoder reconstructs, which bounds every sample's error.
//!
//! A [`CodecSpec`] is the fully resolved chain (every data-derived parameter written out) and
//! is recorded in the file header, so any file decodes with no flags. A [`CodecRequest`] is
//! what a user asks for (`--codec dct:step=0.02`); [`CodecRequest::resolve`] turns it into a
//! spec for a given table. [`search`] picks the smallest spec meeting an error budget.

pub mod coefcode;
pub mod dct;
pub mod domain;
pub mod eigen;
pub mod entropy;
mod header;
mod idct;
pub mod predict;
pub mod quantize;
#[doc(hidden)]
pub mod reference;
mod request_text;
pub mod residual;
mod simd;
pub mod transform;
pub mod tucker;
mod unpredict;

use crate::grid::{Grid, GridKind};
use crate::table::Table;
use crate::{Error, Result};
use domain::Domain;
use entropy::Zstd;
use predict::{Predictor, Shape};
use quantize::Quantizer;
use serde::{Deserialize, Serialize};
use transform::{Colour, Curve, Transform, Weight};

/// A codec, as recorded in a file header (through [`header::SpecRecord`]: a chain with a
/// residual is written as a kind of its own, `dct_residual`, `dct_context_residual` or
/// `tucker_residual`, which readers from before residuals refuse).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(from = "header::SpecRecord", into = "header::SpecRecord")]
pub enum CodecSpec {
    /// Lossless: the f32 samples of every cell (little-endian, cell-major, channel fastest)
    /// compressed with zstd. Typical ratio 1.1–2× on smooth tables.
    ZstdF32 { level: i32 },
    /// Lossless: valid cells only, each f32 predicted from its grid neighbours, the residuals
    /// of the order-preserving integer keys byte-shuffled and compressed.
    Lossless {
        domain: Domain,
        predict: Predictor,
        entropy: Zstd,
    },
    /// Lossy with a known max error in the transformed space: transform, quantize (f16 or
    /// uniform), predict the integer codes, shuffle, compress.
    Quantized {
        domain: Domain,
        transform: Transform,
        quantize: Quantizer,
        predict: Predictor,
        entropy: Zstd,
    },
    /// Lossy transform coding: fill invalid cells, transform, separable DCT over the grid,
    /// quantized coefficients in a low-frequency box, compressed.
    Dct {
        domain: Domain,
        transform: Transform,
        dct: dct::DctStage,
        entropy: Zstd,
        /// Optional quantized residual after the DCT: every valid component within step/2.
        residual: Option<residual::ResidualStage>,
    },
    /// Lossy transform coding, context-coded: as `Dct` (the decoder is the same up to the
    /// coefficients), with dead-zone quantization, optionally a refined fill of the invalid
    /// cells (`domain` `fill_refined`, encoder only), and the coefficients range-coded with
    /// adaptive contexts ([`coefcode`]). Typically 1.3–2× smaller than `Dct` at the same error;
    /// larger on very peaky tables (GGX α < 1e-3), where the search keeps `Dct`.
    DctContext {
        domain: Domain,
        transform: Transform,
        dct: dct::DctStage,
        coding: coefcode::ContextCoding,
        /// Optional quantized residual after the DCT: every valid component within step/2.
        residual: Option<residual::ResidualStage>,
    },
    /// Lossy low rank: fill invalid cells, transform, truncated Tucker decomposition of every
    /// component (factor matrices per grid axis and a core, both quantized), zstd.
    Tucker {
        domain: Domain,
        transform: Transform,
        tucker: tucker::TuckerStage,
        entropy: Zstd,
        /// Optional quantized residual after the Tucker stage: every valid component within
        /// step/2.
        residual: Option<residual::ResidualStage>,
    },
}

impl Default for CodecSpec {
    fn default() -> Self {
        CodecSpec::ZstdF32 { level: 19 }
    }
}

/// What the decoder knows besides the payload: the grid, the validity of every cell (from the
/// grid's geometry or the file's mask) and the channel count.
#[derive(Clone, Copy, Debug)]
pub struct Layout<'a> {
    pub grid: &'a Grid,
    pub valid: &'a [bool],
    pub channels: usize,
}

impl<'a> Layout<'a> {
    pub fn of(table: &'a Table) -> Layout<'a> {
        Layout {
            grid: table.grid(),
            valid: table.valid(),
            channels: table.channels().len(),
        }
    }
    fn values(&self) -> Result<usize> {
        self.valid
            .len()
            .checked_mul(self.channels)
            .ok_or_else(|| Error::input("table too large"))
    }
    fn dims(&self) -> Vec<usize> {
        self.grid.shape()
    }
    fn shape<'b>(&'b self, dims: &'b [usize]) -> Shape<'b> {
        Shape {
            dims,
            valid: self.valid,
            channels: self.channels,
        }
    }
}

/// The order in which [`domain::fill_invalid`] extends along axes: the second polar angle
/// first (θd, θo: the horizon cut runs across it), then the others.
fn fill_order(kind: GridKind) -> Vec<usize> {
    match kind {
        GridKind::Halfdiff3 | GridKind::Spherical3 => vec![1, 0, 2],
        GridKind::Halfdiff4 | GridKind::Spherical4 => vec![2, 0, 1, 3],
    }
}

impl CodecSpec {
    /// True when decoding returns the input bit for bit.
    pub fn is_lossless(&self) -> bool {
        matches!(self, CodecSpec::ZstdF32 { .. } | CodecSpec::Lossless { .. })
    }

    /// The largest error of any valid sample in the transformed space (log space for the log
    /// curve: a relative error of ε + x), when the codec guarantees one.
    pub fn max_transformed_error(&self) -> Option<f64> {
        match self {
            CodecSpec::ZstdF32 { .. } | CodecSpec::Lossless { .. } => Some(0.0),
            CodecSpec::Quantized {
                transform,
                quantize: Quantizer::Uniform { step, .. },
                ..
            } => Some(half_steps_through_colour(transform, step)),
            CodecSpec::Dct {
                transform,
                residual: Some(r),
                ..
            }
            | CodecSpec::DctContext {
                transform,
                residual: Some(r),
                ..
            }
            | CodecSpec::Tucker {
                transform,
                residual: Some(r),
                ..
            } => Some(half_steps_through_colour(transform, &r.step)),
            _ => None,
        }
    }

    /// The quantized residual stage of a DCT or Tucker chain, when it has one.
    pub fn residual(&self) -> Option<&residual::ResidualStage> {
        match self {
            CodecSpec::Dct { residual, .. }
            | CodecSpec::DctContext { residual, .. }
            | CodecSpec::Tucker { residual, .. } => residual.as_ref(),
            _ => None,
        }
    }

    /// The residual stage, mutable (tests and figures edit its fields).
    pub fn residual_mut(&mut self) -> Option<&mut residual::ResidualStage> {
        match self {
            CodecSpec::Dct { residual, .. }
            | CodecSpec::DctContext { residual, .. }
            | CodecSpec::Tucker { residual, .. } => residual.as_mut(),
            _ => None,
        }
    }

    /// The transform stage of the lossy chains.
    pub fn transform(&self) -> Option<&Transform> {
        match self {
            CodecSpec::ZstdF32 { .. } | CodecSpec::Lossless { .. } => None,
            CodecSpec::Quantized { transform, .. }
            | CodecSpec::Dct { transform, .. }
            | CodecSpec::DctContext { transform, .. }
            | CodecSpec::Tucker { transform, .. } => Some(transform),
        }
    }

    /// One line on what the codec preserves.
    pub fn preserves(&self) -> String {
        let mut s = self.preserves_unweighted();
        if let Some(w) = self.transform().and_then(|t| t.weight) {
            s.push_str(&format!(
                " (weight={}: the space codes w·f, w = cos θi cos θo ≥ {:e}, so errors in f \
                 grow as 1/w toward grazing cells)",
                w.name(),
                transform::W_MIN
            ));
        }
        s
    }

    fn preserves_unweighted(&self) -> String {
        if let (Some(r), Some(e)) = (self.residual(), self.max_transformed_error()) {
            return format!(
                "every valid sample within ±{e:.3e} in the transformed space (a quantized \
                 residual of step {:.3e} after the lossy stage: each component within step/2, \
                 plus f32 rounding)",
                r.step.iter().fold(0.0f64, |m, s| m.max(*s))
            );
        }
        match self {
            CodecSpec::ZstdF32 { .. } | CodecSpec::Lossless { .. } => {
                "every valid sample bit for bit".into()
            }
            CodecSpec::Quantized { quantize, .. } => match self.max_transformed_error() {
                Some(e) => format!("every valid sample within ±{e:.3e} in the transformed space"),
                None => match quantize {
                    Quantizer::F16 { .. } => {
                        "every valid sample to f16 precision (relative 2^-11) in the transformed space"
                            .into()
                    }
                    Quantizer::Uniform { .. } => unreachable!("uniform has a bound"),
                },
            },
            CodecSpec::Dct { dct, .. } | CodecSpec::DctContext { dct, .. } => format!(
                "the table in the mean-square sense: RMS error ≈ step/√12 = {:.3e} in the \
                 transformed space (no per-sample bound)",
                dct.step.iter().fold(0.0f64, |m, s| m.max(*s)) / 12f64.sqrt()
            ),
            CodecSpec::Tucker { tucker, .. } => format!(
                "the table in the mean-square sense: ranks {:?}, core RMS error ≈ step/√12 = \
                 {:.3e} in the transformed space plus what the truncation drops (no per-sample \
                 bound)",
                tucker.ranks,
                tucker.step.iter().fold(0.0f64, |m, s| m.max(*s)) / 12f64.sqrt()
            ),
        }
    }

    /// A compact one-line form for reports.
    pub fn summary(&self) -> String {
        serde_json::to_string(self).unwrap_or_else(|_| format!("{self:?}"))
    }

    /// Checks the spec against the table layout (parameters from a header may be hostile).
    fn validate(&self, layout: &Layout) -> Result<()> {
        let c = layout.channels;
        let d = layout.grid.axes().len();
        let check_dct = |transform: &Transform, dct: &dct::DctStage| {
            transform.validate(c)?;
            if dct.step.len() != c || dct.step.iter().any(|s| !(s.is_finite() && *s > 0.0)) {
                return Err(Error::input(format!(
                    "dct steps {:?}: need {c} finite positive values",
                    dct.step
                )));
            }
            Ok(())
        };
        let check_residual = |r: &Option<residual::ResidualStage>| match r {
            Some(r) => r.validate(d, c),
            None => Ok(()),
        };
        let check_pred = |p: &Predictor| {
            if p.orders.len() != d {
                return Err(Error::input(format!(
                    "predictor orders {:?}: expected {d} (one per grid axis)",
                    p.orders
                )));
            }
            Ok(())
        };
        match self {
            CodecSpec::ZstdF32 { .. } => Ok(()),
            CodecSpec::Lossless { predict, .. } => check_pred(predict),
            CodecSpec::Quantized {
                transform,
                quantize,
                predict,
                ..
            } => {
                transform.validate(c)?;
                quantize.validate(c)?;
                check_pred(predict)
            }
            CodecSpec::Dct {
                transform,
                dct,
                residual,
                ..
            } => {
                check_residual(residual)?;
                check_dct(transform, dct)
            }
            CodecSpec::DctContext {
                domain,
                transform,
                dct,
                coding,
                residual,
            } => {
                check_residual(residual)?;
                check_dct(transform, dct)?;
                if let Domain::FillRefined { iterations } = domain
                    && *iterations > domain::MAX_REFINE
                {
                    return Err(Error::input(format!(
                        "dct domain: {iterations} refinement passes (at most {})",
                        domain::MAX_REFINE
                    )));
                }
                coding.validate()
            }
            CodecSpec::Tucker {
                domain,
                transform,
                tucker,
                residual,
                ..
            } => {
                check_residual(residual)?;
                if *domain != Domain::FillInvalid {
                    return Err(Error::input(format!(
                        "tucker domain {domain:?}: only fill_invalid is defined"
                    )));
                }
                transform.validate(c)?;
                tucker.validate(&layout.dims(), c)
            }
        }
    }

    /// Encodes the table's samples.
    pub fn encode(&self, table: &Table) -> Result<Vec<u8>> {
        let lossy = self.encode_chain(table)?;
        let Some(res) = self.residual() else {
            return Ok(lossy);
        };
        let layout = Layout::of(table);
        let dims = layout.dims();
        let r = self.residual_inputs(table, &lossy)?;
        let section = res.encode(&r.source, &r.approx, &layout.shape(&dims))?;
        Ok(residual::join(&lossy, &section))
    }

    /// The source's transformed component planes and the decoder's reconstruction of them
    /// from the `lossy` section. The residual is taken against exactly what the decoder
    /// reconstructs: the planes the decoder's own function returns for these very bytes.
    fn residual_inputs(&self, table: &Table, lossy: &[u8]) -> Result<ResidualInputs> {
        let transform = self
            .transform()
            .ok_or_else(|| Error::Failure("a residual without a transform".into()))?;
        let approx = self.lossy_planes(lossy, &Layout::of(table))?;
        Ok(ResidualInputs {
            source: component_planes(table, transform),
            approx,
        })
    }

    /// The spec with the residual predictor that codes this table's residual best (by a zstd
    /// trial, [`residual::best_predictor`]); unchanged without a residual. Runs the lossy
    /// stage once more (the encoder runs it again), as `predict=auto` of the lossless chain
    /// tries its predictors at resolve time.
    fn with_best_residual_predictor(mut self, table: &Table) -> Result<CodecSpec> {
        if self.residual().is_none() {
            return Ok(self);
        }
        let lossy = self.encode_chain(table)?;
        let inputs = self.residual_inputs(table, &lossy)?;
        let layout = Layout::of(table);
        let dims = layout.dims();
        let shape = layout.shape(&dims);
        if let CodecSpec::Dct {
            residual: Some(r), ..
        }
        | CodecSpec::DctContext {
            residual: Some(r), ..
        }
        | CodecSpec::Tucker {
            residual: Some(r), ..
        } = &mut self
        {
            let codes = r.codes(&inputs.source, &inputs.approx, &shape)?;
            r.predict = residual::best_predictor(&codes, &shape)?;
        }
        Ok(self)
    }

    /// The payload of the chain without its residual stage.
    fn encode_chain(&self, table: &Table) -> Result<Vec<u8>> {
        let layout = Layout::of(table);
        self.validate(&layout)?;
        let c = layout.channels;
        let dims = layout.dims();
        match self {
            CodecSpec::ZstdF32 { level } => {
                let mut raw = Vec::with_capacity(table.data().len() * 4);
                for v in table.data() {
                    raw.extend_from_slice(&v.to_le_bytes());
                }
                Zstd { level: *level }.compress(&raw)
            }
            CodecSpec::Lossless {
                predict, entropy, ..
            } => {
                let res = predict.residuals_f32(table.data(), &layout.shape(&dims))?;
                entropy.compress(&predict::shuffle(&res))
            }
            CodecSpec::Quantized {
                transform,
                quantize,
                predict,
                entropy,
                ..
            } => {
                let z = transform.forward_all(table.data(), c, layout.grid, layout.valid);
                let mut codes = vec![0i32; z.len()];
                for (cell, &ok) in layout.valid.iter().enumerate() {
                    if ok {
                        for k in 0..c {
                            codes[cell * c + k] = quantize.encode(z[cell * c + k], k)?;
                        }
                    }
                }
                let res = predict.residuals_i32(&codes, &layout.shape(&dims))?;
                entropy.compress(&predict::shuffle(&res))
            }
            CodecSpec::Dct {
                transform,
                dct: stage,
                entropy,
                ..
            } => {
                let coefs = dct_coefficients(table, transform)?;
                for (p, &s) in coefs.iter().zip(&stage.step) {
                    dct::check_range(p, s)?;
                }
                let comps: Vec<_> = coefs
                    .iter()
                    .zip(&stage.step)
                    .map(|(p, &s)| dct::quantize(p, &dims, s))
                    .collect();
                entropy.compress(&dct::serialize(&comps))
            }
            CodecSpec::DctContext {
                domain,
                transform,
                dct: stage,
                coding,
                ..
            } => {
                let coefs = dct_coefficients_for(table, transform, *domain, &stage.step, coding)?;
                for (p, &s) in coefs.iter().zip(&stage.step) {
                    dct::check_range(p, s)?;
                }
                Ok(coefcode::encode_model(
                    &coefcode::quantize_all(&coefs, &dims, &stage.step, coding.deadzone),
                    coding.model,
                ))
            }
            CodecSpec::Tucker {
                transform,
                tucker: stage,
                entropy,
                ..
            } => {
                let planes = filled_planes(table, transform);
                entropy.compress(&tucker::encode(&planes, &dims, stage)?)
            }
        }
    }

    /// Decodes `payload` into every cell's values (cell-major, channel fastest); invalid
    /// cells are 0.
    pub fn decode(&self, payload: &[u8], layout: &Layout) -> Result<Vec<f32>> {
        self.validate(layout)?;
        let mut out = crate::memory::try_filled(layout.values()?, 0f32, "decoded table")?;
        self.decode_into(payload, layout, &mut out)?;
        Ok(out)
    }

    /// As [`CodecSpec::decode`], into a buffer the caller owns (cells × channels long; its
    /// previous contents are irrelevant: every value is written). A loader that decodes many
    /// tables of one size reuses one buffer and skips the allocation and page faults of a
    /// fresh 17.5 MB vector per MERL-sized table.
    pub fn decode_into(&self, payload: &[u8], layout: &Layout, out: &mut [f32]) -> Result<()> {
        self.decode_into_with(payload, layout, out, &mut DecodeScratch::default())
    }

    /// As [`CodecSpec::decode_into`], with the decoder's working arrays kept in `scratch`
    /// between calls: a loader decoding many tables of one size then also skips mapping,
    /// faulting in and zeroing the coefficient boxes and pass arrays (~25 MB for the
    /// gold-metallic-paint production table). The output does not depend on `scratch`.
    pub fn decode_into_with(
        &self,
        payload: &[u8],
        layout: &Layout,
        out: &mut [f32],
        scratch: &mut DecodeScratch,
    ) -> Result<()> {
        self.validate(layout)?;
        let values = layout.values()?;
        if out.len() != values {
            return Err(Error::input(format!(
                "decode buffer holds {} values, the table has {values}",
                out.len()
            )));
        }
        if let Some(res) = self.residual() {
            return self.decode_with_residual(res, payload, layout, out);
        }
        let c = layout.channels;
        let dims = layout.dims();
        let n_valid = layout.valid.iter().filter(|&&v| v).count();
        match self {
            CodecSpec::ZstdF32 { level } => Zstd { level: *level }
                .decompress_f32_into(payload, out)
                .map_err(|e| Error::input(format!("zstd-f32 {e}"))),
            CodecSpec::Lossless {
                predict, entropy, ..
            } => {
                let raw = entropy.decompress(payload, n_valid * c * 4)?;
                let v = unpredict::reconstruct_f32(predict, &raw, &layout.shape(&dims))?;
                copy_decoded(&v, out)
            }
            CodecSpec::Quantized {
                transform,
                quantize,
                predict,
                entropy,
                ..
            } => {
                let raw = entropy.decompress(payload, n_valid * c * 4)?;
                let codes = unpredict::reconstruct_i32(predict, &raw, &layout.shape(&dims))?;
                match &transform.colour {
                    // The colour matrix mixes components: apply it in f64 like the encoder.
                    Some(col) => {
                        let mut z = vec![0.0; c];
                        let mut y = vec![0.0; c];
                        for (o, q) in out.chunks_exact_mut(c).zip(codes.chunks_exact(c)) {
                            for k in 0..c {
                                z[k] = quantize.decode(q[k], k);
                            }
                            col.inverse(&z, &mut y);
                            for (o, y) in o.iter_mut().zip(&y) {
                                *o = *y as f32;
                            }
                        }
                        if codes.len() != values {
                            return Err(Error::input("quantized payload: wrong number of codes"));
                        }
                    }
                    None => copy_decoded(&quantize.decode_all_f32(&codes, c), out)?,
                }
                simd::curve_interleaved(&transform.curve, c, layout.valid, out);
                if let Some(rw) = transform.reciprocal_weights(layout.grid, layout.valid) {
                    simd::scale_cells(&rw, c, out);
                }
                Ok(())
            }
            CodecSpec::Dct {
                transform,
                dct: stage,
                entropy,
                ..
            } => {
                let raw = entropy.decompress_capped(payload, dct_stream_cap(layout)?)?;
                let comps = dct::deserialize(&raw, &dims, c)?;
                let fin = simd::Finisher::new(transform, layout);
                idct::decode(&comps, &stage.step, &dims, &fin, layout.valid, out, scratch);
                Ok(())
            }
            CodecSpec::DctContext {
                transform,
                dct: stage,
                coding,
                ..
            } => {
                let comps = coefcode::decode_with(payload, &dims, c, coding.model, scratch)?;
                let fin = simd::Finisher::new(transform, layout);
                idct::decode(&comps, &stage.step, &dims, &fin, layout.valid, out, scratch);
                for q in comps {
                    scratch.give_i32(q.codes);
                }
                Ok(())
            }
            CodecSpec::Tucker {
                transform,
                tucker: stage,
                entropy,
                ..
            } => {
                let comps = tucker_components(payload, &dims, stage, entropy)?;
                let fin = simd::Finisher::new(transform, layout);
                tucker::decode(&comps, &stage.step, &dims, &fin, layout.valid, out);
                Ok(())
            }
        }
    }
}

/// Working arrays of the transform decoders, reusable across decodes
/// ([`CodecSpec::decode_into_with`]); arrays grow to the largest size asked for and are kept.
#[derive(Debug, Default)]
pub struct DecodeScratch {
    f32s: Vec<Vec<f32>>,
    i32s: Vec<Vec<i32>>,
}

impl DecodeScratch {
    /// At least `n` long, contents unspecified (every user writes what it reads).
    pub(crate) fn take_f32(&mut self, n: usize) -> Vec<f32> {
        let mut v = self.f32s.pop().unwrap_or_default();
        Self::grow(&mut v, n);
        v
    }

    pub(crate) fn give_f32(&mut self, v: Vec<f32>) {
        self.f32s.push(v);
    }

    /// Exactly `n` zeros.
    pub(crate) fn take_i32_zeroed(&mut self, n: usize) -> Vec<i32> {
        match self.i32s.pop() {
            // As in `grow`: a fresh array comes zeroed from the allocator.
            None => vec![0; n],
            Some(mut v) => {
                v.clear();
                v.resize(n, 0);
                v
            }
        }
    }

    pub(crate) fn give_i32(&mut self, v: Vec<i32>) {
        self.i32s.push(v);
    }

    /// `v` at least `n` long; it never shrinks, so a reused array is not written again.
    pub(crate) fn grow(v: &mut Vec<f32>, n: usize) {
        if v.capacity() == 0 {
            // A fresh array through the allocator's zeroed path: large ones are new pages,
            // already zero, where `resize` wrote every value (17 MB, ~2 ms, for the
            // intermediate of a MERL table decoded with a fresh scratch).
            *v = vec![0.0; n];
            crate::memory::advise_huge_pages(v);
        } else if v.len() < n {
            v.resize(n, 0.0);
        }
    }
}

impl CodecSpec {
    /// A chain with a residual: the lossy section decoded to component planes in the
    /// transformed space (not fused with the finisher), the residual added, then finished.
    fn decode_with_residual(
        &self,
        res: &residual::ResidualStage,
        payload: &[u8],
        layout: &Layout,
        out: &mut [f32],
    ) -> Result<()> {
        let transform = self
            .transform()
            .ok_or_else(|| Error::Failure("a residual without a transform".into()))?;
        let dims = layout.dims();
        let (lossy, section) = residual::split(payload)?;
        let mut planes = self.lossy_planes(lossy, layout)?;
        res.add(section, &mut planes, &layout.shape(&dims))?;
        let fin = simd::Finisher::new(transform, layout);
        let views: Vec<&[f32]> = planes.iter().map(|p| p.as_slice()).collect();
        simd::finish(&fin, &views, layout.valid, out);
        Ok(())
    }

    /// The component planes (transformed space, every cell) that the lossy section of a DCT
    /// or Tucker chain decodes to: what the encoder takes its residual against and the
    /// decoder adds it to, the same bits on both sides (one function; its kernels give the
    /// same bits on every CPU, `simd`).
    fn lossy_planes(&self, lossy: &[u8], layout: &Layout) -> Result<Vec<Vec<f32>>> {
        let c = layout.channels;
        let dims = layout.dims();
        match self {
            CodecSpec::Dct {
                dct: stage,
                entropy,
                ..
            } => {
                let raw = entropy.decompress_capped(lossy, dct_stream_cap(layout)?)?;
                let comps = dct::deserialize(&raw, &dims, c)?;
                Ok(comps
                    .iter()
                    .zip(&stage.step)
                    .map(|(q, &s)| idct::inverse(q, &dims, s))
                    .collect())
            }
            CodecSpec::DctContext {
                dct: stage, coding, ..
            } => {
                let comps = coefcode::decode(lossy, &dims, c, coding.model)?;
                Ok(comps
                    .iter()
                    .zip(&stage.step)
                    .map(|(q, &s)| idct::inverse(q, &dims, s))
                    .collect())
            }
            CodecSpec::Tucker {
                tucker: stage,
                entropy,
                ..
            } => {
                let comps = tucker_components(lossy, &dims, stage, entropy)?;
                Ok(comps
                    .iter()
                    .zip(&stage.step)
                    .map(|(q, &s)| tucker::inverse(q, &dims, s))
                    .collect())
            }
            _ => Err(Error::Failure(format!(
                "{}: no lossy approximation to add a residual to",
                self.summary()
            ))),
        }
    }
}

/// What a residual is taken between: the source's transformed component planes and the
/// decoder's reconstruction of them (component k over every cell).
struct ResidualInputs {
    source: Vec<Vec<f64>>,
    approx: Vec<Vec<f32>>,
}

/// The largest decompressed varint stream of a `dct` payload: at most 5 bytes per code plus
/// 10 per extent.
fn dct_stream_cap(layout: &Layout) -> Result<usize> {
    layout
        .values()?
        .checked_mul(5)
        .and_then(|v| v.checked_add(10 * layout.channels * layout.grid.axes().len() + 16))
        .ok_or_else(|| Error::input("table too large"))
}

/// The largest error per channel of the curve space when every component k of z = M y is
/// within step_k/2: Σ_i |M_ik| step_i/2 through an orthonormal colour matrix, step/2 without.
fn half_steps_through_colour(transform: &Transform, step: &[f64]) -> f64 {
    let c = step.len();
    match &transform.colour {
        None => step.iter().fold(0.0f64, |m, s| m.max(s / 2.0)),
        Some(col) => (0..c)
            .map(|k| {
                (0..c)
                    .map(|i| col.matrix[i * c + k].abs() * step[i] / 2.0)
                    .sum()
            })
            .fold(0.0f64, f64::max),
    }
}

/// `decoded` into `out`, which must be as long (a stage that produced the wrong count is a
/// corrupt payload, not a panic).
fn copy_decoded(decoded: &[f32], out: &mut [f32]) -> Result<()> {
    if decoded.len() != out.len() {
        return Err(Error::input(format!(
            "payload decoded to {} values, the table has {}",
            decoded.len(),
            out.len()
        )));
    }
    out.copy_from_slice(decoded);
    Ok(())
}

/// The quantized components of a Tucker payload, every field checked.
fn tucker_components(
    payload: &[u8],
    dims: &[usize],
    stage: &tucker::TuckerStage,
    entropy: &Zstd,
) -> Result<Vec<tucker::Component>> {
    let cap = tucker::max_stream(dims, stage).ok_or_else(|| Error::input("table too large"))?;
    let raw = entropy.decompress_capped(payload, cap)?;
    tucker::deserialize(&raw, dims, stage)
}

/// The forward DCT coefficients of every transformed component of `table` (invalid cells
/// filled first). Exposed so the search can quantize one transform at many steps.
pub fn dct_coefficients(table: &Table, transform: &Transform) -> Result<Vec<Vec<f64>>> {
    let dims = table.grid().shape();
    let planes = filled_planes(table, transform);
    Ok(planes.iter().map(|p| dct::forward(p, &dims)).collect())
}

/// The transformed component planes with the invalid cells filled ([`domain::fill_invalid`]):
/// what the DCT and Tucker stages decompose.
pub fn filled_planes(table: &Table, transform: &Transform) -> Vec<Vec<f64>> {
    let dims = table.grid().shape();
    let mut planes = component_planes(table, transform);
    domain::fill_invalid(
        &mut planes,
        &dims,
        table.valid(),
        &fill_order(table.grid().kind()),
    );
    planes
}

/// The DCT coefficients for a context-coded spec: with `Domain::FillRefined` the invalid
/// cells are refilled `iterations` times with the decoded table of the quantized coefficients
/// (at these `steps` and dead zone), which makes the filled table cheaper to code; otherwise
/// as [`dct_coefficients`].
pub fn dct_coefficients_for(
    table: &Table,
    transform: &Transform,
    domain: Domain,
    steps: &[f64],
    coding: &coefcode::ContextCoding,
) -> Result<Vec<Vec<f64>>> {
    let Domain::FillRefined { iterations } = domain else {
        return dct_coefficients(table, transform);
    };
    let dims = table.grid().shape();
    let mut planes = component_planes(table, transform);
    let order = fill_order(table.grid().kind());
    domain::fill_refined(
        &mut planes,
        &dims,
        table.valid(),
        &order,
        iterations,
        |k, p| {
            let q = coefcode::quantize_deadzone(
                &dct::forward(p, &dims),
                &dims,
                steps[k],
                coding.deadzone,
            );
            dct::inverse(&q, &dims, steps[k])
        },
    );
    Ok(planes.iter().map(|p| dct::forward(p, &dims)).collect())
}

/// The transformed table as one plane per component (cell-major data → planes).
fn component_planes(table: &Table, transform: &Transform) -> Vec<Vec<f64>> {
    let c = table.channels().len();
    let cells = table.grid().cells();
    let mut planes = vec![vec![0.0; cells]; c];
    transform.for_each_cell(table.data(), c, table.grid(), table.valid(), |f, z| {
        for (p, &v) in planes.iter_mut().zip(z) {
            p[f] = v;
        }
    });
    planes
}

/// How a curve is chosen for a table.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum CurveRequest {
    Linear,
    /// Log with ε_c = `eps_rel` × mean of channel c over valid cells.
    Log {
        eps_rel: f64,
    },
    /// The signed log curve (`Curve::SignedLog`), ε_c = `eps_rel` × mean |x| of channel c.
    SignedLog {
        eps_rel: f64,
    },
}

/// A codec as asked for on the command line, before data-derived parameters are known.
#[derive(Clone, Debug, PartialEq)]
pub enum CodecRequest {
    ZstdF32 {
        level: i32,
    },
    Lossless {
        level: i32,
        predict: Option<Predictor>,
    },
    F16 {
        curve: CurveRequest,
        weight: Option<Weight>,
        level: i32,
    },
    Uniform {
        curve: CurveRequest,
        weight: Option<Weight>,
        bits: u32,
        colour: bool,
        level: i32,
    },
    Dct {
        curve: CurveRequest,
        weight: Option<Weight>,
        step: f64,
        colour: bool,
        coding: DctCoding,
        /// Step of the quantized residual (`residual=S`), none by default.
        residual: Option<f64>,
    },
    Tucker {
        curve: CurveRequest,
        weight: Option<Weight>,
        ranks: Vec<usize>,
        step: f64,
        factor_step: f64,
        colour: bool,
        level: i32,
        /// Step of the quantized residual (`residual=S`), none by default.
        residual: Option<f64>,
    },
}

/// Default core step of `tucker:` (log space: an RMS error of about 0.014, 1.4%).
pub const DEFAULT_TUCKER_STEP: f64 = 0.05;

/// How DCT coefficients are entropy-coded.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum DctCoding {
    /// Varints in a frequency box + zstd (`CodecSpec::Dct`, the first `dct` files).
    Zstd { level: i32 },
    /// Dead-zone quantization, `refine` passes of [`domain::fill_refined`], context range
    /// coding (`CodecSpec::DctContext`).
    Context { deadzone: f64, refine: u32 },
}

impl Default for DctCoding {
    fn default() -> Self {
        DctCoding::Context {
            deadzone: coefcode::DEFAULT_DEADZONE,
            refine: 0,
        }
    }
}

/// Default log ε relative to a channel's mean: the metrics' ε (spec/metrics.md) is 1e-3 of the
/// mean, so values far below it do not count and need no relative precision.
pub const DEFAULT_EPS_REL: f64 = 1e-3;

impl CodecRequest {
    /// Parses `NAME[:key=value,...]` (grammar in docs/compression.md).
    pub fn parse(spec: &str) -> Result<CodecRequest> {
        let spec = spec.trim();
        let (name, rest) = spec.split_once(':').unwrap_or((spec, ""));
        let mut kv = std::collections::BTreeMap::new();
        for part in rest.split(',').filter(|s| !s.is_empty()) {
            let (k, v) = part.split_once('=').ok_or_else(|| {
                Error::input(format!("codec {spec:?}: option {part:?} is not key=value"))
            })?;
            // A repeated option is an error (which one was meant?), not "the last wins".
            if kv
                .insert(k.trim().to_string(), v.trim().to_string())
                .is_some()
            {
                return Err(Error::input(format!(
                    "codec {spec:?}: option {:?} is given twice",
                    k.trim()
                )));
            }
        }
        let bad = |k: &str, v: &str, want: &str| {
            Error::input(format!("codec {spec:?}: {k} = {v:?}, expected {want}"))
        };
        let level_given = kv.contains_key("level");
        let mut take = |k: &str| kv.remove(k);
        let level = match take("level") {
            None => 19,
            Some(v) => match v.parse::<i32>() {
                Ok(l) if (1..=22).contains(&l) => l,
                _ => return Err(bad("level", &v, "an integer in 1..=22")),
            },
        };
        let eps_rel = match take("eps") {
            None => DEFAULT_EPS_REL,
            Some(v) => match v.parse::<f64>() {
                Ok(e) if e.is_finite() && e > 0.0 => e,
                _ => {
                    return Err(bad(
                        "eps",
                        &v,
                        "a positive number (relative to the channel mean)",
                    ));
                }
            },
        };
        let curve = match take("curve").as_deref() {
            None | Some("log") => CurveRequest::Log { eps_rel },
            Some("signed-log") => CurveRequest::SignedLog { eps_rel },
            Some("linear") => CurveRequest::Linear,
            Some(v) => return Err(bad("curve", v, "log, signed-log or linear")),
        };
        let colour = match take("colour").as_deref() {
            None | Some("klt") => true,
            Some("none") => false,
            Some(v) => return Err(bad("colour", v, "klt or none")),
        };
        let weight = match take("weight").as_deref() {
            None | Some("none") => None,
            Some("cos" | "cosine") => Some(Weight::Cosine),
            Some(v) => return Err(bad("weight", v, "cosine (or cos) or none")),
        };
        // Parsed here for every codec, refused below for those without a lossy approximation
        // to follow (as any option that does not apply).
        let residual = match take("residual") {
            None => None,
            Some(v) if !matches!(name, "dct" | "tucker") => {
                return Err(Error::input(format!(
                    "codec {spec:?}: residual={v} applies to dct and tucker only (a quantized \
                     residual after their lossy approximation)"
                )));
            }
            Some(v) => match v.parse::<f64>() {
                Ok(s) if s.is_finite() && s > 0.0 => Some(s),
                _ => {
                    return Err(bad(
                        "residual",
                        &v,
                        "a positive step (in the transformed space)",
                    ));
                }
            },
        };
        if weight.is_some() && matches!(name, "zstd-f32" | "lossless") {
            return Err(Error::input(format!(
                "codec {spec:?}: weight applies to the lossy codecs (f16, uniform, dct, tucker) only: \
                 {name} keeps every sample bit for bit, so there is no error to weight"
            )));
        }
        let req = match name {
            "zstd-f32" => CodecRequest::ZstdF32 { level },
            "lossless" => {
                let predict = match take("predict").as_deref() {
                    None | Some("auto") => None,
                    Some(o) => {
                        let orders = o
                            .split('.')
                            .map(|x| match x.parse::<u8>() {
                                Ok(v) if v <= 2 => Ok(v),
                                _ => {
                                    Err(bad("predict", o, "auto or orders like 1.1.1 (each 0..=2)"))
                                }
                            })
                            .collect::<Result<Vec<u8>>>()?;
                        let space = match take("space").as_deref() {
                            None | Some("float") => predict::Space::Float,
                            Some("integer") => predict::Space::Integer,
                            Some(v) => return Err(bad("space", v, "float or integer")),
                        };
                        let cross_channel = match take("cross").as_deref() {
                            None | Some("on") => true,
                            Some("off") => false,
                            Some(v) => return Err(bad("cross", v, "on or off")),
                        };
                        Some(Predictor {
                            orders,
                            space,
                            cross_channel,
                        })
                    }
                };
                CodecRequest::Lossless { level, predict }
            }
            "f16" => CodecRequest::F16 {
                curve,
                weight,
                level,
            },
            "uniform" => {
                let bits = match take("bits") {
                    None => {
                        return Err(Error::input(format!(
                            "codec {spec:?}: uniform needs bits=K"
                        )));
                    }
                    Some(v) => match v.parse::<u32>() {
                        Ok(b) if (2..=24).contains(&b) => b,
                        _ => return Err(bad("bits", &v, "an integer in 2..=24")),
                    },
                };
                CodecRequest::Uniform {
                    curve,
                    weight,
                    bits,
                    colour,
                    level,
                }
            }
            "dct" => {
                let step = match take("step") {
                    None => return Err(Error::input(format!("codec {spec:?}: dct needs step=S"))),
                    Some(v) => match v.parse::<f64>() {
                        Ok(s) if s.is_finite() && s > 0.0 => s,
                        _ => return Err(bad("step", &v, "a positive number")),
                    },
                };
                let coding = match take("coding").as_deref() {
                    None | Some("context") => {
                        if level_given {
                            return Err(Error::input(format!(
                                "codec {spec:?}: level applies to dct with coding=zstd only"
                            )));
                        }
                        let (lo, hi) = coefcode::DEADZONE_RANGE;
                        let deadzone = match take("deadzone") {
                            None => coefcode::DEFAULT_DEADZONE,
                            Some(v) => match v.parse::<f64>() {
                                Ok(d) if (lo..=hi).contains(&d) => d,
                                _ => {
                                    return Err(bad(
                                        "deadzone",
                                        &v,
                                        &format!("a number of steps in {lo}..={hi}"),
                                    ));
                                }
                            },
                        };
                        let refine = match take("refine") {
                            None => 0,
                            Some(v) => match v.parse::<u32>() {
                                Ok(n) if n <= domain::MAX_REFINE => n,
                                _ => {
                                    return Err(bad(
                                        "refine",
                                        &v,
                                        &format!("an integer in 0..={}", domain::MAX_REFINE),
                                    ));
                                }
                            },
                        };
                        DctCoding::Context { deadzone, refine }
                    }
                    Some("zstd") => {
                        for k in ["deadzone", "refine"] {
                            if take(k).is_some() {
                                return Err(Error::input(format!(
                                    "codec {spec:?}: {k} applies to dct with coding=context only"
                                )));
                            }
                        }
                        DctCoding::Zstd { level }
                    }
                    Some(v) => return Err(bad("coding", v, "context or zstd")),
                };
                CodecRequest::Dct {
                    curve,
                    weight,
                    step,
                    colour,
                    coding,
                    residual,
                }
            }
            "tucker" => {
                let ranks = match take("ranks") {
                    None => {
                        return Err(Error::input(format!(
                            "codec {spec:?}: tucker needs ranks=R1xR2x... (one per grid axis)"
                        )));
                    }
                    Some(v) => v
                        .split('x')
                        .map(|r| match r.trim().parse::<usize>() {
                            Ok(r) if r >= 1 => Ok(r),
                            _ => Err(bad("ranks", &v, "positive integers like 8x8x16")),
                        })
                        .collect::<Result<Vec<usize>>>()?,
                };
                let step = match take("step") {
                    None => DEFAULT_TUCKER_STEP,
                    Some(v) => match v.parse::<f64>() {
                        Ok(s) if s.is_finite() && s > 0.0 => s,
                        _ => return Err(bad("step", &v, "a positive number")),
                    },
                };
                let (lo, hi) = tucker::FACTOR_STEP_RANGE;
                let factor_step = match take("factor") {
                    None => 1.0,
                    Some(v) => match v.parse::<f64>() {
                        Ok(s) if (lo..=hi).contains(&s) => s,
                        _ => return Err(bad("factor", &v, &format!("a number in {lo}..={hi}"))),
                    },
                };
                CodecRequest::Tucker {
                    curve,
                    weight,
                    ranks,
                    step,
                    factor_step,
                    colour,
                    level,
                    residual,
                }
            }
            _ => {
                return Err(Error::input(format!(
                    "codec {spec:?}: unknown codec {name:?} (expected zstd-f32, lossless, f16, \
                     uniform, dct or tucker)"
                )));
            }
        };
        if let Some(k) = kv.keys().next() {
            return Err(Error::input(format!(
                "codec {spec:?}: option {k:?} does not apply to {name}"
            )));
        }
        Ok(req)
    }

    /// The full spec for `table`: ε from the channel means, the colour matrix from the
    /// channels' covariance, the predictors by trial, steps from ranges.
    pub fn resolve(&self, table: &Table) -> Result<CodecSpec> {
        self.resolve_stages(table)?
            .with_best_residual_predictor(table)
    }

    fn resolve_stages(&self, table: &Table) -> Result<CodecSpec> {
        let c = table.channels().len();
        let d = table.grid().axes().len();
        let shape_dims = table.grid().shape();
        let shape = Shape {
            dims: &shape_dims,
            valid: table.valid(),
            channels: c,
        };
        Ok(match self {
            CodecRequest::ZstdF32 { level } => CodecSpec::ZstdF32 { level: *level },
            CodecRequest::Lossless { level, predict } => {
                let predict = match predict {
                    Some(p) => p.clone(),
                    None => best_predictor(table.data(), &shape, d)?,
                };
                CodecSpec::Lossless {
                    domain: Domain::DropInvalid,
                    predict,
                    entropy: Zstd { level: *level },
                }
            }
            CodecRequest::F16 {
                curve,
                weight,
                level,
            } => {
                let transform = Transform {
                    curve: curve_for(table, *curve, *weight),
                    colour: None,
                    weight: *weight,
                };
                let z = transform.forward_all(table.data(), c, table.grid(), table.valid());
                let max_abs =
                    valid_values(&z, table.valid(), c).fold(0.0f64, |m, v| m.max(v.abs()));
                CodecSpec::Quantized {
                    domain: Domain::DropInvalid,
                    transform,
                    quantize: Quantizer::f16_for(max_abs),
                    predict: Predictor {
                        orders: vec![1; d],
                        space: predict::Space::Integer,
                        cross_channel: c > 1,
                    },
                    entropy: Zstd { level: *level },
                }
            }
            CodecRequest::Uniform {
                curve,
                weight,
                bits,
                colour,
                level,
            } => {
                let transform = transform_for(table, *curve, *colour, *weight);
                let z = transform.forward_all(table.data(), c, table.grid(), table.valid());
                let (lo, hi): (Vec<f64>, Vec<f64>) = (0..c)
                    .map(|k| {
                        let (lo, hi) = z
                            .chunks_exact(c)
                            .zip(table.valid())
                            .filter(|(_, ok)| **ok)
                            .fold((f64::MAX, f64::MIN), |(lo, hi), (v, _)| {
                                (lo.min(v[k]), hi.max(v[k]))
                            });
                        // No valid cell: an empty range at 0.
                        if hi >= lo { (lo, hi) } else { (0.0, 0.0) }
                    })
                    .unzip();
                CodecSpec::Quantized {
                    domain: Domain::DropInvalid,
                    transform,
                    quantize: Quantizer::bits_for(*bits, &lo, &hi)?,
                    predict: Predictor {
                        orders: vec![1; d],
                        space: predict::Space::Integer,
                        cross_channel: false,
                    },
                    entropy: Zstd { level: *level },
                }
            }
            CodecRequest::Dct {
                curve,
                weight,
                step,
                colour,
                coding,
                residual,
            } => {
                let transform = transform_for(table, *curve, *colour, *weight);
                let dct = dct::DctStage {
                    step: vec![*step; c],
                };
                // The residual's zstd level: the chain's, 19 with context coding (no level).
                let residual = residual
                    .map(|s| residual::ResidualStage::new(s, c, d, self.level().unwrap_or(19)));
                match *coding {
                    DctCoding::Zstd { level } => CodecSpec::Dct {
                        domain: Domain::FillInvalid,
                        transform,
                        dct,
                        entropy: Zstd { level },
                        residual,
                    },
                    DctCoding::Context { deadzone, refine } => CodecSpec::DctContext {
                        domain: if refine > 0 {
                            Domain::FillRefined { iterations: refine }
                        } else {
                            Domain::FillInvalid
                        },
                        transform,
                        dct,
                        coding: coefcode::ContextCoding::new(deadzone),
                        residual,
                    },
                }
            }
            CodecRequest::Tucker {
                curve,
                weight,
                ranks,
                step,
                factor_step,
                colour,
                level,
                residual,
            } => {
                let stage = tucker::TuckerStage {
                    ranks: ranks.clone(),
                    step: vec![*step; c],
                    factor_step: *factor_step,
                };
                stage
                    .validate(&shape_dims, c)
                    .map_err(|e| Error::input(format!("codec {self}: grid {shape_dims:?}: {e}")))?;
                CodecSpec::Tucker {
                    domain: Domain::FillInvalid,
                    transform: transform_for(table, *curve, *colour, *weight),
                    tucker: stage,
                    entropy: Zstd { level: *level },
                    residual: residual.map(|s| residual::ResidualStage::new(s, c, d, *level)),
                }
            }
        })
    }
}

fn valid_values<'a>(z: &'a [f64], valid: &'a [bool], c: usize) -> impl Iterator<Item = f64> + 'a {
    z.chunks_exact(c)
        .zip(valid)
        .filter(|(_, ok)| **ok)
        .flat_map(|(v, _)| v.iter().copied())
}

/// The curve for a table: ε_c = eps_rel × the channel's mean over valid cells (falling back
/// to the pooled mean, then 1e-6, so that ε is never 0 for a black channel). With a weight,
/// the mean is that of w·x, the quantity the curve is applied to: ε keeps its meaning (the
/// level below which the coded quantity needs no relative precision).
pub fn curve_for(table: &Table, req: CurveRequest, weight: Option<Weight>) -> Curve {
    match req {
        CurveRequest::Linear => Curve::Linear,
        CurveRequest::Log { eps_rel } | CurveRequest::SignedLog { eps_rel } => {
            let signed = matches!(req, CurveRequest::SignedLog { .. });
            let c = table.channels().len();
            let w = weight.map(|w| w.cells(table.grid(), table.valid()));
            let mut sum = vec![0.0f64; c];
            let mut n = 0usize;
            for (cell, &ok) in table.valid().iter().enumerate() {
                if ok {
                    n += 1;
                    let wf = w.as_ref().map_or(1.0, |w| w[cell]);
                    for (k, s) in sum.iter_mut().enumerate() {
                        let x = table.data()[cell * c + k];
                        *s += wf * if signed { x.abs() } else { x.max(0.0) } as f64;
                    }
                }
            }
            let pooled = sum.iter().sum::<f64>() / (n.max(1) * c) as f64;
            let eps = sum
                .iter()
                .map(|s| {
                    let m = s / n.max(1) as f64;
                    let e = eps_rel * if m > 0.0 { m } else { pooled };
                    if e > 0.0 && e.is_finite() { e } else { 1e-6 }
                })
                .collect();
            if signed {
                Curve::SignedLog { eps }
            } else {
                Curve::Log { eps }
            }
        }
    }
}

/// Weight and curve plus (for several channels) the KLT of the weighted, curved channels.
pub fn transform_for(
    table: &Table,
    req: CurveRequest,
    colour: bool,
    weight: Option<Weight>,
) -> Transform {
    transform_with_curve(table, curve_for(table, req, weight), colour, weight)
}

/// Weight and a given curve plus (for several channels, when `colour`) the KLT of the
/// weighted, curved channels: the planner derives ε itself ([`crate::plan::rate`]).
pub fn transform_with_curve(
    table: &Table,
    curve: Curve,
    colour: bool,
    weight: Option<Weight>,
) -> Transform {
    let c = table.channels().len();
    let colour = if colour && c > 1 {
        let t = Transform {
            curve: curve.clone(),
            colour: None,
            weight,
        };
        let valid = table.valid();
        let mut samples = Vec::with_capacity(table.valid_count() * c);
        t.for_each_cell(table.data(), c, table.grid(), valid, |f, z| {
            if valid[f] {
                samples.extend_from_slice(z);
            }
        });
        Some(Colour::klt(&samples, c))
    } else {
        None
    };
    Transform {
        curve,
        colour,
        weight,
    }
}

/// The predictor with the smallest estimated coded size (order-0 entropy of the residual byte
/// planes) among [`predict::candidates`].
pub fn best_predictor(data: &[f32], shape: &Shape, d: usize) -> Result<Predictor> {
    let mut best: Option<(f64, Predictor)> = None;
    for p in predict::candidates(d, shape.channels) {
        let r = p.residuals_f32(data, shape)?;
        let bits = predict::plane_entropy_bits(&r);
        if best.as_ref().is_none_or(|(b, _)| bits < *b) {
            best = Some((bits, p));
        }
    }
    best.map(|(_, p)| p)
        .ok_or_else(|| Error::Failure("no predictor candidates".into()))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::brdf::Channels;
    use crate::grid::parse_grid_spec;
    use crate::table::Provenance;

    fn small_table() -> Table {
        let g = parse_grid_spec("halfdiff3:8x8x12").unwrap();
        let valid = g.geometric_mask();
        let n = g.cells();
        let data: Vec<f32> = (0..n * 3)
            .map(|i| {
                let f = i / 3;
                let (a, b, cc) = (f / 96, f / 12 % 8, f % 12);
                (0.1 + (a as f32 * 0.3).exp() * (1.0 + 0.1 * b as f32) + 0.01 * cc as f32)
                    * (1.0 + 0.2 * (i % 3) as f32)
            })
            .collect();
        Table::new(
            g,
            Channels::default_for(3),
            Provenance::default(),
            data,
            valid,
        )
        .unwrap()
    }

    #[test]
    fn a_reused_scratch_does_not_change_the_output() {
        // One scratch through tables of different sizes and specs (larger, then smaller, then
        // larger again): the arrays it hands out hold the previous decode's values, and none
        // may leak into the next.
        let small = small_table();
        let big = crate::tabulate::tabulate(
            &crate::testing::GgxConductor::new(0.3),
            &parse_grid_spec("halfdiff3:16x12x24").unwrap(),
            &crate::tabulate::TabulateOptions::default(),
        )
        .unwrap();
        let mut scratch = DecodeScratch::default();
        for (t, req) in [
            (&big, "dct:step=0.05"),
            (&small, "dct:step=0.05"),
            (&small, "dct:step=0.01,coding=zstd,level=3"),
            (&big, "dct:step=0.2,colour=none"),
            (&big, "dct:step=0.05"),
        ] {
            let spec = CodecRequest::parse(req).unwrap().resolve(t).unwrap();
            let payload = spec.encode(t).unwrap();
            let layout = Layout::of(t);
            let want = spec.decode(&payload, &layout).unwrap();
            let mut buf = vec![f32::NAN; want.len()];
            spec.decode_into_with(&payload, &layout, &mut buf, &mut scratch)
                .unwrap();
            assert!(
                buf.iter()
                    .zip(&want)
                    .all(|(a, b)| a.to_bits() == b.to_bits()),
                "{req} on {:?}",
                t.grid().shape()
            );
        }
    }

    #[test]
    fn decode_into_a_dirty_buffer_equals_decode() {
        // Every value must be written: a reused buffer full of NaN must not leak into the
        // result (invalid cells included).
        let t = small_table();
        assert!(t.valid().iter().any(|v| !v), "the grid has invalid cells");
        for req in [
            "zstd-f32",
            "lossless",
            "f16",
            "uniform:bits=10",
            "dct:step=0.05,coding=zstd,level=3",
            "dct:step=0.05",
            "dct:step=0.05,colour=none,curve=linear",
            "dct:step=0.05,residual=0.01",
            "dct:step=0.05,coding=zstd,residual=0.01",
            "tucker:ranks=4x4x6,residual=0.01",
        ] {
            let spec = CodecRequest::parse(req).unwrap().resolve(&t).unwrap();
            let payload = spec.encode(&t).unwrap();
            let layout = Layout::of(&t);
            let want = spec.decode(&payload, &layout).unwrap();
            let mut buf = vec![f32::NAN; want.len()];
            spec.decode_into(&payload, &layout, &mut buf).unwrap();
            assert_eq!(
                buf.iter().map(|v| v.to_bits()).collect::<Vec<_>>(),
                want.iter().map(|v| v.to_bits()).collect::<Vec<_>>(),
                "{req}"
            );
            let mut short = vec![0f32; want.len() - 1];
            assert!(spec.decode_into(&payload, &layout, &mut short).is_err());
        }
    }

    #[test]
    fn every_requested_codec_round_trips_through_its_header() {
        let t = small_table();
        for s in [
            "zstd-f32",
            "lossless",
            "lossless:predict=0.0.1,space=integer,cross=off,level=3",
            "f16",
            "f16:curve=linear",
            "uniform:bits=12",
            "uniform:bits=8,curve=linear,colour=none",
            "dct:step=0.001",
            "dct:step=0.01,curve=linear,colour=none",
            "dct:step=0.001,coding=zstd",
            "dct:step=0.01,coding=zstd,level=3,colour=none",
            "dct:step=0.002,deadzone=1.5,refine=3",
            "dct:step=0.01,coding=context,curve=linear,refine=1",
            "f16:weight=cosine",
            "uniform:bits=12,weight=cos",
            "dct:step=0.001,weight=cosine",
            "dct:step=0.001,weight=cosine,coding=zstd",
            "tucker:ranks=4x4x6,step=0.001",
            "tucker:ranks=8x8x12,step=0.01,curve=linear,colour=none,level=3",
            // Full rank: w·x is not as low-rank as x, so a truncation would say nothing of w.
            "tucker:ranks=8x8x12,step=0.001,weight=cosine",
            "dct:step=0.5,residual=0.01",
            "dct:step=0.5,coding=zstd,level=3,residual=0.02,curve=linear",
            "tucker:ranks=2x2x3,step=0.5,residual=0.01,colour=none",
            "dct:step=0.5,residual=0.005,weight=cosine",
        ] {
            let spec = CodecRequest::parse(s).unwrap().resolve(&t).unwrap();
            let json = serde_json::to_string(&spec).unwrap();
            assert_eq!(
                json.contains(r#""curve":"cosine_"#),
                s.contains("weight"),
                "{s}"
            );
            let back: CodecSpec = serde_json::from_str(&json).unwrap();
            assert_eq!(back, spec, "{s}");
            let payload = spec.encode(&t).unwrap();
            let dec = back.decode(&payload, &Layout::of(&t)).unwrap();
            assert_eq!(dec.len(), t.data().len());
            for (cell, &ok) in t.valid().iter().enumerate() {
                for k in 0..3 {
                    let (a, b) = (dec[cell * 3 + k], t.data()[cell * 3 + k]);
                    if !ok {
                        assert_eq!(a, 0.0, "{s}: invalid cell {cell} decodes to {a}");
                    } else if spec.is_lossless() {
                        assert_eq!(a.to_bits(), b.to_bits(), "{s}");
                    } else {
                        // Coarsest settings above: within 5% (uniform 8-bit linear on a
                        // range of ~15 is ±0.03 absolute). The weighted ones are fine
                        // settings of the log curve, whose errors stay relative down to ε/w.
                        assert!((a - b).abs() <= 0.05 * b + 0.04, "{s}: {a} vs {b}");
                    }
                }
            }
        }
    }

    /// Decoded values of the fast decoders against `reference::decode`: bit for bit where
    /// the chain is lossless, or quantized with the linear curve (no `exp`, same f64 maths);
    /// else within 5e-5 relative to ε + x, i.e. a log-space error of 5e-5: the DCT's f32 sums
    /// run in another order (rounding ≲ box terms × 2⁻²⁴ × the largest partial sum) and `exp`
    /// is ≤ 1 ulp. That is 6× below the quantization noise of the finest step tested
    /// (step/√12 = 2.9e-4 at step 1e-3).
    fn assert_matches_reference(t: &Table, spec: &CodecSpec, what: &str) {
        let layout = Layout::of(t);
        let payload = spec.encode(t).unwrap();
        let fast = spec.decode(&payload, &layout).unwrap();
        let slow = reference::decode(spec, &payload, &layout).unwrap();
        assert_eq!(fast.len(), slow.len());
        let exact = spec.is_lossless();
        let curve = spec.transform().map(|t| &t.curve);
        let weights = spec
            .transform()
            .and_then(|t| t.cell_weights(layout.grid, layout.valid));
        let c = layout.channels;
        let scale = slow.iter().enumerate().fold(0f32, |m, (i, b)| {
            m.max(b.abs() * weights.as_ref().map_or(1.0, |w| w[i / c]) as f32)
        });
        for (i, (a, b)) in fast.iter().zip(&slow).enumerate() {
            // ε is in the units of the coded quantity w·x: ε/w in those of x.
            let w = weights.as_ref().map_or(1.0, |w| w[i / c]) as f32;
            let eps = match curve {
                Some(Curve::Log { eps } | Curve::SignedLog { eps }) => eps[i % c] as f32 / w,
                _ => 0.0,
            };
            let linear_quantized =
                matches!(curve, Some(Curve::Linear)) && matches!(spec, CodecSpec::Quantized { .. });
            if exact || (linear_quantized && weights.is_none()) {
                assert_eq!(a.to_bits(), b.to_bits(), "{what}: value {i}: {a} vs {b}");
            } else if linear_quantized {
                // 1/w: an f32 multiply by the rounded reciprocal against an f64 division,
                // after the f32 rounding of the dequantized value: ≤ 3 roundings of 2⁻²⁴.
                assert!(
                    (a - b).abs() <= 2e-7 * b.abs() + f32::MIN_POSITIVE,
                    "{what}: value {i}: {a} vs {b} (w {w})"
                );
            } else if weights.is_some() && matches!(curve, Some(Curve::Linear)) {
                // The DCT's f32 rounding is relative to the plane's largest values (as in
                // idct's tests, 1e-5 of the largest |w·x|), not to a small w·x at a grazing
                // cell; ÷ w in the units of x.
                assert!(
                    (a - b).abs() <= 5e-5 * b.abs() + 1e-5 * scale / w + f32::MIN_POSITIVE,
                    "{what}: value {i}: {a} vs {b} (w {w}, largest w·x {scale})"
                );
            } else {
                assert!(
                    (a - b).abs() <= 5e-5 * (b.abs() + eps) + f32::MIN_POSITIVE,
                    "{what}: value {i}: {a} vs {b} (ε {eps})"
                );
            }
        }
    }

    #[test]
    fn fast_decoders_match_the_reference_decoder() {
        let t = small_table();
        for s in [
            "zstd-f32",
            "lossless",
            "lossless:predict=1.1.2,space=float,cross=on",
            "lossless:predict=0.0.1,space=integer,cross=off",
            "f16",
            "f16:curve=linear",
            "uniform:bits=12",
            "uniform:bits=10,curve=linear",
            "uniform:bits=10,curve=linear,colour=none",
            "dct:step=0.001",
            "dct:step=0.05",
            "dct:step=0.01,curve=linear,colour=none",
            "f16:weight=cosine",
            "f16:curve=linear,weight=cosine",
            "uniform:bits=12,weight=cosine",
            "uniform:bits=10,curve=linear,weight=cosine",
            "uniform:bits=10,curve=linear,colour=none,weight=cosine",
            "dct:step=0.001,weight=cosine",
            "dct:step=0.01,curve=linear,colour=none,weight=cosine,coding=zstd",
            "tucker:ranks=4x4x6,step=0.001",
            "tucker:ranks=8x8x12,step=0.05,curve=linear,colour=none",
            "dct:step=0.3,residual=0.003",
            "dct:step=0.3,coding=zstd,residual=0.003,weight=cosine",
            "dct:step=0.05,curve=linear,colour=none,residual=0.01",
            "tucker:ranks=2x2x3,step=0.3,residual=0.003",
        ] {
            let spec = CodecRequest::parse(s).unwrap().resolve(&t).unwrap();
            assert_matches_reference(&t, &spec, s);
        }
    }

    /// [`small_table`] shifted down so that about a fifth of its valid values are negative,
    /// as in a measured fit to noisy data.
    fn signed_table() -> Table {
        let t = small_table();
        let data: Vec<f32> = t
            .data()
            .iter()
            .enumerate()
            .map(|(i, &v)| v - 2.5 + 0.3 * ((i * 7919 % 13) as f32 / 13.0))
            .collect();
        let valid = t.valid().to_vec();
        Table::new(
            t.grid().clone(),
            t.channels().clone(),
            t.provenance().clone(),
            data,
            valid,
        )
        .unwrap()
    }

    #[test]
    fn the_signed_log_curve_keeps_negative_values() {
        let t = signed_table();
        let values: Vec<f32> = t
            .data()
            .chunks_exact(3)
            .zip(t.valid())
            .filter(|(_, ok)| **ok)
            .flat_map(|(v, _)| v.iter().copied())
            .collect();
        let negative = values.iter().filter(|&&v| v < 0.0).count();
        assert!(
            negative * 10 > values.len() && negative * 2 < values.len(),
            "{negative} of {} negative",
            values.len()
        );
        // Channel 0's mean |x| over valid cells: its ε is 1e-3 of that.
        let ch0: Vec<f64> = values.iter().step_by(3).map(|v| v.abs() as f64).collect();
        let mean_abs = ch0.iter().sum::<f64>() / ch0.len() as f64;
        for s in [
            "f16:curve=signed-log",
            "uniform:bits=12,curve=signed-log",
            "dct:step=0.002,curve=signed-log",
            "dct:step=0.002,curve=signed-log,coding=zstd,colour=none",
            "dct:step=0.002,curve=signed-log,weight=cosine",
            "tucker:ranks=8x8x12,step=0.002,curve=signed-log",
            "dct:step=0.3,curve=signed-log,residual=0.003",
        ] {
            let spec = CodecRequest::parse(s).unwrap().resolve(&t).unwrap();
            let json = serde_json::to_string(&spec).unwrap();
            assert!(json.contains("signed_log"), "{s}: {json}");
            let back: CodecSpec = serde_json::from_str(&json).unwrap();
            assert_eq!(back, spec, "{s}");
            let text = CodecRequest::parse(s).unwrap().to_string();
            assert!(text.contains("curve=signed-log"), "{s}: {text}");
            let tr = spec.transform().unwrap();
            let eps = tr.curve.eps().unwrap()[0];
            // The curve's ε is in the units of w·x: ε/w in those of x.
            let w = tr.cell_weights(t.grid(), t.valid());
            if w.is_none() {
                // ε relative to the mean |x| (the default 1e-3), not to the mean x.
                assert!((eps / (1e-3 * mean_abs) - 1.0).abs() < 1e-6, "{s}: ε {eps}");
            }
            let payload = spec.encode(&t).unwrap();
            let dec = back.decode(&payload, &Layout::of(&t)).unwrap();
            let mut worst = 0f64;
            for (cell, &ok) in t.valid().iter().enumerate() {
                for k in 0..3 {
                    let (a, b) = (dec[cell * 3 + k] as f64, t.data()[cell * 3 + k] as f64);
                    if !ok {
                        assert_eq!(a, 0.0, "{s}: invalid cell {cell}");
                        continue;
                    }
                    // Relative to |x| + ε on both sides of 0: the steps above are fine ones.
                    let eps = eps / w.as_ref().map_or(1.0, |w| w[cell]);
                    let rel = (a - b).abs() / (b.abs() + eps);
                    worst = worst.max(rel);
                    assert!(rel <= 0.05, "{s}: cell {cell}: {a} vs {b} (ε {eps})");
                    if b.abs() > 10.0 * eps {
                        assert_eq!(a < 0.0, b < 0.0, "{s}: cell {cell}: {a} vs {b}");
                    }
                }
            }
            assert_matches_reference(&t, &spec, s);
            eprintln!("{s}: worst relative error {worst:.2e}");
        }
        // The log curve clamps them at 0: a relative error of 1 at every negative value.
        let spec = CodecRequest::parse("dct:step=0.002")
            .unwrap()
            .resolve(&t)
            .unwrap();
        let dec = spec
            .decode(&spec.encode(&t).unwrap(), &Layout::of(&t))
            .unwrap();
        assert!(dec.iter().all(|&v| v >= 0.0));
    }

    /// A random `halfdiff3:a×b×cc` table (1 or 3 channels): 5% zeros, the rest spread over
    /// 18 e-folds, below-horizon cells invalid.
    fn random_table(a: usize, b: usize, cc: usize, three: bool, seed: u64) -> Table {
        let g = parse_grid_spec(&format!("halfdiff3:{a}x{b}x{cc}")).unwrap();
        let valid = g.geometric_mask();
        let c = if three { 3 } else { 1 };
        let mut rng = crate::math::SplitMix64::new(seed);
        let data: Vec<f32> = (0..g.cells() * c)
            .map(|_| {
                let u = rng.next_f64();
                if u < 0.05 {
                    0.0
                } else {
                    (u * 18.0 - 9.0).exp() as f32
                }
            })
            .collect();
        Table::new(
            g,
            Channels::default_for(c),
            Provenance::default(),
            data,
            valid,
        )
        .unwrap()
    }

    proptest::proptest! {
        #![proptest_config(proptest::prelude::ProptestConfig::with_cases(24))]
        /// Random tables (grid sizes, 1 or 3 channels, magnitudes over 8 decades, zeros):
        /// every chain decodes like the reference.
        #[test]
        fn random_tables_decode_like_the_reference(
            a in 2usize..9, b in 2usize..9, cc in 2usize..13, three in proptest::bool::ANY,
            seed in proptest::prelude::any::<u64>(), which in 0usize..12,
        ) {
            let t = random_table(a, b, cc, three, seed);
            let s = [
                "lossless", "f16", "uniform:bits=14", "dct:step=0.003", "dct:step=0.1",
                "f16:weight=cosine", "uniform:bits=14,weight=cosine",
                "dct:step=0.003,weight=cosine",
                "tucker:ranks=2x2x2,step=0.003", "tucker:ranks=2x2x2,step=0.1,factor=4",
                "dct:step=0.3,residual=0.003", "tucker:ranks=1x1x1,step=0.3,residual=0.01",
            ][which];
            let spec = CodecRequest::parse(s).unwrap().resolve(&t).unwrap();
            assert_matches_reference(&t, &spec, s);
        }
    }

    #[test]
    fn uniform_meets_its_stated_max_error() {
        let t = small_table();
        let spec = CodecRequest::parse("uniform:bits=10")
            .unwrap()
            .resolve(&t)
            .unwrap();
        let bound = spec.max_transformed_error().unwrap();
        let dec = spec
            .decode(&spec.encode(&t).unwrap(), &Layout::of(&t))
            .unwrap();
        let CodecSpec::Quantized { transform, .. } = &spec else {
            panic!()
        };
        for (cell, &ok) in t.valid().iter().enumerate() {
            if ok {
                for k in 0..3 {
                    let a = transform.curve.forward(dec[cell * 3 + k] as f64, k);
                    let b = transform.curve.forward(t.data()[cell * 3 + k] as f64, k);
                    // f32 storage of the decoded value adds ~1e-7 relative.
                    assert!((a - b).abs() <= bound + 1e-6, "{a} {b} {bound}");
                }
            }
        }
    }

    /// The largest error of a decoded table against its source, per channel in the curve
    /// space y = curve(w·x) (the space `max_transformed_error` speaks of), relative to the
    /// stated bound plus the decoder's f32 rounding: the plane value and the sum Mᵀz in f32,
    /// `exp_f32` (1 ulp) and the f32 x, × 1/w in f32. Each is a few 2⁻²⁴ of |y| or of the
    /// cell's ‖z‖; 5e-7 × (2 + |y| + ‖z‖) covers them with a margin of about 2. The clamp at
    /// x ≥ 0 only moves a decoded y towards the true one (y ≥ ln ε, resp. ≥ 0), never away.
    /// Returns the largest error / bound over valid cells (invalid cells must decode to 0).
    fn residual_error_ratio(t: &Table, spec: &CodecSpec, what: &str) -> f64 {
        let c = t.channels().len();
        let bound = spec.max_transformed_error().unwrap();
        let tr = spec.transform().unwrap();
        let dec = spec
            .decode(&spec.encode(t).unwrap(), &Layout::of(t))
            .unwrap();
        let curve_only = Transform {
            colour: None,
            ..tr.clone()
        };
        let ya = curve_only.forward_all(&dec, c, t.grid(), t.valid());
        let yb = curve_only.forward_all(t.data(), c, t.grid(), t.valid());
        let zb = tr.forward_all(t.data(), c, t.grid(), t.valid());
        let mut worst = 0f64;
        for (f, &ok) in t.valid().iter().enumerate() {
            let cell = f * c..(f + 1) * c;
            if !ok {
                assert!(
                    dec[cell].iter().all(|&v| v == 0.0),
                    "{what}: invalid cell {f}"
                );
                continue;
            }
            let norm = zb[cell.clone()].iter().map(|v| v * v).sum::<f64>().sqrt();
            for i in cell {
                assert!(dec[i].is_finite() && dec[i] >= 0.0, "{what}: value {i}");
                let err = (ya[i] - yb[i]).abs();
                let tol = bound * (1.0 + 1e-12) + 5e-7 * (2.0 + yb[i].abs() + norm);
                assert!(
                    err <= tol,
                    "{what}: value {i}: y {} decoded {} (error {err:e}, bound {bound:e})",
                    yb[i],
                    ya[i]
                );
                worst = worst.max(err / bound);
            }
        }
        worst
    }

    proptest::proptest! {
        #![proptest_config(proptest::prelude::ProptestConfig::with_cases(32))]
        /// Random tables (grid sizes, 1 or 3 channels, magnitudes over 8 decades, zeros),
        /// random residual steps, every chain that takes a residual, both curves, with and
        /// without colour and weight: every decoded valid value within the stated
        /// `max_transformed_error` (Σ_i |M_ik| S/2 per channel, S/2 without colour) plus the
        /// f32 rounding of [`residual_error_ratio`].
        #[test]
        fn residual_chains_meet_their_stated_bound_on_random_tables(
            a in 2usize..9, b in 2usize..9, cc in 2usize..13, three in proptest::bool::ANY,
            seed in proptest::prelude::any::<u64>(), which in 0usize..6,
            log_s in -3.0f64..-0.5, lossy_step in 0.05f64..2.0,
        ) {
            let t = random_table(a, b, cc, three, seed);
            let s = 10f64.powf(log_s);
            let req = [
                format!("dct:step={lossy_step},residual={s}"),
                format!("dct:step={lossy_step},coding=zstd,colour=none,residual={s}"),
                format!("dct:step={lossy_step},weight=cosine,residual={s}"),
                // Linear: values up to e^9 ≈ 8e3, the step scaled to that range.
                format!("dct:step={},curve=linear,residual={}", lossy_step * 100.0, s * 10.0),
                format!("tucker:ranks=2x1x2,step={lossy_step},residual={s}"),
                format!("tucker:ranks=1x2x2,step={lossy_step},colour=none,curve=linear,residual={}", s * 10.0),
            ][which].clone();
            let spec = CodecRequest::parse(&req).unwrap().resolve(&t).unwrap();
            residual_error_ratio(&t, &spec, &req);
        }
    }

    /// The bound is tight, not vacuous: on a table with many cells the largest error comes
    /// close to S/2 without colour (and to a good part of Σ|M_ik| S/2 with it), while the DCT
    /// alone at that step is far outside it.
    #[test]
    fn residual_bound_is_reached_and_the_dct_alone_misses_it() {
        let t = ggx_on("halfdiff3:12x10x16");
        for (s, at_least) in [
            ("dct:step=0.5,colour=none,residual=0.01", 0.9),
            ("dct:step=0.5,residual=0.01", 0.5),
            ("dct:step=0.5,coding=zstd,residual=0.002", 0.5),
            ("tucker:ranks=3x3x3,step=0.5,residual=0.01", 0.5),
        ] {
            let spec = CodecRequest::parse(s).unwrap().resolve(&t).unwrap();
            let r = residual_error_ratio(&t, &spec, s);
            assert!(r >= at_least && r <= 1.0 + 1e-6, "{s}: error/bound {r}");
        }
        // Without the residual the same DCT is off by far more than S/2 = 0.005 somewhere.
        let plain = CodecRequest::parse("dct:step=0.5")
            .unwrap()
            .resolve(&t)
            .unwrap();
        let dec = plain
            .decode(&plain.encode(&t).unwrap(), &Layout::of(&t))
            .unwrap();
        let tr = plain.transform().unwrap();
        let ya = tr.forward_all(&dec, 3, t.grid(), t.valid());
        let yb = tr.forward_all(t.data(), 3, t.grid(), t.valid());
        let worst = (0..t.grid().cells())
            .filter(|&f| t.valid()[f])
            .flat_map(|f| (0..3).map(move |k| f * 3 + k))
            .map(|i| (ya[i] - yb[i]).abs())
            .fold(0f64, f64::max);
        assert!(worst > 0.05, "{worst}");
    }

    /// A residual file cut anywhere, with its section length or steps edited, or decoded with
    /// the spec of the chain without the residual: an error, never a panic or a silent
    /// partial decode.
    #[test]
    fn hostile_residual_payloads_and_headers_are_errors() {
        let t = small_table();
        let layout = Layout::of(&t);
        for s in [
            "dct:step=0.1,residual=0.01",
            "dct:step=0.1,coding=zstd,residual=0.01",
            "tucker:ranks=4x4x6,step=0.1,residual=0.01",
        ] {
            let spec = CodecRequest::parse(s).unwrap().resolve(&t).unwrap();
            let payload = spec.encode(&t).unwrap();
            let (lossy, section) = residual::split(&payload).unwrap();
            assert!(!lossy.is_empty() && !section.is_empty(), "{s}");
            let mut cuts: Vec<usize> = (0..12).collect();
            cuts.extend([
                8 + lossy.len() - 1,
                8 + lossy.len(),
                8 + lossy.len() + 1,
                payload.len() / 2,
                payload.len() - 1,
            ]);
            for cut in cuts {
                let e = spec.decode(&payload[..cut], &layout);
                assert!(e.is_err(), "{s}: cut {cut} of {}", payload.len());
                assert!(reference::decode(&spec, &payload[..cut], &layout).is_err());
            }
            // The section length pointing past the end, or short by one byte.
            for len in [u64::MAX, payload.len() as u64, lossy.len() as u64 - 1] {
                let mut bad = payload.clone();
                bad[..8].copy_from_slice(&len.to_le_bytes());
                assert!(spec.decode(&bad, &layout).is_err(), "{s}: length {len}");
            }
            // Hostile residual stages in the header.
            let edits: [fn(&mut residual::ResidualStage); 4] = [
                |r| r.step = vec![0.01; 2],
                |r| r.step[1] = f64::NAN,
                |r| r.step[0] = -1.0,
                |r| r.predict.orders = vec![0, 0],
            ];
            for (i, edit) in edits.iter().enumerate() {
                let mut bad = spec.clone();
                edit(bad.residual_mut().expect("a residual spec"));
                let e = bad.decode(&payload, &layout).unwrap_err().to_string();
                assert!(e.contains("residual"), "{s} edit {i}: {e}");
                assert!(bad.encode(&t).is_err(), "{s} edit {i}");
            }
            // The plain chain given a residual payload (or the reverse) fails too.
            let mut plain = spec.clone();
            match &mut plain {
                CodecSpec::Dct { residual, .. }
                | CodecSpec::DctContext { residual, .. }
                | CodecSpec::Tucker { residual, .. } => *residual = None,
                _ => unreachable!(),
            }
            assert!(
                spec.decode(&plain.encode(&t).unwrap(), &layout).is_err(),
                "{s}"
            );
        }
        // A step too fine for the table: an error naming the step, not a wrap (at resolve,
        // which tries the residual predictors, and at encode).
        let req = CodecRequest::parse("dct:step=1,residual=1e-12").unwrap();
        let e = req.resolve(&t).unwrap_err().to_string();
        assert!(e.contains("residual step 1e-12 is too small"), "{e}");
        let mut spec = CodecRequest::parse("dct:step=1,residual=1")
            .unwrap()
            .resolve(&t)
            .unwrap();
        if let CodecSpec::DctContext {
            residual: Some(r), ..
        } = &mut spec
        {
            r.step = vec![1e-12; 3];
        }
        let e = spec.encode(&t).unwrap_err().to_string();
        assert!(e.contains("residual step 1e-12 is too small"), "{e}");
    }

    /// A GGX conductor (grazing Fresnel peaks) on `grid`, 3 channels.
    fn ggx_on(grid: &str) -> Table {
        let g = parse_grid_spec(grid).unwrap();
        crate::tabulate::tabulate(
            &crate::testing::GgxConductor::new(0.15),
            &g,
            &crate::tabulate::TabulateOptions::default(),
        )
        .unwrap()
    }

    /// Every grid kind (warps, placements, θmax), weighted chains: the decoded table meets the
    /// quantizer's promise in the weighted transformed space, z = M curve(w·x). Uniform: every
    /// valid component within step/2 (through the colour matrix: `max_transformed_error`); f16:
    /// within `max_error` of its magnitude; DCT (orthonormal, Parseval): Σ over valid
    /// components of Δz² ≤ Σ over all coefficients of their quantization error² ≤ cells ×
    /// (r·step)², r = ½ for rounding (zstd coding), the dead zone 0.75 for context coding.
    /// Each plus the f32 rounding of the decoded value (relative 2⁻²³ of w·x and of ε).
    #[test]
    fn weighted_chains_meet_their_bound_in_the_weighted_space_on_every_grid_kind() {
        for grid in [
            "halfdiff3:12x10x16,warp=sqrt/linear/linear,at=edge",
            "halfdiff4:8x6x8x10,warp=sqrt/linear/linear/linear",
            "spherical3:12x12x10,theta-max=85",
            "spherical4:8x6x8x6,at=edge",
        ] {
            let t = ggx_on(grid);
            let c = 3;
            for s in [
                "uniform:bits=12,weight=cosine",
                "uniform:bits=11,curve=linear,weight=cosine",
                "f16:weight=cosine",
                "f16:curve=linear,weight=cosine",
                "dct:step=0.02,weight=cosine",
                "dct:step=0.02,weight=cosine,coding=zstd",
                "dct:step=0.05,curve=linear,colour=none,weight=cosine",
            ] {
                let what = format!("{grid} {s}");
                let spec = CodecRequest::parse(s).unwrap().resolve(&t).unwrap();
                let tr = spec.transform().unwrap().clone();
                assert_eq!(tr.weight, Some(Weight::Cosine), "{what}");
                let dec = spec
                    .decode(&spec.encode(&t).unwrap(), &Layout::of(&t))
                    .unwrap();
                assert!(dec.iter().all(|v| v.is_finite() && *v >= 0.0), "{what}");
                let za = tr.forward_all(&dec, c, t.grid(), t.valid());
                let zb = tr.forward_all(t.data(), c, t.grid(), t.valid());
                let w = tr.cell_weights(t.grid(), t.valid()).unwrap();
                // f32 rounding in the decoder (of y = Mᵀz, |y| ≤ ‖z‖, before the inverse
                // curve; of the decoded x), seen in the transformed space: a few 2⁻²⁴.
                let norm = |f: usize| {
                    zb[f * c..f * c + c]
                        .iter()
                        .map(|v| v * v)
                        .sum::<f64>()
                        .sqrt()
                };
                let rounding = |f: usize, k: usize| match &tr.curve {
                    Curve::Linear => 4.8e-7 * (w[f] * t.data()[f * c + k].abs() as f64 + norm(f)),
                    Curve::Log { .. } | Curve::SignedLog { .. } => 2.4e-7 * (2.0 + norm(f)),
                };
                let valid = |f: &usize| t.valid()[*f];
                let cells = t.grid().cells();
                let mut max_ratio = 0f64;
                match &spec {
                    CodecSpec::Quantized { quantize, .. } => {
                        for f in (0..cells).filter(valid) {
                            // Component k of z is what was quantized, within max_error_k. The
                            // decoder's clamp (x ≥ 0, per channel after Mᵀ) projects onto a
                            // convex set holding the true value, so it can only shorten the
                            // error vector, but it may move it between components: bound the
                            // cell's Euclidean error (M is orthonormal).
                            let zs = f * c..f * c + c;
                            let err = za[zs.clone()]
                                .iter()
                                .zip(&zb[zs.clone()])
                                .map(|(a, b)| (a - b).powi(2))
                                .sum::<f64>()
                                .sqrt();
                            let bound = (0..c)
                                .map(|k| quantize.max_error(k, zb[f * c + k].abs()).powi(2))
                                .sum::<f64>()
                                .sqrt();
                            let r: f64 = (0..c).map(|j| rounding(f, j)).sum();
                            assert!(
                                err <= bound + r + 1e-12,
                                "{what}: cell {f} w {}: {:?} vs {:?} (bound {bound})",
                                w[f],
                                &za[zs.clone()],
                                &zb[zs]
                            );
                            max_ratio = max_ratio.max(err / bound);
                        }
                        // Not vacuous: some cell's error is a sizeable part of its bound.
                        assert!(max_ratio > 0.3, "{what}: largest error/bound {max_ratio}");
                    }
                    CodecSpec::Dct { dct, .. } | CodecSpec::DctContext { dct, .. } => {
                        let r = match &spec {
                            CodecSpec::Dct { .. } => 0.5,
                            _ => coefcode::DEFAULT_DEADZONE,
                        };
                        // z in component space: undo nothing, the colour matrix is orthonormal
                        // so Σ_k Δz_k² is the same before and after it.
                        let sse: f64 = (0..cells)
                            .filter(valid)
                            .flat_map(|f| (0..c).map(move |k| f * c + k))
                            .map(|i| (za[i] - zb[i]).powi(2))
                            .sum();
                        let fp: f64 = (0..cells)
                            .filter(valid)
                            .flat_map(|f| (0..c).map(move |k| (f, k)))
                            .map(|(f, k)| (rounding(f, k) + 2e-5).powi(2))
                            .sum();
                        let bound = (cells * c) as f64 * (r * dct.step[0]).powi(2);
                        assert!(
                            sse.sqrt() <= bound.sqrt() + fp.sqrt(),
                            "{what}: √SSE {} > √bound {}",
                            sse.sqrt(),
                            bound.sqrt()
                        );
                        // Not vacuous: the error is a sizeable part of the bound.
                        assert!(sse > 1e-4 * bound, "{what}: {sse} vs {bound}");
                    }
                    _ => unreachable!(),
                }
            }
        }
    }

    /// Cells at the weight floor (pairs below the horizon declared valid, as an explicit mask
    /// may) holding values up to f32::MAX, and 0: every weighted chain decodes them finite
    /// and ≥ 0, and invalid cells to 0.
    #[test]
    fn grazing_cells_decode_finite() {
        let g = parse_grid_spec("halfdiff3:6x6x8,at=edge").unwrap();
        let prod = g.cos_products();
        let mut valid = g.geometric_mask();
        // Below-horizon cells become valid, except every third (kept invalid).
        for (f, v) in valid.iter_mut().enumerate() {
            if prod[f] == 0.0 && f % 3 != 0 {
                *v = true;
            }
        }
        assert!(valid.iter().zip(&prod).any(|(&ok, &p)| ok && p == 0.0));
        let data: Vec<f32> = (0..g.cells() * 3)
            .map(|i| match (i / 3) % 4 {
                0 => f32::MAX,
                1 => 0.0,
                2 => 1e30,
                _ => 0.5,
            })
            .collect();
        let t = Table::new(
            g,
            Channels::default_for(3),
            Provenance::default(),
            data,
            valid.clone(),
        )
        .unwrap();
        for s in [
            "f16:curve=linear,weight=cosine",
            "f16:weight=cosine",
            "uniform:bits=16,curve=linear,weight=cosine",
            "uniform:bits=16,weight=cosine",
            "dct:step=0.01,weight=cosine",
            "dct:step=0.01,weight=cosine,coding=zstd",
            "dct:step=0.01,weight=cosine,residual=0.001",
        ] {
            let spec = CodecRequest::parse(s).unwrap().resolve(&t).unwrap();
            let layout = Layout::of(&t);
            let payload = spec.encode(&t).unwrap();
            for dec in [
                spec.decode(&payload, &layout).unwrap(),
                reference::decode(&spec, &payload, &layout).unwrap(),
            ] {
                for (i, v) in dec.iter().enumerate() {
                    assert!(v.is_finite() && *v >= 0.0, "{s}: value {i} = {v}");
                    if !valid[i / 3] {
                        assert_eq!(*v, 0.0, "{s}: invalid value {i}");
                    }
                }
                // The floor cells holding f32::MAX come back huge, not clamped to 0.
                let big = dec
                    .chunks_exact(3)
                    .zip(&valid)
                    .zip(&prod)
                    .filter(|((_, ok), p)| **ok && **p == 0.0)
                    .map(|((v, _), _)| v[0])
                    .fold(0f32, f32::max);
                assert!(big > 1e37, "{s}: {big}");
            }
        }
    }

    #[test]
    fn bad_requests_name_the_option() {
        for (s, want) in [
            ("dct", "needs step"),
            ("dct:step=-1", "step"),
            ("uniform:bits=40", "bits"),
            ("lossless:level=99", "level"),
            ("f16:bogus=1", "bogus"),
            ("brotli", "unknown codec"),
            (
                "dct:step=0.1,level=3",
                "level applies to dct with coding=zstd",
            ),
            (
                "dct:step=0.1,coding=zstd,refine=2",
                "refine applies to dct with coding=context",
            ),
            ("dct:step=0.1,deadzone=0.2", "deadzone"),
            ("dct:step=0.1,refine=21", "refine"),
            ("dct:step=0.1,coding=huffman", "coding"),
            (
                "dct:step=0.1,weight=sine",
                "weight = \"sine\", expected cosine",
            ),
            (
                "lossless:weight=cosine",
                "weight applies to the lossy codecs (f16, uniform, dct, tucker) only: lossless keeps",
            ),
            (
                "zstd-f32:weight=cos",
                "zstd-f32 keeps every sample bit for bit",
            ),
            ("tucker", "needs ranks"),
            ("tucker:ranks=8x0x4", "ranks"),
            ("tucker:ranks=8xx4", "ranks"),
            ("tucker:ranks=8x8x8,step=0", "step"),
            ("tucker:ranks=8x8x8,factor=1e9", "factor"),
            ("tucker:ranks=8x8x8,deadzone=1", "deadzone"),
            (
                "dct:step=0.1,residual=0",
                "residual = \"0\", expected a positive step",
            ),
            ("dct:step=0.1,residual=inf", "residual"),
            (
                "uniform:bits=8,residual=0.1",
                "residual=0.1 applies to dct and tucker only",
            ),
            ("lossless:residual=0.1", "applies to dct and tucker only"),
        ] {
            let e = CodecRequest::parse(s).unwrap_err().to_string();
            assert!(e.contains(want), "{s}: {e}");
        }
    }

    #[test]
    fn hostile_headers_and_payloads_are_errors_not_panics() {
        let t = small_table();
        let layout = Layout::of(&t);
        for s in ["dct:step=0.01", "dct:step=0.01,coding=zstd"] {
            let spec = CodecRequest::parse(s).unwrap().resolve(&t).unwrap();
            let payload = spec.encode(&t).unwrap();
            for cut in [0, 1, payload.len() / 2, payload.len() - 1] {
                assert!(
                    spec.decode(&payload[..cut], &layout).is_err(),
                    "{s} cut {cut}"
                );
            }
            let mut bad = spec.clone();
            match &mut bad {
                CodecSpec::Dct { dct, .. } | CodecSpec::DctContext { dct, .. } => {
                    dct.step = vec![0.0; 3]
                }
                _ => unreachable!(),
            }
            assert!(bad.decode(&payload, &layout).is_err(), "{s}");
            if let CodecSpec::DctContext { coding, domain, .. } = &spec {
                for (dz, it) in [(9.0, 0), (0.75, 1000)] {
                    let mut bad = spec.clone();
                    if let CodecSpec::DctContext {
                        coding: c,
                        domain: d,
                        ..
                    } = &mut bad
                    {
                        *c = coefcode::ContextCoding::new(dz);
                        *d = Domain::FillRefined { iterations: it };
                    }
                    assert!(bad.decode(&payload, &layout).is_err(), "{dz} {it}");
                }
                assert_eq!(*domain, Domain::FillInvalid);
                assert_eq!(coding.deadzone, coefcode::DEFAULT_DEADZONE);
            }
        }
        let spec = CodecRequest::parse("tucker:ranks=4x4x6,step=0.01")
            .unwrap()
            .resolve(&t)
            .unwrap();
        let payload = spec.encode(&t).unwrap();
        for cut in [0, 1, payload.len() / 2, payload.len() - 1] {
            assert!(
                spec.decode(&payload[..cut], &layout).is_err(),
                "tucker cut {cut}"
            );
        }
        let edits: [fn(&mut tucker::TuckerStage, &mut Domain); 6] = [
            |s, _| s.ranks = vec![4, 4],
            |s, _| s.ranks = vec![4, 9, 6],
            |s, _| s.ranks = vec![4, 0, 6],
            |s, _| s.step = vec![0.01, f64::INFINITY, 0.01],
            |s, _| s.factor_step = f64::NAN,
            |_, d| *d = Domain::DropInvalid,
        ];
        for (i, edit) in edits.iter().enumerate() {
            let mut bad = spec.clone();
            if let CodecSpec::Tucker { tucker, domain, .. } = &mut bad {
                edit(tucker, domain);
            }
            assert!(bad.decode(&payload, &layout).is_err(), "tucker edit {i}");
            assert!(bad.encode(&t).is_err(), "tucker edit {i}");
        }
        // Smaller ranks than the payload was written with: its extents exceed them.
        let mut small = spec.clone();
        if let CodecSpec::Tucker { tucker, .. } = &mut small {
            tucker.ranks = vec![1, 1, 1];
        }
        assert!(small.decode(&payload, &layout).is_err());
        let lossless = CodecRequest::parse("lossless")
            .unwrap()
            .resolve(&t)
            .unwrap();
        let p = lossless.encode(&t).unwrap();
        assert!(lossless.decode(&p[..p.len() - 1], &layout).is_err());
    }
}
