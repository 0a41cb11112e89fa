//! Stage (2), transform: an optional per-cell weight (cosine: w = cos θi cos θo), a per-channel
//! curve (linear, log(ε + x), or its odd extension for signed tables) and an optional colour decorrelation (an orthonormal c×c matrix,
//! the Karhunen–Loève transform of the table's channels, recorded in the header). The coded
//! components of a cell are z = M curve(w·x); the decoder returns curve⁻¹(Mᵀ z) / w.

use crate::grid::{CellCosProducts, Grid};
use crate::{Error, Result};
use serde::{Deserialize, Serialize};

/// The per-channel curve applied before quantization.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(tag = "curve", rename_all = "snake_case")]
pub enum Curve {
    /// y = x. Lossy codecs drop negative values here too (decoded values are clamped at 0).
    Linear,
    /// y = ln(ε_c + max(x, 0)): errors in y are relative errors of ε_c + x, so dark and bright
    /// regions get the same relative precision above ε_c. Lossy codecs drop negative values
    /// (they are below every ε the search tries).
    Log { eps: Vec<f64> },
    /// y = sign(x) · ln(1 + |x|/ε_c), the odd extension of the log curve (ln(ε_c + x) − ln ε_c
    /// for x ≥ 0): for tables that hold negative values (measured files fitted to noisy data,
    /// RGL files among them), which the metrics compare with the same relative precision as
    /// positive ones. Decoded values keep their sign.
    SignedLog { eps: Vec<f64> },
}

impl Curve {
    /// Checks the curve against the channel count.
    pub fn validate(&self, channels: usize) -> Result<()> {
        if let Some(eps) = self.eps()
            && (eps.len() != channels || eps.iter().any(|e| !(e.is_finite() && *e > 0.0)))
        {
            return Err(Error::input(format!(
                "log curve: eps {eps:?} needs {channels} finite positive values"
            )));
        }
        Ok(())
    }

    /// ε per channel of the log curves.
    pub fn eps(&self) -> Option<&[f64]> {
        match self {
            Curve::Linear => None,
            Curve::Log { eps } | Curve::SignedLog { eps } => Some(eps),
        }
    }

    /// True when decoded values keep their sign (otherwise they are clamped at 0).
    pub fn is_signed(&self) -> bool {
        matches!(self, Curve::SignedLog { .. })
    }
    #[inline]
    pub fn forward(&self, x: f64, ch: usize) -> f64 {
        match self {
            Curve::Linear => x,
            Curve::Log { eps } => (eps[ch] + x.max(0.0)).ln(),
            // ln_1p keeps |x| ≪ ε exact to the ulp (ln(ε + |x|) − ln ε would cancel).
            Curve::SignedLog { eps } => (x.abs() / eps[ch]).ln_1p().copysign(x),
        }
    }
    #[inline]
    pub fn inverse(&self, y: f64, ch: usize) -> f64 {
        match self {
            // Clamp: a BRDF is ≥ 0, but quantization through the colour matrix or DCT ringing
            // decoded a GGX α = 5e-4 table to −172 next to its 1e9 peak (tests/hard_cases.rs).
            Curve::Linear => y.max(0.0),
            // Clamp: quantization error may push a value just below 0.
            Curve::Log { eps } => (y.exp() - eps[ch]).max(0.0),
            Curve::SignedLog { eps } => (eps[ch] * y.abs().exp_m1()).copysign(y),
        }
    }
    /// f32 inverse for the decoder's hot loop (same formula), saturated like [`finite_f32`].
    #[inline]
    pub fn inverse_f32(&self, y: f32, ch: usize) -> f32 {
        let v = match self {
            // Clamp at 0 as in `inverse`.
            Curve::Linear => y.max(0.0),
            Curve::Log { eps } => (y.exp() - eps[ch] as f32).max(0.0),
            Curve::SignedLog { eps } => signed_log_inverse_f32(y, eps[ch] as f32),
        };
        if v.is_nan() {
            0.0
        } else {
            v.clamp(-f32::MAX, f32::MAX)
        }
    }
}

