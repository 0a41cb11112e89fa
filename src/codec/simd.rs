//! Decoder kernels shared by the chains: a vectorizable f32 `exp`, the last step of the lossy
//! decoders (inverse colour matrix, inverse curve, 1/w of a weighted transform, channel
//! interleave, invalid cells to 0), and
//! the run-time choice between the portable and the AVX2 copy of a loop.
//!
//! Every kernel is plain Rust compiled twice: once for the baseline target and once with
//! `#[target_feature(enable = "avx2")]` (FMA deliberately not enabled, and Rust never fuses a
//! multiply and an add on its own), so both copies perform the same IEEE operations in the same
//! order and give the same bits: a file decodes identically on every x86-64 CPU.

#![allow(clippy::needless_range_loop)] // Lane loops index several parallel arrays.

use super::Layout;
use super::transform::{Curve, Transform, signed_log_inverse_f32};
use crate::table::CellSet;

// The CPU-feature detector and the portable/AVX2 dispatch are the crate's one pair
// (`crate::simd`).
pub(crate) use crate::simd::{avx2, dispatch};

/// Inputs of [`exp_f32`] are clamped to this range: e^88 ≈ 1.65e38 stays below f32::MAX and
/// e^−87 ≈ 1.6e−38 above the smallest normal, so the exponent bits built below are valid.
pub const EXP_MIN: f32 = -87.0;
pub const EXP_MAX: f32 = 88.0;

/// 1.5·2^23: adding it rounds to an integer (to nearest even) held in the low mantissa bits.
const EXP_MAGIC: f32 = 12_582_912.0;
/// ln2 split so that n·LN2_HI is exact for |n| ≤ 128 (LN2_HI has 9 significant bits).
const EXP_LN2_HI: f32 = 0.693_359_4;
const EXP_LN2_LO: f32 = -2.121_944_4e-4;
/// Below EXP_MIN: e^x = e^(x + EXP_SMALL_SHIFT) · EXP_SMALL_SCALE (32 ln2 and 2^−32).
const EXP_SMALL_SHIFT: f32 = 32.0 * std::f32::consts::LN_2;
const EXP_SMALL_SCALE: f32 = 2.328_306_4e-10;
/// The Cephes `expf` polynomial, highest degree first (Cephes 5.0000001201e-1 rounds to 0.5
/// in f32).
const EXP_POLY: [f32; 6] = [
    1.987_569_1e-4,
    1.398_199_9e-3,
    8.333_452e-3,
    4.166_579_6e-2,
    1.666_666_5e-1,
    0.5,
];

/// e^x in f32, within 1 ulp of the exact value on [EXP_MIN, EXP_MAX] (tested), subnormal
/// below it and 0 below about −109 (NaN reads as EXP_MIN); x above EXP_MAX is clamped. Cody–Waite reduction x = n ln2 + r, |r| ≤ ln2/2, and
/// the degree-6 minimax polynomial of Cephes `expf` (Moshier 1992), without FMA.
#[inline(always)]
pub fn exp_f32(x: f32) -> f32 {
    // Below EXP_MIN the result is an f32 subnormal (down to e^−103.3): e^x = e^(x + 32 ln2)·2^−32,
    // one rounding. Flushing to e^−87 instead decoded a 1e−41 sample of a dark log-curve table
    // 1e3× too large (tests/hard_cases.rs).
    let small = x < EXP_MIN;
    let x = if small { x + EXP_SMALL_SHIFT } else { x };
    let scale = if small { EXP_SMALL_SCALE } else { 1.0 };
    // Written as the selects that `vmaxps`/`vminps` perform (the second operand when the
    // comparison fails, so NaN reads as EXP_MIN), so the AVX2 finisher gives the same bits.
    let x = if x > EXP_MIN { x } else { EXP_MIN };
    let x = if x < EXP_MAX { x } else { EXP_MAX };
    let t = x * std::f32::consts::LOG2_E + EXP_MAGIC;
    let n = t - EXP_MAGIC;
    let r = x - n * EXP_LN2_HI;
    let r = r - n * EXP_LN2_LO;
    let mut p = EXP_POLY[0];
    for &k in &EXP_POLY[1..] {
        p = p * r + k;
    }
    let y = p * (r * r) + r + 1.0;
    // 2^n from the integer in t's mantissa: n ∈ [−126, 127] here, a normal exponent.
    let e = (t.to_bits() as i32 - EXP_MAGIC.to_bits() as i32 + 127) << 23;
    y * f32::from_bits(e as u32) * scale
}

/// The broadcast constants of [`Finisher::blocks_avx2`].
#[cfg(target_arch = "x86_64")]
struct BlockConsts<const C: usize> {
    m: [[std::arch::x86_64::__m256; C]; C],
    eps: [std::arch::x86_64::__m256; C],
    idx: [std::arch::x86_64::__m256i; 3],
}

