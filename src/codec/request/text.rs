//! The text form of a [`CodecRequest`]: `Display` writes the canonical spec that
//! [`CodecRequest::parse`] reads back to the same request (every option spelled out, numbers
//! in Rust's shortest round-trip notation), e.g.
//! `dct:step=0.02,curve=log,eps=0.001,colour=klt,coding=zstd,level=19`. The exceptions to
//! "every option": `weight` and `residual` are written only when set (`,weight=cosine`;
//! `,residual=0.01` last), so that the canonical text of every request without them is what it
//! was before they existed.

use super::{CodecRequest, CurveRequest, DctCoding};
use crate::codec::predict::{Predictor, Space};
use crate::codec::transform::Weight;
use std::fmt;

impl CodecRequest {
    /// The zstd level of the entropy stage; `None` for DCT context coding (no zstd).
    pub fn level(&self) -> Option<i32> {
        match self {
            CodecRequest::ZstdF32 { level }
            | CodecRequest::Lossless { level, .. }
            | CodecRequest::F16 { level, .. }
            | CodecRequest::Uniform { level, .. }
            | CodecRequest::Tucker { level, .. }
            | CodecRequest::Dct {
                coding: DctCoding::Zstd { level },
                ..
            } => Some(*level),
            CodecRequest::Dct {
                coding: DctCoding::Context { .. },
                ..
            } => None,
        }
    }

    /// The same request with another zstd level (unchanged when it has no zstd stage).
    pub fn with_level(mut self, new: i32) -> CodecRequest {
        match &mut self {
            CodecRequest::ZstdF32 { level }
            | CodecRequest::Lossless { level, .. }
            | CodecRequest::F16 { level, .. }
            | CodecRequest::Uniform { level, .. }
            | CodecRequest::Tucker { level, .. }
            | CodecRequest::Dct {
                coding: DctCoding::Zstd { level },
                ..
            } => *level = new,
            CodecRequest::Dct {
                coding: DctCoding::Context { .. },
                ..
            } => {}
        }
        self
    }
}

fn curve(f: &mut fmt::Formatter, c: &CurveRequest) -> fmt::Result {
    match c {
        CurveRequest::Linear => write!(f, "curve=linear"),
        // `{:?}` of an f64 parses back to the same value (`{}` would too, but writes 1e300
        // with 300 zeros).
        CurveRequest::Log { eps_rel } => write!(f, "curve=log,eps={eps_rel:?}"),
        CurveRequest::SignedLog { eps_rel } => write!(f, "curve=signed-log,eps={eps_rel:?}"),
    }
}

fn weight(f: &mut fmt::Formatter, w: &Option<Weight>) -> fmt::Result {
    match w {
        None => Ok(()),
        Some(w) => write!(f, ",weight={}", w.name()),
    }
}

fn residual(f: &mut fmt::Formatter, r: &Option<f64>) -> fmt::Result {
    match r {
        None => Ok(()),
        Some(s) => write!(f, ",residual={s:?}"),
    }
}

fn colour(colour: bool) -> &'static str {
    if colour { "klt" } else { "none" }
}

fn predictor(f: &mut fmt::Formatter, p: &Predictor) -> fmt::Result {
    let orders: Vec<String> = p.orders.iter().map(u8::to_string).collect();
    let space = match p.space {
        Space::Float => "float",
        Space::Integer => "integer",
    };
    let cross = if p.cross_channel { "on" } else { "off" };
    write!(
        f,
        "predict={},space={space},cross={cross}",
        orders.join(".")
    )
}

