//! Stage (6), transform coding: an orthonormal separable DCT-II of every transformed component
//! over the whole grid, uniform quantization of the coefficients with one step per component,
//! and only the box of low frequencies that holds every nonzero coefficient stored.
//!
//! The transform is orthonormal, so the squared error of the transformed table equals that of
//! the coefficients (Parseval): a step s gives an RMS error of about s/√12 in the transformed
//! space wherever coefficients are not zeroed. The decoder ([`super::idct`]) expands the box
//! back to the grid one axis at a time, in f32.

use crate::{Error, Result};
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

/// Stage parameters recorded in the header.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct DctStage {
    /// Quantization step of the orthonormal coefficients, per transformed component.
    pub step: Vec<f64>,
}

/// Orthonormal DCT-II matrix, row k: s_k cos(π (n + ½) k / N), s_0 = √(1/N), s_k = √(2/N)
/// (Ahmed, Natarajan & Rao 1974).
pub fn dct_matrix(n: usize) -> Vec<f64> {
    let mut m = vec![0.0; n * n];
    for k in 0..n {
        for j in 0..n {
            m[k * n + j] = dct_entry(n, k, j);
        }
    }
    m
}

/// One entry of [`dct_matrix`]: row k, column j (the same f64 value).
#[inline]
pub fn dct_entry(n: usize, k: usize, j: usize) -> f64 {
    let s = if k == 0 {
        (1.0 / n as f64).sqrt()
    } else {
        (2.0 / n as f64).sqrt()
    };
    s * (std::f64::consts::PI * (j as f64 + 0.5) * k as f64 / n as f64).cos()
}

/// out[o][i][x] = Σ_j mat[i][j] · in[o][j][x] along `axis` (mat is m × dims[axis]).
pub(crate) fn apply_axis<T>(
    input: &[T],
    dims: &[usize],
    axis: usize,
    mat: &[T],
    m: usize,
    par: bool,
) -> Vec<T>
where
    T: Copy + Default + Send + Sync + std::ops::Mul<Output = T> + std::ops::AddAssign,
{
    let n = dims[axis];
    let outer: usize = dims[..axis].iter().product();
    let inner: usize = dims[axis + 1..].iter().product();
    let mut out = vec![T::default(); outer * m * inner];
    let block = |o: usize, dst: &mut [T]| {
        let src = &input[o * n * inner..(o + 1) * n * inner];
        if inner == 1 {
            for (i, d) in dst.iter_mut().enumerate() {
                let row = &mat[i * n..(i + 1) * n];
                let mut s = T::default();
                for (a, b) in row.iter().zip(src) {
                    s += *a * *b;
                }
                *d = s;
            }
        } else {
            for i in 0..m {
                let d = &mut dst[i * inner..(i + 1) * inner];
                for j in 0..n {
                    let w = mat[i * n + j];
                    let s = &src[j * inner..(j + 1) * inner];
                    for (dv, sv) in d.iter_mut().zip(s) {
                        *dv += w * *sv;
                    }
                }
            }
        }
    };
    if par {
        out.par_chunks_mut(m * inner)
            .enumerate()
            .for_each(|(o, dst)| block(o, dst));
    } else {
        for (o, dst) in out.chunks_mut(m * inner).enumerate() {
            block(o, dst);
        }
    }
    out
}

/// Full forward DCT of one plane (parallel: the encoder's cost).
pub fn forward(plane: &[f64], dims: &[usize]) -> Vec<f64> {
    forward_owned(plane.to_vec(), dims)
}

/// [`forward`] of a plane the caller no longer needs: its array is the first of the two the
/// passes use in turn (no copy of the plane; same bits).
pub fn forward_owned(plane: Vec<f64>, dims: &[usize]) -> Vec<f64> {
    // In place: a second plane-sized array (33 MB per component on a 4.2 M-cell table) was
    // the encoder's peak beside the table and the coefficients; a fresh one per axis cost
    // page faults on every pass.
    every_axis(plane, dims, Direction::Forward)
}

/// [`forward_owned`] of a plane held in f32: every line is widened to f64, transformed with
/// the same sums, and rounded back once per axis. For planes too large to hold in f64 beside
/// the table (a 64⁴ grid's plane is 134 MB in f64, twice its one-channel table): the
/// rounding, a relative 6e-8 of each pass's values, is far below any step the rate control
/// measures (and what it measures is the decode of the codes these coefficients make).
pub fn forward_owned_f32(plane: Vec<f32>, dims: &[usize]) -> Vec<f32> {
    every_axis(plane, dims, Direction::Forward)
}

/// The inverse of [`forward_owned_f32`] in the coefficients' own memory: the orthonormal
/// DCT's transpose along each axis (each pass rounded to f32 once, as the forward ones are).
pub fn inverse_owned_f32(coef: Vec<f32>, dims: &[usize]) -> Vec<f32> {
    every_axis(coef, dims, Direction::Inverse)
}

/// `plane` transformed along every axis in turn, in its own memory.
fn every_axis<T: PlaneValue>(mut plane: Vec<T>, dims: &[usize], direction: Direction) -> Vec<T> {
    for (a, &n) in dims.iter().enumerate() {
        dct_axis_in_place(&mut plane, dims, a, &FoldedDct::new(n, direction));
    }
    plane
}

