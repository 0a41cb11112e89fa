//! `brdfpack bench --quick` (what CI runs): finishes, and its files parse.

use assert_cmd::Command;

/// A minimal well-formedness check: every element opened is closed in order.
fn assert_well_formed_xml(text: &str, what: &str) {
    let mut stack: Vec<String> = Vec::new();
    let mut rest = text;
    while let Some(i) = rest.find('<') {
        rest = &rest[i + 1..];
        let j = rest
            .find('>')
            .unwrap_or_else(|| panic!("{what}: unterminated tag"));
        let tag = &rest[..j];
        rest = &rest[j + 1..];
        if tag.starts_with('?') || tag.starts_with('!') || tag.ends_with('/') {
            continue;
        }
        let name = |t: &str| t.split_whitespace().next().unwrap_or("").to_string();
        if let Some(closing) = tag.strip_prefix('/') {
            let open = stack
                .pop()
                .unwrap_or_else(|| panic!("{what}: </{closing}> closes nothing"));
            assert_eq!(open, name(closing), "{what}: mismatched tags");
        } else {
            stack.push(name(tag));
        }
    }
    assert!(stack.is_empty(), "{what}: unclosed {stack:?}");
}

#[test]
fn quick_bench_writes_parseable_files() {
    let dir = tempfile::tempdir().unwrap();
    let out = Command::cargo_bin("brdfpack")
        .unwrap()
        .args(["bench", "--quick", "--runs", "1", "--pairs", "20000", "-o"])
        .arg(dir.path())
        .env("BRDFPACK_SHARED", dir.path().join("absent"))
        .assert()
        .success()
        .get_output()
        .stderr
        .clone();
    let log = String::from_utf8_lossy(&out);
    assert!(log.contains("rayon threads"), "machine line missing: {log}");
    let csv = std::fs::read_to_string(dir.path().join("bench.csv")).unwrap();
    let mut lines = csv.lines();
    let header: Vec<&str> = lines.next().unwrap().split(',').collect();
    assert_eq!(header, brdfpack::bench::CSV_COLUMNS);
    let rows: Vec<&str> = lines.collect();
    // lambert, ggx-conductor, ward-aniso × one grid × the quick codecs.
    assert_eq!(
        rows.len(),
        3 * brdfpack::bench::bench_codecs(true).len(),
        "{csv}"
    );
    let json: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(dir.path().join("bench.json")).unwrap())
            .unwrap();
    assert_eq!(json["schema"], "brdfpack-bench/1");
    assert!(json["machine"]["threads"].as_u64().unwrap() >= 1);
    let rows = json["rows"].as_array().unwrap();
    assert_eq!(rows.len(), 3 * brdfpack::bench::bench_codecs(true).len());
    for r in rows {
        assert!(r["bytes"].as_u64().unwrap() > 0);
        assert!(r["lookups_per_s"].as_f64().unwrap() > 0.0);
        assert!(r["log_rmse"].as_f64().unwrap().is_finite());
    }
    // Lambert is constant: its table reproduces it to f32 precision.
    assert!(rows[0]["log_rmse"].as_f64().unwrap() < 1e-6);
    assert_eq!(json["speed"].as_array().unwrap().len(), 2);
    let md = std::fs::read_to_string(dir.path().join("bench.md")).unwrap();
    assert!(md.contains("| source | grid | codec |"));
    // Codecs are named by the request as typed, not by the resolved spec's JSON.
    for request in brdfpack::bench::bench_codecs(true) {
        assert!(md.contains(&format!("| {request} |")), "{request}: {md}");
    }
    assert!(!md.contains("\"kind\""), "{md}");
    for svg in ["error_vs_bytes.svg", "error_vs_lookup_time.svg"] {
        let text = std::fs::read_to_string(dir.path().join(svg)).unwrap();
        assert!(
            text.contains("<svg") && text.contains("Pareto front"),
            "{svg}"
        );
        // Points are labelled by codec family (a legend entry each) and by grid.
        for request in brdfpack::bench::bench_codecs(true) {
            let family = brdfpack::bench::codec_family(request);
            assert!(text.contains(&format!("codec {family}")), "{svg}: {family}");
        }
        assert!(text.contains("16x16x32"), "{svg}: grid label");
        assert_well_formed_xml(&text, svg);
    }
}

/// `bench --zoo --zoo-random`: the drawn material is the library's (same seed, same spec),
/// packed within both budgets and verified on the seeds asked for; with `--zoo-sampled` an
/// isotropic model is packed as its MERL-grid table (`@merl`, the MERL grid kept) and
/// measured against that table. Rows whose file misses a bound exit 1, so the exit status is
/// the rows' own verdict.
#[test]
fn the_zoo_draws_seeded_random_materials_and_their_merl_tables() {
    let want = brdfpack::plan::zoo::random_materials(1, 6).remove(0);
    for sampled in [false, true] {
        let mut cmd = Command::cargo_bin("brdfpack").unwrap();
        cmd.args([
            "bench",
            "--zoo",
            "--zoo-random",
            "1",
            "--zoo-random-seed",
            "6",
            "--zoo-filter",
            "random",
            "--zoo-seeds",
            "2",
            "--zoo-pairs",
            "4000",
            "--json",
            "-q",
        ]);
        if sampled {
            cmd.arg("--zoo-sampled");
        }
        let out = cmd.output().unwrap();
        let text = String::from_utf8(out.stdout).unwrap();
        let rows: Vec<serde_json::Value> = text
            .lines()
            .map(|l| serde_json::from_str(l).unwrap())
            .collect();
        assert_eq!(rows.len(), 2, "{text}");
        let mut holds = true;
        for (row, budget) in rows.iter().zip(["preview", "production"]) {
            let name = if sampled {
                format!("{}@merl", want.name)
            } else {
                want.name.clone()
            };
            assert_eq!(row["material"], name.as_str());
            assert_eq!(row["spec"], want.spec.as_str());
            assert_eq!(row["budget"], budget);
            assert_eq!(row["seeds"], 2);
            assert!(row["bytes"].as_u64().unwrap() > 100, "{row}");
            let grid = row["grid"].as_str().unwrap();
            assert_eq!(
                grid.starts_with("halfdiff3 90x90x180 (warp sqrt/linear/linear"),
                sampled,
                "{grid}"
            );
            holds &= row["holds"].as_bool().unwrap();
        }
        assert_eq!(out.status.code(), Some(if holds { 0 } else { 1 }));
    }
}
