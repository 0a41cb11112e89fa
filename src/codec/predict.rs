//! Stage (4), predict: each sample is predicted from already-coded neighbours on the grid and
//! only the residual is stored; the residuals' bytes are then split into planes (byte
//! shuffle) so that the entropy stage sees long runs of near-zero high bytes.
//!
//! The predictor is a tensor product of finite differences: with shift operator S_a along
//! axis a and order o_a, the residual is r = Π_a (1 − S_a)^{o_a} x. Orders (0,…,0,1) are the
//! delta along the fastest axis; (1,1,1) is the 3-D Lorenzo predictor (Ibarria et al. 2003).
//! Invalid cells carry no residual; they are filled on both sides with the previous sample
//! along the fastest axis so that their valid neighbours still predict well.

#![allow(clippy::needless_range_loop)] // Index loops walk several parallel arrays.

use crate::{Error, Result};
use serde::{Deserialize, Serialize};

/// Where the prediction is computed.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Space {
    /// In f32 values (computed in f64, rounded to f32), residual = difference of the
    /// order-preserving integer keys of the sample and the prediction: exact for any value.
    Float,
    /// In the order-preserving integer keys themselves (a piecewise-linear log scale for
    /// positive floats; the samples of quantized codecs are already integers).
    Integer,
}

/// A predictor: difference orders per grid axis, the space, and whether channels after the
/// first store their residual minus the first channel's (their prediction errors correlate).
#[derive(Clone, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct Predictor {
    pub orders: Vec<u8>,
    pub space: Space,
    pub cross_channel: bool,
}

/// Maps an f32 to an i32 whose order matches the float order (negatives flipped), so that
/// differences of keys are small when the floats are close.
#[inline]
pub fn key_of(x: f32) -> i32 {
    let s = x.to_bits() as i32;
    s ^ ((s >> 31) & 0x7fff_ffff)
}

/// Inverse of [`key_of`].
#[inline]
pub fn float_of(k: i32) -> f32 {
    f32::from_bits((k ^ ((k >> 31) & 0x7fff_ffff)) as u32)
}

#[inline]
fn zigzag(r: i32) -> u32 {
    ((r << 1) ^ (r >> 31)) as u32
}

#[inline]
pub(super) fn unzigzag(u: u32) -> i32 {
    ((u >> 1) as i32) ^ -((u & 1) as i32)
}

/// The grid geometry a predictor runs on.
#[derive(Clone, Debug)]
pub struct Shape<'a> {
    pub dims: &'a [usize],
    pub valid: &'a [bool],
    pub channels: usize,
}

/// The stencil of a predictor on a padded array: (flat offset back, coefficient) for every
/// neighbour (the cell itself, coefficient 1, is excluded).
pub(super) struct Stencil {
    pub(super) terms: Vec<(usize, i64)>,
    pub(super) pdims: Vec<usize>,
    pub(super) pad: Vec<usize>,
}

impl Stencil {
    pub(super) fn new(orders: &[u8], dims: &[usize], channels: usize) -> Result<Stencil> {
        if orders.len() != dims.len() || orders.iter().any(|&o| o > 2) {
            return Err(Error::input(format!(
                "predictor orders {orders:?}: expected one order in 0..=2 per grid axis ({} axes)",
                dims.len()
            )));
        }
        let pad: Vec<usize> = orders.iter().map(|&o| o as usize).collect();
        let pdims: Vec<usize> = dims.iter().zip(&pad).map(|(n, p)| n + p).collect();
        // Strides of the padded array in values (channel fastest).
        let mut strides = vec![0usize; dims.len()];
        let mut s = channels;
        for a in (0..dims.len()).rev() {
            strides[a] = s;
            s *= pdims[a];
        }
        // Binomial coefficients of (1 − S)^o: o = 1 → [1, −1]; o = 2 → [1, −2, 1].
        let coef = |o: u8, d: usize| -> i64 {
            match (o, d) {
                (_, 0) => 1,
                (1, 1) => -1,
                (2, 1) => -2,
                (2, 2) => 1,
                _ => 0,
            }
        };
        let mut terms = Vec::new();
        let total: usize = pad.iter().map(|p| p + 1).product();
        for t in 0..total {
            let mut rem = t;
            let mut off = 0;
            let mut c = 1i64;
            for a in (0..dims.len()).rev() {
                let d = rem % (pad[a] + 1);
                rem /= pad[a] + 1;
                off += d * strides[a];
                c *= coef(orders[a], d);
            }
            if off != 0 && c != 0 {
                // Prediction = −Σ coef·neighbour.
                terms.push((off, -c));
            }
        }
        Ok(Stencil { terms, pdims, pad })
    }

