//! Sums of models (spec/models.md `sum`), e.g. lambert + microfacet.

use super::Model;
use super::finite_large;
use super::params::{ModelDecl, ParamDecl, ParamDefault, ParamKind, ParamReader};
use crate::brdf::{Brdf, Channels};
use crate::geometry::Vec3;
use crate::{Error, Result};
use serde_json::{Value, json};

/// Bound on the number of terms (and on nesting, through the parser's depth limit).
pub const MAX_TERMS: usize = 64;
/// Channels evaluated per chunk: `eval` stays allocation-free with any channel count.
const CHUNK: usize = 32;

pub const PARAMS: &[ParamDecl] =
    &[
        ParamDecl::structured("terms", ParamKind::Terms, ParamDefault::Required).doc(
            "",
            "",
            "the models to add (compact form: joined by +)",
            "",
        ),
    ];

pub const DECL: ModelDecl = ModelDecl {
    name: "sum",
    aliases: &[],
    summary: "sum of models (compact form: a + b + ...)",
    formula: "Σ terms",
    citation: "",
    params: PARAMS,
    isotropic: "when every term is",
    reciprocal: true,
    tabulable: true,
};

#[derive(Clone, Debug)]
pub struct Sum {
    pub terms: Vec<Model>,
    pub(crate) channels: Channels,
}

impl Sum {
    pub(crate) fn from_params(r: &ParamReader, depth: usize) -> Result<Sum> {
        let ctx = r.context();
        let items = match r.raw("terms") {
            Some(Value::Array(items)) if !items.is_empty() => items,
            Some(other) => {
                return Err(Error::input(format!(
                    "{ctx}: terms = {other} is not a non-empty list of models"
                )));
            }
            None => {
                return Err(Error::input(format!(
                    "{ctx}: terms is required (a list of models; compact form: a + b)"
                )));
            }
        };
        if items.len() > MAX_TERMS {
            return Err(Error::input(format!(
                "{ctx}: terms has {} entries; at most {MAX_TERMS} are accepted",
                items.len()
            )));
        }
        let terms = items
            .iter()
            .enumerate()
            .map(|(i, t)| {
                Model::from_json_at_depth(t, depth + 1, r.files())
                    .map_err(|e| Error::input(format!("{ctx}: terms[{i}]: {e}")))
            })
            .collect::<Result<Vec<Model>>>()?;
        Sum::new(terms)
    }

    /// The sum of `terms`; single-channel terms broadcast, the others must agree in C and
    /// in what their channels are (R, G, B or the same spectral wavelengths).
    pub fn new(terms: Vec<Model>) -> Result<Sum> {
        let mut first: Option<(usize, &Channels)> = None;
        for (i, t) in terms.iter().enumerate() {
            let ch = t.channels();
            let c = ch.len();
            if c <= 1 {
                continue;
            }
            match first {
                None => first = Some((i, ch)),
                Some((j, other)) if other.len() != c => {
                    return Err(Error::input(format!(
                        "sum: terms[{i}] has {c} channels but terms[{j}] has {} (channel counts \
                         must agree; a single-channel term applies to every channel)",
                        other.len()
                    )));
                }
                Some((j, other)) if other != ch => {
                    return Err(Error::input(format!(
                        "sum: terms[{i}] has channels {} but terms[{j}] has {} (adding different \
                         channels is meaningless; give every multi-channel term the same \
                         wavelengths_nm)",
                        ch.names().join(", "),
                        other.names().join(", ")
                    )));
                }
                Some(_) => {}
            }
        }
        let channels = first.map_or_else(|| Channels::default_for(1), |(_, ch)| ch.clone());
        Ok(Sum { terms, channels })
    }

    pub(crate) fn to_json(&self) -> Value {
        json!({"model": "sum", "terms": self.terms.iter().map(Model::to_json).collect::<Vec<_>>()})
    }

    #[inline]
    pub(crate) fn eval_channels(&self, wi: Vec3, wo: Vec3, first: usize, out: &mut [f64]) {
        out.fill(0.0);
        let mut buf = [0.0f64; CHUNK];
        for term in &self.terms {
            if term.channels().len() == 1 {
                // A single-channel term applies to every channel.
                term.eval_channels(wi, wo, 0, &mut buf[..1]);
                for o in out.iter_mut() {
                    *o += buf[0];
                }
                continue;
            }
            for (k, chunk) in out.chunks_mut(CHUNK).enumerate() {
                let part = &mut buf[..chunk.len()];
                term.eval_channels(wi, wo, first + k * CHUNK, part);
                for (o, t) in chunk.iter_mut().zip(part.iter()) {
                    *o += t;
                }
            }
        }
        for o in out.iter_mut() {
            // Finite terms near f64::MAX can add up past it: keep the largest finite value.
            *o = finite_large(*o);
        }
    }
}
