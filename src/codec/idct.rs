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
//!    through the portable/AVX2 dispatch of [`super::simd`] (same bits on every CPU);
//! 5. for a 3-D box whose last pass is along axis 0 (MERL grids), with the intermediate of
//!    the last pass stored tile-major, so that the pass reads each tile's rows as one block
//!    ([`decode_tiled`]).
//!
//! Results differ from the reference only by f32 rounding (another summation order), far
//! below the quantization noise: tested against the reference decoder.

#![allow(clippy::needless_range_loop)] // Lane loops index several parallel arrays.

use super::DecodeScratch;
use super::dct::{Coefficients, dct_entry};
use super::simd::{Finisher, dispatch, finish, finish_one_from};
use crate::table::CellSet;
use std::borrow::Cow;

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
    // In place only where the second array is worth its cost: copying each block in and out
    // of a tile makes a pass slower (64⁴: ~0.2 s a decode), and a MERL-sized plane's second
    // array is 17 MB.
    let cells: usize = dims.iter().product();
    if scratch.is_lean() && cells > IN_PLACE_CELLS {
        return expand_axes_in_place(cur, cur_dims, dims, order, scratch, pass);
    }
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

/// Planes above this many cells (2²³, a 32 MB f32 plane: the 64⁴ grids, not MERL's or its
/// refinements up to 180³) are expanded in place by a single decode.
const IN_PLACE_CELLS: usize = 1 << 23;

/// [`expand_axes`] in one array, for a single decode: each pass widens the data where it
/// lies, blocks of the outer axes last first (a block's output never reaches the input of a
/// block before it), each block's input copied out a tile of columns at a time (its output
/// rows share the input's column stride, so a tile's output only lands on its own columns,
/// already copied). The same `pass` on the same values: the same bits as the two arrays,
/// whose second array, the size of the plane, is what this saves (tested).
fn expand_axes_in_place(
    mut cur: Vec<f32>,
    mut cur_dims: Vec<usize>,
    dims: &[usize],
    order: &[usize],
    scratch: &mut DecodeScratch,
    pass: impl FnMut(usize, &[f32], &mut [f32], usize, usize),
) -> (Vec<f32>, Vec<usize>) {
    DecodeScratch::grow(&mut cur, largest_shape(&cur_dims, dims, order));
    expand_in_slice(&mut cur, &mut cur_dims, dims, order, scratch, pass);
    (cur, cur_dims)
}

/// The largest array an expansion of `cur_dims` along `order` holds.
fn largest_shape(cur_dims: &[usize], dims: &[usize], order: &[usize]) -> usize {
    order
        .iter()
        .scan(cur_dims.to_vec(), |shape, &a| {
            shape[a] = dims[a];
            Some(shape.iter().product::<usize>())
        })
        .fold(cur_dims.iter().product::<usize>(), usize::max)
}

/// The passes of [`expand_axes_in_place`] on `cur`, at least [`largest_shape`] long;
/// `cur_dims` becomes the final shape.
fn expand_in_slice(
    cur: &mut [f32],
    cur_dims: &mut [usize],
    dims: &[usize],
    order: &[usize],
    scratch: &mut DecodeScratch,
    mut pass: impl FnMut(usize, &[f32], &mut [f32], usize, usize),
) {
    // Columns per tile: a multiple of the kernels' vector widths, a few KB of each row.
    const TILE: usize = 512;
    // Values of the contiguous kernel's output per group of lines.
    const GROUP: usize = 1 << 16;
    let mut tile_in = scratch.take_f32(0);
    let mut tile_out = scratch.take_f32(0);
    for &a in order {
        let (e, n) = (cur_dims[a], dims[a]);
        let outer: usize = cur_dims[..a].iter().product();
        let inner: usize = cur_dims[a + 1..].iter().product();
        if inner == 1 {
            let lines = (GROUP / n.max(1)).max(1);
            DecodeScratch::grow(&mut tile_in, lines * e);
            let mut end = outer;
            while end > 0 {
                let start = end.saturating_sub(lines);
                let k = end - start;
                tile_in[..k * e].copy_from_slice(&cur[start * e..end * e]);
                pass(a, &tile_in[..k * e], &mut cur[start * n..end * n], k, 1);
                end = start;
            }
        } else {
            // Tiles of TILE columns; a remainder narrower than a vector joins the tile before.
            let mut tiles = Vec::new();
            let mut x0 = 0;
            while x0 < inner {
                let mut w = TILE.min(inner - x0);
                if inner - x0 - w < 8 {
                    w = inner - x0;
                }
                tiles.push((x0, w));
                x0 += w;
            }
            let widest = tiles.iter().map(|t| t.1).max().unwrap_or(0);
            DecodeScratch::grow(&mut tile_in, e * widest);
            DecodeScratch::grow(&mut tile_out, n * widest);
            for o in (0..outer).rev() {
                let (base_in, base_out) = (o * e * inner, o * n * inner);
                for &(x0, w) in &tiles {
                    for k in 0..e {
                        let from = base_in + k * inner + x0;
                        tile_in[k * w..(k + 1) * w].copy_from_slice(&cur[from..from + w]);
                    }
                    pass(a, &tile_in[..e * w], &mut tile_out[..n * w], 1, w);
                    for k in 0..n {
                        let to = base_out + k * inner + x0;
                        cur[to..to + w].copy_from_slice(&tile_out[k * w..(k + 1) * w]);
                    }
                }
            }
        }
        cur_dims[a] = n;
    }
    scratch.give_f32(tile_in);
    scratch.give_f32(tile_out);
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
    let cur = dequantize(c, step, scratch);
    expand_dequantized(cur, c, dims, order, scratch)
}

/// The box's codes × step (from `scratch`, possibly longer than the box).
fn dequantize(c: &Coefficients, step: f64, scratch: &mut DecodeScratch) -> Vec<f32> {
    let mut cur = scratch.take_f32(c.codes.len());
    dequantize_into(c, step, &mut cur);
    cur
}

/// The box's codes × step into the start of `out`.
fn dequantize_into(c: &Coefficients, step: f64, out: &mut [f32]) {
    for (d, &q) in out.iter_mut().zip(&c.codes) {
        *d = dequantized(q, step);
    }
}

/// One code × step, in f32.
#[inline(always)]
fn dequantized(code: i32, step: f64) -> f32 {
    (code as f64 * step) as f32
}

/// A component with nothing coded (no codes, or a box of another dimension): 0 everywhere.
fn is_empty_box(q: &Coefficients, d: usize) -> bool {
    q.codes.is_empty() || q.extent.len() != d
}

/// [`expand_along`] of a box already dequantized into `cur` (`c` gives its extent; its
/// codes are not read).
fn expand_dequantized(
    cur: Vec<f32>,
    c: &Coefficients,
    dims: &[usize],
    order: &[usize],
    scratch: &mut DecodeScratch,
) -> (Vec<f32>, Vec<usize>) {
    expand_axes(
        cur,
        c.extent.clone(),
        dims,
        order,
        scratch,
        dct_pass(c, dims),
    )
}