impl fmt::Display for CodecRequest {
    fn fmt(&self, f: &mut fmt::Formatter) -> fmt::Result {
        match self {
            CodecRequest::ZstdF32 { level } => write!(f, "zstd-f32:level={level}"),
            CodecRequest::Lossless { level, predict } => {
                write!(f, "lossless:")?;
                match predict {
                    None => write!(f, "predict=auto")?,
                    Some(p) => predictor(f, p)?,
                }
                write!(f, ",level={level}")
            }
            CodecRequest::F16 {
                curve: c,
                weight: w,
                level,
            } => {
                write!(f, "f16:")?;
                curve(f, c)?;
                weight(f, w)?;
                write!(f, ",level={level}")
            }
            CodecRequest::Uniform {
                curve: c,
                weight: w,
                bits,
                colour: k,
                level,
            } => {
                write!(f, "uniform:bits={bits},")?;
                curve(f, c)?;
                write!(f, ",colour={}", colour(*k))?;
                weight(f, w)?;
                write!(f, ",level={level}")
            }
            CodecRequest::Dct {
                curve: c,
                weight: w,
                step,
                colour: k,
                coding,
                residual: r,
            } => {
                write!(f, "dct:step={step:?},")?;
                curve(f, c)?;
                write!(f, ",colour={}", colour(*k))?;
                weight(f, w)?;
                match coding {
                    DctCoding::Zstd { level } => write!(f, ",coding=zstd,level={level}")?,
                    DctCoding::Context { deadzone, refine } => {
                        write!(f, ",coding=context,deadzone={deadzone:?},refine={refine}")?
                    }
                }
                residual(f, r)
            }
            CodecRequest::Tucker {
                curve: c,
                weight: w,
                ranks,
                step,
                factor_step,
                colour: k,
                level,
                residual: r,
            } => {
                let ranks: Vec<String> = ranks.iter().map(usize::to_string).collect();
                write!(
                    f,
                    "tucker:ranks={},step={step:?},factor={factor_step:?},",
                    ranks.join("x")
                )?;
                curve(f, c)?;
                write!(f, ",colour={}", colour(*k))?;
                weight(f, w)?;
                write!(f, ",level={level}")?;
                residual(f, r)
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn display_is_the_canonical_spec_and_parses_back() {
        for (spec, canonical) in [
            ("zstd-f32", "zstd-f32:level=19"),
            ("lossless", "lossless:predict=auto,level=19"),
            (
                "lossless:predict=0.1.2,space=integer,cross=off,level=3",
                "lossless:predict=0.1.2,space=integer,cross=off,level=3",
            ),
            ("f16:curve=linear", "f16:curve=linear,level=19"),
            (
                "uniform:bits=12,eps=1e-5",
                "uniform:bits=12,curve=log,eps=1e-5,colour=klt,level=19",
            ),
            (
                "dct: step = 1e300 ,colour=none,coding=zstd,level=1",
                "dct:step=1e300,curve=log,eps=0.001,colour=none,coding=zstd,level=1",
            ),
            (
                "dct:step=0.5,refine=2",
                "dct:step=0.5,curve=log,eps=0.001,colour=klt,coding=context,deadzone=0.75,refine=2",
            ),
            (
                "dct:step=0.5,weight=cos,curve=linear",
                "dct:step=0.5,curve=linear,colour=klt,weight=cosine,coding=context,deadzone=0.75,refine=0",
            ),
            (
                "dct:step=0.5,weight=none,coding=zstd",
                "dct:step=0.5,curve=log,eps=0.001,colour=klt,coding=zstd,level=19",
            ),
            (
                "f16:weight=cosine",
                "f16:curve=log,eps=0.001,weight=cosine,level=19",
            ),
            (
                "uniform:bits=9,weight=cosine,colour=none",
                "uniform:bits=9,curve=log,eps=0.001,colour=none,weight=cosine,level=19",
            ),
            (
                "tucker:ranks=8x8x16",
                "tucker:ranks=8x8x16,step=0.05,factor=1.0,curve=log,eps=0.001,colour=klt,level=19",
            ),
            (
                "tucker: ranks = 2x3x4x5 ,step=0.1,factor=2,curve=linear,colour=none,level=3",
                "tucker:ranks=2x3x4x5,step=0.1,factor=2.0,curve=linear,colour=none,level=3",
            ),
            (
                "dct:residual=1e-2,step=0.3",
                "dct:step=0.3,curve=log,eps=0.001,colour=klt,coding=context,deadzone=0.75,refine=0,residual=0.01",
            ),
            (
                "dct:step=0.3,coding=zstd,level=5,residual=0.02,weight=cos",
                "dct:step=0.3,curve=log,eps=0.001,colour=klt,weight=cosine,coding=zstd,level=5,residual=0.02",
            ),
            (
                "tucker:ranks=8x8x16,residual=0.005",
                "tucker:ranks=8x8x16,step=0.05,factor=1.0,curve=log,eps=0.001,colour=klt,level=19,residual=0.005",
            ),
        ] {
            let r = CodecRequest::parse(spec).unwrap();
            assert_eq!(r.to_string(), canonical, "{spec}");
            assert_eq!(CodecRequest::parse(canonical).unwrap(), r, "{spec}");
        }
    }

    #[test]
    fn level_can_be_replaced() {
        let r = CodecRequest::parse("dct:step=0.1,coding=zstd,level=19").unwrap();
        assert_eq!(r.level(), Some(19));
        let r = r.with_level(3);
        assert_eq!(r.level(), Some(3));
        assert_eq!(
            r.to_string(),
            "dct:step=0.1,curve=log,eps=0.001,colour=klt,coding=zstd,level=3"
        );
        // Context coding has no zstd stage: no level to replace.
        let r = CodecRequest::parse("dct:step=0.1").unwrap();
        assert_eq!(r.level(), None);
        assert_eq!(r.clone().with_level(3), r);
    }
}
