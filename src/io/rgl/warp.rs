//! The tables behind an RGL evaluation: the θi slice axis, plain bilinear grids (`ndf`,
//! `sigma`), the per-slice VNDF sample warp (Dupuy & Jakob 2018, §5; Mitsuba's
//! `Marginal2D<Float, 2, true>`) and the colour tables. Step numbers refer to
//! `spec/rgl-evaluation.md`, "Evaluation algorithm".

/// Which two θi slices a query blends, and with which weights (step 6).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SliceBlend {
    pub k0: usize,
    pub k1: usize,
    pub w0: f64,
    pub w1: f64,
}

/// How a query blends the slices of a table stored slice after slice: the θi slices of an
/// isotropic file ([`SliceBlend`]) or the (φi, θi) slices of an anisotropic one
/// ([`ParamBlend`]), as Mitsuba's `Marginal2D` interpolates its parameters.
pub trait Blend {
    /// Entry `i` of the blended slice, Σ w_s·T[k_s][i], of a table whose slices hold `len`
    /// values each.
    fn mix(&self, table: &[f32], len: usize, i: usize) -> f64;
}

impl Blend for SliceBlend {
    /// T̃ = w0·T[k0] + w1·T[k1].
    #[inline]
    fn mix(&self, table: &[f32], len: usize, i: usize) -> f64 {
        self.w0 * table[self.k0 * len + i] as f64 + self.w1 * table[self.k1 * len + i] as f64
    }
}

/// The four (φi, θi) slices an anisotropic file's query blends, bilinearly in the two
/// parameters; slices are stored φi-major ([φi][θi], the file's layout).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ParamBlend {
    k: [usize; 4],
    w: [f64; 4],
}

impl ParamBlend {
    /// The product of a φi blend and a θi blend over `n_theta` θi slices.
    pub fn new(phi: SliceBlend, theta: SliceBlend, n_theta: usize) -> ParamBlend {
        let at = |p: usize, t: usize| p * n_theta + t;
        ParamBlend {
            k: [
                at(phi.k0, theta.k0),
                at(phi.k0, theta.k1),
                at(phi.k1, theta.k0),
                at(phi.k1, theta.k1),
            ],
            w: [
                phi.w0 * theta.w0,
                phi.w0 * theta.w1,
                phi.w1 * theta.w0,
                phi.w1 * theta.w1,
            ],
        }
    }
}

impl Blend for ParamBlend {
    #[inline]
    fn mix(&self, table: &[f32], len: usize, i: usize) -> f64 {
        let t = |s: usize| self.w[s] * table[self.k[s] * len + i] as f64;
        t(0) + t(1) + t(2) + t(3)
    }
}

/// A slice parameter axis, `theta_i` (or `phi_i` of an anisotropic file): finite, strictly
/// increasing, at least one value.
#[derive(Clone, Debug)]
pub struct ThetaAxis {
    values: Vec<f64>,
}

impl ThetaAxis {
    /// Wraps values already checked to be finite and strictly increasing.
    pub fn new(values: Vec<f64>) -> ThetaAxis {
        debug_assert!(!values.is_empty() && values.windows(2).all(|w| w[0] < w[1]));
        ThetaAxis { values }
    }

    pub fn values(&self) -> &[f64] {
        &self.values
    }

    /// Step 6: the interval k with a[k] < q ≤ a[k+1] (first a[j] ≥ q, j in 1..N−1, k = j − 1)
    /// and w1 = clamp((q − a[k])/(a[k+1] − a[k]), 0, 1).
    #[inline]
    pub fn locate(&self, q: f64) -> SliceBlend {
        let a = &self.values;
        let n = a.len();
        if n == 1 {
            return SliceBlend {
                k0: 0,
                k1: 0,
                w0: 1.0,
                w1: 0.0,
            };
        }
        // partition_point counts the leading a[j] < q; searching a[1..n−1] gives j − 1 = k.
        let k = a[1..n - 1].partition_point(|&v| v < q);
        // Clamped: beyond the last θi the last slice is used unchanged (constant
        // extrapolation), below the first the first slice; the weight never exceeds [0, 1].
        let w1 = ((q - a[k]) / (a[k + 1] - a[k])).clamp(0.0, 1.0);
        SliceBlend {
            k0: k,
            k1: k + 1,
            w0: 1.0 - w1,
            w1,
        }
    }
}

