//! Direction pairs given by a caller (the `eval` command's arguments and stream, the Python
//! and C bindings' arrays): turning vectors into unit directions with the errors a user can
//! act on, the stored-domain rule, and evaluating a source on many pairs.

use crate::brdf::Brdf;
use crate::geometry::Vec3;
use crate::source::{Lookup, Source};
use crate::table::{Interp, InterpolatedTable, Table};
use crate::{Error, Result};
use rayon::prelude::*;

/// A unit direction from any finite non-zero vector; `name` (`wi`, `wo`) starts the error.
pub fn unit_direction(v: [f64; 3], name: &str) -> Result<Vec3, String> {
    let v = Vec3::new(v[0], v[1], v[2]);
    if !v.is_finite() {
        return Err(format!("{name} has a NaN or infinite component"));
    }
    // `try_normalize` scales by the largest component first, so 1e200 and 3e-162 are valid.
    v.try_normalize()
        .ok_or_else(|| format!("{name} has zero length (expected a direction)"))
}

/// A unit direction from polar and azimuth angles in degrees (`eval --wi-deg THETA,PHI`).
/// θ is measured from the normal and must lie in [0°, 90°]: 90° is the horizon, where every
/// source gives 0 ([`Vec3::from_spherical`] places it at z = 0 exactly); a θ beyond it names no
/// direction of the upper hemisphere and is refused rather than folded back. φ may be any
/// finite value: it is reduced modulo 360° first (`%`, exact in f64), so 1e308 is the angle
/// its residue names and every |φ| < 360° is used as given (the same bits as before).
/// The error names the offending angle and the accepted range.
pub fn direction_from_degrees(theta_deg: f64, phi_deg: f64) -> Result<Vec3, String> {
    // Any direction of the sphere, as the vector form (`--wi`) takes: past 90° it lies below
    // the horizon, where the one-sided source is 0 (tests/cli_eval.rs evaluates θ = 120°).
    if !(0.0..=180.0).contains(&theta_deg) {
        return Err(format!(
            "θ = {} is out of range; expected a polar angle in [0, 180] degrees (90 is the \
             horizon, beyond it f = 0)",
            crate::model::params::fmt_num(theta_deg)
        ));
    }
    if !phi_deg.is_finite() {
        return Err(format!(
            "φ = {phi_deg} is not a finite angle; expected an azimuth in degrees"
        ));
    }
    let phi_deg = if phi_deg.abs() < 360.0 {
        phi_deg
    } else {
        phi_deg % 360.0
    };
    Ok(Vec3::from_spherical(
        theta_deg.to_radians(),
        phi_deg.to_radians(),
    ))
}

/// A pair above the horizon but beyond the source's stored θmax has no value
/// (docs/parameterizations.md): the reason, or `None` when the pair may be evaluated. Pairs
/// below the horizon are always allowed (their value is 0).
pub fn outside_domain(brdf: &dyn Brdf, wi: Vec3, wo: Vec3) -> Option<String> {
    if wi.z <= 0.0 || wo.z <= 0.0 || brdf.in_domain(wi, wo) {
        return None;
    }
    Some(format!(
        "pair ({:?}, {:?}) is outside the stored domain θ ≤ {}° of the table",
        wi.to_array(),
        wo.to_array(),
        brdf.theta_max_deg().unwrap_or(90.0)
    ))
}

/// `brdf.eval` at every pair, `out[p·C + ch]` for pair `p` and channel `ch`: the same bits
/// as one call per pair (what `brdfpack eval` prints), computed in parallel.
///
/// # Panics
/// When `out.len() != pairs.len() × channels` (a caller bug).
pub fn eval_pointwise(brdf: &dyn Brdf, pairs: &[(Vec3, Vec3)], out: &mut [f64]) {
    let c = brdf.channels().len();
    assert_eq!(out.len(), pairs.len() * c, "eval_pointwise: output length");
    /// Pairs per parallel work item.
    const CHUNK: usize = 1024;
    out.par_chunks_mut(CHUNK * c)
        .zip(pairs.par_chunks(CHUNK))
        .for_each(|(out, pairs)| {
            for (o, &(wi, wo)) in out.chunks_exact_mut(c).zip(pairs) {
                brdf.eval(wi, wo, o);
            }
        });
}

