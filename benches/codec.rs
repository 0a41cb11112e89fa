//! Decode throughput of the codecs on MERL-sized tables (90×90×180 RGB, 17,496,000 bytes of f32
//! out per decode, one thread): `BRDFPACK_SHARED=/work/shared cargo bench --bench codec`.
//!
//! Tables: `ggx` = GGX conductor (gold η/k) α = 0.2 on the MERL grid; `gold` = the shared
//! gold-metallic-paint MERL file (skipped when the shared folder is absent). "preview" and
//! "production" are the DCT specs that `--max-error` selects for the table (see `SPECS`; the
//! search's ε and step written out so the bench does not rerun the search). `decode` is the
//! decoder files are read with (a fresh output vector per call); `decode_into` the same into
//! a reused buffer; `decode_into_with` also reuses the decoder's working arrays
//! (`DecodeScratch`); `decode_reference` the previous decoder (`codec::reference`), measured in
//! the same run for the before/after ratio. Tucker cases
//! (`tucker:`) compare with the f64 reference expansion; `cargo bench --bench codec -- tucker`
//! runs only them; `-- residual` the chains with a quantized residual.

use brdfpack::codec::{CodecRequest, CodecSpec, DecodeScratch, Layout, reference};
use brdfpack::table::Table;
use brdfpack::testing as testdata;
use std::collections::HashMap;
use std::sync::{Mutex, OnceLock};

fn main() {
    divan::main();
}

/// The specs `--max-error` picks for these tables (docs/compression.md, budget table; steps as
/// printed there): "preview" = log_rmse ≤ 0.01 and p99_rel_core ≤ 0.2, "production" =
/// log_rmse ≤ 0.002 and p99_rel_core ≤ 0.05. "production-zstd" is the production step with
/// the coefficients varint + zstd coded (the `dct` chain before context coding).
const SPECS: &[(&str, &str)] = &[
    ("ggx preview", "dct:eps=0.001,step=24.2,refine=4"),
    ("ggx production", "dct:eps=0.001,step=1.31,refine=4"),
    (
        "ggx production-zstd",
        "dct:eps=0.001,step=1.133,coding=zstd,level=19",
    ),
    ("gold preview", "dct:eps=0.001,step=5.35,deadzone=0.6"),
    ("gold production", "dct:eps=0.001,step=0.316,refine=4"),
    (
        "gold production-zstd",
        "dct:eps=0.001,step=0.3353,coding=zstd,level=19",
    ),
];

fn cases() -> Vec<&'static str> {
    let mut v = vec![
        "ggx zstd-f32:level=3",
        "ggx lossless:level=3",
        "ggx f16:level=3",
        "ggx preview",
        "ggx production",
        "ggx production-zstd",
        // The production step with the cosine weight: the cost of the per-cell 1/w (weights
        // computed from the grid at every decode).
        "ggx dct:eps=0.001,step=1.31,refine=4,weight=cosine",
        "ggx tucker:ranks=16x16x32,step=0.3",
        "ggx tucker:ranks=32x32x64,step=0.3",
        // A quantized residual after the DCT: the separate, unfused decode path (component
        // planes, + residual, finisher); `-- residual` runs only these.
        "ggx dct:eps=0.001,step=0.3,residual=0.03",
    ];
    if gold().is_some() {
        v.extend([
            "gold lossless:level=3",
            "gold preview",
            "gold production",
            "gold production-zstd",
            "gold tucker:ranks=32x32x64,step=0.3",
            "gold dct:eps=0.001,step=0.3,residual=0.03",
        ]);
    } else {
        println!("skipped: gold cases (shared MERL data not found)");
    }
    v
}

fn ggx() -> &'static Table {
    static T: OnceLock<Table> = OnceLock::new();
    T.get_or_init(|| testdata::ggx_merl(0.2))
}

fn gold() -> Option<&'static Table> {
    static T: OnceLock<Option<Table>> = OnceLock::new();
    T.get_or_init(|| testdata::shared_merl("gold-metallic-paint"))
        .as_ref()
}

/// Encoded cases: spec and payload by case name.
type Cache = Mutex<HashMap<&'static str, (CodecSpec, Vec<u8>)>>;

