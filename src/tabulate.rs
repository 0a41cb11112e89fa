//! Sampling any [`Brdf`] onto a [`Grid`]: parallel, and deterministic (every cell is
//! computed independently, so the bytes do not depend on the thread count).

use crate::brdf::Brdf;
use crate::grid::{Grid, Horizon};
use crate::table::{Provenance, Table};
use crate::{Error, Result, TOOL_VERSION};
use structured::HalfdiffMicrofacet;

pub mod structured;
use rayon::prelude::*;

/// Options of [`tabulate`].
#[derive(Clone, Debug, Default)]
pub struct TabulateOptions {
    /// Allow an anisotropic source on an isotropic grid (φh is then fixed at 0; stated in the
    /// table's provenance).
    pub allow_anisotropic: bool,
    /// Allow a source that is not reciprocal on `halfdiff3`, whose φd fold assumes
    /// f(wi, wo) = f(wo, wi) (stated in the table's provenance).
    pub allow_nonreciprocal: bool,
    /// A table tabulated on its own grid keeps its holes (cells its geometry holds but its
    /// values do not: MERL's negative markers) as invalid cells, so that the new table
    /// evaluates as the source does; with this set they are filled with the source's
    /// interpolation at the node instead (no explicit mask to store, at the price of a
    /// table that differs from the source next to each hole; `pack` weighs the two).
    pub fill_own_holes: bool,
    /// Called with (cells done, cells in all) as the generic path advances; the CLI draws a
    /// bar from it on a terminal. The library never prints.
    pub progress: Option<CellProgress>,
}

/// A progress callback: (cells done, cells in all). Called from worker threads.
#[derive(Clone)]
pub struct CellProgress(pub std::sync::Arc<dyn Fn(u64, u64) + Send + Sync>);

impl std::fmt::Debug for CellProgress {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str("CellProgress")
    }
}

/// Cells per parallel work item: large enough to amortise scheduling, small enough to
/// balance 2–64 threads on a MERL-sized grid.
const CHUNK_CELLS: usize = 8192;

/// Tabulates `src` on `grid`. Cells whose sample pair is below the horizon or beyond θmax
/// are marked invalid (not silently 0).
pub fn tabulate(src: &dyn Brdf, grid: &Grid, opts: &TabulateOptions) -> Result<Table> {
    require_memory(src, grid)?;
    let mut table = Table::zeroed(grid.clone(), src.channels().clone());
    tabulate_into(src, grid, opts, &mut table)?;
    Ok(table)
}

/// Refuses a grid whose table (with the copies a command holds) exceeds the memory budget,
/// before anything is allocated: `--grid spherical4:215` is inside the axis limits but
/// needs ~10 GB per channel.
fn require_memory(src: &dyn Brdf, grid: &Grid) -> Result<()> {
    crate::memory::require_table(
        &format!(
            "a table of {} × {} channel(s)",
            grid.describe(),
            src.channels().len()
        ),
        grid.cells(),
        src.channels().len(),
    )
}

/// Like [`tabulate`], into an existing table whose allocation is reused when its size fits
/// (repeated tabulation, benchmarks). On error the table's contents are unspecified.
///
/// Microfacet models on half/difference grids take a fast path (`crate::tabulate::structured`)
/// that gives the generic path's values to ~1e-15 relative and the same validity.
pub fn tabulate_into(
    src: &dyn Brdf,
    grid: &Grid,
    opts: &TabulateOptions,
    table: &mut Table,
) -> Result<()> {
    require_memory(src, grid)?;
    let mut notes = Vec::new();
    if grid.kind().is_isotropic() && !src.is_isotropic() {
        if !opts.allow_anisotropic {
            return Err(Error::input(format!(
                "{} is anisotropic but grid {} can only hold isotropic BRDFs; use spherical4 or \
                 halfdiff4, or pass --allow-anisotropic to sample it at φh = 0 / φi = 0",
                src.describe(),
                grid.kind().name()
            )));
        }
        notes.push(format!(
            "anisotropic source sampled on isotropic grid {} (at φh = 0 / φi = 0)",
            grid.kind().name()
        ));
    }
    if grid.kind() == crate::grid::GridKind::Halfdiff3 && !src.is_reciprocal() {
        if !opts.allow_nonreciprocal {
            return Err(Error::input(format!(
                "{} is not reciprocal but grid halfdiff3 folds φd by reciprocity (f(wi, wo) = \
                 f(wo, wi)); use spherical3 (isotropic, no reciprocity fold) or halfdiff4, or \
                 pass --allow-nonreciprocal to store the value at φd mod π",
                src.describe()
            )));
        }
        notes.push(
            "source is not reciprocal; halfdiff3 stores it at φd mod π (the other half is lost)"
                .to_string(),
        );
    }
    notes.extend(src.provenance_notes());
    let provenance = Provenance {
        source: src.describe(),
        tool: TOOL_VERSION.to_string(),
        notes,
    };
    table.reset(grid, src.channels(), provenance);
    let (data, valid) = table.buffers_mut();
    if let Some(kernel) = src
        .as_any()
        .and_then(|a| a.downcast_ref::<crate::model::Model>())
        .and_then(|m| HalfdiffMicrofacet::new(m, grid))
        && tabulate_fast(&kernel, data, valid)
    {
        // The kernel fills the cells above the horizon; an extended grid's cells below it
        // take the generic path's values.
        if grid.horizon() == Horizon::Extend {
            return tabulate_generic(src, grid, opts, data, valid, Cells::BelowHorizon);
        }
        return Ok(());
    }
    tabulate_generic(src, grid, opts, data, valid, Cells::All)
}

