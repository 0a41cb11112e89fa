//! Hostile files, output targets and interrupted runs (issue 20). Every case is a command a
//! careless user or an attacker could run; each must exit 0, 1 or 2 as documented (never 101
//! or 134), refuse up front what would exhaust memory, and never lose or corrupt an output.
//! docs/robustness.md lists every test here with the behaviour it pins down.
#![cfg(target_os = "linux")]

mod common;

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

/// The binary under test: this build's, or `BRDFPACK_BIN` (to run the tests against another
/// build, e.g. the code before issue 20: docs/robustness.md).
static BIN: std::sync::LazyLock<String> = std::sync::LazyLock::new(|| {
    std::env::var("BRDFPACK_BIN").unwrap_or_else(|_| env!("CARGO_BIN_EXE_brdfpack").to_string())
});

fn brdfpack() -> Command {
    Command::new(&*BIN)
}

fn run(dir: &Path, args: &[&str]) -> Output {
    brdfpack().current_dir(dir).args(args).output().unwrap()
}

/// Runs the tool with its address space capped (`ulimit -v`, KiB), so that an allocation the
/// budget should have refused fails fast instead of swapping.
fn run_capped(dir: &Path, kib: u64, args: &[&str]) -> Output {
    let mut cmd = Command::new("sh");
    cmd.current_dir(dir)
        .arg("-c")
        .arg(format!("ulimit -v {kib} && exec \"$0\" \"$@\""))
        .arg(&*BIN)
        .args(args);
    cmd.output().unwrap()
}

fn stderr(o: &Output) -> String {
    String::from_utf8_lossy(&o.stderr).into_owned()
}

/// Asserts exit 2 with one `brdfpack:` line containing every `needles`.
fn assert_refused(o: &Output, needles: &[&str]) {
    let e = stderr(o);
    assert_eq!(o.status.code(), Some(2), "stderr: {e}");
    assert!(e.starts_with("brdfpack: "), "{e}");
    assert_eq!(e.lines().count(), 1, "{e}");
    for n in needles {
        assert!(e.contains(n), "missing {n:?} in: {e}");
    }
}

fn tabulate(dir: &Path, name: &str, spec: &str, grid: &str, extra: &[&str]) -> PathBuf {
    let p = dir.join(name);
    let mut args = vec!["tabulate", spec, "--grid", grid, "-o", name];
    args.extend_from_slice(extra);
    let o = run(dir, &args);
    assert!(o.status.success(), "{}", stderr(&o));
    p
}

/// A native file's sections (tag, payload), in order.
fn sections(bytes: &[u8]) -> Vec<([u8; 4], Vec<u8>)> {
    let count = u32::from_le_bytes(bytes[12..16].try_into().unwrap()) as usize;
    let mut pos = 20;
    let mut out = Vec::new();
    for _ in 0..count {
        let tag: [u8; 4] = bytes[pos..pos + 4].try_into().unwrap();
        let len = u64::from_le_bytes(bytes[pos + 4..pos + 12].try_into().unwrap()) as usize;
        out.push((tag, bytes[pos + 16..pos + 16 + len].to_vec()));
        pos += 16 + len;
    }
    out
}

/// A native file with valid checksums from its sections (the preamble copied from `like`).
fn assemble(like: &[u8], secs: &[([u8; 4], Vec<u8>)]) -> Vec<u8> {
    let mut out = like[..16].to_vec();
    out[12..16].copy_from_slice(&(secs.len() as u32).to_le_bytes());
    let pre = crc32fast::hash(&out);
    out.extend_from_slice(&pre.to_le_bytes());
    for (tag, p) in secs {
        out.extend_from_slice(tag);
        out.extend_from_slice(&(p.len() as u64).to_le_bytes());
        out.extend_from_slice(&crc32fast::hash(p).to_le_bytes());
        out.extend_from_slice(p);
    }
    out
}

/// A copy of the small native table `base` whose header is rewritten by `edit` (checksums
/// recomputed, so only the declared sizes lie).
fn lying_native(base: &[u8], edit: impl Fn(&mut serde_json::Value)) -> Vec<u8> {
    let mut secs = sections(base);
    // A compressed header (`HEAZ`) is edited as JSON and written back as a plain `HEAD`
    // (readers take either).
    if &secs[0].0 == b"HEAZ" {
        secs[0] = (*b"HEAD", zstd::decode_all(&secs[0].1[..]).unwrap());
    }
    let mut head: serde_json::Value = serde_json::from_slice(&secs[0].1).unwrap();
    edit(&mut head);
    secs[0].1 = serde_json::to_vec(&head).unwrap();
    assemble(base, &secs)
}

fn set_axes(h: &mut serde_json::Value, n: &[u64]) {
    for (a, &k) in h["grid"]["axes"].as_array_mut().unwrap().iter_mut().zip(n) {
        a["n"] = k.into();
    }
}

// ---------------------------------------------------------------------------------------
// 1. Aborts and memory/time bombs

#[test]
fn native_header_declaring_4096_channels_on_256_cubed_is_refused_with_its_size() {
    let dir = tempfile::tempdir().unwrap();
    let t = tabulate(dir.path(), "t.bpk", "lambert", "halfdiff3:4", &[]);
    let valid = brdfpack::grid::parse_grid_spec("halfdiff3:256")
        .unwrap()
        .geometric_mask()
        .iter()
        .filter(|v| **v)
        .count();
    let bomb = lying_native(&std::fs::read(t).unwrap(), |h| {
        set_axes(h, &[256, 256, 256]);
        let names: Vec<String> = (0..4096).map(|i| format!("c{i}")).collect();
        h["channels"] = serde_json::json!({ "names": names });
        // The valid-cell count of the geometric mask of 256³, so that the header is
        // consistent and only its size is hostile (with the small table's 42, the code before
        // issue 20 refused the file for the count, after building the mask; with the right
        // count it tried to allocate 256 GiB and aborted).
        h["valid_cells"] = valid.into();
    });
    std::fs::write(dir.path().join("bomb.bpk"), &bomb).unwrap();
    for cmd in [
        &["inspect", "bomb.bpk"][..],
        &["eval", "bomb.bpk", "--wi", "0,0,1", "--wo", "0,0,1"],
    ] {
        let o = run_capped(dir.path(), 1 << 20, cmd);
        assert_refused(&o, &["bomb.bpk", "needs about", "GiB", "--max-memory"]);
    }
}

#[test]
fn native_header_declaring_2_pow_31_cells_is_refused_before_the_mask() {
    let dir = tempfile::tempdir().unwrap();
    let t = tabulate(dir.path(), "t.bpk", "lambert", "halfdiff3:4", &[]);
    let bomb = lying_native(&std::fs::read(t).unwrap(), |h| {
        set_axes(h, &[1024, 1024, 2048])
    });
    std::fs::write(dir.path().join("bomb.bpk"), &bomb).unwrap();
    let start = std::time::Instant::now();
    let o = run_capped(dir.path(), 1 << 20, &["inspect", "bomb.bpk"]);
    assert_refused(&o, &["needs about", "2.0 GiB"]);
    assert!(start.elapsed().as_secs() < 5, "{:?}", start.elapsed());
}

/// A header's `horizon` is checked like the rest of its grid: on a spherical grid, with an
/// unknown value, or with a valid-cell count its mask does not give (a cut table declared
/// extended), the file is refused with exit 2, naming the file and what is wrong.
#[test]
fn a_header_horizon_is_checked_like_the_rest_of_its_grid() {
    let dir = tempfile::tempdir().unwrap();
    let hd = tabulate(dir.path(), "h.bpk", "lambert", "halfdiff3:4", &[]);
    let sp = tabulate(dir.path(), "s.bpk", "lambert", "spherical3:4", &[]);
    for (base, value, name, needle) in [
        (&sp, "extend", "a.bpk", "halfdiff3 and halfdiff4"),
        (&hd, "sideways", "b.bpk", "sideways"),
        (&hd, "extend", "c.bpk", "valid_cells"),
    ] {
        let bad = lying_native(&std::fs::read(base).unwrap(), |h| {
            h["grid"]["horizon"] = value.into()
        });
        std::fs::write(dir.path().join(name), &bad).unwrap();
        for cmd in [
            &["inspect", name][..],
            &["eval", name, "--wi", "0,0,1", "--wo", "0,0,1"],
        ] {
            assert_refused(&run(dir.path(), cmd), &[name, needle]);
        }
    }
}

#[test]
fn a_small_zstd_payload_that_expands_past_the_budget_is_refused() {
    let dir = tempfile::tempdir().unwrap();
    // 64×64×128 cells, 1 channel of zeros: 2 MiB of f32 in a few hundred bytes of zstd,
    // whose decoding (table + scratch, 5 bytes a cell each) needs 5 MiB.
    tabulate(
        dir.path(),
        "z.bpk",
        "lambert:albedo=0",
        "halfdiff3:64x64x128",
        &["--codec", "zstd-f32"],
    );
    let size = std::fs::metadata(dir.path().join("z.bpk")).unwrap().len();
    assert!(size < 4 << 10, "{size}");
    let o = run(dir.path(), &["--max-memory", "4M", "inspect", "z.bpk"]);
    assert_refused(&o, &["z.bpk", "needs about 5.0 MiB", "budget of 4.0 MiB"]);
    // The same file within a budget that holds it is read.
    let o = run(dir.path(), &["--max-memory", "64M", "inspect", "z.bpk"]);
    assert!(o.status.success(), "{}", stderr(&o));
}

