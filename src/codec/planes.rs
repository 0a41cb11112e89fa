//! What the encoders and the planner read from a table: the transformed component planes
//! (invalid cells filled), their DCT coefficients, the curve and colour transform derived from
//! the table's values, and the best predictor.

use super::*;

/// The forward DCT coefficients of every transformed component of `table` (invalid cells
/// filled first). Exposed so the search can quantize one transform at many steps.
pub fn dct_coefficients(table: &Table, transform: &Transform) -> Result<Vec<Vec<f64>>> {
    let dims = table.grid().shape();
    // One plane at a time: its coefficients replace it (the planes of every component at
    // once were another 2× the f32 table of f64 beside the coefficients).
    Ok((0..table.channels().len())
        .map(|k| dct::forward_owned(filled_plane(table, transform, k), &dims))
        .collect())
}

/// The DCT coefficients of [`dct_coefficients`], each plane checked against its step
/// ([`dct::check_range`]) and quantized by `quantize(coefficients, k)` as soon as it is made:
/// the f64 coefficients of one plane are held at a time, not those of every plane.
pub fn quantized_dct_planes(
    table: &Table,
    transform: &Transform,
    steps: &[f64],
    quantize: impl Fn(&[f64], usize) -> dct::Coefficients,
) -> Result<Vec<dct::Coefficients>> {
    let dims = table.grid().shape();
    (0..table.channels().len())
        .map(|k| {
            let p = dct::forward_owned(filled_plane(table, transform, k), &dims);
            dct::check_range(&p, steps[k])?;
            Ok(quantize(&p, k))
        })
        .collect()
}

/// Plane `k` of [`filled_planes`], the same bits, made alone: the invalid cells of each
/// plane are filled from that plane only.
pub fn filled_plane(table: &Table, transform: &Transform, k: usize) -> Vec<f64> {
    let mut planes = [vec![0.0; table.grid().cells()]];
    transform_into(table, transform, &mut planes, |_| k);
    let [plane] = planes;
    filled(table, plane)
}

/// `plane` (one of `table`'s grid) with its invalid cells filled ([`domain::fill_invalid`]).
fn filled<T: dct::PlaneValue>(table: &Table, plane: Vec<T>) -> Vec<T> {
    let mut planes = [plane];
    domain::fill_invalid(
        &mut planes,
        &table.grid().shape(),
        table.valid(),
        &fill_order(table.grid().kind()),
    );
    let [plane] = planes;
    plane
}

/// Every plane of [`filled_planes`] in f32 (each transformed value rounded once, the fill
/// copying them): for planes too large to hold in f64 beside their table
/// ([`super::dct::forward_owned_f32`]). Made in one pass (each cell's curve and colour once,
/// not once per plane) and filled plane by plane: the same values as [`filled_plane`] of each,
/// rounded.
pub fn filled_planes_f32(table: &Table, transform: &Transform) -> Vec<Vec<f32>> {
    let c = table.channels().len();
    let mut planes = vec![vec![0f32; table.grid().cells()]; c];
    transform_into(table, transform, &mut planes, |k| k);
    fill_each(table, planes)
}

/// Each of `planes` (of `table`'s grid) with its invalid cells filled
/// ([`domain::fill_invalid`]), in parallel: each plane's fill is its own, so the same values
/// as one after the other (a 64⁴ RGB table's three took 1.1 s in a row).
fn fill_each(table: &Table, mut planes: Vec<Vec<f32>>) -> Vec<Vec<f32>> {
    use rayon::prelude::*;
    planes
        .par_iter_mut()
        .for_each(|p| *p = filled(table, std::mem::take(p)));
    planes
}