/// How [`Evaluable::eval_arrays`] computes values.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default)]
pub struct EvalOptions {
    /// One `Brdf::eval` per pair. Otherwise tables take the batched lookup
    /// (`Table::eval_batch`, several times faster). Both give the bits `brdfpack eval`
    /// prints, for every source; `exact` is kept for callers that want the per-pair path.
    pub exact: bool,
    /// Pairs beyond a table's stored θmax give 0 instead of an error.
    pub outside_domain_zero: bool,
}

/// A source opened for evaluation at many pairs: a table keeps its lookup so that batches
/// can take the batched path. What the Python and C bindings hold.
// One value per opened source: the size difference between variants costs nothing.
#[allow(clippy::large_enum_variant)]
pub enum Evaluable {
    Table(InterpolatedTable),
    Other(Box<dyn Brdf>),
}

impl Evaluable {
    /// The source evaluated by `lookup` (as `Source::into_brdf`).
    pub fn new(source: Source, lookup: Lookup) -> Result<Evaluable> {
        Ok(match (source, lookup) {
            (Source::Table(table), Lookup::Linear | Lookup::Nearest) => {
                let interp = if lookup == Lookup::Nearest {
                    Interp::Nearest
                } else {
                    Interp::Linear
                };
                Evaluable::Table(InterpolatedTable { table, interp })
            }
            (other, lookup) => Evaluable::Other(other.into_brdf(lookup)?),
        })
    }

    pub fn brdf(&self) -> &dyn Brdf {
        match self {
            Evaluable::Table(t) => t,
            Evaluable::Other(b) => b.as_ref(),
        }
    }

    /// The table, when the source is one evaluated linearly or by nearest sample.
    pub fn table(&self) -> Option<&Table> {
        match self {
            Evaluable::Table(t) => Some(&t.table),
            Evaluable::Other(_) => None,
        }
    }

    /// Values at the pairs of `wi` and `wo` (row-major, 3 numbers per direction; any finite
    /// non-zero vectors, normalized like `brdfpack eval` does) into `out`, pair-major with
    /// `channels` values per pair. Errors name the first bad row (from 0) and what is wrong;
    /// after an error `out` may hold the values of other rows.
    pub fn eval_arrays(
        &self,
        wi: &[f64],
        wo: &[f64],
        opts: EvalOptions,
        out: &mut [f64],
    ) -> Result<()> {
        self.eval_arrays_with(wi, wo, opts, out, &mut Vec::new())
    }