#[test]
fn every_reader_checks_the_budget_before_decoding() {
    let dir = tempfile::tempdir().unwrap();
    tabulate(
        dir.path(),
        "t.exr",
        "ggx:alpha=0.3,fresnel=au",
        "halfdiff3:16",
        &["--format", "exr"],
    );
    tabulate(
        dir.path(),
        "t.binary",
        "ggx:alpha=0.3,fresnel=au",
        "merl",
        &["--format", "merl"],
    );
    for (f, what) in [("t.exr", "EXR pixels"), ("t.binary", "MERL data")] {
        let o = brdfpack()
            .current_dir(dir.path())
            .env(
                "BRDFPACK_MAX_MEMORY",
                if f == "t.exr" { "64K" } else { "36M" },
            )
            .args(["inspect", f])
            .output()
            .unwrap();
        assert_refused(&o, &[f, what, "needs about", "BRDFPACK_MAX_MEMORY"]);
    }
    let o = brdfpack()
        .env("BRDFPACK_MAX_MEMORY", "lots")
        .args(["models"])
        .output()
        .unwrap();
    assert_refused(&o, &["BRDFPACK_MAX_MEMORY=lots", "unknown unit"]);
}

#[test]
fn grids_and_counts_inside_the_limits_are_refused_up_front_when_too_big() {
    let dir = tempfile::tempdir().unwrap();
    let cases: &[(&[&str], &[&str])] = &[
        (
            &[
                "tabulate",
                "lambert",
                "--grid",
                "spherical4:215",
                "-o",
                "x.bpk",
            ],
            &["spherical4", "needs about"],
        ),
        (
            &[
                "convert",
                "lambert",
                "--grid",
                "spherical4:215",
                "-o",
                "x.bpk",
            ],
            &["needs about"],
        ),
        (
            &[
                "compress",
                "lambert",
                "--grid",
                "spherical4:215",
                "-o",
                "x.bpk",
            ],
            &["needs about"],
        ),
        (
            &["pack", "lambert", "--grid", "spherical4:215", "-o", "x.bpk"],
            &["needs about"],
        ),
        (
            &[
                "compress",
                "lambert",
                "--samples",
                "4000000000",
                "-o",
                "x.bpk",
            ],
            &["--samples 4000000000"],
        ),
        (
            &[
                "compress",
                "lambert",
                "--samples",
                "50000000",
                "-o",
                "x.bpk",
            ],
            &["--samples 50000000", "needs about"],
        ),
        (
            &["bench", "--lookup-only", "--pairs", "4000000000"],
            &["--pairs 4000000000"],
        ),
        (
            &["bench", "--lookup-only", "--threads", "100000"],
            &["--threads 100000", "1024"],
        ),
    ];
    for (args, needles) in cases {
        let start = std::time::Instant::now();
        let o = run_capped(dir.path(), 1 << 20, args);
        assert_refused(&o, needles);
        assert!(
            start.elapsed().as_secs() < 5,
            "{args:?}: {:?}",
            start.elapsed()
        );
        assert!(!dir.path().join("x.bpk").exists(), "{args:?}");
    }
}

#[test]
fn endless_and_random_devices_are_refused_after_a_sniff() {
    let dir = tempfile::tempdir().unwrap();
    for (args, needles) in [
        (
            &["inspect", "/dev/zero"][..],
            &["/dev/zero", "first bytes"][..],
        ),
        (
            &["eval", "/dev/urandom", "--wi", "0,0,1", "--wo", "0,0,1"],
            &["/dev/urandom", "first bytes"],
        ),
        (&["inspect", "/tmp"], &["/tmp", "directory"]),
    ] {
        let o = run_capped(dir.path(), 1 << 19, args);
        assert_refused(&o, needles);
    }
}

// ---------------------------------------------------------------------------------------
// 2. Output targets

fn file_bytes_of_small_table(dir: &Path) -> Vec<u8> {
    std::fs::read(tabulate(dir, "ref.bpk", "lambert", "halfdiff3:4", &[])).unwrap()
}

/// `tabulate lambert --grid halfdiff3:4 --format native -o OUTPUT` in `dir`: the small table
/// the output-target tests write (the same bytes as `file_bytes_of_small_table`'s `.bpk`).
fn tabulate_small_to(dir: &Path, output: &str) -> Output {
    run(
        dir,
        &[
            "tabulate",
            "lambert",
            "--grid",
            "halfdiff3:4",
            "--format",
            "native",
            "-o",
            output,
        ],
    )
}

fn temps_in(dir: &Path) -> Vec<String> {
    std::fs::read_dir(dir)
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .filter(|n| n.ends_with(".tmp"))
        .collect()
}

#[test]
fn a_fifo_target_is_written_in_place_and_stays_a_fifo() {
    use std::os::unix::fs::FileTypeExt;
    let dir = tempfile::tempdir().unwrap();
    let want = file_bytes_of_small_table(dir.path());
    assert!(
        Command::new("mkfifo")
            .arg(dir.path().join("pipe"))
            .status()
            .unwrap()
            .success()
    );
    let o = Command::new("sh")
        .current_dir(dir.path())
        .arg("-c")
        .arg("timeout 20 cat pipe > got & r=$!; \"$0\" tabulate lambert --grid halfdiff3:4 --format native -o pipe; s=$?; wait $r; exit $s")
        .arg(&*BIN)
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", stderr(&o));
    assert!(
        std::fs::metadata(dir.path().join("pipe"))
            .unwrap()
            .file_type()
            .is_fifo()
    );
    assert_eq!(std::fs::read(dir.path().join("got")).unwrap(), want);
}

#[test]
fn descriptor_names_are_written_in_place() {
    let dir = tempfile::tempdir().unwrap();
    let want = file_bytes_of_small_table(dir.path());
    for target in ["/dev/fd/1", "/proc/self/fd/1"] {
        let o = tabulate_small_to(dir.path(), target);
        assert!(o.status.success(), "{target}: {}", stderr(&o));
        assert_eq!(o.stdout, want, "{target}");
    }
    // stdout redirected to a file: written through the descriptor, the file is not replaced.
    let f = std::fs::File::create(dir.path().join("redirected")).unwrap();
    let o = brdfpack()
        .current_dir(dir.path())
        .args([
            "tabulate",
            "lambert",
            "--grid",
            "halfdiff3:4",
            "--format",
            "native",
            "-o",
            "/dev/fd/1",
        ])
        .stdout(f)
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", stderr(&o));
    assert_eq!(std::fs::read(dir.path().join("redirected")).unwrap(), want);
    assert!(temps_in(dir.path()).is_empty());
}

#[test]
fn symlinks_are_followed_and_permissions_kept() {
    use std::os::unix::fs::PermissionsExt;
    let dir = tempfile::tempdir().unwrap();
    let want = file_bytes_of_small_table(dir.path());
    let real = dir.path().join("real.bpk");
    std::fs::write(&real, b"old").unwrap();
    std::fs::set_permissions(&real, std::fs::Permissions::from_mode(0o600)).unwrap();
    std::os::unix::fs::symlink("real.bpk", dir.path().join("link.bpk")).unwrap();
    let o = tabulate_small_to(dir.path(), "link.bpk");
    assert!(o.status.success(), "{}", stderr(&o));
    let link = std::fs::symlink_metadata(dir.path().join("link.bpk")).unwrap();
    assert!(link.file_type().is_symlink());
    assert_eq!(std::fs::read(&real).unwrap(), want);
    assert_eq!(
        std::fs::metadata(&real).unwrap().permissions().mode() & 0o777,
        0o600
    );
    // A dangling link creates its target.
    std::os::unix::fs::symlink("new.bpk", dir.path().join("dangling.bpk")).unwrap();
    let o = tabulate_small_to(dir.path(), "dangling.bpk");
    assert!(o.status.success(), "{}", stderr(&o));
    assert_eq!(std::fs::read(dir.path().join("new.bpk")).unwrap(), want);
    assert!(temps_in(dir.path()).is_empty());
}

#[test]
fn directories_and_long_names_as_outputs() {
    let dir = tempfile::tempdir().unwrap();
    std::fs::create_dir(dir.path().join("somedir")).unwrap();
    let o = tabulate_small_to(dir.path(), "somedir");
    assert_refused(&o, &["somedir", "is a directory"]);
    let o = tabulate_small_to(dir.path(), "newdir/");
    assert_refused(&o, &["newdir/", "ends with /"]);
    // A 250-byte name is a valid name; its temporary name must fit too.
    let long = format!("{}.bpk", "n".repeat(246));
    let o = run(
        dir.path(),
        &["tabulate", "lambert", "--grid", "halfdiff3:4", "-o", &long],
    );
    assert!(o.status.success(), "{}", stderr(&o));
    assert!(dir.path().join(&long).is_file());
    let too_long = format!("{}.bpk", "n".repeat(252));
    let o = run(
        dir.path(),
        &[
            "tabulate",
            "lambert",
            "--grid",
            "halfdiff3:4",
            "-o",
            &too_long,
        ],
    );
    assert_refused(&o, &["File name too long"]);
}

#[test]
fn a_signal_during_the_write_removes_the_temporary_file() {
    use std::os::unix::process::ExitStatusExt;
    let dir = tempfile::tempdir().unwrap();
    std::fs::write(dir.path().join("out.bpk"), b"previous").unwrap();
    // SIGXFSZ (default action: terminate) arrives mid-write at the file-size limit, like
    // SIGINT/SIGTERM/SIGHUP would; the handler removes the temporary file and re-raises.
    let o = Command::new("sh")
        .current_dir(dir.path())
        .arg("-c")
        .arg("ulimit -f 16 && exec \"$0\" tabulate ggx:alpha=0.3,fresnel=au --grid halfdiff3:24x24x48 --codec zstd-f32:level=1 -o out.bpk")
        .arg(&*BIN)
        .output()
        .unwrap();
    assert_eq!(o.status.signal(), Some(25), "{:?} {}", o.status, stderr(&o));
    assert_eq!(
        std::fs::read(dir.path().join("out.bpk")).unwrap(),
        b"previous"
    );
    assert!(
        temps_in(dir.path()).is_empty(),
        "{:?}",
        temps_in(dir.path())
    );
}