/// [`filled_planes_f32`] made in the table's own samples' memory: `samples` are the table's
/// (taken out with `Table::lend_samples`; `table` gives the grid and validity). Each cell's
/// values are replaced by its transformed components, then the last component is copied
/// out as a plane and the others packed closer in the samples, whose tail is given back,
/// until the samples hold the first plane: at most the table and one plane are held, not
/// the table and every plane (a 64⁴ RGB table's 201 MB and 134 MB more). The same bits as
/// `filled_planes_f32`.
///
/// # Panics
/// When `samples` is not the table's size (a caller bug).
pub fn filled_planes_f32_in_place(
    table: &Table,
    transform: &Transform,
    mut samples: Vec<f32>,
) -> Vec<Vec<f32>> {
    use rayon::prelude::*;
    const CHUNK: usize = 1 << 14;
    let c = table.channels().len();
    let cells = table.grid().cells();
    assert_eq!(samples.len(), cells * c, "the table's samples");
    let weights = transform.cell_weights(table.grid(), table.valid());
    samples.par_chunks_mut(CHUNK * c).enumerate().for_each_init(
        || (vec![0.0; c], vec![0.0; c], vec![0f32; c]),
        |(y, z, x), (i, chunk)| {
            for (j, v) in chunk.chunks_exact_mut(c).enumerate() {
                let f = i * CHUNK + j;
                let wf = weights.as_ref().map_or(1.0, |w| w.at(f));
                x.copy_from_slice(v);
                transform.forward_cell(x, wf, y, z);
                for (v, &z) in v.iter_mut().zip(z.iter()) {
                    *v = z as f32;
                }
            }
        },
    );
    drop(weights);
    let mut planes: Vec<Vec<f32>> = Vec::with_capacity(c);
    for k in (1..c).rev() {
        // Components 0..=k interleaved: take k out, pack 0..k closer (each cell's values move
        // to lower addresses, in ascending order, so none is overwritten before it is read).
        let width = k + 1;
        let plane: Vec<f32> = samples.iter().skip(k).step_by(width).copied().collect();
        for f in 0..cells {
            for j in 0..k {
                samples[f * k + j] = samples[f * width + j];
            }
        }
        samples.truncate(cells * k);
        samples.shrink_to_fit();
        planes.push(plane);
    }
    planes.push(samples);
    planes.reverse();
    fill_each(table, planes)
}

/// `planes[i]` = component `component(i)` of every cell's transform (curve, weight, colour),
/// the values [`Transform::for_each_cell`] visits. Each cell's transform is its own: made in
/// parallel chunks (their logs were most of a 64⁴ RGB plane's time on one core).
fn transform_into<T: dct::PlaneValue>(
    table: &Table,
    transform: &Transform,
    planes: &mut [Vec<T>],
    component: impl Fn(usize) -> usize + Sync,
) {
    use rayon::prelude::*;
    const CHUNK: usize = 1 << 14;
    let c = table.channels().len();
    let cells = table.grid().cells();
    let weights = transform.cell_weights(table.grid(), table.valid());
    let data = table.data();
    let mut per_chunk: Vec<Vec<&mut [T]>> = (0..cells.div_ceil(CHUNK))
        .map(|_| Vec::with_capacity(planes.len()))
        .collect();
    for p in planes.iter_mut() {
        for (i, ch) in p.chunks_mut(CHUNK).enumerate() {
            per_chunk[i].push(ch);
        }
    }
    per_chunk.into_par_iter().enumerate().for_each_init(
        || (vec![0.0; c], vec![0.0; c]),
        |(y, z), (i, mut outs)| {
            let n = outs.first().map_or(0, |o| o.len());
            for j in 0..n {
                let f = i * CHUNK + j;
                let wf = weights.as_ref().map_or(1.0, |w| w.at(f));
                transform.forward_cell(&data[f * c..(f + 1) * c], wf, y, z);
                for (p, out) in outs.iter_mut().enumerate() {
                    out[j] = T::narrow(z[component(p)]);
                }
            }
        },
    );
}

/// The transformed component planes with the invalid cells filled ([`domain::fill_invalid`]):
/// what the DCT and Tucker stages decompose.
pub fn filled_planes(table: &Table, transform: &Transform) -> Vec<Vec<f64>> {
    let dims = table.grid().shape();
    let mut planes = component_planes(table, transform);
    domain::fill_invalid(
        &mut planes,
        &dims,
        table.valid(),
        &fill_order(table.grid().kind()),
    );
    planes
}

/// The DCT coefficients for a context-coded spec: with `Domain::FillRefined` the invalid
/// cells are refilled `iterations` times with the decoded table of the quantized coefficients
/// (at these `steps` and dead zone), which makes the filled table cheaper to code; otherwise
/// as [`dct_coefficients`].
pub fn dct_coefficients_for(
    table: &Table,
    transform: &Transform,
    domain: Domain,
    steps: &[f64],
    coding: &coefcode::ContextCoding,
) -> Result<Vec<Vec<f64>>> {
    let Domain::FillRefined { iterations } = domain else {
        return dct_coefficients(table, transform);
    };
    let dims = table.grid().shape();
    let mut planes = component_planes(table, transform);
    let order = fill_order(table.grid().kind());
    domain::fill_refined(
        &mut planes,
        &dims,
        table.valid(),
        &order,
        iterations,
        |k, p| {
            let q = coefcode::quantize_deadzone(
                &dct::forward(p, &dims),
                &dims,
                steps[k],
                coding.deadzone,
            );
            dct::inverse(&q, &dims, steps[k])
        },
    );
    Ok(planes.iter().map(|p| dct::forward(p, &dims)).collect())
}

