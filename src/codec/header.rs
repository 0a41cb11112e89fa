//! The header form of [`CodecSpec`]: the same chains, except that a DCT or Tucker chain with a
//! quantized residual is a kind of its own (`"kind": "dct_residual"`, `"dct_context_residual"`,
//! `"tucker_residual"`), not a `residual` field of the plain kind. A reader built before
//! residuals existed ignores unknown fields, so it would have read the whole payload (length
//! prefix, lossy and residual sections) as the plain chain's: an unrelated error at best
//! (zstd: not a frame), a wrong table at worst; an unknown kind it refuses ("unknown
//! variant"). Chains without a residual are written exactly
//! as before, byte for byte (tested below against a copy of the old enum).

use super::CodecSpec;
use super::coefcode::ContextCoding;
use super::dct::DctStage;
use super::domain::Domain;
use super::entropy::Zstd;
use super::predict::Predictor;
use super::quantize::Quantizer;
use super::residual::ResidualStage;
use super::transform::Transform;
use super::tucker::TuckerStage;
use serde::{Deserialize, Serialize};

#[derive(Clone, Serialize, Deserialize)]
#[serde(tag = "kind", rename_all = "snake_case")]
pub(super) enum SpecRecord {
    ZstdF32 {
        level: i32,
    },
    Lossless {
        domain: Domain,
        predict: Predictor,
        entropy: Zstd,
    },
    Quantized {
        domain: Domain,
        transform: Transform,
        quantize: Quantizer,
        predict: Predictor,
        entropy: Zstd,
    },
    Dct {
        domain: Domain,
        transform: Transform,
        dct: DctStage,
        entropy: Zstd,
    },
    DctContext {
        domain: Domain,
        transform: Transform,
        dct: DctStage,
        coding: ContextCoding,
    },
    Tucker {
        domain: Domain,
        transform: Transform,
        tucker: TuckerStage,
        entropy: Zstd,
    },
    DctResidual {
        domain: Domain,
        transform: Transform,
        dct: DctStage,
        entropy: Zstd,
        residual: ResidualStage,
    },
    DctContextResidual {
        domain: Domain,
        transform: Transform,
        dct: DctStage,
        coding: ContextCoding,
        residual: ResidualStage,
    },
    TuckerResidual {
        domain: Domain,
        transform: Transform,
        tucker: TuckerStage,
        entropy: Zstd,
        residual: ResidualStage,
    },
}

impl From<SpecRecord> for CodecSpec {
    fn from(r: SpecRecord) -> CodecSpec {
        use SpecRecord as R;
        match r {
            R::ZstdF32 { level } => CodecSpec::ZstdF32 { level },
            R::Lossless {
                domain,
                predict,
                entropy,
            } => CodecSpec::Lossless {
                domain,
                predict,
                entropy,
            },
            R::Quantized {
                domain,
                transform,
                quantize,
                predict,
                entropy,
            } => CodecSpec::Quantized {
                domain,
                transform,
                quantize,
                predict,
                entropy,
            },
            R::Dct {
                domain,
                transform,
                dct,
                entropy,
            } => CodecSpec::Dct {
                domain,
                transform,
                dct,
                entropy,
                residual: None,
            },
            R::DctResidual {
                domain,
                transform,
                dct,
                entropy,
                residual,
            } => CodecSpec::Dct {
                domain,
                transform,
                dct,
                entropy,
                residual: Some(residual),
            },
            R::DctContext {
                domain,
                transform,
                dct,
                coding,
            } => CodecSpec::DctContext {
                domain,
                transform,
                dct,
                coding,
                residual: None,
            },
            R::DctContextResidual {
                domain,
                transform,
                dct,
                coding,
                residual,
            } => CodecSpec::DctContext {
                domain,
                transform,
                dct,
                coding,
                residual: Some(residual),
            },
            R::Tucker {
                domain,
                transform,
                tucker,
                entropy,
            } => CodecSpec::Tucker {
                domain,
                transform,
                tucker,
                entropy,
                residual: None,
            },
            R::TuckerResidual {
                domain,
                transform,
                tucker,
                entropy,
                residual,
            } => CodecSpec::Tucker {
                domain,
                transform,
                tucker,
                entropy,
                residual: Some(residual),
            },
        }
    }
}

