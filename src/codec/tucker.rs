//! Stage (6b), low rank: a truncated Tucker decomposition of every transformed component
//! (HOSVD: De Lathauwer, De Moor & Vandewalle 2000, "A multilinear singular value
//! decomposition"), X ≈ G ×₁ U₁ ×₂ U₂ ×₃ U₃, with U_a the N_a × r_a leading left singular
//! vectors of the mode-a unfolding and G the r₁ × r₂ × r₃ core.
//!
//! Encoder (f64):
//! 1. U_a from the eigenvectors of the N_a × N_a Gram matrix X_(a) X_(a)ᵀ (the hand-written
//!    cyclic Jacobi of [`super::eigen`], scalar and sequential, so the same bits on every CPU
//!    and thread count). The Gram matrix of a MERL grid is at most 180 × 180 and costs one
//!    pass over the table per axis; an SVD of the 90 × 16,200 or 180 × 8,100 unfolding would
//!    copy and factor the whole table per axis to get the same vectors. Squaring the spectrum only loses the singular values below
//!    1e-8 × the largest, which a truncation drops anyway. Signs: the largest-|·| entry of
//!    every column is made positive (first such entry on ties), so the vectors are unique.
//! 2. σ_aj = the norm of core slice j along axis a (the singular values of X_(a)); column j of
//!    U_a is quantized with step κ·s/σ_aj (s the core step, κ `factor_step`): an error δ in
//!    that column costs ‖δ‖²σ_aj², so every factor entry weighs about as much as one core
//!    code. The step is clamped to [2⁻²³, 2⁻⁸] × the column's largest |entry|, which keeps
//!    codes below 2²⁴ and the quantized columns independent.
//! 3. The core is the least-squares core for the *quantized* factors Û_a,
//!    G = X ×ₐ (Û_aᵀÛ_a)⁻¹Û_aᵀ (plain f64 with a fixed summation order), quantized with
//!    step s; only the box of leading core indices holding every nonzero code is kept, and the
//!    factor columns outside it are dropped.
//!
//! Stream (then zstd): per component the box extents (varints); every factor column's step
//! (f32 LE); every factor column's codes, zigzag varints of the differences down the column
//! (singular vectors of a smooth table are smooth); the core codes (zigzag varints, C order).
//!
//! Decoder: the core is expanded one axis at a time (cheapest axis order first, as in
//! [`super::idct`]), in f32, with loops vectorized across the lines of each pass; then
//! [`super::simd::finish`] (colour, curve, invalid cells 0, interleave).

#![allow(clippy::needless_range_loop)] // Lane loops index several parallel arrays.

use super::DecodeScratch;
use super::dct::{self, Coefficients};
use super::eigen::SymmetricEigen;
use super::idct::{accumulate_two, expand_axes};
use super::simd::{Finisher, dispatch, finish};
use crate::{Error, Result};
use rayon::prelude::*;
use serde::{Deserialize, Serialize};
use std::borrow::Cow;

/// Stage parameters recorded in the header.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct TuckerStage {
    /// Largest rank per grid axis; a component keeps only the leading columns that carry a
    /// nonzero core code.
    pub ranks: Vec<usize>,
    /// Quantization step of the core, per transformed component.
    pub step: Vec<f64>,
    /// κ: factor column j of axis a is quantized with step κ·step/σ_aj.
    pub factor_step: f64,
}

/// Accepted range of κ.
pub const FACTOR_STEP_RANGE: (f64, f64) = (1e-3, 1e3);
/// Largest |code| of a factor entry (the encoder's clamp keeps codes ≤ 2²³ + 1).
pub const MAX_FACTOR_CODE: i64 = 1 << 24;
/// Factor column steps relative to the column's largest |entry|.
const FACTOR_STEP_CLAMP: (f64, f64) = (1.0 / (1u64 << 23) as f64, 1.0 / 256.0);

impl TuckerStage {
    /// Checks the stage against the grid axes and the component count (header fields may be
    /// hostile).
    pub fn validate(&self, dims: &[usize], components: usize) -> Result<()> {
        if self.ranks.len() != dims.len() {
            return Err(Error::input(format!(
                "tucker ranks {:?}: expected {} (one per grid axis)",
                self.ranks,
                dims.len()
            )));
        }
        for (a, (&r, &n)) in self.ranks.iter().zip(dims).enumerate() {
            if r == 0 || r > n {
                return Err(Error::input(format!(
                    "tucker rank {r} on axis {a}: need 1..={n} (the axis resolution)"
                )));
            }
        }
        if self.step.len() != components || self.step.iter().any(|s| !(s.is_finite() && *s > 0.0)) {
            return Err(Error::input(format!(
                "tucker steps {:?}: need {components} finite positive values",
                self.step
            )));
        }
        let (lo, hi) = FACTOR_STEP_RANGE;
        if !(lo..=hi).contains(&self.factor_step) {
            return Err(Error::input(format!(
                "tucker factor_step {}: need a number in {lo}..={hi}",
                crate::model::params::fmt_num(self.factor_step)
            )));
        }
        Ok(())
    }
}