#[test]
fn leftover_temporary_files_never_block_a_run() {
    let dir = tempfile::tempdir().unwrap();
    // A container where the tool is PID 1 on every run: leftovers of killed runs in the
    // old naming (`.NAME.PID-N.tmp`) used to make every later run fail with "File exists".
    let pid1 = Command::new("unshare")
        .args(["--pid", "--fork", "true"])
        .status();
    if !pid1.is_ok_and(|s| s.success()) {
        println!("skipped: `unshare --pid --fork` is not available (needs root)");
        return;
    }
    std::fs::write(dir.path().join(".out.bpk.1-0.tmp"), b"x").unwrap();
    std::fs::write(dir.path().join(".out.bpk.2-0.tmp"), b"x").unwrap();
    let o = Command::new("unshare")
        .current_dir(dir.path())
        .args([
            "--pid",
            "--fork",
            BIN.as_str(),
            "tabulate",
            "lambert",
            "--grid",
            "halfdiff3:4",
            "-o",
            "out.bpk",
        ])
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", stderr(&o));
    assert!(dir.path().join("out.bpk").is_file());
    assert_eq!(temps_in(dir.path()).len(), 2);
}

#[test]
fn a_failed_bound_never_replaces_the_output() {
    let dir = tempfile::tempdir().unwrap();
    std::fs::write(dir.path().join("out.bpk"), b"previous").unwrap();
    let o = run(
        dir.path(),
        &[
            "pack",
            "ggx:alpha=0.3",
            "--grid",
            "halfdiff3:8",
            "--codec",
            "f16",
            "--max-rmse",
            "1e-30",
            "-o",
            "out.bpk",
        ],
    );
    assert_eq!(o.status.code(), Some(1), "{}", stderr(&o));
    assert!(stderr(&o).contains("not written"), "{}", stderr(&o));
    assert_eq!(
        std::fs::read(dir.path().join("out.bpk")).unwrap(),
        b"previous"
    );
    assert!(temps_in(dir.path()).is_empty());
}

// ---------------------------------------------------------------------------------------
// 3. The stored domain

/// Counts the MERL invalid marker (a negative stored value) in the red channel.
fn merl_invalid_bins(bytes: &[u8]) -> usize {
    let n: usize = (0..3)
        .map(|k| i32::from_le_bytes(bytes[4 * k..4 * k + 4].try_into().unwrap()) as usize)
        .product();
    bytes[12..12 + 8 * n]
        .chunks_exact(8)
        .filter(|b| f64::from_le_bytes((*b).try_into().unwrap()) < 0.0)
        .count()
}

#[test]
fn cells_beyond_theta_max_are_invalid_after_regridding_in_every_format() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    tabulate(
        d,
        "t60.bpk",
        "ggx:alpha=0.3,fresnel=au",
        "halfdiff3:16,theta-max=60",
        &[],
    );
    tabulate(
        d,
        "t90.bpk",
        "ggx:alpha=0.3,fresnel=au",
        "halfdiff3:16",
        &[],
    );
    for t in ["t60", "t90"] {
        let o = run(
            d,
            &[
                "convert",
                &format!("{t}.bpk"),
                "--grid",
                "merl",
                "--format",
                "merl",
                "-o",
                &format!("{t}.binary"),
            ],
        );
        assert!(o.status.success(), "{}", stderr(&o));
        let o = run(
            d,
            &[
                "convert",
                &format!("{t}.bpk"),
                "--grid",
                "halfdiff3:16",
                "-o",
                &format!("{t}-full.bpk"),
            ],
        );
        assert!(o.status.success(), "{}", stderr(&o));
    }
    let full = merl_invalid_bins(&std::fs::read(d.join("t90.binary")).unwrap());
    let limited = merl_invalid_bins(&std::fs::read(d.join("t60.binary")).unwrap());
    // The hemisphere's horizon bins are invalid either way; beyond 60° adds ~515k more.
    assert!(limited > full + 400_000, "{limited} vs {full}");
    // A full-hemisphere native grid keeps the beyond-θmax cells invalid too.
    let valid_of = |f: &str| -> u64 {
        let o = run(d, &["inspect", f, "--json"]);
        assert!(o.status.success(), "{}", stderr(&o));
        let v: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
        v["valid_cells"].as_u64().unwrap_or_else(|| panic!("{v}"))
    };
    assert!(valid_of("t60-full.bpk") < valid_of("t90-full.bpk") * 3 / 4);
}

#[test]
fn eval_beyond_theta_max_is_refused_unless_asked() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    tabulate(
        d,
        "t60.bpk",
        "ggx:alpha=0.3,fresnel=au",
        "halfdiff3:16,theta-max=60",
        &[],
    );
    let o = run(
        d,
        &["eval", "t60.bpk", "--wi-deg", "70,0", "--wo-deg", "10,0"],
    );
    assert_refused(
        &o,
        &["outside the stored domain θ ≤ 60°", "--outside-domain-zero"],
    );
    assert!(o.stdout.is_empty());
    let o = run(
        d,
        &[
            "eval",
            "t60.bpk",
            "--wi-deg",
            "70,0",
            "--wo-deg",
            "10,0",
            "--outside-domain-zero",
        ],
    );
    assert_eq!(String::from_utf8_lossy(&o.stdout), "0.0 0.0 0.0\n");
    let o = run(
        d,
        &["eval", "t60.bpk", "--wi-deg", "30,0", "--wo-deg", "10,0"],
    );
    assert!(o.status.success());
    let v: Vec<f64> = String::from_utf8_lossy(&o.stdout)
        .split_whitespace()
        .map(|x| x.parse().unwrap())
        .collect();
    assert!(v.iter().all(|&x| x > 0.01), "{v:?}");
    let o = run(
        d,
        &["check", "t60.bpk", "--against", "ggx:alpha=0.3,fresnel=au"],
    );
    let out = String::from_utf8_lossy(&o.stdout);
    assert!(out.contains("domain: θi, θo ≤ 60° only"), "{out}");
}

// ---------------------------------------------------------------------------------------
// 4. Names, repeated keys and text from files

#[test]
fn a_model_spec_is_never_shadowed_by_a_file_of_that_name() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    // A table of albedo 0.2 named `lambert` in the working directory.
    tabulate(
        d,
        "lambert",
        "lambert:albedo=0.2",
        "halfdiff3:4",
        &["--format", "native"],
    );
    let value = |src: &str| -> f64 {
        let o = run(d, &["eval", src, "--wi", "0,0,1", "--wo", "0,0,1"]);
        assert!(o.status.success(), "{}", stderr(&o));
        String::from_utf8_lossy(&o.stdout).trim().parse().unwrap()
    };
    let pi = std::f64::consts::PI;
    assert!(
        (value("lambert") - 0.5 / pi).abs() < 1e-12,
        "the model (default albedo 0.5)"
    );
    assert!((value("./lambert") - 0.2 / pi).abs() < 1e-6, "the file");
}

/// A mistaken model spec says what is wrong with it, even when a parameter holds a `/`
/// (per-channel values); a missing file named like one is still "no such file".
#[test]
fn a_model_spec_with_a_slash_is_not_taken_for_a_missing_file() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let o = run(
        d,
        &[
            "eval",
            "lafortune:lobes=0.9/0.9/1.0/20",
            "--wi",
            "0,0,1",
            "--wo",
            "0,0,1",
        ],
    );
    assert_eq!(o.status.code(), Some(2));
    let e = stderr(&o);
    assert!(!e.contains("no such file"), "{e}");
    assert!(e.contains("lobes") || e.contains("lafortune"), "{e}");
    let o = run(
        d,
        &["eval", "tables/gold.bpk", "--wi", "0,0,1", "--wo", "0,0,1"],
    );
    assert_eq!(o.status.code(), Some(2));
    assert!(stderr(&o).contains("no such file"), "{}", stderr(&o));
}

#[test]
fn repeated_keys_are_refused() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let o = run(
        d,
        &[
            "eval",
            r#"{"model":"lambert","albedo":0.5,"albedo":0.9}"#,
            "--wi",
            "0,0,1",
            "--wo",
            "0,0,1",
        ],
    );
    assert_refused(&o, &["\"albedo\" appears twice"]);
    std::fs::write(
        d.join("m.json"),
        r#"{"model":"lambert","albedo":0.5,"albedo":0.9}"#,
    )
    .unwrap();
    let o = run(d, &["eval", "@m.json", "--wi", "0,0,1", "--wo", "0,0,1"]);
    assert_refused(&o, &["m.json", "appears twice"]);
    let o = run(
        d,
        &[
            "tabulate",
            "lambert",
            "--grid",
            "halfdiff3:4",
            "--codec",
            "f16:curve=log,curve=linear",
            "-o",
            "a.bpk",
        ],
    );
    assert_refused(&o, &["\"curve\" is given twice"]);
    let o = run(
        d,
        &[
            "pack",
            "lambert",
            "--grid",
            "halfdiff3:4",
            "--max-error",
            "log_rmse=0.1,log_rmse=0.2",
            "-o",
            "a.bpk",
        ],
    );
    assert_refused(&o, &["log_rmse is given twice"]);
    // A native header with a repeated key (checksums valid).
    let t = tabulate(d, "t.bpk", "lambert", "halfdiff3:4", &[]);
    let base = std::fs::read(t).unwrap();
    let mut secs = sections(&base);
    if &secs[0].0 == b"HEAZ" {
        secs[0] = (*b"HEAD", zstd::decode_all(&secs[0].1[..]).unwrap());
    }
    let head = String::from_utf8(secs[0].1.clone()).unwrap();
    secs[0].1 = head.replacen('{', r#"{"valid_cells":1,"#, 1).into_bytes();
    std::fs::write(d.join("dup.bpk"), assemble(&base, &secs)).unwrap();
    let o = run(d, &["inspect", "dup.bpk"]);
    assert_refused(
        &o,
        &["dup.bpk", "header JSON", "\"valid_cells\" appears twice"],
    );
    assert!(!d.join("a.bpk").exists());
}