/// How a plane's values are stored: f64, or f32 widened exactly to f64 for the sums and
/// rounded once when written back.
pub trait PlaneValue: Copy + Send + Sync + 'static {
    fn widen(self) -> f64;
    fn narrow(x: f64) -> Self;
}

impl PlaneValue for f64 {
    #[inline(always)]
    fn widen(self) -> f64 {
        self
    }
    #[inline(always)]
    fn narrow(x: f64) -> f64 {
        x
    }
}

impl PlaneValue for f32 {
    #[inline(always)]
    fn widen(self) -> f64 {
        self as f64
    }
    #[inline(always)]
    fn narrow(x: f64) -> f32 {
        x as f32
    }
}

/// Which way a [`FoldedDct`] goes: the DCT-II of [`dct_matrix`], or its transpose (DCT-III).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) enum Direction {
    Forward,
    Inverse,
}

/// The orthonormal DCT of length n by its even/odd symmetry, C[k][n−1−j] = (−1)ᵏ C[k][j]: the
/// even rows act on the sums x_j + x_{n−1−j}, the odd rows on the differences (and the
/// inverse the other way round), so each output costs n/2 products instead of n. The
/// encoder's forward DCTs and the refined fill's inverse ones spent a fifth of a pack there.
pub(crate) struct FoldedDct {
    n: usize,
    direction: Direction,
    /// C[2i][j] for i < ⌈n/2⌉, j < ⌈n/2⌉ (forward: row-major by i; inverse: by j).
    even: Vec<f64>,
    /// C[2i+1][j] for i < ⌊n/2⌋, j < ⌊n/2⌋ (forward: row-major by i; inverse: by j).
    odd: Vec<f64>,
}

impl FoldedDct {
    pub(crate) fn new(n: usize, direction: Direction) -> FoldedDct {
        let (ne, no) = (n.div_ceil(2), n / 2);
        let (mut even, mut odd) = (vec![0.0; ne * ne], vec![0.0; no * no]);
        for i in 0..ne {
            for j in 0..ne {
                let c = dct_entry(n, 2 * i, j);
                match direction {
                    Direction::Forward => even[i * ne + j] = c,
                    Direction::Inverse => even[j * ne + i] = c,
                }
            }
        }
        for i in 0..no {
            for j in 0..no {
                let c = dct_entry(n, 2 * i + 1, j);
                match direction {
                    Direction::Forward => odd[i * no + j] = c,
                    Direction::Inverse => odd[j * no + i] = c,
                }
            }
        }
        FoldedDct {
            n,
            direction,
            even,
            odd,
        }
    }

    /// The transform of LANES lines side by side: `cols(j)` holds their j-th inputs,
    /// `put(k, out)` receives their k-th outputs (each k once, in no fixed order).
    /// `scratch` holds 2·⌈n/2⌉·LANES values.
    #[inline(always)]
    fn lanes<'a>(
        &self,
        cols: impl Fn(usize) -> &'a [f64; LANES],
        put: &mut impl FnMut(usize, &[f64; LANES]),
        scratch: &mut [f64],
    ) {
        let n = self.n;
        let (ne, no) = (n.div_ceil(2), n / 2);
        let (first, second) = scratch.split_at_mut(ne * LANES);
        match self.direction {
            Direction::Forward => {
                // Sums in `first` (the middle input alone when n is odd), differences in
                // `second`.
                for (j, (sum, diff)) in first
                    .chunks_exact_mut(LANES)
                    .zip(second.chunks_exact_mut(LANES))
                    .take(no)
                    .enumerate()
                {
                    let (a, b) = (cols(j), cols(n - 1 - j));
                    for l in 0..LANES {
                        sum[l] = a[l] + b[l];
                        diff[l] = a[l] - b[l];
                    }
                }
                if ne > no {
                    first[no * LANES..ne * LANES].copy_from_slice(cols(no));
                }
                let (sums, diffs) = (&*first, &*second);
                row_blocks(&self.even, ne, ne, |j| lane(sums, j), &mut |i, acc| {
                    put(2 * i, acc)
                });
                row_blocks(&self.odd, no, no, |j| lane(diffs, j), &mut |i, acc| {
                    put(2 * i + 1, acc)
                });
            }
            Direction::Inverse => {
                // The even coefficients' part of x_j in `first`; x_j and x_{n−1−j} are its sum
                // and difference with the odd coefficients' part.
                // (Both parts are stored first and combined in a loop of this function: a
                // closure doing the combination inside `row_blocks` was sometimes left out of
                // line, without AVX2, and made the inverse 1.5× slower.)
                row_blocks(&self.even, ne, ne, |i| cols(2 * i), &mut |j, acc| {
                    first[j * LANES..(j + 1) * LANES].copy_from_slice(acc)
                });
                row_blocks(&self.odd, no, no, |i| cols(2 * i + 1), &mut |j, acc| {
                    second[j * LANES..(j + 1) * LANES].copy_from_slice(acc)
                });
                for j in 0..no {
                    let (e, o) = (lane(first, j), lane(second, j));
                    let (mut lo, mut hi) = ([0.0; LANES], [0.0; LANES]);
                    for l in 0..LANES {
                        lo[l] = e[l] + o[l];
                        hi[l] = e[l] - o[l];
                    }
                    put(j, &lo);
                    put(n - 1 - j, &hi);
                }
                if ne > no {
                    put(no, lane(first, no));
                }
            }
        }
    }
}

