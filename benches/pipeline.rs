//! Benchmarks of the core pipeline (divan): model evaluation, tabulation on the MERL grid,
//! and interpolated table lookups. Run: `cargo bench --bench pipeline`.
//! Figures and the machine they were taken on are in docs/benchmarks.md.

use brdfpack::brdf::Brdf;
use brdfpack::check::SampleSet;
use brdfpack::grid::Grid;
use brdfpack::model::Model;
use brdfpack::table::{Interp, InterpolatedTable};
use brdfpack::tabulate::{TabulateOptions, tabulate, tabulate_into};
use divan::{Bencher, black_box, counter::ItemsCount};

fn main() {
    divan::main();
}

/// The GGX conductor of the peer comparison (copper-like η, k of shared/peers/README.md).
const GGX_CONDUCTOR: &str = "ggx:alpha=0.2,shadowing=smith-separable,fresnel=conductor,eta=0.2004/0.924/1.1022,k=3.9129/2.4528/2.1421";

const PAIRS: usize = 100_000;

#[divan::bench(args = [GGX_CONDUCTOR, "lambert:albedo=0.8/0.5/0.2", "ward:alpha_x=0.1,alpha_y=0.3,rho_s=0.3,rho_d=0.1"])]
fn eval_model(bencher: Bencher, spec: &str) {
    let m = Model::parse(spec).unwrap();
    let set = SampleSet::uniform(PAIRS, 1);
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

#[divan::bench(sample_count = 10)]
fn tabulate_merl_grid_ggx_conductor(bencher: Bencher) {
    let m = Model::parse(GGX_CONDUCTOR).unwrap();
    let g = Grid::merl();
    bencher
        .counter(ItemsCount::new(g.cells()))
        .bench_local(|| tabulate(&m, &g, &TabulateOptions::default()).unwrap());
}

/// The peer comparison's measurement: tabulation into a table reused between runs
/// (`brdfpack bench --tabulate-only` times the same; scripts/peer-compare.sh compares).
#[divan::bench(sample_count = 10, args = ["merl", brdfpack::bench::PEER_ANISO_GRID])]
fn tabulate_into_reused(bencher: Bencher, grid: &str) {
    let (spec, g) = if grid == "merl" {
        (GGX_CONDUCTOR, Grid::merl())
    } else {
        (
            brdfpack::bench::PEER_GGX_ANISO,
            brdfpack::grid::parse_grid_spec(grid).unwrap(),
        )
    };
    let m = Model::parse(spec).unwrap();
    let opts = TabulateOptions::default();
    let mut t = tabulate(&m, &g, &opts).unwrap();
    bencher
        .counter(ItemsCount::new(g.cells()))
        .bench_local(|| tabulate_into(&m, &g, &opts, &mut t).unwrap());
}

/// Batched lookups (10⁶ random pairs) in the MERL-grid table, on the default thread pool.
#[divan::bench(sample_count = 10)]
fn lookup_batch_merl_grid_table(bencher: Bencher) {
    lookup_batch(bencher, "merl", None);
}

/// The same on one thread: the per-pair cost without the pool's scheduling.
#[divan::bench(sample_count = 10)]
fn lookup_batch_merl_grid_table_1thread(bencher: Bencher) {
    lookup_batch(bencher, "merl", Some(1));
}

/// A table that fits in L2 (halfdiff3 16×16×32, RGB, 98 KB), one thread: if this is as slow
/// per pair as the MERL grid, the lookup is bound by computation, not memory.
#[divan::bench(sample_count = 10)]
fn lookup_batch_small_table_1thread(bencher: Bencher) {
    lookup_batch(
        bencher,
        "halfdiff3:16x16x32,warp=sqrt/linear/linear",
        Some(1),
    );
}

/// `Table::eval_batch` (linear) of the GGX conductor tabulated on `grid`, 10⁶ uniform pairs,
/// on `threads` threads (the default pool when `None`).
fn lookup_batch(bencher: Bencher, grid: &str, threads: Option<usize>) {
    let m = Model::parse(GGX_CONDUCTOR).unwrap();
    let g = if grid == "merl" {
        Grid::merl()
    } else {
        brdfpack::grid::parse_grid_spec(grid).unwrap()
    };
    let table = tabulate(&m, &g, &TabulateOptions::default()).unwrap();
    let set = SampleSet::uniform(1_000_000, 1);
    let mut out = vec![0.0; set.pairs.len() * 3];
    let pool = threads.map(|n| {
        rayon::ThreadPoolBuilder::new()
            .num_threads(n)
            .build()
            .unwrap()
    });
    bencher
        .counter(ItemsCount::new(set.pairs.len()))
        .bench_local(|| match &pool {
            Some(p) => p.install(|| table.eval_batch(&set.pairs, Interp::Linear, &mut out)),
            None => table.eval_batch(&set.pairs, Interp::Linear, &mut out),
        });
}

#[divan::bench(args = [Interp::Linear, Interp::Nearest])]
fn lookup_merl_grid_table(bencher: Bencher, interp: Interp) {
    let m = Model::parse(GGX_CONDUCTOR).unwrap();
    let table = tabulate(&m, &Grid::merl(), &TabulateOptions::default()).unwrap();
    let t = InterpolatedTable { table, interp };
    let set = SampleSet::uniform(PAIRS, 2);
    let mut out = [0.0; 3];
    bencher.counter(ItemsCount::new(PAIRS)).bench_local(|| {
        let mut acc = 0.0;
        for &(wi, wo) in &set.pairs {
            t.eval(black_box(wi), black_box(wo), &mut out);
            acc += out[0];
        }
        acc
    });
}
