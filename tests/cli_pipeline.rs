//! End-to-end tests of the pipeline commands: tabulate → file → check, pack, stdin/stdout.

mod common;

use assert_cmd::Command;
use predicates::prelude::*;

fn brdfpack() -> Command {
    Command::cargo_bin("brdfpack").unwrap()
}

#[test]
fn tabulate_then_check_passes_a_bound_and_fails_a_tight_one() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("t.bpk");
    brdfpack()
        .args([
            "tabulate",
            "lambert:albedo=0.8/0.5/0.2",
            "--grid",
            "halfdiff3:16x16x32",
            "-o",
        ])
        .arg(&out)
        .assert()
        .success()
        .stdout("");
    // Lambert is constant: any table of it is exact up to f32 rounding.
    brdfpack()
        .arg("check")
        .arg(&out)
        .args([
            "--against",
            "lambert:albedo=0.8/0.5/0.2",
            "--samples",
            "4096",
            "--max-log-rmse",
            "1e-6",
        ])
        .assert()
        .success()
        .stdout(predicate::str::contains("verdict: pass"));
    // Against a different albedo the error is known: |0.8 − 0.7|/π on one channel of three.
    let o = brdfpack()
        .arg("check")
        .arg(&out)
        .args([
            "--against",
            "lambert:albedo=0.7/0.5/0.2",
            "--samples",
            "4096",
            "--json",
            "--max-rmse",
            "0.01",
        ])
        .assert()
        .code(1)
        .get_output()
        .stdout
        .clone();
    let v: serde_json::Value = serde_json::from_slice(&o).unwrap();
    let rmse = v["uniform"]["per_channel"][0]["rmse"].as_f64().unwrap();
    assert!((rmse - 0.1 / std::f64::consts::PI).abs() < 1e-7, "{rmse}");
    assert_eq!(v["bounds_exceeded"].as_array().unwrap().len(), 1);
}

#[test]
fn tables_stream_through_stdin_and_stdout() {
    let a = brdfpack()
        .args(["tabulate", "lambert", "--grid", "halfdiff4:6", "-o", "-"])
        .assert()
        .success()
        .get_output()
        .stdout
        .clone();
    assert!(a.starts_with(b"\x89BPK"));
    brdfpack()
        .args([
            "check",
            "-",
            "--against",
            "lambert",
            "--samples",
            "1000",
            "--max-rmse",
            "1e-6",
        ])
        .write_stdin(a)
        .assert()
        .success();
}

#[test]
fn compress_to_stdout_writes_only_the_file() {
    // The report goes to stderr with `-o -`: the stdout bytes are exactly the file `-o FILE`
    // writes (they used to be followed by the report text, which broke pipes into `inspect`).
    let dir = tempfile::tempdir().unwrap();
    let file = dir.path().join("c.bpk");
    let args = |o: &str| {
        vec![
            "compress".to_string(),
            "lambert".into(),
            "--grid".into(),
            "halfdiff3:6".into(),
            "--codec".into(),
            "dct:step=0.01".into(),
            "--samples".into(),
            "500".into(),
            "-o".into(),
            o.to_string(),
        ]
    };
    let piped = brdfpack()
        .args(args("-"))
        .assert()
        .success()
        .get_output()
        .clone();
    brdfpack()
        .args(args(file.to_str().unwrap()))
        .assert()
        .success();
    assert_eq!(piped.stdout, std::fs::read(&file).unwrap());
    // Quiet by default (issue #22); -v puts the report on stderr, never after the bytes.
    assert!(
        piped.stderr.is_empty(),
        "{}",
        String::from_utf8_lossy(&piped.stderr)
    );
    let verbose = brdfpack()
        .args(args("-"))
        .arg("-v")
        .assert()
        .success()
        .get_output()
        .clone();
    assert_eq!(verbose.stdout, piped.stdout);
    assert!(String::from_utf8_lossy(&verbose.stderr).contains("codec: "));
    brdfpack()
        .args(["inspect", "-"])
        .write_stdin(piped.stdout)
        .assert()
        .success();
}