/// The inverse of the signed log curve in f32: sign(y) · ε · (e^|y| − 1), written with the
/// decoders' own exponential (`simd::exp_f32`) so that every decoder path gives the same bits.
/// e^|y| − 1 loses relative precision for |y| ≪ 1, where |x| ≪ ε: errors there are below ε,
/// the level the metrics' relative errors are measured against.
#[inline(always)]
pub(crate) fn signed_log_inverse_f32(y: f32, eps: f32) -> f32 {
    // `exp_f32` clamps its argument, but ε · e^88 can still pass f32::MAX: saturate there
    // (a NaN y reads as e^EXP_MIN − 1 < 0, so as a tiny magnitude, never NaN).
    let v = eps * (super::simd::exp_f32(y.abs()) - 1.0);
    let v = if v < f32::MAX { v.max(0.0) } else { f32::MAX };
    v.copysign(y)
}

/// A decoded sample as a finite f32. A valid request can still leave the f32 range on the way
/// back (`f16:eps=1e300`: ε ≈ 1e299 and the f16 error of ln ε is a factor e^0.25, so
/// e^z − ε ≈ 3e298), and a hostile header can ask for anything: values beyond it saturate at
/// ±f32::MAX and a NaN (∞ − ∞) reads as 0, so that a decoder never returns Inf or NaN.
#[inline]
pub fn finite_f32(v: f64) -> f32 {
    if v.is_nan() {
        0.0
    } else {
        v.clamp(-(f32::MAX as f64), f32::MAX as f64) as f32
    }
}

/// An orthonormal channel transform z = M y (rows of M are the new components), inverse Mᵀ.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Colour {
    /// c×c, row-major.
    pub matrix: Vec<f64>,
}

/// Hands each row of a set of samples to its argument, in a fixed order.
pub type RowVisitor<'a> = dyn Fn(&mut dyn FnMut(&[f64])) + 'a;

impl Colour {
    pub fn channels(&self) -> usize {
        (self.matrix.len() as f64).sqrt() as usize
    }

    pub fn validate(&self, channels: usize) -> Result<()> {
        if self.matrix.len() != channels * channels || self.matrix.iter().any(|m| !m.is_finite()) {
            return Err(Error::input(format!(
                "colour matrix: {} finite entries needed for {channels} channels, got {}",
                channels * channels,
                self.matrix.len()
            )));
        }
        // Orthonormality is what makes Mᵀ the inverse; a hand-edited header could break it.
        for i in 0..channels {
            for j in 0..channels {
                let d: f64 = (0..channels)
                    .map(|k| self.matrix[i * channels + k] * self.matrix[j * channels + k])
                    .sum();
                let want = if i == j { 1.0 } else { 0.0 };
                if (d - want).abs() > 1e-9 {
                    return Err(Error::input(
                        "colour matrix is not orthonormal (rows must be unit and orthogonal)",
                    ));
                }
            }
        }
        Ok(())
    }

    /// The Karhunen–Loève transform of `samples` (n × c, row-major): eigenvectors of the
    /// channel covariance by cyclic Jacobi rotations (Golub & Van Loan §8.5), sorted by
    /// decreasing variance, each with its largest entry positive (deterministic signs).
    pub fn klt(samples: &[f64], c: usize) -> Colour {
        Colour::klt_of_rows(c, &|row: &mut dyn FnMut(&[f64])| {
            samples.chunks_exact(c).for_each(&mut *row)
        })
    }

