//! RGL-EPFL material database `.bsdf` files (Dupuy & Jakob 2018, "An Adaptive
//! Parameterization for Efficient Material Acquisition and Rendering"), evaluated exactly as
//! Mitsuba 3.9.1's `measured` plugin does. The container is in [`tensor`], the warp and the
//! tables in [`warp`]; `spec/rgl-evaluation.md` describes both, and the step numbers in the
//! comments below are its steps.
//!
//! Conventions: `eval` returns f_r = Mitsuba's eval / wo.z (Mitsuba's eval is f_r·cos θo);
//! one-sided (0 when wi.z ≤ 0 or wo.z ≤ 0); negative table values are passed through unless
//! [`RglBsdf::with_clamp_negative`] asks for them to be clamped at 0 (as powitacq does).

pub mod fidelity;
pub mod fields;
pub mod packed;
pub mod tensor;
pub mod warp;
pub mod write;

use crate::brdf::{Brdf, Channels};
use crate::geometry::Vec3;
use crate::math::{FRAC_PI_2, PI, sqr};
use crate::{Error, Result};
use std::path::Path;
use tensor::{TensorField, TensorFile};
use warp::{ColourTables, Grid2, ParamBlend, ThetaAxis, VndfWarp};

/// Files larger than this are refused before reading (RGL files are about 0.6–2.5 MB).
pub const MAX_FILE_BYTES: u64 = 1 << 30;

/// Facts about a loaded file, for `inspect` and reports.
#[derive(Clone, Debug, PartialEq, serde::Serialize)]
pub struct RglInfo {
    /// The file's free-text `description` (lossy UTF-8; empty when absent).
    pub description: String,
    /// Colour grid resolution (columns, rows) of the warped sample square: n × n.
    pub resolution: [usize; 2],
    /// VNDF grid resolution (columns W, rows H) over the half-vector square.
    pub vndf_resolution: [usize; 2],
    /// Incident elevations of the slices (radians).
    pub theta_i: Vec<f64>,
    /// Number of incident azimuth slices (1 for isotropic files).
    pub phi_slices: usize,
    /// Mitsuba's `m_reduction` of an anisotropic file, round(2π / φi span): at 2 it turns wi
    /// and wo by π into φi < 0, at 4 it mirrors them into x ≤ 0, y ≤ 0 (1: no folding; 1 for
    /// isotropic files).
    pub reduction: i64,
    /// Whether the file is spectral (`spectra` + `wavelengths`) rather than RGB.
    pub spectral: bool,
    /// The `jacobian` flag: the data are multiplied by D(m)/(4σ(wi)).
    pub jacobian: bool,
    /// Per channel: how many entries of the colour table are negative.
    pub negative_counts: Vec<usize>,
    /// Entries per channel in the colour table.
    pub entries_per_channel: usize,
    /// Smallest and largest colour-table entry over all channels.
    pub value_range: [f64; 2],
}

/// A measured BRDF from an RGL `.bsdf` file, ready to evaluate (all warps built at load).
#[derive(Clone, Debug)]
pub struct RglBsdf {
    info: RglInfo,
    channels: Channels,
    theta_axis: ThetaAxis,
    /// The φi slices of an anisotropic file; `None` for an isotropic one.
    phi_axis: Option<ThetaAxis>,
    ndf: Grid2,
    sigma: Grid2,
    vndf: VndfWarp,
    colour: ColourTables,
    clamp_negative: bool,
    /// The file's fields as read (shared by clones: a candidate differs in its tables only).
    fields: std::sync::Arc<fields::RglFields>,
    /// The packed file's header, when read from one.
    packed: Option<std::sync::Arc<packed::PackedHeader>>,
}

impl RglBsdf {
    /// Reads and validates an RGL `.bsdf` file.
    pub fn open(path: impl AsRef<Path>) -> Result<RglBsdf> {
        let path = path.as_ref();
        let len = std::fs::metadata(path)
            .map_err(|e| Error::io(path, e))?
            .len();
        // Cap before reading the whole file into memory.
        if len > MAX_FILE_BYTES {
            return Err(Error::invalid_file(
                path,
                format!(
                    "file is {len} bytes, more than the {MAX_FILE_BYTES}-byte limit for an RGL .bsdf"
                ),
            ));
        }
        let bytes = std::fs::read(path).map_err(|e| Error::io(path, e))?;
        RglBsdf::from_bytes(&bytes, &path.display().to_string())
    }

