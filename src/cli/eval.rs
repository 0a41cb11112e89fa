//! `brdfpack eval`: the value of a source at one direction pair, or at a stream of pairs
//! read from stdin (constant memory: one line in, one row out).

use crate::brdf::Brdf;
use crate::geometry::Vec3;
use crate::{Error, Result};
use clap::{Args, ValueEnum};
use std::io::{BufRead, BufWriter, Read, Write};

pub(crate) const LONG_ABOUT: &str = "\
Evaluate a model or table at direction pairs: the BRDF f_r in 1/sr (no cosine factor), in the
local frame (z = normal, x = tangent), wi towards the light and wo towards the viewer, both
pointing away from the surface. Directions below the horizon give 0.

One pair:    brdfpack eval SOURCE --wi X,Y,Z --wo X,Y,Z     (or --wi-deg/--wo-deg THETA,PHI)
A stream:    brdfpack eval SOURCE < pairs.txt                (when no pair is given)

In --wi-deg/--wo-deg, THETA is the polar angle from the normal in [0, 180] degrees (90 is the
horizon; below it, as for a vector with z <= 0, f is 0; anything else is refused, exit 2) and
PHI the azimuth, any finite value (taken modulo 360).

Stream input, one pair per line: `wix wiy wiz wox woy woz` separated by whitespace or commas
(a header line `wix,wiy,wiz,wox,woy,woz` is allowed), or a JSON object
{\"wi\":[x,y,z],\"wo\":[x,y,z]}; blank lines and lines starting with # are skipped. Without
--input the form is detected per line.

Vectors need not be unit length: they are normalized (--echo prints the normalized vectors).
A zero-length vector, a NaN or infinite component, a bad number or a wrong column count is an
error naming the line number and its text (exit 2). The stream is processed line by line, so
the rows before the bad line have already been printed when the error is reported; nothing is
printed for the bad line or after it. A single pair is checked before anything is printed.

Output, one row per pair: the channel values in Rust's shortest round-trip notation (each
parses back to the same f64).";

/// How stream lines are read.
#[derive(Clone, Copy, Debug, PartialEq, Eq, ValueEnum)]
pub enum InputFormat {
    /// Per line: JSON when it starts with `{`, comma-separated when it has a comma, else
    /// whitespace-separated.
    Auto,
    /// Six whitespace-separated numbers.
    Text,
    /// Six comma-separated numbers.
    Csv,
    /// One JSON object {"wi":[x,y,z],"wo":[x,y,z]} per line.
    Jsonl,
}

/// How rows are written.
#[derive(Clone, Copy, Debug, PartialEq, Eq, ValueEnum)]
pub enum OutputFormat {
    /// Channel values separated by spaces.
    Text,
    /// Comma-separated, after a header line of channel names.
    Csv,
    /// One JSON object {"f":[...]} per line.
    Jsonl,
}

#[derive(Args, Debug)]
pub struct EvalArgs {
    /// Model spec (`lambert:albedo=0.5`, inline JSON `{...}`, `@model.json`), table file
    /// (.bpk, .exr, MERL .binary) or RGL .bsdf file.
    pub source: String,

    /// How a table is evaluated between samples: linear, nearest, or merl (the MERL reference
    /// reader's nearest-lower-bin rule, exactly).
    #[arg(long, value_enum, default_value_t = super::values::LookupArg::Linear)]
    pub interp: super::values::LookupArg,

    /// Clamp negative values of a measured source (RGL) to 0 instead of passing them through.
    #[arg(long)]
    pub clamp_negative: bool,

