//! Analytic BRDF models of `spec/models.md`.
//!
//! One small type per physical idea (distributions, shadowing, Fresnel in their own files),
//! one struct per model, and the closed [`Model`] enum over them. Each model declares its
//! parameters once ([`params::ModelDecl`]); that table drives parsing of both spec forms
//! (canonical JSON and the compact shell form of `docs/models.md`), validation, the `models`
//! listing and the docs.
//!
//! Adding a model (e.g. `Htsg`): a struct with `from_params`, `to_json`, `eval_channels`
//! (channels `first..first + out.len()`, directions already above the horizon) and a
//! `DECL`; then one arm in each `match` below and one entry in [`CATALOG`].

pub mod ashikhmin_shirley;
pub(crate) mod compact;
pub mod fresnel;
pub mod lafortune;
pub mod lambert;
pub mod listing;
pub mod microfacet;
pub mod oren_nayar;
pub mod params;
pub mod phong;
pub mod sum;
pub mod torrance_sparrow;
pub mod ward;

pub use ashikhmin_shirley::AshikhminShirley;
pub use fresnel::{Fresnel, fresnel_conductor, fresnel_dielectric, fresnel_schlick};
pub use htsg::Htsg;
pub use lafortune::{Lafortune, LafortuneLobe};
pub use lambert::{Lambert, Mirror};
pub use microfacet::{
    BeckmannDistribution, BeckmannG1, Distribution, GgxDistribution, Microfacet, Shadowing,
};
pub use oren_nayar::OrenNayar;
pub use params::{Alias, ModelDecl, ParamDecl, ParamDefault, ParamKind};
pub use phong::{BlinnPhong, Phong};
pub use sum::Sum;
pub use torrance_sparrow::TorranceSparrow;
pub use ward::{Ward, WardVariant};

pub mod htsg;

use crate::brdf::{Brdf, Channels};
use crate::geometry::Vec3;
use crate::{Error, Result};
use params::ParamReader;
use serde_json::{Map, Value};

/// Every model, in listing order.
pub const CATALOG: &[ModelDecl] = &[
    lambert::LAMBERT_DECL,
    lambert::MIRROR_DECL,
    phong::PHONG_DECL,
    phong::BLINN_PHONG_DECL,
    torrance_sparrow::DECL,
    microfacet::DECL,
    ward::DECL,
    oren_nayar::DECL,
    ashikhmin_shirley::DECL,
    lafortune::DECL,
    htsg::DECL,
    sum::DECL,
];

/// Nesting limit for sums inside sums (a hostile spec could otherwise recurse deeply).
const MAX_DEPTH: usize = 8;

/// The files a model spec may name: a whole spec (`@spec.json`) and optical constants
/// (`nk = @file.csv`). The models parse text and never open files; a layer above reads them
/// (`io::ModelFiles`, behind `Model::parse`), or a caller supplies its own.
pub trait SpecFiles {
    /// The JSON of the spec file `path` (as written after `@`).
    fn spec_json(&self, path: &str) -> Result<Value>;
    /// The optical constants of the CSV file `path` (as written, `@` removed).
    fn optical_constants(&self, path: &str) -> Result<crate::spectral::OpticalConstants>;
}

/// No files: a spec that names one is refused (for specs known to name none).
pub struct NoFiles;

impl SpecFiles for NoFiles {
    fn spec_json(&self, path: &str) -> Result<Value> {
        Err(Error::input(format!(
            "model spec @{path}: files are not read here"
        )))
    }
    fn optical_constants(&self, path: &str) -> Result<crate::spectral::OpticalConstants> {
        Err(Error::input(format!(
            "optical constants {path}: files are not read here"
        )))
    }
}

/// The largest finite value for results that exceed the f64 range. This happens only where
/// the exact BRDF value itself is above ~1.8e308: directions within ~1e-150 of the horizon
/// (1/(c_i c_o) factors), or Lafortune lobes with |C| > 1 and huge exponents. Returning
/// f64::MAX keeps every output finite as the crate promises; NaN is never passed through.
#[inline]
pub(crate) fn finite_large(x: f64) -> f64 {
    debug_assert!(!x.is_nan(), "NaN in a model evaluation");
    x.min(f64::MAX)
}