    /// Parses an RGL `.bsdf` held in memory, or one packed in its own parameterization (a
    /// `.bpk` of kind [`packed::FORMAT`], read back to its fields); `name` labels error
    /// messages.
    pub fn from_bytes(bytes: &[u8], name: &str) -> Result<RglBsdf> {
        if crate::io::native::is_native(bytes) {
            let (header, fields) = packed::from_bytes(bytes, Path::new(name))?;
            let mut b = RglBsdf::from_fields(fields, name)?;
            b.packed = Some(std::sync::Arc::new(header));
            return Ok(b);
        }
        let mut b = RglBsdf::from_tensor_bytes(bytes, name)?;
        b.fields = std::sync::Arc::new(fields::RglFields::parse(bytes, name)?);
        Ok(b)
    }

    /// The BRDF of an RGL file's fields (validated here); `name` labels error messages.
    pub fn from_fields(fields: fields::RglFields, name: &str) -> Result<RglBsdf> {
        let bytes = fields.to_tensor_bytes();
        let mut b = RglBsdf::from_tensor_bytes(&bytes, name)?;
        b.fields = std::sync::Arc::new(fields);
        Ok(b)
    }

    /// The source's fields (what `convert` writes back and `pack` packs).
    pub fn fields(&self) -> &fields::RglFields {
        &self.fields
    }

    /// The header of the packed file this source was read from (`None`: an RGL `.bsdf`).
    pub fn packed(&self) -> Option<&packed::PackedHeader> {
        self.packed.as_deref()
    }

    /// This BRDF with its colour tables replaced by `values` (the colour field's layout
    /// `[Nφ, Nθ, C, n, n]`, same shape): a candidate of the planner, which changes only them.
    pub fn with_colour(&self, values: &[f32]) -> Result<RglBsdf> {
        let [nx, ny] = self.info.resolution;
        let slices = self.info.phi_slices * self.info.theta_i.len();
        let c = self.channels.len();
        if values.len() != slices * c * nx * ny {
            return Err(Error::input(format!(
                "colour tables of {} values, expected {}",
                values.len(),
                slices * c * nx * ny
            )));
        }
        let mut b = self.clone();
        b.colour = ColourTables::from_planar(values, slices, c, ny, nx);
        Ok(b)
    }

    /// This BRDF with its colour tables and its VNDF replaced (`colour` in the colour field's
    /// layout, `vndf` in the VNDF's `[Nφ, Nθ, H, W]`, finite and ≥ 0): a candidate of the
    /// planner whose VNDF is coded. What [`RglBsdf::from_fields`] makes of this BRDF's fields
    /// with those two replaced, without writing and parsing every field again.
    pub fn with_colour_and_vndf(&self, colour: &[f32], vndf: &[f32]) -> Result<RglBsdf> {
        let [w, h] = self.info.vndf_resolution;
        let slices = self.info.phi_slices * self.info.theta_i.len();
        if vndf.len() != slices * h * w {
            return Err(Error::input(format!(
                "VNDF of {} values, expected {}",
                vndf.len(),
                slices * h * w
            )));
        }
        if let Some(v) = vndf.iter().find(|v| !(v.is_finite() && **v >= 0.0)) {
            return Err(Error::input(format!(
                "VNDF value {v:e}, expected a finite density ≥ 0"
            )));
        }
        let mut b = self.with_colour(colour)?;
        b.vndf = VndfWarp::build(vndf, slices, h, w)
            .map_err(|m| Error::input(format!("field `vndf`: {m}")))?;
        Ok(b)
    }