    pub(super) fn padded_len(&self, channels: usize) -> usize {
        self.pdims.iter().product::<usize>() * channels
    }
}

/// Walks the cells of `dims` in C order, yielding (flat cell, flat padded value index,
/// index along the fastest axis).
/// The working array of a walk over the grid: for two or more axes, only the pad₀ + 1 slices
/// along the slowest axis that the stencil reaches back to (the current slice last), not the
/// whole padded grid: a 52 MB table needs a window of under 1 MB instead of a padded copy of
/// itself (twice its size in i64). Indices are the padded grid's, shifted by the slices
/// already passed; reads only reach earlier cells, which the window still holds.
#[derive(Clone, Copy)]
pub(super) struct Window {
    /// Values in one padded slice along the slowest axis (0: the whole grid is held).
    slice: usize,
    len: usize,
}

impl Window {
    pub(super) fn new(st: &Stencil, dims: &[usize], channels: usize) -> Window {
        if dims.len() < 2 {
            return Window {
                slice: 0,
                len: st.padded_len(channels),
            };
        }
        let slice = st.pdims[1..].iter().product::<usize>() * channels;
        Window {
            slice,
            len: (st.pad[0] + 1) * slice,
        }
    }

    /// The whole padded grid: the working array before the window (kept for the tests).
    #[cfg(test)]
    fn whole(st: &Stencil, channels: usize) -> Window {
        Window {
            slice: 0,
            len: st.padded_len(channels),
        }
    }

    pub(super) fn buffer<T: Copy + Default>(&self) -> Vec<T> {
        vec![T::default(); self.len]
    }

    /// The window index of padded index `p` in slice `i0` of the slowest axis.
    #[inline]
    pub(super) fn local(&self, p: usize, i0: usize) -> usize {
        p - i0 * self.slice
    }

    /// Moves to the next slice: the slices kept slide down one place.
    #[inline]
    pub(super) fn advance<T: Copy>(&self, w: &mut [T]) {
        if self.slice > 0 {
            w.copy_within(self.slice.., 0);
        }
    }
}

/// Calls `f(w, cell, i, k)` for every cell in C order: `i` the cell's first value in the
/// working array `w` ([`Window`]), `k` its index along the fastest axis.
fn walk<T: Copy + Default>(
    dims: &[usize],
    st: &Stencil,
    channels: usize,
    f: impl FnMut(&mut [T], usize, usize, usize),
) {
    walk_in(Window::new(st, dims, channels), dims, st, channels, f)
}

/// [`walk`] in a given window.
fn walk_in<T: Copy + Default>(
    window: Window,
    dims: &[usize],
    st: &Stencil,
    channels: usize,
    mut f: impl FnMut(&mut [T], usize, usize, usize),
) {
    let d = dims.len();
    let last = dims[d - 1];
    let outer: usize = dims[..d - 1].iter().product();
    let mut w: Vec<T> = window.buffer();
    let mut idx = vec![0usize; d];
    let mut cell = 0;
    for _ in 0..outer {
        // Padded flat index of (idx[0..d-1], 0).
        let mut p = 0;
        for a in 0..d {
            let i = if a == d - 1 { 0 } else { idx[a] };
            p = p * st.pdims[a] + i + st.pad[a];
        }
        let p = window.local(p * channels, if d > 1 { idx[0] } else { 0 });
        for k in 0..last {
            f(&mut w, cell, p + k * channels, k);
            cell += 1;
        }
        // Advance the outer multi-index.
        for a in (0..d - 1).rev() {
            idx[a] += 1;
            if idx[a] < dims[a] {
                if a == 0 {
                    window.advance(&mut w);
                }
                break;
            }
            idx[a] = 0;
        }
    }
}