/// An analytic BRDF.
#[derive(Clone, Debug)]
pub enum Model {
    Lambert(Lambert),
    Mirror(Mirror),
    Phong(Phong),
    BlinnPhong(BlinnPhong),
    TorranceSparrow(TorranceSparrow),
    Microfacet(Microfacet),
    Ward(Ward),
    OrenNayar(OrenNayar),
    AshikhminShirley(AshikhminShirley),
    Lafortune(Lafortune),
    Htsg(Htsg),
    Sum(Sum),
}

/// Finds a model declaration by canonical name or alias.
pub fn find_decl(name: &str) -> Option<(&'static ModelDecl, Option<&'static Alias>)> {
    for decl in CATALOG {
        if decl.name == name {
            return Some((decl, None));
        }
        if let Some(alias) = decl.aliases.iter().find(|a| a.name == name) {
            return Some((decl, Some(alias)));
        }
    }
    None
}

fn unknown_model(name: &str) -> Error {
    let mut names: Vec<&str> = Vec::new();
    for d in CATALOG {
        names.push(d.name);
        names.extend(d.aliases.iter().map(|a| a.name));
    }
    Error::input(format!(
        "unknown model {name:?} (known: {}; `brdfpack models` lists their parameters)",
        names.join(", ")
    ))
}

impl Model {
    /// Parses a model from the compact shell form (`ggx:alpha=0.2,fresnel=au`, see
    /// `docs/models.md`), inline JSON (`{...}`) or a JSON file (`@file.json`), the files it
    /// names read by `files` (`Model::parse` in `io` reads them from disk).
    pub fn parse_with(spec: &str, files: &dyn SpecFiles) -> Result<Model> {
        let spec = spec.trim();
        if spec.is_empty() {
            return Err(Error::input(
                "empty model spec (e.g. lambert:albedo=0.8 or ggx:alpha=0.2,fresnel=au)",
            ));
        }
        if spec.starts_with('{') {
            crate::text::reject_duplicate_json_keys(spec.as_bytes()).map_err(|e| {
                Error::input(format!(
                    "model JSON {}: {e}",
                    crate::text::sanitize_short(spec)
                ))
            })?;
            let v: Value = serde_json::from_str(spec)
                .map_err(|e| Error::input(format!("model JSON {spec:?}: {e}")))?;
            return Model::from_json_with(&v, files);
        }
        if let Some(path) = spec.strip_prefix('@') {
            return Model::from_json_with(&files.spec_json(path)?, files);
        }
        Model::from_json_with(&compact::compact_to_json(spec)?, files)
    }

    /// Builds a model from the canonical JSON form of `spec/models.md`
    /// (`{"model": "microfacet", "alpha": 0.2, ...}`); aliases (`ggx`) are accepted as names.
    /// The data files it names are read by `files`.
    pub fn from_json_with(v: &Value, files: &dyn SpecFiles) -> Result<Model> {
        Model::from_json_at_depth(v, 0, files)
    }

    pub(crate) fn from_json_at_depth(
        v: &Value,
        depth: usize,
        files: &dyn SpecFiles,
    ) -> Result<Model> {
        if depth > MAX_DEPTH {
            return Err(Error::input(format!(
                "model JSON: sums nested more than {MAX_DEPTH} deep"
            )));
        }
        let Value::Object(obj) = v else {
            return Err(Error::input(format!(
                "model JSON: expected an object {{\"model\": name, ...}}, got {}",
                truncate(&v.to_string(), 80)
            )));
        };
        let name = match obj.get("model") {
            Some(Value::String(s)) => s.as_str(),
            Some(other) => {
                return Err(Error::input(format!(
                    "model JSON: \"model\" = {} is not a model name",
                    truncate(&other.to_string(), 80)
                )));
            }
            None => {
                return Err(Error::input(
                    "model JSON: \"model\" (the model name) is missing",
                ));
            }
        };
        let (decl, alias) = find_decl(name).ok_or_else(|| unknown_model(name))?;
        let merged;
        let obj = match alias {
            None => obj,
            Some(alias) => {
                merged = apply_preset(decl.name, alias, obj)?;
                &merged
            }
        };
        let r = ParamReader::new(decl.name, "", obj, decl.params, &["model"], files)?;
        Ok(match decl.name {
            "lambert" => Model::Lambert(Lambert::from_params(&r)?),
            "mirror" => Model::Mirror(Mirror::from_params(&r)?),
            "phong" => Model::Phong(Phong::from_params(&r)?),
            "blinn-phong" => Model::BlinnPhong(BlinnPhong::from_params(&r)?),
            "torrance-sparrow" => Model::TorranceSparrow(TorranceSparrow::from_params(&r)?),
            "microfacet" => Model::Microfacet(Microfacet::from_params(&r)?),
            "ward" => Model::Ward(Ward::from_params(&r)?),
            "oren-nayar" => Model::OrenNayar(OrenNayar::from_params(&r)?),
            "ashikhmin-shirley" => Model::AshikhminShirley(AshikhminShirley::from_params(&r)?),
            "lafortune" => Model::Lafortune(Lafortune::from_params(&r)?),
            "htsg" => Model::Htsg(Htsg::from_params(&r)?),
            "sum" => Model::Sum(Sum::from_params(&r, depth)?),
            // Every CATALOG name has an arm above.
            other => unreachable!("model {other} is declared but not constructed"),
        })
    }