    /// Parses and validates a tensor file (an RGL `.bsdf`).
    fn from_tensor_bytes(bytes: &[u8], name: &str) -> Result<RglBsdf> {
        let file = TensorFile::parse(bytes, name)?;
        let bad = |msg: String| Error::invalid_file(name, msg);

        let description = match file.get("description") {
            Some(f) => String::from_utf8_lossy(file.u8_values(f)?).into_owned(),
            None => String::new(),
        };

        // Incident azimuths: one slice means isotropic (φi enters only through φm − φi).
        let phi_field = file.require("phi_i")?;
        let phi_i = vector(&file, phi_field)?;
        let n_phi = phi_i.len();
        if n_phi == 0 || n_phi == 2 {
            return Err(bad(format!(
                "field `phi_i`: {n_phi} slices, expected 1 (isotropic) or at least 3 \
                 (anisotropic; Mitsuba treats 2 as isotropic, which brdfpack does not read)"
            )));
        }
        let phi_axis = if n_phi > 2 {
            let phi: Vec<f64> = phi_i.iter().map(|&p| p as f64).collect();
            strictly_increasing(&file, "phi_i", &phi)?;
            Some(ThetaAxis::new(phi))
        } else {
            None
        };
        // Mitsuba: m_reduction = (int) rint(2π / (φ_last − φ_first)) in float32.
        let reduction = match &phi_axis {
            Some(a) => {
                let v = a.values();
                let r = (2.0 * std::f32::consts::PI / (v[n_phi - 1] as f32 - v[0] as f32))
                    .round_ties_even();
                r as i64
            }
            None => 1,
        };

        let theta_field = file.require("theta_i")?;
        let theta_i: Vec<f64> = vector(&file, theta_field)?
            .into_iter()
            .map(f64::from)
            .collect();
        let n_theta = theta_i.len();
        if n_theta == 0 {
            return Err(file.field_error("theta_i", "is empty, expected at least one slice"));
        }
        strictly_increasing(&file, "theta_i", &theta_i)?;

        // ndf and sigma: 2D grids over the half-vector square, used as stored.
        let ndf = grid2(&file, "ndf", false)?;
        // σ is a divisor: it must be positive everywhere (bilinear keeps it so).
        let sigma = grid2(&file, "sigma", true)?;

        let vndf_field = file.require("vndf")?;
        let [h, w] = match vndf_field.shape[..] {
            [p, t, h, w] if p == n_phi && t == n_theta && h >= 2 && w >= 2 => [h, w],
            _ => {
                return Err(file.field_error(
                    "vndf",
                    format!(
                        "shape {:?} does not match [phi_i, theta_i, H, W] = [{n_phi}, {n_theta}, ≥2, ≥2]",
                        vndf_field.shape
                    ),
                ));
            }
        };
        let vndf_values = finite_values(&file, vndf_field)?;
        // A density: negative values would make the CDFs non-monotonic.
        if let Some(v) = vndf_values.iter().find(|v| **v < 0.0) {
            return Err(file.field_error("vndf", format!("negative density {v:e}, expected ≥ 0")));
        }
        let vndf = VndfWarp::build(&vndf_values, n_phi * n_theta, h, w)
            .map_err(|m| file.field_error("vndf", m))?;

        // Colour data: spectral iff a `wavelengths` field exists (Mitsuba's rule).
        let (data_name, channels) = match file.get("wavelengths") {
            Some(f) => {
                let wl: Vec<f64> = finite_values(&file, f)?
                    .into_iter()
                    .map(f64::from)
                    .collect();
                if f.shape.len() != 1 || wl.is_empty() {
                    return Err(file.field_error(
                        "wavelengths",
                        format!("shape {:?}, expected [Nλ] with Nλ ≥ 1", f.shape),
                    ));
                }
                ("spectra", Channels::spectral(wl))
            }
            None => ("rgb", Channels::default_for(3)),
        };
        let n_ch = channels.len();
        let data_field = file.require(data_name)?;
        let [ny, nx] = match data_field.shape[..] {
            [p, t, c, ny, nx] if p == n_phi && t == n_theta && c == n_ch && ny >= 2 && nx >= 2 => {
                [ny, nx]
            }
            _ => {
                return Err(file.field_error(
                    data_name,
                    format!(
                        "shape {:?} does not match [phi_i, theta_i, channels, n, n] = [{n_phi}, {n_theta}, {n_ch}, ≥2, ≥2]",
                        data_field.shape
                    ),
                ));
            }
        };
        let data = finite_values(&file, data_field)?;
        let plane = nx * ny;
        let mut negative_counts = vec![0usize; n_ch];
        let mut range = [f64::INFINITY, f64::NEG_INFINITY];
        for (p, &v) in data.iter().enumerate() {
            if v < 0.0 {
                negative_counts[(p / plane) % n_ch] += 1;
            }
            range = [range[0].min(v as f64), range[1].max(v as f64)];
        }
        let colour = ColourTables::from_planar(&data, n_phi * n_theta, n_ch, ny, nx);

        let jacobian_field = file.require("jacobian")?;
        let jacobian = match file.u8_values(jacobian_field)? {
            [flag] => *flag != 0,
            other => {
                return Err(file.field_error(
                    "jacobian",
                    format!("{} values, expected exactly 1", other.len()),
                ));
            }
        };
        check_peak(&file, data_name, range, jacobian.then_some((&ndf, &sigma)))?;

        Ok(RglBsdf {
            info: RglInfo {
                description,
                resolution: [nx, ny],
                vndf_resolution: [w, h],
                theta_i: theta_i.clone(),
                phi_slices: n_phi,
                reduction,
                spectral: data_name == "spectra",
                jacobian,
                negative_counts,
                entries_per_channel: n_phi * n_theta * plane,
                value_range: range,
            },
            channels,
            theta_axis: ThetaAxis::new(theta_i),
            phi_axis,
            ndf,
            sigma,
            vndf,
            colour,
            clamp_negative: false,
            fields: std::sync::Arc::new(fields::RglFields { fields: Vec::new() }),
            packed: None,
        })
    }

