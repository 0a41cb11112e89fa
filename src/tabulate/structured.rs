//! Tabulating a microfacet model on a half/difference grid by rows of φd.
//!
//! On halfdiff3/halfdiff4 grids the microfacet terms separate (Rusinkiewicz 1998 angles,
//! Walter et al. 2007 model): D depends on the half vector only (θh, φh), F on wi·h = cos θd
//! only, and only the Smith/V-cavity term G needs the directions themselves. So D is computed
//! once per (θh, φh), F once per θd, every sin/cos once per axis sample, and the inner loop
//! over φd is a few multiplies, two square roots and one division per cell.
//!
//! For GGX with Smith shadowing, G/(4 c_i c_o) needs no Λ: with R = sqrt(z² + α_x² x² +
//! α_y² y²) of a direction v = (x, y, z), 1 + Λ(v) = (1 + R/z)/2 (Heitz 2014, Eq. 86), so
//! G1(v)/z = 2/(z + R) and
//!   separable:  G/(4 c_i c_o) = 1/((z_i + R_i)(z_o + R_o)),
//!   correlated: G/(4 c_i c_o) = 1/(2 (R_i z_o + R_o z_i)),
//! both sums of positive terms (no cancellation, exact near the normal and the horizon).

use crate::grid::{Grid, GridKind};
use crate::math::FRAC_PI_2;
use crate::model::{Distribution, Microfacet, Model, Shadowing};

/// sin and cos of every sample of one axis, computed exactly as `HalfDiff::to_dirs` does.
struct AxisTrig {
    sin: Vec<f64>,
    cos: Vec<f64>,
}

impl AxisTrig {
    /// `zero_cos_at_right_angle`: `Vec3::from_spherical` returns cos(π/2) as exactly 0 for θd;
    /// the rotations by θh and φh use the plain sin_cos.
    fn new(samples: impl Iterator<Item = f64>, zero_cos_at_right_angle: bool) -> AxisTrig {
        let (mut sin, mut cos) = (Vec::new(), Vec::new());
        for a in samples {
            let (s, c) = a.sin_cos();
            sin.push(s);
            cos.push(if zero_cos_at_right_angle && a == FRAC_PI_2 {
                0.0
            } else {
                c
            });
        }
        AxisTrig { sin, cos }
    }
}

/// How the per-cell factor G/(4 c_i c_o) is computed.
#[derive(Clone, Copy, PartialEq, Eq)]
enum CellForm {
    GgxSeparable,
    GgxCorrelated,
    /// Any other distribution/shadowing pair: the model's own G per cell.
    General,
}

/// The constants of one row (fixed θh, φh, θd; φd varies).
#[derive(Clone, Copy)]
struct Row {
    sh: f64,
    ch: f64,
    sph: f64,
    cph: f64,
    st: f64,
    ct: f64,
}

/// A microfacet model prepared for a half/difference grid without θ limit.
pub(crate) struct HalfdiffMicrofacet<'a> {
    model: &'a Microfacet,
    form: CellForm,
    ax: f64,
    ay: f64,
    channels: usize,
    /// Axis sizes (θh, φh, θd, φd); φh has one sample (0) on halfdiff3.
    n: [usize; 4],
    th: AxisTrig,
    ph: AxisTrig,
    td: AxisTrig,
    pd: AxisTrig,
    /// D per (θh, φh), θh-major.
    d: Vec<f64>,
    /// scale · F per (θd, channel).
    sf: Vec<f64>,
    /// Run the AVX2 + FMA copy of the loops (same results, see the module docs of `fast`).
    pub(crate) use_avx2: bool,
}

