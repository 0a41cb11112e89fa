//! `brdfpack compress` end to end on a small self-made table.

use assert_cmd::Command;
use brdfpack::codec::CodecSpec;
use brdfpack::grid::parse_grid_spec;
use brdfpack::io::native;
use brdfpack::tabulate::tabulate;
use brdfpack::testing as testdata;
use predicates::prelude::PredicateBooleanExt;
use std::path::Path;

fn small_table_file(dir: &Path) -> std::path::PathBuf {
    let g = parse_grid_spec("halfdiff3:16x16x24").unwrap();
    let t = tabulate(&testdata::GgxConductor::new(0.3), &g, &Default::default()).unwrap();
    let p = dir.join("in.bpk");
    std::fs::write(&p, native::to_bytes(&t, &CodecSpec::default()).unwrap()).unwrap();
    p
}

#[test]
fn compress_with_a_budget_writes_a_file_that_meets_it() {
    let dir = tempfile::tempdir().unwrap();
    let input = small_table_file(dir.path());
    let out = dir.path().join("out.bpk");
    let a = Command::cargo_bin("brdfpack")
        .unwrap()
        .args([
            "compress",
            input.to_str().unwrap(),
            "-o",
            out.to_str().unwrap(),
        ])
        .args([
            "--max-error",
            "log_rmse=0.01,p99_rel_core=0.2",
            "--samples",
            "4096",
            "-v",
        ])
        .assert()
        .success();
    // The human report is on stderr with -v (quiet by default, issue #22).
    assert!(a.get_output().stdout.is_empty());
    let stdout = String::from_utf8(a.get_output().stderr.clone()).unwrap();
    assert!(stdout.contains("\"kind\":\"dct_context\""), "{stdout}");
    assert!(
        stdout.contains("met by the written file against the input"),
        "{stdout}"
    );
    assert!(
        stdout.contains("on the uniform set of 4096 pairs, seed 1"),
        "{stdout}"
    );
    let log_rmse: f64 = stdout
        .split("file: log_rmse ")
        .nth(1)
        .and_then(|s| s.split([',', ' ']).next())
        .and_then(|s| s.parse().ok())
        .unwrap();
    assert!(log_rmse <= 0.01, "{stdout}");
    let bytes = std::fs::read(&out).unwrap();
    let t = native::from_bytes(&bytes, &out).unwrap();
    assert!(t.data().iter().all(|v| v.is_finite() && *v >= 0.0));
}

#[test]
fn compress_lossless_is_bit_exact_and_bad_specs_exit_2() {
    let dir = tempfile::tempdir().unwrap();
    let input = small_table_file(dir.path());
    let out = dir.path().join("out.bpk");
    Command::cargo_bin("brdfpack")
        .unwrap()
        .args([
            "compress",
            input.to_str().unwrap(),
            "-o",
            out.to_str().unwrap(),
        ])
        .args(["--codec", "lossless", "--samples", "1024"])
        .assert()
        .success();
    let a = native::from_bytes(&std::fs::read(&input).unwrap(), &input).unwrap();
    let b = native::from_bytes(&std::fs::read(&out).unwrap(), &out).unwrap();
    assert_eq!(a.data(), b.data());
    Command::cargo_bin("brdfpack")
        .unwrap()
        .args([
            "compress",
            input.to_str().unwrap(),
            "-o",
            out.to_str().unwrap(),
        ])
        .args(["--codec", "dct:step=-1"])
        .assert()
        .code(2)
        .stderr(predicates::str::contains("step"));
    Command::cargo_bin("brdfpack")
        .unwrap()
        .args([
            "compress",
            input.to_str().unwrap(),
            "-o",
            out.to_str().unwrap(),
        ])
        .args(["--max-error", "bogus=1"])
        .assert()
        .code(2);
}