    /// Clamp negative results to 0 per channel (powitacq / pbrt-v4 behaviour) instead of
    /// passing them through (Mitsuba's behaviour, the default).
    pub fn with_clamp_negative(mut self, clamp: bool) -> RglBsdf {
        self.clamp_negative = clamp;
        self
    }

    pub fn clamps_negative(&self) -> bool {
        self.clamp_negative
    }

    /// What `inspect` reports about the file.
    pub fn info(&self) -> &RglInfo {
        &self.info
    }

    /// The file's free-text description.
    pub fn description(&self) -> &str {
        &self.info.description
    }

    /// Mitsuba's `eval` (f_r·cos θo) for unit `wi`, `wo`, one value per channel, without
    /// clamping. Steps 1–10 of the spec.
    #[inline]
    pub fn eval_cosine(&self, wi: Vec3, wo: Vec3, out: &mut [f64]) {
        // Step 1: one-sided. Comparing in f32 as Mitsuba does also sends z < 1.4e-45 (zero
        // in f32) to 0, which keeps eval / wo.z finite; `!(z > 0)` catches NaN too.
        if !((wi.z as f32) > 0.0 && (wo.z as f32) > 0.0 && wi.is_finite() && wo.is_finite()) {
            out.fill(0.0);
            return;
        }
        if let Some(phi_axis) = &self.phi_axis {
            self.eval_cosine_anisotropic(phi_axis, wi, wo, out);
            return;
        }
        // Step 2 (reduction folding) applies to anisotropic files only.
        // Step 3: the half vector (wi.z + wo.z > 0, so the sum is never zero).
        let m = (wi + wo) * (1.0 / (wi + wo).length());
        // Step 4: angles. φi and φm enter only through φm − φi (isotropic), computed as one
        // relative azimuth; φi alone is needed only by a σ table whose rows differ.
        let theta_i = elevation(wi);
        let theta_m = elevation(m);
        let delta_phi = relative_azimuth(wi, m);
        // Step 5: unit-square coordinates of wi and of m relative to φi (isotropic).
        let u_wi_y = if self.sigma.varies_along_y() {
            (drjit_atan2(wi.y, wi.x) + PI) / (2.0 * PI)
        } else {
            0.0 // any row gives the same value: skip an atan2
        };
        let u_wi = [(theta_i / FRAC_PI_2).sqrt(), u_wi_y];
        let v = (delta_phi + PI) / (2.0 * PI);
        let u_m = [(theta_m / FRAC_PI_2).sqrt(), v - v.floor()];
        // Step 6: θi slice weights (the single φi slice selects itself).
        let blend = self.theta_axis.locate(theta_i);
        // Step 7: invert the blended VNDF warp.
        let sample = self.vndf.invert(u_m, &blend);
        // Step 8: bilinear lookup in the blended colour tables.
        self.colour.lookup(sample, &blend, out);
        // Step 9: the Jacobian D(m)/(4σ(wi)) of the half-vector parameterisation.
        if self.info.jacobian {
            let scale = self.ndf.eval(u_m) / (4.0 * self.sigma.eval(u_wi));
            out.iter_mut().for_each(|o| *o *= scale);
        }
        // Step 10: eval = spec, f_r·cos θo.
    }

