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

#![allow(clippy::needless_range_loop)] // Lane loops index several parallel arrays.

use super::DecodeScratch;
use super::dct::{Coefficients, dct_entry};
use super::simd::{Finisher, dispatch, finish};

/// One axis of the inverse: the transposed DCT basis truncated to the box's frequencies,
/// for the first half of the outputs only. `rows[k·hp + n]` = C[k][n] (n < h = ⌈N/2⌉, zero
/// padded to `hp`); for odd N the middle output has O = 0 exactly, so its odd entries are 0.
struct HalfBasis {
    n: usize,
    e: usize,
    h: usize,
    hp: usize,
    rows: Vec<f32>,
    /// The same entries for the strided kernels, which read two outputs' weights per row:
    /// `pairs[p·e + k]` = (C[k][2p], C[k][2p + 1]) for 2p + 1 < h, contiguous in k (read
    /// from `rows`, a pair's weights are `hp` floats apart for every row, a cache line each).
    pairs: Vec<[f32; 2]>,
}

/// The row-major weights `rows[k·stride + t]` (k < e) regrouped two outputs at a time for the
/// strided kernels: `out[p·e + k]` = (rows[k·stride + 2p], rows[k·stride + 2p + 1]), p < `pairs`.
pub(crate) fn pair_major(rows: &[f32], stride: usize, e: usize, pairs: usize) -> Vec<[f32; 2]> {
    (0..pairs)
        .flat_map(|p| (0..e).map(move |k| (p, k)))
        .map(|(p, k)| [rows[k * stride + 2 * p], rows[k * stride + 2 * p + 1]])
        .collect()
}

/// Width of the register tiles of the contiguous kernel (outputs per tile).
const TILE_N: usize = 16;

impl HalfBasis {
    /// The weights of outputs j and j + 1 (j even) for every row: `[k]` = (C[k][j], C[k][j+1]).
    #[inline(always)]
    fn pair(&self, j: usize) -> &[[f32; 2]] {
        &self.pairs[j / 2 * self.e..(j / 2 + 1) * self.e]
    }

    fn new(n: usize, e: usize) -> HalfBasis {
        let h = n.div_ceil(2);
        let hp = h.div_ceil(TILE_N) * TILE_N;
        let mut rows = vec![0f32; e * hp];
        for k in 0..e {
            for j in 0..h {
                let middle = n % 2 == 1 && j == n / 2;
                rows[k * hp + j] = if middle && k % 2 == 1 {
                    0.0
                } else {
                    dct_entry(n, k, j) as f32
                };
            }
        }
        let pairs = pair_major(&rows, hp, e, h / 2);
        HalfBasis {
            n,
            e,
            h,
            hp,
            rows,
            pairs,
        }
    }
}

/// Multiply-adds (up to a constant) of expanding a box `extent` to `dims` in axis order
/// `perm`: each pass costs the current array size × ⌈N/2⌉ (mirror symmetry).
fn order_cost(extent: &[usize], dims: &[usize], perm: &[usize]) -> f64 {
    let mut cur: Vec<f64> = extent.iter().map(|&e| e as f64).collect();
    let mut cost = 0.0;
    for &a in perm {
        let size: f64 = cur.iter().product();
        cost += size * dims[a].div_ceil(2) as f64;
        cur[a] = dims[a] as f64;
    }
    cost
}

/// The cheapest axis order (optionally the cheapest one ending with axis `last`) and its
/// cost; ties go to the first permutation in lexicographic order, so the choice is
/// deterministic.
fn cheapest_order(extent: &[usize], dims: &[usize], last: Option<usize>) -> (f64, Vec<usize>) {
    let d = dims.len();
    let mut best: Option<(f64, Vec<usize>)> = None;
    let mut perm: Vec<usize> = (0..d).collect();
    loop {
        if last.is_none_or(|l| perm.last() == Some(&l)) {
            let cost = order_cost(extent, dims, &perm);
            if best.as_ref().is_none_or(|(c, _)| cost < *c) {
                best = Some((cost, perm.clone()));
            }
        }
        if !next_permutation(&mut perm) {
            break;
        }
    }
    best.unwrap_or_default()
}

/// The axis order with the fewest multiply-adds for a box `extent` on grid `dims`.
pub(crate) fn axis_order(extent: &[usize], dims: &[usize]) -> Vec<usize> {
    cheapest_order(extent, dims, None).1
}

