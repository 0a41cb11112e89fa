//! He–Torrance–Sillion–Greenberg (1991) BRDF: Kirchhoff diffraction by a Gaussian random
//! surface, with the published errata, in the conventions of `spec/models.md` ("HTSG").
//!
//! f = f_dd + a/π with the directional-diffuse part (per channel, wavelength λ)
//!
//!   f_dd = F(c_h) · S · G · D / (π c_i c_o).
//!
//! The specular part is a Dirac delta and cannot be evaluated pointwise; its coefficient is
//! reported by [`Htsg::specular_coefficient`]. The numerical choices (log-space assembly, the
//! effective-roughness solver, the series summation and its error bound) are explained in
//! `docs/htsg.md`.

use super::params::{ModelDecl, ParamDecl, ParamKind, ParamReader, broadcast};
use crate::brdf::Channels;
use crate::geometry::Vec3;
use crate::math::{FRAC_1_PI, PI, erfc, sqr};
use crate::spectral::nm_from_um;
use crate::{Error, Result};
use serde_json::{Value, json};

/// Largest accepted rms height σ0 (µm). Rougher surfaces are outside the Kirchhoff model's
/// use and need ~2·10⁵ series terms per channel at the shortest wavelength.
pub const SIGMA0_MAX_UM: f64 = 100.0;
/// Largest accepted autocorrelation length τ (µm).
pub const TAU_MAX_UM: f64 = 1000.0;
/// Accepted wavelengths (µm): ultraviolet to far infrared.
pub const WAVELENGTH_RANGE_UM: (f64, f64) = (0.1, 100.0);
/// The spec's default wavelengths (µm), standing for red, green and blue: a model with
/// exactly these has R, G, B channels; any other wavelengths give spectral channels.
pub const RGB_WAVELENGTHS_UM: [f64; 3] = [0.645, 0.526, 0.444];

/// The parameters of `htsg` (spec/models.md), per-channel lists already broadcast to the
/// same length C.
#[derive(Clone, Debug, PartialEq)]
pub struct HtsgParams {
    /// rms surface height σ0 (µm).
    pub sigma0_um: f64,
    /// autocorrelation length τ (µm).
    pub tau_um: f64,
    /// real part η of the relative complex index η + iκ, per channel.
    pub eta_re: Vec<f64>,
    /// imaginary part κ (extinction) of the relative complex index, per channel.
    pub eta_im: Vec<f64>,
    /// wavelength λ of each channel (µm).
    pub wavelengths_um: Vec<f64>,
    /// albedo a of the optional uniform-diffuse term a/π, per channel.
    pub uniform_diffuse: Vec<f64>,
}

impl Default for HtsgParams {
    /// The spec's defaults: σ0 = 0.18 µm, τ = 3 µm, η = 1.5 + 0i, RGB wavelengths, a = 0.
    fn default() -> Self {
        HtsgParams {
            sigma0_um: 0.18,
            tau_um: 3.0,
            eta_re: vec![1.5; 3],
            eta_im: vec![0.0; 3],
            wavelengths_um: RGB_WAVELENGTHS_UM.to_vec(),
            uniform_diffuse: vec![0.0; 3],
        }
    }
}

impl HtsgParams {
    /// Number of channels C.
    pub fn channels(&self) -> usize {
        self.wavelengths_um.len()
    }

    /// Checks ranges and list lengths; messages name the parameter, value and expected range.
    pub fn validate(&self) -> Result<()> {
        let c = self.wavelengths_um.len();
        if c == 0 {
            return Err(Error::input(
                "htsg: wavelengths is empty; expected at least one channel",
            ));
        }
        for (name, list) in [
            ("eta_re", &self.eta_re),
            ("eta_im", &self.eta_im),
            ("uniform_diffuse", &self.uniform_diffuse),
        ] {
            if list.len() != c {
                return Err(Error::input(format!(
                    "htsg: {name} has {} values but wavelengths has {c}; per-channel lists must agree in length",
                    list.len()
                )));
            }
        }
        let s = self.sigma0_um;
        if !(s > 0.0 && s <= SIGMA0_MAX_UM) {
            return Err(Error::input(format!(
                "htsg: sigma0 = {s} µm is out of range; expected 0 < sigma0 <= {SIGMA0_MAX_UM} µm"
            )));
        }
        let t = self.tau_um;
        if !(t > 0.0 && t <= TAU_MAX_UM) {
            return Err(Error::input(format!(
                "htsg: tau = {t} µm is out of range; expected 0 < tau <= {TAU_MAX_UM} µm"
            )));
        }
        let (lo, hi) = WAVELENGTH_RANGE_UM;
        for (i, &w) in self.wavelengths_um.iter().enumerate() {
            if !(lo..=hi).contains(&w) {
                return Err(Error::input(format!(
                    "htsg: wavelengths[{i}] = {w} µm is out of range; expected {lo} <= wavelength <= {hi} µm"
                )));
            }
            // Channels are named by wavelength, so two channels cannot share one.
            if let Some(j) = self.wavelengths_um[..i].iter().position(|&v| v == w) {
                return Err(Error::input(format!(
                    "htsg: wavelengths[{i}] = {w} µm repeats wavelengths[{j}]; each channel \
                     needs its own wavelength"
                )));
            }
        }
        for (i, &e) in self.eta_re.iter().enumerate() {
            if !(e > 0.0 && e.is_finite()) {
                return Err(Error::input(format!(
                    "htsg: eta_re[{i}] = {e} is out of range; expected a finite value > 0"
                )));
            }
        }
        for (i, &k) in self.eta_im.iter().enumerate() {
            if !(k >= 0.0 && k.is_finite()) {
                return Err(Error::input(format!(
                    "htsg: eta_im[{i}] = {k} is out of range; expected a finite value >= 0"
                )));
            }
        }
        for (i, &a) in self.uniform_diffuse.iter().enumerate() {
            if !(a >= 0.0 && a.is_finite()) {
                return Err(Error::input(format!(
                    "htsg: uniform_diffuse[{i}] = {a} is out of range; expected a finite value >= 0"
                )));
            }
        }
        Ok(())
    }
}

/// Per-channel constants, computed once.
#[derive(Clone, Debug)]
struct ChannelConsts {
    /// wave number k = 2π/λ (1/µm).
    wave_number: f64,
    /// ln(π² τ²/(4λ²) / π): D's prefactor (He 1991 Eq. 78) with f_dd's 1/π folded in.
    ln_prefactor: f64,
    /// τ² k²/4, so that the series' exponent τ² v_xy² k²/(4m) is this · v_xy² / m.
    tau2_k2_over_4: f64,
    eta: f64,
    kappa: f64,
    /// a/π, the uniform-diffuse term.
    diffuse_over_pi: f64,
}

/// The HTSG model, ready to evaluate.
#[derive(Clone, Debug)]
pub struct Htsg {
    params: HtsgParams,
    channels: Vec<ChannelConsts>,
    /// R, G, B for the spec's default wavelengths, else spectral samples named by λ (nm).
    pub(crate) names: Channels,
}

/// Evaluation statistics: the largest number of series terms any channel summed.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct HtsgStats {
    pub max_terms: usize,
}

impl Htsg {
    /// Validates the parameters and precomputes the per-channel constants.
    pub fn new(params: HtsgParams) -> Result<Htsg> {
        params.validate()?;
        let tau = params.tau_um;
        let channels = (0..params.channels())
            .map(|c| {
                let lambda = params.wavelengths_um[c];
                let k = 2.0 * PI / lambda;
                ChannelConsts {
                    wave_number: k,
                    ln_prefactor: (PI * sqr(tau) / (4.0 * sqr(lambda))).ln(),
                    tau2_k2_over_4: sqr(tau) * sqr(k) / 4.0,
                    eta: params.eta_re[c],
                    kappa: params.eta_im[c],
                    diffuse_over_pi: params.uniform_diffuse[c] * FRAC_1_PI,
                }
            })
            .collect();
        let names = if params.wavelengths_um == RGB_WAVELENGTHS_UM {
            Channels::default_for(3)
        } else {
            Channels::spectral(
                params
                    .wavelengths_um
                    .iter()
                    .map(|&w| nm_from_um(w))
                    .collect(),
            )
        };
        Ok(Htsg {
            params,
            channels,
            names,
        })
    }