/// Inputs j of the LANES lines held side by side in `buf`.
#[inline(always)]
fn lane(buf: &[f64], j: usize) -> &[f64; LANES] {
    buf[j * LANES..(j + 1) * LANES]
        .try_into()
        .expect("LANES wide")
}

/// One axis of a plane transformed by `dct` in place, in parallel, with the same bits for any
/// number of threads: each worker copies the lines or the tile of columns it transforms into
/// a buffer of its own (in f64) before it writes the same elements, and no two workers touch
/// the same ones.
pub(crate) fn dct_axis_in_place<T: PlaneValue>(
    data: &mut [T],
    dims: &[usize],
    axis: usize,
    dct: &FoldedDct,
) {
    let n = dims[axis];
    let outer: usize = dims[..axis].iter().product();
    let inner: usize = dims[axis + 1..].iter().product();
    assert_eq!(data.len(), outer * n * inner);
    assert_eq!(dct.n, n);
    if data.is_empty() {
        return;
    }
    let scratch_len = 2 * n.div_ceil(2) * LANES;
    if inner == 1 {
        // LANES lines side by side, transposed so that one load holds the j-th input of each,
        // then written back over the lines themselves.
        data.par_chunks_mut(LANES * n).for_each_init(
            || {
                (
                    vec![0.0; n * LANES],
                    vec![0.0; n * LANES],
                    vec![0.0; scratch_len],
                )
            },
            |(t, out, scratch), dst| {
                let lines = transpose_lanes(dst, n, t);
                folded_tile(dct, t, LANES, LANES, out, scratch);
                for (l, line) in dst.chunks_exact_mut(n).take(lines).enumerate() {
                    for (k, d) in line.iter_mut().enumerate() {
                        *d = T::narrow(out[k * LANES + l]);
                    }
                }
            },
        );
        return;
    }
    let tiles_per_block = inner.div_ceil(TILE);
    let shared = SharedOut(data.as_mut_ptr());
    let len = data.len();
    (0..outer * tiles_per_block).into_par_iter().for_each_init(
        || {
            (
                vec![0.0; n * TILE],
                vec![0.0; n * TILE],
                vec![0.0; scratch_len],
            )
        },
        |(src, buf, scratch), u| {
            let (o, x0) = (u / tiles_per_block, (u % tiles_per_block) * TILE);
            let w = TILE.min(inner - x0);
            // The tile's columns gathered contiguously (stride TILE, the columns past w
            // zero): the kernel transforms LANES of them at a time.
            for j in 0..n {
                let at = (o * n + j) * inner + x0;
                assert!(at + w <= len);
                // SAFETY: in bounds (asserted); tile u alone reads and writes columns
                // x0..x0 + w of block o, so no other worker touches these elements.
                let from = unsafe { std::slice::from_raw_parts(shared.at(at), w) };
                let row = &mut src[j * TILE..(j + 1) * TILE];
                for (d, &v) in row.iter_mut().zip(from) {
                    *d = v.widen();
                }
                row[w..].fill(0.0);
            }
            folded_tile(dct, src, TILE, w, buf, scratch);
            for i in 0..n {
                let at = (o * n + i) * inner + x0;
                assert!(at + w <= len);
                // SAFETY: as above.
                let to = unsafe { std::slice::from_raw_parts_mut(shared.at(at), w) };
                for (d, &v) in to.iter_mut().zip(&buf[i * TILE..i * TILE + w]) {
                    *d = T::narrow(v);
                }
            }
        },
    );
}

super::simd::dispatch! {
    /// `out[k·stride + x]` = the k-th output of column x of `src` (n × stride) for x < w,
    /// LANES columns at a time (columns from w up to the next multiple of LANES are
    /// transformed too, and never stored by the callers).
    fn folded_tile / folded_tile_avx2 => folded_tile_body(
        dct: &FoldedDct, src: &[f64], stride: usize, w: usize, out: &mut [f64], scratch: &mut [f64],
    )
}

#[inline(always)]
fn folded_tile_body(
    dct: &FoldedDct,
    src: &[f64],
    stride: usize,
    w: usize,
    out: &mut [f64],
    scratch: &mut [f64],
) {
    let mut xs = 0;
    while xs < w {
        let cols = |j: usize| -> &[f64; LANES] {
            let at = j * stride + xs;
            src[at..at + LANES].try_into().expect("LANES wide")
        };
        let mut put = |k: usize, acc: &[f64; LANES]| {
            out[k * stride + xs..k * stride + xs + LANES].copy_from_slice(acc);
        };
        dct.lanes(cols, &mut put, scratch);
        xs += LANES;
    }
}

/// Copies the ≤ LANES contiguous lines of length `n` in `block` into `t` (n × LANES), the
/// j-th input of every line side by side, and returns how many lines there were. Lanes past
/// the last line keep an earlier block's values: their sums are never stored.
fn transpose_lanes<T: PlaneValue>(block: &[T], n: usize, t: &mut [f64]) -> usize {
    let lines = block.len() / n;
    for (l, line) in block.chunks_exact(n).enumerate() {
        for (j, v) in line.iter().enumerate() {
            t[j * LANES + l] = v.widen();
        }
    }
    lines
}