/// [`exp_f32`] of G × C vectors of 8 lanes: the same operations in the same order per lane,
/// each step applied to every vector before the next (see [`Finisher::finish_group`]).
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
#[inline]
fn exp_avx2_n<const C: usize, const G: usize>(
    x: [[std::arch::x86_64::__m256; C]; G],
) -> [[std::arch::x86_64::__m256; C]; G] {
    use std::arch::x86_64::*;
    let c = _mm256_set1_ps;
    // Loops, not closures: a closure would not inherit the AVX2 target feature.
    let mut small = x;
    let mut xs = x;
    let mut scale = [[c(1.0); C]; G];
    let mut t = x;
    let mut r = x;
    let mut p = [[c(EXP_POLY[0]); C]; G];
    let mut out = x;
    for g in 0..G {
        for k in 0..C {
            small[g][k] = _mm256_cmp_ps::<_CMP_LT_OQ>(x[g][k], c(EXP_MIN));
            xs[g][k] = _mm256_blendv_ps(
                x[g][k],
                _mm256_add_ps(x[g][k], c(EXP_SMALL_SHIFT)),
                small[g][k],
            );
            scale[g][k] = _mm256_blendv_ps(c(1.0), c(EXP_SMALL_SCALE), small[g][k]);
            xs[g][k] = _mm256_min_ps(_mm256_max_ps(xs[g][k], c(EXP_MIN)), c(EXP_MAX));
        }
    }
    for g in 0..G {
        for k in 0..C {
            t[g][k] = _mm256_add_ps(
                _mm256_mul_ps(xs[g][k], c(std::f32::consts::LOG2_E)),
                c(EXP_MAGIC),
            );
        }
    }
    for g in 0..G {
        for k in 0..C {
            let n = _mm256_sub_ps(t[g][k], c(EXP_MAGIC));
            r[g][k] = _mm256_sub_ps(xs[g][k], _mm256_mul_ps(n, c(EXP_LN2_HI)));
            r[g][k] = _mm256_sub_ps(r[g][k], _mm256_mul_ps(n, c(EXP_LN2_LO)));
        }
    }
    for &q in &EXP_POLY[1..] {
        for g in 0..G {
            for k in 0..C {
                p[g][k] = _mm256_add_ps(_mm256_mul_ps(p[g][k], r[g][k]), c(q));
            }
        }
    }
    for g in 0..G {
        for k in 0..C {
            let y = _mm256_add_ps(
                _mm256_add_ps(
                    _mm256_mul_ps(p[g][k], _mm256_mul_ps(r[g][k], r[g][k])),
                    r[g][k],
                ),
                c(1.0),
            );
            let e = _mm256_slli_epi32::<23>(_mm256_add_epi32(
                _mm256_sub_epi32(
                    _mm256_castps_si256(t[g][k]),
                    _mm256_set1_epi32(EXP_MAGIC.to_bits() as i32),
                ),
                _mm256_set1_epi32(127),
            ));
            out[g][k] = _mm256_mul_ps(_mm256_mul_ps(y, _mm256_castsi256_ps(e)), scale[g][k]);
        }
    }
    out
}

/// Cells per block of [`Finisher::run`]: one AVX2 register of f32.
const LANES: usize = 8;

/// The last decoder step: per cell, y = Mᵀ z (when there is a colour matrix), the inverse
/// curve, × 1/w (weighted transforms), written channel-interleaved (cell-major); invalid cells
/// get 0.
pub(crate) struct Finisher {
    c: usize,
    /// Mᵀ applied as y_k = Σ_i m[i·c + k] z_i (the identity without colour).
    m: Vec<f32>,
    eps: Option<Vec<f32>>,
    /// The signed log curve (`Curve::SignedLog`): values keep their sign.
    signed: bool,
    colour: bool,
    /// 1/w of every cell of the layout, computed once per decode (weighted transforms only).
    rw: Option<Vec<f32>>,
    /// Whole blocks of 1 or 3 unweighted components go through [`Finisher::blocks_avx2`]
    /// (set only when the CPU has AVX2; same bits as the portable block, tested).
    avx2: bool,
}

impl Finisher {
    pub(crate) fn new(t: &Transform, layout: &Layout) -> Finisher {
        let c = layout.channels;
        let m = match &t.colour {
            Some(col) => col.matrix.iter().map(|&x| x as f32).collect(),
            None => (0..c * c)
                .map(|i| if i / c == i % c { 1.0 } else { 0.0 })
                .collect(),
        };
        let eps = t
            .curve
            .eps()
            .map(|eps| eps.iter().map(|&e| e as f32).collect());
        let signed = t.curve.is_signed();
        Finisher {
            c,
            m,
            eps,
            signed,
            colour: t.colour.is_some(),
            rw: t.reciprocal_weights(layout.grid, layout.valid),
            // The hand-written blocks know the unsigned curves; signed tables (rare: noisy
            // measured fits) take the portable blocks.
            avx2: avx2() && !signed,
        }
    }

    /// A finisher of `c` (1 or 3) components with a colour matrix and the log curve, for
    /// tests.
    #[cfg(test)]
    pub(crate) fn example(c: usize) -> Finisher {
        let (m, eps) = if c == 3 {
            (
                vec![0.5, 0.3, 0.2, 0.1, -0.4, 0.3, 0.2, 0.1, -0.5],
                vec![1e-3, 2e-3, 4e-3],
            )
        } else {
            (vec![1.0], vec![1e-3])
        };
        Finisher {
            c,
            m,
            eps: Some(eps),
            signed: false,
            colour: true,
            rw: None,
            avx2: avx2(),
        }
    }

    /// A copy, without the hand-vectorized blocks when `portable`.
    #[cfg(test)]
    fn clone_portable(&self, portable: bool) -> Finisher {
        Finisher {
            c: self.c,
            m: self.m.clone(),
            eps: self.eps.clone(),
            signed: self.signed,
            colour: self.colour,
            rw: self.rw.clone(),
            avx2: self.avx2 && !portable,
        }
    }

    /// The same finisher without the hand-vectorized blocks (tests compare the two).
    #[cfg(test)]
    pub(crate) fn portable(mut self) -> Finisher {
        self.avx2 = false;
        self
    }

