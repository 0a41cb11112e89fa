//! Files written before context coding existed still decode unchanged, and the `coding=zstd`
//! path still writes them (fixtures/codec/README.md says how the fixtures were made).

use brdfpack::codec::{CodecRequest, CodecSpec, Layout};
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
    let table = native::from_bytes(&old, &p).unwrap();
    let (q, dec) = fixture("ggx-dct-v1-decoded.bpk");
    let want = native::from_bytes(&dec, &q).unwrap();
    assert_eq!(table.data().len(), 8 * 8 * 16 * 3);
    assert!(
        table
            .data()
            .iter()
            .zip(want.data())
            .all(|(a, b)| a.to_bits() == b.to_bits()),
        "decoded values changed"
    );
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
    // Same payload: decoding it gives the old file's values bit for bit.
    let payload = spec.encode(&source).unwrap();
    let old_table = native::from_bytes(&old, &q).unwrap();
    let dec = spec.decode(&payload, &Layout::of(&source)).unwrap();
    assert!(
        dec.iter()
            .zip(old_table.data())
            .all(|(a, b)| a.to_bits() == b.to_bits())
    );
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