    /// [`RglBsdf::eval_cosine`] of an anisotropic file, as Mitsuba's `measured` plugin: the
    /// reduction folding, absolute azimuths of m, and the warps and tables blended over the
    /// four nearest (φi, θi) slices. `wi` and `wo` are above the horizon and finite.
    fn eval_cosine_anisotropic(
        &self,
        phi_axis: &ThetaAxis,
        mut wi: Vec3,
        mut wo: Vec3,
        out: &mut [f64],
    ) {
        // Step 2: a file whose φi slices span 1/2 (1/4) of a turn holds one half (quadrant)
        // of the azimuths; wi and wo are turned by π (mirrored in x and y) into it, as the
        // sign of wi's y (and x) says. Mitsuba's rule, ±0 included: a zero y counts as
        // positive, so wi.y = +0 becomes −0, whose φi Dr.Jit's atan2 makes +π.
        if self.info.reduction >= 2 {
            let sy = wi.y;
            let sx = if self.info.reduction == 4 { wi.x } else { sy };
            wi = Vec3::new(mulsign_neg(wi.x, sx), mulsign_neg(wi.y, sy), wi.z);
            wo = Vec3::new(mulsign_neg(wo.x, sx), mulsign_neg(wo.y, sy), wo.z);
        }
        // Steps 3–5 with absolute azimuths (φm is not taken relative to φi).
        let m = (wi + wo) * (1.0 / (wi + wo).length());
        let (theta_i, phi_i) = (elevation(wi), drjit_atan2(wi.y, wi.x));
        let (theta_m, phi_m) = (elevation(m), drjit_atan2(m.y, m.x));
        let u_wi = [(theta_i / FRAC_PI_2).sqrt(), (phi_i + PI) / (2.0 * PI)];
        let v = (phi_m + PI) / (2.0 * PI);
        let u_m = [(theta_m / FRAC_PI_2).sqrt(), v - v.floor()];
        // Step 6 in both parameters: the (φi, θi) slices, bilinearly.
        let blend = ParamBlend::new(
            phi_axis.locate(phi_i),
            self.theta_axis.locate(theta_i),
            self.theta_axis.values().len(),
        );
        // Steps 7–9 as for isotropic files.
        let sample = self.vndf.invert(u_m, &blend);
        self.colour.lookup(sample, &blend, out);
        if self.info.jacobian {
            let scale = self.ndf.eval(u_m) / (4.0 * self.sigma.eval(u_wi));
            out.iter_mut().for_each(|o| *o *= scale);
        }
    }
}

/// Dr.Jit's `mulsign_neg(a, s)`: a with its sign flipped unless s's sign bit is set
/// (−|a|·sign(s) for nonzero s; a zero s counts by its sign bit).
#[inline]
fn mulsign_neg(a: f64, s: f64) -> f64 {
    if s.is_sign_negative() { a } else { -a }
}

impl Brdf for RglBsdf {
    fn is_sampled(&self) -> bool {
        true
    }

    /// The planner recognises an RGL file to pack it in its own parameterization.
    fn as_any(&self) -> Option<&dyn std::any::Any> {
        Some(self)
    }

    fn channels(&self) -> &Channels {
        &self.channels
    }

