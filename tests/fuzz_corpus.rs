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
}
