//! `brdfpack build` (issue #22): a small manifest built, rebuilt without rewriting anything,
//! one material rebuilt after its spec changes, the same bytes for 1 and 2 threads and across
//! clean builds, depfiles that list every input, and Make/Ninja driving it (skipped with a
//! printed reason when they are not installed).

use assert_cmd::Command;
use std::path::Path;
use std::time::SystemTime;

fn brdfpack() -> Command {
    Command::cargo_bin("brdfpack").unwrap()
}

const MANIFEST: &str = r#"
[defaults]
grid = "halfdiff3:16x16x32"

[[material]]
name = "white"
source = "lambert:albedo=0.8/0.7/0.6"
codec = "lossless"
scene = { theta_i_max = 60, theta_o_max = 60, channels = "luminance" }
outputs = ["out/white.bpk"]

[[material]]
name = "spec"
source = "@spec.json"
scene = "scene.toml"
codec = "dct:step=0.05"
outputs = ["out/spec.bpk", "out/spec.exr"]

[[material]]
name = "ggx"
source = "ggx:alpha=0.3,fresnel=au"
codec = "f16"
outputs = ["out/ggx.bpk"]
"#;

fn setup(dir: &Path) {
    std::fs::write(dir.join("materials.toml"), MANIFEST).unwrap();
    std::fs::write(
        dir.join("spec.json"),
        r#"{"model": "phong", "albedo": 0.5, "exponent": 20}"#,
    )
    .unwrap();
    std::fs::write(
        dir.join("scene.toml"),
        "theta_i_max = 75\ntheta_o_max = 75\n",
    )
    .unwrap();
}

fn run_build(dir: &Path, extra: &[&str]) -> serde_json::Value {
    let out = brdfpack()
        .current_dir(dir)
        .args(["build", "materials.toml", "--json"])
        .args(extra)
        .assert()
        .success();
    serde_json::from_slice(&out.get_output().stdout).unwrap()
}

fn statuses(summary: &serde_json::Value) -> Vec<(String, String)> {
    summary["materials"]
        .as_array()
        .unwrap()
        .iter()
        .map(|m| {
            (
                m["name"].as_str().unwrap().to_string(),
                m["status"].as_str().unwrap().to_string(),
            )
        })
        .collect()
}

fn outputs(dir: &Path) -> Vec<(String, Vec<u8>, SystemTime)> {
    let mut v: Vec<_> = std::fs::read_dir(dir.join("out"))
        .unwrap()
        .map(|e| {
            let e = e.unwrap();
            (
                e.file_name().to_string_lossy().into_owned(),
                std::fs::read(e.path()).unwrap(),
                e.metadata().unwrap().modified().unwrap(),
            )
        })
        .collect();
    v.sort_by(|a, b| a.0.cmp(&b.0));
    v
}

#[test]
fn builds_caches_and_rebuilds_only_what_changed() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    setup(d);
    let first = run_build(d, &["-j", "1", "--depfile", "build.d"]);
    assert_eq!(first["exit_code"], 0);
    assert!(
        statuses(&first).iter().all(|(_, s)| s == "built"),
        "{first}"
    );
    let built = outputs(d);
    assert_eq!(built.len(), 4);
    // The luminance scene stored one channel on θ ≤ 60°.
    let info = brdfpack()
        .current_dir(d)
        .args(["inspect", "out/white.bpk", "--json"])
        .assert()
        .success();
    let info: serde_json::Value = serde_json::from_slice(&info.get_output().stdout).unwrap();
    assert_eq!(info["channels"], serde_json::json!(["Y"]), "{info}");
    assert!(
        info["grid"].as_str().unwrap().contains("theta-max 60"),
        "{info}"
    );
    // The depfile names the outputs and every input.
    let dep = std::fs::read_to_string(d.join("build.d")).unwrap();
    for name in [
        "out/white.bpk",
        "out/spec.exr",
        "materials.toml",
        "spec.json",
        "scene.toml",
    ] {
        assert!(dep.contains(name), "{name} not in the depfile:\n{dep}");
    }

    // Second run: nothing rebuilt, nothing rewritten.
    let second = run_build(d, &[]);
    assert!(
        statuses(&second).iter().all(|(_, s)| s == "unchanged"),
        "{second}"
    );
    assert_eq!(outputs(d), built);

    // A changed spec rebuilds exactly that material.
    std::fs::write(
        d.join("spec.json"),
        r#"{"model": "phong", "albedo": 0.5, "exponent": 30}"#,
    )
    .unwrap();
    let third = run_build(d, &[]);
    assert_eq!(
        statuses(&third),
        [
            ("white".to_string(), "unchanged".to_string()),
            ("spec".to_string(), "built".to_string()),
            ("ggx".to_string(), "unchanged".to_string())
        ]
    );
    let after = outputs(d);
    for (old, new) in built.iter().zip(&after) {
        if old.0.starts_with("spec") {
            assert_ne!(old.1, new.1, "{} changed", old.0);
        } else {
            assert_eq!(old, new, "{} untouched", old.0);
        }
    }

    // A deleted output is restored from the cache, the same bytes.
    std::fs::remove_file(d.join("out/ggx.bpk")).unwrap();
    let fourth = run_build(d, &[]);
    assert_eq!(statuses(&fourth)[2].1, "restored");
    assert_eq!(std::fs::read(d.join("out/ggx.bpk")).unwrap(), after[0].1);
}

