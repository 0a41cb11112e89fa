//! `brdfpack plot`: pictures of a source, and of its error against a reference.

use super::common::LookupArg;
use crate::io::atomic;
use crate::plot::{self, ImageFormat, PlotOptions, RadiusScale, Subject, View};
use clap::{Args, ValueEnum};
use std::path::{Path, PathBuf};

#[derive(Clone, Copy, Debug, PartialEq, Eq, ValueEnum)]
pub enum ViewArg {
    /// A lit sphere (three panels with --against: reference, source, error).
    Sphere,
    /// Polar plots of f·cosθo in the plane of incidence (and φ = 90° when anisotropic).
    Lobe,
    /// θh × θd image at one φd, log scale; invalid table cells grey.
    Slice,
    /// Directional albedo against θi.
    Albedo,
    /// All four views stacked.
    Report,
}

impl From<ViewArg> for View {
    fn from(v: ViewArg) -> View {
        match v {
            ViewArg::Sphere => View::Sphere,
            ViewArg::Lobe => View::Lobe,
            ViewArg::Slice => View::Slice,
            ViewArg::Albedo => View::Albedo,
            ViewArg::Report => View::Report,
        }
    }
}

#[derive(Clone, Copy, Debug, PartialEq, Eq, ValueEnum)]
pub enum FormatArg {
    Png,
    Svg,
}

#[derive(Clone, Copy, Debug, PartialEq, Eq, ValueEnum)]
pub enum RadiusArg {
    Log,
    Linear,
}

/// How a picture is drawn (shared by `plot` and `check --plot`).
#[derive(Args, Debug, Clone)]
pub struct PictureArgs {
    /// Sphere panel size in pixels.
    #[arg(long, default_value_t = 256, help_heading = "Picture")]
    pub size: usize,
    /// Exposure in stops (radiance × 2^EV before clipping at 1 and the sRGB curve).
    #[arg(
        long,
        default_value_t = 0.0,
        allow_negative_numbers = true,
        help_heading = "Picture"
    )]
    pub exposure: f64,
    /// Light direction in the camera frame, THETA,PHI degrees (θ from the view direction).
    #[arg(
        long,
        default_value = "45,135",
        value_name = "THETA,PHI",
        help_heading = "Picture"
    )]
    pub light: String,
    /// Irradiance of the light (π: a white Lambertian surface facing it is 1.0).
    #[arg(long, help_heading = "Picture")]
    pub irradiance: Option<f64>,
    /// Incidence angles of the lobe view, degrees.
    #[arg(
        long,
        value_delimiter = ',',
        default_value = "0,30,60,75",
        help_heading = "Picture"
    )]
    pub theta_i: Vec<f64>,
    /// Radius scale of the lobe view.
    #[arg(long, value_enum, default_value_t = RadiusArg::Log, help_heading = "Picture")]
    pub radius: RadiusArg,
    /// Decades shown by a log-radius lobe plot.
    #[arg(long, default_value_t = 3.0, help_heading = "Picture")]
    pub decades: f64,
    /// φd of the slice view, degrees (a table shows its nearest stored φd).
    #[arg(long, default_value_t = 90.0, help_heading = "Picture")]
    pub phi_d: f64,
    /// Decades of the slice colour scale.
    #[arg(long, default_value_t = 6.0, help_heading = "Picture")]
    pub slice_decades: f64,
}

impl PictureArgs {
    pub fn options(&self) -> crate::Result<PlotOptions> {
        let bad = || {
            crate::Error::input(format!(
                "--light {}: expected THETA,PHI in degrees, e.g. 45,135",
                self.light
            ))
        };
        let parts: Vec<&str> = self.light.split(',').collect();
        let [t, p] = parts.as_slice() else {
            return Err(bad());
        };
        let d = PlotOptions::default();
        let opts = PlotOptions {
            size: self.size,
            exposure_ev: self.exposure,
            light_theta_deg: t.trim().parse().map_err(|_| bad())?,
            light_phi_deg: p.trim().parse().map_err(|_| bad())?,
            irradiance: self.irradiance.unwrap_or(d.irradiance),
            lobe_theta_i_deg: self.theta_i.clone(),
            lobe_radius: match self.radius {
                RadiusArg::Log => RadiusScale::Log,
                RadiusArg::Linear => RadiusScale::Linear,
            },
            lobe_decades: self.decades,
            lobe_samples: d.lobe_samples,
            phi_d_deg: self.phi_d,
            slice_decades: self.slice_decades,
        };
        opts.validate()?;
        Ok(opts)
    }
}

