//! `brdfpack compress` end to end on a small self-made table.

use assert_cmd::Command;
use brdfpack::codec::{CodecSpec, testdata};
use brdfpack::grid::parse_grid_spec;
use brdfpack::io::native;
use brdfpack::tabulate::tabulate;
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
        ])
        .assert()
        .success();
    let stdout = String::from_utf8(a.get_output().stdout.clone()).unwrap();
    assert!(stdout.contains("\"kind\":\"dct_context\""), "{stdout}");
    assert!(
        stdout.contains("held-out set (uniform, 4096 pairs, seed 2"),
        "{stdout}"
    );
    let log_rmse: f64 = stdout
        .split("log_rmse ")
        .nth(1)
        .and_then(|s| s.split_whitespace().next())
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
    let gs = v["grid_search"].as_array().unwrap();
    assert_eq!(gs.len(), 1, "{v}");
    assert_eq!(gs[0]["status"], "packed");
    assert_eq!(gs[0]["chosen"], true);
    assert_eq!(gs[0]["bytes"], v["bytes"]);
    assert_eq!(v["budget"]["against"], "model");
    // The search's measurement is the check's: same bytes, same set, same model.
    for k in ["log_rmse", "p99_rel_core"] {
        assert_eq!(
            gs[0]["metrics"][k], v["check"]["uniform"]["combined"][k],
            "{k}"
        );
    }
    assert!(
        v["check"]["uniform"]["combined"]["log_rmse"]
            .as_f64()
            .unwrap()
            <= 0.01 * 0.98
    );
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
            predicates::str::contains("no grid meets log_rmse ≤ 0.00001 against the model")
                .and(predicates::str::contains("best reached: log_rmse "))
                .and(predicates::str::contains(
                    "halfdiff3:128x128x256,warp=sqrt/linear/linear,at=edge",
                ))
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
