//! Files written before context coding existed still decode unchanged, and the `coding=zstd`
//! path still writes them; files written in the context coder's first model (before line
//! ends) still decode (fixtures/codec/README.md says how the fixtures were made).

use brdfpack::codec::coefcode::ContextModel;
use brdfpack::codec::transform::Curve;
use brdfpack::codec::{CodecRequest, CodecSpec, Layout, reference};
use brdfpack::io::native;
use std::path::{Path, PathBuf};

fn fixture(name: &str) -> (PathBuf, Vec<u8>) {
    let p = Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("fixtures/codec")
        .join(name);
    let b = std::fs::read(&p).unwrap();
    (p, b)
}

#[test]
fn an_old_dct_file_decodes_to_what_the_old_binary_decoded() {
    let (p, old) = fixture("ggx-dct-v1.bpk");
    let header = native::read_header(&old, &p).unwrap();
    assert!(
        matches!(header.codec, CodecSpec::Dct { .. }),
        "{:?}",
        header.codec
    );
    let eps = match &header.codec {
        CodecSpec::Dct { transform, .. } => match &transform.curve {
            Curve::Log { eps } | Curve::SignedLog { eps } => eps.clone(),
            Curve::Linear => vec![0.0; 3],
        },
        _ => unreachable!(),
    };
    // The fast decoder (src/codec/idct.rs: other summation order, vectorized exp) is not bit
    // for bit the old one; it agrees within 5e-5 of ε + x, the bound src/codec/mod.rs's
    // `assert_matches_reference` states (6× below the finest step's quantization noise). The
    // bit-exact comparison with the old decoder is in the next test, on `codec::reference`.
    assert_decodes_near(&old, &p, "ggx-dct-v1-decoded.bpk", &eps);
}

/// The file `bytes` (read from `path`) decodes to the fixture `decoded` within 5e-5 of ε + x
/// per channel (`eps`).
fn assert_decodes_near(bytes: &[u8], path: &Path, decoded: &str, eps: &[f64]) {
    let table = native::from_bytes(bytes, path).unwrap();
    let (q, dec) = fixture(decoded);
    let want = native::from_bytes(&dec, &q).unwrap();
    assert_eq!(table.data().len(), 8 * 8 * 16 * 3);
    for (i, (a, b)) in table.data().iter().zip(want.data()).enumerate() {
        let tol = 5e-5 * (b.abs() as f64 + eps[i % 3]);
        assert!(
            ((a - b) as f64).abs() <= tol,
            "value {i}: {a} vs the old binary's {b}"
        );
    }
}

#[test]
fn coding_zstd_writes_the_old_format_and_context_coding_is_smaller() {
    let (p, src) = fixture("ggx-lossless.bpk");
    let source = native::from_bytes(&src, &p).unwrap();
    let (q, old) = fixture("ggx-dct-v1.bpk");
    let old_spec = native::read_header(&old, &q).unwrap().codec;
    let spec = CodecRequest::parse("dct:step=0.01,coding=zstd")
        .unwrap()
        .resolve(&source)
        .unwrap();
    assert_eq!(spec, old_spec);
    // Same payload: the old decoder (`codec::reference`) gives the old binary's values bit
    // for bit.
    let payload = spec.encode(&source).unwrap();
    let (d, want) = fixture("ggx-dct-v1-decoded.bpk");
    let want = native::from_bytes(&want, &d).unwrap();
    let slow = reference::decode(&spec, &payload, &Layout::of(&source)).unwrap();
    assert!(
        slow.iter()
            .zip(want.data())
            .all(|(a, b)| a.to_bits() == b.to_bits())
    );
    let dec = spec.decode(&payload, &Layout::of(&source)).unwrap();
    // The default coding of `dct` is now the context coder, at the same step.
    let ctx = CodecRequest::parse("dct:step=0.01,deadzone=0.5")
        .unwrap()
        .resolve(&source)
        .unwrap();
    assert!(matches!(ctx, CodecSpec::DctContext { .. }));
    let cp = ctx.encode(&source).unwrap();
    assert!(
        cp.len() < payload.len(),
        "context {} B vs zstd {} B",
        cp.len(),
        payload.len()
    );
    // With dead zone 0.5 the coefficients are those of the zstd path: same decoded table.
    let back = ctx.decode(&cp, &Layout::of(&source)).unwrap();
    assert!(
        back.iter()
            .zip(&dec)
            .all(|(a, b)| a.to_bits() == b.to_bits())
    );
    let file = native::to_bytes(&source, &ctx).unwrap();
    let again = native::from_bytes(&file, Path::new("ctx.bpk")).unwrap();
    assert!(
        again
            .data()
            .iter()
            .zip(&back)
            .all(|(a, b)| a.to_bits() == b.to_bits())
    );
}