/// The relaxation the rate control's refined fill makes its pass with
/// ([`refine_coefficients_f32`]): each invalid cell moves this share of the way from its
/// value to what the quantized coefficients decode it to. A relaxed alternating projection
/// (λ in (0, 2); Youla & Webb 1982) goes further per pass than the plain one (λ = 1): on 25
/// NBRDF fits of MERL materials at both budgets, λ = 1.5 made production files a median 0.943
/// of λ = 1's (0.906–1.002; black-phenolic 29,798 → 27,685 B) and preview files 1.000
/// (0.91–1.04), about what a second plain pass gives (0.947) without its cost; λ = 1.75 gained
/// no more (0.942) and spread wider.
pub const FILL_RELAXATION: f32 = 1.5;

/// `iterations` passes of the refined fill ([`Domain::FillRefined`]) made on the f32 DCT
/// coefficients `coef` of one plane filled by [`domain::fill_invalid`], in their own memory
/// and one plane at a time (the f64 planes of every component, the refined fill's cost
/// before, added 70 MB to a MERL-grid encode): each pass decodes the coefficients quantized
/// at `step` with `deadzone`, moves the invalid cells of the plane (the plane again by the
/// exact inverse transform) `relaxation` of the way to the decode's values (1: to them;
/// [`FILL_RELAXATION`]), and transforms it again.
pub fn refine_coefficients_f32(
    mut coef: Vec<f32>,
    dims: &[usize],
    valid: &[bool],
    step: f64,
    deadzone: f64,
    iterations: u32,
    relaxation: f32,
) -> Vec<f32> {
    if valid.iter().all(|&v| v) {
        return coef;
    }
    for _ in 0..iterations {
        let decoded = dct::inverse(
            &coefcode::quantize_deadzone(&coef, dims, step, deadzone),
            dims,
            step,
        );
        let mut plane = dct::inverse_owned_f32(coef, dims);
        for ((v, &ok), &x) in plane.iter_mut().zip(valid).zip(&decoded) {
            if !ok {
                *v += relaxation * (x - *v);
            }
        }
        drop(decoded);
        coef = dct::forward_owned_f32(plane, dims);
    }
    coef
}

/// The values of `plane` at the invalid cells of `valid`, in cell order: what the fill put
/// there before the DCT, kept for [`refine_coefficients_from_fill`].
pub fn fill_of<T: dct::PlaneValue>(plane: &[T], valid: &[bool]) -> Vec<f32> {
    plane
        .iter()
        .zip(valid)
        .filter(|&(_, &ok)| !ok)
        .map(|(&v, _)| v.widen() as f32)
        .collect()
}

/// [`refine_coefficients_f32`] of a plane whose invalid cells' values before its DCT are
/// `fill` ([`fill_of`]): a pass changes only those cells, so by linearity the new
/// coefficients are `coef` plus the DCT of the change, and the plane itself (an inverse DCT
/// of every coefficient, two fifths of a pass on the MERL grid) is not made again. The valid
/// cells keep their exact values instead of the inverse transform's f32 rounding of them.
#[allow(clippy::too_many_arguments)]
pub fn refine_coefficients_from_fill(
    mut coef: Vec<f32>,
    dims: &[usize],
    valid: &[bool],
    fill: &[f32],
    step: f64,
    deadzone: f64,
    iterations: u32,
    relaxation: f32,
) -> Vec<f32> {
    if fill.is_empty() {
        return coef;
    }
    let mut fill = fill.to_vec();
    for _ in 0..iterations {
        let decoded = dct::inverse(
            &coefcode::quantize_deadzone(&coef, dims, step, deadzone),
            dims,
            step,
        );
        let mut change = decoded;
        let mut at = fill.iter_mut();
        for (d, &ok) in change.iter_mut().zip(valid) {
            if ok {
                *d = 0.0;
            } else if let Some(v) = at.next() {
                let moved = relaxation * (*d - *v);
                *v += moved;
                *d = moved;
            }
        }
        let change = dct::forward_owned_f32(change, dims);
        for (c, d) in coef.iter_mut().zip(&change) {
            *c += d;
        }
    }
    coef
}

/// The transformed table as one plane per component (cell-major data → planes).
pub(super) fn component_planes(table: &Table, transform: &Transform) -> Vec<Vec<f64>> {
    let c = table.channels().len();
    let cells = table.grid().cells();
    let mut planes = vec![vec![0.0; cells]; c];
    transform.for_each_cell(table.data(), c, table.grid(), table.valid(), |f, z| {
        for (p, &v) in planes.iter_mut().zip(z) {
            p[f] = v;
        }
    });
    planes
}