    /// Cells `first..first + valid.len()` of the layout, held by the component runs `planes`,
    /// into `out` (C values per cell). Inlined into the caller's AVX2 or portable copy. Whole
    /// blocks of [`LANES`] cells take a fixed-size path (no variable-length copies, the
    /// validity applied as a bit mask, the interleave through a fixed-size staging array), the
    /// tail the general one; both perform the same arithmetic per cell, so the same bits.
    /// The colour matrix as `mm[i][k]` (y_k = Σ_i mm[i][k] z_i) and the curve's ε per
    /// component (0 for the linear curve), in fixed-size arrays.
    #[inline(always)]
    fn constants<const C: usize>(&self) -> ([[f32; C]; C], [f32; C]) {
        let mut mm = [[0f32; C]; C];
        for i in 0..C {
            for k in 0..C {
                mm[i][k] = self.m[i * C + k];
            }
        }
        let ee: [f32; C] = std::array::from_fn(|k| self.eps.as_ref().map_or(0.0, |e| e[k]));
        (mm, ee)
    }

    /// `rows` runs of `cells` cells, run j being cells first + j·stride.. of the layout, held
    /// by `planes` (run j at values j·cells..): as [`Finisher::run`] on each run, through one
    /// call of the AVX2 blocks when the runs are whole blocks (their setup once, not per run).
    #[allow(clippy::too_many_arguments)] // The rows' geometry.
    #[inline(always)]
    pub(crate) fn run_rows<const C: usize>(
        &self,
        planes: [&[f32]; C],
        rows: usize,
        cells: usize,
        first: usize,
        stride: usize,
        valid: &[bool],
        out: &mut [f32],
    ) {
        if rows == 0 {
            return;
        }
        #[cfg(target_arch = "x86_64")]
        if self.avx2
            && self.rw.is_none()
            && (C == 1 || C == 3)
            && cells > 0
            && cells.is_multiple_of(LANES)
        {
            let (mm, ee) = self.constants::<C>();
            // SAFETY: `avx2` is set only when the CPU reports AVX2.
            unsafe {
                self.blocks_avx2::<C>(
                    &mm,
                    &ee,
                    planes,
                    rows,
                    cells,
                    stride,
                    &valid[first..],
                    &mut out[first * C..],
                )
            };
            return;
        }
        for j in 0..rows {
            let f = first + j * stride;
            let p: [&[f32]; C] = std::array::from_fn(|k| &planes[k][j * cells..(j + 1) * cells]);
            self.run::<C>(p, f, &valid[f..f + cells], &mut out[f * C..(f + cells) * C]);
        }
    }

    #[inline(always)]
    /// [`Finisher::run`] of the cells of a set only, in place: `out[i·C + k]` holds component
    /// k of the set's cell at place i ([`CellSet`]; flat indices into the layout, whose
    /// validity is `valid`) and becomes its finished channel k. Each cell is finished on its
    /// own, so the same bits as the whole decode.
    pub(crate) fn run_cells<const C: usize>(
        &self,
        cells: &CellSet,
        valid: &[bool],
        out: &mut [f32],
    ) {
        debug_assert_eq!(self.c, C);
        debug_assert_eq!(out.len(), cells.len() * C);
        let (mm, ee) = self.constants::<C>();
        let mut flats = cells.iter();
        for out in out.chunks_mut(LANES * C) {
            let n = out.len() / C;
            let mut block = [0u32; LANES];
            for (b, f) in block[..n].iter_mut().zip(&mut flats) {
                *b = f;
            }
            let mut z = [[0f32; LANES]; C];
            for l in 0..n {
                for k in 0..C {
                    z[k][l] = out[l * C + k];
                }
            }
            let mut y = self.block::<C>(&mm, &ee, z);
            if let Some(r) = self.rw.as_deref() {
                for k in 0..C {
                    for (l, &f) in block[..n].iter().enumerate() {
                        y[k][l] = scale_finite(y[k][l], r[f as usize]);
                    }
                }
            }
            for (l, &f) in block[..n].iter().enumerate() {
                let ok = valid[f as usize];
                for k in 0..C {
                    out[l * C + k] = if ok { y[k][l] } else { 0.0 };
                }
            }
        }
    }

