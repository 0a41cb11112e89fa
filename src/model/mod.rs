//! Analytic BRDF models of `spec/models.md`.
//!
//! PLACEHOLDER: only `lambert` exists until the models work lands. The public surface
//! below (`Model::parse`, `Model::from_json`, `Model::to_json`, `Model::check_tabulable`,
//! `Model::default_material`, `impl Brdf for Model`) is the contract the rest of the crate uses.

pub mod htsg;

use crate::brdf::{Brdf, Channels};
use crate::geometry::Vec3;
use crate::math::FRAC_1_PI;
use crate::{Error, Result};

/// An analytic BRDF.
#[derive(Clone, Debug)]
pub enum Model {
    Lambert {
        albedo: Vec<f64>,
        channels: Channels,
    },
}

impl Model {
    /// Parses a model from the compact shell form, inline JSON (`{...}`) or `@file.json`.
    pub fn parse(spec: &str) -> Result<Model> {
        let spec = spec.trim();
        if spec.starts_with('{') {
            let v: serde_json::Value =
                serde_json::from_str(spec).map_err(|e| Error::input(format!("model JSON: {e}")))?;
            return Model::from_json(&v);
        }
        let (name, params) = spec.split_once(':').unwrap_or((spec, ""));
        match name {
            "lambert" => {
                let mut albedo = vec![0.5];
                for kv in params.split(',').filter(|s| !s.is_empty()) {
                    let (k, v) = kv.split_once('=').ok_or_else(|| {
                        Error::input(format!("model parameter {kv:?}: expected key=value"))
                    })?;
                    if k != "albedo" {
                        return Err(Error::input(format!("lambert: unknown parameter {k:?}")));
                    }
                    albedo = v
                        .split('/')
                        .map(|x| {
                            x.parse::<f64>()
                                .map_err(|_| Error::input(format!("albedo: {x:?} is not a number")))
                        })
                        .collect::<Result<_>>()?;
                }
                Ok(Model::lambert(albedo))
            }
            _ => Err(Error::input(format!("unknown model {name:?}"))),
        }
    }

    /// Builds a model from the canonical JSON form of `spec/models.md`.
    pub fn from_json(v: &serde_json::Value) -> Result<Model> {
        match v.get("model").and_then(|m| m.as_str()) {
            Some("lambert") => {
                let albedo = match v.get("albedo") {
                    None => vec![0.5],
                    Some(serde_json::Value::Array(a)) => {
                        a.iter().filter_map(|x| x.as_f64()).collect()
                    }
                    Some(x) => vec![x.as_f64().unwrap_or(0.5)],
                };
                Ok(Model::lambert(albedo))
            }
            other => Err(Error::input(format!("unknown model {other:?}"))),
        }
    }

    fn lambert(albedo: Vec<f64>) -> Model {
        let channels = Channels::default_for(albedo.len());
        Model::Lambert { albedo, channels }
    }

    /// The canonical JSON form (every parameter written out).
    pub fn to_json(&self) -> serde_json::Value {
        match self {
            Model::Lambert { albedo, .. } => {
                serde_json::json!({"model": "lambert", "albedo": albedo})
            }
        }
    }

    /// Ok when the model can be evaluated pointwise and tabulated (a Dirac delta cannot).
    pub fn check_tabulable(&self) -> Result<()> {
        Ok(())
    }

    /// The built-in material `pack` uses when no model is given.
    pub fn default_material() -> Model {
        Model::lambert(vec![0.8, 0.5, 0.2])
    }
}

impl Brdf for Model {
    fn channels(&self) -> &Channels {
        match self {
            Model::Lambert { channels, .. } => channels,
        }
    }
    fn eval(&self, wi: Vec3, wo: Vec3, out: &mut [f64]) {
        if wi.z <= 0.0 || wo.z <= 0.0 {
            out.fill(0.0);
            return;
        }
        match self {
            Model::Lambert { albedo, .. } => {
                for (o, a) in out.iter_mut().zip(albedo) {
                    *o = a * FRAC_1_PI;
                }
            }
        }
    }
    fn is_isotropic(&self) -> bool {
        true
    }
    fn describe(&self) -> String {
        self.to_json().to_string()
    }
}