/// `pack MODEL --max-error` with an explicit grid: a one-grid search measured against the
/// model, reported in `grid_search`, whose error is the final check's.
#[test]
fn pack_a_model_with_a_budget_reports_the_grid_search() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("out.bpk");
    let o = Command::cargo_bin("brdfpack")
        .unwrap()
        .args(["pack", "ggx:alpha=0.5", "-o", out.to_str().unwrap()])
        .args([
            "--grid",
            "halfdiff3:16x16x32,warp=sqrt/linear/linear,at=edge",
            "--max-error",
            "log_rmse=0.01,p99_rel_core=0.2",
            "--samples",
            "2048",
            "--json",
        ])
        .assert()
        .success()
        .get_output()
        .stdout
        .clone();
    let v: serde_json::Value = serde_json::from_slice(&o).unwrap();
    let b = &v["budget"];
    let gs = b["grids"].as_array().unwrap();
    // A grid the user fixed is never refined.
    assert_eq!(gs.len(), 1, "{v}");
    assert_eq!(gs[0]["chosen"], true);
    assert_eq!(gs[0]["grid"], v["grid"]);
    assert!(gs[0]["payload_bytes"].as_u64().unwrap() < v["bytes"].as_u64().unwrap());
    assert_eq!(b["against"], "source");
    // The planner's check-set measurement is the report's check: same file, same pairs.
    for k in ["log_rmse", "p99_rel_core"] {
        let planned = b["file"]["check"][k].as_f64().unwrap();
        let checked = v["check"]["uniform"]["combined"][k].as_f64().unwrap();
        assert!(
            (planned - checked).abs() <= 1e-12 * checked,
            "{k}: {planned} vs {checked}"
        );
    }
    assert!(b["file"]["upper"]["log_rmse"].as_f64().unwrap() <= 0.01);
    assert!(b["file"]["upper"]["p99_rel_core"].as_f64().unwrap() <= 0.2);
    assert_eq!(
        std::fs::read(&out).unwrap().len() as u64,
        v["bytes"].as_u64().unwrap()
    );
}

/// No grid of the default ladder can meet the budget: exit 1, the closest values, no file.
#[test]
fn pack_with_an_unmeetable_budget_exits_1_and_writes_nothing() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("out.bpk");
    Command::cargo_bin("brdfpack")
        .unwrap()
        .args(["pack", "ggx:alpha=0.5", "-o", out.to_str().unwrap()])
        .args(["--max-error", "log_rmse=1e-5", "--samples", "1024"])
        .assert()
        .code(1)
        .stdout("")
        .stderr(
            predicates::str::contains("the budget log_rmse ≤ 0.00001 cannot be met")
                .and(predicates::str::contains("the grid's own error"))
                // The default grid and the refinements tried, each with its own error.
                // (interpolated in a log space when that is measured closer; the default
                // grid is extended below the horizon).
                .and(predicates::str::is_match(
                    r"halfdiff3 90x90x180 \(warp sqrt/grazing/linear; at edge/edge/edge\)(; space log:[0-9.e+-]+)?; horizon extend: log_rmse ",
                ).unwrap())
                .and(predicates::str::contains("no file written")),
        );
    assert!(!out.exists());
}

/// The Tucker encoder's sums run on rayon threads: the file must not depend on how many.
#[test]
fn tucker_files_are_the_same_bytes_for_any_thread_count() {
    let dir = tempfile::tempdir().unwrap();
    let input = small_table_file(dir.path());
    let run = |threads: &str| {
        let out = dir.path().join(format!("tucker-{threads}.bpk"));
        Command::cargo_bin("brdfpack")
            .unwrap()
            .env("RAYON_NUM_THREADS", threads)
            .args([
                "compress",
                input.to_str().unwrap(),
                "-o",
                out.to_str().unwrap(),
            ])
            .args([
                "--codec",
                "tucker:ranks=8x8x12,step=0.02",
                "--samples",
                "1024",
            ])
            .assert()
            .success();
        std::fs::read(&out).unwrap()
    };
    let one = run("1");
    assert_eq!(one, run("2"));
    let t = native::from_bytes(&one, Path::new("tucker.bpk")).unwrap();
    assert!(t.data().iter().all(|v| v.is_finite() && *v >= 0.0));
    let header = native::read_header(&one, Path::new("tucker.bpk")).unwrap();
    assert!(matches!(header.codec, CodecSpec::Tucker { .. }));
}