/// One axis of `n ≥ 2` equally spaced samples over [0, 1], with the constants of its cell
/// lookup precomputed at load time.
#[derive(Clone, Copy, Debug)]
struct Axis {
    /// n − 1 as f64: the number of cells.
    cells: f64,
    /// n − 2: the last cell's index.
    last: u32,
}

impl Axis {
    /// `n` is at least 2 and at most the file size / 4, so it fits in u32.
    fn new(n: usize) -> Axis {
        debug_assert!((2..=u32::MAX as usize).contains(&n));
        Axis {
            cells: (n - 1) as f64,
            last: (n - 2) as u32,
        }
    }

    /// Cell index and fraction: X = clamp(u, 0, 1)·(n − 1), i = min(⌊X⌋, n − 2), f = X − i
    /// (steps 7–9).
    #[inline]
    fn cell(self, u: f64) -> (usize, f64) {
        // Rounding can put a coordinate a hair outside [0, 1]; the tables end there.
        let x = u.clamp(0.0, 1.0) * self.cells;
        // x ≥ 0, so truncation is the floor (and a NaN, impossible for finite inputs,
        // would become cell 0 rather than an out-of-range index).
        let i = (x as u32).min(self.last);
        (i as usize, x - i as f64)
    }
}

/// a + t·(b − a), the spec's lerp.
#[inline]
fn lerp(a: f64, b: f64, t: f64) -> f64 {
    a + t * (b - a)
}

/// A bilinearly interpolated W×H grid over [0, 1]² (columns x, rows y), used as stored
/// (`ndf`, `sigma`: step 9).
#[derive(Clone, Debug)]
pub struct Grid2 {
    width: usize,
    x: Axis,
    y: Axis,
    data: Vec<f32>,
    /// False when all rows are equal (the isotropic `ndf` and `sigma`): then y is irrelevant.
    varies_along_y: bool,
}

impl Grid2 {
    /// `data` is row-major [height][width]; both sizes are at least 2 (checked by the caller).
    pub fn new(width: usize, height: usize, data: Vec<f32>) -> Grid2 {
        debug_assert!(width >= 2 && height >= 2 && data.len() == width * height);
        let varies_along_y = data.chunks_exact(width).any(|row| row != &data[..width]);
        Grid2 {
            width,
            x: Axis::new(width),
            y: Axis::new(height),
            data,
            varies_along_y,
        }
    }

    /// The stored values, row-major.
    pub fn values(&self) -> &[f32] {
        &self.data
    }

    /// Whether the value depends on y at all.
    pub fn varies_along_y(&self) -> bool {
        self.varies_along_y
    }

    /// Bilinear value at u = (x, y).
    #[inline]
    pub fn eval(&self, u: [f64; 2]) -> f64 {
        let (i, fx) = self.x.cell(u[0]);
        let row = |j: usize| {
            let r = &self.data[j * self.width + i..][..2];
            lerp(r[0] as f64, r[1] as f64, fx)
        };
        if !self.varies_along_y {
            // Equal rows: lerp(a, a, fy) = a exactly, so row 0 alone is bit-identical.
            return row(0);
        }
        let (j, fy) = self.y.cell(u[1]);
        lerp(row(j), row(j + 1), fy)
    }
}

