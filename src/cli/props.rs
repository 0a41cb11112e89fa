//! `brdfpack props`: positivity, reciprocity, isotropy and directional albedo of a source.

use crate::props::{EnergyVerdict, PropsOptions, PropsReport, Symmetry, props};
use clap::Args;
use std::io::Write;

pub(crate) const LONG_ABOUT: &str = "\
Report the physical properties of a model or table:
  positivity   smallest value, counts of negative and non-finite values over the random
               pairs and the hard cases of spec/hard-cases.md (horizon, normal, mirror, ...)
  reciprocity  max |f(wi,wo) - f(wo,wi)| / max(|f|, floor) over the random pairs
  isotropy     the same under a common random rotation of both directions about z
  albedo       a(θi) = ∫ f cos θo dωo at θi = 0, 5.67, ..., 85° (φi = 0, and 90° when the
               source is anisotropic), by a half-vector quadrature accurate to 1e-4 with a
               per-angle error estimate (docs/props.md)
  energy       max albedo <= 1 + max(error estimate, 1e-4); \"unresolved\" when an error
               estimate above 0.1 leaves the albedo possibly above 1
The random pairs are uniform in solid angle over the upper hemisphere from --seed.
In --json, a non-finite number is the string \"inf\", \"-inf\" or \"nan\" (never null).

Exit status: 0 when every property holds, 1 when one fails (negative values, a reciprocity or
isotropy the source promises but does not have, albedo above 1 or unresolved), 2 on bad input,
including a source that gives non-finite values or a non-finite albedo (the report is printed
first).";

#[derive(Args, Debug)]
pub struct PropsArgs {
    /// Model spec (`lambert:albedo=0.5`, inline JSON `{...}`, `@model.json`) or table file.
    pub source: String,
    /// Seed of the random direction pairs.
    #[arg(long, value_name = "N", default_value_t = 1)]
    pub seed: u64,
    /// Random direction pairs per test [1 .. 100000000].
    #[arg(long, value_name = "N", default_value_t = 65_536,
          value_parser = clap::value_parser!(u64).range(1..=100_000_000))]
    pub samples: u64,
    /// Print the report as one JSON object instead of a table.
    #[arg(long)]
    pub json: bool,
    #[command(flatten)]
    pub report: super::common::ReportTarget,
}

pub fn run(args: PropsArgs) -> anyhow::Result<i32> {
    let brdf = crate::source::open_brdf(&args.source).map_err(|e| match e {
        crate::Error::Input(m) => crate::Error::Input(format!("source {:?}: {m}", args.source)),
        other => other,
    })?;
    let options = PropsOptions {
        seed: args.seed,
        samples: args.samples as usize,
    };
    let report = props(&*brdf, &options);
    // Formatted in memory (a few KB), so that a failing stdout is one error naming it.
    let mut text = Vec::new();
    if args.json {
        serde_json::to_writer_pretty(&mut text, &report)?;
        writeln!(text)?;
    } else {
        write_table(&mut text, &report)?;
    }
    let mut out = super::Stdout;
    out.write_all(&text)
        .and_then(|_| out.flush())
        .map_err(super::stdout_error)?;
    // Non-finite values come from the source's data or parameters: the input is at fault.
    let nonfinite = report.positivity.nonfinite;
    if nonfinite > 0 || report.energy.verdict == EnergyVerdict::NonFinite {
        return Err(crate::Error::Input(format!(
            "source {:?}: gives {nonfinite} non-finite value(s) over {} pairs; albedo {} at \
             θi {:.2}°",
            args.source,
            report.positivity.pairs,
            number(report.energy.max_albedo),
            report.energy.at_theta_i_deg
        ))
        .into());
    }
    Ok(if report.failures.is_empty() { 0 } else { 1 })
}

/// A value for the text report: fixed notation in the ordinary range, short scientific
/// notation beyond it (a value of 1e30 would otherwise print 31 digits), `inf`/`NaN` as is.
fn number(x: f64) -> String {
    if x.is_finite() && (x == 0.0 || (1e-4..1e4).contains(&x.abs())) {
        format!("{x:.6}")
    } else if x.is_finite() {
        format!("{x:.4e}")
    } else {
        format!("{x}")
    }
}

fn yes_no(b: bool) -> &'static str {
    if b { "yes" } else { "no" }
}