/// Output columns of one tile of [`apply_axis_f64`] along a strided axis, and the rows and
/// lanes of its register block.
const TILE: usize = 32;
const ROWS: usize = 4;
const LANES: usize = 8;

/// [`apply_axis`] for f64, in parallel, with the same bits: every output is still summed as
/// 0 + w₀x₀ + w₁x₁ + … in the order of j (no reassociation, no fused multiply-add), but the
/// work is tiled so that the input a tile reads stays in cache and each input load feeds
/// [`ROWS`] outputs (with an AVX2 copy of the kernels, same bits: [`super::simd`]). The plain loop read the whole plane once per output row along axis 0
/// (12 MB × 90 on the MERL grid) and summed the contiguous axis one scalar at a time; the
/// encoder's forward DCTs (budget search, refined fill) spent most of their time there.
pub(crate) fn apply_axis_f64(
    input: &[f64],
    dims: &[usize],
    axis: usize,
    mat: &[f64],
    m: usize,
) -> Vec<f64> {
    let mut out = Vec::new();
    apply_axis_f64_into(input, dims, axis, mat, m, &mut out);
    out
}

/// [`apply_axis_f64`] into `out`, resized to the output's length (every element is written,
/// so a reused array's old values do not matter).
pub(crate) fn apply_axis_f64_into(
    input: &[f64],
    dims: &[usize],
    axis: usize,
    mat: &[f64],
    m: usize,
    out: &mut Vec<f64>,
) {
    let n = dims[axis];
    let outer: usize = dims[..axis].iter().product();
    let inner: usize = dims[axis + 1..].iter().product();
    debug_assert_eq!(input.len(), outer * n * inner);
    debug_assert_eq!(mat.len(), m * n);
    out.resize(outer * m * inner, 0.0);
    if out.is_empty() {
        return;
    }
    if inner == 1 {
        // Contiguous lines: LANES lines side by side, transposed so that one load holds the
        // j-th input of each.
        // Lanes past the last line keep an earlier block's values: their sums are never
        // stored.
        out.par_chunks_mut(LANES * m).enumerate().for_each_init(
            || vec![0.0; n * LANES],
            |t, (b, dst)| {
                let lines = dst.len() / m;
                transpose_lanes(&input[b * LANES * n..(b * LANES + lines) * n], n, t);
                lines_block(mat, n, m, t, lines, dst);
            },
        );
        return;
    }
    // Strided axis: a tile is TILE columns of one outer block, all m output rows, computed
    // into a per-worker buffer and copied into `out` by the same worker. (Collecting the
    // tiles as vectors and copying them afterwards allocated the whole output again in small
    // pieces and copied it on one core: an eighth of an anisotropic search's time.)
    let tiles_per_block = inner.div_ceil(TILE);
    let dst = SharedOut(out.as_mut_ptr());
    let len = out.len();
    (0..outer * tiles_per_block).into_par_iter().for_each_init(
        || vec![0.0; m * TILE],
        |buf, u| {
            let (o, x0) = (u / tiles_per_block, (u % tiles_per_block) * TILE);
            let w = TILE.min(inner - x0);
            let src = &input[o * n * inner..(o + 1) * n * inner];
            let tile = &mut buf[..m * w];
            strided_tile(mat, n, m, src, inner, x0, tile);
            for i in 0..m {
                let at = (o * m + i) * inner + x0;
                assert!(at + w <= len);
                // SAFETY: in bounds (asserted), and tile u alone writes columns x0..x0 + w
                // of block o's rows, so no two workers write the same element; `out` is not
                // read until every tile is done (`for_each_init` returns after them all).
                unsafe {
                    std::ptr::copy_nonoverlapping(tile.as_ptr().add(i * w), dst.at(at), w);
                }
            }
        },
    );
}

/// The output array of [`apply_axis_f64`] shared by the workers that fill disjoint parts of it.
struct SharedOut<T>(*mut T);

impl<T> Clone for SharedOut<T> {
    fn clone(&self) -> Self {
        *self
    }
}
impl<T> Copy for SharedOut<T> {}

// SAFETY: only used for the disjoint writes described in `apply_axis_f64`.
unsafe impl<T> Send for SharedOut<T> {}
unsafe impl<T> Sync for SharedOut<T> {}

impl<T> SharedOut<T> {
    /// A pointer to element `i` (a method, so that closures capture the whole `Sync` wrapper,
    /// not the raw pointer field).
    fn at(self, i: usize) -> *mut T {
        // SAFETY: callers pass an index inside the array (asserted where it is used).
        unsafe { self.0.add(i) }
    }
}

super::simd::dispatch! {
    /// `dst[l·m + i]` = Σ_j mat[i][j]·t[j][l] for the `lines` ≤ LANES lines of `t` (n × LANES).
    fn lines_block / lines_block_avx2 => lines_block_body(
        mat: &[f64], n: usize, m: usize, t: &[f64], lines: usize, dst: &mut [f64],
    )
}

#[inline(always)]
fn lines_block_body(mat: &[f64], n: usize, m: usize, t: &[f64], lines: usize, dst: &mut [f64]) {
    let mut put = |i: usize, acc: &[f64; LANES]| {
        for (l, v) in acc.iter().take(lines).enumerate() {
            dst[l * m + i] = *v;
        }
    };
    row_blocks(mat, n, m, |j| lane(t, j), &mut put);
}