/// The curve for a table: ε_c = eps_rel × the channel's mean over valid cells (falling back
/// to the pooled mean, then 1e-6, so that ε is never 0 for a black channel). With a weight,
/// the mean is that of w·x, the quantity the curve is applied to: ε keeps its meaning (the
/// level below which the coded quantity needs no relative precision).
pub fn curve_for(table: &Table, req: CurveRequest, weight: Option<Weight>) -> Curve {
    match req {
        CurveRequest::Linear => Curve::Linear,
        CurveRequest::Log { eps_rel } | CurveRequest::SignedLog { eps_rel } => {
            let signed = matches!(req, CurveRequest::SignedLog { .. });
            let c = table.channels().len();
            let w = weight.map(|w| w.cells(table.grid(), table.valid()));
            let mut sum = vec![0.0f64; c];
            let mut n = 0usize;
            for (cell, &ok) in table.valid().iter().enumerate() {
                if ok {
                    n += 1;
                    let wf = w.as_ref().map_or(1.0, |w| w.at(cell));
                    for (k, s) in sum.iter_mut().enumerate() {
                        let x = table.data()[cell * c + k];
                        *s += wf * if signed { x.abs() } else { x.max(0.0) } as f64;
                    }
                }
            }
            let pooled = sum.iter().sum::<f64>() / (n.max(1) * c) as f64;
            let eps = sum
                .iter()
                .map(|s| {
                    let m = s / n.max(1) as f64;
                    let e = eps_rel * if m > 0.0 { m } else { pooled };
                    if e > 0.0 && e.is_finite() { e } else { 1e-6 }
                })
                .collect();
            if signed {
                Curve::SignedLog { eps }
            } else {
                Curve::Log { eps }
            }
        }
    }
}

/// Weight and curve plus (for several channels) the KLT of the weighted, curved channels.
pub fn transform_for(
    table: &Table,
    req: CurveRequest,
    colour: bool,
    weight: Option<Weight>,
) -> Transform {
    transform_with_curve(table, curve_for(table, req, weight), colour, weight)
}

/// Bytes of transformed values [`transform_with_curve`] collects for the KLT (64 MiB): above
/// it, they are made again for each of its passes.
const KLT_SAMPLES_HELD: usize = 64 << 20;

/// Weight and a given curve plus (for several channels, when `colour`) the KLT of the
/// weighted, curved channels: the planner derives ε itself ([`crate::plan::rate`]).
pub fn transform_with_curve(
    table: &Table,
    curve: Curve,
    colour: bool,
    weight: Option<Weight>,
) -> Transform {
    transform_with_curve_held(table, curve, colour, weight, true)
}

/// [`transform_with_curve`], the KLT's samples held only when `hold` (and they fit under
/// [`KLT_SAMPLES_HELD`]); otherwise made again for each of its two passes: the same bits,
/// without the 27 MB of the MERL grid beside what the caller holds.
pub fn transform_with_curve_held(
    table: &Table,
    curve: Curve,
    colour: bool,
    weight: Option<Weight>,
    hold: bool,
) -> Transform {
    let c = table.channels().len();
    let colour = if colour && c > 1 {
        let t = Transform {
            curve: curve.clone(),
            colour: None,
            weight,
        };
        let valid = table.valid();
        // The valid cells' transformed values, collected (27 MB in f64 on the MERL grid), or
        // made again for each of the KLT's two passes when that would be larger than the
        // table (249 MB for a 64⁴ RGB one): the same rows in the same order, the same bits.
        let rows = |row: &mut dyn FnMut(&[f64])| {
            t.for_each_cell(table.data(), c, table.grid(), valid, |f, z| {
                if valid[f] {
                    row(z);
                }
            })
        };
        if hold && table.valid_count() * c * 8 <= KLT_SAMPLES_HELD {
            let mut samples = Vec::with_capacity(table.valid_count() * c);
            rows(&mut |z| samples.extend_from_slice(z));
            Some(Colour::klt(&samples, c))
        } else {
            Some(Colour::klt_of_rows(c, &rows))
        }
    } else {
        None
    };
    Transform {
        curve,
        colour,
        weight,
    }
}

/// The predictor with the smallest estimated coded size (order-0 entropy of the residual byte
/// planes) among [`predict::candidates`].
///
/// The candidates are scored in parallel, each from histograms filled as its residuals are
/// made (a candidate's residuals were a table-sized array, made 20 times one after another:
/// 40% of a MERL-grid lossless encode); the first smallest in candidate order wins, as in a
/// serial scan.
pub fn best_predictor(data: &[f32], shape: &Shape, d: usize) -> Result<Predictor> {
    use rayon::prelude::*;
    let scored: Vec<(f64, Predictor)> = predict::candidates(d, shape.channels)
        .into_par_iter()
        .map(|p| Ok((p.entropy_bits_f32(data, shape)?, p)))
        .collect::<Result<_>>()?;
    let mut best: Option<(f64, Predictor)> = None;
    for (bits, p) in scored {
        if best.as_ref().is_none_or(|(b, _)| bits < *b) {
            best = Some((bits, p));
        }
    }
    best.map(|(_, p)| p)
        .ok_or_else(|| Error::Failure("no predictor candidates".into()))
}