    pub fn params(&self) -> &HtsgParams {
        &self.params
    }

    /// Number of output channels C.
    pub fn channels(&self) -> usize {
        self.channels.len()
    }

    /// f_r(wi, wo) = f_dd + a/π per channel into `out` (length C). Allocation-free.
    pub fn eval(&self, wi: Vec3, wo: Vec3, out: &mut [f64]) {
        self.eval_with_stats(wi, wo, out);
    }

    /// As [`Htsg::eval`], also returning the largest number of series terms summed.
    pub fn eval_with_stats(&self, wi: Vec3, wo: Vec3, out: &mut [f64]) -> HtsgStats {
        debug_assert_eq!(out.len(), self.channels.len());
        self.eval_range(wi, wo, 0, out)
    }

    /// The channel names (and wavelengths when spectral).
    pub fn channel_names(&self) -> &Channels {
        &self.names
    }

    /// Channels `first..first + out.len()` of f_r(wi, wo), with the largest number of series
    /// terms summed. Allocation-free.
    pub fn eval_range(&self, wi: Vec3, wo: Vec3, first: usize, out: &mut [f64]) -> HtsgStats {
        let consts = &self.channels[first..first + out.len()];
        // One-sided (the horizon counts as below); the negated comparison also sends NaN to 0.
        if !(wi.z > 0.0 && wo.z > 0.0 && wi.is_finite() && wo.is_finite()) {
            out.fill(0.0);
            return HtsgStats::default();
        }
        let sigma0 = self.params.sigma0_um;
        let tau = self.params.tau_um;
        let dir_i = DirectionTerms::new(wi, sigma0, tau);
        let dir_o = DirectionTerms::new(wo, sigma0, tau);

        let v = wi + wo;
        let vv = v.length_squared();
        // v.z = c_i + c_o > 0 here.
        let v_z = v.z;
        let v_xy2 = sqr(v.x) + sqr(v.y);
        // He 1991 Eq. 76: the polarization brackets both equal |k_i × k_r|², so
        // G = (v·v / v.z)² identically (finite at normal incidence and for wi = wo).
        let ln_geometric = 2.0 * (vv.ln() - v_z.ln());
        // c_h = sqrt((1 + wi·wo)/2) = |wi + wo|/2 and sin² = |wi − wo|²/4 (unit vectors):
        // neither form cancels near the mirror or retro direction.
        let cos_h = 0.5 * vv.sqrt();
        let sin2_h = 0.25 * (wi - wo).length_squared();

        let x = effective_roughness_ratio(dir_i.ln_k, dir_o.ln_k);
        let sigma = sigma0 / (1.0 + sqr(x)).sqrt();

        let ln_common = dir_i.ln_s1_over_cos + dir_o.ln_s1_over_cos + ln_geometric;
        let mut stats = HtsgStats::default();
        for (ch, o) in consts.iter().zip(out.iter_mut()) {
            // g = (2π σ (c_i + c_o)/λ)², kept as its logarithm (it can underflow).
            let ln_g = 2.0 * (ch.wave_number * sigma * v_z).ln();
            let series = DiffuseSeries::sum(ln_g, ch.tau2_k2_over_4 * v_xy2);
            stats.max_terms = stats.max_terms.max(series.terms);
            let fresnel = fresnel_complex(cos_h, sin2_h, ch.eta, ch.kappa);
            let f_dd = fresnel * (ln_common + ch.ln_prefactor + series.ln_sum).exp();
            // The exponent is bounded for validated parameters; the guard keeps Inf out of
            // tables should that analysis ever be wrong.
            *o = f_dd.min(f64::MAX) + ch.diffuse_over_pi;
        }
        stats
    }

    /// The coefficient ρ_s(wi) of the specular delta per channel (He 1991 Eq. 71 with the
    /// errata): |F(θ_i)|² e^{−g} S(wi)², g = (4π σ c_i/λ)², σ for the mirror pair. Not part
    /// of f_r; 0 below the horizon.
    pub fn specular_coefficient(&self, wi: Vec3) -> Vec<f64> {
        let mut out = vec![0.0; self.channels.len()];
        // One-sided, and NaN goes to 0.
        if !(wi.z > 0.0 && wi.is_finite()) {
            return out;
        }
        let dir = DirectionTerms::new(wi, self.params.sigma0_um, self.params.tau_um);
        let x = effective_roughness_ratio(dir.ln_k, dir.ln_k);
        let sigma = self.params.sigma0_um / (1.0 + sqr(x)).sqrt();
        let cos_i = wi.z;
        let sin2_i = wi.sin2_theta();
        // S1 = (S1/c)·c; ln form keeps it finite at tiny c.
        let shadow = (2.0 * (dir.ln_s1_over_cos + cos_i.ln())).exp();
        for (ch, o) in self.channels.iter().zip(out.iter_mut()) {
            let g = sqr(2.0 * ch.wave_number * sigma * cos_i);
            *o = fresnel_complex(cos_i, sin2_i, ch.eta, ch.kappa) * (-g).exp() * shadow;
        }
        out
    }
}

const HTSG_CITE: &str = "He, Torrance, Sillion & Greenberg 1991 (with errata)";

/// The `htsg` model's parameters (spec/models.md; `nk`, `wavelengths_nm` are this crate's
/// additions for spectral use, docs/spectral.md).
pub const PARAMS: &[ParamDecl] = &[
    ParamDecl::number("sigma0", 1e-6, SIGMA0_MAX_UM, 0.18).doc(
        "σ0",
        "µm",
        "rms surface height",
        HTSG_CITE,
    ),
    ParamDecl::number("tau", 1e-6, TAU_MAX_UM, 3.0).doc(
        "τ",
        "µm",
        "autocorrelation length of the surface heights",
        HTSG_CITE,
    ),
    ParamDecl::number("eta_re", 1e-6, 1e6, 1.5).per_channel().doc(
        "η",
        "1",
        "real part of the relative complex index η + iκ (exclusive with nk)",
        HTSG_CITE,
    ),
    ParamDecl::number("eta_im", 0.0, 1e6, 0.0).per_channel().doc(
        "κ",
        "1",
        "imaginary part (extinction) of the relative complex index (exclusive with nk)",
        HTSG_CITE,
    ),
    ParamDecl::structured(
        "nk",
        ParamKind::DataFile("CSV wavelength_nm,n,k"),
        super::params::ParamDefault::Derived("none (eta_re, eta_im)"),
    )
    .doc(
        "n, k",
        "",
        "tabulated η(λ), κ(λ), interpolated linearly at the wavelengths (instead of eta_re, eta_im)",
        "docs/spectral.md",
    ),
    ParamDecl::number(
        "wavelengths",
        WAVELENGTH_RANGE_UM.0,
        WAVELENGTH_RANGE_UM.1,
        0.55,
    )
    .per_channel()
    .derived_default("0.645/0.526/0.444 (R, G, B)")
    .doc(
        "λ",
        "µm",
        "wavelength of each channel (distinct); other than the RGB default, the channels are \
         spectral samples (exclusive with wavelengths_nm)",
        HTSG_CITE,
    ),
    super::params::WAVELENGTHS_NM,
    ParamDecl::number("uniform_diffuse", 0.0, 1.0, 0.0)
        .per_channel()
        .doc("a", "1", "albedo of the uniform-diffuse term a/π", HTSG_CITE),
];

pub const DECL: ModelDecl = ModelDecl {
    name: "htsg",
    aliases: &[],
    summary: "He–Torrance–Sillion–Greenberg physically based reflection (Kirchhoff diffraction \
              by a Gaussian rough surface): directional-diffuse + uniform-diffuse parts; the \
              specular part is a Dirac delta, reported separately and never tabulated",
    formula: "F(c_h) S G D / (π c_i c_o) + a/π   (+ ρ_s(wi) δ, not pointwise)",
    citation: HTSG_CITE,
    params: PARAMS,
    isotropic: "always",
    reciprocal: true,
    tabulable: true,
};