pub(crate) fn next_permutation(p: &mut [usize]) -> bool {
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

/// A separable expansion: `cur` (shape `cur_dims`; it may be longer, its tail is ignored)
/// taken to full resolution `dims[a]` along each axis of `order` in turn;
/// `pass(a, src, dst, outer, inner)` expands one axis (`dst` is `outer × dims[a] × inner`,
/// every value written by the pass). Shared by the DCT and Tucker decoders; the two arrays
/// come from `scratch` and are swapped, never zeroed (zeroing cost more than a pass on small
/// boxes). The result may be longer than its shape.
pub(crate) fn expand_axes(
    mut cur: Vec<f32>,
    mut cur_dims: Vec<usize>,
    dims: &[usize],
    order: &[usize],
    scratch: &mut DecodeScratch,
    mut pass: impl FnMut(usize, &[f32], &mut [f32], usize, usize),
) -> (Vec<f32>, Vec<usize>) {
    let mut next = scratch.take_f32(0);
    for &a in order {
        let n = dims[a];
        let outer: usize = cur_dims[..a].iter().product();
        let inner: usize = cur_dims[a + 1..].iter().product();
        let size_in = outer * cur_dims[a] * inner;
        let size = outer * n * inner;
        DecodeScratch::grow(&mut next, size);
        pass(a, &cur[..size_in], &mut next[..size], outer, inner);
        std::mem::swap(&mut cur, &mut next);
        cur_dims[a] = n;
    }
    scratch.give_f32(next);
    (cur, cur_dims)
}

/// The dequantized box expanded along the axes of `order` (in that order): the array (from
/// `scratch`, possibly longer than its shape) and its shape (expanded axes at full
/// resolution, the others at the box extent).
fn expand_along(
    c: &Coefficients,
    dims: &[usize],
    step: f64,
    order: &[usize],
    scratch: &mut DecodeScratch,
) -> (Vec<f32>, Vec<usize>) {
    let mut cur = scratch.take_f32(c.codes.len());
    for (d, &q) in cur.iter_mut().zip(&c.codes) {
        *d = (q as f64 * step) as f32;
    }
    expand_axes(
        cur,
        c.extent.clone(),
        dims,
        order,
        scratch,
        |a, src, dst, outer, inner| {
            let basis = HalfBasis::new(dims[a], c.extent[a]);
            if inner == 1 {
                expand_contiguous(src, dst, outer, &basis);
            } else {
                expand_strided(src, dst, outer, inner, &basis);
            }
        },
    )
}

/// [`expand_along`] of axes `first` and then the other inner axis of a 3-D box, through
/// [`slabs_impl`]: the array (from `scratch`) and its shape (e0, N1, N2).
fn slab_expand(
    c: &Coefficients,
    dims: &[usize],
    step: f64,
    first: usize,
    scratch: &mut DecodeScratch,
) -> (Vec<f32>, Vec<usize>) {
    let e = &c.extent;
    let shape = vec![e[0], dims[1], dims[2]];
    let mut out = scratch.take_f32(shape.iter().product());
    let mut tmp = scratch.take_f32(0);
    let b1 = HalfBasis::new(dims[1], e[1]);
    let b2 = HalfBasis::new(dims[2], e[2]);
    expand_slabs(c, step, first, &b1, &b2, &mut out, &mut tmp);
    scratch.give_f32(tmp);
    (out, shape)
}

/// Reconstructs one component plane (every cell) from its quantized box, in f32.
pub fn inverse(c: &Coefficients, dims: &[usize], step: f64) -> Vec<f32> {
    let cells: usize = dims.iter().product();
    if c.codes.is_empty() || c.extent.len() != dims.len() {
        return vec![0.0; cells];
    }
    let scratch = &mut DecodeScratch::default();
    let mut plane = expand_along(c, dims, step, &axis_order(&c.extent, dims), scratch).0;
    plane.truncate(cells);
    plane
}

/// Decodes every component of a DCT payload and finishes each cell (colour, curve, 1/w,
/// channel interleave, invalid cells 0) into `out` (cells × components values). For 1 and 3
/// components the last pass is fused with the finishing step: all components share their
/// last axis (the one with the lowest total cost), its output is produced a tile at a time
/// and finished while in cache, so no full-size component plane is ever written.
pub(crate) fn decode(
    comps: &[Coefficients],
    steps: &[f64],
    dims: &[usize],
    fin: &Finisher,
    valid: &[bool],
    out: &mut [f32],
    scratch: &mut DecodeScratch,
) {
    let c = comps.len();
    let d = dims.len();
    let empty = |q: &Coefficients| q.codes.is_empty() || q.extent.len() != d;
    if !(c == 1 || c == 3) || d == 0 {
        let planes: Vec<Vec<f32>> = comps
            .iter()
            .zip(steps)
            .map(|(q, &s)| inverse(q, dims, s))
            .collect();
        let views: Vec<&[f32]> = planes.iter().map(|p| p.as_slice()).collect();
        finish(fin, &views, valid, out);
        return;
    }
    // The shared last axis: the lowest total cost over the components.
    let mut best: Option<(f64, usize, Vec<Vec<usize>>)> = None;
    for last in 0..d {
        let mut total = 0.0;
        let mut orders = Vec::with_capacity(c);
        for q in comps {
            if empty(q) {
                orders.push(Vec::new());
            } else {
                let (cost, order) = cheapest_order(&q.extent, dims, Some(last));
                total += cost;
                orders.push(order);
            }
        }
        if best.as_ref().is_none_or(|(t, _, _)| total < *t) {
            best = Some((total, last, orders));
        }
    }
    let (_, last, orders) = best.expect("at least one axis");
    // Every pass but the last, per component; an empty component is a box of extent 0.
    let mut inter: Vec<(Vec<f32>, usize)> = Vec::with_capacity(c);
    let mut bases: Vec<HalfBasis> = Vec::with_capacity(c);
    for ((q, &s), order) in comps.iter().zip(steps).zip(&orders) {
        if empty(q) {
            inter.push((Vec::new(), 0));
            bases.push(HalfBasis::new(dims[last], 0));
        } else {
            let (a, shape) = if d == 3 && last == 0 {
                slab_expand(q, dims, s, order[0], scratch)
            } else {
                expand_along(q, dims, s, &order[..d - 1], scratch)
            };
            inter.push((a, shape.iter().product()));
            bases.push(HalfBasis::new(dims[last], q.extent[last]));
        }
    }
    let views: Vec<&[f32]> = inter.iter().map(|(p, len)| &p[..*len]).collect();
    let outer: usize = dims[..last].iter().product();
    let inner: usize = dims[last + 1..].iter().product();
    if c == 1 {
        final_1(&views, &bases, outer, inner, fin, valid, out);
    } else {
        final_3(&views, &bases, outer, inner, fin, valid, out);
    }
    for (p, _) in inter {
        scratch.give_f32(p);
    }
}

dispatch!(fn expand_contiguous / expand_contiguous_avx2 => contiguous_impl(src: &[f32], dst: &mut [f32], outer: usize, b: &HalfBasis));
dispatch!(fn expand_strided / expand_strided_avx2 => strided_impl(src: &[f32], dst: &mut [f32], outer: usize, inner: usize, b: &HalfBasis));
dispatch!(fn expand_slabs / expand_slabs_avx2 => slabs_impl(c: &Coefficients, step: f64, first: usize, b1: &HalfBasis, b2: &HalfBasis, dst: &mut [f32], tmp: &mut Vec<f32>));
dispatch!(fn final_1 / final_1_avx2 => final_c1(inter: &[&[f32]], bases: &[HalfBasis], outer: usize, inner: usize, fin: &Finisher, valid: &[bool], out: &mut [f32]));
dispatch!(fn final_3 / final_3_avx2 => final_c3(inter: &[&[f32]], bases: &[HalfBasis], outer: usize, inner: usize, fin: &Finisher, valid: &[bool], out: &mut [f32]));

#[inline(always)]
fn final_c1(
    i: &[&[f32]],
    b: &[HalfBasis],
    o: usize,
    n: usize,
    f: &Finisher,
    v: &[bool],
    out: &mut [f32],
) {
    final_pass::<1>(i, b, o, n, f, v, out)
}
#[inline(always)]
fn final_c3(
    i: &[&[f32]],
    b: &[HalfBasis],
    o: usize,
    n: usize,
    f: &Finisher,
    v: &[bool],
    out: &mut [f32],
) {
    final_pass::<3>(i, b, o, n, f, v, out)
}

/// The last pass of every component, a line or a tile at a time, each finished at once.
#[inline(always)]
fn final_pass<const C: usize>(
    inter: &[&[f32]],
    bases: &[HalfBasis],
    outer: usize,
    inner: usize,
    fin: &Finisher,
    valid: &[bool],
    out: &mut [f32],
) {
    let n = bases[0].n;
    if inner == 1 {
        let hp = bases.iter().map(|b| b.hp).max().unwrap_or(0);
        let mut lines = vec![0f32; C * n];
        let mut ev = vec![0f32; hp];
        let mut od = vec![0f32; hp];
        let mut even = Vec::new();
        let mut odd = Vec::new();
        for o in 0..outer {
            for (k, line) in lines.chunks_exact_mut(n).enumerate() {
                let b = &bases[k];
                let s = &inter[k][o * b.e..(o + 1) * b.e];
                contiguous_line(s, b, line, &mut ev, &mut od, &mut even, &mut odd);
            }
            let mut planes: [&[f32]; C] = [&[]; C];
            for (k, p) in planes.iter_mut().enumerate() {
                *p = &lines[k * n..(k + 1) * n];
            }
            fin.run::<C>(
                planes,
                o * n,
                &valid[o * n..(o + 1) * n],
                &mut out[o * n * C..(o + 1) * n * C],
            );
        }
    } else {
        let mut blocks = vec![0f32; C * n * WIDE];
        let mut evens: Vec<Vec<usize>> = vec![Vec::new(); C];
        let mut odds: Vec<Vec<usize>> = vec![Vec::new(); C];
        for o in 0..outer {
            for k in 0..C {
                let b = &bases[k];
                let s = &inter[k][o * b.e * inner..(o + 1) * b.e * inner];
                nonzero_rows(s, b.e, inner, &mut evens[k], &mut odds[k]);
            }
            let t = FinalTile {
                inter,
                bases,
                evens: &evens,
                odds: &odds,
                o,
                inner,
                fin,
                valid,
            };
            let mut x0 = 0;
            while x0 + WIDE <= inner {
                t.run::<C, WIDE>(x0, &mut blocks, out);
                x0 += WIDE;
            }
            while x0 + 8 <= inner {
                t.run::<C, 8>(x0, &mut blocks, out);
                x0 += 8;
            }
            if x0 < inner && inner >= 8 {
                // Overlapping last tile, as in `strided_impl` (finishing is per cell, so the
                // overlapped cells are written again with the same values).
                t.run::<C, 8>(inner - 8, &mut blocks, out);
                x0 = inner;
            }
            while x0 < inner {
                t.run::<C, 1>(x0, &mut blocks, out);
                x0 += 1;
            }
        }
    }
}

/// Lines per tile of the strided kernels.
const WIDE: usize = 32;

/// What one tile of the fused last pass reads.
struct FinalTile<'a> {
    inter: &'a [&'a [f32]],
    bases: &'a [HalfBasis],
    evens: &'a [Vec<usize>],
    odds: &'a [Vec<usize>],
    o: usize,
    inner: usize,
    fin: &'a Finisher,
    valid: &'a [bool],
}