    /// [`Evaluable::eval_arrays`] with the unit pairs built in `scratch`: a caller that keeps
    /// it between calls saves allocating (and first touching) 48 bytes per pair each time.
    pub fn eval_arrays_with(
        &self,
        wi: &[f64],
        wo: &[f64],
        opts: EvalOptions,
        out: &mut [f64],
        scratch: &mut Vec<(Vec3, Vec3)>,
    ) -> Result<()> {
        let c = self.brdf().channels().len();
        if wi.len() != wo.len() || !wi.len().is_multiple_of(3) {
            return Err(Error::input(format!(
                "wi has {} numbers and wo {}: expected two arrays of N rows of 3",
                wi.len(),
                wo.len()
            )));
        }
        let n = wi.len() / 3;
        if out.len() != n * c {
            return Err(Error::input(format!(
                "the output holds {} values, expected {n} pairs × {c} channels",
                out.len()
            )));
        }
        crate::memory::require(
            &format!("{n} direction pairs"),
            crate::memory::pair_bytes(n),
        )?;
        let brdf = self.brdf();
        if let Evaluable::Table(t) = self
            && !opts.exact
            && c > 0
        {
            // One pass per chunk of rows: normalize them into a small buffer, then look them
            // up (the two-pass form wrote and re-read 48 bytes per pair, a fifth of a
            // 10⁶-pair call). The first bad row is the error, for any thread count.
            const ROWS: usize = 4096;
            // A table's domain rule (`InterpolatedTable::in_domain`) is true for every pair
            // when its grid has no θ limit: then no pair needs the check. With one, every pair
            // above the horizon is checked, as `checked_pair` does.
            let limited = !opts.outside_domain_zero && t.table.grid().theta_max().is_some();
            let first_bad = out
                .par_chunks_mut(ROWS * c)
                .enumerate()
                .map_init(Vec::new, |buf, (k, out)| {
                    let (first, rows) = (k * ROWS, out.len() / c);
                    buf.resize(rows, (Vec3::Z, Vec3::Z));
                    let (a, b) = (
                        &wi[3 * first..3 * (first + rows)],
                        &wo[3 * first..3 * (first + rows)],
                    );
                    // Rows the quick normalization leaves (a zero, huge, tiny or non-finite
                    // vector) and the domain rule, in row order: the first error is the first
                    // bad row's.
                    if !unit_rows(a, b, buf) || limited {
                        for (j, pair) in buf.iter_mut().enumerate() {
                            let (i, o) = (&a[3 * j..3 * j + 3], &b[3 * j..3 * j + 3]);
                            if unit_quick(i[0], i[1], i[2]).1 && unit_quick(o[0], o[1], o[2]).1 {
                                if limited {
                                    check_domain(brdf, *pair, first + j)?;
                                }
                            } else {
                                *pair = checked_pair(brdf, wi, wo, first + j, opts)?;
                            }
                        }
                    }
                    t.table.eval_batch_serial(buf, t.interp, out);
                    Ok(())
                })
                .collect::<Vec<Result<()>>>()
                .into_iter()
                .find(|r| r.is_err());
            return first_bad.unwrap_or(Ok(()));
        }
        scratch.clear();
        scratch.resize(n, (Vec3::Z, Vec3::Z));
        /// Pairs per parallel work item.
        const CHUNK: usize = 4096;
        // Each chunk reports its first bad row; the first of those is the error (the same
        // message for any thread count).
        let first_bad = scratch
            .par_chunks_mut(CHUNK)
            .enumerate()
            .map(|(k, chunk)| {
                for (j, pair) in chunk.iter_mut().enumerate() {
                    *pair = checked_pair(brdf, wi, wo, k * CHUNK + j, opts)?;
                }
                Ok(())
            })
            .collect::<Vec<Result<()>>>()
            .into_iter()
            .find(|r| r.is_err());
        if let Some(e) = first_bad {
            return e;
        }
        match self {
            Evaluable::Table(t) if !opts.exact => t.table.eval_batch(scratch, t.interp, out),
            _ => eval_pointwise(brdf, scratch, out),
        }
        Ok(())
    }
}

/// Row `row` of the arrays `wi` and `wo` as a pair of unit directions, or the error naming the
/// row: a zero-length or non-finite vector, or (unless `outside_domain_zero`) a pair beyond
/// the source's stored domain.
#[inline]
fn checked_pair(
    brdf: &dyn Brdf,
    wi: &[f64],
    wo: &[f64],
    row: usize,
    opts: EvalOptions,
) -> Result<(Vec3, Vec3)> {
    let at = |m: String| Error::Input(format!("row {row}: {m}"));
    let (i, o) = (&wi[3 * row..3 * row + 3], &wo[3 * row..3 * row + 3]);
    let wi = unit_direction([i[0], i[1], i[2]], "wi").map_err(at)?;
    let wo = unit_direction([o[0], o[1], o[2]], "wo").map_err(at)?;
    if !opts.outside_domain_zero {
        check_domain(brdf, (wi, wo), row)?;
    }
    Ok((wi, wo))
}

/// The error of row `row` when its pair is beyond the source's stored domain.
#[inline]
fn check_domain(brdf: &dyn Brdf, (wi, wo): (Vec3, Vec3), row: usize) -> Result<()> {
    match outside_domain(brdf, wi, wo) {
        None => Ok(()),
        Some(why) => Err(Error::Input(format!(
            "row {row}: {why}; ask for outside-domain-zero to get 0 there"
        ))),
    }
}