#[derive(Args, Debug)]
pub struct PlotArgs {
    /// The source to draw: a model spec, a table (.bpk, .exr, .binary) or an RGL file.
    pub source: String,
    /// A reference drawn beside it (and the error between them).
    #[arg(long)]
    pub against: Option<String>,
    /// Which picture.
    #[arg(long, value_enum, default_value_t = ViewArg::Sphere)]
    pub view: ViewArg,
    /// Output image (.png or .svg; `-` for stdout with --format).
    #[arg(short, long)]
    pub output: PathBuf,
    /// Image format; default from the output name.
    #[arg(long, value_enum)]
    pub format: Option<FormatArg>,
    /// Interpolation used for tables.
    #[arg(long, value_enum, default_value_t = LookupArg::Linear)]
    pub interp: LookupArg,
    #[command(flatten)]
    pub picture: PictureArgs,
    /// A JSON report (output, format, bytes) on stdout.
    #[arg(long)]
    pub json: bool,
    /// Nothing but errors.
    #[arg(short, long, conflicts_with = "verbose")]
    pub quiet: bool,
    /// Say on stderr what was written.
    #[arg(short, long)]
    pub verbose: bool,
    #[command(flatten)]
    pub depfile: super::common::DepfileArgs,
}

/// The image format of `path` (or the one named).
pub fn image_format(path: &Path, named: Option<FormatArg>) -> crate::Result<ImageFormat> {
    match named {
        Some(FormatArg::Png) => Ok(ImageFormat::Png),
        Some(FormatArg::Svg) => Ok(ImageFormat::Svg),
        None => ImageFormat::from_path(path).ok_or_else(|| {
            crate::Error::input(format!(
                "-o {}: cannot tell the image format from the name; use .png or .svg, or \
                 --format png|svg",
                path.display()
            ))
        }),
    }
}

/// Draws `view` and writes it atomically.
pub fn write_picture(
    view: View,
    source: &Subject,
    reference: Option<&Subject>,
    opts: &PlotOptions,
    path: &Path,
    format: ImageFormat,
) -> crate::Result<()> {
    let fig = plot::plot(view, source, reference, opts)?;
    atomic::write_output(path, &plot::encode(&fig, format)?)
}

pub fn run(a: PlotArgs) -> anyhow::Result<i32> {
    let format = image_format(&a.output, a.format)?;
    let opts = a.picture.options()?;
    let source = Subject::open(&a.source, a.interp.into())?;
    let reference = a
        .against
        .as_deref()
        .map(|r| Subject::open(r, a.interp.into()))
        .transpose()?;
    write_picture(
        a.view.into(),
        &source,
        reference.as_ref(),
        &opts,
        &a.output,
        format,
    )?;
    let mut reads = crate::reads::ReadSet::new();
    for name in std::iter::once(&a.source).chain(a.against.as_ref()) {
        // The subjects were opened above; this records the files they read.
        if std::path::Path::new(name).exists() {
            reads.record(name);
        } else {
            let _ = crate::model::Model::parse_recording(name, &mut reads);
        }
    }
    a.depfile.write(&[a.output.as_path()], &reads)?;
    let bytes = std::fs::metadata(&a.output).map(|m| m.len()).unwrap_or(0);
    if a.verbose {
        eprintln!("brdfpack: wrote {} ({bytes} bytes)", a.output.display());
    }
    if a.json {
        outln!(
            "{}",
            serde_json::json!({"output": a.output.display().to_string(), "bytes": bytes})
        );
    }
    Ok(0)
}
