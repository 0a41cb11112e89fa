//! Issue #22: one flag vocabulary. Walks every subcommand the binary lists (not a hand list)
//! and checks that its `--help` shows examples; then that completions and the man page are
//! generated from the definition. That each subcommand accepts `-o`, `--json`, `-q` and `-v`
//! is checked on the clap definition itself, in the binary's unit tests
//! (`src/cli/vocabulary_tests.rs`: the CLI is not part of the library).

use assert_cmd::Command;

fn brdfpack() -> Command {
    Command::cargo_bin("brdfpack").unwrap()
}

/// The subcommands of `brdfpack --help` (its `Commands:` section, without `help`).
fn subcommands() -> Vec<String> {
    let out = brdfpack().arg("--help").assert().success();
    let text = String::from_utf8(out.get_output().stdout.clone()).unwrap();
    let list = text.split_once("Commands:\n").unwrap().1;
    let list = list.split("\n\n").next().unwrap();
    let names: Vec<String> = list
        .lines()
        .filter(|l| l.starts_with("  ") && !l.starts_with("   "))
        .map(|l| l.split_whitespace().next().unwrap().to_string())
        .filter(|n| n != "help")
        .collect();
    assert!(names.len() >= 14, "{names:?}");
    names
}

#[test]
fn every_help_shows_examples() {
    for name in subcommands() {
        let out = brdfpack().args([&name, "--help"]).assert().success();
        let text = String::from_utf8(out.get_output().stdout.clone()).unwrap();
        let examples = text
            .split_once("Examples:")
            .unwrap_or_else(|| panic!("{name} --help has no Examples:\n{text}"))
            .1;
        assert!(
            examples.contains(&format!("brdfpack {name}")),
            "{name}: the examples do not show the command:\n{examples}"
        );
    }
}

#[test]
fn completions_and_man_are_generated_from_the_definition() {
    let bash = brdfpack().args(["completions", "bash"]).assert().success();
    let script = String::from_utf8(bash.get_output().stdout.clone()).unwrap();
    for name in subcommands() {
        assert!(script.contains(&name), "bash completions miss {name}");
    }
    assert!(script.contains("--depfile"));
    let man = brdfpack().args(["man"]).assert().success();
    let roff = String::from_utf8(man.get_output().stdout.clone()).unwrap();
    assert!(roff.contains(".TH brdfpack 1"), "{roff}");
    assert!(roff.contains("build"));
    let page = brdfpack().args(["man", "pack"]).assert().success();
    let roff = String::from_utf8(page.get_output().stdout.clone()).unwrap();
    assert!(roff.contains(".TH brdfpack-pack 1"), "{roff}");
    assert!(roff.contains("max\\-error"), "pack's flags are on its page");
    brdfpack().args(["man", "nonesuch"]).assert().code(2);
}

#[test]
fn report_commands_write_to_o_and_say_nothing_with_q() {
    let dir = tempfile::tempdir().unwrap();
    let file = dir.path().join("models.json");
    let out = brdfpack()
        .args(["models", "lambert", "--json", "-o"])
        .arg(&file)
        .assert()
        .success();
    assert!(out.get_output().stdout.is_empty());
    let v: serde_json::Value = serde_json::from_slice(&std::fs::read(&file).unwrap()).unwrap();
    assert_eq!(v["models"][0]["name"], "lambert", "{v}");
    let q = brdfpack()
        .args([
            "eval",
            "lambert:albedo=0.5",
            "--wi-deg",
            "0,0",
            "--wo-deg",
            "0,0",
            "-q",
        ])
        .assert()
        .success();
    assert!(q.get_output().stdout.is_empty() && q.get_output().stderr.is_empty());
    let j = brdfpack()
        .args([
            "eval",
            "lambert:albedo=0.5",
            "--wi-deg",
            "0,0",
            "--wo-deg",
            "0,0",
            "--json",
        ])
        .assert()
        .success();
    let row: serde_json::Value = serde_json::from_slice(&j.get_output().stdout).unwrap();
    let f = row["f"][0].as_f64().unwrap();
    assert!((f - 0.5 / std::f64::consts::PI).abs() < 1e-12, "{row}");
}

#[test]
fn pack_is_quiet_by_default_and_reports_on_request() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("l.bpk");
    let quiet = brdfpack()
        .args([
            "pack",
            "lambert:albedo=0.5",
            "--grid",
            "halfdiff3:8x8x16",
            "--codec",
            "lossless",
            "--samples",
            "4096",
            "-o",
        ])
        .arg(&out)
        .assert()
        .success();
    assert!(quiet.get_output().stdout.is_empty() && quiet.get_output().stderr.is_empty());
    let v = brdfpack()
        .args([
            "pack",
            "lambert:albedo=0.5",
            "--grid",
            "halfdiff3:8x8x16",
            "--codec",
            "lossless",
            "--samples",
            "4096",
            "-v",
            "-o",
        ])
        .arg(&out)
        .assert()
        .success();
    assert!(v.get_output().stdout.is_empty());
    let err = String::from_utf8(v.get_output().stderr.clone()).unwrap();
    assert!(err.contains("size ") && err.contains("log_rmse"), "{err}");
    let j = brdfpack()
        .args([
            "pack",
            "lambert:albedo=0.5",
            "--grid",
            "halfdiff3:8x8x16",
            "--codec",
            "lossless",
            "--samples",
            "4096",
            "--json",
            "-o",
        ])
        .arg(&out)
        .assert()
        .success();
    let r: serde_json::Value = serde_json::from_slice(&j.get_output().stdout).unwrap();
    assert_eq!(
        r["bytes"].as_u64().unwrap(),
        std::fs::metadata(&out).unwrap().len()
    );
}
