//! The fast inverse DCT of [`super::dct`]: the coefficient box is expanded to the grid one axis
//! at a time, like the reference decoder, but
//!
//! 1. in the axis order that costs the fewest multiply-adds (each pass costs the current array
//!    size × N/2; expanding the axes whose box is small relative to N last keeps the arrays
//!    small for longest);
//! 2. with half the work per output: the DCT-II basis is mirror-symmetric,
//!    cos(π(N−1−n+½)k/N) = (−1)^k cos(π(n+½)k/N), so out[n] = E + O and out[N−1−n] = E − O
//!    with E the sum over even frequencies and O over odd ones;
//! 3. skipping coefficient rows that are entirely zero (adding a zero product never changes a
//!    sum that starts at +0, so the skip is exact);
//! 4. vectorized across the lines of the pass (or across outputs for the contiguous axis),
//!    through the portable/AVX2 dispatch of [`super::simd`] (same bits on every CPU).
//!
//! Results differ from the reference only by f32 rounding (another summation order), far
//! below the quantization noise: tested against the reference decoder.

use super::dct::{Coefficients, dct_matrix};
use super::simd::dispatch;

/// One axis of the inverse: the transposed DCT basis truncated to the box's frequencies,
/// for the first half of the outputs only. `rows[k·hp + n]` = C[k][n] (n < h = ⌈N/2⌉, zero
/// padded to `hp`); for odd N the middle output has O = 0 exactly, so its odd entries are 0.
struct HalfBasis {
    n: usize,
    e: usize,
    h: usize,
    hp: usize,
    rows: Vec<f32>,
}

/// Width of the register tiles of the contiguous kernel (outputs per tile).
const TILE_N: usize = 16;

impl HalfBasis {
    fn new(n: usize, e: usize) -> HalfBasis {
        let full = dct_matrix(n);
        let h = n.div_ceil(2);
        let hp = h.div_ceil(TILE_N) * TILE_N;
        let mut rows = vec![0f32; e * hp];
        for k in 0..e {
            for j in 0..h {
                let middle = n % 2 == 1 && j == n / 2;
                rows[k * hp + j] = if middle && k % 2 == 1 {
                    0.0
                } else {
                    full[k * n + j] as f32
                };
            }
        }
        HalfBasis { n, e, h, hp, rows }
    }
}

/// The axis order with the fewest multiply-adds for a box `extent` on grid `dims` (ties: the
/// first permutation in lexicographic order, so the choice is deterministic).
pub(crate) fn axis_order(extent: &[usize], dims: &[usize]) -> Vec<usize> {
    let d = dims.len();
    let mut best: Option<(f64, Vec<usize>)> = None;
    let mut perm: Vec<usize> = (0..d).collect();
    loop {
        let mut cur: Vec<f64> = extent.iter().map(|&e| e as f64).collect();
        let mut cost = 0.0;
        for &a in &perm {
            let size: f64 = cur.iter().product();
            cost += size * dims[a].div_ceil(2) as f64;
            cur[a] = dims[a] as f64;
        }
        if best.as_ref().is_none_or(|(c, _)| cost < *c) {
            best = Some((cost, perm.clone()));
        }
        if !next_permutation(&mut perm) {
            break;
        }
    }
    best.map(|(_, p)| p).unwrap_or_default()
}

fn next_permutation(p: &mut [usize]) -> bool {
    let n = p.len();
    if n < 2 {
        return false;
    }
    let mut i = n - 1;
    while i > 0 && p[i - 1] >= p[i] {
        i -= 1;
    }
    if i == 0 {
        return false;
    }
    let mut j = n - 1;
    while p[j] <= p[i - 1] {
        j -= 1;
    }
    p.swap(i - 1, j);
    p[i..].reverse();
    true
}

/// Reconstructs one component plane (every cell) from its quantized box, in f32.
pub fn inverse(c: &Coefficients, dims: &[usize], step: f64) -> Vec<f32> {
    let cells: usize = dims.iter().product();
    let mut out = vec![0f32; cells];
    inverse_into(c, dims, step, &mut out, &mut Vec::new());
    out
}

