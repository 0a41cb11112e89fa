//! The decoders as they were before the fast paths (docs/compression.md, issue 5): a generic
//! stencil walk for the predictors, a dense f32 matrix product per axis for the DCT, libm `exp`
//! per value. Kept as the reference that the fast decoders are tested against (bit for bit
//! for the lossless chains, within a stated tolerance for the lossy ones) and benchmarked
//! beside (`cargo bench --bench codec`). Not part of the public interface.

use super::predict::{self, Predictor};
use super::transform::{Transform, finite_f32};
use super::{CodecSpec, Layout, dct};
use crate::{Error, Result};

/// The decoder of every chain as it was: same checks, same output.
pub fn decode(spec: &CodecSpec, payload: &[u8], layout: &Layout) -> Result<Vec<f32>> {
    spec.validate(layout)?;
    let values = layout.values()?;
    let c = layout.channels;
    let dims = layout.dims();
    let n_valid = layout.valid.iter().filter(|&&v| v).count();
    match spec {
        CodecSpec::ZstdF32 { level } => {
            let want = values
                .checked_mul(4)
                .ok_or_else(|| Error::input("table too large"))?;
            let raw = super::Zstd { level: *level }.decompress(payload, want)?;
            Ok(raw
                .chunks_exact(4)
                .map(|b| f32::from_le_bytes([b[0], b[1], b[2], b[3]]))
                .collect())
        }
        CodecSpec::Lossless {
            predict, entropy, ..
        } => {
            let raw = entropy.decompress(payload, n_valid * c * 4)?;
            let res = predict::unshuffle(&raw)?;
            reconstruct_f32(predict, &res, layout, &dims)
        }
        CodecSpec::Quantized {
            transform,
            quantize,
            predict,
            entropy,
            ..
        } => {
            let raw = entropy.decompress(payload, n_valid * c * 4)?;
            let res = predict::unshuffle(&raw)?;
            let codes = predict.reconstruct_i32(&res, &layout.shape(&dims))?;
            let w = transform.cell_weights(layout.grid, layout.valid);
            let mut out = vec![0f32; values];
            let mut z = vec![0.0; c];
            let mut y = vec![0.0; c];
            for (cell, &ok) in layout.valid.iter().enumerate() {
                if ok {
                    for k in 0..c {
                        z[k] = quantize.decode(codes[cell * c + k], k);
                    }
                    let wf = w.as_ref().map_or(1.0, |w| w.at(cell));
                    transform.inverse_cell(&z, &mut y, wf, &mut out[cell * c..(cell + 1) * c]);
                }
            }
            Ok(out)
        }
        CodecSpec::Dct { transform, .. }
        | CodecSpec::DctContext { transform, .. }
        | CodecSpec::Tucker { transform, .. } => {
            let planes = match spec.residual() {
                None => lossy_planes(spec, payload, layout)?,
                Some(res) => {
                    let (lossy, section) = super::residual::split(payload)?;
                    let mut planes = lossy_planes(spec, lossy, layout)?;
                    res.add(section, &mut planes, &layout.shape(&dims))?;
                    planes
                }
            };
            Ok(inverse_planes(transform, &planes, layout, c))
        }
    }
}

/// The component planes of the lossy section of a DCT or Tucker chain, by the old expansions.
fn lossy_planes(spec: &CodecSpec, lossy: &[u8], layout: &Layout) -> Result<Vec<Vec<f32>>> {
    let values = layout.values()?;
    let c = layout.channels;
    let dims = layout.dims();
    match spec {
        CodecSpec::Dct {
            dct: stage,
            entropy,
            ..
        } => {
            let cap = values
                .checked_mul(5)
                .and_then(|v| v.checked_add(10 * c * dims.len() + 16))
                .ok_or_else(|| Error::input("table too large"))?;
            let raw = entropy.decompress_capped(lossy, cap)?;
            let comps = dct::deserialize(&raw, &dims, c)?;
            Ok(comps
                .iter()
                .zip(&stage.step)
                .map(|(q, &s)| dct_inverse(q, &dims, s))
                .collect())
        }
        CodecSpec::DctContext {
            dct: stage, coding, ..
        } => {
            let comps = super::coefcode::decode(lossy, &dims, c, coding.model)?;
            Ok(comps
                .iter()
                .zip(&stage.step)
                .map(|(q, &s)| dct_inverse(q, &dims, s))
                .collect())
        }
        CodecSpec::Tucker {
            tucker: stage,
            entropy,
            ..
        } => {
            // The f64 reference of the f32 expansion, rounded to f32 once at the end.
            let comps = super::tucker_components(lossy, &dims, stage, entropy)?;
            Ok(comps
                .iter()
                .zip(&stage.step)
                .map(|(q, &s)| {
                    super::tucker::inverse_f64(q, &dims, s)
                        .iter()
                        .map(|&v| v as f32)
                        .collect()
                })
                .collect())
        }
        _ => Err(Error::Failure(
            "reference: only DCT and Tucker chains have lossy planes".into(),
        )),
    }
}