/// The zenith angles (degrees) and relative azimuths of the fixed direction set over which
/// [`Htsg::series_terms_max`] reports the largest term count.
const TERMS_THETAS_DEG: [f64; 8] = [0.0, 15.0, 30.0, 45.0, 60.0, 75.0, 85.0, 89.0];
const TERMS_PHIS_DEG: [f64; 3] = [0.0, 90.0, 180.0];

/// One value if every channel has it, else the list (the channel count is fixed by the
/// wavelengths, so a scalar re-parses to the same model).
fn uniform_or_list(v: &[f64]) -> Value {
    if v.iter().all(|&x| x == v[0]) {
        v[0].into()
    } else {
        v.into()
    }
}

impl Htsg {
    pub(crate) fn from_params(r: &ParamReader) -> Result<Htsg> {
        let ctx = r.context();
        let mut cc = r.channel_count()?;
        let from_nm = cc.wavelengths_nm().map(|w| w.to_vec());
        let wavelengths_um = match (r.is_given("wavelengths"), from_nm) {
            (true, Some(_)) => {
                return Err(Error::input(format!(
                    "{ctx}: wavelengths (µm) and wavelengths_nm are both given; give one"
                )));
            }
            (true, None) => r.channel("wavelengths", &mut cc)?,
            (false, Some(nm)) => nm.iter().map(|w| w / 1e3).collect(),
            (false, None) => {
                cc.record(
                    ctx,
                    "wavelengths (default R, G, B: 0.645/0.526/0.444 µm)",
                    3,
                )?;
                RGB_WAVELENGTHS_UM.to_vec()
            }
        };
        let nk = r.file("nk")?;
        let (eta_re, eta_im) = match nk {
            Some(path) => {
                if let Some(key) = ["eta_re", "eta_im"].into_iter().find(|k| r.is_given(k)) {
                    return Err(Error::input(format!(
                        "{ctx}: {key} and nk are both given; nk = @{path} supplies η and κ"
                    )));
                }
                (Vec::new(), Vec::new())
            }
            None => (r.channel("eta_re", &mut cc)?, r.channel("eta_im", &mut cc)?),
        };
        let uniform_diffuse = r.channel("uniform_diffuse", &mut cc)?;
        let c = cc.count();
        let wavelengths_um = broadcast(&wavelengths_um, c);
        let (eta_re, eta_im) = match nk {
            None => (broadcast(&eta_re, c), broadcast(&eta_im, c)),
            Some(path) => {
                let nm: Vec<f64> = wavelengths_um.iter().map(|&w| nm_from_um(w)).collect();
                r.files()
                    .optical_constants(path)?
                    .at(&nm)
                    .map_err(|e| Error::input(format!("{ctx}: nk: {e}")))?
            }
        };
        Htsg::new(HtsgParams {
            sigma0_um: r.number("sigma0")?,
            tau_um: r.number("tau")?,
            eta_re,
            eta_im,
            wavelengths_um,
            uniform_diffuse: broadcast(&uniform_diffuse, c),
        })
    }

    /// Canonical JSON (spec/models.md names; η, κ written out even when read from `nk`).
    pub(crate) fn to_json(&self) -> Value {
        let p = &self.params;
        let wavelengths = if p.wavelengths_um.len() == 1 {
            p.wavelengths_um[0].into()
        } else {
            Value::from(p.wavelengths_um.clone())
        };
        json!({
            "model": "htsg",
            "sigma0": p.sigma0_um,
            "tau": p.tau_um,
            "eta_re": uniform_or_list(&p.eta_re),
            "eta_im": uniform_or_list(&p.eta_im),
            "wavelengths": wavelengths,
            "uniform_diffuse": uniform_or_list(&p.uniform_diffuse),
        })
    }

    /// The largest number of directional-diffuse series terms any channel sums, over a fixed
    /// set of direction pairs: θi, θo ∈ {0, 15, 30, 45, 60, 75, 85, 89}°, relative azimuth
    /// ∈ {0, 90, 180}° (the most terms are needed near normal incidence on rough surfaces,
    /// where g = (2πσ(c_i + c_o)/λ)² is largest).
    pub fn series_terms_max(&self) -> usize {
        let mut out = vec![0.0; self.channels.len()];
        let mut most = 0;
        for &ti in &TERMS_THETAS_DEG {
            for &to in &TERMS_THETAS_DEG {
                for &dphi in &TERMS_PHIS_DEG {
                    let wi = Vec3::from_spherical(ti.to_radians(), 0.0);
                    let wo = Vec3::from_spherical(to.to_radians(), dphi.to_radians());
                    most = most.max(self.eval_with_stats(wi, wo, &mut out).max_terms);
                }
            }
        }
        most
    }

    /// The provenance note of a table of this model: what the table holds, and the specular
    /// delta's coefficient, which it does not.
    pub fn tabulation_note(&self) -> String {
        let fmt = |v: Vec<f64>| {
            v.iter()
                .map(|x| format!("{x:.4e}"))
                .collect::<Vec<_>>()
                .join("/")
        };
        let at =
            |deg: f64| fmt(self.specular_coefficient(Vec3::from_spherical(deg.to_radians(), 0.0)));
        format!(
            "htsg: the table holds the directional-diffuse and uniform-diffuse parts only; the \
             specular part is a Dirac delta (coefficient ρ_s(wi) = F(θi) e^(−g) S(wi)², He et al. \
             1991 Eq. 71, not tabulable): ρ_s = {} at θi = 0°, {} at 45°, {} at 75° (per channel)",
            at(0.0),
            at(45.0),
            at(75.0)
        )
    }
}

/// Shadowing threshold: for s ≥ 27, e^{−s²} < 1e-316 and erfc(s) < 1e-318, so Λ = 0, S1 = 1
/// and K = 0 to f64 precision (and s = ∞ on the normal itself lands here).
const SHADOW_FREE_S: f64 = 27.0;

/// The per-direction quantities: shadowing S1 (He 1991 Eq. 24 with the errata's exponential)
/// and K(tanθ) of the effective-roughness equation (Eq. 80).
#[derive(Clone, Copy, Debug)]
struct DirectionTerms {
    /// ln(S1/c): S1 divided by cosθ, finite even when cosθ underflows.
    ln_s1_over_cos: f64,
    /// ln K, K = tanθ · erfc(τ cotθ/(2σ0)); −∞ when K = 0.
    ln_k: f64,
}

impl DirectionTerms {
    fn new(w: Vec3, sigma0: f64, tau: f64) -> DirectionTerms {
        let cos = w.z;
        let sin = w.sin2_theta().sqrt();
        // s = τ cotθ/(2σ0) = τ c/(2σ0 sinθ); +∞ on the normal.
        let s_over_cos = tau / (2.0 * sigma0 * sin);
        let s = s_over_cos * cos;
        if s >= SHADOW_FREE_S {
            return DirectionTerms {
                ln_s1_over_cos: -cos.ln(),
                ln_k: f64::NEG_INFINITY,
            };
        }
        // Λ = e^{−s²}/(2√π s) − ½ erfc(s), S1 = (1 − ½ erfc(s))/(Λ + 1). With
        // A = 1 − ½ erfc(s) ∈ [½, 1]: Λ + 1 = A + e^{−s²}/(2√π s), so
        // S1/c = A (s/c) / (A s + e^{−s²}/(2√π)), free of the 1/s and 1/c singularities.
        let erfc_s = erfc(s);
        let a = 1.0 - 0.5 * erfc_s;
        let s1_over_cos = a * s_over_cos / (a * s + (-sqr(s)).exp() / (2.0 * PI.sqrt()));
        DirectionTerms {
            ln_s1_over_cos: s1_over_cos.ln(),
            // K = tanθ erfc(s) as a logarithm: tanθ overflows when c is subnormal.
            ln_k: sin.ln() - cos.ln() + erfc_s.ln(),
        }
    }
}