/// The VNDF sample warp of every θi slice: normalised densities D, conditional (row) CDFs C
/// and marginal CDFs G, built as Mitsuba's `Marginal2D` does at load time and stored in
/// float32 as Mitsuba stores them.
#[derive(Clone, Debug)]
pub struct VndfWarp {
    width: usize,
    height: usize,
    x: Axis,
    y: Axis,
    /// D_s[y][x], slice after slice.
    density: Vec<f32>,
    /// C_s[y][x], x < W − 1, slice after slice.
    conditional_cdf: Vec<f32>,
    /// G_s[y], y < H − 1, slice after slice.
    marginal_cdf: Vec<f32>,
}

impl VndfWarp {
    /// Load time (spec "Load time: build the VNDF warp"): `vndf` holds `slices` grids of
    /// H×W (H, W ≥ 2) finite, non-negative values. Errors (as a message) when a slice has no mass.
    pub fn build(
        vndf: &[f32],
        slices: usize,
        height: usize,
        width: usize,
    ) -> Result<VndfWarp, String> {
        debug_assert!(width >= 2 && height >= 2 && vndf.len() == slices * width * height);
        let (w, h) = (width, height);
        let mut density = Vec::with_capacity(vndf.len());
        let mut conditional_cdf = Vec::with_capacity(slices * h * (w - 1));
        let mut marginal_cdf = Vec::with_capacity(slices * (h - 1));
        let mut c = vec![0.0f64; h * (w - 1)];
        let mut g = vec![0.0f64; h - 1];
        for s in 0..slices {
            let d = &vndf[s * w * h..(s + 1) * w * h];
            // c[y][x] = Σ_{x'≤x} (d[y][x'] + d[y][x'+1]) · 0.5/(W−1)   (row CDF, trapezoid, f64)
            for y in 0..h {
                let mut sum = 0.0f64;
                for x in 0..w - 1 {
                    sum += (d[y * w + x] as f64 + d[y * w + x + 1] as f64) * 0.5 / (w - 1) as f64;
                    c[y * (w - 1) + x] = sum;
                }
            }
            // g[y] = Σ_{y'≤y} (c[y'][W−2] + c[y'+1][W−2]) · 0.5/(H−1)   (marginal CDF, f64)
            let row_total = |y: usize| c[y * (w - 1) + w - 2];
            let mut sum = 0.0f64;
            for (y, g_y) in g.iter_mut().enumerate() {
                sum += (row_total(y) + row_total(y + 1)) * 0.5 / (h - 1) as f64;
                *g_y = sum;
            }
            let total = g[h - 2];
            // A slice without mass cannot be normalised (Mitsuba would divide by zero).
            if !(total > 0.0 && total.is_finite()) {
                return Err(format!(
                    "θi slice {s} integrates to {total}, expected a positive finite mass"
                ));
            }
            // norm = float32(1/g[H−2]); D = d·norm, C = float32(c)·norm, G = float32(g)·norm,
            // each product rounded to float32 as Mitsuba stores them.
            let norm = (1.0 / total) as f32;
            // A mass below ~3e-39 has no float32 reciprocal; the tables would become Inf.
            if !norm.is_finite() {
                return Err(format!(
                    "θi slice {s} integrates to {total}, too small to normalise in float32"
                ));
            }
            density.extend(d.iter().map(|&v| v * norm));
            conditional_cdf.extend(c.iter().map(|&v| v as f32 * norm));
            marginal_cdf.extend(g.iter().map(|&v| v as f32 * norm));
        }
        Ok(VndfWarp {
            width,
            height,
            x: Axis::new(width),
            y: Axis::new(height),
            density,
            conditional_cdf,
            marginal_cdf,
        })
    }

