//! `brdfpack eval` and `brdfpack props` from the outside: argument forms, stream forms,
//! output forms, error messages and exit codes.

use assert_cmd::Command;
use predicates::prelude::*;
use std::f64::consts::FRAC_1_PI;

fn brdfpack() -> Command {
    Command::cargo_bin("brdfpack").unwrap()
}

fn stdout_of(args: &[&str], stdin: &str) -> String {
    let out = brdfpack().args(args).write_stdin(stdin).assert().success();
    String::from_utf8(out.get_output().stdout.clone()).unwrap()
}

/// Runs a command expected to fail with exit 2; returns (stdout, stderr).
fn fails_with_2(args: &[&str], stdin: &str) -> (String, String) {
    let out = brdfpack().args(args).write_stdin(stdin).assert().code(2);
    let o = out.get_output();
    (
        String::from_utf8(o.stdout.clone()).unwrap(),
        String::from_utf8(o.stderr.clone()).unwrap(),
    )
}

/// The numbers of the array `"key":[...]` in one JSON line, parsed by Rust's exact parser
/// (serde_json's default float parser may round the last bit differently).
fn json_numbers(line: &str, key: &str) -> Vec<f64> {
    let start = line.find(&format!("\"{key}\":[")).unwrap() + key.len() + 4;
    let end = start + line[start..].find(']').unwrap();
    line[start..end]
        .split(',')
        .map(|x| x.parse().unwrap())
        .collect()
}

#[test]
fn one_pair_gives_rho_over_pi_exactly() {
    let out = stdout_of(
        &[
            "eval",
            "lambert:albedo=0.5",
            "--wi",
            "0,0,1",
            "--wo",
            "0.3,0.4,0.5",
        ],
        "",
    );
    let v: f64 = out.trim().parse().unwrap();
    // Shortest round-trip formatting: the printed text parses back to the same f64.
    assert_eq!(v, 0.5 * FRAC_1_PI);
    assert_eq!(out, format!("{:?}\n", 0.5 * FRAC_1_PI));
}

#[test]
fn negative_components_and_degrees_are_accepted() {
    let a = stdout_of(
        &["eval", "lambert", "--wi", "-0.5,0,0.8", "--wo", "0,0,1"],
        "",
    );
    let b = stdout_of(
        &["eval", "lambert", "--wi-deg", "30,180", "--wo-deg", "0,0"],
        "",
    );
    assert_eq!(a, b);
    // Below the horizon the one-sided source is 0.
    let c = stdout_of(
        &["eval", "lambert", "--wi-deg", "120,0", "--wo-deg", "0,0"],
        "",
    );
    assert_eq!(c, "0.0\n");
}

#[test]
fn output_forms_for_rgb() {
    let args = |f: &'static str| {
        vec![
            "eval",
            "lambert:albedo=0.8/0.5/0.2",
            "--wi",
            "0,0,2",
            "--wo",
            "1,0,1",
            "--format",
            f,
        ]
    };
    let want: Vec<f64> = [0.8, 0.5, 0.2].iter().map(|a| a * FRAC_1_PI).collect();
    let text = stdout_of(&args("text"), "");
    let got: Vec<f64> = text
        .split_whitespace()
        .map(|x| x.parse().unwrap())
        .collect();
    assert_eq!(got, want);

    let csv = stdout_of(&args("csv"), "");
    let mut lines = csv.lines();
    assert_eq!(lines.next(), Some("R,G,B"));
    let got: Vec<f64> = lines
        .next()
        .unwrap()
        .split(',')
        .map(|x| x.parse().unwrap())
        .collect();
    assert_eq!(got, want);

    let jsonl = stdout_of(&args("jsonl"), "");
    let v: serde_json::Value = serde_json::from_str(jsonl.trim()).unwrap();
    assert_eq!(v["f"].as_array().unwrap().len(), 3);
    assert_eq!(json_numbers(&jsonl, "f"), want);

    // --echo prints the normalized directions.
    let mut a = args("jsonl");
    a.push("--echo");
    let line = stdout_of(&a, "");
    assert!(serde_json::from_str::<serde_json::Value>(line.trim()).is_ok());
    assert_eq!(json_numbers(&line, "wi"), [0.0, 0.0, 1.0]);
    // Normalization multiplies by 1/|v| (one rounding more than the constant 1/√2).
    let h = 1.0 / 2f64.sqrt();
    assert_eq!(json_numbers(&line, "wo"), [h, 0.0, h]);
}