impl FinalTile<'_> {
    /// Lines x0..x0+T of outer block `o`: every component's N outputs, then each output
    /// index's T cells (contiguous in the grid) finished into `out`.
    #[inline(always)]
    fn run<const C: usize, const T: usize>(&self, x0: usize, blocks: &mut [f32], out: &mut [f32]) {
        let n = self.bases[0].n;
        let inner = self.inner;
        for k in 0..C {
            let b = &self.bases[k];
            let s = &self.inter[k][self.o * b.e * inner..(self.o + 1) * b.e * inner];
            let blk = &mut blocks[k * n * T..(k + 1) * n * T];
            strided_tile::<T>(s, blk, inner, x0, b, &self.evens[k], &self.odds[k], T, 0);
        }
        for j in 0..n {
            let f = (self.o * n + j) * inner + x0;
            prefetch_next(self.valid, out, f + T, T, C);
            let mut planes: [&[f32]; C] = [&[]; C];
            for (k, p) in planes.iter_mut().enumerate() {
                *p = &blocks[k * n * T + j * T..k * n * T + (j + 1) * T];
            }
            self.fin.run::<C>(
                planes,
                f,
                &self.valid[f..f + T],
                &mut out[f * C..(f + T) * C],
            );
        }
    }
}

/// Starts loading the validity and output of cells `f..f + t` (the next tile's cells of the
/// same output index): each tile of the strided last pass finishes its cells in n runs of t
/// cells a grid line apart, more streams than the hardware prefetchers follow, so every run
/// began with a miss on the validity.
#[inline(always)]
fn prefetch_next(valid: &[bool], out: &[f32], f: usize, t: usize, c: usize) {
    #[cfg(target_arch = "x86_64")]
    {
        use std::arch::x86_64::{_MM_HINT_T0, _mm_prefetch};
        if f + t <= valid.len() {
            // SAFETY: prefetches never fault; the addresses are inside the slices anyway.
            unsafe {
                _mm_prefetch::<_MM_HINT_T0>(valid.as_ptr().add(f) as *const i8);
                let o = out.as_ptr().add(f * c) as *const i8;
                let mut b = 0;
                while b < t * c * 4 {
                    _mm_prefetch::<_MM_HINT_T0>(o.add(b));
                    b += 64;
                }
            }
        }
    }
}