/// One quantized factor matrix: `extent` columns of N codes each (column-major), and the
/// step of every column.
#[derive(Clone, Debug, PartialEq)]
pub struct Factor {
    pub steps: Vec<f32>,
    pub codes: Vec<i32>,
}

/// One quantized component: the core box (extents and codes) and a factor per axis holding
/// as many columns as the box extent along that axis.
#[derive(Clone, Debug, PartialEq)]
pub struct Component {
    pub core: Coefficients,
    pub factors: Vec<Factor>,
}

impl Component {
    fn is_empty(&self) -> bool {
        self.core.codes.is_empty()
    }
}

/// Dequantized factor entry: the same f64 product in the encoder and in both decoders.
#[inline]
fn dequant(code: i32, step: f32) -> f64 {
    code as f64 * step as f64
}

fn strides_of(dims: &[usize], a: usize) -> (usize, usize) {
    (dims[..a].iter().product(), dims[a + 1..].iter().product())
}

/// G[i][j] = Σ X[o][i][x]·X[o][j][x] over the other indices (row-major, symmetric). Rows
/// in parallel, each summed in a fixed order: the same bits for any thread count.
fn gram(x: &[f64], dims: &[usize], a: usize) -> Vec<f64> {
    let n = dims[a];
    let (outer, inner) = strides_of(dims, a);
    let rows: Vec<Vec<f64>> = (0..n)
        .into_par_iter()
        .map(|i| {
            let mut row = vec![0.0; i + 1];
            if inner == 1 {
                // Element-wise over j (vectorizes); still one fixed order per entry.
                for line in x.chunks_exact(n) {
                    let xi = line[i];
                    for (r, xj) in row.iter_mut().zip(line) {
                        *r += xi * xj;
                    }
                }
                return row;
            }
            for o in 0..outer {
                let base = o * n * inner;
                let xi = &x[base + i * inner..base + (i + 1) * inner];
                for (j, r) in row.iter_mut().enumerate() {
                    let xj = &x[base + j * inner..base + (j + 1) * inner];
                    let mut s = 0.0;
                    for (p, q) in xi.iter().zip(xj) {
                        s += p * q;
                    }
                    *r += s;
                }
            }
            row
        })
        .collect();
    let mut g = vec![0.0; n * n];
    for (i, row) in rows.iter().enumerate() {
        for (j, &v) in row.iter().enumerate() {
            g[i * n + j] = v;
            g[j * n + i] = v;
        }
    }
    g
}

/// The `r` eigenvectors of the symmetric `g` (n × n) with the largest eigenvalues, largest
/// first, column-major (n values per column), each with its largest-|·| entry positive.
fn leading_eigenvectors(g: &[f64], n: usize, r: usize) -> Result<Vec<f64>> {
    let evd = SymmetricEigen::new(g, n).ok_or_else(|| {
        Error::Failure(format!(
            "tucker: eigendecomposition of a {n} × {n} Gram matrix failed \
             (non-finite entries from a non-finite transformed table?)"
        ))
    })?;
    let mut out = Vec::with_capacity(n * r);
    for j in 0..r {
        out.extend_from_slice(evd.vector(j));
    }
    Ok(out)
}

/// X ×ₐ mats[a] for every axis (mats[a] is m_a × dims[a], row-major), the axes that shrink
/// the array most first.
fn multiply_all(x: &[f64], dims: &[usize], mats: &[(Vec<f64>, usize)]) -> Vec<f64> {
    let mut order: Vec<usize> = (0..dims.len()).collect();
    order.sort_by(|&a, &b| {
        (mats[a].1 as f64 / dims[a] as f64).total_cmp(&(mats[b].1 as f64 / dims[b] as f64))
    });
    let mut cur = x.to_vec();
    let mut cur_dims = dims.to_vec();
    for a in order {
        let (mat, m) = &mats[a];
        cur = dct::apply_axis_f64(&cur, &cur_dims, a, mat, *m);
        cur_dims[a] = *m;
    }
    cur
}