#[test]
fn terminal_controls_in_files_are_escaped() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let t = tabulate(d, "t.bpk", "lambert", "halfdiff3:4", &[]);
    let base = std::fs::read(t).unwrap();
    let bomb = lying_native(&base, |h| {
        h["provenance"]["source"] = "\u{1b}[2J\u{1b}[Hverified: OK\r".into();
        h["channels"] = serde_json::json!({ "names": ["\u{1b}]0;pwned\u{7}"] });
    });
    std::fs::write(d.join("esc.bpk"), bomb).unwrap();
    for args in [
        &["inspect", "esc.bpk"][..],
        &[
            "eval", "esc.bpk", "--format", "csv", "--wi", "0,0,1", "--wo", "0,0,1",
        ],
    ] {
        let o = run(d, args);
        assert!(o.status.success(), "{args:?}: {}", stderr(&o));
        let out = String::from_utf8_lossy(&o.stdout);
        assert!(
            !out.contains('\u{1b}') && !out.contains('\r') && !out.contains('\u{7}'),
            "{out:?}"
        );
        assert!(out.contains("\\u{1b}"), "{out}");
    }
    // An error message quoting a huge spec stays one short line.
    let spec = format!(
        "{{\"model\":\"lambert\",\"x\":\"{}\u{1b}[2J\"}}",
        "a".repeat(110_000)
    );
    let o = run(d, &["eval", &spec, "--wi", "0,0,1", "--wo", "0,0,1"]);
    assert_eq!(o.status.code(), Some(2));
    let e = stderr(&o);
    assert!(e.len() < 3000 && !e.contains('\u{1b}'), "{} bytes", e.len());
}

#[test]
fn eval_of_stdin_needs_its_pair_on_the_command_line() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let t = tabulate(d, "t.bpk", "lambert:albedo=0.5", "halfdiff3:4", &[]);
    let o = brdfpack()
        .args(["eval", "-"])
        .stdin(std::fs::File::open(&t).unwrap())
        .output()
        .unwrap();
    assert_refused(&o, &["eval -", "--wi"]);
    let o = brdfpack()
        .args(["eval", "-", "--wi", "0,0,1", "--wo", "0,0,1"])
        .stdin(std::fs::File::open(&t).unwrap())
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", stderr(&o));
    let v: f64 = String::from_utf8_lossy(&o.stdout).trim().parse().unwrap();
    assert!((v - 0.5 / std::f64::consts::PI).abs() < 1e-6, "{v}");
}

#[test]
fn input_at_fault_exits_2() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    // Lafortune lobes whose values overflow f32 storage.
    let spec = r#"{"model":"lafortune","lobes":[{"cx":0,"cy":0,"cz":100,"n":20,"albedo":1e6}]}"#;
    let o = run(
        d,
        &["tabulate", spec, "--grid", "halfdiff3:4", "-o", "x.bpk"],
    );
    assert_refused(&o, &["f32 storage cannot hold", "lafortune", "e45 at cell"]);
    // The value in short scientific form (it printed 47 digits).
    assert!(!has_long_number(&stderr(&o), 20), "{}", stderr(&o));
    assert!(!d.join("x.bpk").exists());
    // Every command that stores the model's values refuses it the same way.
    for args in [
        vec!["convert", spec, "--grid", "halfdiff3:4", "-o", "x.bpk"],
        vec![
            "compress",
            spec,
            "--grid",
            "halfdiff3:4",
            "--codec",
            "lossless",
            "-o",
            "x.bpk",
        ],
        vec![
            "pack",
            spec,
            "--grid",
            "halfdiff3:4",
            "--codec",
            "lossless",
            "-o",
            "x.bpk",
        ],
    ] {
        let o = run(d, &args);
        assert_refused(&o, &["f32 storage cannot hold", "e45 at cell"]);
        assert!(!d.join("x.bpk").exists());
    }
}

#[test]
fn rgb_is_never_compared_with_spectral_channel_by_channel() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    tabulate(
        d,
        "rgb.bpk",
        r#"{"model":"lambert","albedo":[0.5,0.5,0.5]}"#,
        "halfdiff3:4",
        &[],
    );
    let spectral = r#"{"model":"lambert","albedo":[0.5,0.5,0.5],"wavelengths_nm":[450,550,650]}"#;
    let o = run(d, &["check", "rgb.bpk", "--against", spectral]);
    assert_refused(
        &o,
        &[
            "not spectral (R,G,B)",
            "spectral at [450.0, 550.0, 650.0] nm",
            "--to-rgb",
        ],
    );
}

/// The byte offset and value count of the float32 field `name` of an RGL tensor file.
fn rgl_field(bytes: &[u8], name: &str) -> (usize, usize) {
    let n = u32::from_le_bytes(bytes[14..18].try_into().unwrap()) as usize;
    let mut pos = 18;
    for _ in 0..n {
        let nl = u16::from_le_bytes(bytes[pos..pos + 2].try_into().unwrap()) as usize;
        let field = &bytes[pos + 2..pos + 2 + nl];
        pos += 2 + nl;
        let nd = u16::from_le_bytes(bytes[pos..pos + 2].try_into().unwrap()) as usize;
        pos += 3;
        let offset = u64::from_le_bytes(bytes[pos..pos + 8].try_into().unwrap()) as usize;
        pos += 8;
        let mut count = 1;
        for _ in 0..nd {
            count *= u64::from_le_bytes(bytes[pos..pos + 8].try_into().unwrap()) as usize;
            pos += 8;
        }
        if field == name.as_bytes() {
            return (offset, count);
        }
    }
    panic!("no field {name}");
}

/// `fixtures/rgl/tiny.bsdf` with every value of the float32 field `name` set to `value`.
fn rgl_with(name: &str, value: f32) -> Vec<u8> {
    let mut b = std::fs::read(Path::new(env!("CARGO_MANIFEST_DIR")).join("fixtures/rgl/tiny.bsdf"))
        .unwrap();
    let (offset, count) = rgl_field(&b, name);
    for k in 0..count {
        b[offset + 4 * k..offset + 4 * k + 4].copy_from_slice(&value.to_le_bytes());
    }
    b
}

/// A run of `n` or more digits: a number printed in full instead of in short form.
fn has_long_number(s: &str, n: usize) -> bool {
    s.split(|c: char| !c.is_ascii_digit()).any(|w| w.len() >= n)
}

#[test]
fn rgl_values_beyond_f32_are_refused_naming_the_field() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    // Used to be read, then: props exit 1 with 39-digit albedos, tabulate a 40-digit value.
    for (name, field, value, shown) in [
        ("sigma.bsdf", "sigma", 1e-40f32, "1e-40"),
        ("ndf.bsdf", "ndf", 3e38, "3e38"),
        ("rgb.bsdf", "rgb", 3e38, "3e38"),
    ] {
        std::fs::write(d.join(name), rgl_with(field, value)).unwrap();
        for args in [
            vec!["inspect", name],
            vec!["eval", name, "--wi", "0,0,1", "--wo", "0,0,1"],
            vec!["props", name, "--samples", "100"],
            vec![
                "tabulate",
                name,
                "--grid",
                "halfdiff3:4",
                "--allow-nonreciprocal",
                "-o",
                "x.bpk",
            ],
        ] {
            let o = run(d, &args);
            assert_refused(&o, &[name, &format!("field `{field}`"), shown]);
            assert!(!has_long_number(&stderr(&o), 20), "{}", stderr(&o));
            assert!(o.stdout.is_empty());
        }
        assert!(!d.join("x.bpk").exists());
    }
    // A subnormal σ anywhere, even with ordinary ndf and colours.
    let mut b = std::fs::read(Path::new(env!("CARGO_MANIFEST_DIR")).join("fixtures/rgl/tiny.bsdf"))
        .unwrap();
    let (offset, count) = rgl_field(&b, "sigma");
    b[offset + 4 * (count - 1)..offset + 4 * count].copy_from_slice(&1e-39f32.to_le_bytes());
    std::fs::write(d.join("one.bsdf"), &b).unwrap();
    let o = run(d, &["inspect", "one.bsdf"]);
    assert_refused(
        &o,
        &["field `sigma`", &format!("value #{} is 1e-39", count - 1)],
    );
    // Large but storable values stay readable.
    std::fs::write(d.join("big.bsdf"), rgl_with("rgb", 1e20)).unwrap();
    let o = run(d, &["inspect", "big.bsdf"]);
    assert!(o.status.success(), "{}", stderr(&o));
}

#[test]
fn props_reports_non_physical_estimates_plainly() {
    use brdfpack::codec::CodecSpec;
    use brdfpack::table::Table;
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    // A Lambert table with one spike of 1e30 between the quadrature's nodes: the estimate
    // and its error are both huge (was: "max albedo 4735 ... conserves", exit 0).
    let base = tabulate(d, "flat.bpk", "lambert", "halfdiff3:8x8x16", &[]);
    let t = brdfpack::io::native::from_bytes(&std::fs::read(&base).unwrap(), &base).unwrap();
    let mut data = t.data().to_vec();
    let spike = t.valid().iter().position(|&v| v).unwrap() + 300;
    assert!(t.valid()[spike]);
    data[spike] = 1e30;
    let spiked = Table::new(
        t.grid().clone(),
        t.channels().clone(),
        t.provenance().clone(),
        data,
        t.valid().to_vec(),
    )
    .unwrap();
    let bytes = brdfpack::io::native::to_bytes(&spiked, &CodecSpec::ZstdF32 { level: 1 }).unwrap();
    std::fs::write(d.join("spike.bpk"), bytes).unwrap();

    let o = run(d, &["props", "spike.bpk", "--samples", "1000"]);
    let text = String::from_utf8_lossy(&o.stdout);
    assert_eq!(o.status.code(), Some(1), "{text}{}", stderr(&o));
    let energy = text.lines().find(|l| l.starts_with("energy")).unwrap();
    assert!(!energy.contains("conserves"), "{energy}");
    assert!(
        energy.contains("EXCEEDS 1") || energy.contains("UNRESOLVED"),
        "{energy}"
    );
    assert!(!has_long_number(&text, 12), "{text}");
    assert!(text.contains("verdict      FAIL"), "{text}");

    let o = run(d, &["props", "spike.bpk", "--samples", "1000", "--json"]);
    assert_eq!(o.status.code(), Some(1), "{}", stderr(&o));
    let json = String::from_utf8(o.stdout).unwrap();
    assert!(!json.contains("null"), "{json}");
    let v: serde_json::Value = serde_json::from_str(&json).unwrap();
    assert_eq!(v["energy"]["conserves"], false);
    let verdict = v["energy"]["verdict"].as_str().unwrap();
    assert!(["exceeds", "unresolved"].contains(&verdict), "{verdict}");
    assert!(v["energy"]["max_albedo"].as_f64().unwrap() > 1.0);

    // The unspiked table still conserves, as before.
    let o = run(d, &["props", "flat.bpk", "--samples", "1000", "--json"]);
    assert_eq!(o.status.code(), Some(0), "{}", stderr(&o));
    let v: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    assert_eq!(v["energy"]["verdict"], "conserves");
}