impl Predictor {
    /// The prediction residuals (zigzagged) of every valid sample, cell-major, channel fastest.
    /// `data` holds every cell (invalid ones are ignored).
    pub fn residuals_f32(&self, data: &[f32], shape: &Shape) -> Result<Vec<u32>> {
        let mut out = Vec::with_capacity(valid_values(shape));
        self.residuals_f32_each(data, shape, |r| out.push(r))?;
        Ok(out)
    }

    /// [`plane_entropy_bits`] of [`Predictor::residuals_f32`], without holding the residuals.
    pub fn entropy_bits_f32(&self, data: &[f32], shape: &Shape) -> Result<f64> {
        let mut hist = PlaneHistograms::default();
        self.residuals_f32_each(data, shape, |r| hist.add(r))?;
        Ok(hist.entropy_bits())
    }

    /// [`Predictor::residuals_f32`] handed to `sink` one at a time, in order, without holding
    /// them (the encoder streams them to zstd).
    pub fn residuals_f32_each(
        &self,
        data: &[f32],
        shape: &Shape,
        mut sink: impl FnMut(u32),
    ) -> Result<()> {
        if self.space == Space::Integer {
            return self.residuals_int_each(|i| key_of(data[i]), shape, sink);
        }
        let c = shape.channels;
        let st = Stencil::new(&self.orders, shape.dims, c)?;
        let mut r0 = 0i32;
        walk(shape.dims, &st, c, |w: &mut [f32], cell, p, k| {
            for ch in 0..c {
                let i = p + ch;
                if !shape.valid[cell] {
                    // Fill: the previous sample along the fastest axis (pad 0 at k = 0).
                    w[i] = if k > 0 { w[i - c] } else { 0.0 };
                    continue;
                }
                let x = data[cell * c + ch];
                w[i] = x;
                let pred = predict_float(w, i, &st.terms);
                let r = key_of(x).wrapping_sub(key_of(pred));
                sink(residual_of(&mut r0, r, ch, self.cross_channel));
            }
        });
        Ok(())
    }

    /// Inverse of [`Predictor::residuals_f32`]: every cell's values (invalid cells 0).
    pub fn reconstruct_f32(&self, res: &[u32], shape: &Shape) -> Result<Vec<f32>> {
        let c = shape.channels;
        if self.space == Space::Integer {
            let keys = self.reconstruct_i32(res, shape)?;
            return Ok(keys
                .iter()
                .zip(shape.valid.iter().flat_map(|&v| std::iter::repeat_n(v, c)))
                .map(|(&k, v)| if v { float_of(k) } else { 0.0 })
                .collect());
        }
        let st = Stencil::new(&self.orders, shape.dims, c)?;
        check_count(res, shape)?;
        let mut out = vec![0f32; shape.valid.len() * c];
        let mut next = 0usize;
        let mut r0 = 0i32;
        walk(shape.dims, &st, c, |w: &mut [f32], cell, p, k| {
            for ch in 0..c {
                let i = p + ch;
                if !shape.valid[cell] {
                    w[i] = if k > 0 { w[i - c] } else { 0.0 };
                    continue;
                }
                let r = pop_residual(res[next], &mut r0, ch, self.cross_channel);
                next += 1;
                let pred = predict_float(w, i, &st.terms);
                let x = float_of(key_of(pred).wrapping_add(r));
                w[i] = x;
                out[cell * c + ch] = x;
            }
        });
        Ok(out)
    }

    /// Residuals of integer samples (quantized codecs, or float keys), exact.
    pub fn residuals_i32(&self, keys: &[i32], shape: &Shape) -> Result<Vec<u32>> {
        let mut out = Vec::with_capacity(valid_values(shape));
        self.residuals_int_each(|i| keys[i], shape, |r| out.push(r))?;
        Ok(out)
    }