    pub(crate) fn run<const C: usize>(
        &self,
        planes: [&[f32]; C],
        first: usize,
        valid: &[bool],
        out: &mut [f32],
    ) {
        debug_assert_eq!(self.c, C);
        let cells = valid.len();
        let rw = self.rw.as_deref().map(|r| &r[first..first + cells]);
        let (mm, ee) = self.constants::<C>();
        let full = cells - cells % LANES;
        let mut f0 = 0;
        #[cfg(target_arch = "x86_64")]
        if self.avx2 && rw.is_none() && (C == 1 || C == 3) && full > 0 {
            // SAFETY: `avx2` is set only when the CPU reports AVX2.
            unsafe { self.blocks_avx2::<C>(&mm, &ee, planes, 1, full, 0, &valid[..full], out) };
            f0 = full;
            if full < cells {
                // The tail as one block overlapping the last whole one (a MERL line of 180
                // cells ends in 4): the overlapped cells are written again with the same
                // bits, since every cell is finished on its own.
                let t0 = cells - LANES;
                let tail: [&[f32]; C] = std::array::from_fn(|k| &planes[k][t0..]);
                // SAFETY: as above.
                unsafe {
                    self.blocks_avx2::<C>(
                        &mm,
                        &ee,
                        tail,
                        1,
                        LANES,
                        0,
                        &valid[t0..],
                        &mut out[t0 * C..],
                    )
                };
                return;
            }
        }
        while f0 < full {
            let ok: &[bool; LANES] = valid[f0..f0 + LANES]
                .try_into()
                .expect("a whole block inside the validity");
            if !ok.iter().any(|&v| v) {
                // Below the horizon (a quarter of a MERL grid): 0 without the exp.
                out[f0 * C..(f0 + LANES) * C].fill(0.0);
                f0 += LANES;
                continue;
            }
            let z: [[f32; LANES]; C] = std::array::from_fn(|k| {
                planes[k][f0..f0 + LANES]
                    .try_into()
                    .expect("a whole block inside the plane")
            });
            let mut y = self.block::<C>(&mm, &ee, z);
            // One branch per block, taken the same way for the whole decode: the unweighted
            // path does no more work than before.
            if let Some(r) = rw {
                let s: &[f32; LANES] = r[f0..f0 + LANES]
                    .try_into()
                    .expect("a whole block inside the weights");
                for k in 0..C {
                    for l in 0..LANES {
                        y[k][l] = scale_finite(y[k][l], s[l]);
                    }
                }
            }
            let mask: [u32; LANES] = std::array::from_fn(|l| (ok[l] as u32).wrapping_neg());
            let mut staged = [[0f32; C]; LANES];
            for l in 0..LANES {
                for k in 0..C {
                    staged[l][k] = f32::from_bits(y[k][l].to_bits() & mask[l]);
                }
            }
            let dst = &mut out[f0 * C..(f0 + LANES) * C];
            for (d, s) in dst.chunks_exact_mut(C).zip(&staged) {
                d.copy_from_slice(s);
            }
            f0 += LANES;
        }
        if f0 < cells {
            let n = cells - f0;
            let mut z = [[0f32; LANES]; C];
            for k in 0..C {
                z[k][..n].copy_from_slice(&planes[k][f0..cells]);
            }
            let mut y = self.block::<C>(&mm, &ee, z);
            if let Some(r) = rw {
                let mut s = [0f32; LANES];
                s[..n].copy_from_slice(&r[f0..f0 + n]);
                for k in 0..C {
                    for l in 0..LANES {
                        y[k][l] = scale_finite(y[k][l], s[l]);
                    }
                }
            }
            for l in 0..n {
                let ok = valid[f0 + l];
                for k in 0..C {
                    out[(f0 + l) * C + k] = if ok { y[k][l] } else { 0.0 };
                }
            }
        }
    }

    /// The whole blocks of [`Finisher::run`] for 1 or 3 unweighted components, written with
    /// AVX2 intrinsics: the autovectorized block spilled its lanes to the stack to interleave
    /// the channels (a third of the decode of a MERL table). Every lane performs the portable
    /// block's IEEE operations in the same order (`exp_avx2_n` mirrors [`exp_f32`]; `vmaxps`
    /// and `vminps` are the selects written there), so the bits are the same.
    ///
    /// `rows` runs of `cells` cells: run j at cell j·`stride` of `valid` and `out`, and at
    /// value j·`cells` of each plane.
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2")]
    #[inline]
    #[allow(clippy::too_many_arguments)] // The rows' geometry.
    unsafe fn blocks_avx2<const C: usize>(
        &self,
        mm: &[[f32; C]; C],
        ee: &[f32; C],
        planes: [&[f32]; C],
        rows: usize,
        cells: usize,
        stride: usize,
        valid: &[bool],
        out: &mut [f32],
    ) {
        use std::arch::x86_64::*;
        let span = (rows.max(1) - 1) * stride + cells;
        assert!(cells.is_multiple_of(LANES) && (C == 1 || C == 3));
        assert!(planes.iter().all(|p| p.len() >= rows * cells));
        assert!(valid.len() >= span && out.len() >= span * C);
        // No closures in here: they would not inherit the AVX2 target feature, and the
        // intrinsics inside them would become calls.
        let zero = _mm256_setzero_ps();
        let mut k = BlockConsts {
            m: [[zero; C]; C],
            eps: [zero; C],
            idx: [
                _mm256_setr_epi32(0, 0, 0, 1, 1, 1, 2, 2),
                _mm256_setr_epi32(2, 3, 3, 3, 4, 4, 4, 5),
                _mm256_setr_epi32(5, 5, 6, 6, 6, 7, 7, 7),
            ],
        };
        for c in 0..C {
            k.eps[c] = _mm256_set1_ps(ee[c]);
            for i in 0..C {
                k.m[i][c] = _mm256_set1_ps(mm[i][c]);
            }
        }
        for row in 0..rows {
            let (p0, c0) = (row * cells, row * stride);
            let next = c0 + cells;
            if rows > 1 && next + cells <= valid.len() && (next + cells) * C <= out.len() {
                // The same cells of the caller's next tile: the rows of a tile are a grid line
                // apart, more streams than the hardware prefetchers follow, so each run's
                // validity and output missed.
                // SAFETY: next + cells ≤ valid.len() and (next + cells)·C ≤ out.len() (checked
                // above), so the addresses are inside the slices; prefetches never fault.
                unsafe {
                    _mm_prefetch::<_MM_HINT_T0>(valid.as_ptr().add(next) as *const i8);
                    let o = out.as_ptr().add(next * C) as *const i8;
                    let mut b = 0;
                    while b < cells * C * 4 {
                        _mm_prefetch::<_MM_HINT_T0>(o.add(b));
                        b += 64;
                    }
                }
            }
            let mut f0 = 0;
            while f0 < cells {
                // SAFETY (every pointer access below): c0 + f0 + g·LANES ≤ span and p0 + f0 +
                // g·LANES ≤ rows·cells for the g blocks read, and the planes, the validity and
                // `out` (C values per cell) hold that many (asserted).
                let g = if f0 + 2 * LANES <= cells { 2 } else { 1 };
                let mut ok = [0u64; 2];
                for (i, o) in ok.iter_mut().enumerate().take(g) {
                    *o = unsafe {
                        (valid.as_ptr().add(c0 + f0 + i * LANES) as *const u64).read_unaligned()
                    };
                }
                let dst = unsafe { out.as_mut_ptr().add((c0 + f0) * C) };
                if ok[0] == 0 && ok[1] == 0 {
                    // Below the horizon (a quarter of a MERL grid): 0 without the exp.
                    for j in 0..C * g {
                        unsafe { _mm256_storeu_ps(dst.add(j * LANES), zero) };
                    }
                    f0 += g * LANES;
                    continue;
                }
                let src: [*const f32; C] =
                    std::array::from_fn(|k| planes[k].as_ptr().wrapping_add(p0 + f0));
                if g == 2 {
                    unsafe { self.finish_group::<C, 2>(&k, src, ok, dst) };
                } else {
                    unsafe { self.finish_group::<C, 1>(&k, src, [ok[0]], dst) };
                }
                f0 += g * LANES;
            }
        }
    }