#[test]
fn stdin_forms_auto_detected_and_explicit() {
    let f = format!("{:?}", 0.5 * FRAC_1_PI);
    let input =
        "# a comment\n\n0 0 1 0 0 1\n0,0,1, 0.6,0,0.8\n{\"wi\":[0,0,1],\"wo\":[0,1,1]}\n  \n";
    let out = stdout_of(&["eval", "lambert"], input);
    assert_eq!(out, format!("{f}\n{f}\n{f}\n"));

    let out = stdout_of(&["eval", "lambert", "--input", "text"], "0 0 1\t0 0 1\r\n");
    assert_eq!(out, format!("{f}\n"));
    let out = stdout_of(
        &["eval", "lambert", "--input", "csv"],
        "wix,wiy,wiz,wox,woy,woz\n0,0,1,0,0,1\n",
    );
    assert_eq!(out, format!("{f}\n"));
    let out = stdout_of(
        &["eval", "lambert", "--input", "jsonl"],
        "{\"wi\":[0,0,1],\"wo\":[0,0,1]}\n",
    );
    assert_eq!(out, format!("{f}\n"));
    // Commas are not whitespace in explicit text mode.
    let (_, err) = fails_with_2(&["eval", "lambert", "--input", "text"], "0,0,1,0,0,1\n");
    assert!(err.contains("line 1"), "{err}");
}

#[test]
fn stream_of_100k_rows() {
    let mut input = String::with_capacity(100_000 * 40);
    for k in 0..100_000 {
        // Half the rows put wo below the horizon: those give 0.
        let z = if k % 2 == 0 { 0.5 } else { -0.5 };
        input.push_str(&format!("0.1 0.2 0.9 0.3 {} {z}\n", (k % 7) as f64 * 0.1));
    }
    let out = stdout_of(&["eval", "lambert:albedo=0.5", "--format", "csv"], &input);
    let mut lines = out.lines();
    assert_eq!(lines.next(), Some("Y"));
    let values: Vec<f64> = lines.map(|l| l.parse().unwrap()).collect();
    assert_eq!(values.len(), 100_000);
    for (k, v) in values.iter().enumerate() {
        let want = if k % 2 == 0 { 0.5 * FRAC_1_PI } else { 0.0 };
        assert_eq!(*v, want, "row {k}");
    }
}

#[test]
fn stream_error_names_the_line_and_keeps_earlier_rows() {
    let (out, err) = fails_with_2(
        &["eval", "lambert"],
        "0 0 1 0 0 1\n# note\n0 0 1 0 0 1\n0 0 1 0 zz 1\n0 0 1 0 0 1\n",
    );
    assert_eq!(
        out.lines().count(),
        2,
        "rows before the bad line are printed: {out}"
    );
    assert!(err.starts_with("brdfpack: "), "{err}");
    assert!(err.contains("line 4") && err.contains("\"zz\""), "{err}");
    assert!(err.contains("0 0 1 0 zz 1"), "{err}");
}

