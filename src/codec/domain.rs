//! Stage (1), domain: which cells carry information. The validity mask is implied by the grid
//! (or stored in the file's MASK section), so invalid cells cost no bytes: sample codecs skip
//! them; transform codecs fill them with a smooth extension before transforming (the decoder
//! knows the mask and writes 0 there).

use super::dct::PlaneValue;
use serde::{Deserialize, Serialize};

#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Domain {
    /// Only valid cells are coded.
    DropInvalid,
    /// Invalid cells are filled by constant extension of the nearest valid sample along each
    /// axis in turn (cheap for a DCT: its implied boundary is an even reflection), then coded.
    FillInvalid,
    /// Encoder only (decodes like `FillInvalid`: the decoder writes 0 to invalid cells): fill
    /// as `FillInvalid`, then `iterations` times replace the invalid cells with the table the
    /// quantized coefficients decode to. Each pass moves the fill towards values whose
    /// transform has fewer significant coefficients (alternating projections: Youla & Webb
    /// 1982), so the same step codes fewer bytes.
    FillRefined { iterations: u32 },
}

/// Largest `refine=N` accepted (each pass costs a forward and an inverse transform).
pub const MAX_REFINE: u32 = 20;

/// Fills invalid cells of component-planar `planes` (each plane one value per cell) in place:
/// along the axes in `axis_order`, every invalid cell of a line that has known cells takes the
/// nearest known value of that line; cells still unknown at the end take the plane's mean.
pub fn fill_invalid<T: PlaneValue>(
    planes: &mut [Vec<T>],
    dims: &[usize],
    valid: &[bool],
    axis_order: &[usize],
) {
    let cells: usize = dims.iter().product();
    if cells == 0 {
        return;
    }
    // One bit a cell (2 MB on a 64⁴ grid; a copy of the mask was 16.8 MB at the encoder's
    // peak).
    let mut known = CellBits::of(valid);
    let strides = super::dct::c_strides(dims);
    let mut line: Vec<usize> = Vec::new();
    let mut nearest: Vec<usize> = Vec::new();
    for &a in axis_order {
        let n = dims[a];
        let st = strides[a];
        // The lines along a start at o·n·st + x, x < st, in increasing order.
        for start in (0..cells / (n * st)).flat_map(|o| (0..st).map(move |x| o * n * st + x)) {
            line.clear();
            line.extend((0..n).map(|i| start + i * st));
            if line.iter().all(|&f| known.get(f)) || !line.iter().any(|&f| known.get(f)) {
                continue;
            }
            // Nearest known index to each position (ties to the lower one).
            nearest.clear();
            nearest.resize(n, usize::MAX);
            let mut last = None;
            for i in 0..n {
                if known.get(line[i]) {
                    last = Some(i);
                }
                if let Some(l) = last {
                    nearest[i] = l;
                }
            }
            let mut next = None;
            for i in (0..n).rev() {
                if known.get(line[i]) {
                    next = Some(i);
                }
                if let Some(nx) = next
                    && (nearest[i] == usize::MAX || nx - i < i - nearest[i])
                {
                    nearest[i] = nx;
                }
            }
            for i in 0..n {
                let f = line[i];
                if !known.get(f) {
                    for p in planes.iter_mut() {
                        p[f] = p[line[nearest[i]]];
                    }
                    // Marked known at once (no copy of the mask per axis): the lines along
                    // one axis are disjoint, and this line's nearest known cells were all
                    // found above.
                    known.set(f);
                }
            }
        }
    }
    if (0..cells).any(|f| !known.get(f)) {
        for p in planes.iter_mut() {
            let (s, m) = p
                .iter()
                .enumerate()
                .filter(|(f, _)| known.get(*f))
                .fold((0.0, 0usize), |(s, m), (_, v)| (s + v.widen(), m + 1));
            let mean = T::narrow(if m > 0 { s / m as f64 } else { 0.0 });
            for (f, v) in p.iter_mut().enumerate() {
                if !known.get(f) {
                    *v = mean;
                }
            }
        }
    }
}

/// One bit per cell.
pub(crate) struct CellBits(Vec<u64>);

impl CellBits {
    pub(crate) fn of(valid: &[bool]) -> CellBits {
        let mut bits = vec![0u64; valid.len().div_ceil(64)];
        for (f, _) in valid.iter().enumerate().filter(|(_, v)| **v) {
            bits[f / 64] |= 1 << (f % 64);
        }
        CellBits(bits)
    }
    #[inline]
    pub(crate) fn get(&self, f: usize) -> bool {
        self.0[f / 64] >> (f % 64) & 1 == 1
    }
    #[inline]
    fn set(&mut self, f: usize) {
        self.0[f / 64] |= 1 << (f % 64);
    }
}

