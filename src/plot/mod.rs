//! Pictures of a BRDF, of its round trip and of the error (docs/plots.md): the views users
//! know from BRDF Explorer, drawn into a [`Figure`] and written as PNG or SVG.
//!
//! - `sphere`: a sphere lit by a directional light, seen by an orthographic camera;
//! - `lobe`: polar plots of f_r·cos θo in the plane of incidence, for several θi;
//! - `slice`: the θh × θd image at one φd (MERL style), log scale; table cells as stored;
//! - `albedo`: directional albedo against θi (the `props` quadrature);
//! - `report`: all four stacked (what `check --plot` writes).
//!
//! With a reference, each view shows both (three panels for images: reference, source and
//! the relative error |s − r| / (r + ε)). Every pixel is computed independently from the
//! options, so the bytes are the same for any thread count.

pub mod figure;
pub mod raster;
pub mod svg;
mod views;

pub use figure::{Figure, Item, Panel, RgbImage};
pub use views::{
    LobeCurve, SLICE_DEFAULT_RESOLUTION, SliceCells, albedo_view, lobe_curves, lobe_view,
    slice_cells, slice_view, sphere_radiance, sphere_view,
};

use crate::brdf::Brdf;
use crate::source::{Lookup, Source};
use crate::spectral::{SpectrumToRgb, is_spectral};
use crate::table::Table;
use crate::{Error, Result};
use std::path::Path;

/// Which picture.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum View {
    Sphere,
    Lobe,
    Slice,
    Albedo,
    /// All four views stacked.
    Report,
}

/// How lobe radii are scaled.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum RadiusScale {
    Linear,
    /// log10, over [`PlotOptions::lobe_decades`] decades below the largest value.
    Log,
}

/// The image file format.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ImageFormat {
    Png,
    Svg,
}

impl ImageFormat {
    /// The format named by a file's extension (`.png`, `.svg`, any case).
    pub fn from_path(path: &Path) -> Option<ImageFormat> {
        let ext = path.extension()?.to_str()?.to_ascii_lowercase();
        match ext.as_str() {
            "png" => Some(ImageFormat::Png),
            "svg" => Some(ImageFormat::Svg),
            _ => None,
        }
    }
}

/// Everything a view needs besides its sources. [`Default`] gives the documented defaults.
#[derive(Clone, Debug, PartialEq)]
pub struct PlotOptions {
    /// Sphere panel size in pixels (the sphere fills it).
    pub size: usize,
    /// Exposure in stops: radiance is multiplied by 2^exposure before tone mapping.
    pub exposure_ev: f64,
    /// Direction towards the light in the camera frame (x right, y up, z towards the camera):
    /// polar angle from the view direction and azimuth from +x, in degrees.
    pub light_theta_deg: f64,
    pub light_phi_deg: f64,
    /// Irradiance E of the light on a surface facing it; π makes a white Lambertian surface
    /// facing the light exactly 1.0 (radiance L = f_r · cos θi · E).
    pub irradiance: f64,
    /// Incidence angles of the lobe plots, degrees.
    pub lobe_theta_i_deg: Vec<f64>,
    pub lobe_radius: RadiusScale,
    /// Decades shown by a log-radius lobe plot.
    pub lobe_decades: f64,
    /// Samples of θo over [−90°, 90°] per lobe curve.
    pub lobe_samples: usize,
    /// φd of the slice, degrees (a table's nearest stored φd is used and stated).
    pub phi_d_deg: f64,
    /// Decades shown by the slice colour scale.
    pub slice_decades: f64,
}

impl Default for PlotOptions {
    fn default() -> Self {
        PlotOptions {
            size: 256,
            exposure_ev: 0.0,
            light_theta_deg: 45.0,
            light_phi_deg: 135.0,
            irradiance: std::f64::consts::PI,
            lobe_theta_i_deg: vec![0.0, 30.0, 60.0, 75.0],
            lobe_radius: RadiusScale::Log,
            lobe_decades: 3.0,
            lobe_samples: 361,
            phi_d_deg: 90.0,
            slice_decades: 6.0,
        }
    }
}