    /// [`Colour::klt`] of the rows `rows` hands to its argument, in the same order each
    /// time it is called (twice: for the mean, then the covariance), so that the samples
    /// need not be held: the same bits as `klt` of the rows collected.
    pub fn klt_of_rows(c: usize, rows: &RowVisitor) -> Colour {
        let mut n = 0usize;
        let mut mean = vec![0.0; c];
        rows(&mut |row| {
            n += 1;
            for k in 0..c {
                mean[k] += row[k];
            }
        });
        for m in &mut mean {
            *m /= n.max(1) as f64;
        }
        let mut a = vec![0.0; c * c];
        rows(&mut |row| {
            for i in 0..c {
                for j in 0..c {
                    a[i * c + j] += (row[i] - mean[i]) * (row[j] - mean[j]);
                }
            }
        });
        let mut v = vec![0.0; c * c];
        for i in 0..c {
            v[i * c + i] = 1.0;
        }
        for _sweep in 0..50 {
            let off: f64 = (0..c)
                .flat_map(|i| (0..c).filter(move |&j| j != i).map(move |j| (i, j)))
                .map(|(i, j)| a[i * c + j] * a[i * c + j])
                .sum();
            let diag: f64 = (0..c).map(|i| a[i * c + i] * a[i * c + i]).sum();
            if off <= 1e-30 * diag.max(f64::MIN_POSITIVE) {
                break;
            }
            for p in 0..c {
                for q in p + 1..c {
                    let apq = a[p * c + q];
                    if apq == 0.0 {
                        continue;
                    }
                    let theta = (a[q * c + q] - a[p * c + p]) / (2.0 * apq);
                    let t = theta.signum() / (theta.abs() + (theta * theta + 1.0).sqrt());
                    let t = if theta == 0.0 { 1.0 } else { t };
                    let cs = 1.0 / (t * t + 1.0).sqrt();
                    let sn = t * cs;
                    for k in 0..c {
                        let akp = a[k * c + p];
                        let akq = a[k * c + q];
                        a[k * c + p] = cs * akp - sn * akq;
                        a[k * c + q] = sn * akp + cs * akq;
                    }
                    for k in 0..c {
                        let apk = a[p * c + k];
                        let aqk = a[q * c + k];
                        a[p * c + k] = cs * apk - sn * aqk;
                        a[q * c + k] = sn * apk + cs * aqk;
                    }
                    for k in 0..c {
                        let vkp = v[k * c + p];
                        let vkq = v[k * c + q];
                        v[k * c + p] = cs * vkp - sn * vkq;
                        v[k * c + q] = sn * vkp + cs * vkq;
                    }
                }
            }
        }
        let mut order: Vec<usize> = (0..c).collect();
        order.sort_by(|&i, &j| a[j * c + j].total_cmp(&a[i * c + i]));
        let mut m = vec![0.0; c * c];
        for (r, &col) in order.iter().enumerate() {
            let mut vec: Vec<f64> = (0..c).map(|k| v[k * c + col]).collect();
            let big = vec
                .iter()
                .copied()
                .fold(0.0f64, |b, x| if x.abs() > b.abs() { x } else { b });
            if big < 0.0 {
                vec.iter_mut().for_each(|x| *x = -*x);
            }
            let norm = vec.iter().map(|x| x * x).sum::<f64>().sqrt();
            for k in 0..c {
                m[r * c + k] = vec[k] / norm;
            }
        }
        Colour { matrix: m }
    }

    /// z = M y for one cell.
    #[inline]
    pub fn forward(&self, y: &[f64], z: &mut [f64]) {
        let c = y.len();
        for (i, zi) in z.iter_mut().enumerate() {
            *zi = (0..c).map(|k| self.matrix[i * c + k] * y[k]).sum();
        }
    }

    /// y = Mᵀ z for one cell.
    #[inline]
    pub fn inverse(&self, z: &[f64], y: &mut [f64]) {
        let c = z.len();
        for (k, yk) in y.iter_mut().enumerate() {
            *yk = (0..c).map(|i| self.matrix[i * c + k] * z[i]).sum();
        }
    }
}

/// A per-cell weight w applied before the curve: the coded quantity is curve(w·x), and the
/// decoder divides by w.
///
/// Why cosine: what a renderer integrates is f·cos θi (and, summed over a lobe seen from a
/// direction, roughly f·cos θi·cos θo), so an error at a grazing cell matters less than the same
/// relative error head-on; and the grazing peaks of Fresnel and retro-reflection, which would
/// otherwise set the range of the linear curve (and its quantization step), shrink by w.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Weight {
    /// w = max(cos θi · cos θo, [`W_MIN`]) of the cell's sample pair ([`Grid::cos_products`]).
    Cosine,
}

