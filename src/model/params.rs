//! Parameter declarations (style.md #5): each model declares its parameters once, and the same
//! table drives parsing and validation ([`ParamReader`]), the compact grammar, the `models`
//! listing and `docs/models.md`.

use crate::brdf::Channels;
use crate::{Error, Result};
use serde_json::{Map, Value, json};

/// What kind of value a parameter takes.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum ParamKind {
    /// A real number in `[min, max]` (both inclusive); per-channel parameters take a scalar or a
    /// list of numbers.
    Number { min: f64, max: f64 },
    /// One word of a fixed set.
    Choice(&'static [&'static str]),
    /// A Fresnel term: an object `{"type": ..}` with the fields of one of
    /// [`super::fresnel::FRESNEL_TYPES`], or the name of a type without fields / a metal.
    Fresnel,
    /// Lafortune lobes: a list of objects with the fields of [`super::lafortune::LOBE_PARAMS`].
    Lobes,
    /// A list of models (the terms of a sum).
    Terms,
    /// A data file named as `@path` (e.g. a CSV of tabulated η, k over wavelength).
    DataFile(&'static str),
}

/// The value a parameter takes when it is not given.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum ParamDefault {
    /// Must be given: leaving it out is an error, never a silent default.
    Required,
    Number(f64),
    Word(&'static str),
    /// A structured default written in canonical JSON (e.g. a Fresnel object).
    Json(&'static str),
    /// No default of its own; the text says what applies instead.
    Derived(&'static str),
}

/// One parameter of a model: everything parsing, validation, listing and docs need.
#[derive(Clone, Copy, Debug)]
pub struct ParamDecl {
    pub name: &'static str,
    /// The symbol the papers and `spec/models.md` use (`α`, `ρ`, ...).
    pub symbol: &'static str,
    /// Physical unit (`1` for dimensionless, `rad`, ...).
    pub unit: &'static str,
    pub kind: ParamKind,
    pub default: ParamDefault,
    /// True when the parameter takes one value per channel (a scalar broadcasts).
    pub per_channel: bool,
    pub description: &'static str,
    /// Where the parameter (or its role in the formula) comes from.
    pub citation: &'static str,
}

impl ParamDecl {
    /// A scalar number in `[min, max]` with a default.
    pub const fn number(name: &'static str, min: f64, max: f64, default: f64) -> ParamDecl {
        ParamDecl {
            name,
            symbol: "",
            unit: "1",
            kind: ParamKind::Number { min, max },
            default: ParamDefault::Number(default),
            per_channel: false,
            description: "",
            citation: "",
        }
    }
    /// A word from `choices`, defaulting to `default`.
    pub const fn choice(
        name: &'static str,
        choices: &'static [&'static str],
        default: &'static str,
    ) -> ParamDecl {
        ParamDecl {
            kind: ParamKind::Choice(choices),
            default: ParamDefault::Word(default),
            ..ParamDecl::number(name, 0.0, 0.0, 0.0)
        }
    }
    /// A parameter of a structured kind (Fresnel, lobes, terms).
    pub const fn structured(name: &'static str, kind: ParamKind, default: ParamDefault) -> Self {
        ParamDecl {
            kind,
            default,
            ..ParamDecl::number(name, 0.0, 0.0, 0.0)
        }
    }
    /// One value per channel (a scalar broadcasts).
    pub const fn per_channel(self) -> Self {
        ParamDecl {
            per_channel: true,
            ..self
        }
    }
    /// Must be given.
    pub const fn required(self) -> Self {
        ParamDecl {
            default: ParamDefault::Required,
            ..self
        }
    }
    /// Default described by text (see [`ParamDefault::Derived`]).
    pub const fn derived_default(self, text: &'static str) -> Self {
        ParamDecl {
            default: ParamDefault::Derived(text),
            ..self
        }
    }
    /// Symbol, unit, description and citation.
    pub const fn doc(
        self,
        symbol: &'static str,
        unit: &'static str,
        description: &'static str,
        citation: &'static str,
    ) -> Self {
        ParamDecl {
            symbol,
            unit,
            description,
            citation,
            ..self
        }
    }

    /// The accepted values in words: `[1e-6, 10]`, `ggx | beckmann`, ...
    pub fn range_text(&self) -> String {
        match self.kind {
            ParamKind::Number { min, max } => format!("[{}, {}]", fmt_num(min), fmt_num(max)),
            ParamKind::Choice(c) => c.join(" | "),
            ParamKind::Fresnel => "fresnel type (below)".into(),
            ParamKind::Lobes => "list of lobes (below)".into(),
            ParamKind::Terms => "list of models".into(),
            ParamKind::DataFile(what) => format!("@file ({what})"),
        }
    }

    /// The default in words (`0.2`, `ggx`, `required`, ...).
    pub fn default_text(&self) -> String {
        match self.default {
            ParamDefault::Required => "required".into(),
            ParamDefault::Number(x) => fmt_num(x),
            ParamDefault::Word(w) => w.into(),
            ParamDefault::Json(j) => j.into(),
            ParamDefault::Derived(t) => t.into(),
        }
    }

    /// The declaration as JSON (for `models --json`).
    pub fn to_json(&self) -> Value {
        let mut v = json!({
            "name": self.name,
            "symbol": self.symbol,
            "unit": self.unit,
            "per_channel": self.per_channel,
            "description": self.description,
            "citation": self.citation,
            "default": self.default_text(),
            "range": self.range_text(),
        });
        match self.kind {
            ParamKind::Number { min, max } => {
                v["kind"] = "number".into();
                v["min"] = min.into();
                v["max"] = max.into();
            }
            ParamKind::Choice(c) => {
                v["kind"] = "choice".into();
                v["choices"] = c.into();
            }
            ParamKind::Fresnel => v["kind"] = "fresnel".into(),
            ParamKind::Lobes => v["kind"] = "lobes".into(),
            ParamKind::Terms => v["kind"] = "terms".into(),
            ParamKind::DataFile(what) => {
                v["kind"] = "file".into();
                v["contents"] = what.into();
            }
        }
        v
    }
}

/// A shorter name that presets some parameters of a model (`ggx` = microfacet with
/// `distribution = ggx`).
#[derive(Clone, Copy, Debug)]
pub struct Alias {
    pub name: &'static str,
    pub preset: &'static [(&'static str, &'static str)],
}

/// One model of the catalog: its name, what it computes and its parameters.
#[derive(Clone, Copy, Debug)]
pub struct ModelDecl {
    pub name: &'static str,
    pub aliases: &'static [Alias],
    pub summary: &'static str,
    /// The formula in one line, in the notation of `spec/models.md`.
    pub formula: &'static str,
    pub citation: &'static str,
    pub params: &'static [ParamDecl],
    /// When the model is isotropic (`always`, or the condition).
    pub isotropic: &'static str,
    pub reciprocal: bool,
    /// False for Dirac deltas, which cannot be evaluated pointwise or tabulated.
    pub tabulable: bool,
}

impl ModelDecl {
    pub fn param(&self, name: &str) -> Option<&'static ParamDecl> {
        self.params.iter().find(|p| p.name == name)
    }

    /// The declaration as JSON (for `models --json`).
    pub fn to_json(&self) -> Value {
        json!({
            "name": self.name,
            "aliases": self.aliases.iter().map(|a| {
                let preset: Map<String, Value> =
                    a.preset.iter().map(|(k, v)| (k.to_string(), Value::from(*v))).collect();
                json!({"name": a.name, "preset": preset})
            }).collect::<Vec<_>>(),
            "summary": self.summary,
            "formula": self.formula,
            "citation": self.citation,
            "isotropic": self.isotropic,
            "reciprocal": self.reciprocal,
            "tabulable": self.tabulable,
            "params": self.params.iter().map(ParamDecl::to_json).collect::<Vec<_>>(),
        })
    }
}

