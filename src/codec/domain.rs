//! Stage (1), domain: which cells carry information. The validity mask is implied by the grid
//! (or stored in the file's MASK section), so invalid cells cost no bytes: sample codecs skip
//! them; transform codecs fill them with a smooth extension before transforming (the decoder
//! knows the mask and writes 0 there).

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
pub fn fill_invalid(planes: &mut [Vec<f64>], dims: &[usize], valid: &[bool], axis_order: &[usize]) {
    let cells: usize = dims.iter().product();
    let mut known = valid.to_vec();
    let strides = super::dct::c_strides(dims);
    for &a in axis_order {
        let n = dims[a];
        let st = strides[a];
        let mut newly = known.clone();
        for start in 0..cells {
            // Only line starts: index along a is 0.
            if !(start / st).is_multiple_of(n) {
                continue;
            }
            let line: Vec<usize> = (0..n).map(|i| start + i * st).collect();
            if line.iter().all(|&f| known[f]) || !line.iter().any(|&f| known[f]) {
                continue;
            }
            // Nearest known index to each position (ties to the lower one).
            let mut nearest = vec![usize::MAX; n];
            let mut last = None;
            for i in 0..n {
                if known[line[i]] {
                    last = Some(i);
                }
                if let Some(l) = last {
                    nearest[i] = l;
                }
            }
            let mut next = None;
            for i in (0..n).rev() {
                if known[line[i]] {
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
                if !known[f] {
                    for p in planes.iter_mut() {
                        p[f] = p[line[nearest[i]]];
                    }
                    newly[f] = true;
                }
            }
        }
        known = newly;
    }
    if known.iter().any(|k| !k) {
        for p in planes.iter_mut() {
            let (s, m) = p
                .iter()
                .zip(&known)
                .filter(|(_, k)| **k)
                .fold((0.0, 0usize), |(s, m), (v, _)| (s + v, m + 1));
            let mean = if m > 0 { s / m as f64 } else { 0.0 };
            for (v, k) in p.iter_mut().zip(&known) {
                if !k {
                    *v = mean;
                }
            }
        }
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