/// (table, spec, payload) of a case, encoded once and shared by both benches.
fn encoded(case: &'static str) -> (&'static Table, CodecSpec, Vec<u8>) {
    static CACHE: OnceLock<Cache> = OnceLock::new();
    let (name, spec) = case.split_once(' ').expect("case = TABLE SPEC");
    let t = match name {
        "ggx" => ggx(),
        _ => gold().expect("gold cases are listed only when the data is present"),
    };
    let spec = SPECS
        .iter()
        .find(|(c, _)| *c == case)
        .map_or(spec, |(_, s)| *s);
    let mut cache = CACHE.get_or_init(Default::default).lock().unwrap();
    let (s, p) = cache.entry(case).or_insert_with(|| {
        let s = CodecRequest::parse(spec).unwrap().resolve(t).unwrap();
        let p = s.encode(t).unwrap();
        (s, p)
    });
    (t, s.clone(), p.clone())
}

#[divan::bench(args = cases(), sample_count = 7)]
fn decode(bencher: divan::Bencher, case: &'static str) {
    let (t, s, p) = encoded(case);
    bencher
        .counter(divan::counter::BytesCount::new(t.data().len() * 4))
        .bench(|| s.decode(divan::black_box(&p), &Layout::of(t)).unwrap());
}

/// Into one buffer reused across iterations (`CodecSpec::decode_into`): what a loader that
/// decodes many tables of one size pays, without the allocation and first-touch page faults
/// of a fresh 17.5 MB vector.
#[divan::bench(args = cases(), sample_count = 7)]
fn decode_into(bencher: divan::Bencher, case: &'static str) {
    let (t, s, p) = encoded(case);
    let mut buf = vec![0f32; t.data().len()];
    bencher
        .counter(divan::counter::BytesCount::new(t.data().len() * 4))
        .bench_local(|| {
            s.decode_into(divan::black_box(&p), &Layout::of(t), &mut buf)
                .unwrap()
        });
}

/// As `decode_into`, with the decoder's working arrays also kept between calls
/// (`CodecSpec::decode_into_with` and one `DecodeScratch`).
#[divan::bench(args = cases(), sample_count = 7)]
fn decode_into_with(bencher: divan::Bencher, case: &'static str) {
    let (t, s, p) = encoded(case);
    let mut buf = vec![0f32; t.data().len()];
    let mut scratch = DecodeScratch::default();
    bencher
        .counter(divan::counter::BytesCount::new(t.data().len() * 4))
        .bench_local(|| {
            s.decode_into_with(divan::black_box(&p), &Layout::of(t), &mut buf, &mut scratch)
                .unwrap()
        });
}

#[divan::bench(args = cases(), sample_count = 7)]
fn decode_reference(bencher: divan::Bencher, case: &'static str) {
    let (t, s, p) = encoded(case);
    bencher
        .counter(divan::counter::BytesCount::new(t.data().len() * 4))
        .bench(|| reference::decode(&s, divan::black_box(&p), &Layout::of(t)).unwrap());
}

/// A MERL-grid plane of smooth values with some detail (the DCT's cost does not depend on
/// them).
fn merl_plane() -> Vec<f64> {
    (0..90 * 90 * 180)
        .map(|i| ((i * 7919) % 1013) as f64 / 101.0 - 4.0)
        .collect()
}

/// The encoder's forward DCT of one MERL-grid component plane (f64, in place, all threads):
/// three per transform of a table, and one per refined fill of each component.
/// `cargo bench --bench codec -- dct_plane`.
#[divan::bench(sample_count = 15)]
fn dct_plane_forward_f64(bencher: divan::Bencher) {
    let dims = [90usize, 90, 180];
    let plane = merl_plane();
    bencher
        .with_inputs(|| plane.clone())
        .bench_local_values(|p| brdfpack::codec::dct::forward_owned(p, &dims));
}

/// The refined fill's inverse DCT of one MERL-grid plane held in f32 (in place, all threads).
#[divan::bench(sample_count = 15)]
fn dct_plane_inverse_f32(bencher: divan::Bencher) {
    let dims = [90usize, 90, 180];
    let plane: Vec<f32> = merl_plane().iter().map(|&v| v as f32).collect();
    bencher
        .with_inputs(|| plane.clone())
        .bench_local_values(|p| brdfpack::codec::dct::inverse_owned_f32(p, &dims));
}