/// (ÛᵀÛ)⁻¹Ûᵀ (r × n, row-major) of the column-major n × r `u`, by Cholesky; `None` when
/// ÛᵀÛ is not positive definite.
fn pseudo_inverse(u: &[f64], n: usize, r: usize) -> Option<Vec<f64>> {
    let col = |j: usize| &u[j * n..(j + 1) * n];
    let mut l = vec![0.0; r * r];
    for i in 0..r {
        for j in 0..=i {
            let a: f64 = col(i).iter().zip(col(j)).map(|(p, q)| p * q).sum();
            let s = a - (0..j).map(|k| l[i * r + k] * l[j * r + k]).sum::<f64>();
            if i == j {
                if s.is_nan() || s <= 0.0 {
                    return None;
                }
                l[i * r + i] = s.sqrt();
            } else {
                l[i * r + j] = s / l[j * r + j];
            }
        }
    }
    let mut p = vec![0.0; r * n];
    let mut y = vec![0.0; r];
    for t in 0..n {
        // L y = Û[t, :]ᵀ, then Lᵀ p = y.
        for i in 0..r {
            let s = u[i * n + t] - (0..i).map(|k| l[i * r + k] * y[k]).sum::<f64>();
            y[i] = s / l[i * r + i];
        }
        for i in (0..r).rev() {
            let s = y[i] - (i + 1..r).map(|k| l[k * r + i] * p[k * n + t]).sum::<f64>();
            p[i * n + t] = s / l[i * r + i];
        }
    }
    Some(p)
}

/// The squared norms of the core slices along `a` (core of shape `dims`).
fn slice_norms(core: &[f64], dims: &[usize], a: usize) -> Vec<f64> {
    let n = dims[a];
    let (_, inner) = strides_of(dims, a);
    let mut s = vec![0.0; n];
    for (f, v) in core.iter().enumerate() {
        s[(f / inner) % n] += v * v;
    }
    s.iter().map(|x| x.sqrt()).collect()
}

/// Quantizes one component plane (f64, every cell, invalid cells already filled).
pub fn quantize_plane(
    x: &[f64],
    dims: &[usize],
    ranks: &[usize],
    step: f64,
    factor_step: f64,
) -> Result<Component> {
    let d = dims.len();
    let mut u = Vec::with_capacity(d);
    for a in 0..d {
        u.push(leading_eigenvectors(&gram(x, dims, a), dims[a], ranks[a])?);
    }
    let transposed = |a: usize, m: &[f64]| -> (Vec<f64>, usize) {
        // Column-major n × r is row-major r × n: Uᵀ as is.
        (m.to_vec(), ranks[a])
    };
    let mats: Vec<_> = (0..d).map(|a| transposed(a, &u[a])).collect();
    let core0 = multiply_all(x, dims, &mats);
    let mut factors = Vec::with_capacity(d);
    let mut uq = Vec::with_capacity(d);
    for a in 0..d {
        let n = dims[a];
        let sigma = slice_norms(&core0, ranks, a);
        let mut f = Factor {
            steps: Vec::with_capacity(ranks[a]),
            codes: Vec::with_capacity(n * ranks[a]),
        };
        let mut deq = Vec::with_capacity(n * ranks[a]);
        for j in 0..ranks[a] {
            let c = &u[a][j * n..(j + 1) * n];
            let umax = c.iter().fold(0.0f64, |m, v| m.max(v.abs()));
            let want = factor_step * step / sigma[j];
            let fs = want
                .min(FACTOR_STEP_CLAMP.1 * umax)
                .max(FACTOR_STEP_CLAMP.0 * umax) as f32;
            for &v in c {
                let q = (v / fs as f64).round() as i32;
                f.codes.push(q);
                deq.push(dequant(q, fs));
            }
            f.steps.push(fs);
        }
        factors.push(f);
        uq.push(deq);
    }
    let mut mats = Vec::with_capacity(d);
    for a in 0..d {
        let p = pseudo_inverse(&uq[a], dims[a], ranks[a]).ok_or_else(|| {
            Error::Failure(format!(
                "tucker: quantized factor of axis {a} lost rank (step {step:e})"
            ))
        })?;
        mats.push((p, ranks[a]));
    }
    let core = multiply_all(x, dims, &mats);
    dct::check_range(&core, step).map_err(|e| {
        Error::input(
            e.to_string()
                .replacen("dct: coefficient", "tucker: core value", 1),
        )
    })?;
    let core = dct::quantize(&core, ranks, step);
    let factors = if core.codes.is_empty() {
        vec![
            Factor {
                steps: vec![],
                codes: vec![],
            };
            d
        ]
    } else {
        factors
            .into_iter()
            .enumerate()
            .map(|(a, mut f)| {
                let e = core.extent[a];
                f.steps.truncate(e);
                f.codes.truncate(e * dims[a]);
                f
            })
            .collect()
    };
    Ok(Component { core, factors })
}

