//! The fast inverse of [`super::predict`]: one grid row (a line along the fastest axis) at a
//! time, straight from the shuffled byte planes, bit for bit the values of the reference walk
//! ([`Predictor::reconstruct_f32`] / [`Predictor::reconstruct_i32`], kept for the tests).
//!
//! Per row: (1) the row's residuals are gathered from the four byte planes, unzigzagged and the
//! cross-channel offset added back (vectorized); (2) integer space: the part of the prediction
//! that reads earlier rows is summed for the whole row at once (wrapping i32 arithmetic is
//! associative, so any order gives the reference's bits), then the row is rebuilt left to right
//! from the in-row terms; float space: the reference's f64 sum runs term by term in the
//! stencil's order (rounding depends on that order), with the term table resolved once.

#![allow(clippy::needless_range_loop)] // Lane loops index several parallel arrays.

use super::predict::{
    Predictor, Shape, Space, Stencil, Window, check_residual_count, float_of, key_of,
};
use super::simd::dispatch;
use crate::{Error, Result};

/// The four byte planes of a shuffled residual stream ([`super::predict::shuffle`]).
#[derive(Clone, Copy)]
struct Planes<'a> {
    p: [&'a [u8]; 4],
}

impl<'a> Planes<'a> {
    fn split(b: &'a [u8]) -> Result<Planes<'a>> {
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
        Ok(Planes {
            p: [p0, p1, p2, p3],
        })
    }
    fn len(&self) -> usize {
        self.p[0].len()
    }
}

dispatch!(fn gather_residuals / gather_residuals_avx2 => gather_impl(planes: Planes, start: usize, c: usize, cross: bool, r: &mut [i32]));

/// Residuals `start..start + r.len()` of the stream: unshuffled, unzigzagged, and (cross-channel
/// predictors) channel 0's residual added back to the others of the same cell.
#[inline(always)]
fn gather_impl(planes: Planes, start: usize, c: usize, cross: bool, r: &mut [i32]) {
    let n = r.len();
    let [p0, p1, p2, p3] = planes.p;
    let (p0, p1, p2, p3) = (
        &p0[start..start + n],
        &p1[start..start + n],
        &p2[start..start + n],
        &p3[start..start + n],
    );
    for j in 0..n {
        let u = p0[j] as u32 | (p1[j] as u32) << 8 | (p2[j] as u32) << 16 | (p3[j] as u32) << 24;
        r[j] = ((u >> 1) as i32) ^ -((u & 1) as i32);
    }
    if cross && c > 1 {
        for cell in r.chunks_exact_mut(c) {
            let r0 = cell[0];
            for v in &mut cell[1..] {
                *v = v.wrapping_add(r0);
            }
        }
    }
}

/// The row structure of a stencil: in-row terms (offsets within the current row, in the
/// stencil's order, which puts them first) and the others.
struct Rows {
    d: usize,
    last: usize,
    outer: usize,
    c: usize,
    in_row: Vec<(usize, i64)>,
    earlier: Vec<(usize, i64)>,
}

impl Rows {
    fn new(st: &Stencil, dims: &[usize], c: usize) -> Rows {
        let d = dims.len();
        let row_span = st.pdims[d - 1] * c;
        let (in_row, earlier): (Vec<_>, Vec<_>) = st
            .terms
            .iter()
            .copied()
            .partition(|&(off, _)| d == 1 || off < row_span);
        Rows {
            d,
            last: dims[d - 1],
            outer: dims[..d - 1].iter().product(),
            c,
            in_row,
            earlier,
        }
    }