    fn eval(&self, wi: Vec3, wo: Vec3, out: &mut [f64]) {
        self.eval_cosine(wi, wo, out);
        // f_r = eval / cos θo: Mitsuba's eval carries the cosine of wo (spec, "Cosine").
        // Below the horizon eval_cosine wrote zeros; the division must not turn them into NaN.
        if !((wi.z as f32) > 0.0 && (wo.z as f32) > 0.0) {
            return;
        }
        let inv_cos_o = 1.0 / wo.z;
        for o in out.iter_mut() {
            *o *= inv_cos_o;
            if self.clamp_negative {
                // Fitted data can dip below 0; a physical f_r cannot.
                *o = o.max(0.0);
            }
        }
    }

    fn is_isotropic(&self) -> bool {
        self.info.phi_slices == 1
    }

    fn is_reciprocal(&self) -> bool {
        // Measured, fitted data: f(wi, wo) and f(wo, wi) differ by 1–23 % (median).
        false
    }

    fn describe(&self) -> String {
        // The description is file text: it reaches terminals through reports and provenance.
        let mut s = format!(
            "RGL measured BRDF {}",
            crate::text::sanitize(&self.info.description)
        );
        if self.clamp_negative {
            s.push_str(" (negative values clamped to 0)");
        }
        s
    }
}

/// Step 4's elevation 2·asin(min(1, ½·|d − ẑ|)), equal to acos(d.z) for a unit d but
/// accurate near the normal.
#[inline]
fn elevation(d: Vec3) -> f64 {
    // The min guards asin against rounding past 1 for d near −ẑ.
    2.0 * (0.5 * (sqr(d.x) + sqr(d.y) + sqr(d.z - 1.0)).sqrt())
        .min(1.0)
        .asin()
}

/// Dr.Jit's atan2: 0 for (±0, ±0), and the sign of a zero y ignored (atan2(−0, −1) = +π).
#[inline]
fn drjit_atan2(y: f64, x: f64) -> f64 {
    if y == 0.0 {
        // Covers both of Dr.Jit's rules: +0 for y, then (0, ±0) → 0 and (0, x<0) → π.
        if x < 0.0 { PI } else { 0.0 }
    } else {
        y.atan2(x)
    }
}

/// φm − φi (mod 2π) for Dr.Jit's φ = atan2(y, x) of the two directions, as one atan2 of
/// the cross and dot products of their xy projections. Equal to the difference of the two
/// azimuths after step 5's wrap, including Dr.Jit's atan2(0, 0) = 0 for a direction on the
/// normal, and ±π (both wrap to u_φ = 0) for opposite projections.
#[inline]
fn relative_azimuth(wi: Vec3, m: Vec3) -> f64 {
    if wi.x == 0.0 && wi.y == 0.0 {
        // φi = atan2(0, 0) = 0 (normal incidence).
        drjit_atan2(m.y, m.x)
    } else if m.x == 0.0 && m.y == 0.0 {
        // φm = 0 (exact mirror configuration).
        -drjit_atan2(wi.y, wi.x)
    } else {
        drjit_atan2(wi.x * m.y - wi.y * m.x, wi.x * m.x + wi.y * m.y)
    }
}

/// A slice parameter field's values must increase strictly (Mitsuba's interval search needs it).
fn strictly_increasing(file: &TensorFile, name: &str, values: &[f64]) -> Result<()> {
    match values.windows(2).find(|w| w[0] >= w[1]) {
        Some(w) => Err(file.field_error(
            name,
            format!(
                "values must increase strictly, found {} then {}",
                w[0], w[1]
            ),
        )),
        None => Ok(()),
    }
}

/// A 1-dimensional float32 field's values.
fn vector(file: &TensorFile, field: &TensorField) -> Result<Vec<f32>> {
    if field.shape.len() != 1 {
        return Err(file.field_error(
            &field.name,
            format!("shape {:?}, expected one dimension", field.shape),
        ));
    }
    finite_values(file, field)
}

/// A float32 field's values, all finite (NaN or Inf would reach every result).
fn finite_values(file: &TensorFile, field: &TensorField) -> Result<Vec<f32>> {
    let values = file.f32_values(field)?;
    if let Some((i, v)) = values.iter().enumerate().find(|(_, v)| !v.is_finite()) {
        return Err(file.field_error(&field.name, format!("value #{i} is {v}, expected finite")));
    }
    Ok(values)
}

