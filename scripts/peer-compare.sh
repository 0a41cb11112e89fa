#!/usr/bin/env bash
# Issue 6: brdfpack against Mitsuba 3 (llvm_ad_rgb), A/B interleaved on this machine.
#
# Each round runs, back to back, the peer and our in-process benchmark for
#   1. GGX conductor (RGB) on the MERL grid            target ratio ours/peer <= 0.33
#   2. anisotropic GGX conductor on a 64^4 grid          target <= 0.5
#   3. 10^6 random interpolated lookups (pairs/s)        target ours/peer >= 1
# then prints per-round ratios and their median and spread. Both sides time only the work
# (median of RUNS runs after a warm-up, into memory reused between runs).
#
#   scripts/peer-compare.sh                 # ROUNDS=3 RUNS=5 by default
#   ROUNDS=5 THREADS=2 scripts/peer-compare.sh
#
# Needs Mitsuba 3 (see ../shared/peers/README.md):
#   python3 -m venv /tmp/mitsuba-venv && /tmp/mitsuba-venv/bin/pip install mitsuba==3.9.1 numpy
#   apt-get update && apt-get install -y libllvm19
set -euo pipefail
cd "$(dirname "$0")/.."
ROUNDS=${ROUNDS:-3}
RUNS=${RUNS:-5}
VENV=${MITSUBA_VENV:-/tmp/mitsuba-venv}
export DRJIT_LIBLLVM_PATH=${DRJIT_LIBLLVM_PATH:-/usr/lib/x86_64-linux-gnu/libLLVM.so.19.1}
if [[ -n ${BRDFPACK_SHARED:-} ]]; then SHARED=$BRDFPACK_SHARED
elif [[ -d ../shared ]]; then SHARED=../shared
else SHARED=/work/shared; fi
SHARED=$(cd "$SHARED" 2>/dev/null && pwd || echo "$SHARED")
PEERS=$SHARED/peers/mitsuba
PY=$VENV/bin/python

if [[ ! -x $PY ]] || ! "$PY" -c 'import mitsuba' 2>/dev/null || [[ ! -f $DRJIT_LIBLLVM_PATH ]] \
    || [[ ! -d $PEERS ]]; then
  cat <<MSG
Mitsuba 3 is not installed (or $PEERS is missing); to compare, install it once:
  python3 -m venv $VENV && $VENV/bin/pip install mitsuba==3.9.1 numpy
  apt-get update && apt-get install -y libllvm19      # LLVM 19: Debian's LLVM 15 makes Dr.Jit abort
and run again (MITSUBA_VENV, DRJIT_LIBLLVM_PATH and BRDFPACK_SHARED override the paths).
Our side alone: cargo run --release -- bench --speed
MSG
  exit 0
fi

cargo build --release --quiet
BIN=$PWD/target/release/brdfpack
# THREADS limits our side (rayon); Dr.Jit uses every core.
[[ -n ${THREADS:-} ]] && export RAYON_NUM_THREADS=$THREADS
GGX='{"model":"ggx_conductor","alpha":0.2,"eta":[0.2004,0.924,1.1022],"k":[3.9129,2.4528,2.1421]}'
ANISO='{"model":"ggx_conductor","alpha_u":0.1,"alpha_v":0.4,"eta":[0.1431,0.3749,1.4425],"k":[3.9831,2.3857,1.6032]}'
OUT=$(mktemp -d)
trap 'rm -rf "$OUT"' EXIT

ours() { "$BIN" bench --json --runs "$RUNS" "$@" 2>/dev/null; }
for r in $(seq 1 "$ROUNDS"); do
  echo "round $r/$ROUNDS (load $(cut -d' ' -f1 /proc/loadavg))" >&2
  (cd "$PEERS" && "$PY" ref_table.py --grid merl --variant llvm_ad_rgb --bench "$RUNS" --spec "$GGX") \
    >"$OUT/peer_merl_$r.json"
  ours --tabulate-only | grep merl >"$OUT/ours_merl_$r.json"
  (cd "$PEERS" && "$PY" ref_table.py --grid aniso4d --n 64 --variant llvm_ad_rgb --bench "$RUNS" \
    --spec "$ANISO") >"$OUT/peer_aniso_$r.json"
  ours --tabulate-only | grep aniso64 >"$OUT/ours_aniso_$r.json"
  (cd "$PEERS" && "$PY" bench_measured.py --variant llvm_ad_rgb --n 1000000 --runs "$RUNS") \
    | grep '^MEDIAN' >"$OUT/peer_lookup_$r.txt"
  ours --lookup-only >"$OUT/ours_lookup_$r.json"
  # The whole CLI process (parse, tabulate, zstd-19 encode, write) for the MERL grid.
  /usr/bin/env time -f '%e' -o "$OUT/cli_$r.txt" "$BIN" tabulate \
    'ggx:alpha=0.2,shadowing=smith-separable,fresnel=conductor,eta=0.2004/0.924/1.1022,k=3.9129/2.4528/2.1421' \
    --grid merl -o "$OUT/merl.bpk" 2>/dev/null || true
done

python3 - "$OUT" "$ROUNDS" <<'PY'
import json, re, statistics, sys
out, rounds = sys.argv[1], int(sys.argv[2])
def j(p): return json.loads(open(p).read().strip().splitlines()[-1])
rows = {"merl": [], "aniso": [], "lookup": []}
cli = []
for r in range(1, rounds + 1):
    pm, om = j(f"{out}/peer_merl_{r}.json"), j(f"{out}/ours_merl_{r}.json")
    rows["merl"].append((om["timing"]["median_s"], pm["median_eval_s"]))
    pa, oa = j(f"{out}/peer_aniso_{r}.json"), j(f"{out}/ours_aniso_{r}.json")
    rows["aniso"].append((oa["timing"]["median_s"], pa["median_eval_s"]))
    m = re.search(r"kernel/eval ([0-9.]+) s", open(f"{out}/peer_lookup_{r}.txt").read())
    ol = j(f"{out}/ours_lookup_{r}.json")
    rows["lookup"].append((ol["timing"]["median_s"], float(m.group(1))))
    try: cli.append(float(open(f"{out}/cli_{r}.txt").read().split()[-1]))
    except Exception: pass
targets = {"merl": ("time ours/peer", 0.33, "<="), "aniso": ("time ours/peer", 0.5, "<="),
           "lookup": ("pairs/s ours/peer", 1.0, ">=")}
print("workload  round  ours_s    peer_s    ratio")
for k, v in rows.items():
    ratios = []
    for i, (o, p) in enumerate(v):
        ratio = o / p if k != "lookup" else p / o
        ratios.append(ratio)
        print(f"{k:<8}  {i+1:>5}  {o:8.4f}  {p:8.4f}  {ratio:6.3f}")
    name, t, op = targets[k]
    med = statistics.median(ratios)
    ok = med <= t if op == "<=" else med >= t
    print(f"{k:<8}  median {name} = {med:.3f} (spread {min(ratios):.3f}..{max(ratios):.3f}); "
          f"target {op} {t}: {'MET' if ok else 'NOT MET'}")
if cli:
    print(f"whole 'brdfpack tabulate' process, MERL grid, zstd 19: median {statistics.median(cli):.2f} s "
          f"(spread {min(cli):.2f}..{max(cli):.2f})")
PY