/// Floor of the weight of a valid cell. Cells closer to the horizon (cos θi cos θo < 1e-4: θo
/// within 0.006° of it when θi = 0, or both within 0.57°) are coded with w = 1e-4: the division
/// by w amplifies the coding error by at most 1e4 there, and 1/w stays a finite f32.
pub const W_MIN: f64 = 1e-4;

impl Weight {
    /// The weight of every cell of `grid`: valid cells floored at [`W_MIN`] (a NaN product
    /// reads as the floor: `f64::max` drops NaN), invalid cells 1 (never coded; 1 keeps the
    /// filled values of the DCT chains as they are).
    pub fn cells<'v>(self, grid: &Grid, valid: &'v [bool]) -> CellWeights<'v> {
        match self {
            Weight::Cosine => CellWeights {
                cos: grid.cell_cos_products(),
                valid,
            },
        }
    }

    /// The name in `--codec` requests and summaries.
    pub fn name(self) -> &'static str {
        match self {
            Weight::Cosine => "cosine",
        }
    }
}

/// The weights of a grid's cells ([`Weight::cells`]), computed per cell from the axes the
/// cosine product depends on, not stored (an f64 array is 134 MB on a 16.8 M-cell grid).
pub struct CellWeights<'v> {
    cos: CellCosProducts,
    valid: &'v [bool],
}

impl CellWeights<'_> {
    /// The weight of cell `f`.
    #[inline]
    pub fn at(&self, f: usize) -> f64 {
        if self.valid[f] {
            self.cos.at(f).max(W_MIN)
        } else {
            1.0
        }
    }

    /// Cells weighted.
    pub fn len(&self) -> usize {
        self.valid.len()
    }

    pub fn is_empty(&self) -> bool {
        self.valid.is_empty()
    }
}

/// Stage (2) as recorded: an optional weight, a curve and an optional colour decorrelation.
///
/// In the header the weight is part of the curve's tag (`"curve": "cosine_log"`), not a field
/// of its own: a reader built before weights existed ignores unknown fields, so it would have
/// decoded w·f as f without a word; an unknown tag it refuses ("unknown variant"). Unweighted
/// headers are unchanged (`"curve": "log"`), byte for byte.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(from = "TransformRecord", into = "TransformRecord")]
pub struct Transform {
    pub curve: Curve,
    pub colour: Option<Colour>,
    pub weight: Option<Weight>,
}

/// The header form of [`Transform`].
#[derive(Clone, Serialize, Deserialize)]
struct TransformRecord {
    #[serde(flatten)]
    curve: CurveRecord,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    colour: Option<Colour>,
}

/// [`Curve`] with the weight folded into the tag.
#[derive(Clone, Serialize, Deserialize)]
#[serde(tag = "curve", rename_all = "snake_case")]
enum CurveRecord {
    Linear,
    Log { eps: Vec<f64> },
    CosineLinear,
    CosineLog { eps: Vec<f64> },
    SignedLog { eps: Vec<f64> },
    CosineSignedLog { eps: Vec<f64> },
}

impl From<TransformRecord> for Transform {
    fn from(r: TransformRecord) -> Transform {
        let (curve, weight) = match r.curve {
            CurveRecord::Linear => (Curve::Linear, None),
            CurveRecord::Log { eps } => (Curve::Log { eps }, None),
            CurveRecord::CosineLinear => (Curve::Linear, Some(Weight::Cosine)),
            CurveRecord::CosineLog { eps } => (Curve::Log { eps }, Some(Weight::Cosine)),
            CurveRecord::SignedLog { eps } => (Curve::SignedLog { eps }, None),
            CurveRecord::CosineSignedLog { eps } => {
                (Curve::SignedLog { eps }, Some(Weight::Cosine))
            }
        };
        Transform {
            curve,
            colour: r.colour,
            weight,
        }
    }
}