/// A [rows, columns] float32 grid with both sizes ≥ 2, optionally required positive.
fn grid2(file: &TensorFile, name: &str, positive: bool) -> Result<Grid2> {
    let field = file.require(name)?;
    let [rows, cols] = match field.shape[..] {
        [r, c] if r >= 2 && c >= 2 => [r, c],
        _ => {
            return Err(file.field_error(
                name,
                format!("shape {:?}, expected [rows ≥ 2, columns ≥ 2]", field.shape),
            ));
        }
    };
    let values = finite_values(file, field)?;
    // σ is a divisor: a subnormal (below 1.2e-38) is no projected area of a surface, and
    // dividing by it overflows f32 at once.
    if positive
        && let Some((i, v)) = values
            .iter()
            .enumerate()
            .find(|(_, v)| **v < f32::MIN_POSITIVE)
    // finite: checked above
    {
        return Err(file.field_error(
            name,
            format!(
                "value #{i} is {v:e}, expected a normal positive number (≥ {:e})",
                f32::MIN_POSITIVE
            ),
        ));
    }
    // Its bilinear value a + t·(b − a) between a huge and a small node cancels to 0 in f64
    // once their ratio passes ~2⁵² (a fuzzed σ of 7.4e19 beside 4 made eval infinite); with
    // the nodes within 2⁴⁰ of each other the rounding error stays below 2⁻¹² of the smallest,
    // so every interpolated σ is positive. Projected areas of real surfaces span a few
    // decades (σ ≥ 1 at the normal, ≤ ~1/cos θ at grazing).
    if positive {
        let (lo, hi) = values
            .iter()
            .fold((f32::INFINITY, 0f32), |(lo, hi), &v| (lo.min(v), hi.max(v)));
        if f64::from(hi) > f64::from(lo) * MAX_POSITIVE_RANGE {
            return Err(file.field_error(
                name,
                format!(
                    "values span {lo:e} .. {hi:e}, more than a factor of 2^40: interpolating \
                     between them loses the smaller ones (a projected area spans a few decades)"
                ),
            ));
        }
    }
    Ok(Grid2::new(cols, rows, values))
}

/// Largest ratio between the nodes of a grid that must stay positive when interpolated (σ).
const MAX_POSITIVE_RANGE: f64 = (1u64 << 40) as f64;

/// Smallest cos θo at which an RGL file's values must fit f32 (θo ≈ 89.99994°): finer
/// than any grid's cell centres, far beyond any real measurement's range of values.
pub const MIN_COS_THETA_O: f64 = 1e-6;