/// Whether `row` holds a value other than ±0 (NaN counts, as for `v != 0.0`), 16 values at a
/// time without a branch per value: the scalar early-exit loop was a quarter of the strided
/// passes on the sparse coefficient boxes, whose rows are mostly zero.
#[inline(always)]
fn nonzero(row: &[f32]) -> bool {
    let mut chunks = row.chunks_exact(16);
    for c in &mut chunks {
        // The sign bit shifted out: ±0 reads 0, anything else not.
        if c.iter().fold(0u32, |a, v| a | (v.to_bits() << 1)) != 0 {
            return true;
        }
    }
    chunks.remainder().iter().any(|&v| v != 0.0)
}

/// The indices of the rows (of `inner` values) of `s` holding a nonzero, split by parity.
#[inline(always)]
fn nonzero_rows(s: &[f32], e: usize, inner: usize, even: &mut Vec<usize>, odd: &mut Vec<usize>) {
    even.clear();
    odd.clear();
    for k in 0..e {
        if nonzero(&s[k * inner..(k + 1) * inner]) {
            if k % 2 == 0 {
                even.push(k);
            } else {
                odd.push(k);
            }
        }
    }
}

/// The expanded axis is the fastest one: out[o][n] = Σ_k C[k][n] in[o][k].
#[inline(always)]
fn contiguous_impl(src: &[f32], dst: &mut [f32], outer: usize, b: &HalfBasis) {
    let (e, n, hp) = (b.e, b.n, b.hp);
    let mut even = Vec::with_capacity(e);
    let mut odd = Vec::with_capacity(e);
    let mut ev = vec![0f32; hp];
    let mut od = vec![0f32; hp];
    for o in 0..outer {
        let s = &src[o * e..(o + 1) * e];
        let d = &mut dst[o * n..(o + 1) * n];
        contiguous_line(s, b, d, &mut ev, &mut od, &mut even, &mut odd);
    }
}