#[test]
fn the_same_bytes_for_one_and_two_threads_and_clean_builds() {
    let mut runs = Vec::new();
    for threads in ["1", "2", "2"] {
        let dir = tempfile::tempdir().unwrap();
        setup(dir.path());
        run_build(dir.path(), &["-j", threads]);
        runs.push(
            outputs(dir.path())
                .into_iter()
                .map(|(n, b, _)| (n, b))
                .collect::<Vec<_>>(),
        );
    }
    assert_eq!(runs[0], runs[1]);
    assert_eq!(runs[1], runs[2]);
}

#[test]
fn a_failing_material_gives_the_worst_exit_code() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    setup(d);
    let bad = MANIFEST.replace("lambert:albedo=0.8/0.7/0.6", "lambert:albedo=oops");
    std::fs::write(d.join("materials.toml"), bad).unwrap();
    let out = brdfpack()
        .current_dir(d)
        .args([
            "build",
            "materials.toml",
            "--json",
            "--keep-going",
            "-j",
            "1",
        ])
        .assert()
        .code(2);
    let s: serde_json::Value = serde_json::from_slice(&out.get_output().stdout).unwrap();
    assert_eq!(
        statuses(&s)
            .iter()
            .map(|(_, s)| s.as_str())
            .collect::<Vec<_>>(),
        ["failed", "built", "built"]
    );
    assert!(
        s["materials"][0]["error"]
            .as_str()
            .unwrap()
            .contains("oops"),
        "{s}"
    );
    // Without --keep-going the others are not started (one thread: in order).
    let out = brdfpack()
        .current_dir(d)
        .args(["build", "materials.toml", "--json", "-j", "1", "--force"])
        .assert()
        .code(2);
    let s: serde_json::Value = serde_json::from_slice(&out.get_output().stdout).unwrap();
    assert_eq!(statuses(&s)[0].1, "failed");
    // A bad manifest is bad input.
    std::fs::write(d.join("bad.toml"), "[[material]]\nname = 1\n").unwrap();
    brdfpack()
        .current_dir(d)
        .args(["build", "bad.toml"])
        .assert()
        .code(2)
        .stderr(predicates::str::contains("brdfpack: manifest bad.toml"));
}

fn have(tool: &str) -> bool {
    std::process::Command::new(tool)
        .arg("--version")
        .output()
        .is_ok_and(|o| o.status.success())
}