    /// Incident direction (towards the light) as a vector; normalized.
    #[arg(
        long,
        value_name = "X,Y,Z",
        allow_hyphen_values = true,
        help_heading = "One pair"
    )]
    pub wi: Option<String>,
    /// Outgoing direction (towards the viewer) as a vector; normalized.
    #[arg(
        long,
        value_name = "X,Y,Z",
        allow_hyphen_values = true,
        help_heading = "One pair"
    )]
    pub wo: Option<String>,
    /// Incident direction as polar and azimuth angles in degrees.
    #[arg(
        long,
        value_name = "THETA,PHI",
        allow_hyphen_values = true,
        conflicts_with = "wi",
        help_heading = "One pair"
    )]
    pub wi_deg: Option<String>,
    /// Outgoing direction as polar and azimuth angles in degrees.
    #[arg(
        long,
        value_name = "THETA,PHI",
        allow_hyphen_values = true,
        conflicts_with = "wo",
        help_heading = "One pair"
    )]
    pub wo_deg: Option<String>,

    /// Form of the stream lines on stdin.
    #[arg(
        long,
        value_enum,
        value_name = "FORM",
        default_value_t = InputFormat::Auto,
        conflicts_with_all = ["wi", "wo", "wi_deg", "wo_deg"],
        help_heading = "Stream"
    )]
    pub input: InputFormat,

    /// Output form.
    #[arg(long, value_enum, value_name = "FORM", default_value_t = OutputFormat::Text, help_heading = "Output")]
    pub format: OutputFormat,
    /// Print the (normalized) wi and wo before the values of each row.
    #[arg(long, help_heading = "Output")]
    pub echo: bool,
    /// Print 0 for pairs beyond a table's stored θmax instead of refusing them (exit 2).
    #[arg(long)]
    pub outside_domain_zero: bool,
    /// JSON lines: one object {"f": [...]} per pair (the same as `--format jsonl`).
    #[arg(long, help_heading = "Output")]
    pub json: bool,
    #[command(flatten)]
    pub report: super::common::ReportTarget,
}

/// Longest stream line accepted, in bytes (a pair needs well under 200).
const MAX_LINE_BYTES: usize = 64 * 1024;

pub fn run(args: EvalArgs) -> anyhow::Result<i32> {
    // stdin cannot hold both the source and the stream of pairs.
    if args.source == "-" && single_pair(&args)?.is_none() {
        return Err(Error::input(
            "eval -: stdin holds the source, so the pairs cannot be streamed on it too; give \
             one pair with --wi/--wo (or --wi-deg/--wo-deg), or name the source as a file",
        )
        .into());
    }
    let brdf = crate::source::Source::open(&args.source)
        .map(|s| s.clamp_negative(args.clamp_negative))
        .and_then(|s| s.into_brdf(args.interp.into()))
        .map_err(|e| prefix_error(e, &format!("source {:?}", args.source)))?;
    let format = if args.json {
        OutputFormat::Jsonl
    } else {
        args.format
    };
    let mut writer = RowWriter::new(&*brdf, format, args.echo);
    writer.outside_domain_zero = args.outside_domain_zero;
    let pair = single_pair(&args)?;
    if let Some((wi, wo)) = pair {
        writer.check_domain(wi, wo).map_err(Error::Input)?;
    }
    let mut out = BufWriter::with_capacity(1 << 16, super::Stdout);
    let result = match pair {
        Some((wi, wo)) => writer
            .header(&mut out)
            .and_then(|_| writer.row(&mut out, wi, wo))
            .map_err(super::stdout_error),
        None => eval_stream(&writer, std::io::stdin().lock(), &mut out, args.input),
    };
    // Rows before a bad line are flushed before its error is reported (streaming).
    let flushed = out.flush().map_err(super::stdout_error);
    result?;
    flushed?;
    Ok(0)
}

fn prefix_error(e: Error, what: &str) -> Error {
    match e {
        Error::Input(m) => Error::Input(format!("{what}: {m}")),
        other => other,
    }
}

/// The pair given on the command line, or `None` for a stream.
fn single_pair(args: &EvalArgs) -> Result<Option<(Vec3, Vec3)>> {
    let wi = match (&args.wi, &args.wi_deg) {
        (Some(v), _) => Some(parse_vector_arg("--wi", v)?),
        (None, Some(v)) => Some(parse_degrees_arg("--wi-deg", v)?),
        (None, None) => None,
    };
    let wo = match (&args.wo, &args.wo_deg) {
        (Some(v), _) => Some(parse_vector_arg("--wo", v)?),
        (None, Some(v)) => Some(parse_degrees_arg("--wo-deg", v)?),
        (None, None) => None,
    };
    match (wi, wo) {
        (Some(wi), Some(wo)) => Ok(Some((wi, wo))),
        (None, None) => Ok(None),
        (Some(_), None) => Err(Error::input(
            "--wi/--wi-deg given without --wo/--wo-deg: a pair needs both directions",
        )),
        (None, Some(_)) => Err(Error::input(
            "--wo/--wo-deg given without --wi/--wi-deg: a pair needs both directions",
        )),
    }
}

