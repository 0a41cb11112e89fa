"""Python `eval` of 10^6 pairs from NumPy against the Rust batch lookup (issue 25, done-when 3).

The Rust figure is `brdfpack bench --lookup-only` (`Table::eval_batch`, linear, of the GGX
conductor of the peer comparison tabulated on the MERL grid, 10^6 uniform pairs of seed 1).
The Python figure is `Table.eval` on the same table and the same pairs
(`brdfpack.sample_pairs`), converted from and to NumPy arrays, timed from the call to the
returned array. Rounds alternate the two so that load on a shared machine hits both alike;
each figure is the median of `--runs` timed runs after a warm-up. Prints a Markdown table and
the ratio of the medians (Python / Rust throughput).

    python bindings/python/bench/bench_eval.py --bin target/release/brdfpack
"""

import argparse
import json
import os
import statistics
import subprocess
import sys
import time

# NumPy's OpenBLAS starts a thread per core at import, whose busy-waiting took 1-3% of the
# samples of `eval` loops in perf (docs/benchmarks.md), although nothing here calls BLAS
# (`eval` is brdfpack's own lookup): one BLAS thread, set before NumPy is imported, so that
# the Python side is not charged for threads it does not use. A caller's setting is kept.
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import numpy as np  # noqa: E402

import brdfpack  # noqa: E402

# src/bench.rs PEER_GGX.
PEER_GGX = (
    "ggx:alpha=0.2,shadowing=smith-separable,fresnel=conductor,"
    "eta=0.2004/0.924/1.1022,k=3.9129/2.4528/2.1421"
)


def rust_lookup(bin_path, pairs, runs):
    out = subprocess.run(
        [bin_path, "bench", "--lookup-only", "--json", "--runs", str(runs), "--pairs", str(pairs)],
        capture_output=True,
        text=True,
        check=True,
    ).stdout
    row = json.loads(out.splitlines()[0])
    return row["timing"]["median_s"]


def python_eval(table, wi, wo, runs, exact=False, reuse=True):
    """Median seconds of `table.eval`; `reuse`: into one output array (`out=`), as the Rust
    bench reuses its output buffer; otherwise a new array per call."""
    out = np.empty((wi.shape[0], 3)) if reuse else None
    table.eval(wi, wo, exact=exact, out=out)  # warm-up
    times = []
    for _ in range(runs):
        t0 = time.perf_counter()
        f = table.eval(wi, wo, exact=exact, out=out)
        times.append(time.perf_counter() - t0)
    assert f.shape == (wi.shape[0], 3) and np.isfinite(f).all()
    return statistics.median(times)


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--bin", required=True, help="the brdfpack binary (same profile as the wheel)")
    ap.add_argument("--pairs", type=int, default=1_000_000)
    ap.add_argument("--runs", type=int, default=7)
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--exact", action="store_true", help="also time eval(exact=True)")
    ap.add_argument(
        "--min-ratio",
        type=float,
        default=None,
        help="exit 1 when the median ratio is below this (for a quiet machine, not CI)",
    )
    a = ap.parse_args()
    table = brdfpack.tabulate(PEER_GGX, grid="merl")
    wi, wo = brdfpack.sample_pairs(a.pairs, kind="uniform", seed=1)
    rows = []
    for r in range(a.rounds):
        load = os.getloadavg()[0]  # the other processes' share of the machine, as printed
        rust = rust_lookup(a.bin, a.pairs, a.runs)
        py = python_eval(table, wi, wo, a.runs)
        fresh = python_eval(table, wi, wo, a.runs, reuse=False)
        exact = python_eval(table, wi, wo, max(1, a.runs // 3), exact=True) if a.exact else None
        rows.append((rust, py, exact, fresh, load))
        print(
            f"round {r + 1}: rust {rust * 1e3:.1f} ms, python {py * 1e3:.1f} ms "
            f"(new array each call {fresh * 1e3:.1f} ms), ratio {rust / py:.3f}",
            file=sys.stderr,
        )
    print(
        "| round | Rust `eval_batch` (ms) | Python `Table.eval(out=)` (ms) | ratio (Python/Rust "
        "throughput) | Python `Table.eval` new array (ms) | ratio | load average (1 min) |"
    )
    print("|---|---|---|---|---|---|---|")
    for k, (rust, py, _, fresh, load) in enumerate(rows):
        print(
            f"| {k + 1} | {rust * 1e3:.1f} | {py * 1e3:.1f} | {rust / py:.3f} | "
            f"{fresh * 1e3:.1f} | {rust / fresh:.3f} | {load:.2f} |"
        )
    ratio = statistics.median(rust / py for rust, py, _, _, _ in rows)
    fresh_ratio = statistics.median(rust / f for rust, _, _, f, _ in rows)
    print(
        f"\nmedian ratio over {a.rounds} rounds: {ratio:.3f} into `out=`, {fresh_ratio:.3f} "
        f"with a new array per call ({a.pairs} pairs, {a.runs} runs each)"
    )
    if a.exact:
        ex = statistics.median(e for _, _, e, _, _ in rows)
        rust = statistics.median(r for r, _, _, _, _ in rows)
        print(f"eval(exact=True): median {ex * 1e3:.1f} ms, ratio {rust / ex:.3f}")
    if a.min_ratio is not None and ratio < a.min_ratio:
        print(f"ratio {ratio:.3f} below {a.min_ratio}", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