impl From<Transform> for TransformRecord {
    fn from(t: Transform) -> TransformRecord {
        let curve = match (t.curve, t.weight) {
            (Curve::Linear, None) => CurveRecord::Linear,
            (Curve::Log { eps }, None) => CurveRecord::Log { eps },
            (Curve::Linear, Some(Weight::Cosine)) => CurveRecord::CosineLinear,
            (Curve::Log { eps }, Some(Weight::Cosine)) => CurveRecord::CosineLog { eps },
            (Curve::SignedLog { eps }, None) => CurveRecord::SignedLog { eps },
            (Curve::SignedLog { eps }, Some(Weight::Cosine)) => {
                CurveRecord::CosineSignedLog { eps }
            }
        };
        TransformRecord {
            curve,
            colour: t.colour,
        }
    }
}

impl Transform {
    pub fn validate(&self, channels: usize) -> Result<()> {
        self.curve.validate(channels)?;
        if let Some(col) = &self.colour {
            col.validate(channels)?;
        }
        Ok(())
    }

    /// The weight of every cell (see [`Weight::cells`]), `None` when unweighted.
    pub fn cell_weights<'v>(&self, grid: &Grid, valid: &'v [bool]) -> Option<CellWeights<'v>> {
        self.weight.map(|w| w.cells(grid, valid))
    }

    /// 1/w of every cell in f32, for the decoders' final multiply (≤ 1/[`W_MIN`], finite).
    pub fn reciprocal_weights(&self, grid: &Grid, valid: &[bool]) -> Option<Vec<f32>> {
        self.cell_weights(grid, valid)
            .map(|w| (0..w.len()).map(|f| (1.0 / w.at(f)) as f32).collect())
    }

    /// Transformed components of every cell (cell-major, component fastest), in f64; the
    /// weights (when the transform has them) come from `grid` and `valid`.
    pub fn forward_all(&self, data: &[f32], c: usize, grid: &Grid, valid: &[bool]) -> Vec<f64> {
        let mut out = vec![0.0; data.len()];
        self.for_each_cell(data, c, grid, valid, |f, z| {
            out[f * c..(f + 1) * c].copy_from_slice(z)
        });
        out
    }

    /// The transformed components of every cell in turn, `visit(cell, z)`: what
    /// [`Transform::forward_all`] stores, without holding every cell at once. Each batch of
    /// cells is transformed in parallel before its cells are visited, in
    /// order: the values of one `forward_cell` per cell (the curve's logs are most of a
    /// visit's time, and a KLT visits a 64⁴ RGB table's 50 M values twice).
    pub fn for_each_cell(
        &self,
        data: &[f32],
        c: usize,
        grid: &Grid,
        valid: &[bool],
        mut visit: impl FnMut(usize, &[f64]),
    ) {
        use rayon::prelude::*;
        const BATCH: usize = 1 << 16;
        const CHUNK: usize = 1 << 10;
        let c = c.max(1);
        let w = self.cell_weights(grid, valid);
        let cells = data.len() / c;
        let mut out = vec![0.0; BATCH.min(cells) * c];
        let mut start = 0;
        while start < cells {
            let n = BATCH.min(cells - start);
            out[..n * c]
                .par_chunks_mut(CHUNK * c)
                .enumerate()
                .for_each_init(
                    || vec![0.0; c],
                    |y, (i, o)| {
                        for (j, o) in o.chunks_exact_mut(c).enumerate() {
                            let f = start + i * CHUNK + j;
                            let wf = w.as_ref().map_or(1.0, |w| w.at(f));
                            self.forward_cell(&data[f * c..(f + 1) * c], wf, y, o);
                        }
                    },
                );
            for (j, o) in out[..n * c].chunks_exact(c).enumerate() {
                visit(start + j, o);
            }
            start += n;
        }
    }

    /// One cell's transformed components `out`, as [`Transform::for_each_cell`] visits them:
    /// `wf` the cell's weight ([`Transform::cell_weights`]; 1 unweighted), `y` scratch.
    #[inline]
    pub fn forward_cell(&self, cell: &[f32], wf: f64, y: &mut [f64], out: &mut [f64]) {
        for (k, (y, &x)) in y.iter_mut().zip(cell).enumerate() {
            *y = self.curve.forward(wf * x as f64, k);
        }
        match &self.colour {
            Some(col) => col.forward(y, out),
            None => out.copy_from_slice(y),
        }
    }

    /// One cell back from transformed components; `w` is the cell's weight (1 unweighted:
    /// the division is then exact, so unweighted values are as before).
    #[inline]
    pub fn inverse_cell(&self, z: &[f64], y: &mut [f64], w: f64, out: &mut [f32]) {
        match &self.colour {
            Some(col) => col.inverse(z, y),
            None => y.copy_from_slice(z),
        }
        for (k, o) in out.iter_mut().enumerate() {
            *o = finite_f32(self.curve.inverse(y[k], k) / w);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    #[test]
    fn decoded_values_saturate_instead_of_overflowing() {
        assert_eq!(finite_f32(1e300), f32::MAX);
        assert_eq!(finite_f32(f64::NEG_INFINITY), -f32::MAX);
        assert_eq!(finite_f32(f64::NAN), 0.0);
        assert_eq!(finite_f32(0.25), 0.25);
        let log = Curve::Log { eps: vec![1e299] };
        // e^{ln ε + 0.25} − ε ≈ 0.28 ε: beyond f32 in f64, and ∞ − ∞ in f32.
        let mut out = [0f32];
        Transform {
            curve: log.clone(),
            colour: None,
            weight: None,
        }
        .inverse_cell(&[1e299f64.ln() + 0.25], &mut [0.0], 1.0, &mut out);
        assert_eq!(out[0], f32::MAX);
        // A weighted cell at the floor: 1 / W_MIN more, still saturated, never Inf.
        Transform {
            curve: Curve::Linear,
            colour: None,
            weight: Some(Weight::Cosine),
        }
        .inverse_cell(&[f64::MAX], &mut [0.0], W_MIN, &mut out);
        assert_eq!(out[0], f32::MAX);
        assert_eq!(log.inverse_f32(700.0, 0), 0.0);
        assert_eq!(Curve::Linear.inverse_f32(f32::INFINITY, 0), f32::MAX);
    }

    #[test]
    fn klt_of_proportional_channels_puts_all_variance_in_one_component() {
        // y_k = a_k + s: the covariance is rank one along (1,1,1)/√3.
        let mut s = Vec::new();
        for i in 0..100 {
            let t = (i as f64 * 0.37).sin();
            s.extend_from_slice(&[t + 1.0, t - 2.0, t + 0.5]);
        }
        let col = Colour::klt(&s, 3);
        col.validate(3).unwrap();
        let r3 = 1.0 / 3f64.sqrt();
        for k in 0..3 {
            assert!((col.matrix[k] - r3).abs() < 1e-9, "{:?}", col.matrix);
        }
    }

    /// The batched visit (cells transformed in parallel a batch at a time) hands every cell
    /// the values of the serial one, in the same order: a weighted, curved and coloured
    /// transform over more cells than a batch, with invalid cells.
    #[test]
    fn batched_visits_are_the_serial_ones() {
        let g = crate::grid::parse_grid_spec("halfdiff3:20x60x64,at=edge").unwrap();
        assert!(g.cells() > 1 << 16, "more than one batch");
        let mut rng = crate::math::SplitMix64::new(3);
        let data: Vec<f32> = (0..g.cells() * 3)
            .map(|_| (rng.next_f64() * 5.0) as f32)
            .collect();
        let valid: Vec<bool> = (0..g.cells()).map(|_| rng.next_f64() > 0.1).collect();
        let t = Transform {
            curve: Curve::Log {
                eps: vec![1e-3, 2e-3, 5e-4],
            },
            colour: Some(rotation(0.3)),
            weight: Some(Weight::Cosine),
        };
        let (mut serial, mut batched) = (Vec::new(), Vec::new());
        // The serial visit: one `forward_cell` per cell, in order.
        let w = t.cell_weights(&g, &valid);
        let (mut y, mut z) = (vec![0.0; 3], vec![0.0; 3]);
        for (f, cell) in data.chunks_exact(3).enumerate() {
            let wf = w.as_ref().map_or(1.0, |w| w.at(f));
            t.forward_cell(cell, wf, &mut y, &mut z);
            serial.push(f as u64);
            serial.extend(z.iter().map(|v| v.to_bits()));
        }
        t.for_each_cell(&data, 3, &g, &valid, |f, z| {
            batched.push(f as u64);
            batched.extend(z.iter().map(|v| v.to_bits()));
        });
        assert_eq!(serial.len(), g.cells() * 4);
        assert!(serial == batched, "the same cells, values and order");
    }

    /// A rotation about the third axis: orthonormal.
    fn rotation(a: f64) -> Colour {
        let (s, co) = a.sin_cos();
        Colour {
            matrix: vec![co, s, 0.0, -s, co, 0.0, 0.0, 0.0, 1.0],
        }
    }

    #[test]
    fn weights_are_floored_on_valid_cells_and_one_on_invalid_ones() {
        // Every cell declared valid (as an explicit mask may), including pairs below the
        // horizon: their product is 0, their weight the floor.
        let g = crate::grid::parse_grid_spec("halfdiff3:6x8x10,at=edge").unwrap();
        let geo = g.geometric_mask();
        let all = vec![true; g.cells()];
        let raw = g.cos_products();
        let w = Weight::Cosine.cells(&g, &all);
        assert!(raw.contains(&0.0) && raw.iter().any(|&p| p > 0.9));
        for (f, &p) in raw.iter().enumerate() {
            assert_eq!(w.at(f), p.max(W_MIN), "cell {f}");
        }
        let w = Weight::Cosine.cells(&g, &geo);
        for (f, (&p, &ok)) in raw.iter().zip(&geo).enumerate() {
            assert_eq!(w.at(f), if ok { p.max(W_MIN) } else { 1.0 }, "cell {f}");
        }
        let t = Transform {
            curve: Curve::Linear,
            colour: None,
            weight: Some(Weight::Cosine),
        };
        let rw = t.reciprocal_weights(&g, &all).unwrap();
        assert!(
            rw.iter()
                .all(|r| r.is_finite() && *r >= 1.0 && *r <= 1e4 + 1.0)
        );
        assert_eq!(rw.iter().fold(0f32, |m, r| m.max(*r)), (1.0 / W_MIN) as f32);
    }

    #[test]
    fn weighted_headers_say_so_and_unweighted_ones_are_unchanged() {
        let mut t = Transform {
            curve: Curve::Log { eps: vec![0.5] },
            colour: None,
            weight: None,
        };
        let old = r#"{"curve":"log","eps":[0.5]}"#;
        assert_eq!(serde_json::to_string(&t).unwrap(), old);
        assert_eq!(serde_json::from_str::<Transform>(old).unwrap(), t);
        t.weight = Some(Weight::Cosine);
        let new = r#"{"curve":"cosine_log","eps":[0.5]}"#;
        assert_eq!(serde_json::to_string(&t).unwrap(), new);
        assert_eq!(serde_json::from_str::<Transform>(new).unwrap(), t);
        // A reader from before weights parsed the curve with this very enum: it must refuse
        // a weighted header rather than decode w·f as f.
        let e = serde_json::from_str::<Curve>(new).unwrap_err().to_string();
        assert!(e.contains("unknown variant `cosine_log`"), "{e}");
        t.curve = Curve::Linear;
        let lin = r#"{"curve":"cosine_linear"}"#;
        assert_eq!(serde_json::to_string(&t).unwrap(), lin);
        assert_eq!(serde_json::from_str::<Transform>(lin).unwrap(), t);
        assert!(serde_json::from_str::<Curve>(lin).is_err());
        assert!(serde_json::from_str::<Transform>(r#"{"curve":"sine_log","eps":[1]}"#).is_err());
        for (curve, weight, json) in [
            (
                Curve::SignedLog { eps: vec![0.5] },
                None,
                r#"{"curve":"signed_log","eps":[0.5]}"#,
            ),
            (
                Curve::SignedLog { eps: vec![0.5] },
                Some(Weight::Cosine),
                r#"{"curve":"cosine_signed_log","eps":[0.5]}"#,
            ),
        ] {
            let t = Transform {
                curve,
                colour: None,
                weight,
            };
            assert_eq!(serde_json::to_string(&t).unwrap(), json);
            assert_eq!(serde_json::from_str::<Transform>(json).unwrap(), t);
        }
        // Huge ε and y saturate, NaN reads as a tiny magnitude: never non-finite.
        let s = Curve::SignedLog { eps: vec![1e38] };
        assert_eq!(s.inverse_f32(100.0, 0), f32::MAX);
        assert_eq!(s.inverse_f32(-100.0, 0), -f32::MAX);
        assert!(s.inverse_f32(f32::NAN, 0).abs() < 1e38);
    }

    proptest! {
        /// Forward then inverse of both log curves (the signed one on values of either sign),
        /// with a colour rotation: x comes back to 1e-5 of |x| + ε, and the decoders' f32
        /// inverse of the exact curve value too.
        #[test]
        fn transform_round_trips(x in prop::collection::vec(-1e4f32..1e4, 3), e in 1e-6f64..1.0,
                                 a in -3.0f64..3.0, signed in any::<bool>()) {
            let g = crate::grid::parse_grid_spec("spherical3:1").unwrap();
            let (curve, x): (Curve, Vec<f32>) = if signed {
                (Curve::SignedLog { eps: vec![e; 3] }, x)
            } else {
                (Curve::Log { eps: vec![e; 3] }, x.iter().map(|v| v.abs()).collect())
            };
            let t = Transform { curve, colour: Some(rotation(a)), weight: None };
            t.validate(3).unwrap();
            let z = t.forward_all(&x, 3, &g, &[true]);
            let mut y = [0.0; 3];
            let mut back = [0f32; 3];
            t.inverse_cell(&z, &mut y, 1.0, &mut back);
            for k in 0..3 {
                let tol = 1e-5 * (x[k].abs() + e as f32) + 1e-6;
                prop_assert!((back[k] - x[k]).abs() <= tol);
                let v = t.curve.inverse_f32(t.curve.forward(x[k] as f64, k) as f32, k);
                prop_assert!((v - x[k]).abs() <= tol, "{} vs {}", v, x[k]);
            }
        }

        /// Forward then inverse with the cosine weight on random values of every grid kind:
        /// x comes back to f64 rounding before the f32 store (relative 1e-5 of ε/w + x, the
        /// log curve's ε being in weighted units), at grazing cells too, and never non-finite.
        #[test]
        fn weighted_transform_round_trips(
            kind in 0usize..4, seed in any::<u64>(), log in any::<bool>(), a in -3.0f64..3.0,
            e in 1e-6f64..1.0,
        ) {
            let spec = ["halfdiff3:5x6x7,warp=sqrt/linear/linear,at=edge",
                        "halfdiff4:3x4x5x6", "spherical3:6x5x4,theta-max=85",
                        "spherical4:4x3x5x2,at=edge"][kind];
            let g = crate::grid::parse_grid_spec(spec).unwrap();
            let valid = g.geometric_mask();
            let mut rng = crate::math::SplitMix64::new(seed);
            let x: Vec<f32> = (0..g.cells() * 3)
                .map(|_| (rng.next_f64() * 16.0 - 8.0).exp() as f32)
                .collect();
            let curve = if log { Curve::Log { eps: vec![e; 3] } } else { Curve::Linear };
            let t = Transform { curve, colour: Some(rotation(a)), weight: Some(Weight::Cosine) };
            let z = t.forward_all(&x, 3, &g, &valid);
            let w = t.cell_weights(&g, &valid).unwrap();
            let mut y = [0.0; 3];
            let mut back = [0f32; 3];
            for (f, &ok) in valid.iter().enumerate() {
                if !ok {
                    continue;
                }
                t.inverse_cell(&z[f * 3..f * 3 + 3], &mut y, w.at(f), &mut back);
                let floor = if log { e / w.at(f) } else { 0.0 };
                for k in 0..3 {
                    let (b, want) = (back[k] as f64, x[f * 3 + k] as f64);
                    prop_assert!(b.is_finite());
                    prop_assert!((b - want).abs() <= 1e-5 * (want + floor) + 1e-30,
                        "{spec} cell {f} w {}: {b} vs {want}", w.at(f));
                }
            }
        }
    }
}