/// Formats a number for messages and listings: `1e-6`, `10`, `0.2`, `1e6`.
pub fn fmt_num(x: f64) -> String {
    if x.is_nan() {
        "NaN".into()
    } else if x != 0.0 && x.is_finite() && (x.abs() < 1e-3 || x.abs() >= 1e5) {
        format!("{x:e}")
    } else {
        format!("{x}")
    }
}

/// Upper bound on the channel count C (dense spectral sampling needs a few hundred); keeps a
/// hostile spec from making every evaluation and table enormous.
pub const MAX_CHANNELS: usize = 4096;

/// The parameter every model (but `sum`) accepts to make its channels spectral samples.
pub const WAVELENGTHS_NM: ParamDecl = ParamDecl::number("wavelengths_nm", 1.0, 1e6, 550.0)
    .per_channel()
    .derived_default("none (channels are not spectral)")
    .doc(
        "λ",
        "nm",
        "wavelength of each channel, strictly increasing; makes the channels spectral samples \
         named by wavelength (per-channel values then follow these wavelengths)",
        "docs/spectral.md",
    );

/// Tracks the lengths of per-channel lists so that they agree: scalars (and one-element
/// lists) broadcast; every longer list must have the same length C. When the model's
/// channels are spectral, it also holds their wavelengths, which fix C.
#[derive(Debug, Default)]
pub(crate) struct ChannelCount {
    first: Option<(String, usize)>,
    wavelengths_nm: Option<Vec<f64>>,
}