/// The raw (pre-entropy) stream of every component (module doc).
pub fn serialize(comps: &[Component]) -> Vec<u8> {
    let mut out = Vec::new();
    for c in comps {
        for &e in &c.core.extent {
            dct::put_varint(&mut out, e as u64);
        }
    }
    for c in comps {
        for f in &c.factors {
            for s in &f.steps {
                out.extend_from_slice(&s.to_le_bytes());
            }
        }
    }
    let zigzag = |v: i64| ((v << 1) ^ (v >> 63)) as u64;
    for c in comps {
        for f in &c.factors {
            let n = f.codes.len() / f.steps.len().max(1);
            for col in f.codes.chunks(n.max(1)) {
                let mut prev = 0i64;
                for &q in col {
                    dct::put_varint(&mut out, zigzag(q as i64 - prev));
                    prev = q as i64;
                }
            }
        }
    }
    for c in comps {
        for &q in &c.core.codes {
            dct::put_varint(&mut out, zigzag(q as i64));
        }
    }
    out
}

const WHAT: &str = "Tucker stream";

fn get_zigzag(b: &[u8], pos: &mut usize) -> Result<i64> {
    let u = dct::get_varint_in(b, pos, WHAT)?;
    Ok(((u >> 1) as i64) ^ -((u & 1) as i64))
}

/// Inverse of [`serialize`], checking every field against the grid and the stage.
pub fn deserialize(b: &[u8], dims: &[usize], stage: &TuckerStage) -> Result<Vec<Component>> {
    let c = stage.step.len();
    let d = dims.len();
    let mut pos = 0;
    let extents = dct::read_extents(b, &mut pos, &stage.ranks, c, WHAT)?;
    for e in &extents {
        if e.contains(&0) && e.iter().any(|&x| x != 0) {
            return Err(Error::input(format!(
                "{WHAT}: core box {e:?} is empty along one axis only"
            )));
        }
    }
    let mut steps: Vec<Vec<Vec<f32>>> = Vec::with_capacity(c);
    for e in &extents {
        let mut per_axis = Vec::with_capacity(d);
        for &ea in e {
            let mut s = Vec::with_capacity(ea);
            for _ in 0..ea {
                let bytes = b
                    .get(pos..pos + 4)
                    .ok_or_else(|| Error::input(format!("{WHAT}: truncated factor steps")))?;
                pos += 4;
                let v = f32::from_le_bytes([bytes[0], bytes[1], bytes[2], bytes[3]]);
                if !(v.is_finite() && v > 0.0) {
                    return Err(Error::input(format!(
                        "{WHAT}: factor step {v} is not finite and positive"
                    )));
                }
                s.push(v);
            }
            per_axis.push(s);
        }
        steps.push(per_axis);
    }
    let mut factors: Vec<Vec<Factor>> = Vec::with_capacity(c);
    for (e, st) in extents.iter().zip(steps) {
        let mut per_axis = Vec::with_capacity(d);
        for ((&ea, s), &n) in e.iter().zip(st).zip(dims) {
            let mut codes = Vec::with_capacity((ea * n).min(b.len()));
            for _ in 0..ea {
                let mut prev = 0i64;
                for _ in 0..n {
                    let q = prev.saturating_add(get_zigzag(b, &mut pos)?);
                    if q.abs() > MAX_FACTOR_CODE {
                        return Err(Error::input(format!(
                            "{WHAT}: factor code {q} exceeds 2^24"
                        )));
                    }
                    codes.push(q as i32);
                    prev = q;
                }
            }
            per_axis.push(Factor { steps: s, codes });
        }
        factors.push(per_axis);
    }
    let mut out = Vec::with_capacity(c);
    for (extent, factors) in extents.into_iter().zip(factors) {
        let total: usize = if extent.contains(&0) {
            0
        } else {
            extent.iter().product()
        };
        let mut codes = Vec::with_capacity(total.min(b.len()));
        for _ in 0..total {
            let q = get_zigzag(b, &mut pos)?;
            if q.abs() as f64 > dct::MAX_CODE {
                return Err(Error::input(format!("{WHAT}: core code {q} exceeds 2^30")));
            }
            codes.push(q as i32);
        }
        out.push(Component {
            core: Coefficients { extent, codes },
            factors,
        });
    }
    if pos != b.len() {
        return Err(Error::input(format!(
            "{WHAT}: {} trailing bytes",
            b.len() - pos
        )));
    }
    Ok(out)
}