    /// [`Predictor::residuals_i32`] of the samples `value(i)` (i over every cell's values),
    /// handed to `sink` one at a time.
    pub fn residuals_int_each(
        &self,
        mut value: impl FnMut(usize) -> i32,
        shape: &Shape,
        mut sink: impl FnMut(u32),
    ) -> Result<()> {
        let c = shape.channels;
        let st = Stencil::new(&self.orders, shape.dims, c)?;
        let mut r0 = 0i32;
        walk(shape.dims, &st, c, |w: &mut [i64], cell, p, k| {
            for ch in 0..c {
                let i = p + ch;
                if !shape.valid[cell] {
                    w[i] = if k > 0 { w[i - c] } else { 0 };
                    continue;
                }
                let x = value(cell * c + ch);
                w[i] = x as i64;
                let pred = predict_int(w, i, &st.terms);
                // Wrapping: the decoder adds back modulo 2^32, which recovers x exactly.
                let r = (x as i64).wrapping_sub(pred) as i32;
                sink(residual_of(&mut r0, r, ch, self.cross_channel));
            }
        });
        Ok(())
    }

    /// Inverse of [`Predictor::residuals_i32`] (invalid cells hold their fill value).
    pub fn reconstruct_i32(&self, res: &[u32], shape: &Shape) -> Result<Vec<i32>> {
        let c = shape.channels;
        let st = Stencil::new(&self.orders, shape.dims, c)?;
        check_count(res, shape)?;
        let mut out = vec![0i32; shape.valid.len() * c];
        let mut next = 0usize;
        let mut r0 = 0i32;
        walk(shape.dims, &st, c, |w: &mut [i64], cell, p, k| {
            for ch in 0..c {
                let i = p + ch;
                if !shape.valid[cell] {
                    w[i] = if k > 0 { w[i - c] } else { 0 };
                    continue;
                }
                let r = pop_residual(res[next], &mut r0, ch, self.cross_channel);
                next += 1;
                let pred = predict_int(w, i, &st.terms);
                let x = (pred as i32).wrapping_add(r);
                w[i] = x as i64;
                out[cell * c + ch] = x;
            }
        });
        Ok(out)
    }
}

/// Residuals in a stream: valid cells × channels.
fn valid_values(shape: &Shape) -> usize {
    shape.valid.iter().filter(|&&v| v).count() * shape.channels
}

#[inline]
fn predict_float(w: &[f32], i: usize, terms: &[(usize, i64)]) -> f32 {
    let mut s = 0f64;
    for &(off, c) in terms {
        s += c as f64 * w[i - off] as f64;
    }
    // Extrapolation can leave the f32 range; the residual then absorbs the difference.
    s.clamp(-f32::MAX as f64, f32::MAX as f64) as f32
}

#[inline]
fn predict_int(w: &[i64], i: usize, terms: &[(usize, i64)]) -> i64 {
    let mut s = 0i64;
    for &(off, c) in terms {
        s = s.wrapping_add(c.wrapping_mul(w[i - off]));
    }
    s
}

/// The stored residual of channel `ch`: zigzagged, and for cross-channel predictors taken
/// against channel 0's residual of the same cell (kept in `r0`).
#[inline]
fn residual_of(r0: &mut i32, r: i32, ch: usize, cross: bool) -> u32 {
    if ch == 0 {
        *r0 = r;
        zigzag(r)
    } else if cross {
        zigzag(r.wrapping_sub(*r0))
    } else {
        zigzag(r)
    }
}

#[inline]
fn pop_residual(u: u32, r0: &mut i32, ch: usize, cross: bool) -> i32 {
    let r = unzigzag(u);
    if ch == 0 {
        *r0 = r;
        r
    } else if cross {
        r.wrapping_add(*r0)
    } else {
        r
    }
}

fn check_count(res: &[u32], shape: &Shape) -> Result<()> {
    check_residual_count(res.len(), shape)
}

pub(super) fn check_residual_count(n: usize, shape: &Shape) -> Result<()> {
    let want = shape.valid.iter().filter(|&&v| v).count() * shape.channels;
    if n != want {
        return Err(Error::input(format!(
            "payload holds {n} residuals, expected {want} (valid cells × channels)"
        )));
    }
    Ok(())
}

