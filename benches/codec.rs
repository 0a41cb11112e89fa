//! Decode throughput of the codecs on MERL-sized tables (90×90×180 RGB, 17,496,000 bytes of f32
//! out per decode, one thread): `BRDFPACK_SHARED=/work/shared cargo bench --bench codec`.
//!
//! Tables: `ggx` = GGX conductor (gold η/k) α = 0.2 on the MERL grid; `gold` = the shared
//! gold-metallic-paint MERL file (skipped when the shared folder is absent). "production" is
//! the DCT spec that `--max-error log_rmse=0.002,p99_rel_core=0.05` selects for the table (the
//! search's ε and step, written out so the bench does not rerun the search). `decode` is the
//! decoder files are read with; `decode_reference` the previous one
//! (`codec::reference`), measured in the same run for the before/after ratio (for `tucker`
//! the f64 reference expansion). `cargo bench --bench codec -- tucker` runs the Tucker cases.

use brdfpack::codec::{CodecRequest, CodecSpec, Layout, reference, testdata};
use brdfpack::table::Table;
use std::collections::HashMap;
use std::sync::{Mutex, OnceLock};

fn main() {
    divan::main();
}

/// Production specs found by the first `search` (varint + zstd coding of the coefficients);
/// the context-coded cases at the same steps are listed beside them.
const GGX_PRODUCTION: &str = "dct:eps=0.001,step=1.133,coding=zstd,level=19";
const GOLD_PRODUCTION: &str = "dct:eps=0.001,step=0.3353,coding=zstd,level=19";

fn cases() -> Vec<&'static str> {
    let mut v = vec![
        "ggx zstd-f32:level=3",
        "ggx lossless:level=3",
        "ggx f16:level=3",
        "ggx dct:step=1.0",
        "ggx dct:step=0.1",
        "ggx production",
        "ggx dct:eps=0.001,step=1.133",
        "ggx tucker:ranks=16x16x32,step=0.3",
        "ggx tucker:ranks=32x32x64,step=0.3",
    ];
    if gold().is_some() {
        v.extend([
            "gold lossless:level=3",
            "gold production",
            "gold dct:eps=0.001,step=0.3353",
            "gold tucker:ranks=32x32x64,step=0.3",
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
    let spec = match (name, spec) {
        ("ggx", "production") => GGX_PRODUCTION,
        (_, "production") => GOLD_PRODUCTION,
        (_, s) => s,
    };
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

#[divan::bench(args = cases(), sample_count = 7)]
fn decode_reference(bencher: divan::Bencher, case: &'static str) {
    let (t, s, p) = encoded(case);
    bencher
        .counter(divan::counter::BytesCount::new(t.data().len() * 4))
        .bench(|| reference::decode(&s, divan::black_box(&p), &Layout::of(t)).unwrap());
}