    /// Step 7: the sample point (sx, sy) that the forward warp of the blended slice maps to
    /// `u` (clamped to [0, 1]²).
    #[inline]
    pub fn invert<B: Blend>(&self, u: [f64; 2], blend: &B) -> [f64; 2] {
        let (w, h) = (self.width, self.height);
        let (i, fx) = self.x.cell(u[0]);
        let (j, fy) = self.y.cell(u[1]);
        let d = |y: usize, x: usize| blend.mix(&self.density, w * h, y * w + x);
        let c = |y: usize, x: usize| blend.mix(&self.conditional_cdf, h * (w - 1), y * (w - 1) + x);
        let (v00, v10) = (d(j, i), d(j, i + 1));
        let (v01, v11) = (d(j + 1, i), d(j + 1, i + 1));
        // Density along the row at y, at the cell's two columns.
        let c0 = lerp(v00, v01, fy);
        let c1 = lerp(v10, v11, fy);
        // Integral over the partial cell, then the full cells to the left.
        let mut sx = fx * lerp(c0, c1, fx / 2.0) / self.x.cells;
        if i > 0 {
            sx += lerp(c(j, i - 1), c(j + 1, i - 1), fy);
        }
        // Row totals; dividing makes the conditional CDF reach 1 at the row's end.
        let r0 = c(j, w - 2);
        let r1 = c(j + 1, w - 2);
        let row_total = lerp(r0, r1, fy);
        // A row without density has no conditional distribution; its left edge is as good
        // as any point and keeps NaN out of the lookup (never happens for measured files).
        sx = if row_total > 0.0 { sx / row_total } else { 0.0 };
        // Marginal: partial cell, then the CDF below (already normalised to end at 1).
        let mut sy = fy * lerp(r0, r1, fy / 2.0) / self.y.cells;
        if j > 0 {
            sy += blend.mix(&self.marginal_cdf, h - 1, j - 1);
        }
        [sx, sy]
    }
}

/// Per-slice colour tables (`rgb` or `spectra`) over the warped sample square, stored
/// [slice][y][x][channel] so that one lookup reads each corner's channels contiguously.
#[derive(Clone, Debug)]
pub struct ColourTables {
    width: usize,
    height: usize,
    x: Axis,
    y: Axis,
    channels: usize,
    data: Vec<f32>,
}

impl ColourTables {
    /// From the file's [slice][channel][y][x] layout (sizes ≥ 2 checked by the caller).
    pub fn from_planar(
        planar: &[f32],
        slices: usize,
        channels: usize,
        height: usize,
        width: usize,
    ) -> ColourTables {
        debug_assert_eq!(planar.len(), slices * channels * height * width);
        let plane = height * width;
        let mut data = vec![0.0f32; planar.len()];
        for s in 0..slices {
            for ch in 0..channels {
                let src = &planar[(s * channels + ch) * plane..][..plane];
                for (p, &v) in src.iter().enumerate() {
                    data[(s * plane + p) * channels + ch] = v;
                }
            }
        }
        ColourTables {
            width,
            height,
            x: Axis::new(width),
            y: Axis::new(height),
            channels,
            data,
        }
    }