/// z0/σ0 = x of the effective roughness σ = σ0/sqrt(1 + x²) (He 1991 Eq. 80–81):
/// x e^{x²/2} = (K_i + K_o)/sqrt(8π), given ln K_i and ln K_o.
fn effective_roughness_ratio(ln_k_i: f64, ln_k_o: f64) -> f64 {
    // ln(K_i + K_o) by log-sum-exp (either may be −∞).
    let (hi, lo) = if ln_k_i >= ln_k_o {
        (ln_k_i, ln_k_o)
    } else {
        (ln_k_o, ln_k_i)
    };
    if hi == f64::NEG_INFINITY {
        return 0.0;
    }
    let ln_sum = hi + (lo - hi).exp().ln_1p();
    solve_x_exp_half_x2(ln_sum - 0.5 * (8.0 * PI).ln())
}

/// The root x ≥ 0 of x e^{x²/2} = y, given L = ln y (y = 0 ⇒ x = 0, L = −∞ allowed).
///
/// Safeguarded Newton on φ(x) = ln x + x²/2 − L (increasing; the log form is well scaled from
/// y ≈ 1e-308 to y ≈ 1e308), with a bracket that Newton steps may not leave (bisection
/// otherwise), run until the step is below one ulp-scale: full f64 precision.
pub fn solve_x_exp_half_x2(ln_y: f64) -> f64 {
    if ln_y == f64::NEG_INFINITY {
        return 0.0;
    }
    let l_pos = ln_y.max(0.0);
    let y = ln_y.exp(); // may be +∞ for L > 709; only used in min/max below
    // Bounds valid in both regimes: x ≤ y (as e^{x²/2} ≥ 1) and x ≤ max(1, sqrt(2L));
    // x ≥ y e^{−1/2} when x ≤ 1, and x ≥ sqrt(L) when x ≥ 1 (as ln x ≤ x²/2).
    let mut lo = (y * (-0.5f64).exp()).min(l_pos.sqrt());
    let mut hi = y.min(1.0f64.max((2.0 * l_pos).sqrt()));
    // Starting points from the two asymptotes: x ≈ y (small y), x² ≈ 2(L − ln sqrt(2L)).
    let mut x = if ln_y < 1.0 {
        y
    } else {
        (2.0 * ln_y - (2.0 * ln_y).ln()).max(0.0).sqrt()
    };
    x = x.clamp(lo, hi);
    for _ in 0..100 {
        let phi = x.ln() + 0.5 * sqr(x) - ln_y;
        if phi == 0.0 {
            return x;
        }
        if phi > 0.0 {
            hi = x;
        } else {
            lo = x;
        }
        let step = phi / (1.0 / x + x);
        let mut next = x - step;
        // Keep Newton inside the bracket; bisect when it would leave it.
        if !(next > lo && next < hi) {
            next = 0.5 * (lo + hi);
        }
        if (next - x).abs() <= 2.0 * f64::EPSILON * x {
            return next;
        }
        x = next;
    }
    x
}

/// Relative truncation target of the series: the bounded tail is at most this fraction of
/// the partial sum, below half an ulp of the result.
const SERIES_REL_EPS: f64 = f64::EPSILON / 8.0;

/// The directional-diffuse series of He 1991 Eq. 78,
///   Σ_{m≥1} e^{−g} g^m/(m! m) · exp(−T/m),  T = τ² v_xy² k²/4,
/// returned as its logarithm with the number of terms summed.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct DiffuseSeries {
    pub ln_sum: f64,
    pub terms: usize,
}

impl DiffuseSeries {
    /// Sums the series for ln g and T ≥ 0.
    ///
    /// The terms t_m are log-concave in m ≥ 1: their ratio
    ///   r_m = t_{m+1}/t_m = g m/(m+1)² · exp(T/(m(m+1)))
    /// decreases with m. So: locate the mode m0 (where r crosses 1), evaluate ln t_{m0} once
    /// (Loader's saddle-point form of the Poisson term, no lgamma cancellation), then walk
    /// outwards in both directions with t scaled to t_{m0} = 1. Past the mode on either side
    /// the remaining terms are bounded by a geometric series of the current ratio, and the
    /// walk stops when that bound is below SERIES_REL_EPS of the partial sum. Every
    /// REANCHOR_EVERY terms the running product is re-evaluated directly, so rounding does
    /// not grow with the number of terms (docs/htsg.md has the bound and the checks).
    ///
    /// When the terms spread over many indices (a width W = 1/sqrt(−d² ln t/dm²) at the mode
    /// of at least STRIDE_MIN_WIDTH, 12 where T dominates: rough surfaces, ~17·W terms),
    /// every term is not needed: the sum is taken at every s-th index from the mode,
    /// s = ⌊W/2⌋, times s ([`strided_sum`]; its aliasing error is below e^{−70} of the sum,
    /// far under an ulp), which bounds the work at ~40 terms whatever g and T (σ0 = 100 µm at
    /// λ = 0.1 µm summed 211,591 terms one by one).
    pub fn sum(ln_g: f64, t: f64) -> DiffuseSeries {
        if ln_g == f64::NEG_INFINITY {
            // g = 0 (σ underflowed): every term is 0.
            return DiffuseSeries {
                ln_sum: f64::NEG_INFINITY,
                terms: 1,
            };
        }
        let m0 = series_mode(ln_g, t);
        let ln_t0 = ln_term(m0, ln_g, t);
        if let Some(stride) = series_stride(m0, t)
            && let Some((sum, terms)) = strided_sum(ln_g, t, m0, stride)
        {
            return DiffuseSeries {
                ln_sum: ln_t0 + sum.ln(),
                terms,
            };
        }
        Self::walk(ln_g, t, m0, ln_t0)
    }

    /// The series with every term summed (what [`DiffuseSeries::sum`] does for narrow term
    /// distributions), for any width: the reference of the strided sum's tests.
    #[cfg(test)]
    pub(crate) fn sum_every_term(ln_g: f64, t: f64) -> DiffuseSeries {
        let m0 = series_mode(ln_g, t);
        Self::walk(ln_g, t, m0, ln_term(m0, ln_g, t))
    }

    /// Every term from the mode m0 outwards (ln t_{m0} = `ln_t0`), until the bounded tails
    /// are below SERIES_REL_EPS of the sum.
    fn walk(ln_g: f64, t: f64, m0: f64, ln_t0: f64) -> DiffuseSeries {
        let ratio = TermRatio::new(ln_g, t);
        let mut block = [0.0; RATIO_BLOCK];
        // Sum = `total` + `partial`: the partial sum covers at most REANCHOR_EVERY terms, so
        // rounding grows with the number of spans, not of terms (2·10⁵ terms at g = 1.6e8).
        let mut total = 1.0;
        let mut partial = 0.0;
        let mut terms = 1usize;
        // Upwards: t_{m+1} = t_m r_m; tail Σ_{j>m} t_j ≤ t_m r_m/(1 − r_m) once r_m < 1.
        let mut term = 1.0;
        let mut m = m0;
        'up: loop {
            ratio.fill(m, false, &mut block);
            for &r in &block {
                if r < 1.0 && term * r <= SERIES_REL_EPS * (total + partial) * (1.0 - r) {
                    break 'up;
                }
                term *= r;
                partial += term;
                terms += 1;
            }
            m += RATIO_BLOCK as f64;
            if (m - m0) % REANCHOR_EVERY == 0.0 {
                term = (ln_term(m, ln_g, t) - ln_t0).exp();
                total += partial;
                partial = 0.0;
            }
        }
        total += partial;
        partial = 0.0;
        // Downwards: t_{m−1} = t_m q with q = 1/r_{m−1}; once q < 1 the rest is bounded by
        // t_m q/(1 − q). The series starts at m = 1.
        term = 1.0;
        m = m0;
        'down: while m > 1.0 {
            ratio.fill(m - 1.0, true, &mut block);
            for &q in &block {
                if m <= 1.0
                    || (q < 1.0 && term * q <= SERIES_REL_EPS * (total + partial) * (1.0 - q))
                {
                    break 'down;
                }
                term *= q;
                m -= 1.0;
                partial += term;
                terms += 1;
            }
            if (m0 - m) % REANCHOR_EVERY == 0.0 {
                term = (ln_term(m, ln_g, t) - ln_t0).exp();
                total += partial;
                partial = 0.0;
            }
        }
        let sum = total + partial;
        DiffuseSeries {
            ln_sum: ln_t0 + sum.ln(),
            terms,
        }
    }
}