super::simd::dispatch! {
    /// `tile[i·w + x]` = Σ_j mat[i][j]·src[j·inner + x0 + x] for the w = tile.len() / m
    /// columns of one tile.
    fn strided_tile / strided_tile_avx2 => strided_tile_body(
        mat: &[f64], n: usize, m: usize, src: &[f64], inner: usize, x0: usize, tile: &mut [f64],
    )
}

#[inline(always)]
fn strided_tile_body(
    mat: &[f64],
    n: usize,
    m: usize,
    src: &[f64],
    inner: usize,
    x0: usize,
    tile: &mut [f64],
) {
    let w = tile.len() / m;
    let mut xs = 0;
    while xs + LANES <= w {
        let cols = |j: usize| -> &[f64; LANES] {
            let at = j * inner + x0 + xs;
            src[at..at + LANES].try_into().expect("LANES wide")
        };
        let mut put = |i: usize, acc: &[f64; LANES]| {
            tile[i * w + xs..i * w + xs + LANES].copy_from_slice(acc);
        };
        row_blocks(mat, n, m, cols, &mut put);
        xs += LANES;
    }
    // The last columns of a block narrower than LANES.
    for x in xs..w {
        for i in 0..m {
            let mut s = 0.0;
            for j in 0..n {
                s += mat[i * n + j] * src[j * inner + x0 + x];
            }
            tile[i * w + x] = s;
        }
    }
}

/// For every output row i: acc[l] = Σ_j mat[i][j]·cols(j)[l], summed in the order of j from
/// 0.0, handed to `put(i, acc)`; ROWS rows at a time so that each `cols(j)` load is shared.
#[inline(always)]
fn row_blocks<'a>(
    mat: &[f64],
    n: usize,
    m: usize,
    cols: impl Fn(usize) -> &'a [f64; LANES],
    put: &mut impl FnMut(usize, &[f64; LANES]),
) {
    let mut i = 0;
    while i + ROWS <= m {
        let mut acc = [[0.0f64; LANES]; ROWS];
        for j in 0..n {
            let x = cols(j);
            for (r, a) in acc.iter_mut().enumerate() {
                let w = mat[(i + r) * n + j];
                for (al, xl) in a.iter_mut().zip(x) {
                    *al += w * *xl;
                }
            }
        }
        for (r, a) in acc.iter().enumerate() {
            put(i + r, a);
        }
        i += ROWS;
    }
    for i in i..m {
        let mut acc = [0.0f64; LANES];
        for j in 0..n {
            let w = mat[i * n + j];
            for (al, xl) in acc.iter_mut().zip(cols(j)) {
                *al += w * *xl;
            }
        }
        put(i, &acc);
    }
}

/// Quantized coefficients of one component: the box extents and the codes inside it (C order).
#[derive(Clone, Debug, PartialEq)]
pub struct Coefficients {
    pub extent: Vec<usize>,
    pub codes: Vec<i32>,
}

/// Largest |code| of a quantized coefficient.
pub const MAX_CODE: f64 = (1u32 << 30) as f64;

/// Ok when every coefficient of `coef` quantizes with `step` within ±2^30 levels; the error
/// names the coefficient and the step. [`quantize`] clamps codes at that limit, which the
/// budget search tolerates (it measures the result), but an encoder must refuse: a linear
/// DCT of a table with 8e10 peaks at step 0.05 decoded to an RMS error of 3e10
/// (tests/hard_cases.rs).
pub fn check_range(coef: &[f64], step: f64) -> Result<()> {
    let out_of_range = |c: &&f64| {
        let q = (**c / step).abs();
        q.is_nan() || q > MAX_CODE
    };
    match coef.iter().find(out_of_range) {
        None => Ok(()),
        Some(c) => Err(Error::input(format!(
            "dct: coefficient {c:e} / step {step:e} exceeds 2^30 levels; use a larger step \
             or the log curve"
        ))),
    }
}

/// Quantizes a coefficient plane with `step` and keeps the smallest box holding every nonzero.
pub fn quantize<T: Copy + Into<f64>>(coef: &[T], dims: &[usize], step: f64) -> Coefficients {
    quantize_above(coef, dims, step, 0.0)
}