fn pair(p: &crate::props::DirPair) -> String {
    let v = |a: [f64; 3]| format!("({:.4}, {:.4}, {:.4})", a[0], a[1], a[2]);
    format!("wi {} wo {}", v(p.wi), v(p.wo))
}

fn symmetry_line(s: &Symmetry) -> String {
    let rot = s
        .worst_rotation_deg
        .map(|r| format!(", rotated {r:.1}°"))
        .unwrap_or_default();
    format!(
        "max rel. diff {:.3e} at {}{rot}; promised {}, holds {}",
        s.max_rel_diff,
        pair(&s.worst),
        yes_no(s.promised),
        yes_no(s.holds)
    )
}

fn write_table<W: Write>(out: &mut W, r: &PropsReport) -> std::io::Result<()> {
    let p = &r.positivity;
    let e = &r.energy;
    writeln!(out, "source       {}", r.source)?;
    writeln!(out, "channels     {}", r.channels.join(" "))?;
    writeln!(
        out,
        "samples      {} random pairs (seed {}), {} pairs with hard cases",
        r.samples, r.seed, p.pairs
    )?;
    writeln!(
        out,
        "positivity   min {:.6e} at {}; negative {}, non-finite {}",
        p.min_value,
        pair(&p.min_at),
        p.negative,
        p.nonfinite
    )?;
    writeln!(out, "reciprocity  {}", symmetry_line(&r.reciprocity))?;
    writeln!(out, "isotropy     {}", symmetry_line(&r.isotropy))?;
    let label = match e.verdict {
        EnergyVerdict::Conserves => "max albedo",
        EnergyVerdict::Exceeds => "max albedo",
        EnergyVerdict::Unresolved => "albedo",
        EnergyVerdict::NonFinite => "albedo",
    };
    writeln!(
        out,
        "energy       {label} {} ± {:.1e} at θi {:.2}° φi {:.0}° ({}): {}",
        number(e.max_albedo),
        e.tolerance,
        e.at_theta_i_deg,
        e.at_phi_i_deg,
        r.channels.get(e.channel).map(String::as_str).unwrap_or("?"),
        match e.verdict {
            EnergyVerdict::Conserves => "conserves".to_string(),
            EnergyVerdict::Exceeds => "EXCEEDS 1".to_string(),
            EnergyVerdict::Unresolved => format!(
                "UNRESOLVED (error estimate above {}: conservation not shown)",
                crate::props::ALBEDO_UNRESOLVED
            ),
            EnergyVerdict::NonFinite => "NOT FINITE".to_string(),
        }
    )?;
    if let Some(n) = r.htsg_terms {
        writeln!(
            out,
            "htsg terms   {n} (most series terms any channel sums, over a fixed direction set)"
        )?;
    }
    writeln!(out)?;
    // Albedo table: one column per channel, then the largest error estimate of the row.
    let mut header = format!("{:>8} {:>6}", "θi(°)", "φi(°)");
    for c in &r.channels {
        header.push_str(&format!(" {c:>10}"));
    }
    header.push_str(&format!(" {:>9} {:>8}", "error", "evals"));
    writeln!(out, "{header}")?;
    for row in &r.albedo {
        let mut line = format!("{:>8.2} {:>6.0}", row.theta_i_deg, row.phi_i_deg);
        for &a in &row.albedo {
            line.push_str(&format!(" {:>10}", number(a)));
        }
        let err = row.error.iter().copied().fold(0.0, f64::max);
        line.push_str(&format!(" {err:>9.1e} {:>8}", row.evaluations));
        writeln!(out, "{line}")?;
    }
    if let Some(rows) = &r.specular {
        // The delta part, not in the albedo above: the coefficient per channel.
        writeln!(out)?;
        writeln!(out, "specular delta (not in the albedo above): coefficient")?;
        for row in rows {
            let mut line = format!("{:>8.2} {:>6.0}", row.theta_i_deg, row.phi_i_deg);
            for a in &row.coefficient {
                line.push_str(&format!(" {a:>10.3e}"));
            }
            writeln!(out, "{line}")?;
        }
    }
    writeln!(out)?;
    if r.failures.is_empty() {
        writeln!(out, "verdict      ok")?;
    } else {
        writeln!(out, "verdict      FAIL: {}", r.failures.join("; "))?;
    }
    Ok(())
}