/// Refuses a file whose BRDF values f32 storage cannot hold: the largest |colour value|
/// times, with the Jacobian, the largest D(m)/(4σ(wi)), divided by cos θo (f_r = eval /
/// cos θo), must fit f32 for every cos θo ≥ [`MIN_COS_THETA_O`] (issue 20: such files were
/// found only by the command that used a value, exit 1, with 309-digit numbers). The field
/// named is the one with the extreme factor: the colour data, `ndf` or `sigma`.
fn check_peak(
    file: &TensorFile,
    data_name: &str,
    range: [f64; 2],
    jacobian: Option<(&Grid2, &Grid2)>,
) -> Result<()> {
    let colour_peak = range[0].abs().max(range[1].abs());
    let limit = f64::from(f32::MAX) * MIN_COS_THETA_O;
    let (ndf_max, sigma_min) = match jacobian {
        Some((ndf, sigma)) => (
            ndf.values().iter().fold(0f64, |m, &v| m.max(f64::from(v))),
            sigma
                .values()
                .iter()
                .fold(f64::INFINITY, |m, &v| m.min(f64::from(v))),
        ),
        None => (1.0, 0.25),
    };
    let scale = ndf_max / (4.0 * sigma_min);
    let peak = colour_peak * scale;
    if peak > limit {
        // Name the factor furthest from the ordinary (D, 1/σ and colours are O(1) for real
        // surfaces).
        let extremes = [
            (data_name, "largest |value|", colour_peak, colour_peak),
            ("ndf", "largest value", ndf_max, ndf_max),
            ("sigma", "smallest value", sigma_min, 1.0 / sigma_min),
        ];
        let (field, what, value, _) = extremes
            .into_iter()
            .fold(extremes[0], |a, b| if b.3 > a.3 { b } else { a });
        // The factors are f32 values of the file: their shortest f32 form (3e38, not
        // 3.0000000054977558e38).
        let short = |x: f64| x as f32;
        let factors = match jacobian {
            Some(_) => format!(
                " (colour {:e} × ndf {:e} / (4 × sigma {:e}))",
                short(colour_peak),
                short(ndf_max),
                short(sigma_min)
            ),
            None => String::new(),
        };
        return Err(file.field_error(
            field,
            format!(
                "{what} {:e}: the BRDF would reach {peak:.3e} / cos θo{factors}, beyond f32 \
                 storage ({:e}) already at cos θo = {MIN_COS_THETA_O:e}",
                short(value),
                f32::MAX
            ),
        ));
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::math::SplitMix64;

    /// step 5's wrap of an azimuth difference to [0, 1).
    fn wrap(d: f64) -> f64 {
        let v = (d + PI) / (2.0 * PI);
        v - v.floor()
    }

    #[test]
    fn relative_azimuth_equals_the_difference_of_azimuths() {
        let mut rng = SplitMix64::new(11);
        for _ in 0..10_000 {
            let a = Vec3::from_spherical(rng.next_f64() * 1.5, (rng.next_f64() - 0.5) * 7.0);
            let b = Vec3::from_spherical(rng.next_f64() * 1.5, (rng.next_f64() - 0.5) * 7.0);
            let direct = drjit_atan2(b.y, b.x) - drjit_atan2(a.y, a.x);
            let d = (wrap(relative_azimuth(a, b)) - wrap(direct)).abs();
            // Away from the seam the two agree to rounding; across it they differ by ~1.
            assert!(!(1e-14..=1.0 - 1e-14).contains(&d), "{a:?} {b:?}");
        }
        // Exact special cases: coordinate planes, normal incidence, the mirror half vector.
        let cases = [
            (Vec3::new(0.6, 0.0, 0.8), Vec3::new(-0.3, 0.0, 0.9), 0.0),
            (Vec3::new(-0.6, 0.0, 0.8), Vec3::new(0.3, 0.0, 0.9), 0.0),
            (Vec3::new(0.0, 0.6, 0.8), Vec3::new(0.0, -0.3, 0.9), 0.0),
            (Vec3::new(0.6, 0.0, 0.8), Vec3::new(0.3, 0.0, 0.9), 0.5),
            (Vec3::new(0.0, 0.0, 1.0), Vec3::new(0.0, 0.3, 0.9), 0.75),
            (Vec3::new(0.0, 0.6, 0.8), Vec3::new(0.0, 0.0, 1.0), 0.25),
            (Vec3::new(-0.6, -0.0, 0.8), Vec3::new(0.0, 0.0, 1.0), 0.0),
        ];
        for (a, b, want) in cases {
            assert_eq!(wrap(relative_azimuth(a, b)), want, "{a:?} {b:?}");
        }
    }

    #[test]
    fn drjit_atan2_conventions() {
        assert_eq!(drjit_atan2(0.0, 0.0), 0.0);
        assert_eq!(drjit_atan2(-0.0, -0.0), 0.0);
        assert_eq!(drjit_atan2(-0.0, -1.0), PI);
        assert_eq!(drjit_atan2(-0.0, 1.0), 0.0);
        assert_eq!(drjit_atan2(1.0, -0.0), FRAC_PI_2);
    }

    #[test]
    fn elevation_is_acos_for_unit_vectors() {
        for t in [0.0, 1e-9, 0.3, 1.0, 1.5, FRAC_PI_2] {
            let d = Vec3::from_spherical(t, 0.7);
            assert!((elevation(d) - t).abs() < 1e-15, "{t}");
        }
    }
}