/// Bad stream lines: (input, text the message must contain).
const BAD_LINES: &[(&str, &str)] = &[
    ("0 0 1 0 0\n", "5 columns"),
    ("0 0 1 0 0 1 1\n", "7 columns"),
    ("0,0,1,0,,1\n", "\"\" is not a number"),
    ("0 0 1 NaN 0 1\n", "\"NaN\" is not a finite number"),
    ("0 0 1 0 0 inf\n", "\"inf\" is not a finite number"),
    ("0 0 1 0 0 1e999\n", "not a finite number"),
    ("0 0 0 0 0 1\n", "wi has zero length"),
    ("0 0 1 0 0 0\n", "wo has zero length"),
    ("{\"wi\":[0,0,1],\"wo\":[0,1]}\n", "expected {\"wi\""),
    ("{\"wi\":[0,0,1],\"wo\":[0,0,1],\"x\":1}\n", "unknown field"),
    ("{\"wi\":[0,0,1]\n", "expected {\"wi\""),
    ("one two three four five six\n", "\"one\" is not a number"),
];

#[test]
fn bad_stream_lines_exit_2_with_line_number() {
    for (input, want) in BAD_LINES {
        // A good line first: the error must name line 3 (after the comment).
        let stdin = format!("0 0 1 0 0 1\n# c\n{input}");
        let (out, err) = fails_with_2(&["eval", "lambert"], &stdin);
        assert_eq!(out.lines().count(), 1, "{input:?}: {out}");
        assert!(err.contains("<stdin> line 3"), "{input:?}: {err}");
        assert!(err.contains(want), "{input:?}: {err}");
    }
}

/// Bad single-pair arguments: (args after `eval`, text the message must contain).
const BAD_ARGS: &[(&[&str], &str)] = &[
    (
        &["no-such-model", "--wi", "0,0,1", "--wo", "0,0,1"],
        "no-such-model",
    ),
    (
        &["lambert:albedo=x", "--wi", "0,0,1", "--wo", "0,0,1"],
        "albedo",
    ),
    (
        &["lambert", "--wi", "0,0", "--wo", "0,0,1"],
        "2 values, expected 3",
    ),
    (
        &["lambert", "--wi", "0,0,1", "--wo", "a,0,1"],
        "\"a\" is not a number",
    ),
    (
        &["lambert", "--wi", "0,0,NaN", "--wo", "0,0,1"],
        "not a finite number",
    ),
    (
        &["lambert", "--wi", "0,0,0", "--wo", "0,0,1"],
        "zero length",
    ),
    (
        &["lambert", "--wi-deg", "10", "--wo", "0,0,1"],
        "expected 2",
    ),
    (&["lambert", "--wi", "0,0,1"], "needs both"),
    (&["lambert", "--wo-deg", "0,0"], "needs both"),
    (
        &[
            "lambert", "--wi", "0,0,1", "--wi-deg", "0,0", "--wo", "0,0,1",
        ],
        "cannot be used",
    ),
    (
        &[
            "lambert", "--wi", "0,0,1", "--wo", "0,0,1", "--input", "csv",
        ],
        "cannot be used",
    ),
    (&["lambert", "--format", "xml"], "invalid value"),
];

#[test]
fn bad_single_pairs_exit_2_and_print_nothing() {
    for (args, want) in BAD_ARGS {
        let mut a = vec!["eval"];
        a.extend_from_slice(args);
        let (out, err) = fails_with_2(&a, "");
        assert!(out.is_empty(), "{args:?}: stdout {out:?}");
        assert!(err.contains(want), "{args:?}: {err}");
    }
}

#[test]
fn closed_stdout_is_not_an_error() {
    // `| head -1`: the shell closes our stdout early. Emulated by a reader that stops.
    use std::io::{Read, Write};
    use std::process::{Command as Proc, Stdio};
    let mut child = Proc::new(assert_cmd::cargo::cargo_bin("brdfpack"))
        .args(["eval", "lambert"])
        .stdin(Stdio::piped())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    let mut stdin = child.stdin.take().unwrap();
    // The feeder runs in its own thread: the child only writes once it has read.
    let writer = std::thread::spawn(move || {
        let line = b"0 0 1 0 0 1\n".repeat(1000);
        for _ in 0..2000 {
            if stdin.write_all(&line).is_err() {
                break;
            }
        }
    });
    let mut stdout = child.stdout.take().unwrap();
    let mut first = [0u8; 8];
    stdout.read_exact(&mut first).unwrap();
    assert_eq!(&first, b"0.159154");
    drop(stdout);
    let status = child.wait().unwrap();
    writer.join().unwrap();
    let mut err = String::new();
    child
        .stderr
        .take()
        .unwrap()
        .read_to_string(&mut err)
        .unwrap();
    assert_eq!(status.code(), Some(0), "stderr: {err}");
    assert!(err.is_empty(), "{err}");
}