    /// G consecutive blocks of [`Finisher::blocks_avx2`] (`src[k]` their component k values,
    /// `ok` their validity bytes, `dst` their output), each step for every block and
    /// component before the next step: an exp is ~25 dependent operations, and one after the
    /// other they left the blocks latency-bound; side by side in the instruction stream the
    /// core overlaps them. The same operations per value as [`Finisher::block`], so the same
    /// bits.
    ///
    /// # Safety
    /// AVX2; `src[k]` readable for G·LANES values, `dst` writable for G·LANES·C.
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2")]
    #[inline]
    unsafe fn finish_group<const C: usize, const G: usize>(
        &self,
        k: &BlockConsts<C>,
        src: [*const f32; C],
        ok: [u64; G],
        dst: *mut f32,
    ) {
        use std::arch::x86_64::*;
        let zero = _mm256_setzero_ps();
        let mut z = [[zero; C]; G];
        for g in 0..G {
            for c in 0..C {
                // SAFETY: the caller's.
                z[g][c] = unsafe { _mm256_loadu_ps(src[c].add(g * LANES)) };
            }
        }
        let mut v = z;
        if self.colour {
            v = [[zero; C]; G];
            for i in 0..C {
                for g in 0..G {
                    for c in 0..C {
                        v[g][c] = _mm256_add_ps(v[g][c], _mm256_mul_ps(k.m[i][c], z[g][i]));
                    }
                }
            }
        }
        if self.eps.is_some() {
            v = exp_avx2_n(v);
            for g in 0..G {
                for c in 0..C {
                    v[g][c] = _mm256_max_ps(_mm256_sub_ps(v[g][c], k.eps[c]), zero);
                }
            }
        } else {
            let max = _mm256_set1_ps(f32::MAX);
            for g in 0..G {
                for c in 0..C {
                    v[g][c] = _mm256_min_ps(_mm256_max_ps(v[g][c], zero), max);
                }
            }
        }
        for g in 0..G {
            // `bool` is 0 or 1: a lane is valid when its byte is nonzero.
            let mask = _mm256_castsi256_ps(_mm256_cmpgt_epi32(
                _mm256_cvtepu8_epi32(_mm_cvtsi64_si128(ok[g] as i64)),
                _mm256_setzero_si256(),
            ));
            let mut y = [zero; C];
            for c in 0..C {
                y[c] = _mm256_and_ps(v[g][c], mask);
            }
            // SAFETY: the caller's.
            let d = unsafe { dst.add(g * LANES * C) };
            if C == 1 {
                unsafe { _mm256_storeu_ps(d, y[0]) };
            } else {
                // Channel interleave of 3 components: output vector j takes lane l from cell
                // (8j + l) / 3, channel (8j + l) % 3.
                let (r, gg, b) = (y[0], y[1 % C], y[2 % C]);
                for j in 0..3 {
                    let rp = _mm256_permutevar8x32_ps(r, k.idx[j]);
                    let gp = _mm256_permutevar8x32_ps(gg, k.idx[j]);
                    let bp = _mm256_permutevar8x32_ps(b, k.idx[j]);
                    let o = match j {
                        0 => _mm256_blend_ps::<0x24>(_mm256_blend_ps::<0x92>(rp, gp), bp),
                        1 => _mm256_blend_ps::<0x49>(_mm256_blend_ps::<0x24>(rp, gp), bp),
                        _ => _mm256_blend_ps::<0x92>(_mm256_blend_ps::<0x49>(rp, gp), bp),
                    };
                    unsafe { _mm256_storeu_ps(d.add(j * LANES), o) };
                }
            }
        }
    }

    /// One block: y = Mᵀ z, then the inverse curve, per component.
    #[inline(always)]
    fn block<const C: usize>(
        &self,
        mm: &[[f32; C]; C],
        ee: &[f32; C],
        z: [[f32; LANES]; C],
    ) -> [[f32; LANES]; C] {
        let mut y = [[0f32; LANES]; C];
        for k in 0..C {
            if self.colour {
                for l in 0..LANES {
                    let mut s = 0f32;
                    for i in 0..C {
                        s += mm[i][k] * z[i][l];
                    }
                    y[k][l] = s;
                }
            } else {
                y[k] = z[k];
            }
            if self.signed {
                for l in 0..LANES {
                    y[k][l] = signed_log_inverse_f32(y[k][l], ee[k]);
                }
            } else if self.eps.is_some() {
                for l in 0..LANES {
                    y[k][l] = non_negative(exp_f32(y[k][l]) - ee[k]);
                }
            } else {
                for l in 0..LANES {
                    y[k][l] = linear_inverse(y[k][l]);
                }
            }
        }
        y
    }