/// Splits `text` at commas into exactly `n` finite numbers.
fn parse_numbers(text: &str, n: usize, expected: &str) -> std::result::Result<Vec<f64>, String> {
    let fields: Vec<&str> = text.split(',').map(str::trim).collect();
    if fields.len() != n {
        return Err(format!(
            "{} values, expected {n} comma-separated numbers {expected}",
            fields.len()
        ));
    }
    fields.iter().map(|f| parse_finite(f)).collect()
}

/// One number; NaN and infinities are refused (they would make every value NaN).
fn parse_finite(field: &str) -> std::result::Result<f64, String> {
    match field.parse::<f64>() {
        Ok(v) if v.is_finite() => Ok(v),
        Ok(_) => Err(format!("{field:?} is not a finite number")),
        Err(_) => Err(format!("{field:?} is not a number")),
    }
}

/// A unit direction from any finite non-zero vector.
fn unit(v: [f64; 3], name: &str) -> std::result::Result<Vec3, String> {
    crate::pairs::unit_direction(v, name)
}

fn parse_vector_arg(flag: &str, text: &str) -> Result<Vec3> {
    let at = |m: String| Error::input(format!("{flag} {text:?}: {m}"));
    let v = parse_numbers(text, 3, "x,y,z").map_err(at)?;
    unit([v[0], v[1], v[2]], "the vector").map_err(at)
}

fn parse_degrees_arg(flag: &str, text: &str) -> Result<Vec3> {
    let at = |m: String| Error::input(format!("{flag} {text:?}: {m}"));
    let v = parse_numbers(text, 2, "theta,phi in degrees").map_err(at)?;
    crate::pairs::direction_from_degrees(v[0], v[1]).map_err(at)
}

/// One stream line in JSON form.
#[derive(serde::Deserialize)]
#[serde(deny_unknown_fields)]
struct JsonPair {
    wi: [f64; 3],
    wo: [f64; 3],
}

/// Parses one non-blank, non-comment stream line into a pair; `Ok(None)` for a header.
fn parse_line(line: &str, form: InputFormat) -> std::result::Result<Option<(Vec3, Vec3)>, String> {
    let form = match form {
        InputFormat::Auto if line.starts_with('{') => InputFormat::Jsonl,
        InputFormat::Auto if line.contains(',') => InputFormat::Csv,
        InputFormat::Auto => InputFormat::Text,
        f => f,
    };
    let v: Vec<f64> = match form {
        InputFormat::Jsonl => {
            let p: JsonPair = serde_json::from_str(line)
                .map_err(|e| format!("expected {{\"wi\":[x,y,z],\"wo\":[x,y,z]}} ({e})"))?;
            return Ok(Some((unit(p.wi, "wi")?, unit(p.wo, "wo")?)));
        }
        InputFormat::Csv => {
            let fields: Vec<&str> = line.split(',').map(str::trim).collect();
            if fields == ["wix", "wiy", "wiz", "wox", "woy", "woz"] {
                return Ok(None);
            }
            check_count(fields.len(), "comma-separated")?;
            fields
                .iter()
                .map(|f| parse_finite(f))
                .collect::<std::result::Result<_, _>>()?
        }
        InputFormat::Text | InputFormat::Auto => {
            let fields: Vec<&str> = line.split_whitespace().collect();
            check_count(fields.len(), "whitespace-separated")?;
            fields
                .iter()
                .map(|f| parse_finite(f))
                .collect::<std::result::Result<_, _>>()?
        }
    };
    Ok(Some((
        unit([v[0], v[1], v[2]], "wi")?,
        unit([v[3], v[4], v[5]], "wo")?,
    )))
}

fn check_count(n: usize, sep: &str) -> std::result::Result<(), String> {
    if n == 6 {
        Ok(())
    } else {
        Err(format!(
            "{n} columns, expected 6 {sep} numbers wix wiy wiz wox woy woz"
        ))
    }
}

/// `brdfpack eval`'s stream processing on a whole text instead of stdin: the same line
/// parser and row writer ([`eval_stream`]), with the rows returned as a string. An error
/// (the first bad line) discards the rows before it. For the fuzzer and tests.
#[cfg(test)]
pub fn eval_stream_text(
    brdf: &dyn Brdf,
    input: &str,
    form: InputFormat,
    format: OutputFormat,
    echo: bool,
) -> Result<String> {
    let writer = RowWriter::new(brdf, format, echo);
    let mut out = Vec::new();
    eval_stream(&writer, input.as_bytes(), &mut out, form)?;
    String::from_utf8(out).map_err(|e| Error::Failure(format!("eval output is not UTF-8: {e}")))
}