impl<'a> HalfdiffMicrofacet<'a> {
    /// The kernel for `model` on `grid`, or `None` when this fast path does not apply (another
    /// model or grid kind, or a θ limit).
    pub(crate) fn new(model: &'a Model, grid: &Grid) -> Option<HalfdiffMicrofacet<'a>> {
        let Model::Microfacet(m) = model else {
            return None;
        };
        if grid.theta_max().is_some() {
            return None;
        }
        let axes = grid.axes();
        let (th, ph, td, pd) = match grid.kind() {
            GridKind::Halfdiff3 => (&axes[0], None, &axes[1], &axes[2]),
            GridKind::Halfdiff4 => (&axes[0], Some(&axes[1]), &axes[2], &axes[3]),
            _ => return None,
        };
        let samples = |a: &crate::grid::Axis| {
            (0..a.n)
                .map(|i| a.sample(i))
                .collect::<Vec<_>>()
                .into_iter()
        };
        let th_t = AxisTrig::new(samples(th), false);
        let ph_t = match ph {
            Some(a) => AxisTrig::new(samples(a), false),
            // halfdiff3 samples at φh = 0 (Grid::dirs_from_coords).
            None => AxisTrig::new(std::iter::once(0.0), false),
        };
        let td_t = AxisTrig::new(samples(td), true);
        let pd_t = AxisTrig::new(samples(pd), false);
        let (ax, ay) = match m.distribution {
            Distribution::Ggx(g) => (g.alpha_x, g.alpha_y),
            Distribution::Beckmann(b) => (b.alpha_x, b.alpha_y),
        };
        let form = match (m.distribution, m.shadowing) {
            (Distribution::Ggx(_), Shadowing::SmithSeparable) => CellForm::GgxSeparable,
            (Distribution::Ggx(_), Shadowing::SmithCorrelated) => CellForm::GgxCorrelated,
            _ => CellForm::General,
        };
        let c = m.scale.len();
        let mut d = Vec::with_capacity(th_t.sin.len() * ph_t.sin.len());
        for i in 0..th_t.sin.len() {
            for l in 0..ph_t.sin.len() {
                let h = crate::geometry::Vec3::new(
                    th_t.sin[i] * ph_t.cos[l],
                    th_t.sin[i] * ph_t.sin[l],
                    th_t.cos[i],
                );
                d.push(m.distribution.d(h));
            }
        }
        let mut sf = Vec::with_capacity(td_t.cos.len() * c);
        for &cos_d in &td_t.cos {
            for ch in 0..c {
                // wi·h = cos θd; the model gives 0 when it is ≤ 0 (back of the microfacet).
                sf.push(if cos_d > 0.0 {
                    m.scale[ch] * m.fresnel.eval(cos_d, ch)
                } else {
                    0.0
                });
            }
        }
        let n = [th.n, ph.map_or(1, |a| a.n), td.n, pd.n];
        Some(HalfdiffMicrofacet {
            model: m,
            form,
            ax,
            ay,
            channels: c,
            n,
            th: th_t,
            ph: ph_t,
            td: td_t,
            pd: pd_t,
            d,
            sf,
            use_avx2: crate::simd::avx2_fma(),
        })
    }

    /// Cells in one θh slab (all φh, θd, φd).
    pub(crate) fn slab_cells(&self) -> usize {
        self.n[1] * self.n[2] * self.n[3]
    }

    fn row(&self, ih: usize, iph: usize, itd: usize) -> Row {
        Row {
            sh: self.th.sin[ih],
            ch: self.th.cos[ih],
            sph: self.ph.sin[iph],
            cph: self.ph.cos[iph],
            st: self.td.sin[itd],
            ct: self.td.cos[itd],
        }
    }

    /// Fills the θh slab `ih`: `vals` (cells × channels, f32) and `valid`, using `factor`
    /// (at least n_φd long) as scratch. Returns false when a value does not fit in f32 (the
    /// caller then reports it through the generic path).
    pub(crate) fn fill_slab(
        &self,
        ih: usize,
        vals: &mut [f32],
        valid: &mut [bool],
        factor: &mut [f64],
    ) -> bool {
        #[cfg(target_arch = "x86_64")]
        if self.use_avx2 {
            // SAFETY: `use_avx2` is only true when the CPU reports AVX2 and FMA.
            return unsafe { self.fill_slab_avx2(ih, vals, valid, factor) };
        }
        self.fill_slab_impl(ih, vals, valid, factor)
    }

    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2,fma")]
    unsafe fn fill_slab_avx2(
        &self,
        ih: usize,
        vals: &mut [f32],
        valid: &mut [bool],
        factor: &mut [f64],
    ) -> bool {
        self.fill_slab_impl(ih, vals, valid, factor)
    }

    #[inline(always)]
    fn fill_slab_impl(
        &self,
        ih: usize,
        vals: &mut [f32],
        valid: &mut [bool],
        factor: &mut [f64],
    ) -> bool {
        let [_, n_ph, n_td, n_pd] = self.n;
        let c = self.channels;
        let factor = &mut factor[..n_pd];
        let mut finite = true;
        for iph in 0..n_ph {
            let dh = self.d[ih * n_ph + iph];
            for itd in 0..n_td {
                let r = iph * n_td + itd;
                let ok = &mut valid[r * n_pd..(r + 1) * n_pd];
                self.factors(self.row(ih, iph, itd), factor, ok);
                let k = &self.sf[itd * c..(itd + 1) * c];
                let out = &mut vals[r * n_pd * c..(r + 1) * n_pd * c];
                finite &= match c {
                    1 => scale_row::<1>(&[k[0] * dh], factor, out),
                    3 => scale_row::<3>(&[k[0] * dh, k[1] * dh, k[2] * dh], factor, out),
                    _ => scale_row_any(k, dh, factor, out),
                };
            }
        }
        finite
    }

    /// G/(4 c_i c_o) of every φd cell of a row (0 where invalid), and validity.
    #[inline(always)]
    fn factors(&self, r: Row, factor: &mut [f64], valid: &mut [bool]) {
        let (ax, ay) = (self.ax, self.ay);
        let cells = factor
            .iter_mut()
            .zip(valid.iter_mut())
            .zip(self.pd.cos.iter().zip(&self.pd.sin));
        match self.form {
            CellForm::GgxSeparable => ggx_factors::<true>(r, ax, ay, &self.pd, factor, valid),
            CellForm::GgxCorrelated => ggx_factors::<false>(r, ax, ay, &self.pd, factor, valid),
            CellForm::General => {
                use crate::geometry::Vec3;
                let m = self.model;
                let h = Vec3::new(r.sh * r.cph, r.sh * r.sph, r.ch);
                for ((f, ok), (&cp, &sp)) in cells {
                    let ((xi, yi, zi), (xo, yo, zo)) = dirs(r, cp, sp);
                    let inside = zi > 0.0 && zo > 0.0;
                    *ok = inside;
                    *f = if inside && r.ct > 0.0 {
                        let wi = Vec3::new(xi, yi, zi);
                        let wo = Vec3::new(xo, yo, zo);
                        let g = m.shadowing.g(&m.distribution, wi, wo, h, r.ct, r.ct);
                        g / (4.0 * zi) / zo
                    } else {
                        0.0
                    };
                }
            }
        }
    }

    /// The f64 values of one row (cells × channels) and validity: the test hook comparing
    /// this path with the model's own evaluation.
    #[cfg(test)]
    pub(crate) fn row_f64(
        &self,
        ih: usize,
        iph: usize,
        itd: usize,
        out: &mut [f64],
        valid: &mut [bool],
    ) {
        let n_pd = self.n[3];
        let c = self.channels;
        let mut factor = vec![0.0; n_pd];
        self.factors(self.row(ih, iph, itd), &mut factor, valid);
        let dh = self.d[ih * self.n[1] + iph];
        for k in 0..n_pd {
            for ch in 0..c {
                out[k * c + ch] = self.sf[itd * c + ch] * dh * factor[k];
            }
        }
    }
}

/// G/(4 c_i c_o) of GGX with Smith shadowing (module docs) along a row: indexed loops over
/// equal-length slices without calls or branches, so LLVM vectorizes them.
#[inline(always)]
fn ggx_factors<const SEPARABLE: bool>(
    r: Row,
    ax: f64,
    ay: f64,
    pd: &AxisTrig,
    factor: &mut [f64],
    valid: &mut [bool],
) {
    let n = factor.len();
    let (cps, sps, valid) = (&pd.cos[..n], &pd.sin[..n], &mut valid[..n]);
    for k in 0..n {
        let ((xi, yi, zi), (xo, yo, zo)) = dirs(r, cps[k], sps[k]);
        let ri = (zi * zi + (sqr(ax * xi) + sqr(ay * yi))).sqrt();
        let ro = (zo * zo + (sqr(ax * xo) + sqr(ay * yo))).sqrt();
        let v = if SEPARABLE {
            1.0 / ((zi + ri) * (zo + ro))
        } else {
            0.5 / (ri * zo + ro * zi)
        };
        // One-sided BRDF: the horizon counts as below (the generic path's test).
        let inside = zi > 0.0 && zo > 0.0;
        valid[k] = inside;
        factor[k] = if inside { v } else { 0.0 };
    }
}

#[inline(always)]
fn sqr(x: f64) -> f64 {
    x * x
}

/// (wi, wo) of a cell as `HalfDiff::to_dirs` computes them, operation for operation (so the
/// horizon test gives the same answer as the generic path): d = (sinθd cosφd, sinθd sinφd,
/// cosθd), wi = Rz(φh) Ry(θh) d, wo = Rz(φh) Ry(θh) (−dx, −dy, dz).
#[inline(always)]
fn dirs(r: Row, cp: f64, sp: f64) -> ((f64, f64, f64), (f64, f64, f64)) {
    let dx = r.st * cp;
    let dy = r.st * sp;
    let dz = r.ct;
    let xi1 = r.ch * dx + r.sh * dz;
    let zi = r.ch * dz - r.sh * dx;
    let xo1 = r.sh * dz - r.ch * dx;
    let zo = r.sh * dx + r.ch * dz;
    let wi = (r.cph * xi1 - r.sph * dy, r.sph * xi1 + r.cph * dy, zi);
    let wo = (r.cph * xo1 + r.sph * dy, r.sph * xo1 - r.cph * dy, zo);
    (wi, wo)
}

/// out[k·C + ch] = k_ch · factor[k] as f32; false when a value is not finite in f32.
#[inline(always)]
fn scale_row<const C: usize>(k: &[f64; C], factor: &[f64], out: &mut [f32]) -> bool {
    let mut finite = true;
    for (o, &f) in out.chunks_exact_mut(C).zip(factor) {
        for ch in 0..C {
            let v = (k[ch] * f) as f32;
            finite &= v.abs() < f32::INFINITY;
            o[ch] = v;
        }
    }
    finite
}

fn scale_row_any(k: &[f64], dh: f64, factor: &[f64], out: &mut [f32]) -> bool {
    let c = k.len();
    let mut finite = true;
    for (o, &f) in out.chunks_exact_mut(c).zip(factor) {
        for ch in 0..c {
            let v = (k[ch] * dh * f) as f32;
            finite &= v.abs() < f32::INFINITY;
            o[ch] = v;
        }
    }
    finite
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::brdf::Brdf;
    use crate::grid::parse_grid_spec;
    use crate::tabulate::{TabulateOptions, tabulate, tabulate_into};

    fn models() -> Vec<Model> {
        let fresnels = [
            r#"{"type":"none"}"#,
            r#"{"type":"schlick","f0":[0.04,0.5,0.9]}"#,
            r#"{"type":"dielectric","ior":1.5}"#,
            r#"{"type":"dielectric","ior":0.8}"#,
            r#"{"type":"conductor","eta":[0.2004,0.924,1.1022],"k":[3.9129,2.4528,2.1421]}"#,
        ];
        let mut out = Vec::new();
        for (i, f) in fresnels.iter().enumerate() {
            for dist in ["ggx", "beckmann"] {
                for sh in ["smith-separable", "smith-correlated", "v-cavity"] {
                    for rough in [r#""alpha":0.2"#, r#""alpha_x":0.1,"alpha_y":0.4"#] {
                        // Rotate through Beckmann's G1 forms and some tiny roughness.
                        let g1 = if dist == "beckmann" && i % 2 == 1 {
                            "rational"
                        } else {
                            "exact"
                        };
                        let rough = if i == 3 && rough.contains("0.2") {
                            r#""alpha":0.002"#
                        } else {
                            rough
                        };
                        let spec = format!(
                            r#"{{"model":"{dist}","shadowing":"{sh}","g1":"{g1}",{rough},"fresnel":{f}}}"#
                        );
                        out.push(Model::parse(&spec).unwrap());
                    }
                }
            }
        }
        out
    }

    /// Every valid cell of the fast rows equals the model's own value within 1e-9 relative,
    /// and validity is the generic path's, on MERL-placed and centred grids of both kinds.
    #[test]
    fn fast_rows_equal_the_model_on_every_cell() {
        let grids = [
            "halfdiff3:12x10x16,warp=sqrt/linear/linear,at=edge",
            "halfdiff3:12x10x16",
            "halfdiff4:6x8x6x8,warp=sqrt/linear/linear/linear,at=edge",
            "halfdiff4:6x8x6x8",
        ];
        let mut checked = 0usize;
        for spec in grids {
            let g = parse_grid_spec(spec).unwrap();
            let mask = g.geometric_mask();
            for m in models() {
                let k = HalfdiffMicrofacet::new(&m, &g).expect("fast path applies");
                let c = m.channels().len();
                let [n_th, n_ph, n_td, n_pd] = k.n;
                let mut row = vec![0.0; n_pd * c];
                let mut ok = vec![false; n_pd];
                let mut want = vec![0.0; c];
                let mut idx = [0usize; 4];
                for ih in 0..n_th {
                    for iph in 0..n_ph {
                        for itd in 0..n_td {
                            k.row_f64(ih, iph, itd, &mut row, &mut ok);
                            for ip in 0..n_pd {
                                let cell = ((ih * n_ph + iph) * n_td + itd) * n_pd + ip;
                                assert_eq!(ok[ip], mask[cell], "{spec} validity of cell {cell}");
                                if !ok[ip] {
                                    continue;
                                }
                                g.unflatten(cell, &mut idx[..g.axes().len()]);
                                let (wi, wo) = g.cell_dirs(&idx[..g.axes().len()]);
                                m.eval(wi, wo, &mut want);
                                for ch in 0..c {
                                    let (a, b) = (row[ip * c + ch], want[ch]);
                                    assert!(
                                        (a - b).abs() <= 1e-9 * b.abs(),
                                        "{spec} {} cell {cell} ch {ch}: fast {a:e} vs model {b:e}",
                                        m.describe()
                                    );
                                    checked += 1;
                                }
                            }
                        }
                    }
                }
            }
        }
        assert!(checked > 100_000, "{checked}");
    }

    /// A model hidden behind a plain `Brdf`: `tabulate` takes the generic path for it.
    struct Opaque<'a>(&'a Model);
    impl Brdf for Opaque<'_> {
        fn channels(&self) -> &crate::brdf::Channels {
            self.0.channels()
        }
        fn eval(&self, wi: crate::geometry::Vec3, wo: crate::geometry::Vec3, o: &mut [f64]) {
            self.0.eval(wi, wo, o)
        }
        fn is_isotropic(&self) -> bool {
            self.0.is_isotropic()
        }
        fn describe(&self) -> String {
            self.0.describe()
        }
    }

    /// On a grid extended below the horizon, the fast path's kernel fills the cells above
    /// it and the generic path those below: together the generic path's whole table.
    #[test]
    fn extended_grids_tabulate_as_the_generic_path_does() {
        let m = Model::parse("ggx:alpha_x=0.1,alpha_y=0.3,fresnel=au").unwrap();
        let opts = TabulateOptions::default();
        for spec in ["halfdiff4:12x8x10x16,horizon=extend", "merl,horizon=extend"] {
            let iso;
            let src: &Model = if spec.starts_with("merl") {
                iso = Model::parse("ggx:alpha=0.05,fresnel=au").unwrap();
                &iso
            } else {
                &m
            };
            let g = parse_grid_spec(spec).unwrap();
            assert!(
                HalfdiffMicrofacet::new(src, &g).is_some(),
                "{spec}: no fast path"
            );
            let fast = tabulate(src, &g, &opts).unwrap();
            let slow = tabulate(&Opaque(src), &g, &opts).unwrap();
            assert_eq!(fast.valid(), slow.valid(), "{spec}");
            assert!(fast.valid().iter().all(|&v| v), "{spec}");
            for (a, b) in fast.data().iter().zip(slow.data()) {
                assert!(
                    (a - b).abs() <= f32::EPSILON * b.abs(),
                    "{spec}: {a} vs {b}"
                );
            }
        }
    }

    /// The fast path through `tabulate` gives the generic path's f32 table (the table the
    /// per-cell loop writes, obtained by hiding the model behind a plain `Brdf`), on the MERL
    /// grid itself; reuse of a table's memory and the thread count change nothing.
    #[test]
    fn tabulate_fast_path_matches_generic_tables_bit_for_bit_or_within_an_ulp() {
        let m = Model::parse(
            "ggx:alpha=0.2,shadowing=smith-separable,fresnel=conductor,\
             eta=0.2004/0.924/1.1022,k=3.9129/2.4528/2.1421",
        )
        .unwrap();
        let g = Grid::merl();
        let opts = TabulateOptions::default();
        let fast = tabulate(&m, &g, &opts).unwrap();
        let slow = tabulate(&Opaque(&m), &g, &opts).unwrap();
        assert_eq!(fast.valid(), slow.valid());
        assert_eq!(fast.provenance(), slow.provenance());
        for (a, b) in fast.data().iter().zip(slow.data()) {
            // f64 results within 1e-15 relative may still round to adjacent f32 values.
            assert!((a - b).abs() <= f32::EPSILON * b.abs(), "{a} vs {b}");
        }
        // Reusing a table of another shape, and one thread instead of the pool.
        let mut reused = tabulate(&m, &parse_grid_spec("halfdiff3:4").unwrap(), &opts).unwrap();
        let one = rayon::ThreadPoolBuilder::new()
            .num_threads(1)
            .build()
            .unwrap();
        one.install(|| tabulate_into(&m, &g, &opts, &mut reused))
            .unwrap();
        assert_eq!(reused, fast);
        // Same bytes from the baseline and the AVX2 copies of the loops.
        let mut k = HalfdiffMicrofacet::new(&m, &g).unwrap();
        let slab = k.slab_cells();
        let mut a = (vec![0f32; slab * 3], vec![false; slab]);
        let mut b = a.clone();
        let mut scratch = vec![0.0; slab];
        for ih in [0, 1, 45, 89] {
            k.use_avx2 = false;
            assert!(k.fill_slab(ih, &mut a.0, &mut a.1, &mut scratch));
            k.use_avx2 = crate::simd::avx2_fma();
            assert!(k.fill_slab(ih, &mut b.0, &mut b.1, &mut scratch));
            assert_eq!(a, b);
            let cells = ih * slab..(ih + 1) * slab;
            assert_eq!(&a.1[..], &fast.valid()[cells.clone()]);
            assert_eq!(&a.0[..], &fast.data()[cells.start * 3..cells.end * 3]);
        }
    }

    #[test]
    fn values_beyond_f32_are_flagged() {
        let mut out = [0f32; 3];
        assert!(scale_row::<1>(&[2.0], &[1.0, 0.5, 0.0], &mut out));
        assert_eq!(out, [2.0, 1.0, 0.0]);
        assert!(!scale_row::<1>(&[1e30], &[1.0, 1e10, 0.0], &mut out));
        assert!(!scale_row_any(&[1e30], 1.0, &[1e10], &mut out[..1]));
    }
}
