//! The codec as a file records it ([`CodecSpec`]): the variant enum, what the decoder knows
//! besides the payload ([`Layout`]), and the dispatch of encode and decode over the stages.

use super::*;

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
    pub(super) fn values(&self) -> Result<usize> {
        self.valid
            .len()
            .checked_mul(self.channels)
            .ok_or_else(|| Error::input("table too large"))
    }
    pub(super) fn dims(&self) -> Vec<usize> {
        self.grid.shape()
    }
    pub(super) fn shape<'b>(&'b self, dims: &'b [usize]) -> Shape<'b> {
        Shape {
            dims,
            valid: self.valid,
            channels: self.channels,
        }
    }
}

/// The order in which [`domain::fill_invalid`] extends along axes: the second polar angle
/// first (θd, θo: the horizon cut runs across it), then the others.
pub(super) fn fill_order(kind: GridKind) -> Vec<usize> {
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
    pub(super) fn validate(&self, layout: &Layout) -> Result<()> {
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
    pub(super) fn with_best_residual_predictor(mut self, table: &Table) -> Result<CodecSpec> {
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
                let shape = layout.shape(&dims);
                let count = table.valid_count() * c;
                predict::compress_shuffled(entropy, count, |sink| {
                    predict.residuals_f32_each(table.data(), &shape, sink)
                })
            }
            CodecSpec::Quantized {
                transform,
                quantize,
                predict,
                entropy,
                ..
            } => {
                // No array of codes, nor of transformed values (f64, twice the table): each
                // cell's codes are made when the walk reaches it, again on each of the four
                // byte-plane passes (a curve and a rounding per value, a small part of zstd's
                // time).
                let weights = transform.cell_weights(layout.grid, layout.valid);
                let failed = std::cell::RefCell::new(None);
                let shape = layout.shape(&dims);
                let count = table.valid_count() * c;
                let data = table.data();
                let payload = predict::compress_shuffled(entropy, count, |sink| {
                    let (mut y, mut z, mut q) = (vec![0.0; c], vec![0.0; c], vec![0i32; c]);
                    let mut current = usize::MAX;
                    let code = |i: usize| {
                        let cell = i / c;
                        if cell != current {
                            current = cell;
                            let wf = weights.as_ref().map_or(1.0, |w| w.at(cell));
                            transform.forward_cell(
                                &data[cell * c..(cell + 1) * c],
                                wf,
                                &mut y,
                                &mut z,
                            );
                            for k in 0..c {
                                q[k] = quantize.encode(z[k], k).unwrap_or_else(|e| {
                                    failed.borrow_mut().get_or_insert(e);
                                    0
                                });
                            }
                        }
                        q[i % c]
                    };
                    predict.residuals_int_each(code, &shape, sink)
                });
                if let Some(e) = failed.into_inner() {
                    return Err(e);
                }
                payload
            }
            CodecSpec::Dct {
                transform,
                dct: stage,
                entropy,
                ..
            } => {
                let comps = quantized_dct_planes(table, transform, &stage.step, |p, k| {
                    dct::quantize(p, &dims, stage.step[k])
                })?;
                let bytes = dct::serialize(&comps);
                drop(comps);
                entropy.compress(&bytes)
            }
            CodecSpec::DctContext {
                domain,
                transform,
                dct: stage,
                coding,
                ..
            } => {
                let comps = match domain {
                    // The refined fill iterates on every plane together: all planes'
                    // coefficients at once. Otherwise one plane's at a time.
                    Domain::FillRefined { .. } => {
                        let coefs =
                            dct_coefficients_for(table, transform, *domain, &stage.step, coding)?;
                        for (p, &s) in coefs.iter().zip(&stage.step) {
                            dct::check_range(p, s)?;
                        }
                        coefcode::quantize_all(&coefs, &dims, &stage.step, coding.deadzone)
                    }
                    _ => quantized_dct_planes(table, transform, &stage.step, |p, k| {
                        coefcode::quantize_deadzone(p, &dims, stage.step[k], coding.deadzone)
                    })?,
                };
                Ok(coefcode::encode_model(&comps, coding.model))
            }
            CodecSpec::Tucker {
                transform,
                tucker: stage,
                entropy,
                ..
            } => {
                let c = table.channels().len();
                let plane = |k| std::borrow::Cow::Owned(filled_plane(table, transform, k));
                entropy.compress(&tucker::encode_each(c, plane, &dims, stage)?)
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
        self.decode_into_with(payload, layout, out, &mut DecodeScratch::lean())
    }

    /// A DCT chain's quantized coefficient boxes read from `payload`, with its transform and
    /// steps (`None` for another chain).
    #[allow(clippy::type_complexity)] // the three parts the inverse DCT takes.
    fn dct_components(
        &self,
        payload: &[u8],
        layout: &Layout,
        scratch: &mut DecodeScratch,
    ) -> Result<Option<(Vec<dct::Coefficients>, &Transform, &[f64])>> {
        let (c, dims) = (layout.channels, layout.dims());
        Ok(match self {
            CodecSpec::Dct {
                transform,
                dct: stage,
                entropy,
                ..
            } => {
                let raw = entropy.decompress_capped(payload, dct_stream_cap(layout)?)?;
                Some((dct::deserialize(&raw, &dims, c)?, transform, &stage.step))
            }
            CodecSpec::DctContext {
                transform,
                dct: stage,
                coding,
                ..
            } => Some((
                coefcode::decode_with(payload, &dims, c, coding.model, scratch)?,
                transform,
                &stage.step,
            )),
            _ => None,
        })
    }

    /// Whether [`CodecSpec::decode_cells`] decodes this chain on a table of `channels`
    /// channels: the DCT chains without a residual, of 1 or 3 channels.
    pub fn decodes_cells(&self, channels: usize) -> bool {
        matches!(self, CodecSpec::Dct { .. } | CodecSpec::DctContext { .. })
            && self.residual().is_none()
            && (channels == 1 || channels == 3)
    }

    /// The decoded values of a set's cells alone (`out[i·C + k]` is channel k of the cell at
    /// place i, [`CellSet`]), the same bits as [`CodecSpec::decode_into`] gives them, without
    /// an array of the table's size: what a measurement at a few million pairs of a 64⁴ table
    /// needs. Only for the chains [`CodecSpec::decodes_cells`] accepts.
    pub fn decode_cells(
        &self,
        payload: &[u8],
        layout: &Layout,
        cells: &crate::table::CellSet,
        out: &mut [f32],
    ) -> Result<()> {
        self.validate(layout)?;
        let c = layout.channels;
        if !self.decodes_cells(c) {
            return Err(Error::Failure(format!(
                "decode_cells: not a DCT chain of 1 or 3 channels without a residual ({c} channels)"
            )));
        }
        let dims = layout.dims();
        let grid_cells: usize = dims.iter().product();
        if out.len() != cells.len() * c || cells.grid_cells() != grid_cells {
            return Err(Error::Failure(
                "decode_cells: the set is of another grid, or the output is not its size"
                    .to_string(),
            ));
        }
        let (mut comps, transform, steps) = self
            .dct_components(payload, layout, &mut DecodeScratch::lean())?
            .expect("decodes_cells accepted the chain");
        let fin = simd::Finisher::new(transform, layout);
        idct::decode_cells(&mut comps, steps, &dims, &fin, layout.valid, cells, out);
        Ok(())
    }

    /// The transform and steps of a DCT chain that decodes from its boxes alone (no
    /// residual), for [`CodecSpec::decode_of`] and [`CodecSpec::decode_cells_of`].
    fn dct_parts(
        &self,
        comps: &[dct::Coefficients],
        layout: &Layout,
    ) -> Result<(&Transform, &[f64])> {
        self.validate(layout)?;
        let c = layout.channels;
        let dims = layout.dims();
        let parts = match self {
            CodecSpec::Dct {
                transform,
                dct: stage,
                ..
            }
            | CodecSpec::DctContext {
                transform,
                dct: stage,
                ..
            } if self.residual().is_none() => Some((transform, stage.step.as_slice())),
            _ => None,
        };
        match parts {
            Some(p)
                if comps.len() == c
                    && comps
                        .iter()
                        .all(|q| q.codes.is_empty() || q.extent.len() == dims.len()) =>
            {
                Ok(p)
            }
            _ => Err(Error::Failure(format!(
                "decoding kept boxes: not a DCT chain without a residual, or {} boxes of another table ({c} channels)",
                comps.len()
            ))),
        }
    }

    /// [`CodecSpec::decode_into_with`] of the quantized boxes `comps` the payload codes (the
    /// bits a reader gets from the payload): the rate control measures a candidate from its
    /// codes instead of decoding the payload they were coded into.
    pub(crate) fn decode_of(
        &self,
        comps: &[dct::Coefficients],
        layout: &Layout,
        out: &mut [f32],
        scratch: &mut DecodeScratch,
    ) -> Result<()> {
        let (transform, steps) = self.dct_parts(comps, layout)?;
        if out.len() != layout.values()? {
            return Err(Error::Failure(
                "decode_of: the output is not the table's size".to_string(),
            ));
        }
        let fin = simd::Finisher::new(transform, layout);
        idct::decode_of(
            comps,
            steps,
            &layout.dims(),
            &fin,
            layout.valid,
            out,
            scratch,
        );
        Ok(())
    }

    /// [`CodecSpec::decode_cells`] of the quantized boxes `comps` the payload codes, as
    /// [`CodecSpec::decode_of`].
    pub(crate) fn decode_cells_of(
        &self,
        comps: &[dct::Coefficients],
        layout: &Layout,
        cells: &crate::table::CellSet,
        out: &mut [f32],
    ) -> Result<()> {
        let (transform, steps) = self.dct_parts(comps, layout)?;
        let c = layout.channels;
        let dims = layout.dims();
        if !self.decodes_cells(c)
            || out.len() != cells.len() * c
            || cells.grid_cells() != dims.iter().product::<usize>()
        {
            return Err(Error::Failure(format!(
                "decode_cells_of: not 1 or 3 channels ({c}), or the set or the output is not of this table"
            )));
        }
        let fin = simd::Finisher::new(transform, layout);
        idct::decode_cells_of(comps, steps, &dims, &fin, layout.valid, cells, out);
        Ok(())
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
                unpredict::reconstruct_f32_into(predict, &raw, &layout.shape(&dims), out)
            }
            CodecSpec::Quantized {
                transform,
                quantize,
                predict,
                entropy,
                ..
            } => {
                let raw = entropy.decompress(payload, n_valid * c * 4)?;
                // The codes' bits go into the output buffer and become values there: no array
                // of codes beside it.
                unpredict::reconstruct_i32_with(predict, &raw, &layout.shape(&dims), |i, q| {
                    out[i] = f32::from_bits(q as u32)
                })?;
                drop(raw);
                match &transform.colour {
                    // The colour matrix mixes components: apply it in f64 like the encoder.
                    Some(col) => {
                        let mut z = vec![0.0; c];
                        let mut y = vec![0.0; c];
                        for o in out.chunks_exact_mut(c) {
                            for k in 0..c {
                                z[k] = quantize.decode(o[k].to_bits() as i32, k);
                            }
                            col.inverse(&z, &mut y);
                            for (o, y) in o.iter_mut().zip(&y) {
                                *o = *y as f32;
                            }
                        }
                    }
                    None => quantize.decode_bits_in_place(out, c),
                }
                simd::curve_interleaved(&transform.curve, c, layout.valid, out);
                if let Some(rw) = transform.reciprocal_weights(layout.grid, layout.valid) {
                    simd::scale_cells(&rw, c, out);
                }
                Ok(())
            }
            CodecSpec::Dct { .. } | CodecSpec::DctContext { .. } => {
                let (mut comps, transform, steps) = self
                    .dct_components(payload, layout, scratch)?
                    .expect("a DCT chain");
                inverse_dct(&mut comps, transform, steps, layout, out, scratch);
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

/// The decoded coefficient boxes of a DCT chain through the inverse DCT and the finishing
/// step (colour, curve, 1/w, interleave) into `out`.
fn inverse_dct(
    comps: &mut [dct::Coefficients],
    transform: &Transform,
    steps: &[f64],
    layout: &Layout,
    out: &mut [f32],
    scratch: &mut DecodeScratch,
) {
    let fin = simd::Finisher::new(transform, layout);
    let dims = layout.dims();
    idct::decode(comps, steps, &dims, &fin, layout.valid, out, scratch);
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
pub(super) struct ResidualInputs {
    source: Vec<Vec<f64>>,
    approx: Vec<Vec<f32>>,
}

/// The largest decompressed varint stream of a `dct` payload: at most 5 bytes per code plus
/// 10 per extent.
pub(super) fn dct_stream_cap(layout: &Layout) -> Result<usize> {
    layout
        .values()?
        .checked_mul(5)
        .and_then(|v| v.checked_add(10 * layout.channels * layout.grid.axes().len() + 16))
        .ok_or_else(|| Error::input("table too large"))
}

/// The largest error per channel of the curve space when every component k of z = M y is
/// within step_k/2: Σ_i |M_ik| step_i/2 through an orthonormal colour matrix, step/2 without.
pub(super) fn half_steps_through_colour(transform: &Transform, step: &[f64]) -> f64 {
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

/// The quantized components of a Tucker payload, every field checked.
pub(super) fn tucker_components(
    payload: &[u8],
    dims: &[usize],
    stage: &tucker::TuckerStage,
    entropy: &Zstd,
) -> Result<Vec<tucker::Component>> {
    let cap = tucker::max_stream(dims, stage).ok_or_else(|| Error::input("table too large"))?;
    let raw = entropy.decompress_capped(payload, cap)?;
    tucker::deserialize(&raw, dims, stage)
}
