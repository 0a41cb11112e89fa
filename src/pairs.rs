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
            // One pass per chunk of rows: check and normalize them into a small buffer, then
            // look them up (the two-pass form wrote and re-read 48 bytes per pair, a fifth of
            // a 10⁶-pair call). The first bad row is the error, for any thread count.
            const ROWS: usize = 4096;
            let first_bad = out
                .par_chunks_mut(ROWS * c)
                .enumerate()
                .map_init(
                    || Vec::with_capacity(ROWS),
                    |buf, (k, out)| {
                        buf.clear();
                        for j in 0..out.len() / c {
                            buf.push(checked_pair(brdf, wi, wo, k * ROWS + j, opts)?);
                        }
                        t.table.eval_batch_serial(buf, t.interp, out);
                        Ok(())
                    },
                )
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
    if !opts.outside_domain_zero
        && let Some(why) = outside_domain(brdf, wi, wo)
    {
        return Err(at(format!(
            "{why}; ask for outside-domain-zero to get 0 there"
        )));
    }
    Ok((wi, wo))
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
