//! Writes that fail (issue 7): a full disk on stdout (`/dev/full`), a file-size limit on an
//! output file (`ulimit -f`), and a reader that goes away (a closed pipe). Every command
//! must fail cleanly: exit 1 with one `brdfpack:` line naming the output and the OS error,
//! no panic (exit 101), the previous output file intact and no temporary file left; a closed
//! pipe ends the command quietly (exit 0, nothing on stderr), as `| head` expects.
#![cfg(target_os = "linux")]

use std::path::Path;
use std::process::{Command, Output, Stdio};

fn brdfpack() -> Command {
    Command::new(env!("CARGO_BIN_EXE_brdfpack"))
}

/// A small table file and a stream of pairs in `dir`, for the commands that read them.
fn make_inputs(dir: &Path) {
    let out = brdfpack()
        .args([
            "tabulate",
            "ggx:alpha=0.3,fresnel=au",
            "--grid",
            "halfdiff3:6",
        ])
        .arg("-o")
        .arg(dir.join("t.bpk"))
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    std::fs::write(
        dir.join("pairs.txt"),
        "0 0 1 0 0 1\n0.3 0 0.9 -0.2 0.1 0.9\n",
    )
    .unwrap();
}

/// The commands that print to stdout or write `-o -`, each small enough for a debug build.
fn commands(dir: &Path) -> Vec<(&'static str, Vec<String>)> {
    let t = dir.join("t.bpk").display().to_string();
    let o = |name: &str| dir.join(name).display().to_string();
    let v = |a: &[&str]| a.iter().map(|s| s.to_string()).collect::<Vec<_>>();
    vec![
        (
            "tabulate",
            v(&["tabulate", "lambert", "--grid", "halfdiff3:4", "-o", "-"]),
        ),
        (
            "convert",
            v(&[
                "convert",
                &t,
                "--grid",
                "halfdiff3:4",
                "--format",
                "exr",
                "-o",
                "-",
            ]),
        ),
        (
            "pack",
            v(&[
                "pack",
                "lambert",
                "--grid",
                "halfdiff3:4",
                "--samples",
                "256",
                "-o",
                &o("p.bpk"),
                // Quiet by default (issue #22): the JSON report is what goes to stdout.
                "--json",
            ]),
        ),
        (
            "compress",
            v(&[
                "compress",
                &t,
                "--codec",
                "uniform:bits=10,level=3",
                "--samples",
                "256",
                "-o",
                &o("c.bpk"),
                "--json",
            ]),
        ),
        ("eval", v(&["eval", &t, "--wi", "0,0,1", "--wo", "0.3,0,1"])),
        ("inspect", v(&["inspect", &t])),
        ("inspect --json", v(&["inspect", "--json", &t])),
        (
            "check",
            v(&[
                "check",
                &t,
                "--against",
                "ggx:alpha=0.3,fresnel=au",
                "--samples",
                "256",
                "--uniform-only",
            ]),
        ),
        (
            "bench",
            v(&[
                "bench",
                "--lookup-only",
                "--runs",
                "1",
                "--pairs",
                "1000",
                "--threads",
                "1",
                "--json",
            ]),
        ),
        ("props", v(&["props", "lambert", "--samples", "256"])),
        ("models", v(&["models"])),
    ]
}

fn stderr_of(out: &Output) -> String {
    String::from_utf8_lossy(&out.stderr).into_owned()
}

#[test]
fn stdout_on_a_full_disk_is_exit_1_with_one_message() {
    let dir = tempfile::tempdir().unwrap();
    make_inputs(dir.path());
    let mut cases = commands(dir.path());
    cases.push(("eval stream", vec![]));
    for (name, args) in cases {
        let full = std::fs::OpenOptions::new()
            .write(true)
            .open("/dev/full")
            .unwrap();
        let out = if args.is_empty() {
            // A stream of pairs on stdin: rows are written as lines come in.
            brdfpack()
                .arg("eval")
                .arg(dir.path().join("t.bpk"))
                .stdin(std::fs::File::open(dir.path().join("pairs.txt")).unwrap())
                .stdout(full)
                .output()
                .unwrap()
        } else {
            brdfpack().args(&args).stdout(full).output().unwrap()
        };
        let err = stderr_of(&out);
        assert_eq!(out.status.code(), Some(1), "{name}: {err}");
        // Progress and notes go to stderr too; the error is the one `brdfpack:` line.
        let lines: Vec<&str> = err.lines().filter(|l| l.starts_with("brdfpack:")).collect();
        assert_eq!(
            lines,
            ["brdfpack: <stdout>: No space left on device (os error 28)"],
            "{name}: {err}"
        );
        assert!(!err.contains("panicked"), "{name}: {err}");
    }
}

#[test]
fn closed_stdout_pipe_ends_quietly() {
    let dir = tempfile::tempdir().unwrap();
    make_inputs(dir.path());
    for (name, args) in commands(dir.path()) {
        if name == "bench" {
            continue; // seconds of work before its first line; nothing new to learn here.
        }
        let mut child = brdfpack()
            .args(&args)
            .stdout(Stdio::piped())
            .stderr(Stdio::piped())
            .spawn()
            .unwrap();
        // The reader is gone before the first write: every write gets EPIPE.
        drop(child.stdout.take());
        let out = child.wait_with_output().unwrap();
        let err = stderr_of(&out);
        assert_eq!(out.status.code(), Some(0), "{name}: {err}");
        assert!(
            !err.contains("brdfpack:") && !err.contains("panicked"),
            "{name}: {err}"
        );
    }
}

/// `ulimit -f 16` (8 or 16 KiB, per shell) with SIGXFSZ ignored, so that the write returns
/// EFBIG instead of killing the process.
fn limited(cmd: &str) -> Output {
    Command::new("sh")
        .arg("-c")
        .arg(format!("ulimit -f 16 && trap '' XFSZ && exec {cmd}"))
        .output()
        .unwrap()
}

#[test]
fn file_size_limit_keeps_the_previous_file_and_leaves_no_temp() {
    let dir = tempfile::tempdir().unwrap();
    let target = dir.path().join("out.bpk");
    std::fs::write(&target, b"the previous file").unwrap();
    let bin = env!("CARGO_BIN_EXE_brdfpack");
    // ~170 KB: a GGX table on 24x24x48 cells in raw f32 with zstd, well over the limit.
    let out = limited(&format!(
        "'{bin}' tabulate ggx:alpha=0.3,fresnel=au --grid halfdiff3:24x24x48 \
         --codec zstd-f32:level=1 -o '{}'",
        target.display()
    ));
    let err = stderr_of(&out);
    assert_eq!(out.status.code(), Some(1), "{err}");
    assert_eq!(
        err.lines().collect::<Vec<_>>(),
        [format!(
            "brdfpack: {}: File too large (os error 27)",
            target.display()
        )],
    );
    assert_eq!(std::fs::read(&target).unwrap(), b"the previous file");
    let left: Vec<_> = std::fs::read_dir(dir.path())
        .unwrap()
        .map(|e| e.unwrap().file_name())
        .collect();
    assert_eq!(left, [std::ffi::OsString::from("out.bpk")]);

    // The same command under the limit writes the file (the failure above is the limit's).
    let small = limited(&format!(
        "'{bin}' tabulate lambert --grid halfdiff3:4 -o '{}'",
        target.display()
    ));
    assert!(small.status.success(), "{}", stderr_of(&small));
    assert!(std::fs::read(&target).unwrap().starts_with(b"\x89BPK"));
}