    /// Any channel count, one cell at a time (the fused fast paths cover 1 and 3 channels).
    #[inline(always)]
    fn run_any(&self, planes: &[&[f32]], valid: &[bool], out: &mut [f32]) {
        let c = self.c;
        for (f, &ok) in valid.iter().enumerate() {
            for k in 0..c {
                out[f * c + k] = if ok {
                    let y = if self.colour {
                        let mut s = 0f32;
                        for (i, pl) in planes.iter().enumerate() {
                            s += self.m[i * c + k] * pl[f];
                        }
                        s
                    } else {
                        planes[k][f]
                    };
                    let e = self.eps.as_ref().map(|e| e[k]);
                    let v = match e {
                        Some(e) if self.signed => signed_log_inverse_f32(y, e),
                        _ => curve_inverse(y, e),
                    };
                    match &self.rw {
                        Some(r) => scale_finite(v, r[f]),
                        None => v,
                    }
                } else {
                    0.0
                };
            }
        }
    }
}

/// Whole component planes (`planes[k]` holds component k of every cell) through the
/// [`Finisher`] into `out`.
pub(crate) fn finish(f: &Finisher, planes: &[&[f32]], valid: &[bool], out: &mut [f32]) {
    match planes.len() {
        1 => finish_1(f, planes, valid, out),
        3 => finish_3(f, planes, valid, out),
        _ => finish_n(f, planes, valid, out),
    }
}

/// [`finish`] of one component's cells `first..first + valid.len()` of the layout, which
/// `plane` and `out` hold alone: a decode that finishes its plane a chunk at a time.
pub(crate) fn finish_one_from(
    f: &Finisher,
    plane: &[f32],
    first: usize,
    valid: &[bool],
    out: &mut [f32],
) {
    finish_from_1(f, plane, first, valid, out)
}

dispatch!(fn finish_from_1 / finish_from_1_avx2 => finish_from_c1(f: &Finisher, plane: &[f32], first: usize, valid: &[bool], out: &mut [f32]));

#[inline(always)]
fn finish_from_c1(f: &Finisher, p: &[f32], first: usize, v: &[bool], o: &mut [f32]) {
    f.run::<1>([p], first, v, o)
}

dispatch!(fn finish_1 / finish_1_avx2 => finish_c1(f: &Finisher, planes: &[&[f32]], valid: &[bool], out: &mut [f32]));
dispatch!(fn finish_3 / finish_3_avx2 => finish_c3(f: &Finisher, planes: &[&[f32]], valid: &[bool], out: &mut [f32]));
dispatch!(fn finish_n / finish_n_avx2 => finish_cn(f: &Finisher, planes: &[&[f32]], valid: &[bool], out: &mut [f32]));

#[inline(always)]
fn finish_c1(f: &Finisher, p: &[&[f32]], v: &[bool], o: &mut [f32]) {
    f.run::<1>([p[0]], 0, v, o)
}
#[inline(always)]
fn finish_c3(f: &Finisher, p: &[&[f32]], v: &[bool], o: &mut [f32]) {
    f.run::<3>([p[0], p[1], p[2]], 0, v, o)
}
#[inline(always)]
fn finish_cn(f: &Finisher, p: &[&[f32]], v: &[bool], o: &mut [f32]) {
    f.run_any(p, v, o)
}

/// The inverse curve applied in place to cell-major values (`c` per cell); invalid cells set
/// to 0.
pub fn curve_interleaved(curve: &Curve, c: usize, valid: &[bool], v: &mut [f32]) {
    // ε repeated over a block of LANES cells, so the block loop is a plain vector loop.
    let eps: Option<Vec<f32>> = curve
        .eps()
        .map(|eps| (0..LANES * c).map(|j| eps[j % c] as f32).collect());
    if curve.is_signed() {
        let eps = eps.expect("the signed curve has ε");
        for (blk, ok) in v.chunks_mut(LANES * c).zip(valid.chunks(LANES)) {
            for (x, &e) in blk.iter_mut().zip(&eps) {
                *x = signed_log_inverse_f32(*x, e);
            }
            for (cell, &ok) in blk.chunks_exact_mut(c).zip(ok) {
                if !ok {
                    cell.fill(0.0);
                }
            }
        }
        return;
    }
    curve_block(eps.as_deref(), c, valid, v)
}

dispatch!(fn curve_block / curve_block_avx2 => curve_impl(eps: Option<&[f32]>, c: usize, valid: &[bool], v: &mut [f32]));

#[inline(always)]
fn curve_impl(eps: Option<&[f32]>, c: usize, valid: &[bool], v: &mut [f32]) {
    for (blk, ok) in v.chunks_mut(LANES * c).zip(valid.chunks(LANES)) {
        if let Some(e) = eps {
            for (x, &e) in blk.iter_mut().zip(e) {
                *x = non_negative(exp_f32(*x) - e);
            }
        } else {
            for x in blk.iter_mut() {
                *x = linear_inverse(*x);
            }
        }
        for (cell, &ok) in blk.chunks_exact_mut(c).zip(ok) {
            if !ok {
                cell.fill(0.0);
            }
        }
    }
}

/// Cell-major values (`c` per cell, finite and ≥ 0 as the inverse curves leave them) × the
/// cell's 1/w, in place.
pub fn scale_cells(rw: &[f32], c: usize, v: &mut [f32]) {
    scale_block(rw, c, v)
}

dispatch!(fn scale_block / scale_block_avx2 => scale_impl(rw: &[f32], c: usize, v: &mut [f32]));

#[inline(always)]
fn scale_impl(rw: &[f32], c: usize, v: &mut [f32]) {
    for (cell, &r) in v.chunks_exact_mut(c).zip(rw) {
        for x in cell {
            *x = scale_finite(*x, r);
        }
    }
}