#[test]
fn rgl_descriptions_are_escaped() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let mut b = std::fs::read(Path::new(env!("CARGO_MANIFEST_DIR")).join("fixtures/rgl/tiny.bsdf"))
        .unwrap();
    let old = b"brdfpack synthetic tiny RGL material";
    let at = b.windows(old.len()).position(|w| w == old).unwrap();
    let mut bomb = b"\x1b[2J\x1b]0;pwned\x07verified: OK\r".to_vec();
    bomb.resize(old.len(), b' ');
    b[at..at + old.len()].copy_from_slice(&bomb);
    std::fs::write(d.join("esc.bsdf"), &b).unwrap();
    for args in [
        &["inspect", "esc.bsdf"][..],
        &["props", "esc.bsdf", "--samples", "10"],
        &[
            "tabulate",
            "esc.bsdf",
            "--grid",
            "halfdiff3:4",
            "--allow-nonreciprocal",
            "-o",
            "-",
        ],
    ] {
        let o = run(d, args);
        // props may fail a property (exit 1); the text is what matters here.
        assert!(
            matches!(o.status.code(), Some(0 | 1)),
            "{args:?}: {}",
            stderr(&o)
        );
        let text = format!("{}{}", String::from_utf8_lossy(&o.stdout), stderr(&o));
        if args[0] != "tabulate" {
            assert!(text.contains("\\u{1b}"), "{args:?}: {text}");
            assert!(!text.contains('\u{1b}') && !text.contains('\u{7}') && !text.contains('\r'));
        } else {
            // The binary table carries the description in its header; stderr is clean.
            assert!(!stderr(&o).contains('\u{1b}'));
        }
    }
}

#[test]
fn device_outputs_stay_devices() {
    use std::os::unix::fs::FileTypeExt;
    let dir = tempfile::tempdir().unwrap();
    let want = file_bytes_of_small_table(dir.path());
    // As root, `-o /dev/null` replaced the device node with a regular file.
    let o = tabulate_small_to(dir.path(), "/dev/null");
    assert!(o.status.success(), "{}", stderr(&o));
    assert!(
        std::fs::metadata("/dev/null")
            .unwrap()
            .file_type()
            .is_char_device()
    );
    // `/dev/stdout` (a symlink to /proc/self/fd/1) is written through, not replaced.
    let o = tabulate_small_to(dir.path(), "/dev/stdout");
    assert!(o.status.success(), "{}", stderr(&o));
    assert_eq!(o.stdout, want);
    assert!(
        std::fs::symlink_metadata("/dev/stdout")
            .unwrap()
            .file_type()
            .is_symlink()
    );
}

#[test]
fn binary_output_to_a_terminal_needs_force() {
    // `script` gives the command a pseudo-terminal as stdout.
    if Command::new("script").arg("--version").output().is_err() {
        println!("skipped: no `script` to allocate a pseudo-terminal");
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    let tty = |extra: &str| {
        Command::new("script")
            .current_dir(dir.path())
            .args(["-qec"])
            .arg(format!(
                "{} tabulate lambert --grid halfdiff3:4 -o - {extra}; echo \" exit=$?\"",
                *BIN
            ))
            .arg("/dev/null")
            .stdin(std::process::Stdio::null())
            .output()
            .unwrap()
    };
    let o = tty("");
    let text = String::from_utf8_lossy(&o.stdout);
    assert!(text.contains("exit=2"), "{text}");
    assert!(
        text.contains("brdfpack:") && text.contains("terminal"),
        "{text}"
    );
    assert!(!text.contains("BPK"), "{text}");
    let o = tty("--force-terminal");
    let text = String::from_utf8_lossy(&o.stdout);
    assert!(text.contains("exit=0"), "{text}");
}

#[test]
fn thousands_of_spectral_channels_are_refused_up_front() {
    let dir = tempfile::tempdir().unwrap();
    let n = 4096;
    let wl: Vec<String> = (0..n)
        .map(|i| format!("{}", 380.0 + i as f64 * 0.1))
        .collect();
    let albedo: Vec<String> = (0..n).map(|_| "0.5".to_string()).collect();
    let spec = format!(
        r#"{{"model":"lambert","albedo":[{}],"wavelengths_nm":[{}]}}"#,
        albedo.join(","),
        wl.join(",")
    );
    for cmd in ["tabulate", "convert", "compress"] {
        let o = run_capped(
            dir.path(),
            1 << 20,
            &[cmd, &spec, "--grid", "merl", "-o", "x.bpk"],
        );
        assert_refused(&o, &["4096 channel", "needs about"]);
        assert!(!dir.path().join("x.bpk").exists());
    }
}

/// Peak resident memory (KiB) of a command run with environment variables `env` set, from
/// wait4's rusage, and its exit status.
// The child is reaped by wait4 (which std's `wait` cannot do: it drops the rusage).
#[allow(clippy::zombie_processes)]
fn peak_rss_kib_with(dir: &Path, env: &[(&str, &str)], args: &[&str]) -> (i32, i64) {
    let child = brdfpack()
        .current_dir(dir)
        .envs(env.iter().copied())
        .args(args)
        .stdout(std::process::Stdio::null())
        .stderr(std::process::Stdio::null())
        .spawn()
        .unwrap();
    let mut status = 0;
    // SAFETY: an all-zero rusage is valid; wait4 reaps the child we own (std never waits
    // for it afterwards: `child` is only dropped).
    let mut usage: libc::rusage = unsafe { std::mem::zeroed() };
    let pid = unsafe { libc::wait4(child.id() as i32, &mut status, 0, &mut usage) };
    assert_eq!(pid, child.id() as i32);
    (libc::WEXITSTATUS(status), usage.ru_maxrss)
}

#[test]
fn peak_memory_stays_within_twice_the_table_plus_64_mb() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    // 128 × 128 × 256 cells × 3 channels: 4.2 M cells, 48 MiB of f32 and 4 MiB of flags.
    let grid = "halfdiff3:128x128x256";
    tabulate(
        d,
        "big.bpk",
        "ggx:alpha=0.3,fresnel=au",
        grid,
        &["--codec", "zstd-f32:level=1"],
    );
    let table_kib: i64 = 128 * 128 * 256 * (3 * 4 + 1) / 1024;
    let bound = 2 * table_kib + 64 * 1024;
    // `check` is held to the same bound: its `cells` set (every valid cell) is streamed in
    // chunks, never held (it used to be: 388 MiB).
    for args in [
        &["inspect", "big.bpk"][..],
        &["eval", "big.bpk", "--wi", "0,0,1", "--wo", "0.3,0,0.9"],
        &["convert", "big.bpk", "--format", "exr", "-o", "big.exr"],
        &["inspect", "big.exr"],
        // The lossless codec (the default of `tabulate` and `convert`): its residuals are
        // streamed to zstd per byte plane and its predictor keeps a window of two slices,
        // not a padded copy of the table (241 MiB before); its decoder writes into the
        // table's buffer (143 MiB before).
        &["convert", "big.bpk", "-o", "big_lossless.bpk"],
        &["inspect", "big_lossless.bpk"],
        &[
            "check",
            "big.bpk",
            "--against",
            "ggx:alpha=0.3,fresnel=au",
            "--samples",
            "1000",
        ],
        // The planner: the encoder decodes its candidates into the table's own samples
        // (read again from the file if the lossless chain is chosen), makes the
        // coefficients before the estimator's stencils, and quantizes without a plane of
        // codes (217–219 MiB before, 71f6271).
        &[
            "compress",
            "big.bpk",
            "--max-error",
            "production",
            "-o",
            "c.bpk",
        ],
        // An explicit codec: its measurement decodes into the table's own samples (the
        // payload is made; the reference values and stencils were taken before), and its
        // reference is the table borrowed, not a clone (208,788 KiB before, in release).
        &[
            "compress",
            "big.bpk",
            "--codec",
            "dct:step=0.01,curve=log,coding=context",
            "-o",
            "d.bpk",
        ],
        // `pack` of a stored table on its own grid: the table is read for the reference
        // values and the tabulation, then freed while the codec is chosen, and read again
        // for the check (237 MiB before, with the table held throughout).
        &["pack", "big.bpk", "--grid", grid, "-o", "p.bpk"],
    ] {
        // `compress` and `pack` with one worker thread: with two, compress's peak depends on timing (which
        // worker's arena serves an allocation, when freed blocks are handed back): 164,784 to
        // 169,116 KiB over ten runs of the debug build, against the bound of 172,032. With
        // one it is 165,096–165,224 KiB (three runs), so the assertion tracks the planner's
        // arrays, not the scheduler. The other commands are measured as users run them.
        let env: &[(&str, &str)] = if matches!(args[0], "compress" | "pack") {
            &[("RAYON_NUM_THREADS", "1")]
        } else {
            &[]
        };
        let (code, kib) = peak_rss_kib_with(d, env, args);
        assert_eq!(code, 0, "{args:?}");
        println!(
            "{args:?}: peak RSS {} MiB (bound {} MiB)",
            kib / 1024,
            bound / 1024
        );
        assert!(kib <= bound, "{args:?}: peak RSS {kib} KiB > {bound} KiB");
        // The same command under an address-space cap of the bound plus 128 MiB for what is
        // mapped but not resident (the binary, thread stacks, malloc arenas: two threads and
        // two arenas, so that the cap does not depend on the machine's cores). Measured
        // (release): 87 MiB of address space for `inspect`, `eval` and `check`, 183 MiB for
        // `convert`; `check` needed 486 MiB while it held its `cells` set. The cap was bound
        // + 64 MiB (232 MiB): `convert` failed under it in 2 of ~10 full-suite runs on the
        // loaded 2-core machine (address space, unlike RSS, depends on timing: which thread's
        // arena serves an allocation, glibc's adaptive mmap threshold), never alone. The RSS
        // bound above is the issue's figure and stays as it is.
        let mut capped = Command::new("sh");
        capped
            .current_dir(d)
            .env("RAYON_NUM_THREADS", "2")
            .env("MALLOC_ARENA_MAX", "2")
            .arg("-c")
            .arg(format!(
                "ulimit -v {} && exec \"$0\" \"$@\"",
                bound + 128 * 1024
            ))
            .arg(&*BIN)
            .args(args);
        let o = capped.output().unwrap();
        assert!(
            o.status.success(),
            "{args:?} under ulimit -v: {}",
            stderr(&o)
        );
    }
}

