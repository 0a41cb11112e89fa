//! Opening a BRDF source named on the command line: a table file (native), a measured file
//! (RGL `.bsdf`), or an analytic model spec (`Model::parse`: shell form, inline JSON or
//! `@file.json`). A name that exists as a file (or `-` for stdin) is read as a file.

use crate::brdf::Brdf;
use crate::io::{atomic, native, rgl::RglBsdf};
use crate::model::Model;
use crate::table::{Interp, InterpolatedTable, Table};
use crate::{Error, Result};
use std::path::Path;

/// A source opened from a name.
// One value per command: the size difference between variants costs nothing.
#[allow(clippy::large_enum_variant)]
pub enum Source {
    Table(Table),
    Measured(RglBsdf),
    Model(Model),
}

impl Source {
    /// Opens `spec`: an existing file (or `-`) by its content, anything else as a model spec.
    pub fn open(spec: &str) -> Result<Source> {
        let path = Path::new(spec);
        if spec == "-" || path.is_file() {
            let bytes = atomic::read_input(path)?;
            if native::is_native(&bytes) {
                return Ok(Source::Table(native::from_bytes(&bytes, path)?));
            }
            if bytes.starts_with(b"tensor_file\0") {
                return Ok(Source::Measured(RglBsdf::from_bytes(
                    &bytes,
                    &path.display().to_string(),
                )?));
            }
            return Err(Error::invalid_file(
                path,
                "not a recognised format (expected a brdfpack .bpk table or an RGL .bsdf file)",
            ));
        }
        Ok(Source::Model(Model::parse(spec)?))
    }

    /// The source as a pointwise BRDF; tables are interpolated by `interp`. Errors for a
    /// model without pointwise values (a Dirac delta such as `mirror`).
    pub fn into_brdf(self, interp: Interp) -> Result<Box<dyn Brdf>> {
        Ok(match self {
            Source::Table(table) => Box::new(InterpolatedTable { table, interp }),
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
    Source::open(spec)?.into_brdf(Interp::Linear)
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