#[test]
fn pack_default_material_reports_every_metric() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("p.bpk");
    // The default budget (log_rmse ≤ 0.002) is below this coarse grid's own error, so the
    // test names a budget the grid can meet; the default budget's refusal is in codec_cli.
    let pack = [
        "pack",
        "--grid",
        "halfdiff3:32x32x64",
        "--samples",
        "4096",
        "--max-error",
        "log_rmse=0.02,p99_rel_core=0.1",
    ];
    let o = brdfpack()
        .args(pack)
        .args(["--json", "-o"])
        .arg(&out)
        .assert()
        .success()
        .get_output()
        .stdout
        .clone();
    let v: serde_json::Value = serde_json::from_slice(&o).unwrap();
    assert_eq!(
        v["bytes"].as_u64().unwrap(),
        std::fs::metadata(&out).unwrap().len()
    );
    for m in [
        "rmse",
        "rel_rmse",
        "max_abs",
        "max_rel",
        "log_rmse",
        "rel_rmse_core",
        "p99_rel_core",
    ] {
        let x = v["check"]["uniform"]["combined"][m].as_f64().unwrap();
        assert!(x.is_finite() && x >= 0.0, "{m} = {x}");
    }
    assert_eq!(v["check"]["uniform"]["combined"]["nonfinite"], 0);
    // The budget is the written file against the model: met on the check set, and by the
    // 3σ upper values that stand for any independent set of the same size; the grid's own
    // error is reported apart and is below the file's.
    let b = &v["budget"];
    assert_eq!(b["default"], false);
    assert_eq!(b["against"], "source");
    assert_eq!(v["bounds_exceeded"].as_array().unwrap().len(), 0);
    assert_ne!(v["codec"]["kind"], "lossless", "{}", v["codec"]);
    for (k, bound) in [("log_rmse", 0.02), ("p99_rel_core", 0.1)] {
        let checked = b["file"]["check"][k].as_f64().unwrap();
        let reported = v["check"]["uniform"]["combined"][k].as_f64().unwrap();
        // The same pairs in another order: equal up to the summation's rounding.
        assert!(
            (checked - reported).abs() <= 1e-12 * reported,
            "{k}: {checked} vs {reported}"
        );
        assert!(checked <= bound, "{k} = {checked} on the check set");
        let upper = b["file"]["upper"][k].as_f64().unwrap();
        assert!(upper <= bound, "{k} = {upper} (upper value)");
        let floor = b["grid_alone"]["metrics"][k].as_f64().unwrap();
        assert!(
            floor <= b["file"]["metrics"][k].as_f64().unwrap() * 1.001,
            "{k}: grid {floor}"
        );
    }
    let raw = v["raw_f32_bytes"].as_u64().unwrap();
    assert!(
        v["bytes"].as_u64().unwrap() * 20 < raw,
        "{} of {raw}",
        v["bytes"]
    );
    // The search runs its bisections in parallel: one thread must choose the same bytes.
    let one = dir.path().join("p1.bpk");
    brdfpack()
        .env("RAYON_NUM_THREADS", "1")
        .args(pack)
        .args(["-q", "-o"])
        .arg(&one)
        .assert()
        .success();
    assert!(std::fs::read(&one).unwrap() == std::fs::read(&out).unwrap());
}

#[test]
fn same_input_same_bytes_for_any_thread_count() {
    let run = |threads: &str| {
        brdfpack()
            .env("RAYON_NUM_THREADS", threads)
            .args([
                "tabulate",
                "lambert:albedo=0.3",
                "--grid",
                "halfdiff4:8x8x8x12",
                "-o",
                "-",
            ])
            .assert()
            .success()
            .get_output()
            .stdout
            .clone()
    };
    assert_eq!(run("1"), run("2"));
}

#[test]
fn bad_inputs_exit_2_with_a_message_and_no_output_file() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("never.bpk");
    let cases: &[(&[&str], &str)] = &[
        (&["tabulate", "lambert", "--grid", "cube:4"], "unknown kind"),
        (
            &["tabulate", "lambert", "--grid", "halfdiff3:0x4x4"],
            "resolution 0",
        ),
        (
            &["tabulate", "nosuchmodel", "--grid", "halfdiff3:4"],
            "nosuchmodel",
        ),
        (
            &["tabulate", "lambert", "--grid", "halfdiff3:4,theta-max=95"],
            "theta-max",
        ),
    ];
    for (args, needle) in cases {
        brdfpack()
            .args(*args)
            .arg("-o")
            .arg(&out)
            .assert()
            .code(2)
            .stdout("")
            .stderr(
                predicate::str::starts_with("brdfpack: ").and(predicate::str::contains(*needle)),
            );
        assert!(!out.exists());
    }
    // A corrupt table file.
    let bad = dir.path().join("bad.bpk");
    std::fs::write(&bad, b"\x89BPK\r\n\x1a\nrubbish").unwrap();
    brdfpack()
        .arg("check")
        .arg(&bad)
        .args(["--against", "lambert"])
        .assert()
        .code(2)
        .stderr(predicate::str::contains("bad.bpk"));
    // An output directory that does not exist.
    brdfpack()
        .args([
            "tabulate",
            "lambert",
            "--grid",
            "halfdiff3:4",
            "-o",
            "/nonexistent-dir/x.bpk",
        ])
        .assert()
        .code(2)
        .stderr(predicate::str::contains("does not exist"));
    // A bound that is not a number.
    brdfpack()
        .args([
            "check",
            "lambert",
            "--against",
            "lambert",
            "--max-log-rmse",
            "NaN",
        ])
        .assert()
        .code(2);
}

#[test]
fn a_killed_run_leaves_the_previous_file_intact() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("table.bpk");
    std::fs::write(&out, b"previous contents").unwrap();
    let bin = assert_cmd::cargo::cargo_bin("brdfpack");
    // A 64⁴ anisotropic table takes seconds: long enough to be killed mid-run.
    let mut child = std::process::Command::new(bin)
        .args([
            "tabulate",
            "ggx:alpha_x=0.1,alpha_y=0.4,fresnel=au",
            "--grid",
            "halfdiff4:64",
            "-o",
        ])
        .arg(&out)
        .spawn()
        .unwrap();
    std::thread::sleep(std::time::Duration::from_millis(300));
    child.kill().unwrap();
    let status = child.wait().unwrap();
    assert!(
        !status.success(),
        "the run finished before it could be killed"
    );
    assert_eq!(std::fs::read(&out).unwrap(), b"previous contents");
}