impl ChannelCount {
    /// A count whose C is fixed by spectral wavelengths (nm; already checked to be finite,
    /// positive and strictly increasing): every per-channel list must then have N values.
    pub fn spectral(name: &str, wavelengths_nm: Vec<f64>) -> ChannelCount {
        ChannelCount {
            first: Some((name.to_string(), wavelengths_nm.len())),
            wavelengths_nm: Some(wavelengths_nm),
        }
    }

    /// The spectral wavelengths (nm), when the channels are spectral.
    pub fn wavelengths_nm(&self) -> Option<&[f64]> {
        self.wavelengths_nm.as_deref()
    }

    /// The channels of a model with C = `c` channels: spectral samples named by wavelength,
    /// or the conventional names.
    pub fn channels(&self, c: usize) -> Channels {
        match &self.wavelengths_nm {
            Some(w) if w.len() == c => Channels::spectral(w.clone()),
            _ => Channels::default_for(c),
        }
    }

    /// Records that parameter `name` of `context` has `len` values.
    pub fn record(&mut self, context: &str, name: &str, len: usize) -> Result<()> {
        if len <= 1 {
            return Ok(());
        }
        if len > MAX_CHANNELS {
            return Err(Error::input(format!(
                "{context}: {name} has {len} values; at most {MAX_CHANNELS} channels are accepted"
            )));
        }
        match &self.first {
            None => self.first = Some((name.to_string(), len)),
            Some((first, n)) if *n != len => {
                return Err(Error::input(format!(
                    "{context}: {name} has {len} values but {first} has {n} \
                     (per-channel lists must agree in length; a scalar applies to every channel)"
                )));
            }
            Some(_) => {}
        }
        Ok(())
    }

    /// The channel count C (1 when every colour parameter is a scalar).
    pub fn count(&self) -> usize {
        self.first.as_ref().map_or(1, |(_, n)| *n)
    }
}

/// Checks that wavelengths are strictly increasing (they were range-checked already).
pub(crate) fn check_increasing(context: &str, name: &str, w: &[f64], unit: &str) -> Result<()> {
    for (i, pair) in w.windows(2).enumerate() {
        if pair[1] <= pair[0] {
            return Err(Error::input(format!(
                "{context}: {name}[{}] = {} {unit} is not greater than {name}[{i}] = {} {unit}; \
                 wavelengths must be strictly increasing",
                i + 1,
                fmt_num(pair[1]),
                fmt_num(pair[0])
            )));
        }
    }
    Ok(())
}

/// `v` with one value per channel: a single value is repeated `c` times.
pub(crate) fn broadcast(v: &[f64], c: usize) -> Vec<f64> {
    if v.len() == c {
        v.to_vec()
    } else {
        vec![v[0]; c]
    }
}