    /// Calls `f(w, row, index of the row's first cell in w)` for every row in C order, `w`
    /// the working array of a [`Window`] (slid on as the slowest axis advances).
    fn for_each<T: Copy + Default>(
        &self,
        dims: &[usize],
        st: &Stencil,
        mut f: impl FnMut(&mut [T], usize, usize),
    ) {
        let d = self.d;
        let window = Window::new(st, dims, self.c);
        let mut w: Vec<T> = window.buffer();
        let mut idx = vec![0usize; d];
        for row in 0..self.outer {
            let mut p = 0;
            for a in 0..d {
                let i = if a == d - 1 { 0 } else { idx[a] };
                p = p * st.pdims[a] + i + st.pad[a];
            }
            f(
                &mut w,
                row,
                window.local(p * self.c, if d > 1 { idx[0] } else { 0 }),
            );
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
}

/// Inverse of [`Predictor::residuals_i32`] from the shuffled stream: every cell's values
/// (invalid cells 0), identical to [`Predictor::reconstruct_i32`] after an unshuffle.
pub fn reconstruct_i32(p: &Predictor, shuffled: &[u8], shape: &Shape) -> Result<Vec<i32>> {
    let mut out = vec![0i32; shape.valid.len() * shape.channels];
    reconstruct_i32_with(p, shuffled, shape, |i, x| out[i] = x)?;
    Ok(out)
}

/// [`reconstruct_i32`] handed to `put(index, value)` for every value in order (invalid cells
/// 0), so that the caller stores it where it wants (a decoder, in its output buffer).
pub fn reconstruct_i32_with(
    p: &Predictor,
    shuffled: &[u8],
    shape: &Shape,
    mut put: impl FnMut(usize, i32),
) -> Result<()> {
    let c = shape.channels;
    let st = Stencil::new(&p.orders, shape.dims, c)?;
    let planes = Planes::split(shuffled)?;
    check_residual_count(planes.len(), shape)?;
    let rows = Rows::new(&st, shape.dims, c);
    let in_row: Vec<(usize, i32)> = rows.in_row.iter().map(|&(o, k)| (o, k as i32)).collect();
    let earlier: Vec<(usize, i32)> = rows.earlier.iter().map(|&(o, k)| (o, k as i32)).collect();
    let row_values = rows.last * c;
    let mut rest = vec![0i32; row_values];
    let mut r = vec![0i32; row_values];
    let mut next = 0usize;
    rows.for_each(shape.dims, &st, |w: &mut [i32], row, base| {
        let cell0 = row * rows.last;
        let valid = &shape.valid[cell0..cell0 + rows.last];
        let nres = valid.iter().filter(|&&v| v).count() * c;
        gather_residuals(planes, next, c, p.cross_channel, &mut r[..nres]);
        next += nres;
        earlier_sum_i32(w, base, &earlier, &mut rest);
        let mut j = 0;
        for (k, &ok) in valid.iter().enumerate() {
            let i = base + k * c;
            if !ok {
                // Fill: the previous sample along the fastest axis (0 at the row start).
                for ch in 0..c {
                    w[i + ch] = if k > 0 { w[i + ch - c] } else { 0 };
                    put((cell0 + k) * c + ch, 0);
                }
                continue;
            }
            for ch in 0..c {
                let ii = i + ch;
                let mut pred = rest[k * c + ch];
                for &(off, coef) in &in_row {
                    pred = pred.wrapping_add(coef.wrapping_mul(w[ii - off]));
                }
                let x = pred.wrapping_add(r[j]);
                j += 1;
                w[ii] = x;
                put((cell0 + k) * c + ch, x);
            }
        }
    });
    Ok(())
}

dispatch!(fn earlier_sum_i32 / earlier_sum_i32_avx2 => earlier_impl(w: &[i32], base: usize, terms: &[(usize, i32)], rest: &mut [i32]));

/// rest[j] = Σ_terms coef · w[base + j − off], modulo 2³² (order-free).
#[inline(always)]
fn earlier_impl(w: &[i32], base: usize, terms: &[(usize, i32)], rest: &mut [i32]) {
    rest.fill(0);
    let n = rest.len();
    for &(off, coef) in terms {
        let src = &w[base - off..base - off + n];
        for (r, &s) in rest.iter_mut().zip(src) {
            *r = r.wrapping_add(coef.wrapping_mul(s));
        }
    }
}

/// Inverse of [`Predictor::residuals_f32`] from the shuffled stream: every cell's values
/// (invalid cells 0), bit for bit those of [`Predictor::reconstruct_f32`].
#[cfg(test)]
pub fn reconstruct_f32(p: &Predictor, shuffled: &[u8], shape: &Shape) -> Result<Vec<f32>> {
    let mut out = vec![0f32; shape.valid.len() * shape.channels];
    reconstruct_f32_into(p, shuffled, shape, &mut out)?;
    Ok(out)
}

/// [`reconstruct_f32`] into `out` (every cell's values; the decoder's buffer, so that a
/// decode holds the stream and the table, not a third array of the table's size).
pub fn reconstruct_f32_into(
    p: &Predictor,
    shuffled: &[u8],
    shape: &Shape,
    out: &mut [f32],
) -> Result<()> {
    let c = shape.channels;
    if out.len() != shape.valid.len() * c {
        return Err(Error::input(format!(
            "payload decodes to {} values, the table has {}",
            shape.valid.len() * c,
            out.len()
        )));
    }
    if p.space == Space::Integer {
        // Invalid cells are handed key 0, the float 0.
        return reconstruct_i32_with(p, shuffled, shape, |i, k| out[i] = float_of(k));
    }
    let st = Stencil::new(&p.orders, shape.dims, c)?;
    let planes = Planes::split(shuffled)?;
    check_residual_count(planes.len(), shape)?;
    let rows = Rows::new(&st, shape.dims, c);
    // The reference adds the terms in the stencil's order; so must we (f64 rounding).
    let terms: Vec<(usize, f64)> = st.terms.iter().map(|&(o, k)| (o, k as f64)).collect();
    let row_values = rows.last * c;
    let mut r = vec![0i32; row_values];
    let mut next = 0usize;
    rows.for_each(shape.dims, &st, |w: &mut [f32], row, base| {
        let cell0 = row * rows.last;
        let valid = &shape.valid[cell0..cell0 + rows.last];
        let nres = valid.iter().filter(|&&v| v).count() * c;
        gather_residuals(planes, next, c, p.cross_channel, &mut r[..nres]);
        next += nres;
        let mut j = 0;
        for (k, &ok) in valid.iter().enumerate() {
            let i = base + k * c;
            if !ok {
                for ch in 0..c {
                    w[i + ch] = if k > 0 { w[i + ch - c] } else { 0.0 };
                    out[(cell0 + k) * c + ch] = 0.0;
                }
                continue;
            }
            for ch in 0..c {
                let ii = i + ch;
                let mut s = 0f64;
                for &(off, coef) in &terms {
                    s += coef * w[ii - off] as f64;
                }
                // As the reference: extrapolation may leave the f32 range.
                let pred = s.clamp(-f32::MAX as f64, f32::MAX as f64) as f32;
                let x = float_of(key_of(pred).wrapping_add(r[j]));
                j += 1;
                w[ii] = x;
                out[(cell0 + k) * c + ch] = x;
            }
        }
    });
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::codec::predict::{candidates, shuffle};
    use proptest::prelude::*;

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(96))]
        /// The fast inverse equals the reference walk bit for bit, for every candidate
        /// predictor, on masks, mixed magnitudes, signs, zeros and subnormals.
        #[test]
        fn matches_the_reference_walk(
            d0 in 1usize..5, d1 in 1usize..6, d2 in 1usize..9, c in 1usize..4,
            seed in any::<u64>(), which in 0usize..20,
        ) {
            let dims = [d0, d1, d2];
            let n = d0 * d1 * d2;
            let mut rng = crate::math::SplitMix64::new(seed);
            let valid: Vec<bool> = (0..n).map(|_| rng.next_f64() < 0.8).collect();
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
            let res = p.residuals_f32(&data, &shape).unwrap();
            let want = p.reconstruct_f32(&res, &shape).unwrap();
            let got = reconstruct_f32(p, &shuffle(&res), &shape).unwrap();
            prop_assert_eq!(got.len(), want.len());
            for (a, b) in got.iter().zip(&want) {
                prop_assert_eq!(a.to_bits(), b.to_bits());
            }
            // Arbitrary (hostile) residuals decode to the same bits too.
            let junk: Vec<u32> = (0..res.len()).map(|_| rng.next_u64() as u32).collect();
            let want = p.reconstruct_f32(&junk, &shape).unwrap();
            let got = reconstruct_f32(p, &shuffle(&junk), &shape).unwrap();
            for (a, b) in got.iter().zip(&want) {
                prop_assert_eq!(a.to_bits(), b.to_bits());
            }
            let want = p.reconstruct_i32(&junk, &shape).unwrap();
            prop_assert_eq!(reconstruct_i32(p, &shuffle(&junk), &shape).unwrap(), want);
        }
    }

    #[test]
    fn four_axes_and_bad_lengths() {
        let dims = [3usize, 2, 4, 5];
        let n = 120;
        let valid: Vec<bool> = (0..n).map(|i| i % 7 != 3).collect();
        let shape = Shape {
            dims: &dims,
            valid: &valid,
            channels: 2,
        };
        let data: Vec<f32> = (0..n * 2).map(|i| (i as f32 * 0.37).sin() * 10.0).collect();
        for p in candidates(4, 2) {
            let res = p.residuals_f32(&data, &shape).unwrap();
            let want = p.reconstruct_f32(&res, &shape).unwrap();
            let got = reconstruct_f32(&p, &shuffle(&res), &shape).unwrap();
            assert!(
                got.iter()
                    .zip(&want)
                    .all(|(a, b)| a.to_bits() == b.to_bits()),
                "{p:?}"
            );
            let b = shuffle(&res);
            assert!(reconstruct_f32(&p, &b[..b.len() - 4], &shape).is_err());
            assert!(reconstruct_f32(&p, &b[..b.len() - 1], &shape).is_err());
        }
    }
}
