//! `brdfpack convert` and `brdfpack inspect` end to end: round trips between the formats,
//! stdout output, re-gridding notes, and errors with exit code 2.

use assert_cmd::Command;
use predicates::prelude::*;
use std::path::Path;

fn brdfpack() -> Command {
    Command::cargo_bin("brdfpack").unwrap()
}

const MODEL: &str = "lambert:albedo=0.8/0.5/0.2";
/// A small MERL-shaped grid (halfdiff3, sqrt/linear/linear, lower edges): fast tests.
const SMALL_MERL: &str = "halfdiff3:10x9x20,warp=sqrt/linear/linear,at=edge";

fn convert(args: &[&str], input: &str, out: &Path) {
    brdfpack()
        .arg("convert")
        .arg(input)
        .arg("-o")
        .arg(out)
        .args(args)
        .assert()
        .success()
        .stdout("");
}

fn inspect_json(file: &Path) -> serde_json::Value {
    let o = brdfpack()
        .arg("inspect")
        .arg(file)
        .arg("--json")
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    serde_json::from_slice(&o.stdout).unwrap()
}

#[test]
fn merl_survives_exr_and_native_round_trips_through_the_cli() {
    let d = tempfile::tempdir().unwrap();
    let p = |n: &str| d.path().join(n);
    convert(&["--grid", SMALL_MERL], MODEL, &p("a.binary"));
    let merl = std::fs::read(p("a.binary")).unwrap();
    // 12-byte header + 3 × 1800 f64.
    assert_eq!(merl.len(), 12 + 3 * 1800 * 8);
    assert_eq!(&merl[..12], [10i32, 9, 20].map(i32::to_le_bytes).concat());
    convert(&[], p("a.binary").to_str().unwrap(), &p("b.exr"));
    convert(&[], p("b.exr").to_str().unwrap(), &p("c.bpk"));
    convert(&[], p("c.bpk").to_str().unwrap(), &p("d.binary"));
    assert!(std::fs::read(p("d.binary")).unwrap() == merl);

    let j = inspect_json(&p("b.exr"));
    assert_eq!(j["format"], "exr");
    assert_eq!(j["cells"], 1800);
    assert_eq!(j["exact_f64"], true);
    assert_eq!(j["channels"], serde_json::json!(["R", "G", "B"]));
    // Lambert: f = albedo/π in every valid cell.
    let r = &j["stats"][0];
    let want = (0.8f64 / std::f64::consts::PI) as f32 as f64;
    assert_eq!(r["min"].as_f64().unwrap(), want);
    assert_eq!(r["max"].as_f64().unwrap(), want);
    assert_eq!(j["negative_values"], 0);
    let inv = j["invalid_cells"].as_u64().unwrap();
    assert!(inv > 0 && inv < 1800, "{inv}");
}

#[test]
fn output_to_stdout_matches_the_file() {
    let d = tempfile::tempdir().unwrap();
    let file = d.path().join("m.exr");
    convert(&["--grid", "halfdiff3:4x4x8"], MODEL, &file);
    let o = brdfpack()
        .args([
            "convert",
            MODEL,
            "--grid",
            "halfdiff3:4x4x8",
            "-o",
            "-",
            "--format",
            "exr",
        ])
        .output()
        .unwrap();
    assert!(o.status.success());
    assert!(o.stdout == std::fs::read(&file).unwrap());
    // The same bytes can be read back from stdin.
    brdfpack()
        .args(["inspect", "-"])
        .write_stdin(o.stdout)
        .assert()
        .success()
        .stdout(predicate::str::contains("format: exr"));
    // Without --format, stdout gets the native format.
    let native = brdfpack()
        .args(["convert", MODEL, "-o", "-"])
        .output()
        .unwrap();
    assert!(native.status.success());
    assert!(native.stdout.starts_with(b"\x89BPK"));
    // A name with no known extension needs --format.
    brdfpack()
        .args(["convert", MODEL, "-o"])
        .arg(d.path().join("out.dat"))
        .assert()
        .code(2)
        .stderr(predicate::str::contains("--format"));
}

#[test]
fn regridding_is_recorded_and_reported_with_verbose() {
    let d = tempfile::tempdir().unwrap();
    let src = d.path().join("s.bpk");
    convert(&["--grid", "halfdiff3:8x8x16"], MODEL, &src);
    let out = d.path().join("m.binary");
    brdfpack()
        .arg("convert")
        .arg(&src)
        .arg("-o")
        .arg(&out)
        .args(["--grid", SMALL_MERL, "--interp", "nearest", "-v"])
        .assert()
        .success()
        .stderr(
            predicate::str::contains("re-gridded from halfdiff3 8x8x16")
                .and(predicate::str::contains("by nearest-sample interpolation")),
        );
    // MERL holds no provenance; the same conversion to EXR keeps the note.
    let exr = d.path().join("m.exr");
    convert(&["--grid", SMALL_MERL], src.to_str().unwrap(), &exr);
    let j = inspect_json(&exr);
    let notes = j["notes"].to_string();
    assert!(notes.contains("re-gridded"), "{notes}");
    assert!(j["source"].as_str().unwrap().contains("lambert"), "{j}");
    // Without -v, convert is quiet.
    brdfpack()
        .arg("convert")
        .arg(&src)
        .arg("-o")
        .arg(d.path().join("q.exr"))
        .args(["--grid", SMALL_MERL])
        .assert()
        .success()
        .stderr("");
}

