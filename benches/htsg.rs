//! HTSG evaluation cost through the `Model` path (divan). Done-criterion: ≤ 20 µs per RGB
//! sample at the roughest swept setting (σ0 = 3 µm, τ = 3 µm; docs/htsg.md).
//! Run: `cargo bench --bench htsg`. Figures are in docs/htsg.md ("Timing").

use brdfpack::brdf::Brdf;
use brdfpack::check::SampleSet;
use brdfpack::geometry::Vec3;
use brdfpack::model::Model;
use divan::{Bencher, black_box, counter::ItemsCount};

fn main() {
    divan::main();
}

/// The spec's default (σ0 = 0.18 µm) and the roughest setting of the σ0 sweep.
const SPECS: [&str; 2] = ["htsg", "htsg:sigma0=3,tau=3"];
/// Pairs per iteration: ~2 ms at the roughest setting, short enough that the fastest of
/// divan's samples is rarely preempted on the shared 2-core machine.
const PAIRS: usize = 200;

/// Uniformly random direction pairs on the upper hemisphere, RGB.
#[divan::bench(args = SPECS)]
fn eval_rgb_random_pairs(bencher: Bencher, spec: &str) {
    let m = Model::parse(spec).unwrap();
    let set = SampleSet::uniform(PAIRS, 7);
    let mut out = [0.0; 3];
    bencher.counter(ItemsCount::new(PAIRS)).bench_local(|| {
        let mut acc = 0.0;
        for &(wi, wo) in &set.pairs {
            m.eval(black_box(wi), black_box(wo), &mut out);
            acc += out[0];
        }
        acc
    });
}

/// Both directions normal: the largest g = (4πσ0/λ)² (1,430 series terms in blue at
/// σ0 = 3 µm one by one; 36 since they are summed at a stride, docs/htsg.md).
#[divan::bench(args = SPECS)]
fn eval_rgb_both_normal(bencher: Bencher, spec: &str) {
    let m = Model::parse(spec).unwrap();
    let mut out = [0.0; 3];
    bencher.counter(ItemsCount::new(PAIRS)).bench_local(|| {
        let mut acc = 0.0;
        for _ in 0..PAIRS {
            m.eval(black_box(Vec3::Z), black_box(Vec3::Z), &mut out);
            acc += out[2];
        }
        acc
    });
}

/// 16 spectral channels 400–700 nm at the roughest setting (per sample, all 16 channels).
#[divan::bench]
fn eval_16_wavelengths_random_pairs(bencher: Bencher) {
    let w: Vec<String> = (0..16).map(|i| format!("{}", 400 + 20 * i)).collect();
    let m = Model::parse(&format!(
        "htsg:sigma0=3,tau=3,wavelengths_nm={}",
        w.join("/")
    ))
    .unwrap();
    let set = SampleSet::uniform(PAIRS, 7);
    let mut out = [0.0; 16];
    bencher.counter(ItemsCount::new(PAIRS)).bench_local(|| {
        let mut acc = 0.0;
        for &(wi, wo) in &set.pairs {
            m.eval(black_box(wi), black_box(wo), &mut out);
            acc += out[0];
        }
        acc
    });
}