#[test]
fn help_documents_streaming_errors() {
    brdfpack()
        .args(["eval", "--help"])
        .assert()
        .success()
        .stdout(predicate::str::contains("already been printed"))
        .stdout(predicate::str::contains("normalized"));
}

#[test]
fn props_human_table() {
    let out = stdout_of(
        &["props", "lambert:albedo=0.8/0.5/0.2", "--samples", "2000"],
        "",
    );
    assert!(out.contains("reciprocity"), "{out}");
    assert!(out.contains("isotropy"), "{out}");
    assert!(out.contains("verdict      ok"), "{out}");
    // 16 albedo rows, each with the three channel values.
    let rows: Vec<&str> = out
        .lines()
        .filter(|l| l.trim_start().starts_with(|c: char| c.is_ascii_digit()))
        .collect();
    assert_eq!(rows.len(), 16, "{out}");
    for r in rows {
        let cols: Vec<&str> = r.split_whitespace().collect();
        assert_eq!(&cols[2..5], ["0.800000", "0.500000", "0.200000"], "{r}");
    }
}

#[test]
fn props_json_lambert_albedo_is_rho() {
    let out = stdout_of(
        &[
            "props",
            "lambert:albedo=0.8/0.5/0.2",
            "--json",
            "--seed",
            "7",
            "--samples",
            "3000",
        ],
        "",
    );
    let v: serde_json::Value = serde_json::from_str(&out).unwrap();
    assert_eq!(v["seed"], 7);
    assert_eq!(v["samples"], 3000);
    assert_eq!(v["positivity"]["negative"], 0);
    assert_eq!(v["positivity"]["nonfinite"], 0);
    assert_eq!(v["reciprocity"]["holds"], true);
    assert_eq!(v["isotropy"]["holds"], true);
    assert_eq!(v["energy"]["conserves"], true);
    assert_eq!(v["failures"].as_array().unwrap().len(), 0);
    let rows = v["albedo"].as_array().unwrap();
    assert_eq!(rows.len(), 16);
    let mut theta = Vec::new();
    for row in rows {
        theta.push(row["theta_i_deg"].as_f64().unwrap());
        let a: Vec<f64> = row["albedo"]
            .as_array()
            .unwrap()
            .iter()
            .map(|x| x.as_f64().unwrap())
            .collect();
        for (got, want) in a.iter().zip([0.8, 0.5, 0.2]) {
            assert!((got - want).abs() < 1e-6, "{row}");
        }
    }
    assert_eq!(theta.first(), Some(&0.0));
    assert_eq!(theta.last(), Some(&85.0));
}

#[test]
fn props_exit_1_when_energy_is_not_conserved() {
    let out = brdfpack()
        // A sum of two valid lobes whose albedos add up to 1.5.
        .args([
            "props",
            "lambert:albedo=1 + lambert:albedo=0.5",
            "--samples",
            "100",
        ])
        .assert()
        .code(1);
    let text = String::from_utf8(out.get_output().stdout.clone()).unwrap();
    assert!(
        text.contains("FAIL") && text.contains("albedo 1.5"),
        "{text}"
    );
}

#[test]
fn props_rejects_bad_arguments() {
    let (out, err) = fails_with_2(&["props", "lambert", "--samples", "0"], "");
    assert!(out.is_empty());
    assert!(err.contains("--samples"), "{err}");
    let (_, err) = fails_with_2(&["props", "nope"], "");
    assert!(err.contains("\"nope\""), "{err}");
}
