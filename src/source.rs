//! Opening a BRDF source named on the command line: a table file (native `.bpk`, EXR, MERL
//! `.binary`), a measured file (RGL `.bsdf`), or an analytic model spec (`Model::parse`: shell
//! form, inline JSON or `@file.json`). A name that exists as a file (or `-` for stdin) is read
//! as a file, recognised by its content.

use crate::brdf::Brdf;
use crate::io::{self, Format, atomic, merl::MerlLookup, rgl::RglBsdf};
use crate::model::Model;
use crate::table::{Interp, InterpolatedTable, Table};
use crate::{Error, Result};
use std::path::Path;

/// How a table source is evaluated between its samples.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default)]
pub enum Lookup {
    /// Multilinear in warped index space (docs/parameterizations.md).
    #[default]
    Linear,
    /// The nearest sample.
    Nearest,
    /// The MERL reference reader's nearest-lower-bin rule, exactly (MERL-grid tables only).
    Merl,
}

/// A source opened from a name.
// One value per command: the size difference between variants costs nothing.
#[allow(clippy::large_enum_variant)]
pub enum Source {
    Table(Table),
    Measured(RglBsdf),
    Model(Model),
}

impl Source {
    /// The source with negative values of a measured file clamped to 0 when `on` (RGL files
    /// hold some; by default they are passed through, as the reference evaluator does).
    /// Tables and models are returned as they are.
    pub fn clamp_negative(self, on: bool) -> Source {
        match self {
            Source::Measured(m) if on => Source::Measured(m.with_clamp_negative(true)),
            other => other,
        }
    }

    /// Opens `spec`: a model spec, else an existing file (or `-`) by its content. A model
    /// spec is never shadowed by a file of the same name in the working directory: `./lambert`
    /// (a name starting with `./`, `../` or `/`) always means the file.
    pub fn open(spec: &str) -> Result<Source> {
        Source::open_recording(spec, &mut crate::reads::ReadSet::new())
    }

    /// [`Source::open`], recording every file read in `reads` (the source file, or a model
    /// spec's `@file.json` and data files) for depfiles and build caches.
    pub fn open_recording(spec: &str, reads: &mut crate::reads::ReadSet) -> Result<Source> {
        let path = Path::new(spec);
        let explicit_path = spec == "-"
            || spec.starts_with("./")
            || spec.starts_with("../")
            || spec.starts_with('/');
        let parsed = if explicit_path {
            None
        } else {
            match Model::parse_recording(spec, reads) {
                Ok(m) => return Ok(Source::Model(m)),
                Err(e) => Some(e),
            }
        };
        // Any existing non-directory: regular files, and devices, FIFOs, /dev/stdin.
        if spec == "-" || path.exists() {
            if spec != "-"
                && let Some(t) = io::merl::read_regular_file(path)?
            {
                reads.record(path);
                return Ok(Source::Table(t));
            }
            let bytes = atomic::read_input(path)?;
            reads.record(path);
            return match io::detect(&bytes, path) {
                Format::Rgl => Ok(Source::Measured(RglBsdf::from_bytes(
                    &bytes,
                    &path.display().to_string(),
                )?)),
                // A source may also be an RGL file: the list says so.
                Format::Unknown => Err(io::unknown_format(&bytes, path, true)),
                _ => Ok(Source::Table(io::decode_table(&bytes, path)?)),
            };
        }
        let Some(parse_error) = parsed else {
            return Err(Error::io(
                path,
                std::io::Error::new(std::io::ErrorKind::NotFound, "no such file"),
            ));
        };
        // A name that looks like a file but is none: say so rather than "unknown model". A
        // `name:params` spec is a model spec with a mistake, even when a parameter holds a `/`
        // (per-channel values, `lobes=0.9/0.9/1.0/20`): its own parse error says which.
        let model_shaped = spec.split_once(':').is_some_and(|(name, _)| {
            name.len() > 1
                && name
                    .chars()
                    .all(|c| c.is_ascii_alphanumeric() || c == '-' || c == '_')
        });
        if !spec.starts_with('@')
            && !spec.starts_with('{')
            && !model_shaped
            && (io::FormatName::from_path(path).is_some() || spec.contains('/'))
        {
            return Err(Error::io(
                path,
                std::io::Error::new(std::io::ErrorKind::NotFound, "no such file"),
            ));
        }
        Err(parse_error)
    }

    /// Refuses a table none of whose cells is valid (a MERL file of −1s, a table tabulated
    /// from one): it holds no value of the BRDF and every lookup of it is 0, so there is
    /// nothing to pack. `pack` and `build` ask before anything else: with a budget the planner
    /// refused such a table too, but with `--codec` it was tabulated and checked cell by cell
    /// through the nearest-valid fallback (22–25 s for a MERL file, exit 0, a file of 0s).
    /// The message is the planner's. Models, measured files and tables with a valid cell pass.
    pub fn require_valid_cells(&self) -> Result<()> {
        if let Source::Table(t) = self
            && !t.valid().contains(&true)
        {
            return Err(Error::input(format!(
                "{}: every one of its {} cells is marked invalid (for a MERL file, a negative \
                 stored value), so there is nothing to pack; no file written",
                t.provenance().source,
                t.valid().len()
            )));
        }
        Ok(())
    }

    /// The source as a pointwise BRDF; tables are evaluated by `lookup`. Errors for a
    /// model without pointwise values (a Dirac delta such as `mirror`), and for `merl`
    /// lookups of a table that is not on a MERL grid.
    pub fn into_brdf(self, lookup: Lookup) -> Result<Box<dyn Brdf>> {
        let interp = match lookup {
            Lookup::Nearest => Interp::Nearest,
            Lookup::Linear | Lookup::Merl => Interp::Linear,
        };
        Ok(match self {
            Source::Table(table) if lookup == Lookup::Merl => {
                Box::new(MerlLookup::from_table(&table)?)
            }
            // A pointwise BRDF reads the f32 samples only: a MERL file's exact f64 values
            // (35 MB) would be held idle through a whole `pack` (its peak: 148 → 113 MB).
            Source::Table(table) => Box::new(InterpolatedTable {
                table: table.without_exact(),
                interp,
            }),
            _ if lookup == Lookup::Merl => {
                return Err(Error::input(
                    "--interp merl applies to MERL-grid tables only (this source is not a table)",
                ));
            }
            Source::Measured(m) => Box::new(m),
            Source::Model(m) => {
                m.check_tabulable()?;
                Box::new(m)
            }
        })
    }
}

/// Opens `spec` as a BRDF that can be evaluated pointwise (tables: linear interpolation).
pub fn open_brdf(spec: &str) -> Result<Box<dyn Brdf>> {
    Source::open(spec)?.into_brdf(Lookup::Linear)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::Vec3;

    #[test]
    fn opens_a_model_spec() {
        let b = open_brdf("lambert:albedo=0.3").unwrap();
        let mut out = [0.0];
        b.eval(Vec3::Z, Vec3::Z, &mut out);
        assert!((out[0] - 0.3 / std::f64::consts::PI).abs() < 1e-15);
    }

    #[test]
    fn rejects_an_unknown_model() {
        let e = open_brdf("no-such-model").err().unwrap();
        assert_eq!(e.exit_code(), 2);
        assert!(e.to_string().contains("no-such-model"), "{e}");
    }

    #[test]
    fn refuses_a_delta() {
        let e = open_brdf("mirror").err().unwrap();
        assert_eq!(e.exit_code(), 2);
    }
}
