//! A codec as a user asks for it ([`CodecRequest`], `--codec dct:step=0.02`): parsing, and
//! resolving it into a [`CodecSpec`] for a given table; the text form is in [`text`].

use super::*;

mod text;

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
                let mut max_abs = 0.0f64;
                transform.for_each_cell(table.data(), c, table.grid(), table.valid(), |f, z| {
                    if table.valid()[f] {
                        max_abs = z.iter().fold(max_abs, |m, v| m.max(v.abs()));
                    }
                });
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
                let (mut lo, mut hi) = (vec![f64::MAX; c], vec![f64::MIN; c]);
                transform.for_each_cell(table.data(), c, table.grid(), table.valid(), |f, z| {
                    if table.valid()[f] {
                        for k in 0..c {
                            (lo[k], hi[k]) = (lo[k].min(z[k]), hi[k].max(z[k]));
                        }
                    }
                });
                // No valid cell: an empty range at 0.
                for k in 0..c {
                    if hi[k] < lo[k] {
                        (lo[k], hi[k]) = (0.0, 0.0);
                    }
                }
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