/// The cosine weight added an optional field to `transform`: headers without it (every file
/// written before it) parse to unweighted specs, and those serialize to the very bytes the old
/// binary wrote (the field is skipped, not written as null).
#[test]
fn old_headers_parse_unweighted_and_serialize_byte_for_byte() {
    for name in [
        "ggx-dct-v1.bpk",
        "ggx-lossless.bpk",
        "ggx-dct-v1-decoded.bpk",
    ] {
        let (p, old) = fixture(name);
        let header = native::read_header(&old, &p).unwrap();
        assert!(
            header.codec.transform().is_none_or(|t| t.weight.is_none()),
            "{name}"
        );
        let json = serde_json::to_string(&header.codec).unwrap();
        // The header is pretty-printed; the codec JSON has no spaces inside strings, so the
        // comparison without whitespace is one of keys, order and number spellings.
        let squeeze = |s: &str| s.split_whitespace().collect::<String>();
        let raw = squeeze(&String::from_utf8_lossy(&old));
        assert!(
            raw.contains(&format!("\"codec\":{json}")),
            "{name}: {json} is not in the old header"
        );
        assert!(!json.contains("cosine"), "{name}");
    }
}

/// A `dct` file of the context coder's first model (every position coded, written by the main
/// binary at efcdcd2, before line ends): its header has no `model` and reads as that model, it
/// decodes to what the old binary decoded, the old model's encoder still writes its very
/// payload, and today's `dct:step=0.01` (the current model) decodes to the same table.
#[test]
fn a_first_model_context_file_decodes_to_what_the_old_binary_decoded() {
    let (codec, source, payload) = old_context_file(
        "ggx-dct-context-v1.bpk",
        "ggx-dct-context-v1-decoded.bpk",
        ContextModel::EveryPosition,
    );
    let now = CodecRequest::parse("dct:step=0.01")
        .unwrap()
        .resolve(&source)
        .unwrap();
    let CodecSpec::DctContext { coding, .. } = &now else {
        panic!("{now:?}")
    };
    assert_eq!(coding.model, ContextModel::CURRENT);
    let ends = now.encode(&source).unwrap();
    // This box is dense (step 0.01 on 8 × 8 × 16: most lines run to their last position or
    // near it), so the ends save few zero flags and cost about as much as they save: 964 B
    // against 952 B when this was written. The sparse boxes of real budgets gain 2–17%
    // (docs/compression.md "Line ends").
    assert!(
        ends.len() * 100 <= payload.len() * 102,
        "line ends {} B vs every position {} B",
        ends.len(),
        payload.len()
    );
    // Same coefficients (same quantizer), other stream: the same decoded table.
    assert_same_table(&now, &ends, &codec, &payload, &source);
}

/// A `dct` file of the line-end model (written by the main binary at db7d7bd, before the zero
/// flags' contexts held the second neighbours): its header names `line_ends`, it decodes to
/// what that binary decoded, that model's encoder still writes its very payload, and today's
/// model codes the same coefficients into a stream that decodes to the same table.
#[test]
fn a_line_end_model_file_decodes_to_what_the_old_binary_decoded() {
    let (codec, source, payload) = old_context_file(
        "ggx-dct-context-v2.bpk",
        "ggx-dct-context-v2-decoded.bpk",
        ContextModel::LineEnds,
    );
    let mut now = codec.clone();
    if let CodecSpec::DctContext { coding, .. } = &mut now {
        coding.model = ContextModel::CURRENT;
    }
    assert_ne!(ContextModel::CURRENT, ContextModel::LineEnds);
    let wide = now.encode(&source).unwrap();
    assert_ne!(wide, payload);
    assert_same_table(&now, &wide, &codec, &payload, &source);
}

/// The context-coded fixture `name`, written by an old binary in `model`: its header names
/// that model, it decodes to `decoded` (what that binary decoded; within the tolerance of the
/// `dct` file above, for the same reason: the fast inverse DCT may change its summation order,
/// while the coefficients themselves are the old ones exactly, as the payload check shows),
/// and that model's encoder still writes its very payload from the lossless fixture. Returns
/// the file's codec, the lossless source and that payload.
fn old_context_file(
    name: &str,
    decoded: &str,
    model: ContextModel,
) -> (CodecSpec, brdfpack::table::Table, Vec<u8>) {
    let (p, old) = fixture(name);
    let header = native::read_header(&old, &p).unwrap();
    let CodecSpec::DctContext {
        transform, coding, ..
    } = &header.codec
    else {
        panic!("{:?}", header.codec)
    };
    assert_eq!(coding.model, model);
    let eps = match &transform.curve {
        Curve::Log { eps } | Curve::SignedLog { eps } => eps.clone(),
        Curve::Linear => vec![0.0; 3],
    };
    assert_decodes_near(&old, &p, decoded, &eps);
    let (s, src) = fixture("ggx-lossless.bpk");
    let source = native::from_bytes(&src, &s).unwrap();
    let payload = header.codec.encode(&source).unwrap();
    assert!(
        old.windows(payload.len()).any(|w| w == payload),
        "the {model:?} model's encoder no longer writes the old payload"
    );
    (header.codec, source, payload)
}

/// `a` (of spec `sa`) and `b` (of `sb`) decode to the same table, bit for bit.
fn assert_same_table(
    sa: &CodecSpec,
    a: &[u8],
    sb: &CodecSpec,
    b: &[u8],
    source: &brdfpack::table::Table,
) {
    let layout = Layout::of(source);
    let (x, y) = (
        sa.decode(a, &layout).unwrap(),
        sb.decode(b, &layout).unwrap(),
    );
    assert_eq!(x.len(), y.len());
    assert!(x.iter().zip(&y).all(|(p, q)| p.to_bits() == q.to_bits()));
}