#[test]
fn an_allocation_the_machine_refuses_ends_with_exit_1_and_a_message_not_an_abort() {
    // Inside the budget (2 GiB), but not inside the address space: 64 MiB for a command
    // whose table alone is 48 MiB. Rust's default is an abort (exit 134, "memory allocation
    // of N bytes failed" and a backtrace); the binary's allocator ends with exit 1, one
    // `brdfpack:` line, the temporary files removed and the previous output untouched.
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    std::fs::write(d.join("out.bpk"), b"previous").unwrap();
    let mut cmd = Command::new("sh");
    cmd.current_dir(d)
        .env("RAYON_NUM_THREADS", "2")
        .env("MALLOC_ARENA_MAX", "2")
        .arg("-c")
        .arg("ulimit -v 65536 && exec \"$0\" \"$@\"")
        .arg(&*BIN)
        .args([
            "tabulate",
            "ggx:alpha=0.3,fresnel=au",
            "--grid",
            "halfdiff3:128x128x256",
            "-o",
            "out.bpk",
        ]);
    let o = cmd.output().unwrap();
    let e = stderr(&o);
    assert_eq!(o.status.code(), Some(1), "stderr: {e}");
    // Which allocation fails first depends on the binary's mapped size: an allocation of the
    // table, or a worker thread's stack (rayon's pool panicked there, exit 101, until the
    // pool was started up front: `memory::start_worker_threads`).
    assert!(
        e.starts_with("brdfpack: out of memory: an allocation of ")
            || e.starts_with("brdfpack: out of memory: the worker threads could not be started"),
        "{e}"
    );
    assert!(e.contains("no file written"), "{e}");
    assert_eq!(e.lines().count(), 1, "{e}");
    assert_eq!(std::fs::read(d.join("out.bpk")).unwrap(), b"previous");
    assert!(temps_in(d).is_empty(), "{:?}", temps_in(d));
}

#[test]
fn the_default_pack_peaks_within_128_mb() {
    // Issue 19's bound for `pack` on a MERL-sized table (90×90×180 RGB, 17.5 MB of f32): peak
    // RSS ≤ 128 MB. It peaked at 162–166 MB (f64 DCT coefficients, a second copy of the
    // estimation pairs, a decoder scratch kept across candidates, freed blocks kept resident
    // by glibc's adaptive mmap threshold); now 116–118 MB (release) on this 2-core machine.
    // Two worker threads, so that the thread stacks and allocator arenas do not depend on the
    // machine's cores.
    let dir = tempfile::tempdir().unwrap();
    let (code, kib) = peak_rss_kib_with(
        dir.path(),
        &[("RAYON_NUM_THREADS", "2")],
        &["pack", "-q", "-o", "gold.bpk"],
    );
    assert_eq!(code, 0);
    let bytes = std::fs::metadata(dir.path().join("gold.bpk"))
        .unwrap()
        .len();
    println!("pack -o gold.bpk: peak RSS {} KiB, {bytes} B", kib);
    // 128 MB = 125,000 KiB.
    assert!(kib <= 125_000, "pack: peak RSS {kib} KiB > 128 MB");
}

/// The same bound for a MERL file as the source: it peaked at 148 MB while the source held its
/// exact f64 values (35 MB) through the plan, which a pointwise source never reads.
#[test]
fn packing_a_merl_file_peaks_within_128_mb() {
    let Some(merl) = common::shared_file("data/merl/gold-metallic-paint.binary") else {
        return;
    };
    let dir = tempfile::tempdir().unwrap();
    let (code, kib) = peak_rss_kib_with(
        dir.path(),
        &[("RAYON_NUM_THREADS", "2")],
        &["pack", merl.to_str().unwrap(), "-q", "-o", "paint.bpk"],
    );
    assert_eq!(code, 0);
    println!("pack gold-metallic-paint.binary: peak RSS {kib} KiB");
    assert!(kib <= 125_000, "pack: peak RSS {kib} KiB > 128 MB");
}

/// A θmax table packed on a grid the user gives without θmax is measured within the table's
/// stored domain, as `check` measures it: the planner once compared the whole hemisphere with
/// a source that has no values beyond 60° and refused every budget (exit 1, p99_rel_core
/// 3e4). The written file then holds the budget against the table in `check`, which samples
/// the same domain and says so.
#[test]
fn a_theta_max_table_packed_on_a_full_grid_is_measured_within_its_domain() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    tabulate(
        d,
        "t60.bpk",
        "ggx:alpha=0.3,fresnel=au",
        "halfdiff3:32x32x64,theta-max=60",
        &["--codec", "lossless"],
    );
    let o = run(
        d,
        &[
            "pack",
            "t60.bpk",
            "--grid",
            "halfdiff3:32x32x64",
            "--max-error",
            "preview",
            "-o",
            "p.bpk",
        ],
    );
    assert_eq!(o.status.code(), Some(0), "{}", stderr(&o));
    let o = run(
        d,
        &[
            "check",
            "p.bpk",
            "--against",
            "t60.bpk",
            "--samples",
            "100000",
            "--uniform-only",
            "--max-log-rmse",
            "0.01",
            "--max-p99-rel-core",
            "0.2",
        ],
    );
    let out = String::from_utf8_lossy(&o.stdout);
    assert_eq!(o.status.code(), Some(0), "{out}{}", stderr(&o));
    assert!(out.contains("θi, θo ≤ 60° only"), "{out}");
}

/// A MERL file whose every value is a negative marker has nothing to compress: `pack` and
/// `compress --max-error` refuse it (exit 2, naming the file) instead of meeting the budget
/// vacuously with a file of zeros (590 bytes of black, exit 0, before). `inspect` and
/// `convert` still read it.
#[test]
fn a_table_without_one_valid_cell_is_refused_by_the_planner() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let dims = [8i32, 8, 16];
    let mut bytes: Vec<u8> = dims.iter().flat_map(|v| v.to_le_bytes()).collect();
    for _ in 0..3 * 8 * 8 * 16 {
        bytes.extend_from_slice(&(-1.0f64).to_le_bytes());
    }
    std::fs::write(d.join("dark.binary"), &bytes).unwrap();
    let o = run(d, &["pack", "dark.binary", "-o", "dark.bpk"]);
    assert_refused(&o, &["dark.binary", "invalid", "no file written"]);
    assert!(!d.join("dark.bpk").exists());
    let o = run(d, &["inspect", "dark.binary"]);
    assert!(o.status.success(), "{}", stderr(&o));
    assert!(String::from_utf8_lossy(&o.stdout).contains("valid 0"));
    let o = run(
        d,
        &[
            "convert",
            "dark.binary",
            "-o",
            "dark-table.bpk",
            "--codec",
            "lossless",
        ],
    );
    assert!(o.status.success(), "{}", stderr(&o));
    let o = run(
        d,
        &[
            "compress",
            "dark-table.bpk",
            "-o",
            "c.bpk",
            "--max-error",
            "preview",
        ],
    );
    assert_refused(&o, &["dark.binary", "invalid"]);
    assert!(!d.join("c.bpk").exists());
}

/// A packed RGL file whose header asks for a derived VNDF of an absurd shape: the reader
/// rebuilds that field from the NDF, so nothing stored bounds it. H = W = 2^32 made the
/// shape's product wrap to 0, which passed the budget, and the derivation ran until memory
/// ran out (exit 1 after 30 s and 4.2 GB, a ~2 KB file); a shape within the cap was counted
/// at 4 bytes a value and took 5.8 GB (2^28 values, exit 0 after 15 s). Both are refused at
/// once now, exit 2 naming the file and the field.
#[test]
fn a_packed_rgl_header_cannot_ask_for_an_endless_derived_vndf() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let fixture =
        Path::new(env!("CARGO_MANIFEST_DIR")).join("fixtures/rgl/ggx-packed-line-ends.bpk");
    let base = std::fs::read(fixture).unwrap();
    let mut secs = sections(&base);
    let mut head: serde_json::Value =
        serde_json::from_slice(&zstd::decode_all(&secs[0].1[..]).unwrap()).unwrap();
    // The colour payload alone after the stored fields: the VNDF is derived, not coded.
    let colour_end =
        (head["stored_bytes"].as_u64().unwrap() + head["colour_bytes"].as_u64().unwrap()) as usize;
    secs[1].1.truncate(colour_end);
    let obj = head.as_object_mut().unwrap();
    obj.remove("vndf_coding");
    obj.remove("colour_bytes");
    obj.insert("vndf".into(), "derived".into());
    for (name, shape, needle) in [
        ("ok.bpk", [1u64, 4, 16, 16], None),
        (
            "wrap.bpk",
            [1, 4, 1 << 32, 1 << 32],
            Some("larger than any RGL file"),
        ),
        (
            "wrap2.bpk",
            [1, 4, 1 << 62, 4],
            Some("larger than any RGL file"),
        ),
        ("big.bpk", [1, 4, 2, 1 << 25], Some("needs about 6.0 GiB")),
    ] {
        head["vndf_shape"] = serde_json::json!(shape);
        let mut s = secs.clone();
        s[0] = (*b"HEAD", serde_json::to_vec(&head).unwrap());
        std::fs::write(d.join(name), assemble(&base, &s)).unwrap();
        let start = std::time::Instant::now();
        let o = run_capped(d, 1 << 20, &["inspect", name]);
        match needle {
            None => assert!(o.status.success(), "{name}: {}", stderr(&o)),
            Some(n) => assert_refused(&o, &[name, "vndf", n]),
        }
        assert!(
            start.elapsed().as_secs() < 5,
            "{name}: {:?}",
            start.elapsed()
        );
    }
}