/// [`shuffle`] of the `count` residuals `each` hands to its sink, compressed by `entropy`
/// without holding the residuals or their planes: `each` runs once per byte plane (a walk
/// costs a small fraction of zstd's time; the residuals and the planes were each the size
/// of the table).
pub fn compress_shuffled(
    entropy: &super::entropy::Zstd,
    count: usize,
    each: impl Fn(&mut dyn FnMut(u32)) -> Result<()>,
) -> Result<Vec<u8>> {
    const CHUNK: usize = 1 << 16;
    let mut failed = None;
    entropy.compress_streamed(4 * count, |w| {
        let mut buf = Vec::with_capacity(CHUNK);
        for plane in 0..4 {
            let shift = 8 * plane;
            let mut seen = 0usize;
            let walked = each(&mut |r| {
                seen += 1;
                buf.push((r >> shift) as u8);
                if buf.len() == CHUNK {
                    if let Err(e) = w.write_all(&buf) {
                        failed.get_or_insert(e);
                    }
                    buf.clear();
                }
            });
            if let Err(e) = walked {
                return Err(std::io::Error::other(e.to_string()));
            }
            if seen != count {
                return Err(std::io::Error::other(format!(
                    "{seen} residuals in byte plane {plane}, expected {count}"
                )));
            }
            w.write_all(&buf)?;
            buf.clear();
            if let Some(e) = failed.take() {
                return Err(e);
            }
        }
        Ok(())
    })
}

/// Byte shuffle: the k-th byte of every value into plane k (little-endian).
pub fn shuffle(v: &[u32]) -> Vec<u8> {
    let n = v.len();
    let mut out = vec![0u8; 4 * n];
    let (p0, rest) = out.split_at_mut(n);
    let (p1, rest) = rest.split_at_mut(n);
    let (p2, p3) = rest.split_at_mut(n);
    for (i, &x) in v.iter().enumerate() {
        let b = x.to_le_bytes();
        p0[i] = b[0];
        p1[i] = b[1];
        p2[i] = b[2];
        p3[i] = b[3];
    }
    out
}

/// Inverse of [`shuffle`].
pub fn unshuffle(b: &[u8]) -> Result<Vec<u32>> {
    if !b.len().is_multiple_of(4) {
        return Err(Error::input(format!(
            "shuffled residuals: {} bytes is not a multiple of 4",
            b.len()
        )));
    }
    let n = b.len() / 4;
    let (p0, rest) = b.split_at(n);
    let (p1, rest) = rest.split_at(n);
    let (p2, p3) = rest.split_at(n);
    Ok((0..n)
        .map(|i| u32::from_le_bytes([p0[i], p1[i], p2[i], p3[i]]))
        .collect())
}

/// Order-0 entropy (bits) of the byte planes of `v`: a fast proxy for the coded size, used
/// to choose a predictor without running the entropy coder on every candidate.
pub fn plane_entropy_bits(v: &[u32]) -> f64 {
    let mut hist = PlaneHistograms::default();
    v.iter().for_each(|&x| hist.add(x));
    hist.entropy_bits()
}

/// Byte histograms of the four planes of a stream of residuals: [`plane_entropy_bits`]
/// without holding the stream.
#[derive(Clone, Debug)]
pub struct PlaneHistograms {
    counts: [[u64; 256]; 4],
    n: u64,
}

impl Default for PlaneHistograms {
    fn default() -> Self {
        PlaneHistograms {
            counts: [[0; 256]; 4],
            n: 0,
        }
    }
}

impl PlaneHistograms {
    #[inline]
    pub fn add(&mut self, x: u32) {
        for (plane, hist) in self.counts.iter_mut().enumerate() {
            hist[(x >> (8 * plane)) as u8 as usize] += 1;
        }
        self.n += 1;
    }

    /// The order-0 entropy of the planes, in bits (the sum over planes, in plane order).
    pub fn entropy_bits(&self) -> f64 {
        let n = self.n as f64;
        let mut total = 0.0;
        for hist in &self.counts {
            for &h in hist {
                if h > 0 {
                    let p = h as f64 / n;
                    total -= h as f64 * p.log2();
                }
            }
        }
        total
    }
}