/// One line of the contiguous kernel, vectorized across outputs in tiles of [`TILE_N`] held
/// in registers; `ev`/`od` (≥ hp long) and `even`/`odd` are scratch.
#[inline(always)]
fn contiguous_line(
    s: &[f32],
    b: &HalfBasis,
    d: &mut [f32],
    ev: &mut [f32],
    od: &mut [f32],
    even: &mut Vec<(usize, f32)>,
    odd: &mut Vec<(usize, f32)>,
) {
    let (n, h, hp) = (b.n, b.h, b.hp);
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
        // Even and odd rows side by side: four independent sums instead of two (the adds are
        // latency-bound), each still in row order, so the same bits.
        let row = |k: usize| -> &[f32; TILE_N] {
            b.rows[k * hp + t0..k * hp + t0 + TILE_N]
                .try_into()
                .expect("tile inside the padded row")
        };
        let both = even.len().min(odd.len());
        for (&(ke, we), &(ko, wo)) in even[..both].iter().zip(&odd[..both]) {
            let (re, ro) = (row(ke), row(ko));
            for l in 0..TILE_N {
                te[l] += we * re[l];
                to[l] += wo * ro[l];
            }
        }
        for (acc, rest) in [(&mut te, &even[both..]), (&mut to, &odd[both..])] {
            for &(k, w) in rest {
                let r = row(k);
                for l in 0..TILE_N {
                    acc[l] += w * r[l];
                }
            }
        }
        ev[t0..t0 + TILE_N].copy_from_slice(&te);
        od[t0..t0 + TILE_N].copy_from_slice(&to);
    }
    for ((d, e), o) in d[..h].iter_mut().zip(&ev[..h]).zip(&od[..h]) {
        *d = e + o;
    }
    // The mirrored half in blocks of 8 written to ascending addresses (one reversed vector
    // store instead of 8 scalar ones); same differences, same bits.
    let m = n / 2;
    let mut j = 0;
    while j + 8 <= m {
        let e: &[f32; 8] = ev[j..j + 8].try_into().expect("8 sums inside the scratch");
        let o: &[f32; 8] = od[j..j + 8].try_into().expect("8 sums inside the scratch");
        let hi: &mut [f32; 8] = (&mut d[n - j - 8..n - j])
            .try_into()
            .expect("8 outputs inside the line");
        let mut diff: [f32; 8] = std::array::from_fn(|l| e[l] - o[l]);
        diff.reverse();
        *hi = diff;
        j += 8;
    }
    for j in j..m {
        d[n - 1 - j] = ev[j] - od[j];
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
        nonzero_rows(s, e, inner, &mut even, &mut odd);
        strided_tiles(s, d, inner, b, &even, &odd);
    }
}