/// [`quantize`] with every coefficient of magnitude below `threshold` taken as 0 first (the
/// dead zone; 0 for none: no magnitude, not even NaN's, compares below it). The box is found
/// and gathered a line (of the last axis) at a time: per element, the multi-index arithmetic
/// (d divisions) cost more than the quantization in a budget search on a 4-D table.
/// The coefficients may be held in f32 (the planner's, half the memory): each is widened to
/// f64 exactly, then quantized as an f64 coefficient of that value.
pub(crate) fn quantize_above<T: Copy + Into<f64>>(
    coef: &[T],
    dims: &[usize],
    step: f64,
    threshold: f64,
) -> Coefficients {
    let d = dims.len();
    // Each coefficient is quantized where it is read (twice for those in the box): a plane of
    // codes would be a transient as large as the coefficients (16.7 MB for a 4.2 M-cell
    // component), at the encoder's peak.
    let code = |c: T| -> i32 {
        let c: f64 = c.into();
        if c.abs() < threshold {
            0
        } else {
            (c / step).round().clamp(-MAX_CODE, MAX_CODE) as i32
        }
    };
    if d == 0 {
        // A single value: a box of no axes holding it.
        return Coefficients {
            extent: vec![],
            codes: coef.iter().map(|&c| code(c)).collect(),
        };
    }
    let empty = || Coefficients {
        extent: vec![0; d],
        codes: vec![],
    };
    if coef.is_empty() {
        return empty();
    }
    let len = dims[d - 1];
    let mut extent = vec![0usize; d];
    let mut idx = vec![0usize; d - 1];
    for line in coef.chunks_exact(len) {
        if let Some(last) = line.iter().rposition(|&v| code(v) != 0) {
            extent[d - 1] = extent[d - 1].max(last + 1);
            for a in 0..d - 1 {
                extent[a] = extent[a].max(idx[a] + 1);
            }
        }
        advance(&mut idx, &dims[..d - 1]);
    }
    if extent.contains(&0) {
        return empty();
    }
    let total: usize = extent.iter().product();
    let mut codes = Vec::with_capacity(total);
    let run = extent[d - 1];
    let mut idx = vec![0usize; d - 1];
    for _ in 0..total / run {
        let f = idx.iter().zip(dims).fold(0, |f, (&i, &n)| f * n + i) * len;
        codes.extend(coef[f..f + run].iter().map(|&c| code(c)));
        advance(&mut idx, &extent[..d - 1]);
    }
    Coefficients { extent, codes }
}

/// The C-order strides of an array of shape `dims` (the last axis contiguous).
pub(crate) fn c_strides(dims: &[usize]) -> Vec<usize> {
    let mut strides = vec![1usize; dims.len()];
    for a in (0..dims.len().saturating_sub(1)).rev() {
        strides[a] = strides[a + 1] * dims[a + 1];
    }
    strides
}

/// The next multi-index in C order within `extent` (wrapping to all zeros after the last).
pub(crate) fn advance(idx: &mut [usize], extent: &[usize]) {
    for a in (0..idx.len()).rev() {
        idx[a] += 1;
        if idx[a] < extent[a] {
            return;
        }
        idx[a] = 0;
    }
}

pub(crate) fn put_varint(out: &mut Vec<u8>, mut v: u64) {
    while v >= 0x80 {
        out.push((v as u8) | 0x80);
        v >>= 7;
    }
    out.push(v as u8);
}

fn get_varint(b: &[u8], pos: &mut usize) -> Result<u64> {
    get_varint_in(b, pos, "DCT stream")
}

/// A LEB128 varint of the stream named `what` (for its error messages).
pub(crate) fn get_varint_in(b: &[u8], pos: &mut usize, what: &str) -> Result<u64> {
    let mut v = 0u64;
    for shift in (0..64).step_by(7) {
        let byte = *b
            .get(*pos)
            .ok_or_else(|| Error::input(format!("{what}: truncated varint")))?;
        *pos += 1;
        v |= ((byte & 0x7f) as u64) << shift;
        if byte & 0x80 == 0 {
            return Ok(v);
        }
    }
    Err(Error::input(format!("{what}: varint longer than 64 bits")))
}

/// The frequency box extents of `components` components, each checked against the grid.
pub(crate) fn read_extents(
    b: &[u8],
    pos: &mut usize,
    dims: &[usize],
    components: usize,
    what: &str,
) -> Result<Vec<Vec<usize>>> {
    let mut extents = Vec::with_capacity(components);
    for _ in 0..components {
        let mut e = Vec::with_capacity(dims.len());
        for &n in dims {
            let v = get_varint_in(b, pos, what)?;
            if v > n as u64 {
                return Err(Error::input(format!(
                    "{what}: box extent {v} exceeds the axis resolution {n}"
                )));
            }
            e.push(v as usize);
        }
        extents.push(e);
    }
    Ok(extents)
}

/// The raw (pre-entropy) stream: per component its extents then its zigzagged codes.
/// Extents come first for all components so the codes of every component are contiguous.
pub fn serialize(comps: &[Coefficients]) -> Vec<u8> {
    let mut out = Vec::new();
    for c in comps {
        for &e in &c.extent {
            put_varint(&mut out, e as u64);
        }
    }
    for c in comps {
        for &q in &c.codes {
            put_varint(&mut out, ((q << 1) ^ (q >> 31)) as u32 as u64);
        }
    }
    out
}

/// Inverse of [`serialize`], checking every extent against the grid.
pub fn deserialize(b: &[u8], dims: &[usize], components: usize) -> Result<Vec<Coefficients>> {
    let mut pos = 0;
    let extents = read_extents(b, &mut pos, dims, components, "DCT stream")?;
    let mut out = Vec::with_capacity(components);
    for extent in extents {
        let total: usize = if extent.contains(&0) {
            0
        } else {
            extent.iter().product()
        };
        let mut codes = Vec::with_capacity(total.min(b.len()));
        for _ in 0..total {
            // One-byte codes (|q| < 64) are the common case: no loop.
            let u = match b.get(pos) {
                Some(&byte) if byte < 0x80 => {
                    pos += 1;
                    byte as u64
                }
                _ => get_varint(b, &mut pos)?,
            };
            let u =
                u32::try_from(u).map_err(|_| Error::input("DCT stream: code exceeds 32 bits"))?;
            codes.push(((u >> 1) as i32) ^ -((u & 1) as i32));
        }
        out.push(Coefficients { extent, codes });
    }
    if pos != b.len() {
        return Err(Error::input(format!(
            "DCT stream: {} trailing bytes",
            b.len() - pos
        )));
    }
    Ok(out)
}