/// [`inverse`] into `out` (every cell), with `scratch` reused between calls.
pub fn inverse_into(
    c: &Coefficients,
    dims: &[usize],
    step: f64,
    out: &mut [f32],
    scratch: &mut Vec<f32>,
) {
    let cells: usize = dims.iter().product();
    let out = &mut out[..cells];
    if c.codes.is_empty() || c.extent.len() != dims.len() {
        out.fill(0.0);
        return;
    }
    let order = axis_order(&c.extent, dims);
    // Ping-pong between `out` and `scratch`, arranged so that the last pass writes `out`.
    scratch.clear();
    scratch.resize(cells, 0.0);
    let passes = order.len();
    let mut cur_dims = c.extent.clone();
    let box_len = c.codes.len();
    {
        // The dequantized box goes where pass 0 reads it.
        let first: &mut [f32] = if passes % 2 == 0 { out } else { scratch };
        for (d, &q) in first.iter_mut().zip(&c.codes) {
            *d = (q as f64 * step) as f32;
        }
    }
    let mut len = box_len;
    for (i, &a) in order.iter().enumerate() {
        let n = dims[a];
        let e = cur_dims[a];
        let outer: usize = cur_dims[..a].iter().product();
        let inner: usize = cur_dims[a + 1..].iter().product();
        let basis = HalfBasis::new(n, e);
        let new_len = outer * n * inner;
        let reads_scratch = (passes - i) % 2 == 1;
        let (src, dst): (&[f32], &mut [f32]) = if reads_scratch {
            (&scratch[..len], &mut out[..new_len])
        } else {
            (&out[..len], &mut scratch[..new_len])
        };
        if inner == 1 {
            expand_contiguous(src, dst, outer, &basis);
        } else {
            expand_strided(src, dst, outer, inner, &basis);
        }
        cur_dims[a] = n;
        len = new_len;
    }
}

dispatch!(fn expand_contiguous / expand_contiguous_avx2 => contiguous_impl(src: &[f32], dst: &mut [f32], outer: usize, b: &HalfBasis));
dispatch!(fn expand_strided / expand_strided_avx2 => strided_impl(src: &[f32], dst: &mut [f32], outer: usize, inner: usize, b: &HalfBasis));

/// The expanded axis is the fastest one: out[o][n] = Σ_k C[k][n] in[o][k], vectorized across
/// n in tiles of [`TILE_N`] outputs held in registers.
#[inline(always)]
fn contiguous_impl(src: &[f32], dst: &mut [f32], outer: usize, b: &HalfBasis) {
    let (e, n, h, hp) = (b.e, b.n, b.h, b.hp);
    let mut even: Vec<(usize, f32)> = Vec::with_capacity(e);
    let mut odd: Vec<(usize, f32)> = Vec::with_capacity(e);
    let mut ev = vec![0f32; hp];
    let mut od = vec![0f32; hp];
    for o in 0..outer {
        let s = &src[o * e..(o + 1) * e];
        let d = &mut dst[o * n..(o + 1) * n];
        even.clear();
        odd.clear();
        for (k, &w) in s.iter().enumerate() {
            if w != 0.0 {
                if k % 2 == 0 {
                    even.push((k, w));
                } else {
                    odd.push((k, w));
                }
            }
        }
        for t0 in (0..hp).step_by(TILE_N) {
            let mut te = [0f32; TILE_N];
            let mut to = [0f32; TILE_N];
            for &(k, w) in &even {
                let row: &[f32; TILE_N] = b.rows[k * hp + t0..k * hp + t0 + TILE_N]
                    .try_into()
                    .expect("tile inside the padded row");
                for l in 0..TILE_N {
                    te[l] += w * row[l];
                }
            }
            for &(k, w) in &odd {
                let row: &[f32; TILE_N] = b.rows[k * hp + t0..k * hp + t0 + TILE_N]
                    .try_into()
                    .expect("tile inside the padded row");
                for l in 0..TILE_N {
                    to[l] += w * row[l];
                }
            }
            ev[t0..t0 + TILE_N].copy_from_slice(&te);
            od[t0..t0 + TILE_N].copy_from_slice(&to);
        }
        for j in 0..h {
            d[j] = ev[j] + od[j];
        }
        for j in 0..n / 2 {
            d[n - 1 - j] = ev[j] - od[j];
        }
    }
}

/// The expanded axis has `inner` > 1 values per index: out[o][n][x] = Σ_k C[k][n] in[o][k][x],
/// vectorized across x in tiles (a tile of every nonzero row stays in L1 across all n).
#[inline(always)]
fn strided_impl(src: &[f32], dst: &mut [f32], outer: usize, inner: usize, b: &HalfBasis) {
    let e = b.e;
    let n = b.n;
    let mut even = Vec::with_capacity(e);
    let mut odd = Vec::with_capacity(e);
    for o in 0..outer {
        let s = &src[o * e * inner..(o + 1) * e * inner];
        let d = &mut dst[o * n * inner..(o + 1) * n * inner];
        even.clear();
        odd.clear();
        for k in 0..e {
            if s[k * inner..(k + 1) * inner].iter().any(|&v| v != 0.0) {
                if k % 2 == 0 {
                    even.push(k);
                } else {
                    odd.push(k);
                }
            }
        }
        let mut x0 = 0;
        while x0 + 32 <= inner {
            strided_tile::<32>(s, d, inner, x0, b, &even, &odd);
            x0 += 32;
        }
        while x0 + 8 <= inner {
            strided_tile::<8>(s, d, inner, x0, b, &even, &odd);
            x0 += 8;
        }
        while x0 < inner {
            strided_tile::<1>(s, d, inner, x0, b, &even, &odd);
            x0 += 1;
        }
    }
}