/// The inverse DCT of one axis of the box `c` as an [`expand_axes`] pass.
fn dct_pass<'a>(
    c: &'a Coefficients,
    dims: &'a [usize],
) -> impl FnMut(usize, &[f32], &mut [f32], usize, usize) + 'a {
    |a, src, dst, outer, inner| {
        let basis = HalfBasis::new(dims[a], c.extent[a]);
        if inner == 1 {
            expand_contiguous(src, dst, outer, &basis);
        } else {
            expand_strided(src, dst, outer, inner, &basis);
        }
    }
}

/// Reconstructs one component plane (every cell) from its quantized box, in f32.
pub fn inverse(c: &Coefficients, dims: &[usize], step: f64) -> Vec<f32> {
    let cells: usize = dims.iter().product();
    if is_empty_box(c, dims.len()) {
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
    comps: &mut [Coefficients],
    steps: &[f64],
    dims: &[usize],
    fin: &Finisher,
    valid: &[bool],
    out: &mut [f32],
    scratch: &mut DecodeScratch,
) {
    let c = comps.len();
    let d = dims.len();
    let empty = |q: &Coefficients| is_empty_box(q, d);
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
    let (last, orders) = shared_orders(comps, dims);
    let cells: usize = dims.iter().product();
    // A single decode of a large one-component table expands and finishes in `out` itself.
    // (Three components would need two planes of their own for the in-place finish, about
    // what their intermediates hold, and their full expansions in place cost more time.)
    if scratch.is_lean() && c == 1 && cells > IN_PLACE_CELLS {
        decode_in_place(
            &mut comps[0],
            steps[0],
            dims,
            &orders[0],
            fin,
            valid,
            out,
            scratch,
        );
        return;
    }
    if d == 3 && last == 0 {
        decode_tiled(comps, steps, dims, &orders, fin, valid, out, scratch);
        return;
    }
    // Every pass but the last, per component; an empty component is a box of extent 0.
    let mut inter: Vec<(Vec<f32>, usize)> = Vec::with_capacity(c);
    let mut bases: Vec<HalfBasis> = Vec::with_capacity(c);
    for ((q, &s), order) in comps.iter_mut().zip(steps).zip(&orders) {
        if empty(q) {
            inter.push((Vec::new(), 0));
            bases.push(HalfBasis::new(dims[last], 0));
        } else {
            // The codes are given back once dequantized: a full box's codes are a plane's
            // size, and the expansion's two arrays need not sit beside them.
            let cur = dequantize(q, s, scratch);
            scratch.give_i32(std::mem::take(&mut q.codes));
            let (a, shape) = expand_dequantized(cur, q, dims, &order[..d - 1], scratch);
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

/// [`decode`] of boxes the caller keeps (the rate control's quantized codes, measured
/// without a decode of the payload they were coded into): the same bits. The tiled decode of a MERL-grid
/// table reads the codes where they are; the other paths take a copy.
pub(crate) fn decode_of(
    comps: &[Coefficients],
    steps: &[f64],
    dims: &[usize],
    fin: &Finisher,
    valid: &[bool],
    out: &mut [f32],
    scratch: &mut DecodeScratch,
) {
    let (c, d) = (comps.len(), dims.len());
    let cells: usize = dims.iter().product();
    // `decode`'s choice of path, up to its tiled one.
    if (c == 1 || c == 3) && d == 3 && !(scratch.is_lean() && c == 1 && cells > IN_PLACE_CELLS) {
        let (last, orders) = shared_orders(comps, dims);
        if last == 0 {
            decode_tiled(comps, steps, dims, &orders, fin, valid, out, scratch);
            return;
        }
    }
    decode(&mut comps.to_vec(), steps, dims, fin, valid, out, scratch);
}

/// [`decode`]'s values at the cells of a set alone: `out[i·C + k]` (i the cell's place in
/// the set) gets the bits `decode` gives the cell's channel k, without a plane of the
/// grid's size. Each component is expanded along the first axis of `decode`'s order, then
/// one slab (one index of that axis) at a time along the others, slabs in parallel; a
/// slab's passes are `decode`'s passes restricted to it (no pass after the first mixes
/// indices of that axis), and only the set's cells are kept, then finished in `out`. For 1
/// or 3 components (`decode`'s fused cases).
///
/// What the rate control measures a candidate with: its estimator reads a few million cells,
/// and a 64⁴ table's decode buffer (67 MB) was a third of its peak.
pub(crate) fn decode_cells(
    comps: &mut [Coefficients],
    steps: &[f64],
    dims: &[usize],
    fin: &Finisher,
    valid: &[bool],
    cells: &CellSet,
    out: &mut [f32],
) {
    check_cells_args(comps.len(), dims, cells, out);
    let (_, orders) = shared_orders(comps, dims);
    // Each box's codes are dequantized in their own memory as its pass begins.
    let codes: Vec<Vec<i32>> = comps
        .iter_mut()
        .map(|q| std::mem::take(&mut q.codes))
        .collect();
    let codes = codes.into_iter().map(Cow::Owned);
    expand_and_finish(comps, codes, &orders, steps, dims, fin, valid, cells, out);
}

/// [`decode_cells`] of boxes the caller keeps (the rate control's quantized codes): the
/// same bits, without their payload's decode. A box with mostly nonzero codes is copied for its first pass.
pub(crate) fn decode_cells_of(
    comps: &[Coefficients],
    steps: &[f64],
    dims: &[usize],
    fin: &Finisher,
    valid: &[bool],
    cells: &CellSet,
    out: &mut [f32],
) {
    check_cells_args(comps.len(), dims, cells, out);
    let (_, orders) = shared_orders(comps, dims);
    let codes = comps.iter().map(|q| Cow::Borrowed(&q.codes[..]));
    expand_and_finish(comps, codes, &orders, steps, dims, fin, valid, cells, out);
}

/// The boxes `comps` (their extents; their codes given by `codes`, in order) expanded at the
/// set's cells along their `orders`, then finished: [`decode_cells`]' body.
#[allow(clippy::too_many_arguments)] // `decode_cells`' arguments, its codes and orders.
fn expand_and_finish<'a>(
    comps: &[Coefficients],
    codes: impl Iterator<Item = Cow<'a, [i32]>>,
    orders: &[Vec<usize>],
    steps: &[f64],
    dims: &[usize],
    fin: &Finisher,
    valid: &[bool],
    cells: &CellSet,
    out: &mut [f32],
) {
    for (k, (q, codes)) in comps.iter().zip(codes).enumerate() {
        expand_or_zero(q, codes, steps[k], dims, &orders[k], cells, k, out);
    }
    finish_cells(comps.len(), fin, valid, cells, out);
}

fn check_cells_args(c: usize, dims: &[usize], cells: &CellSet, out: &[f32]) {
    assert!(c == 1 || c == 3, "decode_cells: 1 or 3 components");
    assert_eq!(out.len(), cells.len() * c, "decode_cells: output length");
    assert_eq!(
        cells.grid_cells(),
        dims.iter().product::<usize>(),
        "decode_cells: the set's grid"
    );
}

/// Component k of [`decode_cells`] before the finishing step: its box expanded at the set's
/// cells, or 0 for an empty box (as in [`decode`]).
#[allow(clippy::too_many_arguments)] // one component's box, codes, step and place.
fn expand_or_zero(
    q: &Coefficients,
    codes: Cow<'_, [i32]>,
    step: f64,
    dims: &[usize],
    order: &[usize],
    cells: &CellSet,
    k: usize,
    out: &mut [f32],
) {
    let c = if out.len() == cells.len() { 1 } else { 3 };
    if codes.is_empty() || q.extent.len() != dims.len() {
        for v in out.iter_mut().skip(k).step_by(c) {
            *v = 0.0;
        }
    } else {
        expand_at_cells(q, codes, step, dims, order, cells, k, c, out);
    }
}

fn finish_cells(c: usize, fin: &Finisher, valid: &[bool], cells: &CellSet, out: &mut [f32]) {
    if c == 1 {
        fin.run_cells::<1>(cells, valid, out);
    } else {
        fin.run_cells::<3>(cells, valid, out);
    }
}

/// One component of [`decode_cells`] before the finishing step: `out[i·c + k]` becomes the
/// expanded plane's value at the set's cell of place i.
#[allow(clippy::too_many_arguments)] // the component, its place and the set's output.
fn expand_at_cells(
    q: &Coefficients,
    codes: Cow<'_, [i32]>,
    step: f64,
    dims: &[usize],
    order: &[usize],
    cells: &CellSet,
    k: usize,
    c: usize,
    out: &mut [f32],
) {
    use rayon::prelude::*;
    let a0 = order[0];
    let n0 = dims[a0];
    let first = FirstPass::new(q, codes, step, dims, a0);
    // A cell's flat index is hi·(n0·stride) + j·stride + lo (j its index along a0), its
    // index in slab j's full array hi·stride + lo.
    let stride: usize = dims[a0 + 1..].iter().product();
    let blocks: usize = dims[..a0].iter().product();
    let outer: usize = q.extent[..a0].iter().product();
    let inner: usize = q.extent[a0 + 1..].iter().product();
    let mut slab_shape = q.extent.clone();
    slab_shape[a0] = 1;
    let mut slab_dims = dims.to_vec();
    slab_dims[a0] = 1;
    // The set's cells of each slab. Read from the set's bitmap a block of `stride` cells at a
    // time when blocks are long; with short ones (a0 near the last axis: a slab's cells are
    // every n0-th) that is a call per few cells, so the cells are sorted into their slabs
    // first, in one pass (4 bytes a cell, freed with the decode).
    let buckets = (stride < 64).then(|| {
        let slab_of = |f: u32| (f as usize / stride) % n0;
        let mut starts = vec![0usize; n0 + 1];
        for f in cells.iter() {
            starts[slab_of(f) + 1] += 1;
        }
        for j in 0..n0 {
            starts[j + 1] += starts[j];
        }
        let mut next = starts.clone();
        let mut flats = vec![0u32; cells.len()];
        for f in cells.iter() {
            let j = slab_of(f);
            flats[next[j]] = f;
            next[j] += 1;
        }
        (starts, flats)
    });
    // One slab: its (place, value) pairs.
    let slab = |scratch: &mut DecodeScratch, j: usize| -> Vec<(u32, f32)> {
        let mut kept = Vec::new();
        if let Some((starts, _)) = &buckets
            && starts[j] == starts[j + 1]
        {
            return kept;
        }
        let mut a = scratch.take_f32(outer * inner);
        first.slab(j, outer, inner, &mut a[..outer * inner]);
        let (full, _) = expand_axes(
            a,
            slab_shape.clone(),
            &slab_dims,
            &order[1..],
            scratch,
            dct_pass(q, dims),
        );
        // Cell f of slab j is at hi·stride + lo of its full array.
        let at = |f: u32| {
            let f = f as usize;
            full[f / (stride * n0) * stride + f % stride]
        };
        match &buckets {
            Some((starts, flats)) => {
                kept.extend(
                    flats[starts[j]..starts[j + 1]]
                        .iter()
                        .map(|&f| (cells.position(f), at(f))),
                );
            }
            None => {
                for hi in 0..blocks {
                    let start = (hi * n0 + j) * stride;
                    cells.for_each_in(start..start + stride, |f, place| {
                        kept.push((place as u32, at(f)));
                    });
                }
            }
        }
        scratch.give_f32(full);
        kept
    };
    // Slabs in parallel, a few per thread at a time, so that their kept values are not all
    // held at once.
    let batch = 4 * rayon::current_num_threads().max(1);
    let mut j0 = 0;
    while j0 < n0 {
        let j1 = (j0 + batch).min(n0);
        let kept: Vec<Vec<(u32, f32)>> = (j0..j1)
            .into_par_iter()
            .map_init(DecodeScratch::default, slab)
            .collect();
        for (place, v) in kept.into_iter().flatten() {
            out[place as usize * c + k] = v;
        }
        j0 = j1;
    }
}

/// The first pass of [`expand_at_cells`] (along axis a0), as it serves one slab (one output
/// index along a0) at a time.
enum FirstPass {
    /// The pass made whole: the dequantized box expanded along a0 (a box of mostly nonzero
    /// codes).
    Dense { array: Vec<f32>, n0: usize },
    /// The box's nonzero values by their index along a0 (`entries[starts[k]..starts[k + 1]]`:
    /// (place in the slab, value) of row k), and the basis along a0. A slab's outputs are then
    /// made from them alone: a lossy box is mostly zeros, and the pass made whole was the
    /// largest array of a 64⁴ measurement (41 MB for a production file of 5 KB).
    Sparse {
        entries: Vec<(u32, f32)>,
        starts: Vec<usize>,
        basis: HalfBasis,
    },
}

impl FirstPass {
    /// The box of `q` (its codes taken) dequantized at `step`, ready to give its slabs along
    /// axis `a0` of `dims`.
    fn new(
        q: &Coefficients,
        codes: Cow<'_, [i32]>,
        step: f64,
        dims: &[usize],
        a0: usize,
    ) -> FirstPass {
        let nonzero = codes.iter().filter(|&&c| c != 0).count();
        // 8 bytes a nonzero value against 4 a code: sparse when under half are nonzero.
        if nonzero * 2 >= codes.len() {
            // Dequantized in the codes' own memory (a collect from a vector into one of the
            // same layout reuses its allocation), then expanded along a0 there.
            let cur: Vec<f32> = codes
                .into_owned()
                .into_iter()
                .map(|code| dequantized(code, step))
                .collect();
            let mut scratch = DecodeScratch::lean();
            let (array, _) = expand_dequantized(cur, q, dims, &[a0], &mut scratch);
            return FirstPass::Dense {
                array,
                n0: dims[a0],
            };
        }
        let e = &q.extent;
        let (outer, b0, inner) = (
            e[..a0].iter().product::<usize>(),
            e[a0],
            e[a0 + 1..].iter().product::<usize>(),
        );
        let mut starts = vec![0usize; b0 + 1];
        for (i, &code) in codes.iter().enumerate() {
            if code != 0 {
                starts[i / inner % b0 + 1] += 1;
            }
        }
        for k in 0..b0 {
            starts[k + 1] += starts[k];
        }
        let mut next = starts.clone();
        let mut entries = vec![(0u32, 0f32); nonzero];
        for o in 0..outer {
            for k in 0..b0 {
                let row = &codes[(o * b0 + k) * inner..(o * b0 + k + 1) * inner];
                for (i, &code) in row.iter().enumerate() {
                    if code != 0 {
                        entries[next[k]] = ((o * inner + i) as u32, dequantized(code, step));
                        next[k] += 1;
                    }
                }
            }
        }
        FirstPass::Sparse {
            entries,
            starts,
            basis: HalfBasis::new(dims[a0], b0),
        }
    }

    /// Output index j along a0 of the pass (`outer` × `inner` values, the box's other axes)
    /// into `slab`: the bits of the pass made whole. Each output is E + O, or E − O for the
    /// mirrored half, with E and O the sums of the even and odd rows' products in row order,
    /// as the kernels make them (their zero rows add exact zeros).
    fn slab(&self, j: usize, outer: usize, inner: usize, slab: &mut [f32]) {
        match self {
            FirstPass::Dense { array, n0 } => {
                for o in 0..outer {
                    let from = (o * n0 + j) * inner;
                    slab[o * inner..(o + 1) * inner].copy_from_slice(&array[from..from + inner]);
                }
            }
            FirstPass::Sparse {
                entries,
                starts,
                basis,
            } => {
                let (m, mirrored) = if j < basis.h {
                    (j, false)
                } else {
                    (basis.n - 1 - j, true)
                };
                let rest = outer * inner;
                let mut odd = vec![0f32; rest];
                let even = &mut slab[..rest];
                even.fill(0.0);
                for k in 0..basis.e {
                    let r = basis.rows[k * basis.hp + m];
                    let sums = if k % 2 == 0 { &mut *even } else { &mut odd[..] };
                    for &(x, v) in &entries[starts[k]..starts[k + 1]] {
                        sums[x as usize] += v * r;
                    }
                }
                for (e, o) in even.iter_mut().zip(&odd) {
                    *e = if mirrored { *e - o } else { *e + o };
                }
            }
        }
    }
}

/// The last axis [`decode`] shares between the components (the lowest total cost over
/// them) and each component's axis order ending in it (empty for an empty component).
fn shared_orders(comps: &[Coefficients], dims: &[usize]) -> (usize, Vec<Vec<usize>>) {
    let d = dims.len();
    let empty = |q: &Coefficients| is_empty_box(q, d);
    // The shared last axis: the lowest total cost over the components.
    let mut best: Option<(f64, usize, Vec<Vec<usize>>)> = None;
    for last in 0..d {
        let mut total = 0.0;
        let mut orders = Vec::with_capacity(comps.len());
        for q in comps.iter() {
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
    (last, orders)
}

/// [`decode`] of a large one-component table by a single decode ([`DecodeScratch::lean`]):
/// the box dequantized and expanded along every axis in `out` itself, then every cell
/// finished in place, a chunk at a time through a small copy. A whole pass along the last
/// axis has the arithmetic of [`decode`]'s fused last pass (tested): the same bits, without
/// the intermediate beside `out`.
#[allow(clippy::too_many_arguments)] // `decode`'s arguments and the axis order.
fn decode_in_place(
    q: &mut Coefficients,
    step: f64,
    dims: &[usize],
    order: &[usize],
    fin: &Finisher,
    valid: &[bool],
    out: &mut [f32],
    scratch: &mut DecodeScratch,
) {
    // Cells finished per chunk: the copy is this many floats.
    const CHUNK: usize = 1 << 14;
    let cells: usize = dims.iter().product();
    expand_whole(q, step, dims, order, &mut out[..cells], scratch);
    let mut copy = scratch.take_f32(CHUNK);
    let mut start = 0;
    while start < cells {
        let end = (start + CHUNK).min(cells);
        copy[..end - start].copy_from_slice(&out[start..end]);
        finish_one_from(
            fin,
            &copy[..end - start],
            start,
            &valid[start..end],
            &mut out[start..end],
        );
        start = end;
    }
    scratch.give_f32(copy);
}

/// The component of [`decode_in_place`]: its box dequantized into `plane` (every cell) and
/// expanded there along `order` (every axis); its codes given back once dequantized. An
/// empty component is 0 everywhere, as in [`decode`].
fn expand_whole(
    q: &mut Coefficients,
    step: f64,
    dims: &[usize],
    order: &[usize],
    plane: &mut [f32],
    scratch: &mut DecodeScratch,
) {
    if is_empty_box(q, dims.len()) {
        plane.fill(0.0);
        return;
    }
    dequantize_into(q, step, plane);
    scratch.give_i32(std::mem::take(&mut q.codes));
    let mut shape = q.extent.clone();
    expand_in_slice(plane, &mut shape, dims, order, scratch, dct_pass(q, dims));
}

dispatch!(fn expand_contiguous / expand_contiguous_avx2 => contiguous_impl(src: &[f32], dst: &mut [f32], outer: usize, b: &HalfBasis));
dispatch!(fn expand_strided / expand_strided_avx2 => strided_impl(src: &[f32], dst: &mut [f32], outer: usize, inner: usize, b: &HalfBasis));
dispatch!(fn expand_slabs_tiled / expand_slabs_tiled_avx2 => slabs_tiled_impl(c: &Coefficients, step: f64, axes: &InnerAxes, tiles: &[(usize, usize)], dst: &mut [f32], bufs: &mut [Vec<f32>; 2], lists: &mut (Vec<usize>, Vec<usize>)));
dispatch!(fn final_tiled_n / final_tiled_n_avx2 => final_tiled_c(inter: &[&[f32]], lists: &[(Vec<usize>, Vec<usize>)], bases: &[HalfBasis], tiles: &[(usize, usize)], fin: &Finisher, valid: &[bool], out: &mut [f32]));
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
        let tiles = final_tiles(inner);
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
            for &(x0, w) in &tiles {
                match w {
                    WIDE => t.run::<C, WIDE>(x0, &mut blocks, out),
                    8 => t.run::<C, 8>(x0, &mut blocks, out),
                    _ => t.run::<C, 1>(x0, &mut blocks, out),
                }
            }
        }
    }
}

/// [`final_tiled`] for 1 or 3 components (`inter.len()`), as one function for the dispatch.
#[inline(always)]
fn final_tiled_c(
    inter: &[&[f32]],
    lists: &[(Vec<usize>, Vec<usize>)],
    bases: &[HalfBasis],
    tiles: &[(usize, usize)],
    fin: &Finisher,
    valid: &[bool],
    out: &mut [f32],
) {
    if inter.len() == 1 {
        final_tiled::<1>(inter, lists, bases, tiles, fin, valid, out)
    } else {
        final_tiled::<3>(inter, lists, bases, tiles, fin, valid, out)
    }
}

/// [`final_pass`] over the tiles stored by [`slabs_tiled_impl`]: `inter[k]` component k's
/// tiles, `lists[k]` its nonzero rows (even, odd).
#[inline(always)]
fn final_tiled<const C: usize>(
    inter: &[&[f32]],
    lists: &[(Vec<usize>, Vec<usize>)],
    bases: &[HalfBasis],
    tiles: &[(usize, usize)],
    fin: &Finisher,
    valid: &[bool],
    out: &mut [f32],
) {
    let n = bases[0].n;
    let inner: usize = valid.len() / n;
    let mut blocks = vec![0f32; C * n * WIDE];
    let mut base = 0;
    for &(x0, t) in tiles {
        let mut views: [&[f32]; C] = [&[]; C];
        for (k, v) in views.iter_mut().enumerate() {
            let e = bases[k].e;
            *v = &inter[k][base * e..(base + t) * e];
        }
        let tile = TiledTile {
            views,
            lists,
            bases,
            inner,
            fin,
            valid,
        };
        match t {
            WIDE => tile.run::<WIDE>(x0, &mut blocks, out),
            8 => tile.run::<8>(x0, &mut blocks, out),
            _ => tile.run::<1>(x0, &mut blocks, out),
        }
        base += t;
    }
}

/// What one tile of [`final_tiled`] reads: `views[k]` the tile's rows of component k.
struct TiledTile<'a, const C: usize> {
    views: [&'a [f32]; C],
    lists: &'a [(Vec<usize>, Vec<usize>)],
    bases: &'a [HalfBasis],
    inner: usize,
    fin: &'a Finisher,
    valid: &'a [bool],
}

impl<const C: usize> TiledTile<'_, C> {
    /// Every component's N outputs of the tile's T cells (x0.. of each output index), then
    /// the cells finished into `out`.
    #[inline(always)]
    fn run<const T: usize>(&self, x0: usize, blocks: &mut [f32], out: &mut [f32]) {
        let n = self.bases[0].n;
        for k in 0..C {
            let b = &self.bases[k];
            let blk = &mut blocks[k * n * T..(k + 1) * n * T];
            let (ev, od) = &self.lists[k];
            strided_tile::<T>(self.views[k], blk, T, 0, b, ev, od, T, 0);
        }
        let planes: [&[f32]; C] = std::array::from_fn(|k| &blocks[k * n * T..(k + 1) * n * T]);
        self.fin
            .run_rows::<C>(planes, n, T, x0, self.inner, self.valid, out);
    }
}

/// [`decode`] of a 3-D box whose last pass is along axis 0 (every MERL-grid table): the
/// inner passes slab by slab into a tile-major intermediate ([`slabs_tiled_impl`]), then
/// the last pass and the finishing step a tile at a time ([`final_tiled`]).
#[allow(clippy::too_many_arguments)] // `decode`'s arguments and its axis orders.
fn decode_tiled(
    comps: &[Coefficients],
    steps: &[f64],
    dims: &[usize],
    orders: &[Vec<usize>],
    fin: &Finisher,
    valid: &[bool],
    out: &mut [f32],
    scratch: &mut DecodeScratch,
) {
    let tiles = final_tiles(dims[1] * dims[2]);
    let width: usize = tiles.iter().map(|t| t.1).sum();
    let mut bufs = [scratch.take_f32(0), scratch.take_f32(0)];
    // Per component: its array and the range of its tiles in it, its nonzero rows (even,
    // odd), the basis of its last pass.
    let mut inter: Vec<(Vec<f32>, std::ops::Range<usize>)> = Vec::with_capacity(comps.len());
    let mut lists: Vec<(Vec<usize>, Vec<usize>)> = Vec::with_capacity(comps.len());
    let mut bases: Vec<HalfBasis> = Vec::with_capacity(comps.len());
    for ((q, &s), order) in comps.iter().zip(steps).zip(orders) {
        let mut rows = (Vec::new(), Vec::new());
        let mut a = scratch.take_f32(0);
        let mut range = 0..0;
        if is_empty_box(q, 3) {
            bases.push(HalfBasis::new(dims[0], 0));
        } else {
            let len = width * q.extent[0];
            // 16 floats of slack, so that the tiles can start on a 64-byte boundary.
            DecodeScratch::grow(&mut a, len + 16);
            let off = (64 - a.as_ptr() as usize % 64) % 64 / 4;
            range = off..off + len;
            let axes = InnerAxes {
                first: order[0],
                b1: HalfBasis::new(dims[1], q.extent[1]),
                b2: HalfBasis::new(dims[2], q.extent[2]),
            };
            expand_slabs_tiled(
                q,
                s,
                &axes,
                &tiles,
                &mut a[range.clone()],
                &mut bufs,
                &mut rows,
            );
            bases.push(HalfBasis::new(dims[0], q.extent[0]));
        }
        inter.push((a, range));
        lists.push(rows);
    }
    let views: Vec<&[f32]> = inter.iter().map(|(a, r)| &a[r.clone()]).collect();
    final_tiled_n(&views, &lists, &bases, &tiles, fin, valid, out);
    // In reverse, so that the next decode takes each array back for the same component.
    for (a, _) in inter.into_iter().rev() {
        scratch.give_f32(a);
    }
    let [tmp, plane] = bufs;
    scratch.give_f32(plane);
    scratch.give_f32(tmp);
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
        let planes: [&[f32]; C] = std::array::from_fn(|k| &blocks[k * n * T..(k + 1) * n * T]);
        let first = self.o * n * inner + x0;
        self.fin
            .run_rows::<C>(planes, n, T, first, inner, self.valid, out);
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

/// The scratch of [`slabs_tiled_impl`].
struct SlabWork {
    even: Vec<usize>,
    odd: Vec<usize>,
    line_even: Vec<(usize, f32)>,
    line_odd: Vec<(usize, f32)>,
    ev: Vec<f32>,
    od: Vec<f32>,
    deq: Vec<f32>,
}

impl SlabWork {
    #[inline(always)]
    fn new(c: &Coefficients, axes: &InnerAxes, tmp: &mut Vec<f32>) -> SlabWork {
        let InnerAxes { first, b1, b2 } = axes;
        let (e1, e2) = (c.extent[1], c.extent[2]);
        let hp = b1.hp.max(b2.hp);
        let tmp_len = if *first == 2 { e1 * b2.n } else { b1.n * e2 };
        if tmp.len() < tmp_len {
            tmp.resize(tmp_len, 0.0);
        }
        SlabWork {
            even: Vec::with_capacity(e1),
            odd: Vec::with_capacity(e1),
            line_even: Vec::with_capacity(e2),
            line_odd: Vec::with_capacity(e2),
            ev: vec![0f32; hp],
            od: vec![0f32; hp],
            // Dequantized as `expand_along` does.
            deq: vec![0f32; e1 * e2],
        }
    }

    /// Slab k0 of the codes into `plane` (N1 × N2); false, and `plane` all zero, when the
    /// slab holds no nonzero code.
    #[inline(always)]
    fn expand(
        &mut self,
        c: &Coefficients,
        k0: usize,
        step: f64,
        axes: &InnerAxes,
        tmp: &mut [f32],
        plane: &mut [f32],
    ) -> bool {
        let InnerAxes { first, b1, b2 } = axes;
        let (codes, extent) = (&c.codes, &c.extent);
        let (e1, e2) = (extent[1], extent[2]);
        let (n1, n2) = (b1.n, b2.n);
        let slab = &codes[k0 * e1 * e2..(k0 + 1) * e1 * e2];
        let (even, odd) = (&mut self.even, &mut self.odd);
        even.clear();
        odd.clear();
        for k1 in 0..e1 {
            let cl = &slab[k1 * e2..(k1 + 1) * e2];
            // An OR over the line (vectorized; `all` stopped at each code).
            if cl.iter().fold(0, |a, &q| a | q) == 0 {
                continue;
            }
            let dl = &mut self.deq[k1 * e2..(k1 + 1) * e2];
            for (d, &q) in dl.iter_mut().zip(cl) {
                *d = (q as f64 * step) as f32;
            }
            if k1 % 2 == 0 {
                even.push(k1);
            } else {
                odd.push(k1);
            }
        }
        if *first == 2 {
            // Along axis 2 (contiguous), the nonempty lines only; then along axis 1 over the
            // rows they became (the others are zero rows, which the strided pass skips).
            for &k1 in even.iter().chain(odd.iter()) {
                contiguous_line(
                    &self.deq[k1 * e2..(k1 + 1) * e2],
                    b2,
                    &mut tmp[k1 * n2..(k1 + 1) * n2],
                    &mut self.ev,
                    &mut self.od,
                    &mut self.line_even,
                    &mut self.line_odd,
                );
            }
            strided_tiles(&tmp[..e1 * n2], plane, n2, b1, even, odd);
        } else {
            // Along axis 1 (rows of e2 values), then each of the N1 lines along axis 2.
            strided_tiles(&self.deq, &mut tmp[..n1 * e2], e2, b1, even, odd);
            for (src, d) in tmp[..n1 * e2]
                .chunks_exact(e2)
                .zip(plane.chunks_exact_mut(n2))
            {
                contiguous_line(
                    src,
                    b2,
                    d,
                    &mut self.ev,
                    &mut self.od,
                    &mut self.line_even,
                    &mut self.line_odd,
                );
            }
        }
        !(even.is_empty() && odd.is_empty())
    }
}

/// The tiles of the fused last pass along the inner cells: (x0, width). The last lines are
/// one 8-wide tile overlapping the previous ones, as in `strided_tiles` (finishing is per
/// cell, so the overlapped cells are written again with the same values).
fn final_tiles(inner: usize) -> Vec<(usize, usize)> {
    let mut v = Vec::new();
    let mut x0 = 0;
    while x0 + WIDE <= inner {
        v.push((x0, WIDE));
        x0 += WIDE;
    }
    while x0 + 8 <= inner {
        v.push((x0, 8));
        x0 += 8;
    }
    if x0 < inner && inner >= 8 {
        v.push((inner - 8, 8));
        x0 = inner;
    }
    while x0 < inner {
        v.push((x0, 1));
        x0 += 1;
    }
    v
}

/// The inner axes of a 3-D box: the one expanded first (1 or 2) and the bases of axes 1, 2.
struct InnerAxes {
    first: usize,
    b1: HalfBasis,
    b2: HalfBasis,
}

/// The two inner axes of a 3-D box expanded one k0 slab at a time (the last pass is then
/// along axis 0): slab k0 of the codes (e1 × e2) becomes plane k0 (N1 × N2), the first of the
/// two axes being `first` (1 or 2). The kernels, rows and summation order are those of
/// expanding the whole box axis by axis, so the bits are the same; but the slab's
/// intermediate stays in cache, and the code lines that are all zero (most of a DCT box) are
/// skipped instead of dequantized, expanded to zeros, written and scanned again.
///
/// Each plane is built in `plane` (in cache) and stored into `dst` tile by tile of
/// [`final_tiles`]: tile t's rows k0 are contiguous, `width` values each, from
/// e0 × (the widths of the tiles before it). The last pass then reads a tile's rows as one
/// block, where the plane-major layout had it read e0 lines a plane (64 KB for a MERL grid)
/// apart, more streams than the prefetchers follow; and the stores are non-temporal, so the
/// planes (5.8 MB per component of a MERL table) do not evict the expansion's working set.
/// Planes of empty slabs are not stored; the others are listed in `lists` (even, odd) by parity
/// of k0 (the rows the last pass visits).
#[inline(always)]
fn slabs_tiled_impl(
    c: &Coefficients,
    step: f64,
    axes: &InnerAxes,
    tiles: &[(usize, usize)],
    dst: &mut [f32],
    bufs: &mut [Vec<f32>; 2],
    lists: &mut (Vec<usize>, Vec<usize>),
) {
    let [tmp, plane] = bufs;
    let (even, odd) = lists;
    let e0 = c.extent[0];
    let cells = axes.b1.n * axes.b2.n;
    let mut w = SlabWork::new(c, axes, tmp);
    DecodeScratch::grow(plane, cells);
    for k0 in 0..e0 {
        if !w.expand(c, k0, step, axes, tmp, &mut plane[..cells]) {
            continue;
        }
        if k0 % 2 == 0 {
            even.push(k0);
        } else {
            odd.push(k0);
        }
        let mut base = 0;
        for &(x0, t) in tiles {
            let d = &mut dst[base + k0 * t..base + (k0 + 1) * t];
            if t % 8 == 0 {
                stream_copy(d, &plane[x0..x0 + t]);
            } else {
                d.copy_from_slice(&plane[x0..x0 + t]);
            }
            base += e0 * t;
        }
    }
    #[cfg(target_arch = "x86_64")]
    // SAFETY: a fence has no preconditions.
    unsafe {
        std::arch::x86_64::_mm_sfence()
    };
}

/// `dst` = `src` (a multiple of 8 values) with non-temporal stores when `dst` is 32-byte
/// aligned: the planes are read back by the last pass only after every slab is expanded,
/// so keeping them in cache evicts what the expansion is using.
#[inline(always)]
fn stream_copy(dst: &mut [f32], src: &[f32]) {
    #[cfg(target_arch = "x86_64")]
    if crate::codec::simd::avx2() && (dst.as_ptr() as usize).is_multiple_of(32) {
        use std::arch::x86_64::{_mm256_loadu_ps, _mm256_stream_ps};
        assert!(dst.len() == src.len() && dst.len().is_multiple_of(8));
        for i in (0..dst.len()).step_by(8) {
            // SAFETY: i + 8 ≤ len for both slices (asserted); `dst + i` is 32-byte aligned;
            // the CPU has AVX (checked).
            unsafe {
                _mm256_stream_ps(
                    dst.as_mut_ptr().add(i),
                    _mm256_loadu_ps(src.as_ptr().add(i)),
                )
            };
        }
        return;
    }
    dst.copy_from_slice(src);
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

    /// Codes of a box `extent` with empty slabs (k0 = 1), empty lines (every third) and the
    /// rest 30% nonzero.
    fn sparse_box(extent: [usize; 3], seed: u64) -> Coefficients {
        let total: usize = extent.iter().product();
        let mut rng = crate::math::SplitMix64::new(seed);
        let codes: Vec<i32> = (0..total)
            .map(|i| {
                let (k0, line) = (i / (extent[1] * extent[2]), i / extent[2]);
                if k0 == 1 || line % 3 == 2 || rng.next_f64() > 0.3 {
                    0
                } else {
                    (rng.next_f64() * 200.0 - 100.0) as i32
                }
            })
            .collect();
        Coefficients {
            extent: extent.to_vec(),
            codes,
        }
    }

    /// The tiled decode (slab-wise inner passes into a tile-major intermediate, then the last
    /// pass a tile at a time) gives the bits of expanding the inner axes axis by axis and
    /// running the plane-major last pass, for both inner axis orders, 1 and 3 components, an
    /// empty component, odd resolutions and a row narrower than a tile.
    #[test]
    fn tiled_decode_gives_the_plane_major_bits() {
        let cases: [([usize; 3], [[usize; 3]; 3]); 3] = [
            ([7, 9, 13], [[5, 6, 11], [3, 9, 4], [0, 0, 0]]),
            ([90, 90, 180], [[12, 30, 61], [40, 7, 9], [9, 20, 37]]),
            ([5, 3, 2], [[4, 2, 2], [5, 3, 1], [1, 1, 1]]),
        ];
        for (dims, extents) in cases {
            let comps: Vec<Coefficients> = extents
                .iter()
                .enumerate()
                .map(|(k, &e)| sparse_box(e, 11 + k as u64))
                .collect();
            let steps = [0.37, 0.05, 1.3];
            let cells: usize = dims.iter().product();
            let mut rng = crate::math::SplitMix64::new(5);
            let valid: Vec<bool> = (0..cells).map(|_| rng.next_f64() > 0.2).collect();
            for c in [3usize, 1] {
                let fin = Finisher::example(c);
                for orders in [
                    [[2, 1, 0], [1, 2, 0], [2, 1, 0]],
                    [[1, 2, 0], [2, 1, 0], [1, 2, 0]],
                ] {
                    let orders: Vec<Vec<usize>> = orders[..c].iter().map(|o| o.to_vec()).collect();
                    let mut scratch = DecodeScratch::default();
                    let mut tiled = vec![f32::NAN; cells * c];
                    decode_tiled(
                        &comps[..c],
                        &steps[..c],
                        &dims,
                        &orders,
                        &fin,
                        &valid,
                        &mut tiled,
                        &mut scratch,
                    );
                    // The plane-major reference: inner axes one after the other, then the
                    // last pass over whole planes.
                    let mut planes = Vec::new();
                    let mut bases = Vec::new();
                    for ((q, &s), o) in comps[..c].iter().zip(&steps).zip(&orders) {
                        if q.codes.is_empty() {
                            planes.push(Vec::new());
                            bases.push(HalfBasis::new(dims[0], 0));
                        } else {
                            let (a, shape) = expand_along(q, &dims, s, &o[..2], &mut scratch);
                            let n: usize = shape.iter().product();
                            planes.push(a[..n].to_vec());
                            bases.push(HalfBasis::new(dims[0], q.extent[0]));
                        }
                    }
                    let views: Vec<&[f32]> = planes.iter().map(|p| p.as_slice()).collect();
                    let mut plain = vec![f32::NAN; cells * c];
                    let inner = dims[1] * dims[2];
                    if c == 3 {
                        final_3(&views, &bases, 1, inner, &fin, &valid, &mut plain);
                    } else {
                        final_1(&views, &bases, 1, inner, &fin, &valid, &mut plain);
                    }
                    let differ = tiled
                        .iter()
                        .zip(&plain)
                        .filter(|(x, y)| x.to_bits() != y.to_bits())
                        .count();
                    assert_eq!(
                        differ,
                        0,
                        "{differ} of {} values differ, dims {dims:?}, {c} components, orders {orders:?}",
                        tiled.len()
                    );
                    assert!(plain.iter().any(|&v| v > 0.0));
                }
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

    /// `n` codes, 40% zero, the others uniform in (−1000, 1000).
    fn random_codes(n: usize, rng: &mut crate::math::SplitMix64) -> Vec<i32> {
        (0..n)
            .map(|_| {
                if rng.next_f64() < 0.4 {
                    0
                } else {
                    (rng.next_f64() * 2000.0 - 1000.0) as i32
                }
            })
            .collect()
    }

    /// The in-place expansion of a single (lean) decode gives the bits of the two-array one:
    /// every axis order, full and partial boxes, rows wider than a column tile with
    /// remainders wider and narrower than a vector, and the contiguous axis in groups.
    #[test]
    fn the_in_place_expansion_gives_the_two_array_bits() {
        let cases: [(&[usize], &[usize]); 5] = [
            (&[7, 9, 13], &[5, 9, 11]),
            (&[3, 600, 4], &[3, 517, 4]),
            (&[9, 5, 1030], &[9, 5, 1030]),
            (&[6, 8, 5, 130], &[6, 3, 5, 129]),
            (&[40, 3000], &[30, 2900]),
        ];
        for (seed, (dims, extent)) in cases.iter().enumerate() {
            let total: usize = extent.iter().product();
            let mut rng = crate::math::SplitMix64::new(seed as u64 + 17);
            let c = Coefficients {
                extent: extent.to_vec(),
                codes: random_codes(total, &mut rng),
            };
            let d = dims.len();
            let mut order: Vec<usize> = (0..d).collect();
            loop {
                let (two, shape_two) =
                    expand_along(&c, dims, 0.01, &order, &mut DecodeScratch::default());
                // In place whatever the plane's size (a decode takes it above IN_PLACE_CELLS).
                let lean = &mut DecodeScratch::lean();
                let cur = dequantize(&c, 0.01, lean);
                let (one, shape_one) = expand_axes_in_place(
                    cur,
                    c.extent.clone(),
                    dims,
                    &order,
                    lean,
                    dct_pass(&c, dims),
                );
                assert_eq!(shape_two, shape_one);
                let n: usize = shape_two.iter().product();
                let bits = |v: &[f32]| v[..n].iter().map(|x| x.to_bits()).collect::<Vec<_>>();
                assert!(
                    bits(&two) == bits(&one),
                    "{dims:?} {extent:?} order {order:?}"
                );
                if !next_permutation(&mut order) {
                    break;
                }
            }
        }
    }

    /// The values of a set's cells ([`decode_cells`]: the first axis of the decode's order
    /// expanded whole or a slab at a time from the nonzero codes, the others a slab at a
    /// time) are the bits the whole decode gives them, fused, tiled or in place: 3 and 4
    /// axes, 1 and 3 components, full, partial and empty boxes, dense and sparse, every cell
    /// or a few. So are those of the boxes kept by the caller ([`decode_of`],
    /// [`decode_cells_of`]).
    #[test]
    fn listed_cells_decode_to_the_whole_decodes_bits() {
        let cases: [(&[usize], [&[usize]; 3]); 4] = [
            (&[7, 9, 13], [&[5, 9, 11], &[3, 2, 13], &[0, 0, 0]]),
            (&[20, 9, 31], [&[3, 9, 31], &[20, 2, 4], &[11, 9, 30]]),
            (
                &[6, 8, 5, 130],
                [&[6, 3, 5, 129], &[2, 8, 1, 40], &[1, 1, 1, 1]],
            ),
            (
                &[9, 12, 10, 11],
                [&[9, 12, 10, 11], &[4, 2, 9, 3], &[0, 0, 0, 0]],
            ),
        ];
        for (seed, (dims, extents)) in cases.iter().enumerate() {
            let mut rng = crate::math::SplitMix64::new(seed as u64 + 71);
            let cells: usize = dims.iter().product();
            let valid: Vec<bool> = (0..cells).map(|_| rng.next_f64() > 0.2).collect();
            // Boxes of mostly nonzero codes (the pass along the first axis made whole) and
            // of mostly zeros (made a slab at a time from the nonzero ones).
            let mut boxes: Vec<Coefficients> = Vec::new();
            for sparse in [false, true] {
                for e in extents {
                    let total: usize = e.iter().product();
                    let mut codes = random_codes(total, &mut rng);
                    if sparse {
                        for c in codes.iter_mut() {
                            if rng.next_f64() < 0.9 {
                                *c = 0;
                            }
                        }
                    }
                    boxes.push(Coefficients {
                        extent: if total == 0 { Vec::new() } else { e.to_vec() },
                        codes,
                    });
                }
            }
            let every: Vec<u32> = (0..cells as u32).collect();
            let some: Vec<u32> = (0..cells as u32)
                .filter(|_| rng.next_f64() < 0.05)
                .collect();
            let steps = [0.01, 0.003, 0.02];
            // One component (each box in turn) and three.
            let mut sets: Vec<Vec<Coefficients>> = boxes.iter().map(|b| vec![b.clone()]).collect();
            sets.push(boxes[..3].to_vec());
            sets.push(boxes[3..].to_vec());
            for comps in sets {
                let c = comps.len();
                let fin = Finisher::example(c);
                let steps = &steps[..c];
                for lean in [false, true] {
                    let mut whole = vec![f32::NAN; cells * c];
                    let mut scratch = if lean {
                        DecodeScratch::lean()
                    } else {
                        DecodeScratch::default()
                    };
                    decode(
                        &mut comps.clone(),
                        steps,
                        dims,
                        &fin,
                        &valid,
                        &mut whole,
                        &mut scratch,
                    );
                    // The boxes kept (the rate control's codes): the same bits.
                    let mut kept = vec![f32::NAN; cells * c];
                    let mut scratch = if lean {
                        DecodeScratch::lean()
                    } else {
                        DecodeScratch::default()
                    };
                    decode_of(&comps, steps, dims, &fin, &valid, &mut kept, &mut scratch);
                    assert!(
                        kept.iter()
                            .zip(&whole)
                            .all(|(a, b)| a.to_bits() == b.to_bits()),
                        "dims {dims:?}, {c} components: decode_of"
                    );
                    for list in [&every, &some] {
                        let set = CellSet::new(cells, list.iter().copied());
                        let mut got = vec![f32::NAN; list.len() * c];
                        decode_cells(
                            &mut comps.clone(),
                            steps,
                            dims,
                            &fin,
                            &valid,
                            &set,
                            &mut got,
                        );
                        let mut got_of = vec![f32::NAN; list.len() * c];
                        decode_cells_of(&comps, steps, dims, &fin, &valid, &set, &mut got_of);
                        for (i, &f) in list.iter().enumerate() {
                            for k in 0..c {
                                let want = whole[f as usize * c + k].to_bits();
                                assert_eq!(
                                    got[i * c + k].to_bits(),
                                    want,
                                    "dims {dims:?}, {c} components, cell {f}, channel {k}"
                                );
                                assert_eq!(
                                    got_of[i * c + k].to_bits(),
                                    want,
                                    "decode_cells_of: dims {dims:?}, {c} components, cell {f}"
                                );
                            }
                        }
                    }
                }
            }
        }
    }

    /// A large single decode of one component ([`decode_in_place`]: expanded whole in the
    /// output, then finished in place) gives the bits of the fused decode: 3 and 4 axes,
    /// every last axis, full and partial boxes, an empty component, more cells than a chunk.
    #[test]
    fn the_in_place_decode_gives_the_fused_bits() {
        let cases: [(&[usize], [&[usize]; 3]); 3] = [
            (&[7, 9, 13], [&[5, 9, 11], &[3, 2, 13], &[0, 0, 0]]),
            (
                &[6, 8, 5, 130],
                [&[6, 3, 5, 129], &[2, 8, 1, 40], &[1, 1, 1, 1]],
            ),
            (&[33, 40, 30], [&[20, 31, 9], &[33, 40, 30], &[4, 7, 2]]),
        ];
        let fin = Finisher::example(1);
        let bits = |v: &[f32]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
        for (seed, (dims, extents)) in cases.iter().enumerate() {
            let mut rng = crate::math::SplitMix64::new(seed as u64 + 29);
            let cells: usize = dims.iter().product();
            let valid: Vec<bool> = (0..cells).map(|_| rng.next_f64() > 0.2).collect();
            for (k, e) in extents.iter().enumerate() {
                let total: usize = e.iter().product();
                let q = Coefficients {
                    extent: if total == 0 { Vec::new() } else { e.to_vec() },
                    codes: random_codes(total, &mut rng),
                };
                let step = [0.01, 0.003, 0.02][k];
                // The decode's own last axis, through `decode` (fused), and every other.
                let mut fused = vec![f32::NAN; cells];
                let scratch = &mut DecodeScratch::default();
                decode(
                    &mut [q.clone()],
                    &[step],
                    dims,
                    &fin,
                    &valid,
                    &mut fused,
                    scratch,
                );
                let (chosen, orders) = shared_orders(std::slice::from_ref(&q), dims);
                for last in 0..dims.len() {
                    let order = if q.codes.is_empty() {
                        Vec::new()
                    } else {
                        cheapest_order(&q.extent, dims, Some(last)).1
                    };
                    let mut reference = fused.clone();
                    if last != chosen && !q.codes.is_empty() {
                        let d = dims.len();
                        let (a, shape) = expand_along(&q, dims, step, &order[..d - 1], scratch);
                        let n: usize = shape.iter().product();
                        let basis = [HalfBasis::new(dims[last], q.extent[last])];
                        let outer: usize = dims[..last].iter().product();
                        let inner: usize = dims[last + 1..].iter().product();
                        final_1(
                            &[&a[..n]],
                            &basis,
                            outer,
                            inner,
                            &fin,
                            &valid,
                            &mut reference,
                        );
                    }
                    let order = if last == chosen {
                        orders[0].clone()
                    } else {
                        order
                    };
                    let mut in_place = vec![f32::NAN; cells];
                    let lean = &mut DecodeScratch::lean();
                    decode_in_place(
                        &mut q.clone(),
                        step,
                        dims,
                        &order,
                        &fin,
                        &valid,
                        &mut in_place,
                        lean,
                    );
                    assert!(
                        bits(&in_place) == bits(&reference),
                        "{dims:?}, component {k}, last axis {last}"
                    );
                }
                if !q.codes.is_empty() {
                    assert!(fused.iter().any(|&v| v > 0.0));
                }
            }
        }
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