/// The canonical JSON of a per-channel value stored with one value per channel: a scalar for
/// one channel, a list otherwise (so that re-parsing gives the same channel count).
pub(crate) fn channel_json(v: &[f64]) -> Value {
    if v.len() == 1 { v[0].into() } else { v.into() }
}

/// Reads the parameters of one JSON object against its declarations. Every value is checked
/// here (type, finiteness, range, unknown keys), so both spec forms share one validation path.
pub(crate) struct ParamReader<'a> {
    /// The model name, for messages (`microfacet`).
    context: &'a str,
    /// Prefix of parameter names in messages (`fresnel.`, `lobes[1].`).
    prefix: String,
    obj: &'a Map<String, Value>,
    decls: &'static [ParamDecl],
    /// Where the files the parameters name are read (`nk = @file.csv`).
    files: &'a dyn super::SpecFiles,
}

impl<'a> ParamReader<'a> {
    /// Checks that every key of `obj` (other than `ignore`) is declared.
    pub fn new(
        context: &'a str,
        prefix: impl Into<String>,
        obj: &'a Map<String, Value>,
        decls: &'static [ParamDecl],
        ignore: &[&str],
        files: &'a dyn super::SpecFiles,
    ) -> Result<Self> {
        let prefix = prefix.into();
        for key in obj.keys() {
            if !ignore.contains(&key.as_str()) && !decls.iter().any(|d| d.name == key) {
                let accepted: Vec<&str> = decls.iter().map(|d| d.name).collect();
                return Err(Error::input(format!(
                    "{context}: unknown parameter {:?} (accepted: {})",
                    format!("{prefix}{key}"),
                    accepted.join(", ")
                )));
            }
        }
        Ok(ParamReader {
            context,
            prefix,
            obj,
            decls,
            files,
        })
    }