/// One outer block of [`strided_impl`]: every output of the rows `even` and `odd` of `s`
/// (`inner` values each) into `d` (N rows of `inner`), a tile of lines at a time.
#[inline(always)]
fn strided_tiles(
    s: &[f32],
    d: &mut [f32],
    inner: usize,
    b: &HalfBasis,
    even: &[usize],
    odd: &[usize],
) {
    let mut x0 = 0;
    while x0 + WIDE <= inner {
        strided_tile::<WIDE>(s, d, inner, x0, b, even, odd, inner, x0);
        x0 += WIDE;
    }
    while x0 + 8 <= inner {
        strided_tile::<8>(s, d, inner, x0, b, even, odd, inner, x0);
        x0 += 8;
    }
    if x0 < inner && inner >= 8 {
        // The last lines as one 8-wide tile overlapping the previous one: the overlap is
        // recomputed with the same operations, so rewritten with the same bits.
        strided_tile::<8>(s, d, inner, inner - 8, b, even, odd, inner, inner - 8);
        x0 = inner;
    }
    while x0 < inner {
        strided_tile::<1>(s, d, inner, x0, b, even, odd, inner, x0);
        x0 += 1;
    }
}

/// The two inner axes of a 3-D box expanded one k0 slab at a time (the last pass is then
/// along axis 0): slab k0 of the codes (e1 × e2) becomes plane k0 of `dst` (N1 × N2), the
/// first of the two axes being `first` (1 or 2). The kernels, rows and summation order are
/// those of expanding the whole box axis by axis, so the bits are the same; but the slab's
/// intermediate stays in cache, and the code lines that are all zero (most of a DCT box)
/// are skipped instead of dequantized, expanded to zeros, written and scanned again.
#[inline(always)]
fn slabs_impl(
    c: &Coefficients,
    step: f64,
    first: usize,
    b1: &HalfBasis,
    b2: &HalfBasis,
    dst: &mut [f32],
    tmp: &mut Vec<f32>,
) {
    let (codes, extent) = (&c.codes, &c.extent);
    let (e1, e2) = (extent[1], extent[2]);
    let (n1, n2) = (b1.n, b2.n);
    let mut even = Vec::with_capacity(e1);
    let mut odd = Vec::with_capacity(e1);
    let mut line_even = Vec::with_capacity(e2);
    let mut line_odd = Vec::with_capacity(e2);
    let hp = b1.hp.max(b2.hp);
    let (mut ev, mut od) = (vec![0f32; hp], vec![0f32; hp]);
    // Dequantized as `expand_along` does.
    let mut deq = vec![0f32; e1 * e2];
    let tmp_len = if first == 2 { e1 * n2 } else { n1 * e2 };
    if tmp.len() < tmp_len {
        tmp.resize(tmp_len, 0.0);
    }
    for (k0, plane) in dst.chunks_exact_mut(n1 * n2).enumerate().take(extent[0]) {
        let slab = &codes[k0 * e1 * e2..(k0 + 1) * e1 * e2];
        even.clear();
        odd.clear();
        for k1 in 0..e1 {
            let cl = &slab[k1 * e2..(k1 + 1) * e2];
            // An OR over the line (vectorized; `all` stopped at each code).
            if cl.iter().fold(0, |a, &q| a | q) == 0 {
                continue;
            }
            let dl = &mut deq[k1 * e2..(k1 + 1) * e2];
            for (d, &q) in dl.iter_mut().zip(cl) {
                *d = (q as f64 * step) as f32;
            }
            if k1 % 2 == 0 {
                even.push(k1);
            } else {
                odd.push(k1);
            }
        }
        if first == 2 {
            // Along axis 2 (contiguous), the nonempty lines only; then along axis 1 over the
            // rows they became (the others are zero rows, which the strided pass skips).
            for &k1 in even.iter().chain(&odd) {
                contiguous_line(
                    &deq[k1 * e2..(k1 + 1) * e2],
                    b2,
                    &mut tmp[k1 * n2..(k1 + 1) * n2],
                    &mut ev,
                    &mut od,
                    &mut line_even,
                    &mut line_odd,
                );
            }
            strided_tiles(&tmp[..e1 * n2], plane, n2, b1, &even, &odd);
        } else {
            // Along axis 1 (rows of e2 values), then each of the N1 lines along axis 2.
            strided_tiles(&deq, &mut tmp[..n1 * e2], e2, b1, &even, &odd);
            for (src, d) in tmp[..n1 * e2]
                .chunks_exact(e2)
                .zip(plane.chunks_exact_mut(n2))
            {
                contiguous_line(src, b2, d, &mut ev, &mut od, &mut line_even, &mut line_odd);
            }
        }
    }
}