    /// The canonical JSON form: canonical name, every parameter written out (named metals as
    /// η and k), per-channel values as lists when the model has more than one channel.
    /// `Model::from_json(&m.to_json())` rebuilds the same model.
    pub fn to_json(&self) -> Value {
        let mut v = match self {
            Model::Lambert(m) => m.to_json(),
            Model::Mirror(m) => m.to_json(),
            Model::Phong(m) => m.to_json(),
            Model::BlinnPhong(m) => m.to_json(),
            Model::TorranceSparrow(m) => m.to_json(),
            Model::Microfacet(m) => m.to_json(),
            Model::Ward(m) => m.to_json(),
            Model::OrenNayar(m) => m.to_json(),
            Model::AshikhminShirley(m) => m.to_json(),
            Model::Lafortune(m) => m.to_json(),
            // HTSG writes its wavelengths itself (µm, spec/models.md); a sum's terms carry theirs.
            Model::Htsg(m) => return m.to_json(),
            Model::Sum(m) => return m.to_json(),
        };
        if let (Some(w), Value::Object(obj)) = (self.channels().wavelengths_nm(), &mut v) {
            obj.insert(params::WAVELENGTHS_NM.name.into(), params::channel_json(w));
        }
        v
    }

    /// The canonical model name (`microfacet` for `ggx`).
    pub fn name(&self) -> &'static str {
        self.decl().name
    }

    /// The declaration of this model's kind.
    pub fn decl(&self) -> &'static ModelDecl {
        match self {
            Model::Lambert(_) => &lambert::LAMBERT_DECL,
            Model::Mirror(_) => &lambert::MIRROR_DECL,
            Model::Phong(_) => &phong::PHONG_DECL,
            Model::BlinnPhong(_) => &phong::BLINN_PHONG_DECL,
            Model::TorranceSparrow(_) => &torrance_sparrow::DECL,
            Model::Microfacet(_) => &microfacet::DECL,
            Model::Ward(_) => &ward::DECL,
            Model::OrenNayar(_) => &oren_nayar::DECL,
            Model::AshikhminShirley(_) => &ashikhmin_shirley::DECL,
            Model::Lafortune(_) => &lafortune::DECL,
            Model::Htsg(_) => &htsg::DECL,
            Model::Sum(_) => &sum::DECL,
        }
    }

    /// Every model's declaration (parameters, defaults, ranges, properties).
    pub fn catalog() -> &'static [ModelDecl] {
        CATALOG
    }

    /// Ok when the model can be evaluated pointwise and tabulated; a Dirac delta cannot.
    pub fn check_tabulable(&self) -> Result<()> {
        match self {
            Model::Mirror(m) => Err(Error::input(format!(
                "mirror: a perfect mirror is a Dirac delta (all light leaves at \
                 wo = (−wi.x, −wi.y, wi.z)) and cannot be evaluated pointwise or tabulated; use a \
                 very smooth microfacet model instead, e.g. ggx:alpha=0.001 (its albedo ρ = {} is \
                 reported separately)",
                m.albedo
                    .iter()
                    .map(|a| params::fmt_num(*a))
                    .collect::<Vec<_>>()
                    .join("/")
            ))),
            Model::Sum(s) => {
                for (i, t) in s.terms.iter().enumerate() {
                    t.check_tabulable()
                        .map_err(|e| Error::input(format!("sum: terms[{i}]: {e}")))?;
                }
                Ok(())
            }
            _ => Ok(()),
        }
    }

    /// The albedo ρ of the Dirac-delta part (per channel), when the model has one.
    pub fn delta_albedo(&self) -> Option<Vec<f64>> {
        match self {
            Model::Mirror(m) => Some(m.albedo.clone()),
            Model::Sum(s) => {
                let c = s.channels.len();
                let mut total: Option<Vec<f64>> = None;
                for t in &s.terms {
                    if let Some(a) = t.delta_albedo() {
                        let acc = total.get_or_insert_with(|| vec![0.0; c]);
                        for (ch, v) in acc.iter_mut().enumerate() {
                            // A single-channel term applies to every channel.
                            *v += if a.len() == 1 { a[0] } else { a[ch] };
                        }
                    }
                }
                total
            }
            _ => None,
        }
    }

    /// The built-in material `pack` uses when no model is given: GGX α = 0.2,
    /// height-correlated Smith, conductor Fresnel of gold (`au`).
    pub fn default_material() -> Model {
        // A constant spec of this crate: failing to parse it is a bug.
        Model::parse_with(
            "ggx:alpha=0.2,shadowing=smith-correlated,fresnel=au",
            &NoFiles,
        )
        .expect("the default material parses")
    }

    /// Channels `first..first + out.len()` of f(wi, wo) for directions strictly above the
    /// horizon (the caller has checked wi.z > 0 and wo.z > 0).
    #[inline]
    pub(crate) fn eval_channels(&self, wi: Vec3, wo: Vec3, first: usize, out: &mut [f64]) {
        match self {
            Model::Lambert(m) => m.eval_channels(wi, wo, first, out),
            // A delta has no pointwise value; callers must call check_tabulable first.
            Model::Mirror(_) => out.fill(0.0),
            Model::Phong(m) => m.eval_channels(wi, wo, first, out),
            Model::BlinnPhong(m) => m.eval_channels(wi, wo, first, out),
            Model::TorranceSparrow(m) => m.eval_channels(wi, wo, first, out),
            Model::Microfacet(m) => m.eval_channels(wi, wo, first, out),
            Model::Ward(m) => m.eval_channels(wi, wo, first, out),
            Model::OrenNayar(m) => m.eval_channels(wi, wo, first, out),
            Model::AshikhminShirley(m) => m.eval_channels(wi, wo, first, out),
            Model::Lafortune(m) => m.eval_channels(wi, wo, first, out),
            Model::Htsg(m) => {
                m.eval_range(wi, wo, first, out);
            }
            Model::Sum(m) => m.eval_channels(wi, wo, first, out),
        }
    }
}