#[inline(always)]
fn strided_tile<const T: usize>(
    s: &[f32],
    d: &mut [f32],
    inner: usize,
    x0: usize,
    b: &HalfBasis,
    even: &[usize],
    odd: &[usize],
) {
    let tile = |k: usize| -> &[f32; T] {
        s[k * inner + x0..k * inner + x0 + T]
            .try_into()
            .expect("tile inside the line")
    };
    for j in 0..b.h {
        let mut te = [0f32; T];
        let mut to = [0f32; T];
        for &k in even {
            let w = b.rows[k * b.hp + j];
            let v = tile(k);
            for l in 0..T {
                te[l] += w * v[l];
            }
        }
        for &k in odd {
            let w = b.rows[k * b.hp + j];
            let v = tile(k);
            for l in 0..T {
                to[l] += w * v[l];
            }
        }
        let lo = j * inner + x0;
        for l in 0..T {
            d[lo + l] = te[l] + to[l];
        }
        let m = b.n - 1 - j;
        if m != j {
            let hi = m * inner + x0;
            for l in 0..T {
                d[hi + l] = te[l] - to[l];
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::codec::dct::{forward, quantize};
    use crate::codec::reference;
    use proptest::prelude::*;

    #[test]
    fn the_cheapest_order_expands_small_boxes_last() {
        // A box thin along axis 2 relative to its resolution: expand it last.
        assert_eq!(axis_order(&[40, 40, 4], &[90, 90, 180]), vec![0, 1, 2]);
        assert_eq!(axis_order(&[4, 80, 170], &[90, 90, 180]), vec![2, 1, 0]);
        assert_eq!(axis_order(&[3], &[7]), vec![0]);
    }

    /// Largest |fast − reference| relative to the largest |reference| value.
    fn relative_gap(c: &Coefficients, dims: &[usize], step: f64) -> f64 {
        let a = inverse(c, dims, step);
        let b = reference::dct_inverse(c, dims, step);
        assert_eq!(a.len(), b.len());
        let scale = b.iter().fold(0f32, |m, v| m.max(v.abs())).max(f32::MIN_POSITIVE) as f64;
        a.iter()
            .zip(&b)
            .map(|(x, y)| (*x as f64 - *y as f64).abs())
            .fold(0.0, f64::max)
            / scale
    }

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(64))]
        /// Both decoders compute the same sums in f32 in another order: the gap is f32
        /// rounding, ≤ (box terms summed) × 2⁻²⁴ relative; 1e-5 leaves room for 3–4 axes.
        #[test]
        fn matches_the_reference_decoder(
            d0 in 1usize..9, d1 in 1usize..9, d2 in 1usize..13, seed in any::<u64>(),
            step in 1e-3f64..0.5,
        ) {
            let dims = [d0, d1, d2];
            let n = d0 * d1 * d2;
            let mut rng = crate::math::SplitMix64::new(seed);
            let plane: Vec<f64> = (0..n).map(|_| rng.next_f64() * 4.0 - 2.0).collect();
            let q = quantize(&forward(&plane, &dims), &dims, step);
            let gap = relative_gap(&q, &dims, step);
            prop_assert!(gap <= 1e-5, "gap {gap} for box {:?} of {dims:?}", q.extent);
        }
    }

    #[test]
    fn a_merl_sized_box_matches_the_reference() {
        // Sparse rows (only some frequencies set) exercise the zero-row skip.
        let dims = [90usize, 90, 180];
        let extent = vec![9usize, 20, 37];
        let total: usize = extent.iter().product();
        let mut rng = crate::math::SplitMix64::new(3);
        let codes: Vec<i32> = (0..total)
            .map(|i| {
                if (i / 37) % 3 == 1 {
                    0
                } else {
                    (rng.next_f64() * 2000.0 - 1000.0) as i32
                }
            })
            .collect();
        let c = Coefficients { extent, codes };
        let gap = relative_gap(&c, &dims, 1e-3);
        assert!(gap <= 1e-5, "gap {gap}");
    }

    #[test]
    fn four_axes_and_degenerate_boxes() {
        let dims = [5usize, 4, 3, 6];
        let c = Coefficients {
            extent: vec![2, 1, 3, 5],
            codes: (0..30).map(|i| i - 15).collect(),
        };
        assert!(relative_gap(&c, &dims, 0.01) <= 1e-5);
        let empty = Coefficients {
            extent: vec![0; 4],
            codes: vec![],
        };
        assert_eq!(inverse(&empty, &dims, 0.01), vec![0.0; 360]);
    }
}