/// `compress --codec ...,residual=S` end to end: the file's header records the residual kind,
/// it decodes with no flags within the stated bound of the source in the transformed space
/// (every valid sample), `inspect` and `check` read it, and the bytes do not depend on the
/// thread count (the DCT forward and the Tucker encoder run on rayon threads).
#[test]
fn compress_with_a_residual_round_trips_within_its_bound_through_the_cli() {
    let dir = tempfile::tempdir().unwrap();
    let input = small_table_file(dir.path());
    let source = native::from_bytes(&std::fs::read(&input).unwrap(), &input).unwrap();
    for (codec, kind) in [
        ("dct:step=0.5,residual=0.01", "dct_context_residual"),
        ("dct:step=0.5,coding=zstd,residual=0.02", "dct_residual"),
        (
            "tucker:ranks=4x4x6,step=0.3,residual=0.01",
            "tucker_residual",
        ),
    ] {
        let run = |threads: &str| {
            let out = dir.path().join(format!("{kind}-{threads}.bpk"));
            let a = Command::cargo_bin("brdfpack")
                .unwrap()
                .env("RAYON_NUM_THREADS", threads)
                .args([
                    "compress",
                    input.to_str().unwrap(),
                    "-o",
                    out.to_str().unwrap(),
                ])
                .args(["--codec", codec, "--samples", "2048", "-v"])
                .assert()
                .success();
            let stdout = String::from_utf8(a.get_output().stderr.clone()).unwrap();
            assert!(
                stdout.contains(&format!("\"kind\":\"{kind}\"")),
                "{codec}: {stdout}"
            );
            assert!(
                stdout.contains("preserves: every valid sample within ±"),
                "{codec}: {stdout}"
            );
            let bytes = std::fs::read(&out).unwrap();
            (out, bytes)
        };
        let (out, one) = run("1");
        assert_eq!(one, run("2").1, "{codec}: bytes depend on the thread count");
        let header = native::read_header(&one, &out).unwrap();
        let spec = header.codec;
        assert!(spec.residual().is_some(), "{codec}");
        let bound = spec.max_transformed_error().unwrap();
        let t = native::from_bytes(&one, &out).unwrap();
        let tr = spec.transform().unwrap();
        let curve_only = brdfpack::codec::transform::Transform {
            colour: None,
            ..tr.clone()
        };
        let c = 3;
        let a = curve_only.forward_all(t.data(), c, t.grid(), t.valid());
        let b = curve_only.forward_all(source.data(), c, t.grid(), t.valid());
        let mut worst = 0f64;
        for (f, &ok) in t.valid().iter().enumerate() {
            for k in 0..c {
                let i = f * c + k;
                if !ok {
                    assert_eq!(t.data()[i], 0.0, "{codec}: invalid cell {f}");
                    continue;
                }
                // f32 rounding of the decoded value (log space: a few 1e-7).
                assert!(
                    (a[i] - b[i]).abs() <= bound + 1e-5,
                    "{codec}: value {i}: {} vs {} (bound {bound})",
                    a[i],
                    b[i]
                );
                worst = worst.max((a[i] - b[i]).abs());
            }
        }
        assert!(worst > 0.2 * bound, "{codec}: {worst} vs {bound}");
        let i = Command::cargo_bin("brdfpack")
            .unwrap()
            .args(["inspect", out.to_str().unwrap(), "--json"])
            .assert()
            .success();
        let v: serde_json::Value = serde_json::from_slice(&i.get_output().stdout).unwrap();
        assert_eq!(v["negative_values"], 0, "{v}");
        assert_eq!(v["valid_cells"].as_u64().unwrap() as usize, {
            t.valid().iter().filter(|&&ok| ok).count()
        });
        let ch = Command::cargo_bin("brdfpack")
            .unwrap()
            .args(["check", out.to_str().unwrap(), "--against"])
            .arg(&input)
            .args(["--uniform-only", "--samples", "4096", "--json"])
            .args(["--max-log-rmse", "0.01"])
            .assert()
            .success();
        let v: serde_json::Value = serde_json::from_slice(&ch.get_output().stdout).unwrap();
        assert_eq!(v["bounds_exceeded"], serde_json::json!([]), "{codec}: {v}");
    }
}