/// v × 1/w for a decoded v ≥ 0 (finite, not NaN) and 1/w ∈ [1, 1/W_MIN]: the product may
/// pass f32::MAX and saturates there, so a weighted decode never returns Inf either.
#[inline(always)]
fn scale_finite(v: f32, rw: f32) -> f32 {
    // `max` as well for the signed curve's negative values (a no-op for v ≥ 0).
    (v * rw).clamp(-f32::MAX, f32::MAX)
}

/// The linear inverse as in `Curve::inverse_f32`: clamped at 0 (ringing next to a 1e9 peak
/// decoded to −172), saturated at f32::MAX, NaN read as 0 (`max` drops NaN): never non-finite.
#[inline(always)]
fn linear_inverse(y: f32) -> f32 {
    let y = non_negative(y);
    if y < f32::MAX { y } else { f32::MAX }
}

/// y when y > 0, else +0 (NaN and −0 included): `vmaxps y, 0` exactly, unlike `f32::max`,
/// whose choice between ±0 is unspecified.
#[inline(always)]
fn non_negative(y: f32) -> f32 {
    if y > 0.0 { y } else { 0.0 }
}

/// The inverse curve: y, or max(e^y − ε, 0) (quantization noise may dip just below 0).
#[inline(always)]
fn curve_inverse(y: f32, eps: Option<f32>) -> f32 {
    match eps {
        None => linear_inverse(y),
        Some(e) => non_negative(exp_f32(y) - e),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Error of `exp_f32(x)` in ulps of the exact value (f64 exp is exact to ~1e-16 relative).
    fn ulps(x: f32) -> f64 {
        let exact = (x as f64).exp();
        let got = exp_f32(x) as f64;
        let ulp = {
            let r = exact as f32;
            let below = f32::from_bits(r.to_bits() - 1) as f64;
            let above = f32::from_bits(r.to_bits() + 1) as f64;
            // The ulp of the f32 binade holding the exact value.
            if (exact - r as f64).abs() < 1e-300 {
                above - r as f64
            } else {
                (above - below) / 2.0
            }
        };
        (got - exact).abs() / ulp
    }

    #[test]
    fn exp_is_within_one_ulp_on_its_range() {
        let mut worst = (0.0f64, 0.0f32);
        let mut rng = crate::math::SplitMix64::new(7);
        let mut check = |x: f32| {
            let u = ulps(x);
            if u > worst.0 {
                worst = (u, x);
            }
        };
        for _ in 0..400_000 {
            check((rng.next_f64() * (EXP_MAX - EXP_MIN) as f64 + EXP_MIN as f64) as f32);
            // Small arguments, where most of a log-curve table lives.
            check((rng.next_f64() * 8.0 - 4.0) as f32);
        }
        for x in [
            EXP_MIN, EXP_MAX, 0.0, -0.0, 1.0, -1.0, 0.3465736, -0.3465736,
        ] {
            check(x);
        }
        assert!(worst.0 <= 1.0, "worst {} ulp at x = {}", worst.0, worst.1);
    }

    /// Values a decoded plane can hold, hostile ones included.
    fn plane_value(rng: &mut crate::math::SplitMix64) -> f32 {
        match rng.next_u64() % 16 {
            0 => f32::NAN,
            1 => f32::INFINITY,
            2 => f32::NEG_INFINITY,
            3 => -0.0,
            4 => 0.0,
            5 => (rng.next_f64() * 400.0 - 200.0) as f32,
            6 => f32::from_bits(rng.next_u64() as u32),
            7 => (rng.next_f64() * 1e-40) as f32,
            _ => (rng.next_f64() * 12.0 - 8.0) as f32,
        }
    }

    #[test]
    fn the_avx2_blocks_give_the_portable_bits() {
        if !avx2() {
            println!("skipped: this CPU has no AVX2, so only the portable blocks exist");
            return;
        }
        let mut rng = crate::math::SplitMix64::new(11);
        for case in 0..24 {
            let c = if case % 2 == 0 { 3 } else { 1 };
            let colour = c == 3 && case % 4 == 0;
            let log = case % 3 != 0;
            let cells = 8 * (case + 1) + case % 8;
            let planes: Vec<Vec<f32>> = (0..c)
                .map(|_| (0..cells).map(|_| plane_value(&mut rng)).collect())
                .collect();
            let valid: Vec<bool> = (0..cells)
                .map(|i| i % 8 == 0 || !rng.next_u64().is_multiple_of(4))
                .collect();
            let fin = Finisher {
                c,
                m: if colour {
                    (0..9)
                        .map(|_| (rng.next_f64() * 4.0 - 2.0) as f32)
                        .collect()
                } else {
                    (0..c * c)
                        .map(|i| if i / c == i % c { 1.0 } else { 0.0 })
                        .collect()
                },
                eps: log.then(|| (0..c).map(|k| 1e-3 * (k + 1) as f32).collect()),
                signed: false,
                colour,
                rw: None,
                avx2: true,
            };
            let views: Vec<&[f32]> = planes.iter().map(|p| p.as_slice()).collect();
            let mut fast = vec![f32::NAN; cells * c];
            finish(&fin, &views, &valid, &mut fast);
            let fin = fin.portable();
            let mut slow = vec![f32::NAN; cells * c];
            finish(&fin, &views, &valid, &mut slow);
            for (i, (a, b)) in fast.iter().zip(&slow).enumerate() {
                assert_eq!(
                    a.to_bits(),
                    b.to_bits(),
                    "case {case} (c {c}, colour {colour}, log {log}) value {i}: {a:e} vs {b:e}"
                );
                assert!(a.is_finite() && *a >= 0.0, "case {case} value {i}: {a:e}");
            }
            for (cell, &ok) in fast.chunks(c).zip(&valid) {
                if !ok {
                    assert!(cell.iter().all(|v| v.to_bits() == 0));
                }
            }
        }
    }

    #[test]
    fn exp_clamps_instead_of_overflowing() {
        for x in [100.0f32, f32::INFINITY, f32::MAX] {
            assert_eq!(exp_f32(x), exp_f32(EXP_MAX));
            assert!(exp_f32(x).is_finite());
        }
        assert_eq!(exp_f32(f32::NAN), exp_f32(EXP_MIN));
        for x in [-120.0f32, f32::NEG_INFINITY, -f32::MAX] {
            assert_eq!(exp_f32(x), 0.0);
        }
        assert_eq!(exp_f32(0.0), 1.0);
    }

    #[test]
    fn exp_reaches_the_subnormals() {
        // Within 1 ulp of the correctly rounded f32 (a subnormal's ulp is 2^−149).
        let mut x = -104.0f32;
        while x < EXP_MIN {
            let got = exp_f32(x);
            let want = (x as f64).exp() as f32;
            let ulp = (want.to_bits() as i64 - got.to_bits() as i64).abs();
            assert!(ulp <= 1, "e^{x}: {got:e} vs {want:e}");
            x += 0.013;
        }
        assert!(exp_f32(-100.0) > 0.0 && exp_f32(-100.0) < f32::MIN_POSITIVE);
    }

    /// Runs finished together (`run_rows`, one AVX2 call for whole blocks, the next runs
    /// prefetched) give the bits of finishing each run on its own, portable or not.
    #[test]
    fn rows_finish_as_single_runs() {
        let mut rng = crate::math::SplitMix64::new(23);
        for (c, cells, rows, stride) in [(3, 32, 6, 40), (3, 16, 4, 16), (1, 8, 7, 9), (3, 3, 5, 7)]
        {
            let fin = Finisher::example(c);
            let first = 5;
            let total = first + (rows - 1) * stride + cells + 3;
            let planes: Vec<Vec<f32>> = (0..c)
                .map(|_| (0..rows * cells).map(|_| plane_value(&mut rng)).collect())
                .collect();
            let valid: Vec<bool> = (0..total)
                .map(|_| !rng.next_u64().is_multiple_of(5))
                .collect();
            for fin in [fin.clone_portable(false), fin.clone_portable(true)] {
                let mut together = vec![f32::NAN; total * c];
                let mut alone = together.clone();
                if c == 3 {
                    let p: [&[f32]; 3] = std::array::from_fn(|k| planes[k].as_slice());
                    fin.run_rows::<3>(p, rows, cells, first, stride, &valid, &mut together);
                } else {
                    fin.run_rows::<1>(
                        [planes[0].as_slice()],
                        rows,
                        cells,
                        first,
                        stride,
                        &valid,
                        &mut together,
                    );
                }
                for j in 0..rows {
                    let f = first + j * stride;
                    let views: Vec<&[f32]> = planes
                        .iter()
                        .map(|p| &p[j * cells..(j + 1) * cells])
                        .collect();
                    finish(
                        &fin,
                        &views,
                        &valid[f..f + cells],
                        &mut alone[f * c..(f + cells) * c],
                    );
                }
                for (i, (a, b)) in together.iter().zip(&alone).enumerate() {
                    assert_eq!(a.to_bits(), b.to_bits(), "c {c}, cells {cells}, value {i}");
                }
            }
        }
    }

    /// Finishing a set's cells in place (`run_cells`) gives each cell the bits the whole
    /// run gives it: 1 and 3 components, with and without 1/w weights, portable or not, sets
    /// smaller and larger than a block.
    #[test]
    fn listed_cells_finish_as_the_whole_run() {
        let mut rng = crate::math::SplitMix64::new(41);
        for c in [1, 3] {
            let cells = 203;
            let planes: Vec<Vec<f32>> = (0..c)
                .map(|_| (0..cells).map(|_| plane_value(&mut rng)).collect())
                .collect();
            let valid: Vec<bool> = (0..cells)
                .map(|_| !rng.next_u64().is_multiple_of(5))
                .collect();
            let weights: Vec<f32> = (0..cells)
                .map(|_| (rng.next_f64() * 40.0 + 0.5) as f32)
                .collect();
            let listed: Vec<u32> = (0..cells as u32)
                .filter(|_| rng.next_u64().is_multiple_of(3))
                .collect();
            for weighted in [false, true] {
                for portable in [false, true] {
                    let mut fin = Finisher::example(c).clone_portable(portable);
                    fin.rw = weighted.then(|| weights.clone());
                    let mut whole = vec![f32::NAN; cells * c];
                    let views: Vec<&[f32]> = planes.iter().map(|p| p.as_slice()).collect();
                    finish(&fin, &views, &valid, &mut whole);
                    for list in [&listed[..], &listed[..5], &[]] {
                        let set = CellSet::new(cells, list.iter().copied());
                        let mut got: Vec<f32> = list
                            .iter()
                            .flat_map(|&f| planes.iter().map(move |p| p[f as usize]))
                            .collect();
                        if c == 3 {
                            fin.run_cells::<3>(&set, &valid, &mut got);
                        } else {
                            fin.run_cells::<1>(&set, &valid, &mut got);
                        }
                        for (i, &f) in list.iter().enumerate() {
                            for k in 0..c {
                                assert_eq!(
                                    got[i * c + k].to_bits(),
                                    whole[f as usize * c + k].to_bits(),
                                    "c {c}, weighted {weighted}, portable {portable}, cell {f}"
                                );
                            }
                        }
                    }
                }
            }
        }
    }
}