/// `(x, y, z)` normalized as [`unit_direction`] does when its squared length is a finite
/// number of at least `f64::MIN_POSITIVE` (then every component is finite too), and whether
/// it is: the same operations (`Vec3::try_normalize`: x·x + y·y + z·z, then each component
/// × 1/√l2), so the same bits. Without branches, so that a loop of it vectorizes.
#[inline(always)]
fn unit_quick(x: f64, y: f64, z: f64) -> (Vec3, bool) {
    let l2 = x * x + y * y + z * z;
    // NaN and ∞ are outside the range.
    let ok = (f64::MIN_POSITIVE..=f64::MAX).contains(&l2);
    let s = 1.0 / l2.sqrt();
    (Vec3::new(x * s, y * s, z * s), ok)
}

/// The rows of `wi` and `wo` (3 numbers each) normalized into `pairs` by [`unit_quick`];
/// whether every row took it (the others hold garbage, for [`checked_pair`] to redo).
fn unit_rows(wi: &[f64], wo: &[f64], pairs: &mut [(Vec3, Vec3)]) -> bool {
    #[cfg(target_arch = "x86_64")]
    if crate::simd::avx2() {
        // SAFETY: only called when the CPU reports AVX2.
        return unsafe { unit_rows_avx2(wi, wo, pairs) };
    }
    unit_rows_impl(wi, wo, pairs)
}

/// [`unit_rows_impl`] compiled for AVX2: 4-lane square roots and divisions, which round
/// like the scalar ones (IEEE: correctly rounded), and no FMA (Rust never contracts `a·b + c`).
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
unsafe fn unit_rows_avx2(wi: &[f64], wo: &[f64], pairs: &mut [(Vec3, Vec3)]) -> bool {
    unit_rows_impl(wi, wo, pairs)
}