#[test]
fn ninja_with_restat_and_depfile() {
    if !have("ninja") {
        eprintln!("skipped: ninja is not installed (apt-get install ninja-build)");
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    setup(d);
    let exe = assert_cmd::cargo::cargo_bin("brdfpack");
    std::fs::write(
        d.join("build.ninja"),
        format!(
            "rule brdfpack\n  command = {} build $in -q --depfile summary.d -o summary.json\n  depfile = summary.d\n  deps = gcc\n  restat = 1\n\
             build summary.json out/white.bpk out/spec.bpk out/spec.exr out/ggx.bpk: brdfpack materials.toml\n\
             rule size\n  command = wc -c $in > $out\n\
             build ggx.size: size out/ggx.bpk\n",
            exe.display()
        ),
    )
    .unwrap();
    let ninja = |args: &[&str]| {
        let o = std::process::Command::new("ninja")
            .current_dir(d)
            .args(args)
            .output()
            .unwrap();
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stdout));
        String::from_utf8_lossy(&o.stdout).into_owned()
    };
    ninja(&["summary.json", "ggx.size"]);
    let again = ninja(&["summary.json", "ggx.size"]);
    assert!(again.contains("no work to do"), "{again}");
    // Ninja tracks spec.json through the depfile: editing it reruns the build, which
    // rebuilds one material only.
    std::thread::sleep(std::time::Duration::from_millis(1100));
    std::fs::write(
        d.join("spec.json"),
        r#"{"model": "phong", "albedo": 0.5, "exponent": 30}"#,
    )
    .unwrap();
    let before = std::fs::metadata(d.join("out/ggx.bpk"))
        .unwrap()
        .modified()
        .unwrap();
    let third = ninja(&["summary.json", "ggx.size"]);
    assert!(third.contains("brdfpack"), "{third}");
    let s: serde_json::Value =
        serde_json::from_slice(&std::fs::read(d.join("summary.json")).unwrap()).unwrap();
    assert_eq!(statuses(&s)[1], ("spec".to_string(), "built".to_string()));
    assert_eq!(
        statuses(&s)[2],
        ("ggx".to_string(), "unchanged".to_string())
    );
    assert_eq!(
        std::fs::metadata(d.join("out/ggx.bpk"))
            .unwrap()
            .modified()
            .unwrap(),
        before
    );
}

#[test]
fn make_with_depfiles() {
    if !have("make") {
        eprintln!("skipped: make is not installed");
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    setup(d);
    let exe = assert_cmd::cargo::cargo_bin("brdfpack");
    std::fs::write(
        d.join("Makefile"),
        format!(
            "summary.json: materials.toml\n\t{} build materials.toml -q --depfile summary.d -o $@\n-include summary.d\n",
            exe.display()
        ),
    )
    .unwrap();
    let make = || {
        let o = std::process::Command::new("make")
            .current_dir(d)
            .output()
            .unwrap();
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
        String::from_utf8_lossy(&o.stdout).into_owned()
    };
    make();
    assert!(make().contains("up to date"));
    std::thread::sleep(std::time::Duration::from_millis(1100));
    std::fs::write(d.join("scene.toml"), "theta_i_max = 70\ntheta_o_max = 70\n").unwrap();
    assert!(make().contains("build materials.toml"));
    let s: serde_json::Value =
        serde_json::from_slice(&std::fs::read(d.join("summary.json")).unwrap()).unwrap();
    assert_eq!(
        statuses(&s)
            .iter()
            .map(|(_, s)| s.as_str())
            .collect::<Vec<_>>(),
        ["unchanged", "built", "unchanged"]
    );
}

/// An output that is the material's own source is refused before anything is written
/// (exit 2, the source kept byte for byte): written, it would replace the input with its
/// re-encoding, lossy under a codec, which the next build would then read as the source.
/// Also through another spelling of the same file (`./`).
#[test]
fn an_output_that_is_the_materials_source_is_refused() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    brdfpack()
        .current_dir(d)
        .args([
            "tabulate",
            "ggx:alpha=0.3,fresnel=au",
            "--grid",
            "halfdiff3:16x16x32",
            "--codec",
            "lossless",
            "-o",
            "src.bpk",
        ])
        .assert()
        .success();
    let before = std::fs::read(d.join("src.bpk")).unwrap();
    for out in ["src.bpk", "./src.bpk"] {
        let manifest = format!(
            "[[material]]\nname = \"self\"\nsource = \"src.bpk\"\ncodec = \"dct:step=0.5\"\n\
             outputs = [\"{out}\"]\n"
        );
        std::fs::write(d.join("m.toml"), manifest).unwrap();
        brdfpack()
            .current_dir(d)
            .args(["build", "m.toml", "-q"])
            .assert()
            .code(2)
            .stderr(predicates::str::contains("which the material reads"));
        assert_eq!(std::fs::read(d.join("src.bpk")).unwrap(), before, "{out}");
    }
}
