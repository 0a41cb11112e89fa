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
use super::transform::{Curve, Transform};

/// True when the AVX2 copies of the decoder loops can run on this CPU.
#[inline]
pub(crate) fn avx2() -> bool {
    #[cfg(target_arch = "x86_64")]
    {
        std::is_x86_feature_detected!("avx2")
    }
    #[cfg(not(target_arch = "x86_64"))]
    {
        false
    }
}

/// Defines `$name` that runs `$body` (an `#[inline(always)]` fn) through its AVX2 copy when
/// the CPU has AVX2, else the portable copy. Same bits either way (module doc).
macro_rules! dispatch {
    ($(#[$m:meta])* $vis:vis fn $name:ident / $avx:ident => $body:ident ( $($a:ident : $t:ty),* $(,)? ) $(-> $r:ty)?) => {
        $(#[$m])*
        $vis fn $name($($a: $t),*) $(-> $r)? {
            #[cfg(target_arch = "x86_64")]
            if $crate::codec::simd::avx2() {
                // SAFETY: only called when the CPU reports AVX2.
                return unsafe { $avx($($a),*) };
            }
            $body($($a),*)
        }
        #[cfg(target_arch = "x86_64")]
        #[target_feature(enable = "avx2")]
        unsafe fn $avx($($a: $t),*) $(-> $r)? {
            $body($($a),*)
        }
    };
}
pub(crate) use dispatch;

/// Inputs of [`exp_f32`] are clamped to this range: e^88 ≈ 1.65e38 stays below f32::MAX and
/// e^−87 ≈ 1.6e−38 above the smallest normal, so the exponent bits built below are valid.
pub const EXP_MIN: f32 = -87.0;
pub const EXP_MAX: f32 = 88.0;

/// e^x in f32, within 1 ulp of the exact value on [EXP_MIN, EXP_MAX] (tested), subnormal
/// below it and 0 below about −109 (NaN reads as EXP_MIN); x above EXP_MAX is clamped. Cody–Waite reduction x = n ln2 + r, |r| ≤ ln2/2, and
/// the degree-6 minimax polynomial of Cephes `expf` (Moshier 1992), without FMA.
#[inline(always)]
pub fn exp_f32(x: f32) -> f32 {
    const LOG2E: f32 = std::f32::consts::LOG2_E;
    // 1.5·2^23: adding it rounds to an integer (to nearest even) held in the low mantissa bits.
    const MAGIC: f32 = 12_582_912.0;
    // ln2 split so that n·LN2_HI is exact for |n| ≤ 128 (LN2_HI has 9 significant bits).
    const LN2_HI: f32 = 0.693_359_4;
    const LN2_LO: f32 = -2.121_944_4e-4;
    // Below EXP_MIN the result is an f32 subnormal (down to e^−103.3): e^x = e^(x + 32 ln2)·2^−32,
    // one rounding. Flushing to e^−87 instead decoded a 1e−41 sample of a dark log-curve table
    // 1e3× too large (tests/hard_cases.rs).
    let small = x < EXP_MIN;
    let x = if small {
        x + 32.0 * std::f32::consts::LN_2
    } else {
        x
    };
    let scale = if small { 2.328_306_4e-10 } else { 1.0 }; // 2^−32
    // Not `clamp`: it would keep NaN, and NaN must read as EXP_MIN.
    #[allow(clippy::manual_clamp)]
    let x = x.max(EXP_MIN).min(EXP_MAX);
    let t = x * LOG2E + MAGIC;
    let n = t - MAGIC;
    let r = x - n * LN2_HI;
    let r = r - n * LN2_LO;
    let mut p = 1.987_569_1e-4f32;
    p = p * r + 1.398_199_9e-3;
    p = p * r + 8.333_452e-3;
    p = p * r + 4.166_579_6e-2;
    p = p * r + 1.666_666_5e-1;
    p = p * r + 0.5; // Cephes 5.0000001201e-1 rounds to 0.5 in f32.
    let y = p * (r * r) + r + 1.0;
    // 2^n from the integer in t's mantissa: n ∈ [−126, 127] here, a normal exponent.
    let e = (t.to_bits() as i32 - MAGIC.to_bits() as i32 + 127) << 23;
    y * f32::from_bits(e as u32) * scale
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
    colour: bool,
    /// 1/w of every cell of the layout, computed once per decode (weighted transforms only).
    rw: Option<Vec<f32>>,
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
        let eps = match &t.curve {
            Curve::Linear => None,
            Curve::Log { eps } => Some(eps.iter().map(|&e| e as f32).collect()),
        };
        Finisher {
            c,
            m,
            eps,
            colour: t.colour.is_some(),
            rw: t.reciprocal_weights(layout.grid, layout.valid),
        }
    }

    /// Cells `first..first + valid.len()` of the layout, held by the component runs `planes`,
    /// into `out` (C values per cell). Inlined into the caller's AVX2 or portable copy. Whole
    /// blocks of [`LANES`] cells take a fixed-size path (no variable-length copies, the
    /// validity applied as a bit mask, the interleave through a fixed-size staging array), the
    /// tail the general one; both perform the same arithmetic per cell, so the same bits.
    #[inline(always)]
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
        let mut mm = [[0f32; C]; C];
        for i in 0..C {
            for k in 0..C {
                mm[i][k] = self.m[i * C + k];
            }
        }
        let ee: [f32; C] = std::array::from_fn(|k| self.eps.as_ref().map_or(0.0, |e| e[k]));
        let full = cells - cells % LANES;
        let mut f0 = 0;
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
            if self.eps.is_some() {
                for l in 0..LANES {
                    y[k][l] = (exp_f32(y[k][l]) - ee[k]).max(0.0);
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
                    let v = curve_inverse(y, self.eps.as_ref().map(|e| e[k]));
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
    let eps: Option<Vec<f32>> = match curve {
        Curve::Linear => None,
        // ε repeated over a block of LANES cells, so the block loop is a plain vector loop.
        Curve::Log { eps } => Some((0..LANES * c).map(|j| eps[j % c] as f32).collect()),
    };
    curve_block(eps.as_deref(), c, valid, v)
}

dispatch!(fn curve_block / curve_block_avx2 => curve_impl(eps: Option<&[f32]>, c: usize, valid: &[bool], v: &mut [f32]));

#[inline(always)]
fn curve_impl(eps: Option<&[f32]>, c: usize, valid: &[bool], v: &mut [f32]) {
    for (blk, ok) in v.chunks_mut(LANES * c).zip(valid.chunks(LANES)) {
        if let Some(e) = eps {
            for (x, &e) in blk.iter_mut().zip(e) {
                *x = (exp_f32(*x) - e).max(0.0);
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
    (v * rw).min(f32::MAX)
}

/// The linear inverse as in `Curve::inverse_f32`: clamped at 0 (ringing next to a 1e9 peak
/// decoded to −172), saturated at f32::MAX, NaN read as 0 (`max` drops NaN): never non-finite.
#[inline(always)]
fn linear_inverse(y: f32) -> f32 {
    // Not `clamp`: it would keep NaN.
    #[allow(clippy::manual_clamp)]
    y.max(0.0).min(f32::MAX)
}

/// The inverse curve: y, or max(e^y − ε, 0) (quantization noise may dip just below 0).
#[inline(always)]
fn curve_inverse(y: f32, eps: Option<f32>) -> f32 {
    match eps {
        None => linear_inverse(y),
        Some(e) => (exp_f32(y) - e).max(0.0),
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
}