#[inline(always)]
fn unit_rows_impl(wi: &[f64], wo: &[f64], pairs: &mut [(Vec3, Vec3)]) -> bool {
    let mut all = true;
    for ((i, o), pair) in wi
        .chunks_exact(3)
        .zip(wo.chunks_exact(3))
        .zip(pairs.iter_mut())
    {
        let (u, ok_u) = unit_quick(i[0], i[1], i[2]);
        let (v, ok_v) = unit_quick(o[0], o[1], o[2]);
        *pair = (u, v);
        all &= ok_u & ok_v;
    }
    all
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn huge_and_tiny_vectors_normalize_to_unit_length() {
        let want = unit_direction([1.0, 0.0, 1.0], "wi").unwrap().to_array();
        for v in [
            [1e200, 0.0, 1e200],
            [1e-162, 0.0, 1e-162],
            [3e-162, 0.0, 3e-162],
            [5e-324, 0.0, 5e-324],
            [f64::MAX, 0.0, f64::MAX],
        ] {
            let u = unit_direction(v, "wi").unwrap().to_array();
            for k in 0..3 {
                assert!((u[k] - want[k]).abs() <= 1e-15, "{v:?}: {u:?} vs {want:?}");
            }
        }
        let e = unit_direction([0.0, -0.0, 0.0], "wo").unwrap_err();
        assert_eq!(e, "wo has zero length (expected a direction)");
        let e = unit_direction([f64::NAN, 0.0, 1.0], "wi").unwrap_err();
        assert_eq!(e, "wi has a NaN or infinite component");
    }

    #[test]
    fn degrees_keep_theta_on_the_hemisphere_and_reduce_phi() {
        let d = |t: f64, p: f64| direction_from_degrees(t, p).map(|v| v.to_array());
        // The horizon is allowed and exactly z = 0; the normal is (0, 0, 1).
        assert_eq!(d(90.0, 0.0).unwrap()[2], 0.0);
        assert_eq!(d(0.0, 123.0).unwrap(), [0.0, 0.0, 1.0]);
        assert_eq!(d(-0.0, 0.0).unwrap(), [0.0, 0.0, 1.0]);
        // Below the horizon: a direction like any other (the source is 0 there); the
        // opposite pole is (0, 0, −1).
        assert!(d(120.0, 0.0).unwrap()[2] < 0.0);
        assert_eq!(d(180.0, 0.0).unwrap()[2], -1.0);
        // Below the normal's 0 and past the opposite pole: refused, naming the angle and the
        // range.
        for (t, shown) in [
            (-10.0, "-10"),
            (180.000001, "180.000001"),
            (1e308, "1e308"),
            (-1e-300, "-1e-300"),
        ] {
            let e = d(t, 0.0).unwrap_err();
            assert!(
                e.starts_with(&format!("θ = {shown} is out of range")),
                "{e}"
            );
            assert!(e.contains("[0, 180] degrees"), "{e}");
        }
        // φ below 360° in magnitude is used as given; beyond, its residue (exact in f64).
        assert_eq!(d(30.0, 370.0).unwrap(), d(30.0, 10.0).unwrap());
        assert_eq!(d(30.0, -370.0).unwrap(), d(30.0, -10.0).unwrap());
        let r = 1e308 % 360.0;
        assert!((0.0..360.0).contains(&r));
        assert_eq!(d(30.0, 1e308).unwrap(), d(30.0, r).unwrap());
        let v = d(30.0, 1e308).unwrap();
        assert!((v[0].hypot(v[1]) - 0.5).abs() < 1e-15 && (v[2] - 0.75f64.sqrt()).abs() < 1e-15);
        assert!(d(30.0, f64::INFINITY).is_err() && d(30.0, f64::NAN).is_err());
    }

    #[test]
    fn pointwise_batch_equals_one_call_per_pair() {
        let brdf = crate::source::open_brdf("ggx:alpha=0.3,fresnel=au").unwrap();
        let set = crate::check::SampleSet::uniform(5000, 3);
        let mut batch = vec![f64::NAN; set.pairs.len() * 3];
        eval_pointwise(&*brdf, &set.pairs, &mut batch);
        let mut one = [0.0; 3];
        for (p, &(wi, wo)) in set.pairs.iter().enumerate() {
            brdf.eval(wi, wo, &mut one);
            for ch in 0..3 {
                assert_eq!(batch[p * 3 + ch].to_bits(), one[ch].to_bits(), "pair {p}");
            }
        }
    }

    #[test]
    fn arrays_are_validated_and_evaluated() {
        let e =
            Evaluable::new(Source::open("lambert:albedo=0.5").unwrap(), Lookup::Linear).unwrap();
        let mut out = [0.0; 2];
        let wi = [0.0, 0.0, 2.0, 0.0, 0.0, -1.0];
        let wo = [0.0, 0.0, 1.0, 0.0, 0.0, 1.0];
        e.eval_arrays(&wi, &wo, EvalOptions::default(), &mut out)
            .unwrap();
        assert_eq!(out, [0.5 / std::f64::consts::PI, 0.0]);
        let bad = [0.0, 0.0, 1.0, 0.0, 0.0, 0.0];
        let err = e
            .eval_arrays(&wi, &bad, EvalOptions::default(), &mut out)
            .unwrap_err();
        assert_eq!(
            err.to_string(),
            "row 1: wo has zero length (expected a direction)"
        );
        let err = e
            .eval_arrays(&wi[..3], &wo, EvalOptions::default(), &mut out)
            .unwrap_err();
        assert!(
            err.to_string().contains("wi has 3 numbers and wo 6"),
            "{err}"
        );
    }

    #[test]
    fn table_arrays_take_one_pass_with_the_batch_bits_and_the_first_bad_row() {
        let t = crate::tabulate::tabulate(
            &crate::model::Model::parse("ggx:alpha=0.3,fresnel=au").unwrap(),
            &crate::grid::parse_grid_spec("halfdiff3:16x12x20").unwrap(),
            &Default::default(),
        )
        .unwrap();
        let set = crate::check::SampleSet::uniform(10_000, 5);
        let mut want = vec![f64::NAN; set.pairs.len() * 3];
        t.eval_batch(&set.pairs, Interp::Linear, &mut want);
        // Unnormalized rows (× 3 and × 0.5) normalize to the same pairs.
        let wi: Vec<f64> = set
            .pairs
            .iter()
            .flat_map(|p| p.0.to_array().map(|x| 3.0 * x))
            .collect();
        let wo: Vec<f64> = set
            .pairs
            .iter()
            .flat_map(|p| p.1.to_array().map(|x| 0.5 * x))
            .collect();
        let e = Evaluable::Table(InterpolatedTable {
            table: t,
            interp: Interp::Linear,
        });
        let mut got = vec![f64::NAN; want.len()];
        e.eval_arrays(&wi, &wo, EvalOptions::default(), &mut got)
            .unwrap();
        let bits = |v: &[f64]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
        let mut exact = vec![f64::NAN; want.len()];
        let opts = EvalOptions {
            exact: true,
            ..Default::default()
        };
        e.eval_arrays(&wi, &wo, opts, &mut exact).unwrap();
        assert_eq!(bits(&got), bits(&exact));
        // The unit pairs are the set's own to rounding, so the batch on them agrees closely.
        for (a, b) in got.iter().zip(&want) {
            assert!((a - b).abs() <= 1e-9 * b.abs().max(1e-12), "{a} vs {b}");
        }
        // Bad rows in two chunks: the first one is named, for any thread count.
        let mut bad = wo.clone();
        bad[3 * 9000..3 * 9000 + 3].fill(0.0);
        bad[3 * 5000 + 2] = f64::NAN;
        for threads in [1, 2, 3] {
            let err = rayon::ThreadPoolBuilder::new()
                .num_threads(threads)
                .build()
                .unwrap()
                .install(|| e.eval_arrays(&wi, &bad, EvalOptions::default(), &mut got))
                .unwrap_err();
            assert_eq!(
                err.to_string(),
                "row 5000: wo has a NaN or infinite component"
            );
        }
    }

    #[test]
    fn quick_rows_normalize_to_the_bits_of_unit_direction() {
        let mut rng = crate::math::SplitMix64::new(7);
        let mut rows: Vec<[f64; 3]> = (0..997)
            .map(|_| {
                let e = rng.next_f64() * 40.0 - 20.0;
                [0, 1, 2].map(|_| (rng.next_f64() * 2.0 - 1.0) * 10f64.powf(e))
            })
            .collect();
        let odd = [
            [1e200, 0.0, 1e200],
            [3e-162, 0.0, 3e-162],
            [5e-324, 0.0, 0.0],
            [f64::MAX, 0.0, 0.0],
            [0.0, -0.0, 0.0],
            [f64::NAN, 0.0, 1.0],
            [0.0, f64::INFINITY, 1.0],
            [1e154, 1e154, 1e154],
            [1.4e-154, 0.0, 0.0],
            [0.0, 0.0, -2.0],
        ];
        rows.extend(odd);
        let flat: Vec<f64> = rows.iter().flatten().copied().collect();
        let rev: Vec<f64> = rows.iter().rev().flatten().copied().collect();
        let n = rows.len();
        let mut quick = vec![(Vec3::Z, Vec3::Z); n];
        let mut portable = quick.clone();
        assert!(!unit_rows(&flat, &rev, &mut quick));
        assert!(!unit_rows_impl(&flat, &rev, &mut portable));
        assert!(unit_rows(&flat[..30], &rev[30..60], &mut quick[..10]));
        unit_rows(&flat, &rev, &mut quick);
        let mut taken = 0;
        for j in 0..n {
            let (v, w) = (rows[j], rows[n - 1 - j]);
            let want = (unit_direction(v, "wi"), unit_direction(w, "wo"));
            let oks = (
                unit_quick(v[0], v[1], v[2]).1,
                unit_quick(w[0], w[1], w[2]).1,
            );
            let bits = |p: Vec3| p.to_array().map(f64::to_bits);
            if oks.0 {
                assert_eq!(bits(quick[j].0), bits(want.0.clone().unwrap()), "{v:?}");
                assert_eq!(bits(portable[j].0), bits(want.0.unwrap()), "{v:?}");
                taken += 1;
            }
            if oks.1 {
                assert_eq!(bits(quick[j].1), bits(want.1.unwrap()), "{w:?}");
            }
        }
        // The rows of magnitude ~1e±20 (and the plain ones above) take the quick path; the
        // zero, huge, tiny and non-finite ones do not.
        assert!(taken >= 990, "{taken}");
        for v in odd.iter().take(9) {
            assert!(!unit_quick(v[0], v[1], v[2]).1, "{v:?}");
        }
    }

    #[test]
    fn theta_max_table_arrays_check_every_pair_like_one_call_per_pair() {
        let t = crate::tabulate::tabulate(
            &crate::model::Model::parse("ggx:alpha=0.3,fresnel=au").unwrap(),
            &crate::grid::parse_grid_spec("halfdiff3:8x8x16,theta-max=60").unwrap(),
            &Default::default(),
        )
        .unwrap();
        let e = Evaluable::Table(InterpolatedTable {
            table: t,
            interp: Interp::Linear,
        });
        // 5000 pairs within 50° (× 7 and with huge and tiny rows among them), one beyond.
        let mut rng = crate::math::SplitMix64::new(3);
        let mut dir = || {
            let th = 0.87 * rng.next_f64();
            let ph = std::f64::consts::TAU * rng.next_f64();
            Vec3::from_spherical(th, ph).to_array().map(|x| 7.0 * x)
        };
        let mut wi: Vec<f64> = (0..5000).flat_map(|_| dir()).collect();
        let wo: Vec<f64> = (0..5000).flat_map(|_| dir()).collect();
        wi[3 * 10..3 * 10 + 3].copy_from_slice(&[1e200, 0.0, 1e200]);
        wi[3 * 4500..3 * 4500 + 3].copy_from_slice(&[1e-170, 0.0, 2e-170]);
        let mut got = vec![f64::NAN; 15_000];
        let mut exact = got.clone();
        let x = EvalOptions {
            exact: true,
            ..Default::default()
        };
        e.eval_arrays(&wi, &wo, EvalOptions::default(), &mut got)
            .unwrap();
        e.eval_arrays(&wi, &wo, x, &mut exact).unwrap();
        let bits = |v: &[f64]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
        assert_eq!(bits(&got), bits(&exact));
        assert!(got.iter().filter(|v| **v > 0.0).count() > 14_000);
        // Row 4200 beyond θmax, row 4300 zero: the domain error of the earlier row, in
        // whichever chunk; with outside-domain-zero, a 0 there and the zero row's error.
        let mut bad = wi.clone();
        bad[3 * 4200..3 * 4200 + 3].copy_from_slice(&[1.0, 0.0, 0.1]);
        bad[3 * 4300..3 * 4300 + 3].fill(0.0);
        let err = e
            .eval_arrays(&bad, &wo, EvalOptions::default(), &mut got)
            .unwrap_err()
            .to_string();
        assert!(err.starts_with("row 4200: pair (["), "{err}");
        assert!(err.contains("outside the stored domain θ ≤ 60°"), "{err}");
        let zero = EvalOptions {
            outside_domain_zero: true,
            ..Default::default()
        };
        let err = e.eval_arrays(&bad, &wo, zero, &mut got).unwrap_err();
        assert_eq!(
            err.to_string(),
            "row 4300: wi has zero length (expected a direction)"
        );
        bad[3 * 4300..3 * 4300 + 3].copy_from_slice(&[0.0, 0.0, 1.0]);
        e.eval_arrays(&bad, &wo, zero, &mut got).unwrap();
        e.eval_arrays(
            &bad,
            &wo,
            EvalOptions {
                exact: true,
                ..zero
            },
            &mut exact,
        )
        .unwrap();
        assert_eq!(bits(&got), bits(&exact));
        assert_eq!(got[3 * 4200..3 * 4200 + 3], [0.0; 3]);
    }

    #[test]
    fn the_domain_rule_names_the_limit() {
        let t = crate::tabulate::tabulate(
            &crate::model::Model::parse("lambert:albedo=0.5").unwrap(),
            &crate::grid::parse_grid_spec("spherical3:4,theta-max=60").unwrap(),
            &Default::default(),
        )
        .unwrap();
        let t = crate::table::InterpolatedTable {
            table: t,
            interp: crate::table::Interp::Linear,
        };
        let low = Vec3::from_spherical(0.3, 0.0);
        let high = Vec3::from_spherical(1.3, 0.0);
        assert_eq!(outside_domain(&t, low, low), None);
        let e = outside_domain(&t, high, low).unwrap();
        assert!(e.contains("outside the stored domain θ ≤ 60°"), "{e}");
        // Below the horizon is a value (0), not an error.
        assert_eq!(outside_domain(&t, Vec3::new(0.0, 0.0, -1.0), high), None);
    }
}
