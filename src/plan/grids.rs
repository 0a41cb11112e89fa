//! The default grid of a source: the grid `pack` starts from when the user gives none
//! ([`super::pack`] refines it from there when the budget asks for more).

use crate::brdf::Brdf;
use crate::grid::GridDesc;
use crate::table::Table;
use rayon::prelude::*;

/// The default grid of a source: its symmetries at about MERL's resolution — `halfdiff4:64`
/// with a grazing θd warp for anisotropic sources, `spherical3:90x90x180` for isotropic
/// non-reciprocal ones (measured data), and for the others MERL's 90×90×180 half/difference
/// grid extended below the horizon ([`crate::grid::Horizon::Extend`]) with the same θd warp.
/// Cut at the horizon, the queries beside it carried most of a narrow peak's error; extended,
/// the rest sat in MERL's last θd step (89°–90°, beyond its last sample), which the warp
/// brings to 0.011° (both measured in docs/parameterizations.md). On the 64⁴ grid the last
/// centred θd sample sat at 89.3°, and one pair at θd 89.58° made Ward 0.1×0.3 miss the
/// production budget on one seed in ten; with the warp it holds on all ten. A sampled source
/// (a MERL file: [`Brdf::is_sampled`]) keeps MERL's grid, its own: on another grid its
/// interpolation adds to the new grid's (`pack gold-metallic-paint.binary --grid` with the
/// models' default: 109,152 B, against 28,290 B on its own), and so does a source seen within
/// θmax (the y60 scene of docs/build.md: 1,637 → 3,524 B). The 64⁴ anisotropic grid stays cut:
/// extended, its files grew (`pack 'ggx:alpha_x=0.05,alpha_y=0.3,fresnel=au' --max-error
/// preview --grid halfdiff4:64[,horizon=extend]`: 5,188 → 8,196 B), and Ward's f, which grows
/// without bound toward the horizon, is farther from its continuation there.
pub fn default_grid_spec(src: &dyn Brdf) -> &'static str {
    if !src.is_isotropic() {
        "halfdiff4:64,warp=linear/linear/grazing/linear"
    } else if !src.is_reciprocal() {
        "spherical3:90x90x180"
    } else if src.is_sampled() || src.theta_max_deg().is_some() {
        // A sampled source's own grid; a source seen within θmax has no horizon in its
        // domain (a scene's θ ≤ 60°: the grazing θd samples fall outside it).
        "merl"
    } else {
        "halfdiff3:90x90x180,warp=sqrt/grazing/linear,at=edge,horizon=extend"
    }
}

/// The default grid of a source ([`default_grid_spec`]), stored up to the source's own θmax
/// when it has one: a table kept within θ ≤ 60° has no values beyond, and on the whole
/// hemisphere the grid's cells there were filled from the nearest valid sample, which the
/// source (0 beyond its domain) then measured as a relative error of 10⁴ — `pack t60.bpk`
/// of a table `tabulate` wrote refused every budget after 35 s of trying finer grids.
pub fn default_grid(src: &dyn Brdf) -> crate::Result<crate::grid::Grid> {
    within_source_domain(crate::grid::parse_grid_spec(default_grid_spec(src))?, src)
}

/// The grid `tabulate`, `convert` and `compress` store a source on when none is given: MERL's
/// for an isotropic reciprocal source (as these commands always did), else the planner's
/// default ([`default_grid`]): an RGL file is not reciprocal, and MERL's reciprocity fold of
/// φd refused it (exit 2) until the user named a grid.
pub fn table_default_grid(src: &dyn Brdf) -> crate::Result<crate::grid::Grid> {
    if src.is_isotropic() && src.is_reciprocal() {
        Ok(crate::grid::Grid::merl())
    } else {
        default_grid(src)
    }
}

/// `grid` stored only up to `src`'s θmax when the source has one (the smaller of the two
/// limits; `check` compares within both domains the same way).
pub fn within_source_domain(
    grid: crate::grid::Grid,
    src: &dyn Brdf,
) -> crate::Result<crate::grid::Grid> {
    let Some(t) = src.theta_max_deg() else {
        return Ok(grid);
    };
    let mut d = grid.desc();
    d.theta_max_deg = Some(d.theta_max_deg.map_or(t, |g| g.min(t)));
    crate::grid::Grid::from_desc(&d)
}