impl Brdf for Model {
    fn channels(&self) -> &Channels {
        match self {
            Model::Lambert(m) => &m.channels,
            Model::Mirror(m) => &m.channels,
            Model::Phong(m) => &m.channels,
            Model::BlinnPhong(m) => &m.channels,
            Model::TorranceSparrow(m) => &m.channels,
            Model::Microfacet(m) => &m.channels,
            Model::Ward(m) => &m.channels,
            Model::OrenNayar(m) => &m.channels,
            Model::AshikhminShirley(m) => &m.channels,
            Model::Lafortune(m) => &m.channels,
            Model::Htsg(m) => m.channel_names(),
            Model::Sum(m) => &m.channels,
        }
    }

    /// f_r(wi, wo). A `mirror` (Dirac delta) writes zeros: check `check_tabulable` first.
    #[inline]
    fn eval(&self, wi: Vec3, wo: Vec3, out: &mut [f64]) {
        let n = self.channels().len().min(out.len());
        let out = &mut out[..n];
        // One-sided: the horizon counts as below (spec); written as !(a && b) so that a NaN
        // z also gives 0 rather than reaching the formulas.
        if !(wi.z > 0.0 && wo.z > 0.0) {
            out.fill(0.0);
            return;
        }
        self.eval_channels(wi, wo, 0, out);
    }