/// A truncated residual file: exit 2 naming the file, no panic.
#[test]
fn a_truncated_residual_file_is_a_clear_error() {
    let dir = tempfile::tempdir().unwrap();
    let input = small_table_file(dir.path());
    let out = dir.path().join("res.bpk");
    Command::cargo_bin("brdfpack")
        .unwrap()
        .args([
            "compress",
            input.to_str().unwrap(),
            "-o",
            out.to_str().unwrap(),
        ])
        .args(["--codec", "dct:step=0.5,residual=0.01", "--samples", "1024"])
        .assert()
        .success();
    let bytes = std::fs::read(&out).unwrap();
    let cut = dir.path().join("cut.bpk");
    std::fs::write(&cut, &bytes[..bytes.len() - 7]).unwrap();
    Command::cargo_bin("brdfpack")
        .unwrap()
        .args(["inspect", cut.to_str().unwrap()])
        .assert()
        .code(2)
        .stderr(predicates::str::contains("cut.bpk"))
        .stderr(predicates::str::contains("panicked").not());
}

/// A table carrying exact f64 values (as read from a MERL `.binary`): `compress --max-error`
/// plans on its f32 samples without holding the f64 values, and when the budget takes the
/// lossless codec the written file still carries them, read again from the input; a lossy
/// file never does.
#[test]
fn a_budget_met_losslessly_keeps_the_exact_values_and_a_lossy_one_drops_them() {
    use brdfpack::table::ExactValues;
    let dir = tempfile::tempdir().unwrap();
    let g = parse_grid_spec("halfdiff3:16x16x24").unwrap();
    let t = tabulate(&testdata::GgxConductor::new(0.3), &g, &Default::default()).unwrap();
    // Numbers that f32 does not hold: 1 + 1e-10 relative off the samples.
    let raw: Vec<f64> = t.data().iter().map(|&v| v as f64 * (1.0 + 1e-10)).collect();
    assert!(raw.iter().zip(t.data()).any(|(r, &v)| *r != v as f64));
    let exact = ExactValues {
        scale: vec![1.0; 3],
        raw: raw.clone(),
    };
    let t = t.with_exact(exact.clone()).unwrap();
    let input = dir.path().join("exact.bpk");
    let lossless = CodecSpec::default();
    assert!(lossless.is_lossless());
    std::fs::write(&input, native::to_bytes(&t, &lossless).unwrap()).unwrap();
    for (budget, keeps) in [
        ("log_rmse=1e-12,p99_rel_core=1e-12", true),
        ("log_rmse=0.01,p99_rel_core=0.2", false),
    ] {
        let out = dir.path().join("out.bpk");
        Command::cargo_bin("brdfpack")
            .unwrap()
            .arg("compress")
            .arg(&input)
            .arg("-o")
            .arg(&out)
            .args(["--max-error", budget, "--samples", "4096"])
            .assert()
            .success();
        let back = native::from_bytes(&std::fs::read(&out).unwrap(), &out).unwrap();
        if keeps {
            assert_eq!(back.exact(), Some(&exact), "{budget}");
            assert_eq!(back.data(), t.data(), "{budget}");
        } else {
            assert!(back.exact().is_none(), "{budget}");
        }
    }
}