/// Largest raw stream a valid payload can have for this grid and stage (the zstd cap).
pub fn max_stream(dims: &[usize], stage: &TuckerStage) -> Option<usize> {
    let core: usize = stage
        .ranks
        .iter()
        .try_fold(1usize, |p, &r| p.checked_mul(r))?;
    let factor: usize = stage
        .ranks
        .iter()
        .zip(dims)
        .try_fold(0usize, |s, (&r, &n)| s.checked_add(r.checked_mul(n)?))?;
    let sum = core
        .checked_mul(5)?
        .checked_add(factor.checked_mul(10)?)?
        .checked_add(stage.ranks.iter().sum::<usize>().checked_mul(4)?)?
        .checked_add(10 * dims.len())?;
    sum.checked_mul(stage.step.len())?.checked_add(16)
}

/// Encodes the filled component planes into the raw stream.
pub fn encode(planes: &[Vec<f64>], dims: &[usize], stage: &TuckerStage) -> Result<Vec<u8>> {
    encode_each(planes.len(), |k| Cow::Borrowed(&planes[k]), dims, stage)
}

/// [`encode`] of the `components` planes `plane(k)` makes, each made, decomposed and freed
/// before the next (the components are decomposed independently): one f64 plane at a time
/// instead of all of them (100 MB for the 52 MiB table of docs/robustness.md).
pub fn encode_each<'p>(
    components: usize,
    plane: impl Fn(usize) -> Cow<'p, [f64]>,
    dims: &[usize],
    stage: &TuckerStage,
) -> Result<Vec<u8>> {
    let comps = (0..components)
        .zip(&stage.step)
        .map(|(k, &s)| quantize_plane(&plane(k), dims, &stage.ranks, s, stage.factor_step))
        .collect::<Result<Vec<_>>>()?;
    Ok(serialize(&comps))
}

/// Register tile of the contiguous kernel (outputs per tile).
const TILE_N: usize = 16;
/// Lines per tile of the strided kernel.
const WIDE: usize = 32;

/// One axis of the expansion: `rows[k·np + t]` = U[t][k] (the factor transposed, each row
/// zero-padded to `np`, a multiple of [`TILE_N`]), in f32.
struct Basis {
    n: usize,
    e: usize,
    np: usize,
    rows: Vec<f32>,
    /// `pairs[p·e + k]` = (U[2p][k], U[2p + 1][k]) (0 past n): the strided kernel's weights
    /// of two outputs, contiguous in k (in `rows` they are `np` floats apart for every k).
    pairs: Vec<[f32; 2]>,
}

impl Basis {
    fn new(f: &Factor, n: usize) -> Basis {
        let e = f.steps.len();
        let np = n.div_ceil(TILE_N) * TILE_N;
        let mut rows = vec![0f32; e * np];
        for k in 0..e {
            for t in 0..n {
                rows[k * np + t] = dequant(f.codes[k * n + t], f.steps[k]) as f32;
            }
        }
        let pairs = super::idct::pair_major(&rows, np, e, n.div_ceil(2));
        Basis {
            n,
            e,
            np,
            rows,
            pairs,
        }
    }
}

/// Axis order with the fewest multiply-adds (each pass costs the current size × N_a); ties
/// to the first in lexicographic order.
fn axis_order(extent: &[usize], dims: &[usize]) -> Vec<usize> {
    let d = dims.len();
    let mut perm: Vec<usize> = (0..d).collect();
    let mut best: Option<(f64, Vec<usize>)> = None;
    loop {
        let mut cur: Vec<f64> = extent.iter().map(|&e| e as f64).collect();
        let mut cost = 0.0;
        for &a in &perm {
            cost += cur.iter().product::<f64>() * dims[a] as f64;
            cur[a] = dims[a] as f64;
        }
        if best.as_ref().is_none_or(|(c, _)| cost < *c) {
            best = Some((cost, perm.clone()));
        }
        if !super::idct::next_permutation(&mut perm) {
            break;
        }
    }
    best.map(|b| b.1).unwrap_or_default()
}

/// One component plane (every cell) in f32.
pub fn inverse(c: &Component, dims: &[usize], step: f64) -> Vec<f32> {
    let cells: usize = dims.iter().product();
    if c.is_empty() {
        return vec![0.0; cells];
    }
    let scratch = &mut DecodeScratch::default();
    let mut cur = scratch.take_f32(c.core.codes.len());
    for (d, &q) in cur.iter_mut().zip(&c.core.codes) {
        *d = (q as f64 * step) as f32;
    }
    let order = axis_order(&c.core.extent, dims);
    let expand = |a: usize, src: &[f32], dst: &mut [f32], outer: usize, inner: usize| {
        let b = Basis::new(&c.factors[a], dims[a]);
        if inner == 1 {
            expand_contiguous(src, dst, outer, &b);
        } else {
            expand_strided(src, dst, outer, inner, &b);
        }
    };
    let mut plane = expand_axes(cur, c.core.extent.clone(), dims, &order, scratch, expand).0;
    plane.truncate(cells);
    plane
}