fn reconstruct_f32(
    p: &Predictor,
    res: &[u32],
    layout: &Layout,
    dims: &[usize],
) -> Result<Vec<f32>> {
    p.reconstruct_f32(res, &layout.shape(dims))
}

/// out[o][i][x] = Σ_j mat[i][j] · in[o][j][x] along `axis` (mat is m × dims[axis]).
fn apply_axis(input: &[f32], dims: &[usize], axis: usize, mat: &[f32], m: usize) -> Vec<f32> {
    let n = dims[axis];
    let outer: usize = dims[..axis].iter().product();
    let inner: usize = dims[axis + 1..].iter().product();
    let mut out = vec![0f32; outer * m * inner];
    for (o, dst) in out.chunks_mut(m * inner).enumerate() {
        let src = &input[o * n * inner..(o + 1) * n * inner];
        if inner == 1 {
            for (i, d) in dst.iter_mut().enumerate() {
                let row = &mat[i * n..(i + 1) * n];
                let mut s = 0f32;
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
    }
    out
}

/// The old `dct::inverse`: dense expansion, last axis first.
pub fn dct_inverse(c: &dct::Coefficients, dims: &[usize], step: f64) -> Vec<f32> {
    let cells: usize = dims.iter().product();
    if c.codes.is_empty() {
        return vec![0.0; cells];
    }
    let mut cur: Vec<f32> = c.codes.iter().map(|&q| (q as f64 * step) as f32).collect();
    let mut cur_dims = c.extent.clone();
    for a in (0..dims.len()).rev() {
        let n = dims[a];
        let k = c.extent[a];
        let full = dct::dct_matrix(n);
        let mat: Vec<f32> = (0..n)
            .flat_map(|i| (0..k).map(move |kk| (i, kk)))
            .map(|(i, kk)| full[kk * n + i] as f32)
            .collect();
        cur = apply_axis(&cur, &cur_dims, a, &mat, n);
        cur_dims[a] = n;
    }
    cur
}

/// Component planes → cell-major channels through the inverse transform, libm `exp`, a
/// division by the weight in f64.
fn inverse_planes(t: &Transform, planes: &[Vec<f32>], layout: &Layout, c: usize) -> Vec<f32> {
    let valid = layout.valid;
    let w = t.cell_weights(layout.grid, valid);
    let cells = valid.len();
    let mut out = vec![0f32; cells * c];
    let m: Option<Vec<f32>> = t
        .colour
        .as_ref()
        .map(|col| col.matrix.iter().map(|&x| x as f32).collect());
    let mut z = vec![0f32; c];
    for (f, &ok) in valid.iter().enumerate() {
        if !ok {
            continue;
        }
        for k in 0..c {
            z[k] = planes[k][f];
        }
        let o = &mut out[f * c..(f + 1) * c];
        for (k, ok) in o.iter_mut().enumerate() {
            let y = match &m {
                Some(m) => (0..c).map(|i| m[i * c + k] * z[i]).sum::<f32>(),
                None => z[k],
            };
            *ok = match &w {
                Some(w) => finite_f32(t.curve.inverse_f32(y, k) as f64 / w.at(f)),
                None => t.curve.inverse_f32(y, k),
            };
        }
    }
    out
}