/// [`fill_invalid`], then `iterations` passes of: `reconstruct(k, plane)` (the plane as the
/// decoder would see it after lossy coding) copied into the invalid cells of plane k. Valid
/// cells are never changed.
pub fn fill_refined<F>(
    planes: &mut [Vec<f64>],
    dims: &[usize],
    valid: &[bool],
    axis_order: &[usize],
    iterations: u32,
    reconstruct: F,
) where
    F: Fn(usize, &[f64]) -> Vec<f32> + Sync,
{
    use rayon::prelude::*;
    fill_invalid(planes, dims, valid, axis_order);
    if valid.iter().all(|&v| v) {
        return;
    }
    // The components refine independently of each other: in parallel, same result.
    planes.par_iter_mut().enumerate().for_each(|(k, p)| {
        for _ in 0..iterations {
            let r = reconstruct(k, p);
            for ((v, &ok), &x) in p.iter_mut().zip(valid).zip(&r) {
                if !ok {
                    *v = x as f64;
                }
            }
        }
    });
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn refined_fill_keeps_valid_cells_and_moves_towards_the_reconstruction() {
        let dims = [1, 6];
        let valid = [true, true, true, false, false, false];
        let mut planes = vec![vec![1.0, 2.0, 3.0, 0.0, 0.0, 0.0]];
        // A stand-in for "decode(encode(plane))": x/2 + 1 everywhere.
        let codec = |_k: usize, p: &[f64]| -> Vec<f32> {
            p.iter().map(|x| (0.5 * x + 1.0) as f32).collect()
        };
        fill_refined(&mut planes, &dims, &valid, &[1, 0], 0, codec);
        assert_eq!(planes[0], vec![1.0, 2.0, 3.0, 3.0, 3.0, 3.0]);
        // Two passes: 3 → 2.5 → 2.25 in the invalid cells only.
        fill_refined(&mut planes, &dims, &valid, &[1, 0], 2, codec);
        assert_eq!(planes[0], vec![1.0, 2.0, 3.0, 2.25, 2.25, 2.25]);
    }

    /// The refinement made on f32 coefficients keeps every valid cell (the plane its
    /// coefficients invert to is the original there) and codes the table in fewer bytes at
    /// the step it was made for: a smooth field whose invalid corner the plain fill extends
    /// with kinks.
    #[test]
    fn refined_coefficients_keep_valid_cells_and_code_in_fewer_bytes() {
        use crate::codec::{coefcode, dct};
        let dims = [24, 24, 16];
        let n: usize = dims.iter().product();
        let mut plane = vec![0f32; n];
        let mut valid = vec![true; n];
        for i in 0..dims[0] {
            for j in 0..dims[1] {
                for k in 0..dims[2] {
                    let f = (i * dims[1] + j) * dims[2] + k;
                    let (x, y, z) = (i as f64 / 23.0, j as f64 / 23.0, k as f64 / 15.0);
                    plane[f] = ((3.0 * x).sin() + (2.0 * y * z).cos() + 4.0 * x * y) as f32;
                    valid[f] = x + y < 1.3;
                }
            }
        }
        let mut planes = vec![plane.clone()];
        fill_invalid(&mut planes, &dims, &valid, &[0, 1, 2]);
        let plain = dct::forward_owned_f32(planes.pop().unwrap(), &dims);
        let (step, deadzone) = (0.02, 0.75);
        let bytes = |c: &[f32]| {
            coefcode::encode(&[coefcode::quantize_deadzone(c, &dims, step, deadzone)]).len()
        };
        // The plain passes and the relaxed ones the rate control makes.
        for relaxation in [1.0, crate::codec::FILL_RELAXATION] {
            let refined = crate::codec::refine_coefficients_f32(
                plain.clone(),
                &dims,
                &valid,
                step,
                deadzone,
                2,
                relaxation,
            );
            let back = dct::inverse_owned_f32(refined.clone(), &dims);
            for f in 0..n {
                if valid[f] {
                    assert!(
                        (back[f] - plane[f]).abs() < 1e-4,
                        "λ {relaxation}, cell {f}"
                    );
                }
            }
            assert!(
                bytes(&refined) < bytes(&plain),
                "λ {relaxation}: {} vs {}",
                bytes(&refined),
                bytes(&plain)
            );
        }
    }

    #[test]
    fn fills_by_nearest_along_the_first_axis_then_the_next() {
        // 2×4 grid; row 0 has one known cell, row 1 none.
        let dims = [2, 4];
        let valid = [false, true, false, false, false, false, false, false];
        let mut planes = vec![vec![0.0, 5.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0]];
        fill_invalid(&mut planes, &dims, &valid, &[1, 0]);
        assert_eq!(planes[0], vec![5.0; 8]);
        let valid = [true, false, false, true, false, false, false, false];
        let mut planes = vec![vec![1.0, 0.0, 0.0, 4.0, 0.0, 0.0, 0.0, 0.0]];
        fill_invalid(&mut planes, &dims, &valid, &[1, 0]);
        assert_eq!(planes[0], vec![1.0, 1.0, 4.0, 4.0, 1.0, 1.0, 4.0, 4.0]);
        // Nothing known: the mean (0) everywhere, no NaN.
        let mut planes = vec![vec![7.0; 8]];
        fill_invalid(&mut planes, &dims, &[false; 8], &[1, 0]);
        assert_eq!(planes[0], vec![0.0; 8]);
    }
}
