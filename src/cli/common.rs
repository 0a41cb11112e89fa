//! Plumbing shared by subcommands: output format flags, writing tables, terminals.

use crate::codec::CodecRequest;
use crate::grid::Grid;
use crate::io::exr::ExrOptions;
use crate::io::mbsdf::{MbsdfOptions, mbsdf_dims};
use crate::io::merl::merl_dims;
use crate::io::{FormatName, OutputFormat, atomic, encode_table};
use crate::table::Table;
use crate::{Error, Result};
use clap::Args;
use std::io::IsTerminal;
use std::path::Path;

pub use super::values::{ExrCompressionArg, ExrTypeArg, FormatArg, InterpArg, LookupArg};
pub use crate::source::{Lookup, Source};

/// How a table is written: the format (from the output name or `--format`) and its options.
#[derive(Args, Debug, Clone)]
pub struct OutputArgs {
    /// Output format; default from the output name: .bpk native, .exr EXR, .binary MERL,
    /// .mbsdf MDL, .bsdf RGL (`convert` only) (and native for `-`, stdout).
    #[arg(long, value_enum, help_heading = "Output")]
    pub format: Option<FormatArg>,
    /// EXR sample type (f16 values above 65504 are scaled by a recorded power of two).
    #[arg(long, value_enum, default_value_t = ExrTypeArg::F32, help_heading = "Output")]
    pub exr_type: ExrTypeArg,
    /// EXR compression; lossless by default (pxr24 is lossy for f32 and only used when named).
    #[arg(long, value_enum, default_value_t = ExrCompressionArg::Zip, help_heading = "Output")]
    pub exr_compression: ExrCompressionArg,
    /// Codec of the native format: `lossless` (prediction + byte shuffle + zstd, bit-exact),
    /// `zstd-f32`, `f16`, `uniform:bits=K`, `dct:step=S` ... (docs/compression.md).
    #[arg(long, default_value = "lossless", help_heading = "Output")]
    pub codec: String,
    /// MDL .mbsdf: write a scalar file (Rec. 709 luminance) from an RGB table.
    #[arg(long, help_heading = "Output")]
    pub mbsdf_scalar: bool,
}

/// Where a table goes: the format, with the native codec still to be fitted to the table.
pub enum OutputPlan {
    Native(CodecRequest),
    Other(OutputFormat),
    /// An RGL `.bsdf`: written from a BRDF by `convert`, not from a table.
    Rgl,
}

impl OutputArgs {
    /// The format for `path`, checking that `grid` can be written in it and that the codec
    /// spec parses (before any work is done).
    pub fn resolve(&self, path: &Path, grid: &Grid) -> Result<OutputPlan> {
        let format = self
            .format
            .map(FormatName::from)
            .or_else(|| FormatName::from_path(path))
            // stdout: the native format unless told otherwise.
            .or((path.as_os_str() == "-").then_some(FormatName::Native))
            .ok_or_else(|| {
                Error::input(format!(
                    "-o {}: cannot tell the output format from the name; use .bpk, .exr, \
                     .binary, .mbsdf or .bsdf, or --format native|exr|merl|mbsdf|rgl",
                    path.display()
                ))
            })?;
        if format == FormatName::Merl && merl_dims(grid).is_none() {
            return Err(Error::input(format!(
                "--grid {}: MERL .binary needs a halfdiff3 grid with warps sqrt/linear/linear at \
                 the lower bin edges (e.g. `merl`)",
                grid.describe()
            )));
        }
        if format == FormatName::Mbsdf && mbsdf_dims(grid).is_none() {
            return Err(Error::input(format!(
                "--grid {}: MDL .mbsdf needs a spherical3 grid with nθi = nθo, linear warps and \
                 centred samples (e.g. `spherical3:90x90x180`)",
                grid.describe()
            )));
        }
        Ok(match format {
            FormatName::Native => OutputPlan::Native(CodecRequest::parse(&self.codec)?),
            FormatName::Exr => OutputPlan::Other(OutputFormat::Exr(ExrOptions {
                sample_type: self.exr_type.into(),
                compression: self.exr_compression.into(),
            })),
            FormatName::Merl => OutputPlan::Other(OutputFormat::Merl),
            FormatName::Mbsdf => OutputPlan::Other(OutputFormat::Mbsdf(MbsdfOptions {
                scalar: self.mbsdf_scalar,
            })),
            FormatName::Rgl => OutputPlan::Rgl,
        })
    }
}