    /// Step 8: bilinear lookup at `sample` of the slice-blended tables, one value per
    /// channel written into `out` (length = channel count).
    #[inline]
    pub fn lookup<B: Blend>(&self, sample: [f64; 2], blend: &B, out: &mut [f64]) {
        let (w, nc) = (self.width, self.channels);
        let (i, fx) = self.x.cell(sample[0]);
        let (j, fy) = self.y.cell(sample[1]);
        let len = w * self.height * nc;
        // Corners (i, j) and (i + 1, j) are adjacent, as are (i, j + 1) and (i + 1, j + 1).
        let (lo, hi) = ((j * w + i) * nc, ((j + 1) * w + i) * nc);
        for (ch, o) in out.iter_mut().enumerate().take(nc) {
            let m = |at: usize| blend.mix(&self.data, len, at + ch);
            let bottom = lerp(m(lo), m(lo + nc), fx);
            let top = lerp(m(hi), m(hi + nc), fx);
            *o = lerp(bottom, top, fy);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn locate_follows_the_strict_left_predicate_and_clamps() {
        let axis = ThetaAxis::new(vec![0.0, 1.0, 3.0]);
        // a[k] < q ≤ a[k+1]: q = 1 lies in interval 0 with weight 1.
        assert_eq!(
            axis.locate(1.0),
            SliceBlend {
                k0: 0,
                k1: 1,
                w0: 0.0,
                w1: 1.0
            }
        );
        assert_eq!(
            axis.locate(2.0),
            SliceBlend {
                k0: 1,
                k1: 2,
                w0: 0.5,
                w1: 0.5
            }
        );
        assert_eq!(axis.locate(9.0).w1, 1.0);
        assert_eq!(axis.locate(9.0).k0, 1);
        assert_eq!(
            axis.locate(-1.0),
            SliceBlend {
                k0: 0,
                k1: 1,
                w0: 1.0,
                w1: 0.0
            }
        );
        let one = ThetaAxis::new(vec![0.5]);
        assert_eq!(
            one.locate(0.1),
            SliceBlend {
                k0: 0,
                k1: 0,
                w0: 1.0,
                w1: 0.0
            }
        );
    }

    #[test]
    fn uniform_warp_is_the_identity() {
        let warp = VndfWarp::build(&[3.0; 4 * 5], 1, 4, 5).unwrap();
        let blend = ThetaAxis::new(vec![0.0]).locate(0.0);
        for &u in &[[0.0, 0.0], [0.3, 0.7], [1.0, 1.0], [0.999, 0.01]] {
            let s = warp.invert(u, &blend);
            assert!(
                (s[0] - u[0]).abs() < 1e-6 && (s[1] - u[1]).abs() < 1e-6,
                "{u:?} {s:?}"
            );
        }
    }

    #[test]
    fn linear_density_inverts_to_its_cdf() {
        // d(x, y) = 1 + x: the conditional CDF is (x + x²/2)/1.5 exactly, the marginal uniform.
        let (w, h) = (6, 3);
        let vndf: Vec<f32> = (0..w * h)
            .map(|p| 1.0 + (p % w) as f32 / (w - 1) as f32)
            .collect();
        let warp = VndfWarp::build(&vndf, 1, h, w).unwrap();
        let blend = ThetaAxis::new(vec![0.0]).locate(0.0);
        for &x in &[0.0, 0.13, 0.5, 0.77, 1.0] {
            let s = warp.invert([x, 0.4], &blend);
            let want = (x + x * x / 2.0) / 1.5;
            assert!((s[0] - want).abs() < 1e-6, "{x}: {} vs {want}", s[0]);
            assert!((s[1] - 0.4).abs() < 1e-6);
        }
    }

    #[test]
    fn grid_is_bilinear_and_clamped() {
        // f(x, y) = 1 + 2x + 3y + 4xy on a 3×2 grid: bilinear interpolation reproduces it.
        let f = |x: f64, y: f64| 1.0 + 2.0 * x + 3.0 * y + 4.0 * x * y;
        let data: Vec<f32> = (0..2)
            .flat_map(|y| (0..3).map(move |x| f(x as f64 / 2.0, y as f64) as f32))
            .collect();
        let g = Grid2::new(3, 2, data);
        assert!(g.varies_along_y());
        for &(x, y) in &[(0.0, 0.0), (0.3, 0.6), (0.5, 1.0), (1.0, 0.25), (0.9, 0.9)] {
            assert!((g.eval([x, y]) - f(x, y)).abs() < 1e-6, "{x} {y}");
        }
        // Outside [0, 1]² the edge values are used.
        assert_eq!(g.eval([-0.5, 2.0]), g.eval([0.0, 1.0]));
        assert_eq!(g.eval([1.5, -1.0]), g.eval([1.0, 0.0]));
        // Equal rows: y is ignored, with the same value as the full interpolation.
        let flat = Grid2::new(3, 2, vec![1.0, 2.0, 4.0, 1.0, 2.0, 4.0]);
        assert!(!flat.varies_along_y());
        assert_eq!(flat.eval([0.75, 0.3]), 3.0);
    }

    #[test]
    fn massless_slice_is_rejected() {
        assert!(VndfWarp::build(&[0.0; 4], 1, 2, 2).is_err());
    }
}