#[test]
fn conversion_errors_exit_2_with_a_message() {
    let d = tempfile::tempdir().unwrap();
    // MERL output on a grid it cannot hold.
    brdfpack()
        .args(["convert", MODEL, "--grid", "spherical4:4", "-o"])
        .arg(d.path().join("x.binary"))
        .assert()
        .code(2)
        .stderr(predicate::str::contains(
            "MERL .binary needs a halfdiff3 grid",
        ));
    // MERL needs three channels.
    brdfpack()
        .args(["convert", "lambert:albedo=0.5", "--grid", SMALL_MERL, "-o"])
        .arg(d.path().join("x.binary"))
        .assert()
        .code(2)
        .stderr(predicate::str::contains("exactly 3 channels"));
    // A missing input file.
    brdfpack()
        .args(["convert", "missing.bpk", "-o"])
        .arg(d.path().join("x.exr"))
        .assert()
        .code(2)
        .stderr(predicate::str::contains("missing.bpk"));
    // An unknown output extension.
    brdfpack()
        .args(["convert", MODEL, "-o"])
        .arg(d.path().join("x.png"))
        .assert()
        .code(2)
        .stderr(predicate::str::contains("cannot tell the output format"));
    // Garbage in: inspect and convert both refuse it.
    let junk = d.path().join("junk.dat");
    std::fs::write(&junk, b"certainly not a table").unwrap();
    for cmd in [
        vec!["inspect", junk.to_str().unwrap()],
        vec![
            "convert",
            junk.to_str().unwrap(),
            "-o",
            "/dev/null",
            "--format",
            "exr",
        ],
    ] {
        brdfpack()
            .args(&cmd)
            .assert()
            .code(2)
            .stderr(predicate::str::contains("unknown format"));
    }
    // A truncated MERL file is named as such.
    let m = d.path().join("m.binary");
    convert(&["--grid", SMALL_MERL], MODEL, &m);
    let bytes = std::fs::read(&m).unwrap();
    std::fs::write(&m, &bytes[..bytes.len() - 3]).unwrap();
    brdfpack()
        .arg("inspect")
        .arg(&m)
        .assert()
        .code(2)
        .stderr(predicate::str::contains("truncated"));
    // Nothing was left behind by the failed writes.
    assert!(!d.path().join("x.binary").exists());
}

/// A non-reciprocal measured file (an RGL `.bsdf`) without `--grid`: `tabulate`, `convert`
/// to EXR and `compress` store it on the planner's grid for such sources (spherical3, no
/// reciprocity fold) instead of refusing MERL's φd fold (exit 2 until a grid was named);
/// an isotropic reciprocal model keeps MERL's grid.
#[test]
fn a_measured_file_without_a_grid_goes_on_a_grid_that_keeps_it() {
    let dir = tempfile::tempdir().unwrap();
    let rgl = Path::new(env!("CARGO_MANIFEST_DIR")).join("fixtures/rgl/tiny.bsdf");
    let rgl = rgl.to_str().unwrap();
    let kind = |p: &Path| {
        inspect_json(p)["grid_desc"]["kind"]
            .as_str()
            .unwrap()
            .to_string()
    };
    let t = dir.path().join("t.bpk");
    brdfpack()
        .args(["tabulate", rgl, "-o"])
        .arg(&t)
        .assert()
        .success();
    assert_eq!(kind(&t), "spherical3");
    let e = dir.path().join("t.exr");
    convert(&[], rgl, &e);
    assert_eq!(kind(&e), "spherical3");
    let c = dir.path().join("c.bpk");
    brdfpack()
        .args(["compress", rgl, "--codec", "lossless", "-o"])
        .arg(&c)
        .assert()
        .success();
    assert_eq!(kind(&c), "spherical3");
    let m = dir.path().join("m.bpk");
    brdfpack()
        .args(["tabulate", MODEL, "-o"])
        .arg(&m)
        .assert()
        .success();
    assert_eq!(
        inspect_json(&m)["grid"].as_str().unwrap(),
        "halfdiff3 90x90x180 (warp sqrt/linear/linear; at edge/edge/edge)"
    );
}