    /// The reader of the files the parameters name.
    pub fn files(&self) -> &'a dyn super::SpecFiles {
        self.files
    }

    pub fn context(&self) -> &'a str {
        self.context
    }

    fn decl(&self, name: &str) -> &'static ParamDecl {
        // A name missing from the table is a bug in this crate, not bad input.
        self.decls
            .iter()
            .find(|d| d.name == name)
            .unwrap_or_else(|| panic!("{}: parameter {name} is not declared", self.context))
    }

    /// The raw value of `name`, when given.
    pub fn raw(&self, name: &str) -> Option<&'a Value> {
        self.obj.get(name)
    }

    pub fn is_given(&self, name: &str) -> bool {
        self.obj.contains_key(name)
    }

    fn required_error(&self, d: &ParamDecl) -> Error {
        Error::input(format!(
            "{}: {}{} is required ({}; accepted: {})",
            self.context,
            self.prefix,
            d.name,
            d.description,
            d.range_text()
        ))
    }

    /// A scalar number, range-checked, or its default.
    pub fn number(&self, name: &str) -> Result<f64> {
        let d = self.decl(name);
        let ParamKind::Number { min, max } = d.kind else {
            panic!("{}: {name} is not a number parameter", self.context)
        };
        match self.obj.get(name) {
            None => match d.default {
                ParamDefault::Number(x) => Ok(x),
                _ => Err(self.required_error(d)),
            },
            Some(v) => {
                let x = v.as_f64().ok_or_else(|| {
                    Error::input(format!(
                        "{}: {}{name} = {v} is not a number (accepted: [{}, {}])",
                        self.context,
                        self.prefix,
                        fmt_num(min),
                        fmt_num(max)
                    ))
                })?;
                self.check_range(name, None, x, min, max)?;
                Ok(x)
            }
        }
    }

    /// A per-channel number: a scalar or a non-empty list, every value range-checked. Its
    /// length is recorded in `channels`; the caller broadcasts once C is known.
    pub fn channel(&self, name: &str, channels: &mut ChannelCount) -> Result<Vec<f64>> {
        let d = self.decl(name);
        let ParamKind::Number { min, max } = d.kind else {
            panic!("{}: {name} is not a number parameter", self.context)
        };
        let values = match self.obj.get(name) {
            None => match d.default {
                ParamDefault::Number(x) => vec![x],
                _ => return Err(self.required_error(d)),
            },
            Some(Value::Array(items)) => {
                if items.is_empty() {
                    return Err(Error::input(format!(
                        "{}: {}{name} = [] is empty (give a number or one number per channel)",
                        self.context, self.prefix
                    )));
                }
                let mut out = Vec::with_capacity(items.len());
                for (i, item) in items.iter().enumerate() {
                    let x = item.as_f64().ok_or_else(|| {
                        Error::input(format!(
                            "{}: {}{name}[{i}] = {item} is not a number",
                            self.context, self.prefix
                        ))
                    })?;
                    self.check_range(name, Some(i), x, min, max)?;
                    out.push(x);
                }
                out
            }
            Some(v) => {
                let x = v.as_f64().ok_or_else(|| {
                    Error::input(format!(
                        "{}: {}{name} = {v} is not a number or a list of numbers",
                        self.context, self.prefix
                    ))
                })?;
                self.check_range(name, None, x, min, max)?;
                vec![x]
            }
        };
        channels.record(
            self.context,
            &format!("{}{name}", self.prefix),
            values.len(),
        )?;
        Ok(values)
    }

    /// The channel count of a model: fixed by `wavelengths_nm` when that is given (checked
    /// to be strictly increasing), else empty.
    pub fn channel_count(&self) -> Result<ChannelCount> {
        if !self.is_given(WAVELENGTHS_NM.name) {
            return Ok(ChannelCount::default());
        }
        let mut scratch = ChannelCount::default();
        let w = self.channel(WAVELENGTHS_NM.name, &mut scratch)?;
        let name = format!("{}{}", self.prefix, WAVELENGTHS_NM.name);
        check_increasing(self.context, &name, &w, "nm")?;
        Ok(ChannelCount::spectral(&name, w))
    }

    /// The path of a data-file parameter (`@path`; the `@` is optional), when given.
    pub fn file(&self, name: &str) -> Result<Option<&'a str>> {
        let d = self.decl(name);
        let ParamKind::DataFile(what) = d.kind else {
            panic!("{}: {name} is not a file parameter", self.context)
        };
        match self.obj.get(name) {
            None => Ok(None),
            Some(Value::String(s)) if !s.trim_start_matches('@').is_empty() => {
                Ok(Some(s.strip_prefix('@').unwrap_or(s)))
            }
            Some(v) => Err(Error::input(format!(
                "{}: {}{name} = {v} is not a file name (expected \"@path\" of {what})",
                self.context, self.prefix
            ))),
        }
    }

    /// A word from the declared choices, or its default.
    pub fn word(&self, name: &str) -> Result<&'static str> {
        let d = self.decl(name);
        let ParamKind::Choice(choices) = d.kind else {
            panic!("{}: {name} is not a choice parameter", self.context)
        };
        match self.obj.get(name) {
            None => match d.default {
                ParamDefault::Word(w) => Ok(w),
                _ => Err(self.required_error(d)),
            },
            Some(v) => {
                let s = v.as_str().unwrap_or("");
                choices.iter().copied().find(|c| *c == s).ok_or_else(|| {
                    Error::input(format!(
                        "{}: {}{name} = {v} is not one of {}",
                        self.context,
                        self.prefix,
                        choices.join(" | ")
                    ))
                })
            }
        }
    }

    fn check_range(
        &self,
        name: &str,
        index: Option<usize>,
        x: f64,
        min: f64,
        max: f64,
    ) -> Result<()> {
        // NaN fails both comparisons, so it is reported here too (JSON cannot carry it, but a
        // programmatic Value can).
        if !(x >= min && x <= max) {
            let idx = index.map(|i| format!("[{i}]")).unwrap_or_default();
            return Err(Error::input(format!(
                "{}: {}{name}{idx} = {} is out of range [{}, {}]",
                self.context,
                self.prefix,
                fmt_num(x),
                fmt_num(min),
                fmt_num(max)
            )));
        }
        Ok(())
    }
}