/// Smallest width W of the term distribution at its mode (W² = −1/(d ln r_m/dm), the
/// terms' standard deviation when they are near-Gaussian) from which the series is summed at
/// a stride instead of term by term. The walk needs ~17·W terms at ~3.5 ns each (Taylor
/// ratios) and the strided sum ~36 terms evaluated directly, ~2 µs in all: they cost the
/// same near W = 35 (measured, docs/htsg.md).
const STRIDE_MIN_WIDTH: f64 = 32.0;
/// The same where the walk's ratios need libm's `exp` (δ = T/(m0(m0+1)) > EXP_TAYLOR_MAX at
/// the mode: long τ, off-specular), ~20 ns a term: the costs meet near W = 6.
const STRIDE_MIN_WIDTH_EXACT_RATIOS: f64 = 12.0;

/// The stride is W / STRIDE_PER_WIDTH: the aliasing error of a sum taken at every s-th
/// index is ~2·exp(−2π² (W/s)²) of the sum for near-Gaussian terms, e^{−79} here (exactly
/// 2·exp(−g(1 − cos(2π/s))) for Poisson weights: e^{−72} or less for W ≥ 12).
const STRIDE_PER_WIDTH: f64 = 2.0;

/// The stride s ≥ 6 for a series whose mode is m0, or `None` when its terms are too narrow
/// for a stride to pay (W below STRIDE_MIN_WIDTH or STRIDE_MIN_WIDTH_EXACT_RATIOS).
fn series_stride(m0: f64, t: f64) -> Option<f64> {
    // −d(ln r_m)/dm = 2/(m+1) − 1/m + T(2m+1)/(m(m+1))² ≈ 1/m + 2T/m³: 1/W².
    let curvature = 2.0 / (m0 + 1.0) - 1.0 / m0 + t * (2.0 * m0 + 1.0) / sqr(m0 * (m0 + 1.0));
    let w2 = 1.0 / curvature;
    let min_width = if t / (m0 * (m0 + 1.0)) > EXP_TAYLOR_MAX {
        STRIDE_MIN_WIDTH_EXACT_RATIOS
    } else {
        STRIDE_MIN_WIDTH
    };
    // (A NaN or non-positive curvature leaves the walk to decide.)
    (w2 >= sqr(min_width)).then(|| (w2.sqrt() / STRIDE_PER_WIDTH).floor())
}

/// ln r_m = ln(t_{m+1}/t_m) = ln g + ln(m/(m+1)²) + T/(m(m+1)).
fn ln_ratio(m: f64, ln_g: f64, t: f64) -> f64 {
    ln_g + (m / sqr(m + 1.0)).ln() + t / (m * (m + 1.0))
}

/// ln(t_m / t_{m0}) for m, m0 > 15, formed from differences so that the parts common to
/// both (½ ln 2πm + ln m, most of bd0 and of T/m) cancel exactly instead of in rounding.
/// `at_mode` holds what depends on m0 alone.
struct RelativeTerm {
    m0: f64,
    ln_g: f64,
    g: f64,
    t: f64,
    ln_m0_over_g: f64,
    stirling_m0: f64,
    bd0_m0: f64,
}

impl RelativeTerm {
    fn new(m0: f64, ln_g: f64, t: f64) -> RelativeTerm {
        let g = ln_g.exp();
        RelativeTerm {
            m0,
            ln_g,
            g,
            t,
            ln_m0_over_g: m0.ln() - ln_g,
            stirling_m0: stirling_error(m0),
            bd0_m0: bd0(m0, g, ln_g),
        }
    }

    fn near(&self, x: f64) -> bool {
        (x - self.g).abs() < 0.1 * (x + self.g)
    }

    fn at(&self, m: f64) -> f64 {
        let (m0, g) = (self.m0, self.g);
        let d = m - m0;
        let ln_ratio = (d / m0).ln_1p();
        // bd0(m, g) − bd0(m0, g); away from g, bd0 = x ln(x/g) + g − x, whose difference is
        // d (ln(m0/g) − 1) + m ln(m/m0).
        let d_bd0 = if self.near(m) || self.near(m0) {
            bd0(m, g, self.ln_g) - self.bd0_m0
        } else {
            d * (self.ln_m0_over_g - 1.0) + m * ln_ratio
        };
        -(stirling_error(m) - self.stirling_m0) - d_bd0 - 1.5 * ln_ratio + self.t * d / (m * m0)
    }
}

/// Σ_{m≥1} t_m / t_{m0} estimated as s · Σ_j t_{m0 + js} (j ∈ ℤ, m0 + js ≥ 1), with the
/// number of terms evaluated; `None` when the walk down would come near m = 1 before its
/// tail is negligible (the terms are then not spread evenly enough for a stride: sum every
/// term).
///
/// Why it is the sum: for any sequence a_m, s Σ_j a_{m0+js} − Σ_m a_m = Σ_{k=1}^{s−1}
/// e^{2πi k m0/s} A(2πk/s) with A(ξ) = Σ_m a_m e^{−iξm}. For Poisson weights
/// |A(ξ)| = e^{−g(1 − cos ξ)} A(0) exactly, e^{−79} A(0) at s = √g/2; the slowly varying
/// factor e^{−T/m}/m and the T-dominated regime keep the near-Gaussian shape of width W
/// (checked against the term-by-term sum over g up to 1.6e8 and T up to 4e9: docs/htsg.md).
///
/// Truncation: the terms are log-concave, so past the mode t_{m+js} ≤ t_m ρ^j with
/// ρ = r_m^s (r_m the ratio at the last term, < 1): the walk stops when both the strided
/// tail s·t_m ρ/(1 − ρ) and the term-by-term tail t_m r_m/(1 − r_m) are below
/// SERIES_REL_EPS of the sum; likewise downwards with q = 1/r_{m−1}.
fn strided_sum(ln_g: f64, t: f64, m0: f64, s: f64) -> Option<(f64, usize)> {
    if m0 <= 16.0 {
        return None;
    }
    let rel = RelativeTerm::new(m0, ln_g, t);
    let mut sum = 1.0;
    let mut terms = 1usize;
    // Whether the tail beyond `term`, whose neighbour ratio is e^{ln_r}, is negligible. The
    // bound is only formed for terms below 1e-12 of the sum (checking later never loses
    // accuracy; it saves the exponentials near the mode).
    let negligible = |term: f64, ln_r: &dyn Fn() -> f64, sum: f64| {
        if term > 1e-12 * sum {
            return false;
        }
        let ln_r = ln_r();
        if ln_r >= 0.0 {
            return false;
        }
        let rho = (s * ln_r).exp();
        let tail = (s * rho / -(s * ln_r).exp_m1()).max(ln_r.exp() / -ln_r.exp_m1());
        term * tail <= SERIES_REL_EPS * s * sum
    };
    // ~9 W/s = 18 terms a side reach the tail bound; the cap only guards the loop.
    const MAX_STEPS: usize = 1000;
    let mut m = m0;
    loop {
        if terms > MAX_STEPS {
            return None;
        }
        m += s;
        let term = rel.at(m).exp();
        sum += term;
        terms += 1;
        if negligible(term, &|| ln_ratio(m, ln_g, t), sum) {
            break;
        }
    }
    m = m0;
    loop {
        if m - s <= 16.0 || terms > 2 * MAX_STEPS {
            return None;
        }
        m -= s;
        let term = rel.at(m).exp();
        sum += term;
        terms += 1;
        if negligible(term, &|| -ln_ratio(m - 1.0, ln_g, t), sum) {
            break;
        }
    }
    Some((s * sum, terms))
}