/// Optical constants from a CSV file (`nk=@file.csv`) are held to the range of the
/// parameters they replace (`eta`, `k`, `eta_re`, `eta_im`: at most 1e6). n = k = 1e308 made
/// the Fresnel term overflow: `eval` printed 1.7976931348623157e308 (exit 0) for a conductor
/// whose f is 2.635, and `props` said "0 non-finite value(s) ... albedo inf".
#[test]
fn optical_constants_beyond_the_parameter_range_are_refused_naming_the_line() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    std::fs::write(
        d.join("huge.csv"),
        "wavelength_nm,n,k\n400,1,2\n700,1e308,1e308\n",
    )
    .unwrap();
    std::fs::write(
        d.join("edge.csv"),
        "wavelength_nm,n,k\n400,1e6,1e6\n700,1e6,1e6\n",
    )
    .unwrap();
    let pair = ["--wi-deg", "30,0", "--wo-deg", "30,180"];
    for spec in [
        "ggx:alpha=0.2,fresnel=conductor,nk=@huge.csv,wavelengths_nm=400/550/700",
        "htsg:nk=@huge.csv,wavelengths_nm=400/550/700",
    ] {
        for cmd in ["eval", "props"] {
            let mut args = vec![cmd, spec];
            if cmd == "eval" {
                args.extend_from_slice(&pair);
            }
            let o = run(d, &args);
            assert_refused(&o, &["huge.csv", "line 3", "n = 1e308", "[0, 1e6]"]);
            assert!(
                o.stdout.is_empty(),
                "{}",
                String::from_utf8_lossy(&o.stdout)
            );
        }
    }
    let spec = "ggx:alpha=0.2,fresnel=conductor,nk=@edge.csv,wavelengths_nm=400/550/700";
    let o = run(d, &[&["eval", spec][..], &pair].concat());
    assert!(o.status.success(), "{}", stderr(&o));
    let f: f64 = String::from_utf8_lossy(&o.stdout)
        .split_whitespace()
        .next()
        .unwrap()
        .parse()
        .unwrap();
    assert!(f > 2.0 && f < 3.0, "{f}");
}

/// A header number at f64's edges is quoted in short form: `dct dead zone 1e300`, not the
/// 301 digits `{}` gives an f64 (which filled the error line up to its 2000-character cut
/// for the dead zone, Tucker's factor_step, the log interpolation scale and θmax).
#[test]
fn header_numbers_at_the_edges_of_f64_are_quoted_in_short_form() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let dct = tabulate(
        d,
        "d.bpk",
        "lambert",
        "halfdiff3:4",
        &["--codec", "dct:step=0.01"],
    );
    let tucker = tabulate(
        d,
        "k.bpk",
        "lambert",
        "halfdiff3:4",
        &["--codec", "tucker:ranks=2x2x4"],
    );
    let plain = tabulate(d, "p.bpk", "lambert", "halfdiff3:4", &[]);
    type Edit = fn(&mut serde_json::Value);
    let cases: [(&PathBuf, Edit, &str); 4] = [
        (
            &dct,
            |h| h["codec"]["coding"]["deadzone"] = 1e300.into(),
            "dead zone 1e300",
        ),
        (
            &tucker,
            |h| h["codec"]["tucker"]["factor_step"] = (-1e300).into(),
            "factor_step -1e300",
        ),
        (
            &plain,
            |h| h["grid"]["interp_space"] = serde_json::json!({"log": {"scale": 1e-320}}),
            "scale 1e-320",
        ),
        (
            &plain,
            |h| h["grid"]["theta_max_deg"] = 1e300.into(),
            "theta-max = 1e300",
        ),
    ];
    for (k, (base, edit, needle)) in cases.into_iter().enumerate() {
        let name = format!("edge{k}.bpk");
        std::fs::write(
            d.join(&name),
            lying_native(&std::fs::read(base).unwrap(), edit),
        )
        .unwrap();
        let o = run(d, &["inspect", &name]);
        assert_refused(&o, &[&name, needle]);
        assert!(stderr(&o).len() < 300, "{}", stderr(&o));
    }
    // A requested residual step too small for the table (`uniform quantizer: value ... /
    // step 0.000...` before).
    let o = run(
        d,
        &[
            "compress",
            "p.bpk",
            "--codec",
            "dct:step=0.01,residual=1e-300",
            "-o",
            "r.bpk",
        ],
    );
    assert_refused(&o, &["step 1e-300 exceeds 2^30 levels"]);
    assert!(stderr(&o).len() < 300, "{}", stderr(&o));
    assert!(!d.join("r.bpk").exists());
}

#[test]
fn eval_angles_off_the_sphere_are_refused_naming_the_option() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let spec = "lambert:albedo=0.5";
    // θ outside [0°, 180°] in either option: exit 2 naming the option, its text and the range
    // (both were exit 0 before: 1e308° and -10° were taken as angles like any other). Below
    // the horizon (90° < θ ≤ 180°) is a direction, as in the vector form, where f = 0.
    for (wi, wo, flag) in [
        ("1e308,0", "0,0", "--wi-deg \"1e308,0\""),
        ("-10,0", "0,0", "--wi-deg \"-10,0\""),
        ("180.5,0", "0,0", "--wi-deg \"180.5,0\""),
        ("0,0", "1e308,0", "--wo-deg \"1e308,0\""),
        ("0,0", "-10,0", "--wo-deg \"-10,0\""),
    ] {
        let o = run(d, &["eval", spec, "--wi-deg", wi, "--wo-deg", wo]);
        assert_refused(&o, &[flag, "is out of range", "[0, 180] degrees"]);
        assert!(o.stdout.is_empty());
    }
    let o = run(d, &["eval", spec, "--wi-deg", "1e308,0", "--wo-deg", "0,0"]);
    assert!(stderr(&o).contains("θ = 1e308"), "{}", stderr(&o));
    // The horizon itself is a direction (f = 0 there), the normal gives albedo / π, and φ
    // beyond a turn is its residue: 30,370 is 30,10.
    let value = |wi: &str, wo: &str| {
        let o = run(d, &["eval", spec, "--wi-deg", wi, "--wo-deg", wo]);
        assert!(o.status.success(), "{wi} {wo}: {}", stderr(&o));
        String::from_utf8(o.stdout).unwrap().trim().to_string()
    };
    assert_eq!(value("90,0", "0,0"), "0.0");
    assert_eq!(value("120,0", "0,0"), "0.0");
    let f: f64 = value("0,0", "0,1e308").parse().unwrap();
    assert!((f - 0.5 / std::f64::consts::PI).abs() < 1e-15, "{f}");
    let spec = "ggx:alpha=0.3";
    let at = |wi: &str, wo: &str| {
        let o = run(d, &["eval", spec, "--wi-deg", wi, "--wo-deg", wo]);
        assert!(o.status.success(), "{}", stderr(&o));
        String::from_utf8(o.stdout).unwrap()
    };
    assert_eq!(at("30,370", "40,-530"), at("30,10", "40,-170"));
}

/// A small MERL-layout file (dims in the header) whose bins are all invalid (−1) but for
/// `valid` (cell index, the same value in each channel).
fn merl_with_valid_bins(dims: [i32; 3], valid: &[usize]) -> Vec<u8> {
    let n: usize = dims.iter().map(|&d| d as usize).product();
    let mut bytes: Vec<u8> = dims.iter().flat_map(|v| v.to_le_bytes()).collect();
    for _ in 0..3 {
        for cell in 0..n {
            let v = if valid.contains(&cell) {
                750.0f64
            } else {
                -1.0
            };
            bytes.extend_from_slice(&v.to_le_bytes());
        }
    }
    bytes
}