/// Reads pairs from `input` line by line and writes one row per pair: constant memory.
/// A failed write is reported as a failure of `<stdout>` (the CLI's only output).
fn eval_stream<R: BufRead, W: Write>(
    writer: &RowWriter,
    mut input: R,
    out: &mut W,
    form: InputFormat,
) -> Result<()> {
    writer.header(out).map_err(super::stdout_error)?;
    let mut buf = Vec::new();
    let mut line_no = 0usize;
    loop {
        buf.clear();
        // A line is read through a cap so that a hostile stream without newlines cannot
        // make us allocate without bound.
        let n = (&mut input)
            .take(MAX_LINE_BYTES as u64 + 1)
            .read_until(b'\n', &mut buf)
            .map_err(|e| Error::io("-", e))?;
        if n == 0 {
            return Ok(());
        }
        line_no += 1;
        let bad = |msg: String, text: &[u8]| {
            Error::input(format!(
                "<stdin> line {line_no}: {msg}: {:?}",
                shorten(&String::from_utf8_lossy(text))
            ))
        };
        if buf.len() > MAX_LINE_BYTES {
            return Err(bad(format!("longer than {MAX_LINE_BYTES} bytes"), &buf));
        }
        let Ok(text) = std::str::from_utf8(&buf) else {
            return Err(bad("not UTF-8 text".into(), &buf));
        };
        let line = text.trim();
        if line.is_empty() || line.starts_with('#') {
            continue;
        }
        match parse_line(line, form) {
            Ok(Some((wi, wo))) => {
                if let Err(msg) = writer.check_domain(wi, wo) {
                    return Err(bad(msg, line.as_bytes()));
                }
                writer.row(out, wi, wo).map_err(super::stdout_error)?
            }
            Ok(None) => {}
            Err(msg) => return Err(bad(msg, line.as_bytes())),
        }
    }
}

/// At most 80 characters of an offending line, for the error message.
fn shorten(s: &str) -> String {
    const MAX: usize = 80;
    if s.chars().count() <= MAX {
        s.trim_end().to_string()
    } else {
        format!("{}...", s.chars().take(MAX).collect::<String>())
    }
}

/// Writes rows of channel values in the chosen form.
struct RowWriter<'a> {
    brdf: &'a dyn Brdf,
    format: OutputFormat,
    echo: bool,
    outside_domain_zero: bool,
}

impl<'a> RowWriter<'a> {
    fn new(brdf: &'a dyn Brdf, format: OutputFormat, echo: bool) -> Self {
        RowWriter {
            brdf,
            format,
            echo,
            outside_domain_zero: false,
        }
    }

    /// A pair above the horizon but beyond the source's stored θmax has no value: an error
    /// (docs/parameterizations.md) unless `--outside-domain-zero` asks for 0.
    fn check_domain(&self, wi: Vec3, wo: Vec3) -> std::result::Result<(), String> {
        if self.outside_domain_zero {
            return Ok(());
        }
        match crate::pairs::outside_domain(self.brdf, wi, wo) {
            None => Ok(()),
            Some(why) => Err(format!(
                "{why}; pass --outside-domain-zero to print 0 there"
            )),
        }
    }

    /// The csv header (channel names, after the echoed directions); nothing for other forms.
    fn header<W: Write>(&self, out: &mut W) -> std::io::Result<()> {
        if self.format != OutputFormat::Csv {
            return Ok(());
        }
        let mut names: Vec<&str> = Vec::new();
        if self.echo {
            names.extend(["wix", "wiy", "wiz", "wox", "woy", "woz"]);
        }
        names.extend(self.brdf.channels().names().iter().map(String::as_str));
        // Channel names come from the file: no terminal controls reach stdout.
        writeln!(out, "{}", crate::text::sanitize(&names.join(",")))
    }