impl PlotOptions {
    /// Checks ranges (exit 2 on bad values): sizes, finite angles, at least one θi in [0, 90).
    pub fn validate(&self) -> Result<()> {
        let bad = |what: &str, v: String, want: &str| {
            Err(Error::input(format!("{what} {v}: expected {want}")))
        };
        if !(16..=2048).contains(&self.size) {
            return bad("--size", self.size.to_string(), "16 to 2048 pixels");
        }
        if !(self.exposure_ev.is_finite() && self.exposure_ev.abs() <= 64.0) {
            return bad(
                "--exposure",
                self.exposure_ev.to_string(),
                "a finite EV in [-64, 64]",
            );
        }
        if !(self.light_theta_deg.is_finite() && (0.0..90.0).contains(&self.light_theta_deg)) {
            return bad(
                "--light",
                self.light_theta_deg.to_string(),
                "θ in [0, 90) degrees",
            );
        }
        if !self.light_phi_deg.is_finite() {
            return bad("--light", self.light_phi_deg.to_string(), "a finite φ");
        }
        if !(self.irradiance.is_finite() && self.irradiance > 0.0) {
            return bad(
                "--irradiance",
                self.irradiance.to_string(),
                "a finite value > 0",
            );
        }
        if self.lobe_theta_i_deg.is_empty() || self.lobe_theta_i_deg.len() > 8 {
            return bad(
                "--theta-i",
                format!("{:?}", self.lobe_theta_i_deg),
                "1 to 8 angles",
            );
        }
        for &t in &self.lobe_theta_i_deg {
            if !(t.is_finite() && (0.0..90.0).contains(&t)) {
                return bad("--theta-i", t.to_string(), "angles in [0, 90) degrees");
            }
        }
        if !(self.lobe_decades.is_finite() && (0.5..=12.0).contains(&self.lobe_decades)) {
            return bad("--decades", self.lobe_decades.to_string(), "0.5 to 12");
        }
        if !(3..=100_001).contains(&self.lobe_samples) {
            return bad(
                "--lobe-samples",
                self.lobe_samples.to_string(),
                "3 to 100001",
            );
        }
        if !(self.phi_d_deg.is_finite() && (0.0..360.0).contains(&self.phi_d_deg)) {
            return bad(
                "--phi-d",
                self.phi_d_deg.to_string(),
                "an angle in [0, 360) degrees",
            );
        }
        if !(self.slice_decades.is_finite() && (0.5..=12.0).contains(&self.slice_decades)) {
            return bad(
                "--slice-decades",
                self.slice_decades.to_string(),
                "0.5 to 12",
            );
        }
        Ok(())
    }
}

/// How a source's channels become display colours: RGB as is, one channel as grey, spectral
/// samples through CIE 1931 to linear sRGB (crate::spectral), any other count as the mean.
pub enum Display {
    Rgb,
    Grey,
    Spectral(SpectrumToRgb),
    Mean,
}

impl Display {
    pub fn for_brdf(brdf: &dyn Brdf) -> Display {
        let ch = brdf.channels();
        if is_spectral(ch)
            && let Some(w) = ch.wavelengths_nm()
            && let Ok(s) = SpectrumToRgb::new(w)
        {
            return Display::Spectral(s);
        }
        match ch.len() {
            1 => Display::Grey,
            3 => Display::Rgb,
            _ => Display::Mean,
        }
    }

    /// Linear RGB of one value per channel.
    pub fn rgb(&self, v: &[f64]) -> [f64; 3] {
        match self {
            Display::Rgb => [v[0], v[1], v[2]],
            Display::Grey => [v[0]; 3],
            Display::Spectral(s) => s.convert(v),
            Display::Mean => [v.iter().sum::<f64>() / v.len().max(1) as f64; 3],
        }
    }

    /// True when the display has one value (grey), not three colours.
    pub fn is_grey(&self) -> bool {
        matches!(self, Display::Grey | Display::Mean)
    }

    /// Rec. 709 luminance Y of one value per channel.
    pub fn luminance(&self, v: &[f64]) -> f64 {
        let [r, g, b] = self.rgb(v);
        0.2126 * r + 0.7152 * g + 0.0722 * b
    }
}

/// A source ready to be drawn: its name, pointwise evaluation and, for tables, the stored
/// cells (the slice view shows them as stored, with the grid's validity).
pub struct Subject {
    pub label: String,
    pub brdf: Box<dyn Brdf>,
    pub table: Option<Table>,
}

impl Subject {
    /// Opens a source named on the command line (see [`Source::open`]).
    pub fn open(spec: &str, lookup: Lookup) -> Result<Subject> {
        let source = Source::open(spec)?;
        let table = match &source {
            Source::Table(t) => Some(t.clone()),
            _ => None,
        };
        Ok(Subject {
            label: spec.to_string(),
            brdf: source.into_brdf(lookup)?,
            table,
        })
    }

    /// A source that is a pointwise BRDF only.
    pub fn from_brdf(label: impl Into<String>, brdf: Box<dyn Brdf>) -> Subject {
        Subject {
            label: label.into(),
            brdf,
            table: None,
        }
    }
}

/// Draws `view` of `source` (and `reference`, when given).
pub fn plot(
    view: View,
    source: &Subject,
    reference: Option<&Subject>,
    opts: &PlotOptions,
) -> Result<Figure> {
    opts.validate()?;
    Ok(match view {
        View::Sphere => sphere_view(source, reference, opts),
        View::Lobe => lobe_view(source, reference, opts),
        View::Slice => slice_view(source, reference, opts),
        View::Albedo => albedo_view(source, reference),
        View::Report => Figure::stack(vec![
            sphere_view(source, reference, opts),
            lobe_view(source, reference, opts),
            slice_view(source, reference, opts),
            albedo_view(source, reference),
        ]),
    })
}

/// The file bytes of a figure.
pub fn encode(fig: &Figure, format: ImageFormat) -> Result<Vec<u8>> {
    match format {
        ImageFormat::Png => raster::encode_png(&raster::rasterize(fig)),
        ImageFormat::Svg => Ok(svg::to_svg(fig)?.into_bytes()),
    }
}