/// Per axis, the share of a table's interpolation error that the axis's spacing causes: the
/// solid-angle-weighted mean of the squared second difference, along that axis, of
/// y = asinh(f̄/`scale`) (f̄ the cell's channel mean).
///
/// Linear interpolation between samples h apart misses a smooth y by about h²·y''/8 at
/// the midpoint, and y's second difference along the axis is h²·y'': the squared second
/// differences are each axis's share of the squared interpolation error, up to a common
/// factor. An axis with twice the samples has a quarter of the second difference (a
/// sixteenth of its share); one with half, sixteen times the share. In y the shares are
/// relative errors for values above `scale` (the metrics' ε or the grid's log scale), as the
/// relative metrics and `log_rmse` of a bright value see them; weighting by each cell's
/// solid angle makes them the uniform pairs' error. Each share is over the valid cells of the
/// lines read (a cell whose two neighbours along the axis are not both valid adds 0); every
/// fourth line along each axis is read (an estimate, and a
/// quarter of the cost: a 64⁴ grid in a fraction of a second).
pub fn axis_curvature(table: &Table, scale: f64) -> Vec<f64> {
    let grid = table.grid();
    let dims = grid.shape();
    let d = dims.len();
    let c = table.channels().len().max(1);
    let data = table.data();
    let valid = table.valid();
    let factors = grid.cell_measure_factors();
    let cells = grid.cells();
    if cells == 0 || data.len() != cells * c || !(scale > 0.0 && scale.is_finite()) {
        return vec![0.0; d];
    }
    let y = |cell: usize| -> f64 {
        let v = &data[cell * c..cell * c + c];
        let mean = v.iter().map(|&x| x as f64).sum::<f64>() / c as f64;
        (mean / scale).asinh()
    };
    let mut strides = vec![1usize; d];
    for k in (0..d.saturating_sub(1)).rev() {
        strides[k] = strides[k + 1] * dims[k + 1];
    }
    const EVERY: usize = 4;
    const CHUNK: usize = 256;
    let mut shares = Vec::with_capacity(d);
    for k in 0..d {
        let n = dims[k];
        let inner = strides[k];
        let lines = cells / n;
        let periodic = grid.axes()[k].is_periodic();
        let line_ids: Vec<usize> = (0..lines).step_by(EVERY).collect();
        let parts: Vec<(f64, f64)> = line_ids
            .par_chunks(CHUNK)
            .map(|ids| {
                let mut ys = vec![0.0f64; n];
                let (mut sum, mut weight) = (0.0, 0.0);
                for &l in ids {
                    let base = (l / inner) * n * inner + l % inner;
                    // The measure of the line's other axes; cell i's is this × factors[k][i].
                    let line_measure: f64 = (0..d)
                        .filter(|&j| j != k)
                        .map(|j| factors[j][(base / strides[j]) % dims[j]])
                        .product();
                    for (i, yi) in ys.iter_mut().enumerate() {
                        *yi = y(base + i * inner);
                    }
                    for i in 0..n {
                        let cell = base + i * inner;
                        if !valid[cell] {
                            continue;
                        }
                        let m = line_measure * factors[k][i];
                        weight += m;
                        let (lo, hi) = if periodic {
                            ((i + n - 1) % n, (i + 1) % n)
                        } else if i == 0 || i + 1 == n {
                            continue;
                        } else {
                            (i - 1, i + 1)
                        };
                        if n < 3 || !valid[base + lo * inner] || !valid[base + hi * inner] {
                            continue;
                        }
                        let d2 = ys[hi] - 2.0 * ys[i] + ys[lo];
                        if d2.is_finite() {
                            sum += m * d2 * d2;
                        }
                    }
                }
                (sum, weight)
            })
            .collect();
        let sum: f64 = parts.iter().map(|p| p.0).sum();
        let weight: f64 = parts.iter().map(|p| p.1).sum();
        shares.push(if weight > 0.0 { sum / weight } else { 0.0 });
    }
    shares
}

