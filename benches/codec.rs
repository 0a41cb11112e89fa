//! Decode throughput of the codecs on a MERL-sized table (GGX conductor α = 0.2 on the MERL
//! grid): `cargo bench --bench codec`. Output bytes = 17,496,000 f32 per decode.

use brdfpack::codec::{CodecRequest, CodecSpec, Layout, testdata};
use brdfpack::table::Table;
use std::sync::OnceLock;

fn main() {
    divan::main();
}

fn table() -> &'static Table {
    static T: OnceLock<Table> = OnceLock::new();
    T.get_or_init(|| testdata::ggx_merl(0.2))
}

fn encoded(spec: &str) -> (CodecSpec, Vec<u8>) {
    let t = table();
    let s = CodecRequest::parse(spec).unwrap().resolve(t).unwrap();
    let p = s.encode(t).unwrap();
    (s, p)
}

#[divan::bench(args = ["zstd-f32:level=3", "lossless:level=3", "f16:level=3", "dct:step=1.0", "dct:step=0.1"], sample_count = 5)]
fn decode(bencher: divan::Bencher, spec: &str) {
    let (s, p) = encoded(spec);
    let t = table();
    bencher
        .counter(divan::counter::BytesCount::new(t.data().len() * 4))
        .bench(|| s.decode(divan::black_box(&p), &Layout::of(t)).unwrap());
}