/// Every this many terms the running product is replaced by the directly evaluated term
/// (a multiple of RATIO_BLOCK): the product's rounding errors grow with the number of
/// steps (1.4e-13 after 10⁵ steps at g = 1.6e8), the direct form's do not (≈ 1e-15).
const REANCHOR_EVERY: f64 = 256.0;

/// Term ratios are computed a block at a time (independent of each other, so the block
/// vectorizes); the walk then consumes them serially.
const RATIO_BLOCK: usize = 8;

/// Largest δ = T/(m(m+1)) for which e^δ is taken from its degree-8 Taylor polynomial
/// (remainder < δ⁹/9! · e^δ < 1e-19, far below an ulp) instead of a libm call.
const EXP_TAYLOR_MAX: f64 = 1.0 / 32.0;
/// Largest δ for the degree-3 polynomial (remainder < δ⁴/4! · e^δ < 1e-17): the common case
/// for rough surfaces, where m is in the thousands and δ ≤ T/m² is tiny.
const EXP_TAYLOR3_MAX: f64 = 1.0 / 8192.0;

/// The term ratio r_m = t_{m+1}/t_m = g m/(m+1)² · exp(T/(m(m+1))).
struct TermRatio {
    ln_g: f64,
    g: f64,
    inv_g: f64,
    t: f64,
    /// g and 1/g are normal numbers, so the product form is exact to rounding.
    g_is_normal: bool,
}

impl TermRatio {
    fn new(ln_g: f64, t: f64) -> TermRatio {
        let g = ln_g.exp();
        TermRatio {
            ln_g,
            g,
            inv_g: 1.0 / g,
            t,
            g_is_normal: ln_g.abs() < 700.0,
        }
    }

    /// Upwards (`inverse` false): out[j] = r_{m+j}. Downwards (`inverse` true):
    /// out[j] = 1/r_{m−j}. Indices below 1 (past the series' start) get unused filler.
    #[inline]
    fn fill(&self, m: f64, inverse: bool, out: &mut [f64; RATIO_BLOCK]) {
        let last = RATIO_BLOCK as f64 - 1.0;
        let m_min = if inverse { m - last } else { m }.max(1.0);
        // δ = T/(m(m+1)) is largest at the block's smallest m.
        let delta_max = self.t / (m_min * (m_min + 1.0));
        if !self.g_is_normal || delta_max > EXP_TAYLOR_MAX {
            self.fill_exact(m, inverse, out);
        } else if delta_max == 0.0 {
            self.fill_taylor::<0>(m, inverse, out);
        } else if delta_max <= EXP_TAYLOR3_MAX {
            self.fill_taylor::<3>(m, inverse, out);
        } else {
            self.fill_taylor::<8>(m, inverse, out);
        }
    }

    /// The block with e^{±δ} from its degree-N Taylor polynomial; N is chosen by `fill` so
    /// that the remainder is below SERIES_REL_EPS.
    #[inline]
    fn fill_taylor<const N: usize>(&self, m: f64, inverse: bool, out: &mut [f64; RATIO_BLOCK]) {
        if inverse {
            for (j, o) in out.iter_mut().enumerate() {
                // Filler for indices below 1: m = 1 keeps the arithmetic finite.
                let mj = (m - j as f64).max(1.0);
                let m1 = mj + 1.0;
                // 1/r = (m+1)²/(g m) · e^{−δ}, with p = 1/(m(m+1)): (m+1)²/m = (m+1)³p.
                let p = 1.0 / (mj * m1);
                *o = self.inv_g * m1 * m1 * m1 * p * exp_taylor::<N>(-self.t * p);
            }
        } else {
            for (j, o) in out.iter_mut().enumerate() {
                let mj = m + j as f64;
                let m1 = mj + 1.0;
                // r = g m/(m+1)² · e^{δ}, with p = 1/(m(m+1)²): m/(m+1)² = m²p, δ = T(m+1)p.
                let p = 1.0 / (mj * m1 * m1);
                *o = self.g * mj * mj * p * exp_taylor::<N>(self.t * m1 * p);
            }
        }
    }

    /// The block by the full exponential in log form: large δ (small m, large T) or a g
    /// whose product form would overflow or underflow.
    fn fill_exact(&self, m: f64, inverse: bool, out: &mut [f64; RATIO_BLOCK]) {
        let step = if inverse { -1.0 } else { 1.0 };
        for (j, o) in out.iter_mut().enumerate() {
            // Filler for indices below 1: m = 1 keeps the arithmetic finite.
            let mj = (m + step * j as f64).max(1.0);
            let m1 = mj + 1.0;
            let ln_r = self.ln_g + self.t / (mj * m1) + (mj / (m1 * m1)).ln();
            *o = if inverse { (-ln_r).exp() } else { ln_r.exp() };
        }
    }
}

/// e^d ≈ Σ_{k≤N} d^k/k! by Horner, for the small |d| that `TermRatio::fill` allows.
#[inline]
fn exp_taylor<const N: usize>(d: f64) -> f64 {
    const C: [f64; 9] = [
        1.0,
        1.0,
        1.0 / 2.0,
        1.0 / 6.0,
        1.0 / 24.0,
        1.0 / 120.0,
        1.0 / 720.0,
        1.0 / 5040.0,
        1.0 / 40320.0,
    ];
    // Plain multiply-add, not f64::mul_add: without a target FMA feature that is a libm call.
    let mut acc = C[N];
    for &c in C[..N].iter().rev() {
        acc = acc * d + c;
    }
    acc
}

/// ln t_m = ln(e^{−g} g^m/m!) − ln m − T/m.
fn ln_term(m: f64, ln_g: f64, t: f64) -> f64 {
    ln_poisson(m, ln_g) - m.ln() - t / m
}

/// ln(e^{−g} g^m / m!) for integer m ≥ 1, after Loader (2000), "Fast and accurate computation
/// of binomial probabilities": −stirlerr(m) − bd0(m, g) − ½ ln(2πm), which avoids the
/// cancellation of m ln g − g − lnΓ(m+1) (terms of size 10⁴ for g in the thousands).
fn ln_poisson(m: f64, ln_g: f64) -> f64 {
    let g = ln_g.exp();
    if m <= 15.0 {
        // Small m: the direct form's terms are small, so its cancellation is too.
        return m * ln_g - g - libm::lgamma(m + 1.0);
    }
    -stirling_error(m) - bd0(m, g, ln_g) - 0.5 * (2.0 * PI * m).ln()
}

/// stirlerr(n) = lnΓ(n+1) − (n + ½) ln n + n − ln sqrt(2π) for n > 15, by its asymptotic
/// series (Loader 2000; truncation < 3e-16 absolute at n = 16).
fn stirling_error(n: f64) -> f64 {
    const S0: f64 = 1.0 / 12.0;
    const S1: f64 = 1.0 / 360.0;
    const S2: f64 = 1.0 / 1260.0;
    const S3: f64 = 1.0 / 1680.0;
    const S4: f64 = 1.0 / 1188.0;
    let nn = n * n;
    (S0 - (S1 - (S2 - (S3 - S4 / nn) / nn) / nn) / nn) / n
}

/// bd0(x, M) = x ln(x/M) + M − x without cancellation (Loader 2000): a series in
/// v = (x − M)/(x + M) when x is near M.
fn bd0(x: f64, m: f64, ln_m: f64) -> f64 {
    if (x - m).abs() < 0.1 * (x + m) {
        let mut v = (x - m) / (x + m);
        let mut s = (x - m) * v;
        let mut ej = 2.0 * x * v;
        v *= v;
        for j in 1..1000 {
            ej *= v;
            let s1 = s + ej / (2 * j + 1) as f64;
            if s1 == s {
                return s1;
            }
            s = s1;
        }
        return s;
    }
    x * (x.ln() - ln_m) + m - x
}