/// acc[p][l] += w(k)[p] × s[k·inner + x0 + l] over the rows k (Q outputs per loaded tile:
/// the sums are latency-bound otherwise), each sum in row order.
#[inline(always)]
fn accumulate<const T: usize, const Q: usize>(
    acc: &mut [[f32; T]; Q],
    s: &[f32],
    inner: usize,
    x0: usize,
    rows: &[usize],
    w: impl Fn(usize) -> [f32; Q],
) {
    // Summed in a local copy: with `acc` itself, every iteration stored the sums back to the
    // caller's memory (a failed bounds check must leave them there), QT/8 stores per row.
    let mut a = *acc;
    for &k in rows {
        let wk = w(k);
        let v: &[f32; T] = s[k * inner + x0..k * inner + x0 + T]
            .try_into()
            .expect("tile inside the line");
        for l in 0..T {
            for q in 0..Q {
                a[q][l] += wk[q] * v[l];
            }
        }
    }
    *acc = a;
}

/// [`accumulate`] for two outputs. Shared by the DCT and Tucker expansions.
#[inline(always)]
pub(crate) fn accumulate_two<const T: usize>(
    acc: &mut [[f32; T]; 2],
    s: &[f32],
    inner: usize,
    x0: usize,
    rows: &[usize],
    w: impl Fn(usize) -> (f32, f32),
) {
    accumulate::<T, 2>(acc, s, inner, x0, rows, |k| {
        let (a, b) = w(k);
        [a, b]
    })
}

/// Outputs j..j+Q (and their mirrors) of lines x0..x0+T, `w(k)` their weights of row k.
#[allow(clippy::too_many_arguments)] // The kernel's whole state, as `strided_tile`.
#[inline(always)]
fn outputs<const T: usize, const Q: usize>(
    s: &[f32],
    d: &mut [f32],
    inner: usize,
    x0: usize,
    b: &HalfBasis,
    even: &[usize],
    odd: &[usize],
    dstride: usize,
    dx: usize,
    j: usize,
    w: impl Fn(usize) -> [f32; Q],
) {
    // The even sums are parked in the outputs before the odd ones are formed: both sets
    // held in registers (2QT floats) spilled to the stack on every row. Read back, they are
    // the same floats, so out = E ± O keeps its bits.
    let mut te = [[0f32; T]; Q];
    accumulate::<T, Q>(&mut te, s, inner, x0, even, &w);
    for (p, e) in te.iter().enumerate() {
        for r in mirror_rows(b.n, j + p) {
            // Through fixed-size slices: indexing `d[lo + l]` left one bounds check per
            // lane in the loop, and the stores scalar.
            let lo = r * dstride + dx;
            let dl: &mut [f32; T] = (&mut d[lo..lo + T]).try_into().expect("a tile");
            *dl = *e;
        }
    }
    let mut to = [[0f32; T]; Q];
    accumulate::<T, Q>(&mut to, s, inner, x0, odd, &w);
    for (p, o) in to.iter().enumerate() {
        let jj = j + p;
        let lo = jj * dstride + dx;
        let dl: &mut [f32; T] = (&mut d[lo..lo + T]).try_into().expect("a tile");
        for l in 0..T {
            dl[l] += o[l];
        }
        let m = b.n - 1 - jj;
        if m != jj {
            let hi = m * dstride + dx;
            let dh: &mut [f32; T] = (&mut d[hi..hi + T]).try_into().expect("a tile");
            for l in 0..T {
                dh[l] -= o[l];
            }
        }
    }
}

