#!/usr/bin/env bash
# Shows that the hard-case suite (tests/hard_cases.rs) catches the removal of a numerical
# guard: copies the tree to target/break-a-guard/tree, applies a small patch that removes one
# guard, runs `cargo test --test hard_cases` there with its own target dir, and reports the
# failing tests. The real tree is never modified.
#
#   scripts/break-a-guard.sh ward   # Ward: the `falloff == 0` early return (0 · ∞ = NaN)
#   scripts/break-a-guard.sh as     # Ashikhmin–Shirley: the sin²θh = 0 guard (0/0 exponent)
#   scripts/break-a-guard.sh f16    # f16 quantizer: the scale that keeps peaks below 65504
#
# Exit 0 when the suite fails (the guard is covered), 1 when it passes (not covered), 2 on a
# usage or patch error. Set BRDFPACK_SHARED to include the measured-data tests.
set -euo pipefail

guard=${1:-}
root=$(cd "$(dirname "$0")/.." && pwd)
work="$root/target/break-a-guard"
tree="$work/tree"

patch_for() {
  case "$1" in
    ward) cat <<'PATCH'
--- a/src/model/ward.rs
+++ b/src/model/ward.rs
@@ -128,9 +128,6 @@
         let e = if num == 0.0 { 0.0 } else { num / sqr(hv.z) };
         let falloff = (-e).exp();
         // Underflowed exponential: the lobe is 0 even where P overflows (no 0·∞).
-        if falloff == 0.0 {
-            return 0.0;
-        }
         let p = match self.variant {
             // sqrt(c_i) sqrt(c_o): the product c_i c_o underflows near the horizon.
             WardVariant::Ward => 1.0 / (4.0 * PI * ax * ay * wi.z.sqrt() * wo.z.sqrt()),
PATCH
    ;;
    as) cat <<'PATCH'
--- a/src/model/ashikhmin_shirley.rs
+++ b/src/model/ashikhmin_shirley.rs
@@ -97,11 +97,7 @@
         // 1 − h.z² as h.x² + h.y² (no cancellation); 0 at the normal, where e is 0/0 but
         // h.z = 1 makes h.z^e = 1 for any e.
         let sin2_h = h.sin2_theta();
-        let e = if sin2_h == 0.0 {
-            0.0
-        } else {
-            (self.nu * sqr(h.x) + self.nv * sqr(h.y)) / sin2_h
-        };
+        let e = (self.nu * sqr(h.x) + self.nv * sqr(h.y)) / sin2_h;
         // Eq. 4: the specular lobe without its Fresnel factor; h.z^e in log space (e ≤ 1e6).
         let lobe = if k <= 0.0 {
             // Back-facing half vector (rounding only above the horizon).
PATCH
    ;;
    f16) cat <<'PATCH'
--- a/src/codec/quantize.rs
+++ b/src/codec/quantize.rs
@@ -24,11 +24,7 @@
 impl Quantizer {
     /// An f16 quantizer for components whose largest magnitude is `max_abs`.
     pub fn f16_for(max_abs: f64) -> Quantizer {
-        let scale = if max_abs > F16_LIMIT {
-            F16_LIMIT / max_abs
-        } else {
-            1.0
-        };
+        let scale = 1.0;
         Quantizer::F16 { scale }
     }
 
PATCH
    ;;
    *) return 1 ;;
  esac
}

if ! patch_for "$guard" >/dev/null; then
  echo "usage: $0 ward|as|f16" >&2
  exit 2
fi

# A fresh copy of the tree (tracked and new files, not target/).
rm -rf "$tree"
mkdir -p "$tree"
(cd "$root" && git ls-files -co --exclude-standard -z | tar --null -T - -cf -) | tar -xf - -C "$tree"
if ! patch_for "$guard" | patch -d "$tree" -p1 --forward --no-backup-if-mismatch; then
  echo "break-a-guard: the $guard patch no longer applies; update it in $0" >&2
  exit 2
fi
echo "== removed guard '$guard' in $tree:"
(cd "$tree" && patch_for "$guard" | sed -n '/^[-+][^-+]/p')

# Own target dir, seeded from the real one's dependencies when it is first created (only
# brdfpack itself is then rebuilt).
export CARGO_TARGET_DIR="$work/target"
if [ ! -d "$CARGO_TARGET_DIR/debug" ] && [ -d "$root/target/debug/deps" ]; then
  mkdir -p "$CARGO_TARGET_DIR/debug"
  cp -a "$root/target/debug/build" "$root/target/debug/deps" "$root/target/debug/.fingerprint" \
    "$CARGO_TARGET_DIR/debug/" 2>/dev/null || true
fi

log="$work/$guard.log"
start=$(date +%s)
set +e
(cd "$tree" && RUST_BACKTRACE=0 cargo test --test hard_cases 2>&1) >"$log"
rc=$?
set -e
echo "== cargo test --test hard_cases: exit $rc after $(( $(date +%s) - start )) s (log: $log)"
grep -E '^test result:' "$log" || true
if [ "$rc" -eq 0 ]; then
  echo "break-a-guard: NOT CAUGHT: the suite passes without the '$guard' guard" >&2
  exit 1
fi
if ! grep -q '^failures:' "$log"; then
  echo "break-a-guard: cargo failed before running the suite; see $log" >&2
  exit 2
fi
echo "== failing tests:"
awk '/^failures:$/ {n++} n == 2 && /^    / {print}' "$log"
echo "== their messages (first lines, repeats dropped):"
awk '/^---- .* stdout ----$/ {p = 12}
     p > 0 && !/^(stack backtrace:|note: |proptest: |$)/ && !seen[$0]++ {print; p--}' "$log" |
  cut -c1-300
echo "break-a-guard: caught: the suite fails without the '$guard' guard"