/// The cells the generic path fills.
#[derive(Clone, Copy, PartialEq)]
enum Cells {
    All,
    /// Only those whose sample pair lies below the horizon (the rest are already filled).
    BelowHorizon,
}

/// The fast path: one work item per θh slab. False when a value does not fit in f32; the
/// generic path then reports the cell.
fn tabulate_fast(kernel: &HalfdiffMicrofacet, data: &mut [f32], valid: &mut [bool]) -> bool {
    let slab = kernel.slab_cells();
    let c = data.len() / valid.len().max(1);
    data.par_chunks_mut(slab * c)
        .zip(valid.par_chunks_mut(slab))
        .enumerate()
        .map_init(Vec::new, |factor: &mut Vec<f64>, (ih, (vals, ok))| {
            factor.resize(slab, 0.0);
            kernel.fill_slab(ih, vals, ok, factor)
        })
        .reduce(|| true, |a, b| a && b)
}

/// The generic path: every cell's directions (`Grid::cell_directions`, the bits of
/// `Grid::cell_dirs`) through `Brdf::eval`.
fn tabulate_generic(
    src: &dyn Brdf,
    grid: &Grid,
    opts: &TabulateOptions,
    data: &mut [f32],
    valid: &mut [bool],
    which: Cells,
) -> Result<()> {
    let c = src.channels().len();
    let cells = grid.cells();
    let d = grid.axes().len();
    let done = std::sync::atomic::AtomicU64::new(0);
    let dirs = grid.cell_directions();
    // Re-tabulating a MERL file on the MERL grid reads its samples.
    let own = Table::behind(src, grid);
    data.par_chunks_mut(CHUNK_CELLS * c)
        .zip(valid.par_chunks_mut(CHUNK_CELLS))
        .enumerate()
        .try_for_each(|(chunk, (vals, ok))| -> Result<()> {
            let mut idx = [0usize; 4];
            let mut buf = vec![0f64; c];
            let first = chunk * CHUNK_CELLS;
            for (j, okj) in ok.iter_mut().enumerate() {
                let cell = first + j;
                grid.unflatten(cell, &mut idx[..d]);
                let (wi, wo) = dirs.at(&idx[..d]);
                if which == Cells::BelowHorizon && wi.z > 0.0 && wo.z > 0.0 {
                    continue;
                }
                // The buffers may hold an earlier table: write every cell.
                *okj = false;
                vals[j * c..(j + 1) * c].fill(0.0);
                // Outside the source's stored domain (a θmax table re-gridded) there is
                // no value: invalid, not 0. Below the horizon of an extended grid, the
                // value of the pair raised to it.
                let Some((wi, wo)) = grid.value_pair(wi, wo) else {
                    continue;
                };
                if !src.in_domain(wi, wo) {
                    continue;
                }
                // A node of the source's own grid. Valid, the interpolation there is the
                // sample (up to the rounding of the node's indices, which this avoids).
                // Invalid (a hole of a measurement, MERL's negative marker), it stays a hole
                // unless `fill_own_holes`: its lookups interpolate the valid neighbours as
                // the source's own do, so the table is the source exactly; filled, it holds a
                // made-up sample that interpolates otherwise beside it.
                if let Some(t) = own {
                    if t.valid()[cell] {
                        vals[j * c..(j + 1) * c]
                            .copy_from_slice(&t.data()[cell * c..(cell + 1) * c]);
                        *okj = true;
                        continue;
                    }
                    if !opts.fill_own_holes {
                        continue;
                    }
                }
                src.eval(wi, wo, &mut buf);
                for (k, &v) in buf.iter().enumerate() {
                    let f = v as f32;
                    // The source's parameters are the user's: input at fault (exit 2).
                    if !f.is_finite() {
                        return Err(Error::Input(format!(
                            "{} gave {v:.4e} at cell {cell} (wi = {:?}, wo = {:?}), which f32 storage \
                             cannot hold",
                            src.describe(),
                            wi.to_array(),
                            wo.to_array()
                        )));
                    }
                    vals[j * c + k] = f;
                }
                *okj = true;
            }
            if let Some(p) = &opts.progress {
                let n = done.fetch_add(ok.len() as u64, std::sync::atomic::Ordering::Relaxed);
                (p.0)(n + ok.len() as u64, cells as u64);
            }
            Ok(())
        })?;
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::brdf::Channels;
    use crate::geometry::Vec3;
    use crate::grid::parse_grid_spec;
    use crate::table::{Interp, InterpolatedTable};

    /// A smooth, anisotropic, non-separable test BRDF (not a physical model).
    struct Smooth {
        ch: Channels,
    }
    impl Brdf for Smooth {
        fn channels(&self) -> &Channels {
            &self.ch
        }
        fn eval(&self, wi: Vec3, wo: Vec3, out: &mut [f64]) {
            if wi.z <= 0.0 || wo.z <= 0.0 {
                out.fill(0.0);
                return;
            }
            let h = (wi + wo).try_normalize().unwrap();
            out[0] = 0.2 + h.z * h.z + 0.3 * wi.z * wo.z;
            out[1] = 0.1 + 0.5 * (h.x * h.x) + 0.2 * wi.dot(wo);
        }
        fn is_isotropic(&self) -> bool {
            false
        }
        fn describe(&self) -> String {
            "smooth test BRDF".into()
        }
    }

    #[test]
    fn tables_reproduce_samples_and_converge() {
        let src = Smooth {
            ch: Channels::default_for(2),
        };
        for spec in ["halfdiff4:16", "spherical4:16"] {
            let g = parse_grid_spec(spec).unwrap();
            let t = tabulate(&src, &g, &TabulateOptions::default()).unwrap();
            // At its own samples the table returns the source (f32 storage).
            let mut idx = [0usize; 4];
            let mut a = [0.0; 2];
            let mut b = [0.0; 2];
            for f in (0..g.cells()).step_by(37) {
                g.unflatten(f, &mut idx);
                let (wi, wo) = g.cell_dirs(&idx);
                if !g.in_domain(wi, wo) {
                    continue;
                }
                src.eval(wi, wo, &mut a);
                t.eval_into(wi, wo, Interp::Linear, &mut b);
                for k in 0..2 {
                    assert!((a[k] - b[k]).abs() <= 1e-6 * a[k].abs(), "{spec} {f}");
                }
            }
        }
        // Error falls as resolution rises.
        let mut errs = Vec::new();
        for n in [8, 16, 32] {
            let g = parse_grid_spec(&format!("halfdiff4:{n}")).unwrap();
            let t = InterpolatedTable {
                table: tabulate(&src, &g, &TabulateOptions::default()).unwrap(),
                interp: Interp::Linear,
            };
            let mut rng = crate::math::SplitMix64::new(3);
            let mut e = 0.0;
            let mut a = [0.0; 2];
            let mut b = [0.0; 2];
            for _ in 0..2000 {
                let wi = Vec3::from_spherical(
                    rng.next_f64() * 1.4,
                    rng.next_f64() * std::f64::consts::TAU,
                );
                let wo = Vec3::from_spherical(
                    rng.next_f64() * 1.4,
                    rng.next_f64() * std::f64::consts::TAU,
                );
                src.eval(wi, wo, &mut a);
                t.eval(wi, wo, &mut b);
                e += (a[0] - b[0]).powi(2);
            }
            errs.push((e / 2000.0).sqrt());
        }
        assert!(
            errs[1] < errs[0] * 0.6 && errs[2] < errs[1] * 0.6,
            "{errs:?}"
        );
    }

    /// An extended grid's cells below the horizon hold the source at the pair raised to it;
    /// the cells above hold what the grid cut at the horizon holds, bit for bit.
    #[test]
    fn extended_cells_below_the_horizon_hold_the_raised_pair() {
        let src = Smooth {
            ch: Channels::default_for(2),
        };
        for spec in [
            "halfdiff4:9x8x10x12",
            "halfdiff4:7x6x9x10,warp=sqrt/linear/linear/linear,at=edge",
        ] {
            let cut = parse_grid_spec(spec).unwrap();
            let ext = parse_grid_spec(&format!("{spec},horizon=extend")).unwrap();
            let a = tabulate(&src, &cut, &TabulateOptions::default()).unwrap();
            let b = tabulate(&src, &ext, &TabulateOptions::default()).unwrap();
            let d = cut.axes().len();
            let mut idx = [0usize; 4];
            let mut want = [0.0; 2];
            let mut below = 0;
            for f in 0..cut.cells() {
                cut.unflatten(f, &mut idx[..d]);
                let (wi, wo) = cut.cell_dirs(&idx[..d]);
                assert!(b.valid()[f], "{spec}: cell {f}");
                if a.valid()[f] {
                    assert_eq!(a.cell(f), b.cell(f), "{spec}: cell {f}");
                    continue;
                }
                below += 1;
                let (ri, ro) = (
                    crate::grid::raised_to_horizon(wi),
                    crate::grid::raised_to_horizon(wo),
                );
                assert!(ri.z > 0.0 && ro.z > 0.0 && ri.z.min(ro.z) == crate::grid::HORIZON_COS);
                src.eval(ri, ro, &mut want);
                let got: Vec<f32> = want.iter().map(|&v| v as f32).collect();
                assert_eq!(b.cell(f), &got[..], "{spec}: cell {f}");
            }
            assert!(
                below > cut.cells() / 20,
                "{spec}: {below} cells below the horizon"
            );
        }
    }

    /// A table re-tabulated on its own grid is itself at its valid cells, bit for bit (the
    /// samples are copied, not interpolated at nodes whose indices round); the domain rules
    /// still apply (a valid cell below the horizon of a cut grid, as MERL files store, is
    /// invalid), and an invalid cell takes the table's interpolation there, as any source's
    /// value would be taken. On another grid the table is interpolated.
    #[test]
    fn a_table_tabulated_on_its_own_grid_is_itself() {
        let m = crate::model::Model::parse("lambert:albedo=0.05+ggx:alpha=0.1,fresnel=au").unwrap();
        let g = parse_grid_spec("halfdiff3:24x24x48,warp=sqrt/linear/linear,at=edge").unwrap();
        let mut t = tabulate(&m, &g, &Default::default()).unwrap();
        let (mut idx, c) = ([0usize; 3], 3);
        let (mut below, mut holes) = (Vec::new(), Vec::new());
        {
            let (data, valid) = t.buffers_mut();
            for cell in 0..g.cells() {
                g.unflatten(cell, &mut idx);
                let (wi, wo) = g.cell_dirs(&idx);
                if wi.z <= 0.0 || wo.z <= 0.0 {
                    // Below the horizon: valid, with a value only a copy would keep.
                    valid[cell] = true;
                    data[cell * c..(cell + 1) * c].fill(7.0);
                    below.push(cell);
                } else if cell % 97 == 5 {
                    valid[cell] = false;
                    holes.push(cell);
                }
            }
        }
        assert!(below.len() > 100 && holes.len() > 100);
        let src = InterpolatedTable {
            table: t.clone(),
            interp: Interp::Linear,
        };
        assert!(Table::behind(&src, &g).is_some());
        let again = tabulate(&src, &g, &Default::default()).unwrap();
        let filled = tabulate(
            &src,
            &g,
            &TabulateOptions {
                fill_own_holes: true,
                ..Default::default()
            },
        )
        .unwrap();
        let mut v = [0.0; 3];
        for cell in 0..g.cells() {
            let (a, b) = (
                &t.data()[cell * c..(cell + 1) * c],
                &again.data()[cell * c..(cell + 1) * c],
            );
            if below.contains(&cell) {
                assert!(!again.valid()[cell], "cell {cell} below the horizon");
            } else if holes.binary_search(&cell).is_ok() {
                // A hole stays one; filled, it holds the source's interpolation there.
                assert!(!again.valid()[cell], "hole {cell} kept");
                assert!(filled.valid()[cell], "hole {cell} filled");
                g.unflatten(cell, &mut idx);
                let (wi, wo) = g.cell_dirs(&idx);
                t.eval_into(wi, wo, Interp::Linear, &mut v);
                let want: Vec<f32> = v.iter().map(|&x| x as f32).collect();
                assert_eq!(
                    &filled.data()[cell * c..(cell + 1) * c],
                    &want[..],
                    "hole {cell}"
                );
            } else {
                assert!(again.valid()[cell], "cell {cell}");
                assert_eq!(
                    a.iter().map(|x| x.to_bits()).collect::<Vec<_>>(),
                    b.iter().map(|x| x.to_bits()).collect::<Vec<_>>(),
                    "cell {cell}"
                );
            }
        }
        // Another resolution, or the same axes with another interpolation space, is not the
        // table's grid.
        for other in [
            "halfdiff3:24x24x47,warp=sqrt/linear/linear,at=edge",
            "halfdiff3:24x24x48,warp=sqrt/linear/linear,at=edge,space=log:1e-3",
        ] {
            assert!(
                Table::behind(&src, &parse_grid_spec(other).unwrap()).is_none(),
                "{other}"
            );
        }
    }

    /// The reason for extending: beside the horizon a grid cut there reads only the valid
    /// corners, up to a θd step away. On a narrow gold peak over a dark body (log space,
    /// sqrt θh), the extended grid's log error over uniform pairs is far below the cut
    /// one's, and the queries with a corner below the horizon no longer carry most of it.
    #[test]
    fn extending_below_the_horizon_cuts_the_error_beside_it() {
        let m =
            crate::model::Model::parse("lambert:albedo=0.002+ggx:alpha=0.03,fresnel=au").unwrap();
        let spec = "halfdiff3:45x45x90,warp=sqrt/linear/linear,space=log:1e-4";
        let cut = tabulate(&m, &parse_grid_spec(spec).unwrap(), &Default::default()).unwrap();
        let ext = parse_grid_spec(&format!("{spec},horizon=extend")).unwrap();
        let ext = tabulate(&m, &ext, &Default::default()).unwrap();
        let set = crate::check::SampleSet::uniform(40_000, 11);
        let (mut e_cut, mut e_ext) = (0.0, 0.0);
        let (mut f, mut a, mut b) = ([0.0; 3], [0.0; 3], [0.0; 3]);
        for &(wi, wo) in &set.pairs {
            m.eval(wi, wo, &mut f);
            cut.eval_into(wi, wo, Interp::Linear, &mut a);
            ext.eval_into(wi, wo, Interp::Linear, &mut b);
            for k in 0..3 {
                e_cut += crate::check::log_error(f[k], a[k], wi.z).powi(2);
                e_ext += crate::check::log_error(f[k], b[k], wi.z).powi(2);
            }
        }
        let n = 3.0 * set.pairs.len() as f64;
        let (e_cut, e_ext) = ((e_cut / n).sqrt(), (e_ext / n).sqrt());
        eprintln!("log_rmse cut {e_cut:.4e}, extended {e_ext:.4e}");
        assert!(e_ext < 0.5 * e_cut, "cut {e_cut:.4e}, extended {e_ext:.4e}");
    }

    #[test]
    fn isotropic_grid_refuses_anisotropic_source() {
        let src = Smooth {
            ch: Channels::default_for(2),
        };
        let g = parse_grid_spec("halfdiff3:8").unwrap();
        let e = tabulate(&src, &g, &TabulateOptions::default()).unwrap_err();
        assert!(e.to_string().contains("anisotropic"));
        let t = tabulate(
            &src,
            &g,
            &TabulateOptions {
                allow_anisotropic: true,
                ..Default::default()
            },
        )
        .unwrap();
        assert_eq!(t.provenance().notes.len(), 1);
    }

    /// Reciprocal in nothing: f depends on wi only through wi.z and on wo through wo.x.
    struct OneWay(Channels);
    impl Brdf for OneWay {
        fn channels(&self) -> &Channels {
            &self.0
        }
        fn eval(&self, wi: Vec3, wo: Vec3, out: &mut [f64]) {
            out[0] = if wi.z > 0.0 && wo.z > 0.0 {
                1.0 + wi.z * 0.5
            } else {
                0.0
            };
        }
        fn is_isotropic(&self) -> bool {
            true
        }
        fn is_reciprocal(&self) -> bool {
            false
        }
        fn describe(&self) -> String {
            "one-way".into()
        }
    }

    #[test]
    fn reciprocity_fold_refuses_a_non_reciprocal_source() {
        let src = OneWay(Channels::default_for(1));
        let g = parse_grid_spec("halfdiff3:8").unwrap();
        let e = tabulate(&src, &g, &TabulateOptions::default()).unwrap_err();
        assert!(e.to_string().contains("not reciprocal"), "{e}");
        // No fold on spherical3 or halfdiff4: accepted.
        for spec in ["spherical3:8", "halfdiff4:6"] {
            tabulate(
                &src,
                &parse_grid_spec(spec).unwrap(),
                &TabulateOptions::default(),
            )
            .unwrap();
        }
        let opts = TabulateOptions {
            allow_nonreciprocal: true,
            ..Default::default()
        };
        let t = tabulate(&src, &g, &opts).unwrap();
        assert!(t.provenance().notes[0].contains("not reciprocal"));
    }
}