    fn is_isotropic(&self) -> bool {
        match self {
            Model::Microfacet(m) => m.is_isotropic(),
            Model::Ward(m) => m.is_isotropic(),
            Model::AshikhminShirley(m) => m.is_isotropic(),
            Model::Lafortune(m) => m.is_isotropic(),
            Model::Sum(s) => s.terms.iter().all(Brdf::is_isotropic),
            Model::Lambert(_)
            | Model::Mirror(_)
            | Model::Phong(_)
            | Model::BlinnPhong(_)
            | Model::TorranceSparrow(_)
            | Model::OrenNayar(_)
            | Model::Htsg(_) => true,
        }
    }

    fn describe(&self) -> String {
        self.to_json().to_string()
    }

    /// The coefficient of the Dirac-delta (specular) part per channel for light arriving
    /// from `wi`, when the model has one: ρ for a `mirror`, ρ_s(wi) for `htsg`, summed over
    /// the terms of a sum. This part is never in f_r or in a table; reports show it apart.
    fn specular_coefficient(&self, wi: Vec3) -> Option<Vec<f64>> {
        match self {
            Model::Mirror(m) => Some(if wi.z > 0.0 {
                m.albedo.clone()
            } else {
                vec![0.0; m.albedo.len()]
            }),
            Model::Htsg(m) => Some(m.specular_coefficient(wi)),
            Model::Sum(s) => {
                let c = s.channels.len();
                let mut total: Option<Vec<f64>> = None;
                for t in &s.terms {
                    if let Some(a) = t.specular_coefficient(wi) {
                        let acc = total.get_or_insert_with(|| vec![0.0; c]);
                        for (ch, v) in acc.iter_mut().enumerate() {
                            // A single-channel term applies to every channel.
                            *v += if a.len() == 1 { a[0] } else { a[ch] };
                        }
                    }
                }
                total
            }
            _ => None,
        }
    }

    /// For models evaluated by a series (`htsg`, also inside a sum): the largest number of
    /// series terms any channel sums over the fixed direction set of
    /// [`Htsg::series_terms_max`]; None for closed-form models.
    fn series_terms_max(&self) -> Option<usize> {
        match self {
            Model::Htsg(m) => Some(m.series_terms_max()),
            Model::Sum(s) => s.terms.iter().filter_map(Model::series_terms_max).max(),
            _ => None,
        }
    }

    fn provenance_notes(&self) -> Vec<String> {
        match self {
            Model::Htsg(m) => vec![m.tabulation_note()],
            Model::Sum(s) => s
                .terms
                .iter()
                .enumerate()
                .flat_map(|(i, t)| {
                    t.provenance_notes()
                        .into_iter()
                        .map(move |n| format!("sum: terms[{i}]: {n}"))
                })
                .collect(),
            _ => Vec::new(),
        }
    }

    fn as_any(&self) -> Option<&dyn std::any::Any> {
        Some(self)
    }
}

/// `obj` with the alias's preset parameters added; a conflicting explicit value is an error.
fn apply_preset(
    model: &str,
    alias: &Alias,
    obj: &Map<String, Value>,
) -> Result<Map<String, Value>> {
    let mut merged = obj.clone();
    for (key, value) in alias.preset {
        match merged.get(*key) {
            Some(Value::String(s)) if s == value => {}
            Some(other) => {
                return Err(Error::input(format!(
                    "{model}: {key} = {other} contradicts the name {:?}, which means {key} = {value}",
                    alias.name
                )));
            }
            None => {
                merged.insert((*key).to_string(), Value::from(*value));
            }
        }
    }
    merged.insert("model".into(), Value::from(model));
    Ok(merged)
}

/// Parameters whose value names a data file (`ParamKind::DataFile`): `nk` of conductors and
/// HTSG.
const DATA_FILE_PARAMS: &[&str] = &["nk"];

/// Every data file a model's JSON names, at any depth (sums, Fresnel objects), `@` removed.
pub(crate) fn data_files(v: &Value, out: &mut Vec<String>) {
    match v {
        Value::Object(obj) => {
            for (k, v) in obj {
                match v {
                    Value::String(s) if DATA_FILE_PARAMS.contains(&k.as_str()) => {
                        out.push(s.strip_prefix('@').unwrap_or(s).to_string());
                    }
                    other => data_files(other, out),
                }
            }
        }
        Value::Array(items) => items.iter().for_each(|v| data_files(v, out)),
        _ => {}
    }
}

fn truncate(s: &str, n: usize) -> String {
    if s.chars().count() <= n {
        s.to_string()
    } else {
        format!("{}…", s.chars().take(n).collect::<String>())
    }
}