    fn row<W: Write>(&self, out: &mut W, wi: Vec3, wo: Vec3) -> std::io::Result<()> {
        let mut f = [0.0f64; 8];
        let mut heap;
        let nc = self.brdf.channels().len();
        // Up to 8 channels on the stack; spectral sources with more use the heap.
        let values: &mut [f64] = if nc <= f.len() {
            &mut f[..nc]
        } else {
            heap = vec![0.0; nc];
            &mut heap
        };
        self.brdf.eval(wi, wo, values);
        // `{:?}` is Rust's shortest representation that parses back to the same f64
        // (scientific notation for very large or small magnitudes), valid JSON and CSV.
        let list = |out: &mut W, v: &[f64], sep: &str| -> std::io::Result<()> {
            for (k, x) in v.iter().enumerate() {
                if k > 0 {
                    out.write_all(sep.as_bytes())?;
                }
                write!(out, "{x:?}")?;
            }
            Ok(())
        };
        let (wi, wo) = (wi.to_array(), wo.to_array());
        match self.format {
            OutputFormat::Text | OutputFormat::Csv => {
                let sep = if self.format == OutputFormat::Csv {
                    ","
                } else {
                    " "
                };
                if self.echo {
                    list(out, &wi, sep)?;
                    out.write_all(sep.as_bytes())?;
                    list(out, &wo, sep)?;
                    out.write_all(sep.as_bytes())?;
                }
                list(out, values, sep)?;
            }
            OutputFormat::Jsonl => {
                if self.echo {
                    out.write_all(b"{\"wi\":[")?;
                    list(out, &wi, ",")?;
                    out.write_all(b"],\"wo\":[")?;
                    list(out, &wo, ",")?;
                    out.write_all(b"],\"f\":[")?;
                } else {
                    out.write_all(b"{\"f\":[")?;
                }
                list(out, values, ",")?;
                out.write_all(b"]}")?;
            }
        }
        out.write_all(b"\n")
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn run_stream(input: &str, form: InputFormat) -> (String, Option<String>) {
        let brdf = crate::source::open_brdf("lambert:albedo=0.5").unwrap();
        let w = RowWriter::new(&*brdf, OutputFormat::Text, false);
        let mut out = Vec::new();
        let r = eval_stream(&w, input.as_bytes(), &mut out, form);
        (
            String::from_utf8(out).unwrap(),
            r.err().map(|e| e.to_string()),
        )
    }

    #[test]
    fn stream_rows_before_a_bad_line_are_kept() {
        let (out, err) = run_stream(
            "0 0 1 0 0 1\n\n# c\n0 0 1 0 0 x\n0 0 1 0 0 1\n",
            InputFormat::Auto,
        );
        assert_eq!(out, format!("{:?}\n", 0.5 / std::f64::consts::PI));
        let err = err.unwrap();
        assert!(err.contains("line 4") && err.contains("\"x\""), "{err}");
    }

    #[test]
    fn overlong_line_is_refused_without_reading_it_whole() {
        let long = "1".repeat(MAX_LINE_BYTES + 10);
        let (out, err) = run_stream(&long, InputFormat::Text);
        assert!(out.is_empty());
        assert!(err.unwrap().contains("longer than"));
    }

    #[test]
    fn text_entry_point_matches_the_stream() {
        let brdf = crate::source::open_brdf("lambert:albedo=0.5").unwrap();
        let out = eval_stream_text(
            &*brdf,
            "wix,wiy,wiz,wox,woy,woz\n0,0,2,0,0,1\n",
            InputFormat::Auto,
            OutputFormat::Csv,
            true,
        )
        .unwrap();
        let v = 0.5 / std::f64::consts::PI;
        assert_eq!(
            out,
            format!("wix,wiy,wiz,wox,woy,woz,Y\n0.0,0.0,1.0,0.0,0.0,1.0,{v:?}\n")
        );
        let e = eval_stream_text(
            &*brdf,
            "1 2 3\n",
            InputFormat::Auto,
            OutputFormat::Text,
            false,
        )
        .unwrap_err();
        assert!(e.to_string().contains("line 1: 3 columns"), "{e}");
    }

    #[test]
    fn forms_agree() {
        let text = run_stream("0.1 0.2 0.9 -0.3 0.1 0.8", InputFormat::Text);
        let csv = run_stream("0.1, 0.2,0.9,-0.3,0.1,0.8", InputFormat::Csv);
        let json = run_stream(
            r#"{"wi":[0.1,0.2,0.9],"wo":[-0.3,0.1,0.8]}"#,
            InputFormat::Jsonl,
        );
        assert_eq!(text, csv);
        assert_eq!(text, json);
        assert!(text.1.is_none());
    }
}