impl OutputPlan {
    /// The concrete format for `table` (the native codec's data-derived parameters filled in).
    pub fn for_table(&self, table: &Table) -> Result<OutputFormat> {
        Ok(match self {
            OutputPlan::Native(req) => OutputFormat::Native(req.resolve(table)?),
            OutputPlan::Other(f) => f.clone(),
            OutputPlan::Rgl => {
                return Err(Error::input(
                    "an RGL .bsdf is written from a BRDF by `brdfpack convert SOURCE -o \
                     out.bsdf`, not from a table by this command",
                ));
            }
        })
    }
}

/// Encodes and writes a table atomically (`-` for stdout); returns the bytes written.
pub fn write_table(table: &Table, path: &Path, plan: &OutputPlan) -> Result<usize> {
    let bytes = encode_table(table, &plan.for_table(table)?)?;
    atomic::write_output(path, &bytes)?;
    Ok(bytes.len())
}

/// Progress bars only when a person is watching.
/// A one-line JSON report on stdout, or on stderr when the output file itself goes to
/// stdout (`-o -`).
pub fn print_json_line(text: &str, output: &Path) -> anyhow::Result<()> {
    if output.as_os_str() == "-" {
        eprintln!("{text}");
    } else {
        outln!("{text}");
    }
    Ok(())
}

pub fn stderr_is_terminal() -> bool {
    std::io::stderr().is_terminal()
}

/// How a source is sampled: overrides for a grid whose symmetry it lacks, and clamping of
/// negative measured values.
#[derive(Args, Debug, Clone, Default)]
pub struct SamplingArgs {
    /// Clamp negative values of a measured source (RGL files hold some) to 0; by default they
    /// are passed through, as the reference evaluator does.
    #[arg(long)]
    pub clamp_negative: bool,
    /// Sample an anisotropic source on an isotropic grid anyway (at φh = 0 / φi = 0);
    /// recorded in the file.
    #[arg(long)]
    pub allow_anisotropic: bool,
    /// Sample a non-reciprocal source (e.g. RGL measurements) on halfdiff3 anyway, whose φd
    /// fold assumes reciprocity; recorded in the file.
    #[arg(long)]
    pub allow_nonreciprocal: bool,
}

impl SamplingArgs {
    /// Applies `--clamp-negative` to an opened source.
    pub fn apply(&self, source: Source) -> Source {
        source.clamp_negative(self.clamp_negative)
    }

    pub fn options(
        &self,
        progress: Option<crate::tabulate::CellProgress>,
    ) -> crate::tabulate::TabulateOptions {
        crate::tabulate::TabulateOptions {
            allow_anisotropic: self.allow_anisotropic,
            allow_nonreciprocal: self.allow_nonreciprocal,
            fill_own_holes: false,
            progress,
        }
    }
}

/// A progress bar on stderr that names the stage and counts cells; drawn only when stderr is
/// a terminal and the command is not quiet (nothing at all otherwise).
#[derive(Clone)]
pub struct Bar(Option<indicatif::ProgressBar>);

impl Bar {
    pub fn new(quiet: bool) -> Bar {
        if quiet || !stderr_is_terminal() {
            return Bar(None);
        }
        let b = indicatif::ProgressBar::new_spinner();
        b.set_style(
            indicatif::ProgressStyle::with_template("{spinner} {msg} [{elapsed}]")
                .unwrap_or_else(|_| indicatif::ProgressStyle::default_spinner()),
        );
        b.enable_steady_tick(std::time::Duration::from_millis(120));
        Bar(Some(b))
    }

    /// A stage of a command: the message shown beside the spinner.
    pub fn stage(&self, stage: &str) {
        if let Some(b) = &self.0 {
            b.set_message(stage.to_string());
        }
    }