/// The candidate predictors for a grid of `d` axes, from simplest to richest.
pub fn candidates(d: usize, channels: usize) -> Vec<Predictor> {
    let mut out = Vec::new();
    let mut orders_list = vec![];
    let with_last = |last: &[u8]| {
        let mut o = vec![0u8; d];
        let n = last.len().min(d);
        o[d - n..].copy_from_slice(&last[last.len() - n..]);
        o
    };
    orders_list.push(with_last(&[1]));
    orders_list.push(with_last(&[2]));
    orders_list.push(with_last(&[1, 1]));
    orders_list.push(vec![1u8; d]);
    let mut o = vec![1u8; d];
    o[d - 1] = 2;
    orders_list.push(o);
    for orders in orders_list {
        for space in [Space::Float, Space::Integer] {
            for cross in [false, true] {
                if cross && channels < 2 {
                    continue;
                }
                out.push(Predictor {
                    orders: orders.clone(),
                    space,
                    cross_channel: cross,
                });
            }
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    #[test]
    fn the_window_reads_what_the_whole_padded_grid_held() {
        // Every stencil of orders 0..=2 per axis on 2-, 3- and 4-axis grids with invalid
        // cells: the predictions made in the sliding window of pad₀ + 1 slices are those made
        // in the whole padded grid (the window's indices, its slide, and the fill of invalid
        // cells), bit for bit, float and integer.
        let mut seed = 0x9e37_79b9_7f4a_7c15u64;
        let mut next = move || {
            seed ^= seed << 13;
            seed ^= seed >> 7;
            seed ^= seed << 17;
            seed
        };
        for dims in [vec![5, 7], vec![4, 3, 6], vec![3, 2, 4, 5], vec![1, 4, 3]] {
            let d = dims.len();
            let cells: usize = dims.iter().product();
            let c = 2;
            let valid: Vec<bool> = (0..cells).map(|_| next() % 5 != 0).collect();
            let data: Vec<f32> = (0..cells * c)
                .map(|_| (next() % 20_000) as f32 / 97.0 - 60.0)
                .collect();
            for code in 0..3usize.pow(d as u32) {
                let orders: Vec<u8> = (0..d)
                    .map(|a| (code / 3usize.pow(a as u32) % 3) as u8)
                    .collect();
                let st = Stencil::new(&orders, &dims, c).unwrap();
                let run = |window: Window| {
                    let mut seen: Vec<(u32, i64)> = Vec::new();
                    walk_in(window, &dims, &st, c, |w: &mut [f32], cell, p, k| {
                        for ch in 0..c {
                            let i = p + ch;
                            if !valid[cell] {
                                w[i] = if k > 0 { w[i - c] } else { 0.0 };
                                continue;
                            }
                            w[i] = data[cell * c + ch];
                            seen.push((predict_float(w, i, &st.terms).to_bits(), 0));
                        }
                    });
                    walk_in(window, &dims, &st, c, |w: &mut [i64], cell, p, k| {
                        for ch in 0..c {
                            let i = p + ch;
                            if !valid[cell] {
                                w[i] = if k > 0 { w[i - c] } else { 0 };
                                continue;
                            }
                            w[i] = key_of(data[cell * c + ch]) as i64;
                            seen.push((0, predict_int(w, i, &st.terms)));
                        }
                    });
                    seen
                };
                let windowed = run(Window::new(&st, &dims, c));
                let whole = run(Window::whole(&st, c));
                assert_eq!(windowed, whole, "dims {dims:?} orders {orders:?}");
                // The window holds at most what the padded grid did.
                assert!(Window::new(&st, &dims, c).len <= Window::whole(&st, c).len);
            }
        }
    }

    #[test]
    fn the_streamed_stream_is_the_shuffle_of_the_residuals() {
        // compress_shuffled walks once per byte plane and streams to zstd: decompressed, it
        // must be exactly the shuffle of the residuals collected in one walk.
        let dims = [6usize, 5, 9];
        let cells: usize = dims.iter().product();
        let c = 3;
        let valid: Vec<bool> = (0..cells).map(|i| i % 7 != 3).collect();
        let data: Vec<f32> = (0..cells * c)
            .map(|i| ((i * 37 % 101) as f32).ln_1p() * 1e3)
            .collect();
        let shape = Shape {
            dims: &dims,
            valid: &valid,
            channels: c,
        };
        let zstd = super::super::entropy::Zstd { level: 19 };
        for p in candidates(3, c) {
            let res = p.residuals_f32(&data, &shape).unwrap();
            let z = compress_shuffled(&zstd, res.len(), |sink| {
                p.residuals_f32_each(&data, &shape, sink)
            })
            .unwrap();
            assert_eq!(
                zstd.decompress(&z, res.len() * 4).unwrap(),
                shuffle(&res),
                "{p:?}"
            );
            // A walk that hands fewer residuals than promised is an error, not a short frame.
            assert!(
                compress_shuffled(&zstd, res.len() + 1, |sink| p
                    .residuals_f32_each(&data, &shape, sink))
                .is_err()
            );
        }
    }

    #[test]
    fn keys_preserve_order_and_round_trip() {
        let xs = [-3.5f32, -1e-30, -0.0, 0.0, 1e-30, 1.0, 2.0, f32::MAX];
        for w in xs.windows(2) {
            assert!(key_of(w[0]) <= key_of(w[1]), "{w:?}");
        }
        for x in xs {
            assert_eq!(float_of(key_of(x)).to_bits(), x.to_bits());
        }
    }

    #[test]
    fn lorenzo_is_exact_on_trilinear_data() {
        // Π(1 − S) annihilates a + bx + cy + dz + … only up to its own order: a sum of
        // per-axis linear terms is predicted exactly away from the boundary.
        let dims = [6usize, 5, 7];
        let n: usize = dims.iter().product();
        let valid = vec![true; n];
        let keys: Vec<i32> = (0..n)
            .map(|f| {
                let (i, j, k) = (f / 35, f / 7 % 5, f % 7);
                (3 * i + 5 * j + 7 * k) as i32
            })
            .collect();
        let p = Predictor {
            orders: vec![1, 1, 1],
            space: Space::Integer,
            cross_channel: false,
        };
        let shape = Shape {
            dims: &dims,
            valid: &valid,
            channels: 1,
        };
        let r = p.residuals_i32(&keys, &shape).unwrap();
        for f in 0..n {
            let (i, j, k) = (f / 35, f / 7 % 5, f % 7);
            if i > 0 && j > 0 && k > 0 {
                assert_eq!(r[f], 0, "cell {f}");
            }
        }
        assert_eq!(p.reconstruct_i32(&r, &shape).unwrap(), keys);
    }

    #[test]
    fn shuffle_round_trips() {
        let v = vec![0u32, 1, 0xdead_beef, u32::MAX];
        let s = shuffle(&v);
        assert_eq!(&s[..4], &[0, 1, 0xef, 0xff]);
        assert_eq!(unshuffle(&s).unwrap(), v);
        assert!(unshuffle(&s[..3]).is_err());
    }

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(64))]
        #[test]
        fn every_predictor_round_trips_bit_exactly(
            d0 in 1usize..5, d1 in 1usize..5, d2 in 1usize..6, c in 1usize..4,
            seed in any::<u64>(), which in 0usize..20,
        ) {
            let dims = [d0, d1, d2];
            let n = d0 * d1 * d2;
            let mut rng = crate::math::SplitMix64::new(seed);
            let valid: Vec<bool> = (0..n).map(|_| rng.next_f64() < 0.8).collect();
            // Mixed magnitudes, signs, zeros and subnormals.
            let data: Vec<f32> = (0..n * c).map(|i| {
                let u = rng.next_f64();
                if !valid[i / c] || u < 0.1 { 0.0 }
                else if u < 0.15 { -(u as f32) * 1e3 }
                else if u < 0.2 { 1e-40 }
                else { ((u * 40.0 - 20.0).exp()) as f32 }
            }).collect();
            let cands = candidates(3, c);
            let p = &cands[which % cands.len()];
            let shape = Shape { dims: &dims, valid: &valid, channels: c };
            let r = p.residuals_f32(&data, &shape).unwrap();
            // The streamed score is the held residuals' score, bit for bit (the lossless
            // encoder picks its predictor by it).
            prop_assert_eq!(
                p.entropy_bits_f32(&data, &shape).unwrap().to_bits(),
                plane_entropy_bits(&r).to_bits()
            );
            let back = p.reconstruct_f32(&r, &shape).unwrap();
            prop_assert_eq!(back.len(), data.len());
            for (a, b) in back.iter().zip(&data) {
                prop_assert_eq!(a.to_bits(), b.to_bits());
            }
        }
    }
}