/// Output j and its mirror N − 1 − j (once when they coincide, the middle of an odd N).
#[inline(always)]
fn mirror_rows(n: usize, j: usize) -> impl Iterator<Item = usize> {
    let m = n - 1 - j;
    std::iter::once(j).chain((m != j).then_some(m))
}

/// Lines x0..x0+T of one outer block: d[j·dstride + dx + l] for every output j.
#[allow(clippy::too_many_arguments)] // The kernel's whole state; a struct would hide the loads.
#[inline(always)]
fn strided_tile<const T: usize>(
    s: &[f32],
    d: &mut [f32],
    inner: usize,
    x0: usize,
    b: &HalfBasis,
    even: &[usize],
    odd: &[usize],
    dstride: usize,
    dx: usize,
) {
    // Several outputs at a time: each loaded tile feeds Q sets of accumulators (the sums are
    // latency-bound otherwise); every output's sum keeps its order, so its bits. Q = 4 on
    // narrow tiles halves the row loads per multiply-add; at T = 32 it would not fit the
    // registers.
    let mut j = 0;
    if T <= 16 {
        while j + 3 < b.h {
            let (p0, p1) = (b.pair(j), b.pair(j + 2));
            outputs::<T, 4>(s, d, inner, x0, b, even, odd, dstride, dx, j, |k| {
                [p0[k][0], p0[k][1], p1[k][0], p1[k][1]]
            });
            j += 4;
        }
    }
    while j + 1 < b.h {
        let p0 = b.pair(j);
        outputs::<T, 2>(s, d, inner, x0, b, even, odd, dstride, dx, j, |k| {
            [p0[k][0], p0[k][1]]
        });
        j += 2;
    }
    // The last output when h is odd, one at a time.
    for j in j..b.h {
        outputs::<T, 1>(s, d, inner, x0, b, even, odd, dstride, dx, j, |k| {
            [b.rows[k * b.hp + j]]
        });
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
        let scale = b
            .iter()
            .fold(0f32, |m, v| m.max(v.abs()))
            .max(f32::MIN_POSITIVE) as f64;
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

    /// The slab-wise expansion of the two inner axes gives the axis-by-axis expansion's bits,
    /// for both axis orders, on boxes with empty lines, empty slabs and odd resolutions.
    #[test]
    fn slabs_give_the_axis_by_axis_bits() {
        for (dims, extent) in [
            ([7usize, 9, 13], [5usize, 6, 11]),
            ([90, 90, 180], [12, 30, 61]),
        ] {
            let total: usize = extent.iter().product();
            let mut rng = crate::math::SplitMix64::new(11);
            let codes: Vec<i32> = (0..total)
                .map(|i| {
                    let (k0, line) = (i / (extent[1] * extent[2]), i / extent[2]);
                    // Slab 1 empty, every third line empty, the rest 30% nonzero.
                    if k0 == 1 || line % 3 == 2 || rng.next_f64() > 0.3 {
                        0
                    } else {
                        (rng.next_f64() * 200.0 - 100.0) as i32
                    }
                })
                .collect();
            let c = Coefficients {
                extent: extent.to_vec(),
                codes,
            };
            for (first, second) in [(2, 1), (1, 2)] {
                let mut scratch = DecodeScratch::default();
                let (a, shape_a) = slab_expand(&c, &dims, 0.37, first, &mut scratch);
                let (b, shape_b) = expand_along(&c, &dims, 0.37, &[first, second], &mut scratch);
                assert_eq!(shape_a, shape_b);
                let n: usize = shape_a.iter().product();
                let differ = a[..n]
                    .iter()
                    .zip(&b[..n])
                    .filter(|(x, y)| x.to_bits() != y.to_bits())
                    .count();
                assert_eq!(
                    differ, 0,
                    "{differ} of {n} values differ, first axis {first}"
                );
                assert!(b[..n].iter().any(|&v| v != 0.0));
            }
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