    /// The library's tabulation callback, shown as `tabulating done/total cells`.
    pub fn cells(&self) -> Option<crate::tabulate::CellProgress> {
        let b = self.0.clone()?;
        Some(crate::tabulate::CellProgress(std::sync::Arc::new(
            move |done, total| {
                b.set_message(format!("tabulating {done}/{total} cells"));
            },
        )))
    }

    pub fn finish(&self) {
        if let Some(b) = &self.0 {
            b.finish_and_clear();
        }
    }
}

/// `--depfile FILE`: a Make/Ninja depfile naming the outputs and every file read.
#[derive(Args, Debug, Clone, Default)]
pub struct DepfileArgs {
    /// Write a Make/Ninja depfile (`deps = gcc`) listing every file this run read (sources,
    /// `@spec.json`, spectral CSVs, scenes, manifests) as dependencies of the output.
    #[arg(long, value_name = "FILE", help_heading = "Build")]
    pub depfile: Option<std::path::PathBuf>,
}

impl DepfileArgs {
    /// Writes the depfile (atomically) when one was asked for.
    pub fn write(&self, outputs: &[&Path], reads: &crate::reads::ReadSet) -> Result<()> {
        if let Some(d) = &self.depfile {
            let text = crate::reads::depfile_text(outputs.iter().copied(), reads);
            atomic::write_output(d, text.as_bytes())?;
        }
        Ok(())
    }
}

/// A scene's needs (`--scene FILE` and the flags that override it; docs/build.md).
#[derive(Args, Debug, Clone, Default)]
pub struct SceneArgs {
    /// Scene file (TOML or JSON): theta_i_max, theta_o_max, channels, isotropic, max_error.
    /// Only that domain and those channels are stored and checked (docs/build.md).
    #[arg(long, value_name = "FILE", help_heading = "Scene")]
    pub scene: Option<std::path::PathBuf>,
    /// Largest light angle from the normal the scene needs (degrees).
    #[arg(long, value_name = "DEG", help_heading = "Scene")]
    pub theta_i_max: Option<f64>,
    /// Largest view angle from the normal the scene needs (degrees).
    #[arg(long, value_name = "DEG", help_heading = "Scene")]
    pub theta_o_max: Option<f64>,
    /// Channels to keep: `rgb`, `luminance`, names separated by `/` (`R/G`), or a band of
    /// a spectral source (`400-700nm`).
    #[arg(long, value_name = "SET", help_heading = "Scene")]
    pub channels: Option<String>,
    /// The scene needs an isotropic material only (an anisotropic source may be sampled on
    /// an isotropic grid; recorded in the file).
    #[arg(long, help_heading = "Scene")]
    pub isotropic: bool,
}

impl SceneArgs {
    /// The scene: the file's fields, overridden by the flags; the file is recorded in `reads`.
    pub fn load(&self, reads: &mut crate::reads::ReadSet) -> Result<crate::plan::scene::Scene> {
        use crate::plan::scene::Scene;
        let file = match &self.scene {
            Some(p) => Scene::load(p, reads)?,
            None => Scene::default(),
        };
        let flags = Scene {
            theta_i_max: self.theta_i_max,
            theta_o_max: self.theta_o_max,
            channels: self.channels.clone(),
            isotropic: self.isotropic.then_some(true),
            max_error: None,
        };
        flags.validate("flags")?;
        Ok(file.overridden_by(&flags))
    }
}

/// `-o`, `-q`, `-v` of the commands whose output is a report or text on stdout (check,
/// inspect, eval, props, models, completions, man): the report can go to a file instead.
#[derive(Args, Debug, Clone, Default)]
pub struct ReportTarget {
    /// Write the report (stdout's text) to FILE instead of stdout, atomically, when the
    /// command finishes (also when a check fails, exit 1).
    #[arg(short, long, value_name = "FILE", help_heading = "Report")]
    pub output: Option<std::path::PathBuf>,
    /// Print nothing; the exit code says how it went (errors still print on stderr).
    #[arg(short, long, conflicts_with = "verbose", help_heading = "Report")]
    pub quiet: bool,
    /// Also print the command's time on stderr.
    #[arg(short, long, help_heading = "Report")]
    pub verbose: bool,
}