/// The mode of the series' terms: the smallest integer m ≥ 1 with r_m ≤ 1, i.e. the root of
/// h(m) = ln r_m = ln g + ln m − 2 ln(m+1) + T/(m(m+1)) (decreasing), rounded up.
fn series_mode(ln_g: f64, t: f64) -> f64 {
    let h = |m: f64| ln_g + m.ln() - 2.0 * (m + 1.0).ln() + t / (m * (m + 1.0));
    if h(1.0) <= 0.0 {
        return 1.0;
    }
    // Upper bracket: for m ≥ max(e·g, sqrt T), h(m) < ln g − ln m + T/m² ≤ −1 + 1 = 0.
    let mut lo = 1.0;
    let mut hi = (ln_g + 1.0).exp().max(t.sqrt()).max(1.0);
    // Start from the T = 0 root (m ≈ g − 2) or the T-dominated one (m ≈ sqrt T).
    let mut m = (ln_g.exp() - 2.0).max(t.sqrt()).clamp(lo, hi);
    for _ in 0..200 {
        let hm = h(m);
        if hm > 0.0 {
            lo = m;
        } else {
            hi = m;
        }
        // h'(m) = 1/m − 2/(m+1) − T(2m+1)/(m(m+1))², negative for m ≥ 1.
        let dh = 1.0 / m - 2.0 / (m + 1.0) - t * (2.0 * m + 1.0) / sqr(m * (m + 1.0));
        let mut next = m - hm / dh;
        // Safeguard: stay in the bracket; bisect (geometrically, the scale spans decades).
        if !(next > lo && next < hi) {
            next = (lo * hi).sqrt();
        }
        if (next - m).abs() < 0.25 || hi - lo < 0.5 {
            m = next;
            break;
        }
        m = next;
    }
    // The integer mode is ceil(root); correct a possible off-by-one from the tolerance.
    let mut m0 = m.ceil().max(1.0);
    while m0 > 1.0 && h(m0 - 1.0) <= 0.0 {
        m0 -= 1.0;
    }
    while h(m0) > 0.0 {
        m0 += 1.0;
    }
    m0
}