impl From<CodecSpec> for SpecRecord {
    fn from(s: CodecSpec) -> SpecRecord {
        use SpecRecord as R;
        match s {
            CodecSpec::ZstdF32 { level } => R::ZstdF32 { level },
            CodecSpec::Lossless {
                domain,
                predict,
                entropy,
            } => R::Lossless {
                domain,
                predict,
                entropy,
            },
            CodecSpec::Quantized {
                domain,
                transform,
                quantize,
                predict,
                entropy,
            } => R::Quantized {
                domain,
                transform,
                quantize,
                predict,
                entropy,
            },
            CodecSpec::Dct {
                domain,
                transform,
                dct,
                entropy,
                residual,
            } => match residual {
                None => R::Dct {
                    domain,
                    transform,
                    dct,
                    entropy,
                },
                Some(residual) => R::DctResidual {
                    domain,
                    transform,
                    dct,
                    entropy,
                    residual,
                },
            },
            CodecSpec::DctContext {
                domain,
                transform,
                dct,
                coding,
                residual,
            } => match residual {
                None => R::DctContext {
                    domain,
                    transform,
                    dct,
                    coding,
                },
                Some(residual) => R::DctContextResidual {
                    domain,
                    transform,
                    dct,
                    coding,
                    residual,
                },
            },
            CodecSpec::Tucker {
                domain,
                transform,
                tucker,
                entropy,
                residual,
            } => match residual {
                None => R::Tucker {
                    domain,
                    transform,
                    tucker,
                    entropy,
                },
                Some(residual) => R::TuckerResidual {
                    domain,
                    transform,
                    tucker,
                    entropy,
                    residual,
                },
            },
        }
    }
}

#[cfg(test)]
mod tests {
    use super::super::CodecRequest;
    use super::*;
    use crate::grid::parse_grid_spec;
    use crate::table::Table;
    use crate::testing as testdata;

    /// `CodecSpec` as a reader built before residuals parsed it (src/codec/mod.rs at
    /// 9cd0a3e): the derive on the enum itself.
    #[derive(Serialize, Deserialize)]
    #[serde(tag = "kind", rename_all = "snake_case")]
    enum OldSpec {
        ZstdF32 {
            level: i32,
        },
        Lossless {
            domain: Domain,
            predict: Predictor,
            entropy: Zstd,
        },
        Quantized {
            domain: Domain,
            transform: Transform,
            quantize: Quantizer,
            predict: Predictor,
            entropy: Zstd,
        },
        Dct {
            domain: Domain,
            transform: Transform,
            dct: DctStage,
            entropy: Zstd,
        },
        DctContext {
            domain: Domain,
            transform: Transform,
            dct: DctStage,
            coding: ContextCoding,
        },
        Tucker {
            domain: Domain,
            transform: Transform,
            tucker: TuckerStage,
            entropy: Zstd,
        },
    }

    fn table() -> Table {
        let g = parse_grid_spec("halfdiff3:6x6x8").unwrap();
        crate::tabulate::tabulate(
            &testdata::GgxConductor::new(0.3),
            &g,
            &crate::tabulate::TabulateOptions::default(),
        )
        .unwrap()
    }

    #[test]
    fn plain_headers_are_unchanged_and_old_readers_refuse_residual_ones() {
        let t = table();
        for s in [
            "zstd-f32",
            "lossless",
            "uniform:bits=10",
            "f16:weight=cosine",
            "dct:step=0.01,coding=zstd",
            "dct:step=0.01,refine=2",
            "dct:step=0.01,weight=cosine",
            "tucker:ranks=3x3x4",
        ] {
            let spec = CodecRequest::parse(s).unwrap().resolve(&t).unwrap();
            let json = serde_json::to_string(&spec).unwrap();
            // The old reader parses it and writes it back to the same bytes.
            let old: OldSpec = serde_json::from_str(&json).unwrap();
            assert_eq!(serde_json::to_string(&old).unwrap(), json, "{s}");
            assert!(!json.contains("residual"), "{s}: {json}");
            let back: CodecSpec = serde_json::from_str(&json).unwrap();
            assert_eq!(back, spec, "{s}");
        }
        for (s, kind) in [
            ("dct:step=0.1,coding=zstd,residual=0.01", "dct_residual"),
            ("dct:step=0.1,residual=0.01", "dct_context_residual"),
            ("tucker:ranks=3x3x4,residual=0.02", "tucker_residual"),
        ] {
            let spec = CodecRequest::parse(s).unwrap().resolve(&t).unwrap();
            assert!(spec.residual().is_some(), "{s}");
            let json = serde_json::to_string(&spec).unwrap();
            assert!(
                json.starts_with(&format!(r#"{{"kind":"{kind}","#)),
                "{s}: {json}"
            );
            assert!(json.contains(r#""residual":{"step":["#), "{s}: {json}");
            let back: CodecSpec = serde_json::from_str(&json).unwrap();
            assert_eq!(back, spec, "{s}");
            // A reader from before residuals must refuse the file, not decode the lossy
            // section alone.
            let e = serde_json::from_str::<OldSpec>(&json)
                .err()
                .map(|e| e.to_string())
                .unwrap_or_default();
            assert!(e.contains(&format!("unknown variant `{kind}`")), "{s}: {e}");
        }
    }
}