#[test]
fn a_failed_run_leaves_the_previous_file_intact_and_no_temporary() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("table.bpk");
    std::fs::write(&out, b"previous contents").unwrap();
    // The mirror is refused after the output path is known: nothing may be written.
    brdfpack()
        .args(["tabulate", "mirror", "--grid", "halfdiff3:8", "-o"])
        .arg(&out)
        .assert()
        .code(2)
        .stderr(predicate::str::contains("mirror"));
    assert_eq!(std::fs::read(&out).unwrap(), b"previous contents");
    assert_eq!(std::fs::read_dir(dir.path()).unwrap().count(), 1);
}

#[test]
fn rgl_negative_values_pass_through_unless_clamped_and_inspect_counts_them() {
    let Some(file) = common::shared_file("data/rgl/vch_golden_yellow_rgb.bsdf") else {
        return;
    };
    // A fixture pair where Mitsuba returns a negative blue value (-0.0299).
    let args = [
        "--wi",
        "0.48157772421836853,-0.23028609156608582,0.84560698270797729",
        "--wo",
        "-0.43477007746696472,0.35556581616401672,0.82737410068511963",
        "--format",
        "jsonl",
    ];
    let run = |extra: &[&str]| -> Vec<f64> {
        let o = brdfpack()
            .arg("eval")
            .arg(&file)
            .args(args)
            .args(extra)
            .assert()
            .success();
        let v: serde_json::Value = serde_json::from_slice(&o.get_output().stdout).unwrap();
        v["f"]
            .as_array()
            .unwrap()
            .iter()
            .map(|x| x.as_f64().unwrap())
            .collect()
    };
    let raw = run(&[]);
    assert!(
        (raw[2] - -0.029925483667138916).abs() < 1e-3 * 3.3,
        "{raw:?}"
    );
    assert_eq!(run(&["--clamp-negative"])[2], 0.0);
    brdfpack()
        .arg("inspect")
        .arg(&file)
        .assert()
        .success()
        .stdout(predicate::str::contains(
            "negative entries per channel: [0, 0, 1118]",
        ));
}

/// A cosine-weighted grid with the grazing warp (what `pack` picks for sources that grow
/// toward the horizon) is a fact of the table: native and EXR files evaluate alike, and
/// `inspect` names it.
#[test]
fn cosine_weighted_grids_keep_their_weight_in_every_table_format() {
    let dir = tempfile::tempdir().unwrap();
    let bpk = dir.path().join("t.bpk");
    let exr = dir.path().join("t.exr");
    brdfpack()
        .args([
            "tabulate",
            "ggx:alpha=0.3,fresnel=au",
            "--grid",
            "spherical3:16x16x32,warp=grazing/grazing/linear,weight=cosine",
            "--codec",
            "lossless",
            "-o",
        ])
        .arg(&bpk)
        .assert()
        .success();
    brdfpack()
        .arg("convert")
        .arg(&bpk)
        .arg("-o")
        .arg(&exr)
        .assert()
        .success();
    let eval = |p: &std::path::Path| {
        let out = brdfpack()
            .arg("eval")
            .arg(p)
            .args(["--wi-deg", "30,0", "--wo-deg", "89.9,180"])
            .output()
            .unwrap();
        assert!(out.status.success());
        String::from_utf8(out.stdout).unwrap()
    };
    let a = eval(&bpk);
    assert!(!a.trim().is_empty());
    assert_eq!(a, eval(&exr));
    for p in [&bpk, &exr] {
        brdfpack()
            .arg("inspect")
            .arg(p)
            .assert()
            .success()
            .stdout(predicate::str::contains("weight cosine"))
            .stdout(predicate::str::contains("grazing/grazing/linear"));
    }
}

/// `pack` on a grid stored up to θmax measures the budget inside that domain only (the
/// table holds nothing beyond it), as `check` does.
#[test]
fn pack_on_a_theta_max_grid_meets_the_budget_inside_the_domain() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("p.bpk");
    brdfpack()
        .args([
            "pack",
            "ggx:alpha=0.3,fresnel=au",
            "--grid",
            "halfdiff3:45x45x90,theta-max=60",
            "--max-error",
            "preview",
            "-q",
            "-o",
        ])
        .arg(&out)
        .assert()
        .success();
    brdfpack()
        .arg("check")
        .arg(&out)
        .args([
            "--against",
            "ggx:alpha=0.3,fresnel=au",
            "--max-log-rmse",
            "0.01",
            "--max-p99-rel-core",
            "0.2",
            "--seed",
            "77",
        ])
        .assert()
        .success()
        .stdout(predicate::str::contains("60"));
}