/// Unpolarized Fresnel reflectance (Rs + Rp)/2 for the relative complex index η + iκ at
/// cosθ = `cos`, sin²θ = `sin2` (spec/models.md "conductor"; κ = 0 gives the exact
/// dielectric, including total internal reflection for η < 1).
///
/// With A = sqrt(t² + 4η²κ²), t = η² − κ² − s², a² = (A + t)/2, b² = (A − t)/2:
/// Rs = ((a − c)² + b²)/((a + c)² + b²), Rp = Rs ((ac − s²)² + b²c²)/((ac + s²)² + b²c²),
/// the spec's A ∓ 2ac + c² rewritten as sums of squares (no cancellation), and whichever of
/// a², b² would cancel taken from a²b² = η²κ².
fn fresnel_complex(cos: f64, sin2: f64, eta: f64, kappa: f64) -> f64 {
    let t = sqr(eta) - sqr(kappa) - sin2;
    let eta_kappa2 = sqr(eta * kappa);
    let big_a = t.hypot(2.0 * eta * kappa);
    let (a2, b2) = if t >= 0.0 {
        let a2 = 0.5 * (big_a + t);
        // a2 = 0 only when t = 0 and ηκ = 0, where b² = 0 too.
        (a2, if a2 > 0.0 { eta_kappa2 / a2 } else { 0.0 })
    } else {
        let b2 = 0.5 * (big_a - t);
        (eta_kappa2 / b2, b2)
    };
    let a = a2.sqrt();
    // Rs in units of max(a, b, c): at grazing incidence with η = 1 + 0i, a = b = 0 and c²
    // underflows, which would make Rs = 0/0 instead of its limit 1.
    let b = b2.sqrt();
    let unit = a.max(cos).max(b);
    let (a_u, c_u, b2_u) = (a / unit, cos / unit, sqr(b / unit));
    let rs = (sqr(a_u - c_u) + b2_u) / (sqr(a_u + c_u) + b2_u);
    let b2c2 = b2 * sqr(cos);
    let rp = rs * (sqr(a * cos - sin2) + b2c2) / (sqr(a * cos + sin2) + b2c2);
    0.5 * (rs + rp)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn x_exp_half_x2_solves_to_full_precision_over_all_scales() {
        for &y in &[
            1e-300, 1e-100, 1e-20, 1e-8, 1e-3, 0.1, 0.5, 1.0, 1.6487, 3.0, 10.0, 1e3, 1e10, 1e100,
            1e300,
        ] {
            let x = solve_x_exp_half_x2(f64::ln(y));
            // Check in log form (y up to 1e300 is not representable as x e^{x²/2} products).
            let resid = x.ln() + 0.5 * x * x - y.ln();
            assert!(
                resid.abs() <= 4.0 * f64::EPSILON * y.ln().abs().max(1.0),
                "{y} {x} {resid}"
            );
        }
        assert_eq!(solve_x_exp_half_x2(f64::NEG_INFINITY), 0.0);
        // Known value: x = 1 ⇔ y = e^{1/2}.
        let x = solve_x_exp_half_x2(0.5);
        assert!((x - 1.0).abs() <= 2.0 * f64::EPSILON, "{x}");
        // Tiny y: x = y (1 − y²/2 + …) = e^L to f64 precision.
        let l = f64::ln(1e-200);
        assert!((solve_x_exp_half_x2(l) / l.exp() - 1.0).abs() <= 2.0 * f64::EPSILON);
    }

    #[test]
    fn fresnel_matches_dielectric_closed_forms() {
        // Normal incidence: ((η−1)/(η+1))².
        let f = fresnel_complex(1.0, 0.0, 1.5, 0.0);
        assert!((f - 0.04).abs() < 1e-16, "{f}");
        // Conductor at normal incidence: ((η−1)² + κ²)/((η+1)² + κ²).
        let f = fresnel_complex(1.0, 0.0, 0.2, 3.9);
        let want = (sqr(0.8) + sqr(3.9)) / (sqr(1.2) + sqr(3.9));
        assert!((f / want - 1.0).abs() < 1e-15, "{f} {want}");
        // Index 1: no reflection.
        assert!(fresnel_complex(0.6, 0.64, 1.0, 0.0).abs() < 1e-16);
        // η < 1 beyond the critical angle: total internal reflection.
        assert_eq!(fresnel_complex(0.3, 0.91, 0.9, 0.0), 1.0);
        // Brewster angle: Rp = 0, F = Rs/2 with Rs = ((c − a)/(c + a))².
        let tan_b: f64 = 1.5;
        let c = 1.0 / (1.0 + tan_b * tan_b).sqrt();
        let s2 = 1.0 - c * c;
        let a = (2.25 - s2).sqrt();
        let want = 0.5 * sqr((c - a) / (c + a));
        let f = fresnel_complex(c, s2, 1.5, 0.0);
        assert!((f / want - 1.0).abs() < 1e-14, "{f} {want}");
    }

    /// The series by brute force: every term from m = 1 in log space with lgamma.
    fn brute_force_series(ln_g: f64, t: f64, max_m: usize) -> f64 {
        let g = ln_g.exp();
        let logs: Vec<f64> = (1..=max_m)
            .map(|m| {
                let m = m as f64;
                m * ln_g - g - libm::lgamma(m + 1.0) - m.ln() - t / m
            })
            .collect();
        let top = logs.iter().cloned().fold(f64::NEG_INFINITY, f64::max);
        top + logs.iter().map(|l| (l - top).exp()).sum::<f64>().ln()
    }

    #[test]
    fn series_matches_brute_force_from_smooth_to_very_rough() {
        for &(g, t) in &[
            (1e-6, 0.0),
            (1e-3, 50.0),
            (0.08, 1800.0),
            (0.5, 0.0),
            (3.0, 10.0),
            (40.0, 0.0),
            (40.0, 3000.0),
            (800.0, 0.0),
            (800.0, 1e5),
            (7200.0, 0.0),
            (7200.0, 1800.0),
        ] {
            let got = DiffuseSeries::sum(f64::ln(g), t);
            let want = brute_force_series(f64::ln(g), t, 20_000);
            // The brute force loses ~|ln t| · eps in lgamma's cancellation: 1e-11 at g = 7200.
            let tol = 1e-15 * (1.0 + g);
            assert!(
                (got.ln_sum - want).abs() <= tol,
                "g {g} T {t}: {got:?} vs {want}"
            );
        }
    }

    /// Σ_{m≥1} e^{−g} g^m/(m! m) = e^{−g}(Ei(g) − γ − ln g) for T = 0; for g ≥ 1000 the
    /// asymptotic series Ei(g) ~ e^g/g Σ k!/g^k reaches full precision and e^{−g}(γ + ln g)
    /// is below 1e-400. An analytic check at very large term counts.
    #[test]
    fn series_matches_exponential_integral_asymptotics_for_very_rough_surfaces() {
        for &g in &[1e3, 7.2e3, 1e5, 1.58e8] {
            let mut acc = 0.0;
            let mut term = 1.0;
            for k in 0..40 {
                acc += term;
                term *= (k + 1) as f64 / g;
            }
            let want = acc / g;
            let got = DiffuseSeries::sum(f64::ln(g), 0.0);
            let rel = (got.ln_sum.exp() / want - 1.0).abs();
            eprintln!("g = {g:e}: {} terms, rel err {rel:e}", got.terms);
            assert!(rel < 2e-14, "g = {g}: {got:?} vs {want}, rel {rel:e}");
        }
    }

    /// The strided sum against every term, over the accepted ranges: g up to (4π σ0/λ)² =
    /// 1.58e8 (σ0 = 100 µm, λ = 0.1 µm) and T up to τ²k²·4/4 = 3.95e9 (τ = 1000 µm).
    #[test]
    fn strided_sum_matches_every_term_over_the_accepted_ranges() {
        let mut strided = 0;
        let mut worst: f64 = 0.0;
        let mut most_terms = 0;
        for i in 0..=60 {
            let g = 1e-3 * (1.58e11f64).powf(i as f64 / 60.0);
            for j in 0..=30 {
                let t = if j == 0 {
                    0.0
                } else {
                    1e-2 * (3.95e11f64).powf((j - 1) as f64 / 29.0)
                };
                let (ln_g, m0) = (g.ln(), series_mode(g.ln(), t));
                let got = DiffuseSeries::sum(ln_g, t);
                let want = DiffuseSeries::sum_every_term(ln_g, t);
                if series_stride(m0, t).is_some() {
                    strided += 1;
                    most_terms = most_terms.max(got.terms);
                } else {
                    assert_eq!(got, want, "g {g:e} T {t:e}: unchanged where not strided");
                }
                // ln Σ = ln t_{m0} + ln(Σ/t_{m0}), the anchor shared. Where T dominates
                // (m0 ≫ g) the walk's re-anchored terms carry ~|ln t|·ε of their own: at
                // g = 1.06e5, T = 3.95e9 the walk's ln(Σ/t_{m0}) is off by 4.1e-11 and the
                // strided one by 2.4e-12 (against mpmath at 40 digits), ln Σ = −32,865.
                let diff = (got.ln_sum - want.ln_sum).abs();
                let rounding = 8.0 * f64::EPSILON * want.ln_sum.abs();
                worst = worst.max((diff - rounding).max(0.0));
                assert!(
                    diff <= 2e-14 + rounding,
                    "g {g:e} T {t:e}: {got:?} vs {want:?}"
                );
            }
        }
        eprintln!(
            "{strided} of 1891 strided, worst |Δ ln Σ| beyond its rounding {worst:e}, most terms {most_terms}"
        );
        assert!(strided > 500, "{strided}");
        assert!(most_terms <= 45, "{most_terms}");
    }

    #[test]
    fn series_mode_is_the_integer_mode() {
        for &(g, t) in &[
            (0.5, 0.0),
            (3.0, 0.0),
            (3.0, 100.0),
            (800.0, 0.0),
            (0.01, 1e4),
        ] {
            let ln_g = f64::ln(g);
            let m0 = series_mode(ln_g, t);
            let lt = |m: f64| ln_term(m, ln_g, t);
            assert!(lt(m0 + 1.0) <= lt(m0), "{g} {t} {m0}");
            if m0 > 1.0 {
                assert!(lt(m0 - 1.0) <= lt(m0), "{g} {t} {m0}");
            }
        }
    }

    #[test]
    fn loader_poisson_matches_direct_form_where_both_are_accurate() {
        for &(m, g) in &[(16.0, 16.0), (20.0, 3.0), (100.0, 90.0), (40.0, 400.0)] {
            let direct = m * f64::ln(g) - g - libm::lgamma(m + 1.0);
            let loader = ln_poisson(m, f64::ln(g));
            assert!(
                (direct - loader).abs() < 1e-12,
                "{m} {g}: {direct} {loader}"
            );
        }
    }

    #[test]
    fn validate_names_parameter_value_and_range() {
        let bad = HtsgParams {
            sigma0_um: -1.0,
            ..HtsgParams::default()
        };
        let msg = bad.validate().unwrap_err().to_string();
        assert!(
            msg.contains("sigma0") && msg.contains("-1") && msg.contains("100"),
            "{msg}"
        );
        let bad = HtsgParams {
            wavelengths_um: vec![0.5, f64::NAN, 0.4],
            ..HtsgParams::default()
        };
        let msg = bad.validate().unwrap_err().to_string();
        assert!(
            msg.contains("wavelengths[1]") && msg.contains("NaN"),
            "{msg}"
        );
        let bad = HtsgParams {
            eta_im: vec![0.0, -0.1, 0.0],
            ..HtsgParams::default()
        };
        assert!(
            bad.validate()
                .unwrap_err()
                .to_string()
                .contains("eta_im[1]")
        );
        let bad = HtsgParams {
            eta_re: vec![1.5; 2],
            ..HtsgParams::default()
        };
        assert!(
            bad.validate()
                .unwrap_err()
                .to_string()
                .contains("eta_re has 2")
        );
        let bad = HtsgParams {
            tau_um: f64::INFINITY,
            ..HtsgParams::default()
        };
        assert!(bad.validate().unwrap_err().to_string().contains("tau"));
        assert!(HtsgParams::default().validate().is_ok());
    }

    #[test]
    fn normal_incidence_limit_is_finite_and_continuous() {
        let m = Htsg::new(HtsgParams::default()).unwrap();
        let mut at = [0.0; 3];
        let mut near = [0.0; 3];
        m.eval(Vec3::Z, Vec3::Z, &mut at);
        let tilt = 1e-7;
        m.eval(Vec3::Z, Vec3::from_spherical(tilt, 0.3), &mut near);
        for c in 0..3 {
            assert!(at[c].is_finite() && at[c] > 0.0);
            assert!((near[c] / at[c] - 1.0).abs() < 1e-9, "{at:?} {near:?}");
        }
    }

    #[test]
    fn below_horizon_and_nan_give_zero() {
        let m = Htsg::new(HtsgParams::default()).unwrap();
        let mut out = [1.0; 3];
        m.eval(Vec3::new(1.0, 0.0, 0.0), Vec3::Z, &mut out);
        assert_eq!(out, [0.0; 3]);
        out = [1.0; 3];
        m.eval(Vec3::new(f64::NAN, 0.0, 1.0), Vec3::Z, &mut out);
        assert_eq!(out, [0.0; 3]);
        assert_eq!(
            m.specular_coefficient(Vec3::new(0.0, 1.0, -0.1)),
            vec![0.0; 3]
        );
    }

    #[test]
    fn specular_coefficient_at_normal_is_fresnel_times_roughness_loss() {
        let m = Htsg::new(HtsgParams::default()).unwrap();
        let rho = m.specular_coefficient(Vec3::Z);
        for (c, lambda) in [0.645, 0.526, 0.444].into_iter().enumerate() {
            // Normal: S = 1, σ = σ0, g = (4π σ0/λ)², F = 0.04.
            let want = 0.04 * (-sqr(4.0 * PI * 0.18 / lambda)).exp();
            assert!((rho[c] / want - 1.0).abs() < 1e-14, "{rho:?}");
        }
    }
}