/// `pack` with `--codec` (no budget, so the planner's refusal of a table without values was
/// not reached) of a MERL file without one valid bin: it tabulated and checked every cell
/// through the nearest-valid fallback and wrote a file of 0s (22–25 s for a 90×90×180 file
/// with `--codec lossless --full-check`, exit 0). Refused up front now, exit 2, as `build`
/// refuses such a material; a file with one valid bin still packs.
#[test]
fn packing_a_table_without_one_valid_cell_is_refused_up_front_with_any_codec() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    std::fs::write(d.join("dark.binary"), merl_with_valid_bins([8, 8, 16], &[])).unwrap();
    for codec in ["lossless", "dct:step=0.05"] {
        let o = run(
            d,
            &[
                "pack",
                "dark.binary",
                "--codec",
                codec,
                "--full-check",
                "-o",
                "dark.bpk",
            ],
        );
        assert_refused(
            &o,
            &[
                "dark.binary",
                "every one of its 1024 cells is marked invalid",
                "nothing to pack",
                "no file written",
            ],
        );
        assert!(!d.join("dark.bpk").exists());
    }
    std::fs::write(
        d.join("m.toml"),
        "[[material]]\nname = \"dark\"\nsource = \"dark.binary\"\ncodec = \"lossless\"\n\
         outputs = [\"dark.bpk\"]\n",
    )
    .unwrap();
    let o = run(d, &["build", "m.toml"]);
    assert_eq!(o.status.code(), Some(2), "{}", stderr(&o));
    let e = stderr(&o);
    assert!(
        e.contains("material dark") && e.contains("nothing to pack"),
        "{e}"
    );
    assert!(!d.join("dark.bpk").exists());
    // One valid bin: packed on its own grid (its lookups find it, or nothing near, at once).
    std::fs::write(
        d.join("one.binary"),
        merl_with_valid_bins([8, 8, 16], &[300]),
    )
    .unwrap();
    let o = run(
        d,
        &[
            "pack",
            "one.binary",
            "--grid",
            "halfdiff3:8x8x16,warp=sqrt/linear/linear,at=edge",
            "--codec",
            "lossless",
            "--full-check",
            "--json",
            "-o",
            "one.bpk",
        ],
    );
    assert!(o.status.success(), "{}", stderr(&o));
    let v: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    assert_eq!(v["valid_cells"], 1, "{v}");
}

/// An RGL file shaped like `fixtures/rgl/tiny.bsdf` but with 4 θi slices of `n` × `n` colour
/// samples, all 0 (a packed form of it is a few KB however large `n`).
fn rgl_of_zeros(n: usize) -> Vec<u8> {
    let b = std::fs::read(Path::new(env!("CARGO_MANIFEST_DIR")).join("fixtures/rgl/tiny.bsdf"))
        .unwrap();
    let count = u32::from_le_bytes(b[14..18].try_into().unwrap()) as usize;
    let mut pos = 18;
    // (name, dtype, shape, data) in the file's order.
    let mut fields: Vec<(String, u8, Vec<u64>, Vec<u8>)> = Vec::new();
    for _ in 0..count {
        let nl = u16::from_le_bytes(b[pos..pos + 2].try_into().unwrap()) as usize;
        let name = String::from_utf8(b[pos + 2..pos + 2 + nl].to_vec()).unwrap();
        pos += 2 + nl;
        let nd = u16::from_le_bytes(b[pos..pos + 2].try_into().unwrap()) as usize;
        let dtype = b[pos + 2];
        let offset = u64::from_le_bytes(b[pos + 3..pos + 11].try_into().unwrap()) as usize;
        pos += 11;
        let shape: Vec<u64> = (0..nd)
            .map(|k| u64::from_le_bytes(b[pos + 8 * k..pos + 8 * k + 8].try_into().unwrap()))
            .collect();
        pos += 8 * nd;
        let size = if dtype == 1 { 1 } else { 4 };
        let len = size * shape.iter().product::<u64>() as usize;
        fields.push((name, dtype, shape, b[offset..offset + len].to_vec()));
    }
    let (slices, n64) = (4u64, n as u64);
    for f in &mut fields {
        match f.0.as_str() {
            "theta_i" => {
                f.2 = vec![slices];
                f.3 = [0.0f32, 0.35, 0.7, 1.05]
                    .iter()
                    .flat_map(|v| v.to_le_bytes())
                    .collect();
            }
            "vndf" => {
                f.2[1] = slices;
                f.3 = f.3.repeat(2);
            }
            "luminance" => {
                f.2 = vec![1, slices, n64, n64];
                f.3 = vec![0; 4 * 4 * n * n];
            }
            "rgb" => {
                f.2 = vec![1, slices, 3, n64, n64];
                f.3 = vec![0; 4 * 12 * n * n];
            }
            "valid" => {
                f.2 = vec![n64 * n64];
                f.3 = vec![1; n * n];
            }
            _ => {}
        }
    }
    let head: usize = 18
        + fields
            .iter()
            .map(|f| 13 + f.0.len() + 8 * f.2.len())
            .sum::<usize>();
    let mut offset = head.div_ceil(8) * 8;
    let mut out = b[..14].to_vec();
    out.extend_from_slice(&(fields.len() as u32).to_le_bytes());
    for f in &fields {
        out.extend_from_slice(&(f.0.len() as u16).to_le_bytes());
        out.extend_from_slice(f.0.as_bytes());
        out.extend_from_slice(&(f.2.len() as u16).to_le_bytes());
        out.push(f.1);
        out.extend_from_slice(&(offset as u64).to_le_bytes());
        for s in &f.2 {
            out.extend_from_slice(&s.to_le_bytes());
        }
        offset += f.3.len().div_ceil(8) * 8;
    }
    out.resize(head.div_ceil(8) * 8, 0);
    for f in &fields {
        out.extend_from_slice(&f.3);
        out.resize(out.len().div_ceil(8) * 8, 0);
    }
    out
}

/// The memory a packed RGL colour tensor is counted at covers what reading it takes: 16
/// bytes a value were counted while `inspect` peaked at ~18.9 (`[1, 4, 3, 2048, 2048]` of
/// zeros, a 9 KB file: 915 MiB for 768 MiB counted). With `[1, 4, 3, 1024, 1024]`: peak RSS
/// 234 MiB, counted 192 MiB before and 240 MiB now.
#[test]
fn a_packed_rgl_colour_tensor_is_counted_at_what_its_read_takes() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    std::fs::write(d.join("z.bsdf"), rgl_of_zeros(1024)).unwrap();
    let o = run(
        d,
        &["pack", "z.bsdf", "--codec", "lossless", "-o", "z.bpk", "-q"],
    );
    assert!(o.status.success(), "{}", stderr(&o));
    assert!(std::fs::metadata(d.join("z.bpk")).unwrap().len() < 100_000);
    // The count, from the refusal under a budget that admits the stored fields (the
    // luminance and flags, 17 MiB).
    let o = run(d, &["--max-memory", "32M", "inspect", "z.bpk"]);
    assert_refused(&o, &["z.bpk", "the packed RGL colour tensor needs about"]);
    let e = stderr(&o);
    let mib: f64 = e
        .split("needs about ")
        .nth(1)
        .and_then(|r| r.split(" MiB").next())
        .and_then(|x| x.parse().ok())
        .unwrap_or_else(|| panic!("{e}"));
    assert_eq!(mib, 240.0, "{e}");
    // The read's peak (the process's own ~8 MiB included) within the count and 16 MiB.
    let (code, kib) = peak_rss_kib_with(d, &[], &["inspect", "z.bpk"]);
    assert_eq!(code, 0);
    println!("inspect of a packed [1, 4, 3, 1024, 1024]: peak RSS {kib} KiB, counted {mib} MiB");
    assert!(
        (kib as f64) <= (mib + 16.0) * 1024.0,
        "peak {kib} KiB > counted {mib} MiB + 16 MiB"
    );
}

/// Messages that left out what the user needs: a truncated MERL file on stdin was "unknown
/// format (...): expected a brdfpack table (.bpk), a brdfpack EXR, a MERL .binary or an MDL
/// .mbsdf file" (from a file, MERL's size error), a list without the RGL `.bsdf` that `eval -`
/// reads; and a native table whose header gives a wavelength of −1 nm was read, then refused
/// by `convert --to-rgb` as "spectral to RGB: wavelength[0] = -1 nm" without the file's name.
#[test]
fn stream_and_wavelength_errors_name_what_is_read() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let pair = ["--wi", "0,0,1", "--wo", "0,0,1"];
    let eval_stdin = |bytes: &[u8]| {
        std::fs::write(d.join("in"), bytes).unwrap();
        brdfpack()
            .current_dir(d)
            .args(["eval", "-"])
            .args(pair)
            .stdin(std::fs::File::open(d.join("in")).unwrap())
            .output()
            .unwrap()
    };
    // MERL's standard dims and too few values: MERL's own error, as from a file.
    let mut merl: Vec<u8> = [90i32, 90, 180]
        .iter()
        .flat_map(|v| v.to_le_bytes())
        .collect();
    merl.extend_from_slice(&0.5f64.to_le_bytes());
    let o = eval_stdin(&merl);
    assert_refused(&o, &["does not match dims", "truncated"]);
    std::fs::write(d.join("short.binary"), &merl).unwrap();
    let o = run(
        d,
        &["eval", "short.binary", "--wi", "0,0,1", "--wo", "0,0,1"],
    );
    assert_refused(&o, &["short.binary", "does not match dims", "truncated"]);
    // Bytes of no known format: every format a source may be is listed, RGL's too (`eval`
    // and `inspect` read it).
    let o = eval_stdin(b"not a brdf at all");
    assert_refused(
        &o,
        &[
            "unknown format (17 bytes)",
            "a MERL .binary, an RGL .bsdf or an MDL .mbsdf file",
        ],
    );
    let o = run(d, &["inspect", "in"]);
    assert_refused(&o, &["in: unknown format (17 bytes)", "an RGL .bsdf"]);
    // A wavelength that is no length: refused where the file is read, naming it.
    let base = std::fs::read(tabulate(
        d,
        "sp.bpk",
        "lambert:albedo=0.5,wavelengths_nm=450/550/650",
        "halfdiff3:4",
        &[],
    ))
    .unwrap();
    for (w, shown) in [(-1.0, "-1.0"), (0.0, "0.0"), (-1e300, "-1e300")] {
        std::fs::write(
            d.join("neg.bpk"),
            lying_native(&base, |h| h["channels"]["wavelengths_nm"][0] = w.into()),
        )
        .unwrap();
        for args in [
            vec!["convert", "neg.bpk", "--to-rgb", "-o", "rgb.bpk"],
            vec!["inspect", "neg.bpk"],
        ] {
            let o = run(d, &args);
            assert_refused(
                &o,
                &[
                    "neg.bpk",
                    &format!("wavelength[0] = {shown} nm (channel \"450nm\")"),
                    "expected a finite value > 0",
                ],
            );
        }
        assert!(!d.join("rgb.bpk").exists());
    }
}
