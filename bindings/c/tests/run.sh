#!/usr/bin/env bash
# The C example against the CLI (issue 25, done-when 2): compiled with cc -Wall -Werror
# against the generated header, linked dynamically and statically, it prints the values
# `brdfpack eval` prints, bit for bit (a .bpk from a path and from memory, a model, an RGL
# file); a corrupt buffer, a truncated file and a bad spec give an error code and message,
# not a crash. Usage: bindings/c/tests/run.sh PROFILE_DIR (e.g. target/debug, which holds
# brdfpack and libbrdfpack_c.{so,a}: `cargo build && cargo build -p brdfpack-c`).
set -euo pipefail
cd "$(dirname "$0")/../../.."
dir=${1:-target/debug}
bin=$dir/brdfpack
tmp=$(mktemp -d)
trap 'rm -rf "$tmp"' EXIT
passed=0
failed=0
ok() { passed=$((passed + 1)); echo "ok: $*"; }
bad() { failed=$((failed + 1)); echo "FAILED: $*"; }

cflags=(-Wall -Wextra -Werror -std=c11 -Ibindings/c/include)
cc "${cflags[@]}" bindings/c/examples/eval_pairs.c -L"$dir" -lbrdfpack_c \
    -Wl,-rpath,"$PWD/$dir" -o "$tmp/eval_pairs"
cc "${cflags[@]}" bindings/c/examples/eval_pairs.c "$dir/libbrdfpack_c.a" \
    -lm -lpthread -ldl -o "$tmp/eval_pairs_static"
ok "the example compiles with cc -Wall -Wextra -Werror (shared and static)"

# Same numbers, bit for bit: both sides parsed as f64 by Python (exact for %.17g and for
# Rust's shortest round-trip form).
same() {
    python3 - "$1" "$2" <<'PY'
import struct, sys
rows = [[l.split() for l in open(p).read().splitlines() if l.strip()] for p in sys.argv[1:]]
a, b = ([[struct.pack("<d", float(x)) for x in r] for r in rs] for rs in rows)
sys.exit(0 if a == b and len(a) > 0 else 1)
PY
}

python3 - > "$tmp/pairs.txt" <<'PY'
import random
random.seed(4)
for _ in range(500):
    v = [random.gauss(0, 1) for _ in range(6)]
    v[2], v[5] = abs(v[2]), abs(v[5])
    print(" ".join(f"{x:.17g}" for x in v))
PY
printf '0 0 1 0 0 1\n0.5 0 0.8660254037844386 -0.5 0 0.8660254037844386\n0.3 0.4 0.8660254037844386 0.1 -0.6 0.7937253933193772\n' > "$tmp/fixed.txt"
"$bin" tabulate 'ggx:alpha=0.3,fresnel=au' --grid halfdiff3:24x12x24 --codec dct:step=0.05 -o "$tmp/t.bpk"

check_same() {
    local what=$1 want=$2 got=$3
    if same "$want" "$got"; then ok "$what"; else bad "$what"; diff <(head -3 "$want") <(head -3 "$got") || true; fi
}
"$bin" eval "$tmp/t.bpk" --input text < "$tmp/fixed.txt" > "$tmp/want"
"$tmp/eval_pairs" "$tmp/t.bpk" > "$tmp/got" 2> "$tmp/err"
check_same "three fixed pairs of a .bpk (shared library)" "$tmp/want" "$tmp/got"
grep -q "table: 3 axes (24x12x24), 3 channels, 20736 floats decoded" "$tmp/err" && ok "grid and decode" || bad "grid and decode: $(cat "$tmp/err")"
"$bin" eval "$tmp/t.bpk" --input text < "$tmp/pairs.txt" > "$tmp/want"
"$tmp/eval_pairs" "$tmp/t.bpk" - < "$tmp/pairs.txt" > "$tmp/got" 2>/dev/null
check_same "500 pairs of a .bpk" "$tmp/want" "$tmp/got"
"$tmp/eval_pairs_static" --memory "$tmp/t.bpk" - < "$tmp/pairs.txt" > "$tmp/got" 2>/dev/null
check_same "500 pairs of a .bpk from memory (static library)" "$tmp/want" "$tmp/got"
model='lambert:albedo=0.2/0.4/0.6+phong:albedo=0.3,exponent=20'
"$bin" eval "$model" --input text < "$tmp/pairs.txt" > "$tmp/want"
"$tmp/eval_pairs" "$model" - < "$tmp/pairs.txt" > "$tmp/got"
check_same "500 pairs of a model" "$tmp/want" "$tmp/got"
rgl=fixtures/rgl/tiny.bsdf
"$bin" eval "$rgl" --input text < "$tmp/pairs.txt" > "$tmp/want"
"$tmp/eval_pairs" --memory "$rgl" - < "$tmp/pairs.txt" > "$tmp/got"
check_same "500 pairs of an RGL file from memory" "$tmp/want" "$tmp/got"

# Errors: an exit code the example chose (2 input, 1 other), never a signal; the message.
expect_error() {
    local what=$1 code=$2 pattern=$3
    shift 3
    set +e
    "$@" > /dev/null 2> "$tmp/err" < /dev/null
    local rc=$?
    set -e
    if [ "$rc" -ge 1 ] && [ "$rc" -le 2 ] && grep -q "code $code: brdfpack: .*$pattern" "$tmp/err"; then
        ok "$what: $(head -c 160 "$tmp/err")"
    else
        bad "$what: exit $rc, $(cat "$tmp/err")"
    fi
}
head -c 300 "$tmp/t.bpk" > "$tmp/truncated.bpk"
expect_error "a truncated .bpk in memory" 3 "" "$tmp/eval_pairs" --memory "$tmp/truncated.bpk"
python3 -c "import os,sys; sys.stdout.buffer.write(b'\x89BPK\r\n\x1a\n' + bytes(range(256)) * 8)" > "$tmp/garbage.bpk"
expect_error "a corrupt .bpk header in memory" 3 "" "$tmp/eval_pairs_static" --memory "$tmp/garbage.bpk"
python3 - "$tmp/t.bpk" "$tmp/flipped.bpk" <<'PY'
import sys
b = bytearray(open(sys.argv[1], "rb").read())
b[len(b) // 2] ^= 0xFF
open(sys.argv[2], "wb").write(bytes(b))
PY
expect_error "a .bpk with a flipped payload byte in memory" 3 "" "$tmp/eval_pairs" --memory "$tmp/flipped.bpk"
head -c 5000 /dev/zero > "$tmp/zeros"
expect_error "5000 zero bytes in memory" 3 "unknown format" "$tmp/eval_pairs" --memory "$tmp/zeros"
expect_error "an unknown model" 2 "no-such-model" "$tmp/eval_pairs" 'no-such-model:alpha=1'
expect_error "a missing file" 4 "missing.bpk" "$tmp/eval_pairs" ./missing.bpk
printf '0 0 1 0 0 0\n' > "$tmp/zero.txt"
set +e
"$tmp/eval_pairs" "$tmp/t.bpk" - < "$tmp/zero.txt" > /dev/null 2> "$tmp/err"
rc=$?
set -e
if [ "$rc" = 2 ] && grep -q "code 2: brdfpack: row 0: wo has zero length" "$tmp/err"; then
    ok "a zero-length direction"
else
    bad "a zero-length direction: exit $rc, $(cat "$tmp/err")"
fi

echo "c_example: $passed passed, $failed failed"
[ "$failed" = 0 ]