/// Reconstructs one component plane (every cell) from its quantized box, in f32 (the fast
/// path of [`super::idct`]).
pub fn inverse(c: &Coefficients, dims: &[usize], step: f64) -> Vec<f32> {
    super::idct::inverse(c, dims, step)
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    #[test]
    fn dct_matrix_is_orthonormal() {
        for n in [1, 2, 7, 16] {
            let m = dct_matrix(n);
            for i in 0..n {
                for j in 0..n {
                    let d: f64 = (0..n).map(|k| m[i * n + k] * m[j * n + k]).sum();
                    assert!((d - if i == j { 1.0 } else { 0.0 }).abs() < 1e-12);
                }
            }
        }
    }

    /// The f32 inverse undoes the f32 forward transform to f32 rounding, on every axis
    /// length the grids use (odd, even, 1).
    #[test]
    fn the_f32_inverse_undoes_the_forward_transform() {
        let dims = [5, 1, 12, 7];
        let n: usize = dims.iter().product();
        let mut rng = crate::math::SplitMix64::new(3);
        let plane: Vec<f32> = (0..n)
            .map(|_| (rng.next_f64() * 20.0 - 10.0) as f32)
            .collect();
        let back = inverse_owned_f32(forward_owned_f32(plane.clone(), &dims), &dims);
        for (a, b) in plane.iter().zip(&back) {
            assert!((a - b).abs() <= 1e-5 * 10.0, "{a} vs {b}");
        }
    }

    #[test]
    fn the_folded_axis_transform_is_the_matrix_product() {
        // Contiguous and strided axes, odd and even lengths (1 and 2 included), column counts
        // that are and are not multiples of the tile (32) and the register block (8), and
        // lines fewer than LANES; both directions.
        for dims in [
            vec![5usize, 3, 7],
            vec![3, 70, 9],
            vec![2, 9, 33, 40],
            vec![13],
            vec![1, 1, 1],
            vec![4, 2, 90],
        ] {
            let len: usize = dims.iter().product();
            let plane: Vec<f64> = (0..len)
                .map(|i| ((i * 7919) % 1013) as f64 / 101.0 - 4.0)
                .collect();
            for axis in 0..dims.len() {
                let n = dims[axis];
                let mat = dct_matrix(n);
                let transposed: Vec<f64> = (0..n * n).map(|i| mat[(i % n) * n + i / n]).collect();
                for (direction, m) in [
                    (Direction::Forward, &mat),
                    (Direction::Inverse, &transposed),
                ] {
                    let want = apply_axis_f64(&plane, &dims, axis, m, n);
                    let mut got = plane.clone();
                    dct_axis_in_place(&mut got, &dims, axis, &FoldedDct::new(n, direction));
                    // Rounding only: a few ulps of the largest partial sum (|x| ≤ 4, n terms).
                    let tol = 4.0 * n as f64 * 8.0 * f64::EPSILON;
                    for (a, b) in got.iter().zip(&want) {
                        assert!(
                            (a - b).abs() <= tol,
                            "{dims:?} axis {axis} {direction:?}: {a} {b}"
                        );
                    }
                }
            }
        }
    }

    #[test]
    fn the_f32_plane_transform_rounds_each_pass_of_the_f64_one() {
        // Each axis of an f32 plane is the f64 pass of its widened values, rounded once.
        for dims in [vec![5usize, 3, 7], vec![2, 9, 33, 40], vec![13]] {
            let len: usize = dims.iter().product();
            let plane: Vec<f32> = (0..len)
                .map(|i| ((i * 7919) % 1013) as f32 / 101.0 - 4.0)
                .collect();
            let mut f32s = plane.clone();
            let mut f64s: Vec<f64> = plane.iter().map(|&v| v as f64).collect();
            for axis in 0..dims.len() {
                let dct = FoldedDct::new(dims[axis], Direction::Forward);
                dct_axis_in_place(&mut f64s, &dims, axis, &dct);
                dct_axis_in_place(&mut f32s, &dims, axis, &dct);
                for (a, b) in f32s.iter().zip(&f64s) {
                    assert_eq!(a.to_bits(), (*b as f32).to_bits(), "{dims:?} axis {axis}");
                }
                f64s = f32s.iter().map(|&v| v as f64).collect();
            }
            // And the whole transform stays within f32 rounding of the f64 one.
            let whole = forward_owned_f32(plane.clone(), &dims);
            let exact = forward_owned(plane.iter().map(|&v| v as f64).collect(), &dims);
            let scale = exact.iter().fold(0.0f64, |m, c| m.max(c.abs()));
            for (a, b) in whole.iter().zip(&exact) {
                assert!((*a as f64 - b).abs() <= 1e-6 * scale, "{dims:?}: {a} {b}");
            }
        }
    }

    #[test]
    fn a_single_cosine_has_a_single_coefficient() {
        let dims = [4usize, 6];
        let m = dct_matrix(6);
        // Plane = row 0 constant × basis 2 along axis 1.
        let plane: Vec<f64> = (0..24).map(|f| m[2 * 6 + f % 6] * 0.5).collect();
        let coef = forward(&plane, &dims);
        let q = quantize(&coef, &dims, 1e-3);
        assert_eq!(q.extent, vec![1, 3]);
        assert_eq!(q.codes, vec![0, 0, 1000]);
    }

    /// The element-wise quantizer `quantize_above` replaced: per element a code, the box from
    /// every nonzero's multi-index, then every box position gathered by its flat index.
    fn quantize_elementwise(coef: &[f64], dims: &[usize], step: f64, t: f64) -> Coefficients {
        let d = dims.len();
        let q: Vec<i32> = coef
            .iter()
            .map(|&c| if c.abs() < t { 0.0 } else { c })
            .map(|c| (c / step).round().clamp(-MAX_CODE, MAX_CODE) as i32)
            .collect();
        let mut extent = vec![0usize; d];
        for (f, &v) in q.iter().enumerate() {
            if v != 0 {
                let mut r = f;
                for a in (0..d).rev() {
                    extent[a] = extent[a].max(r % dims[a] + 1);
                    r /= dims[a];
                }
            }
        }
        if extent.contains(&0) {
            return Coefficients {
                extent: vec![0; d],
                codes: vec![],
            };
        }
        let total: usize = extent.iter().product();
        let codes = (0..total)
            .map(|b| {
                let (mut r, mut f, mut stride) = (b, 0, 1);
                for a in (0..d).rev() {
                    f += (r % extent[a]) * stride;
                    r /= extent[a];
                    stride *= dims[a];
                }
                q[f]
            })
            .collect();
        Coefficients { extent, codes }
    }

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(256))]
        /// The line-wise quantizer gives the element-wise one's box and codes, with and
        /// without a dead zone, on 1–4 axes with sparse, empty and NaN-holding planes.
        #[test]
        fn quantize_matches_the_elementwise_quantizer(
            dims in proptest::collection::vec(1usize..6, 1..5),
            seed in any::<u64>(),
            density in 0.0f64..1.0,
            t in prop_oneof![Just(0.0), 0.0f64..2.0],
        ) {
            let n: usize = dims.iter().product();
            let mut rng = crate::math::SplitMix64::new(seed);
            let coef: Vec<f64> = (0..n)
                .map(|_| {
                    let u = rng.next_f64();
                    if u > density { 0.0 } else if u < 0.01 { f64::NAN } else { rng.next_f64() * 8.0 - 4.0 }
                })
                .collect();
            let a = quantize_above(&coef, &dims, 0.7, t);
            let b = quantize_elementwise(&coef, &dims, 0.7, t);
            prop_assert_eq!(&a.extent, &b.extent);
            prop_assert_eq!(&a.codes, &b.codes);
        }
    }

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(48))]
        #[test]
        fn quantized_round_trip_error_is_within_parseval(
            d0 in 1usize..6, d1 in 1usize..6, d2 in 1usize..7, seed in any::<u64>(),
            step in 1e-4f64..0.5,
        ) {
            let dims = [d0, d1, d2];
            let n = d0 * d1 * d2;
            let mut rng = crate::math::SplitMix64::new(seed);
            let plane: Vec<f64> = (0..n).map(|_| rng.next_f64() * 4.0 - 2.0).collect();
            let coef = forward(&plane, &dims);
            let q = quantize(&coef, &dims, step);
            let bytes = serialize(std::slice::from_ref(&q));
            let back = deserialize(&bytes, &dims, 1).unwrap();
            prop_assert_eq!(&back[0], &q);
            let rec = inverse(&back[0], &dims, step);
            // Per coefficient error ≤ step/2 ⇒ total squared error ≤ n (step/2)² (Parseval),
            // plus f32 rounding of the inverse.
            let se: f64 = rec.iter().zip(&plane).map(|(a, b)| (*a as f64 - b).powi(2)).sum();
            prop_assert!(se.sqrt() <= (n as f64).sqrt() * step / 2.0 + 1e-5 * n as f64,
                         "{} vs {}", se.sqrt(), step);
        }
    }

    #[test]
    fn the_tiled_f64_kernel_gives_the_plain_loops_bits() {
        let mut rng = crate::math::SplitMix64::new(7);
        for dims in [
            vec![90usize, 5, 37],
            vec![3, 41, 9],
            vec![1, 1, 13],
            vec![17, 2, 1],
        ] {
            let plane: Vec<f64> = (0..dims.iter().product::<usize>())
                .map(|_| rng.next_f64() * 8.0 - 4.0)
                .collect();
            for axis in 0..3 {
                for m in [dims[axis], dims[axis].div_ceil(3), 6] {
                    let mat: Vec<f64> = (0..m * dims[axis]).map(|_| rng.next_f64() - 0.5).collect();
                    let plain = apply_axis(&plane, &dims, axis, &mat, m, false);
                    let tiled = apply_axis_f64(&plane, &dims, axis, &mat, m);
                    let bits = |v: &[f64]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
                    assert_eq!(
                        bits(&plain),
                        bits(&tiled),
                        "dims {dims:?} axis {axis} m {m}"
                    );
                }
            }
        }
    }

    #[test]
    fn hostile_streams_are_refused() {
        let dims = [4usize, 4];
        assert!(deserialize(&[9, 1], &dims, 1).is_err());
        assert!(deserialize(&[2, 2, 0], &dims, 1).is_err());
        assert!(deserialize(&[0xff; 12], &dims, 1).is_err());
    }
}