/// Decodes every component and finishes each cell into `out` (cells × components values).
pub(crate) fn decode(
    comps: &[Component],
    steps: &[f64],
    dims: &[usize],
    fin: &Finisher,
    valid: &[bool],
    out: &mut [f32],
) {
    let planes: Vec<Vec<f32>> = comps
        .iter()
        .zip(steps)
        .map(|(q, &s)| inverse(q, dims, s))
        .collect();
    let views: Vec<&[f32]> = planes.iter().map(|p| p.as_slice()).collect();
    finish(fin, &views, valid, out);
}

dispatch!(fn expand_contiguous / expand_contiguous_avx2 => contiguous_impl(src: &[f32], dst: &mut [f32], outer: usize, b: &Basis));
dispatch!(fn expand_strided / expand_strided_avx2 => strided_impl(src: &[f32], dst: &mut [f32], outer: usize, inner: usize, b: &Basis));

/// The expanded axis is the fastest one: out[o][t] = Σ_k U[t][k] in[o][k], vectorized across
/// t in register tiles; zero inputs are skipped (adding +0·finite to a sum that starts at +0
/// never changes it).
#[inline(always)]
fn contiguous_impl(src: &[f32], dst: &mut [f32], outer: usize, b: &Basis) {
    let (e, n, np) = (b.e, b.n, b.np);
    let mut nz: Vec<(usize, f32)> = Vec::with_capacity(e);
    for o in 0..outer {
        let s = &src[o * e..(o + 1) * e];
        let d = &mut dst[o * n..(o + 1) * n];
        nz.clear();
        nz.extend(s.iter().copied().enumerate().filter(|(_, w)| *w != 0.0));
        for t0 in (0..np).step_by(TILE_N) {
            let mut acc = [0f32; TILE_N];
            for &(k, w) in &nz {
                let row: &[f32; TILE_N] = b.rows[k * np + t0..k * np + t0 + TILE_N]
                    .try_into()
                    .expect("tile inside the padded row");
                for l in 0..TILE_N {
                    acc[l] += w * row[l];
                }
            }
            let m = TILE_N.min(n - t0);
            d[t0..t0 + m].copy_from_slice(&acc[..m]);
        }
    }
}

/// The expanded axis has `inner` > 1 values per index: out[o][t][x] = Σ_k U[t][k] in[o][k][x],
/// vectorized across x in tiles; all-zero input rows are skipped.
#[inline(always)]
fn strided_impl(src: &[f32], dst: &mut [f32], outer: usize, inner: usize, b: &Basis) {
    let (e, n) = (b.e, b.n);
    let mut rows = Vec::with_capacity(e);
    for o in 0..outer {
        let s = &src[o * e * inner..(o + 1) * e * inner];
        let d = &mut dst[o * n * inner..(o + 1) * n * inner];
        rows.clear();
        rows.extend((0..e).filter(|&k| s[k * inner..(k + 1) * inner].iter().any(|v| *v != 0.0)));
        let mut x0 = 0;
        while x0 + WIDE <= inner {
            strided_tile::<WIDE>(s, d, inner, x0, b, &rows);
            x0 += WIDE;
        }
        while x0 + 8 <= inner {
            strided_tile::<8>(s, d, inner, x0, b, &rows);
            x0 += 8;
        }
        while x0 < inner {
            strided_tile::<1>(s, d, inner, x0, b, &rows);
            x0 += 1;
        }
    }
}

/// Lines x0..x0+T of one outer block, two outputs at a time (each loaded input tile feeds
/// two accumulators; every output keeps its summation order, so its bits).
#[inline(always)]
fn strided_tile<const T: usize>(
    s: &[f32],
    d: &mut [f32],
    inner: usize,
    x0: usize,
    b: &Basis,
    rows: &[usize],
) {
    let mut t = 0;
    while t < b.n {
        let two = t + 1 < b.n;
        let mut acc = [[0f32; T]; 2];
        let pair = &b.pairs[t / 2 * b.e..(t / 2 + 1) * b.e];
        accumulate_two::<T>(&mut acc, s, inner, x0, rows, |k| (pair[k][0], pair[k][1]));
        d[t * inner + x0..t * inner + x0 + T].copy_from_slice(&acc[0]);
        if two {
            d[(t + 1) * inner + x0..(t + 1) * inner + x0 + T].copy_from_slice(&acc[1]);
        }
        t += 2;
    }
}

