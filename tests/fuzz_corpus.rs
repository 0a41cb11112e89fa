//! Replays every committed fuzz corpus and crash input (`fuzz/corpus/<target>/*`) through the
//! same entry points as the fuzz targets (`fuzz/checks.rs`), without a fuzzer: each must
//! return (usually with an error) without a panic and without a NaN/Inf or negative value
//! where the contract forbids one. See docs/robustness.md.

#[allow(dead_code)]
#[path = "../fuzz/checks.rs"]
mod checks;

use std::path::Path;

#[test]
fn every_committed_fuzz_input_replays_cleanly() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("fuzz/corpus");
    let mut total = 0;
    for (target, check) in checks::TARGETS {
        let dir = root.join(target);
        let mut files: Vec<_> = std::fs::read_dir(&dir)
            .unwrap_or_else(|e| panic!("{}: {e}", dir.display()))
            .map(|e| e.expect("directory entry").path())
            .collect();
        files.sort();
        // An empty directory would make the replay vacuous for that target.
        assert!(!files.is_empty(), "{} holds no inputs", dir.display());
        for f in &files {
            let data = std::fs::read(f).unwrap_or_else(|e| panic!("{}: {e}", f.display()));
            let r = std::panic::catch_unwind(|| check(&data));
            assert!(r.is_ok(), "{target}: input {} panicked", f.display());
            total += 1;
        }
    }
    println!("replayed {total} fuzz inputs");
}

/// The seeds are real files, so the replay reaches past the readers' first checks: each
/// seed decodes (guards against a corpus of junk that only exercises the error paths).
#[test]
fn seed_files_decode() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("fuzz/corpus");
    let read = |p: &str| std::fs::read(root.join(p)).expect("seed file");
    let fuzz = Path::new("fuzz");
    let t = brdfpack::io::native::from_bytes(&read("native/n_lossless.bpk"), fuzz).unwrap();
    assert_eq!(t.grid().cells(), 6 * 5 * 4);
    let framed = checks::frame_native(&read("native_framed/n_lossless.bpk"));
    let u = brdfpack::io::native::from_bytes(&framed, fuzz).unwrap();
    assert_eq!(u.data(), t.data());
    let e = brdfpack::io::exr::from_bytes(&read("exr/e.exr"), fuzz).unwrap();
    assert_eq!(e.grid().cells(), 6 * 5 * 4);
    let m = brdfpack::io::merl::from_bytes(&read("merl/small.binary"), fuzz).unwrap();
    assert_eq!(m.grid().cells(), 8);
    brdfpack::io::rgl::RglBsdf::from_bytes(&read("rgl/tiny.bsdf"), "tiny").unwrap();
    brdfpack::model::Model::parse("ggx:alpha=0.2,fresnel=au").unwrap();
    let text = |p: &str| String::from_utf8(read(p)).expect("UTF-8 seed");
    assert_eq!(
        brdfpack::grid::parse_grid_spec(&text("grid/seed00")).unwrap(),
        brdfpack::grid::Grid::merl()
    );
    let req = brdfpack::codec::CodecRequest::parse(&text("codec/seed02")).unwrap();
    assert_eq!(req.level(), Some(3));
}

/// The `eval` seeds reach the row writer: their first lines evaluate (the rest of a seed may
/// hold a deliberate error).
#[test]
fn eval_seeds_evaluate() {
    let seed = std::fs::read(
        Path::new(env!("CARGO_MANIFEST_DIR")).join("fuzz/corpus/eval/text_text_echo"),
    )
    .unwrap();
    // The seed's first byte is the fuzzer's mode (text in, text out, echo); the binary is
    // given the same choices as flags and the rest as its stream.
    let run = assert_cmd::Command::cargo_bin("brdfpack")
        .unwrap()
        .args([
            "eval",
            "ggx:alpha=0.15,fresnel=au",
            "--input",
            "text",
            "--format",
            "text",
            "--echo",
        ])
        .write_stdin(seed[1..].to_vec())
        .assert()
        .success();
    let out = String::from_utf8(run.get_output().stdout.clone()).unwrap();
    // 3 rows; the third's huge and tiny vectors normalize to the same unit direction.
    let rows: Vec<Vec<f64>> = out
        .lines()
        .map(|l| l.split(' ').map(|x| x.parse().unwrap()).collect())
        .collect();
    assert_eq!(rows.len(), 3);
    let h = std::f64::consts::FRAC_1_SQRT_2;
    for (k, want) in [h, 0.0, h, h, 0.0, h].iter().enumerate() {
        assert!((rows[2][k] - want).abs() < 1e-15, "{:?}", rows[2]);
    }
    assert_eq!(rows[2].len(), 6 + 3);
}