/// The same cells spent better: the axis `a` to double and `b` to halve that
/// [`axis_curvature`]'s shares predict to lower the interpolation error the most, with the
/// predicted ratio of the new squared error to the old. `None` when no exchange is predicted
/// to help or no axis can be halved (an axis keeps at least 8 samples).
pub fn reallocation(grid: &GridDesc, shares: &[f64]) -> Option<(usize, usize, f64)> {
    let total: f64 = shares.iter().sum();
    if !(total > 0.0 && total.is_finite()) || shares.len() != grid.axes.len() {
        return None;
    }
    let mut best: Option<(usize, usize, f64)> = None;
    for a in 0..shares.len() {
        for b in 0..shares.len() {
            let n_b = grid.axes[b].n;
            if a == b || !n_b.is_multiple_of(2) || n_b / 2 < 8 {
                continue;
            }
            let after = total - shares[a] - shares[b] + shares[a] / 16.0 + 16.0 * shares[b];
            let ratio = after / total;
            if ratio < 1.0 && best.is_none_or(|(_, _, r)| ratio < r) {
                best = Some((a, b, ratio));
            }
        }
    }
    best
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::grid::parse_grid_spec;
    use crate::model::Model;

    /// A table of y = asinh(f/scale) = q(θ) on spherical3, every cell valid.
    fn table_of(spec: &str, scale: f64, q: impl Fn(f64) -> f64) -> Table {
        let grid = parse_grid_spec(spec).unwrap();
        let theta = grid.axes()[0].clone();
        let inner: usize = grid.shape()[1..].iter().product();
        let data: Vec<f32> = (0..grid.cells())
            .map(|cell| (scale * q(theta.sample(cell / inner)).sinh()) as f32)
            .collect();
        let valid = vec![true; grid.cells()];
        let channels = crate::brdf::Channels::default_for(1);
        Table::new(grid, channels, Default::default(), data, valid).unwrap()
    }

    #[test]
    fn the_curvature_is_the_axis_that_varies_and_falls_as_the_fourth_power_of_the_spacing() {
        let scale = 1e-3;
        let q = |t: f64| 3.0 * t * t;
        let coarse = axis_curvature(&table_of("spherical3:16x8x12", scale, q), scale);
        let fine = axis_curvature(&table_of("spherical3:32x8x12", scale, q), scale);
        // Only θi varies: the other axes' second differences are exactly 0.
        assert_eq!(&coarse[1..], &[0.0, 0.0]);
        assert_eq!(&fine[1..], &[0.0, 0.0]);
        // y'' = 6, h = (π/2)/n: each interior cell's (h²y'')², weighted by the share of the
        // measure inside the ends; twice the samples, a sixteenth (up to the ends' share and
        // f32 rounding of the values).
        let h = std::f64::consts::FRAC_PI_2 / 16.0;
        let full = (6.0 * h * h).powi(2);
        assert!(
            coarse[0] > 0.8 * full && coarse[0] < 1.001 * full,
            "{} vs {full}",
            coarse[0]
        );
        let ratio = coarse[0] / fine[0];
        assert!((ratio - 16.0).abs() < 1.0, "{ratio}");
    }

    #[test]
    fn an_exchange_doubles_the_axis_with_the_most_curvature_and_halves_the_least() {
        let grid = parse_grid_spec("halfdiff4:64").unwrap().desc();
        let (a, b, ratio) = reallocation(&grid, &[0.015, 0.128, 6e-5, 0.0]).unwrap();
        assert_eq!((a, b), (1, 3));
        let want = (0.015 + 0.128 / 16.0 + 6e-5) / (0.015 + 0.128 + 6e-5);
        assert!((ratio - want).abs() < 1e-12, "{ratio} vs {want}");
        // Even shares: any exchange makes it worse.
        assert_eq!(reallocation(&grid, &[1.0; 4]), None);
        // An axis with 8 samples is not halved.
        let narrow = parse_grid_spec("halfdiff4:64x64x64x8").unwrap().desc();
        let (_, b, _) = reallocation(&narrow, &[0.015, 0.128, 6e-5, 0.0]).unwrap();
        assert_eq!(b, 2);
    }

    #[test]
    fn default_grids_follow_the_source_symmetries() {
        const ISOTROPIC: &str =
            "halfdiff3:90x90x180,warp=sqrt/grazing/linear,at=edge,horizon=extend";
        for (m, want) in [
            ("ggx:alpha=0.2", ISOTROPIC),
            ("lambert", ISOTROPIC),
            (
                "ward:alpha_x=0.1,alpha_y=0.3",
                "halfdiff4:64,warp=linear/linear/grazing/linear",
            ),
        ] {
            let model = Model::parse(m).unwrap();
            let spec = default_grid_spec(&model);
            assert_eq!(spec, want, "{m}");
            parse_grid_spec(spec).unwrap();
        }
        // A sampled source keeps MERL's grid (its own, for a MERL file).
        let g = parse_grid_spec("halfdiff3:6x6x8").unwrap();
        let t = crate::tabulate::tabulate(
            &Model::parse("ggx:alpha=0.2").unwrap(),
            &g,
            &Default::default(),
        )
        .unwrap();
        let sampled = crate::table::InterpolatedTable {
            table: t,
            interp: crate::table::Interp::Linear,
        };
        assert_eq!(default_grid_spec(&sampled), "merl");
    }
}
