//! Opening a BRDF source named on the command line.
//!
//! Today a source is an analytic model spec (`Model::parse`: shell form, inline JSON or
//! `@file.json`); table files join here later without changing the callers.

use crate::brdf::Brdf;
use crate::model::Model;

/// Opens `spec` as a BRDF that can be evaluated pointwise.
///
/// Errors (exit 2) when the spec does not parse, or names a source that has no pointwise
/// value (a Dirac delta such as `mirror`: `Model::check_tabulable` says why).
pub fn open_brdf(spec: &str) -> crate::Result<Box<dyn Brdf>> {
    let model = Model::parse(spec)?;
    model.check_tabulable()?;
    Ok(Box::new(model))
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
}