/// The f64 reference of [`inverse`]: the dequantized core times every dequantized factor in
/// axis order, dense, f64 throughout.
pub fn inverse_f64(c: &Component, dims: &[usize], step: f64) -> Vec<f64> {
    let cells: usize = dims.iter().product();
    if c.is_empty() {
        return vec![0.0; cells];
    }
    let mut cur: Vec<f64> = c.core.codes.iter().map(|&q| q as f64 * step).collect();
    let mut cur_dims = c.core.extent.clone();
    for (a, f) in c.factors.iter().enumerate() {
        let n = dims[a];
        let e = f.steps.len();
        // Row-major n × e: U[t][k].
        let mut mat = vec![0.0; n * e];
        for k in 0..e {
            for t in 0..n {
                mat[t * e + k] = dequant(f.codes[k * n + t], f.steps[k]);
            }
        }
        cur = dct::apply_axis(&cur, &cur_dims, a, &mat, n, false);
        cur_dims[a] = n;
    }
    cur
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    /// Σ_p w_p a_p ⊗ b_p ⊗ c_p with smooth random-ish vectors: Tucker rank ≤ (P, P, P).
    fn low_rank(dims: &[usize], p: usize, seed: u64) -> Vec<f64> {
        let mut rng = crate::math::SplitMix64::new(seed);
        let vecs: Vec<Vec<Vec<f64>>> = (0..p)
            .map(|_| {
                dims.iter()
                    .map(|&n| (0..n).map(|_| rng.next_f64() * 2.0 - 1.0).collect())
                    .collect()
            })
            .collect();
        let cells: usize = dims.iter().product();
        (0..cells)
            .map(|f| {
                let (i, j, k) = (f / (dims[1] * dims[2]), f / dims[2] % dims[1], f % dims[2]);
                vecs.iter()
                    .enumerate()
                    .map(|(q, v)| (1.0 + q as f64) * v[0][i] * v[1][j] * v[2][k])
                    .sum::<f64>()
                    + 3.0
            })
            .collect()
    }

    fn round_trip(x: &[f64], dims: &[usize], ranks: &[usize], step: f64) -> Vec<f32> {
        let c = quantize_plane(x, dims, ranks, step, 1.0).unwrap();
        let stage = TuckerStage {
            ranks: ranks.to_vec(),
            step: vec![step],
            factor_step: 1.0,
        };
        let back = deserialize(&serialize(std::slice::from_ref(&c)), dims, &stage).unwrap();
        assert_eq!(back[0], c);
        inverse(&back[0], dims, step)
    }

    fn max_err(a: &[f32], b: &[f64]) -> f64 {
        a.iter()
            .zip(b)
            .map(|(p, q)| (*p as f64 - q).abs())
            .fold(0.0, f64::max)
    }

    #[test]
    fn an_exact_low_rank_table_comes_back_to_f32_precision() {
        let dims = [9usize, 10, 12];
        let x = low_rank(&dims, 3, 5);
        let scale = x.iter().fold(0.0f64, |m, v| m.max(v.abs()));
        // Rank (4, 4, 4) holds the 3 terms and the constant exactly; full rank trivially.
        for ranks in [[4usize, 4, 4], [9, 10, 12]] {
            let y = round_trip(&x, &dims, &ranks, 1e-7);
            let e = max_err(&y, &x);
            // f32 storage and sums: a few 2⁻²⁴ relative to the largest value.
            assert!(e <= 1e-6 * scale, "{ranks:?}: {e} vs scale {scale}");
        }
    }

    #[test]
    fn truncation_error_falls_with_the_rank() {
        let dims = [12usize, 12, 16];
        let x: Vec<f64> = (0..12 * 12 * 16)
            .map(|f| {
                let (i, j, k) = (f / 192, f / 16 % 12, f % 16);
                (-(((i as f64 - j as f64) / 3.0).powi(2)) - (k as f64 / 7.0 - 1.0).powi(2)).exp()
            })
            .collect();
        let mut last = f64::INFINITY;
        for r in [1usize, 2, 4, 8, 12] {
            let ranks = [r, r, r.min(16)];
            let y = round_trip(&x, &dims, &ranks, 1e-7);
            let rms = (y
                .iter()
                .zip(&x)
                .map(|(p, q)| (*p as f64 - q).powi(2))
                .sum::<f64>()
                / x.len() as f64)
                .sqrt();
            assert!(rms < last, "rank {r}: rms {rms} not below {last}");
            last = rms;
        }
        assert!(last < 1e-6, "full rank rms {last}");
    }

    #[test]
    fn the_same_bytes_for_any_thread_count() {
        let dims = [20usize, 18, 30];
        let x = low_rank(&dims, 6, 9);
        let stage = TuckerStage {
            ranks: vec![5, 5, 8],
            step: vec![1e-3],
            factor_step: 1.0,
        };
        let run = |threads: usize| {
            rayon::ThreadPoolBuilder::new()
                .num_threads(threads)
                .build()
                .unwrap()
                .install(|| encode(std::slice::from_ref(&x), &dims, &stage).unwrap())
        };
        let one = run(1);
        assert_eq!(one, run(2));
        assert_eq!(one, run(2));
    }

    #[test]
    fn hostile_streams_are_refused() {
        let dims = [6usize, 5, 7];
        let x = low_rank(&dims, 2, 1);
        let stage = TuckerStage {
            ranks: vec![3, 3, 3],
            step: vec![1e-3],
            factor_step: 1.0,
        };
        let good = encode(std::slice::from_ref(&x), &dims, &stage).unwrap();
        assert!(deserialize(&good, &dims, &stage).is_ok());
        for cut in [0, 1, 3, good.len() / 2, good.len() - 1] {
            assert!(
                deserialize(&good[..cut], &dims, &stage).is_err(),
                "cut {cut}"
            );
        }
        let mut long = good.clone();
        long.push(0);
        assert!(deserialize(&long, &dims, &stage).is_err());
        // Extent 4 > rank 3.
        let mut bad = good.clone();
        bad[0] = 4;
        assert!(deserialize(&bad, &dims, &stage).is_err());
        // A NaN factor step.
        let mut bad = good.clone();
        bad[3..7].copy_from_slice(&f32::NAN.to_le_bytes());
        assert!(deserialize(&bad, &dims, &stage).is_err());
        // Extent 0 along one axis only.
        assert!(deserialize(&[0, 1, 1], &dims, &stage).is_err());
        // A 64-bit varint factor code.
        let mut huge = vec![1, 1, 1];
        huge.extend_from_slice(&1f32.to_le_bytes());
        huge.extend_from_slice(&1f32.to_le_bytes());
        huge.extend_from_slice(&1f32.to_le_bytes());
        huge.extend_from_slice(&[0xff, 0xff, 0xff, 0x7f]);
        let e = deserialize(&huge, &dims, &stage).unwrap_err().to_string();
        assert!(e.contains("2^24"), "{e}");
        for bad in [
            TuckerStage {
                ranks: vec![3, 3],
                ..stage.clone()
            },
            TuckerStage {
                ranks: vec![0, 3, 3],
                ..stage.clone()
            },
            TuckerStage {
                ranks: vec![7, 3, 3],
                ..stage.clone()
            },
            TuckerStage {
                step: vec![f64::NAN],
                ..stage.clone()
            },
            TuckerStage {
                factor_step: 0.0,
                ..stage.clone()
            },
        ] {
            assert!(bad.validate(&dims, 1).is_err(), "{bad:?}");
        }
    }

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(32))]
        /// Random planes, ranks and steps: the stream round-trips, and the f32 decoder matches
        /// the f64 reference within f32 rounding of its sums (≤ (Σ e_a) × 2⁻²⁴ × the largest
        /// partial sum; 2e-5 of the largest |value| leaves room for 3 axes of ≤ 12 terms).
        #[test]
        fn round_trips_and_matches_the_f64_reference(
            d0 in 1usize..9, d1 in 1usize..9, d2 in 1usize..13, seed in any::<u64>(),
            r0 in 1usize..9, r1 in 1usize..9, r2 in 1usize..13, step in 1e-4f64..0.5,
            kappa in 0.1f64..10.0,
        ) {
            let dims = [d0, d1, d2];
            let ranks = [r0.min(d0), r1.min(d1), r2.min(d2)];
            let mut rng = crate::math::SplitMix64::new(seed);
            let x: Vec<f64> = (0..d0 * d1 * d2).map(|_| rng.next_f64() * 4.0 - 2.0).collect();
            let stage = TuckerStage { ranks: ranks.to_vec(), step: vec![step], factor_step: kappa };
            let c = quantize_plane(&x, &dims, &ranks, step, kappa).unwrap();
            let back = deserialize(&serialize(std::slice::from_ref(&c)), &dims, &stage).unwrap();
            prop_assert_eq!(&back[0], &c);
            let fast = inverse(&c, &dims, step);
            let slow = inverse_f64(&c, &dims, step);
            let scale = slow.iter().fold(1e-30f64, |m, v| m.max(v.abs()));
            let gap = max_err(&fast, &slow);
            prop_assert!(gap <= 2e-5 * scale, "gap {} scale {}", gap, scale);
            // At full rank the only error is quantization: core and factors each add about
            // step/√12 per entry in the mean-square sense; allow 4 × step RMS.
            if ranks == dims {
                let rms = (slow.iter().zip(&x).map(|(p, q)| (p - q).powi(2)).sum::<f64>()
                    / x.len() as f64).sqrt();
                prop_assert!(rms <= 4.0 * step * (1.0 + kappa), "rms {} step {}", rms, step);
            }
        }
    }
}
