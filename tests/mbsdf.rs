//! MDL `.mbsdf`: the byte layout against a reference file built by hand from the MDL
//! specification's appendix (fixtures/mbsdf/rgb_2x3.mbsdf, written by a separate Python
//! `struct.pack` script and rebuilt here byte by byte, not by the writer), exact round trips at
//! the grid samples, the CLI, and errors.

use assert_cmd::Command;
use brdfpack::grid::parse_grid_spec;
use brdfpack::io::mbsdf::{self, MbsdfFile, MbsdfOptions};
use brdfpack::model::Model;
use brdfpack::tabulate::{TabulateOptions, tabulate};
use std::path::Path;

const FIXTURE: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/fixtures/mbsdf/rgb_2x3.mbsdf");

/// The reference value at θin bin i, θout bin o, Δφ bin p, channel c.
fn reference_value(i: usize, o: usize, p: usize, c: usize) -> f32 {
    0.5 + i as f32 + 0.25 * o as f32 + 0.0625 * p as f32 + 0.125 * c as f32
}

/// The BRDF block of the reference, by hand: u32 type 1 (RGB), u32 resolution_theta 2,
/// u32 resolution_phi 3, then f32 [θin][θout][Δφ][R, G, B], all little-endian.
fn reference_block() -> Vec<u8> {
    let mut b = Vec::new();
    for v in [1u32, 2, 3] {
        b.extend_from_slice(&v.to_le_bytes());
    }
    for i in 0..2 {
        for o in 0..2 {
            for p in 0..3 {
                for c in 0..3 {
                    b.extend_from_slice(&reference_value(i, o, p, c).to_le_bytes());
                }
            }
        }
    }
    b
}

fn reference_file() -> Vec<u8> {
    let mut f = b"NVIDIA ARC MBSDF V1\n".to_vec();
    f.extend_from_slice(b"description=\"hand-built reference\"\n");
    f.extend_from_slice(b"MBSDF_DATA_REFLECTION=\n");
    f.extend_from_slice(&reference_block());
    f
}

#[test]
fn the_fixture_is_the_hand_built_layout() {
    let bytes = std::fs::read(FIXTURE).unwrap();
    assert_eq!(bytes, reference_file());
    // 20 + 35 + 23 header bytes, 12 block-header bytes, 2·2·3·3 floats.
    assert_eq!(bytes.len(), 20 + 35 + 23 + 12 + 36 * 4);
}

#[test]
fn reading_the_reference_places_each_value_at_its_bin_centre() {
    let bytes = std::fs::read(FIXTURE).unwrap();
    let t = mbsdf::from_bytes(&bytes, Path::new(FIXTURE)).unwrap();
    assert_eq!(
        t.grid().describe(),
        mbsdf::mbsdf_grid(2, 3).unwrap().describe()
    );
    assert_eq!(t.channels().names(), ["R", "G", "B"]);
    let mut idx = [0usize; 3];
    for cell in 0..12 {
        t.grid().unflatten(cell, &mut idx);
        let [i, o, p] = idx;
        // Bin centres: θ = (k + ½)·45°, Δφ = (p + ½)·60°.
        let c = t.grid().sample_coords(&idx);
        assert!((c[0] - (i as f64 + 0.5) * 45f64.to_radians()).abs() < 1e-12);
        assert!((c[1] - (o as f64 + 0.5) * 45f64.to_radians()).abs() < 1e-12);
        assert!((c[2] - (p as f64 + 0.5) * 60f64.to_radians()).abs() < 1e-12);
        for ch in 0..3 {
            assert_eq!(t.cell(cell)[ch], reference_value(i, o, p, ch));
        }
    }
    assert!(t.valid().iter().all(|v| *v));
}

#[test]
fn writing_the_table_back_gives_the_reference_block_bit_for_bit() {
    let bytes = std::fs::read(FIXTURE).unwrap();
    let t = mbsdf::from_bytes(&bytes, Path::new(FIXTURE)).unwrap();
    let out = mbsdf::to_bytes(&t, &MbsdfOptions::default()).unwrap();
    assert!(
        out.starts_with(b"NVIDIA ARC MBSDF V1\ndescription=\"MDL .mbsdf file rgb_2x3.mbsdf\"\n")
    );
    let tag = b"MBSDF_DATA_REFLECTION=\n";
    let at = out.windows(tag.len()).position(|w| w == tag).unwrap();
    assert_eq!(&out[at + tag.len()..], reference_block().as_slice());
    // Every meta-data line is printable ASCII.
    for line in out[20..at].split(|b| *b == b'\n').filter(|l| !l.is_empty()) {
        assert!(line.iter().all(|b| (0x20..0x7f).contains(b)), "{line:?}");
    }
}

#[test]
fn a_tabulated_model_round_trips_exactly_at_the_grid_samples() {
    let grid = parse_grid_spec("spherical3:12x12x20").unwrap();
    let m = Model::parse("ggx:alpha=0.2,fresnel=schlick,f0=0.9/0.6/0.3").unwrap();
    let t = tabulate(&m, &grid, &TabulateOptions::default()).unwrap();
    let bytes = mbsdf::to_bytes(&t, &MbsdfOptions::default()).unwrap();
    // magic + meta-data + tag + 12 + 12·12·20·3 floats.
    let back = mbsdf::from_bytes(&bytes, Path::new("x.mbsdf")).unwrap();
    assert_eq!(back.grid(), t.grid());
    assert_eq!(back.data().len(), t.data().len());
    for (a, b) in back.data().iter().zip(t.data()) {
        assert_eq!(a.to_bits(), b.to_bits());
    }
    // Scalar: one Rec. 709 luminance per cell.
    let s = mbsdf::to_bytes(&t, &MbsdfOptions { scalar: true }).unwrap();
    let f = MbsdfFile::parse(&s, Path::new("s.mbsdf")).unwrap();
    let p = f.reflection.unwrap();
    assert!(!p.rgb);
    for (cell, y) in p.values.iter().enumerate() {
        let v = t.cell(cell);
        let want = 0.2126 * v[0] as f64 + 0.7152 * v[1] as f64 + 0.0722 * v[2] as f64;
        assert_eq!(*y, want as f32);
    }
}

fn brdfpack() -> Command {
    Command::cargo_bin("brdfpack").unwrap()
}

#[test]
fn cli_writes_reads_and_inspects_mbsdf() {
    let d = tempfile::tempdir().unwrap();
    let out = d.path().join("g.mbsdf");
    brdfpack()
        .args(["convert", "ggx:alpha=0.3,fresnel=schlick,f0=0.9", "-o"])
        .arg(&out)
        .args(["--grid", "spherical3:8x8x16"])
        .assert()
        .success();
    let bytes = std::fs::read(&out).unwrap();
    assert!(bytes.starts_with(b"NVIDIA ARC MBSDF V1\n"));
    let o = brdfpack()
        .arg("inspect")
        .arg(&out)
        .arg("--json")
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let j: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    assert_eq!(j["format"], "mbsdf");
    assert_eq!(j["cells"], 8 * 8 * 16);
    // .mbsdf as a source, converted back: the same bytes.
    let again = d.path().join("h.mbsdf");
    brdfpack()
        .arg("convert")
        .arg(&out)
        .arg("-o")
        .arg(&again)
        .assert()
        .success();
    let b2 = MbsdfFile::parse(&std::fs::read(&again).unwrap(), &again).unwrap();
    let b1 = MbsdfFile::parse(&bytes, &out).unwrap();
    assert_eq!(b1.reflection, b2.reflection);
    // A grid the format cannot hold is refused before any work.
    brdfpack()
        .args(["convert", "lambert", "-o"])
        .arg(d.path().join("x.mbsdf"))
        .args(["--grid", "merl"])
        .assert()
        .code(2)
        .stderr(predicates::str::contains(
            "MDL .mbsdf needs a spherical3 grid",
        ));
}

#[test]
fn damaged_files_are_refused_with_the_place_and_value() {
    let good = reference_file();
    let check = |bytes: &[u8], want: &str| {
        let e = MbsdfFile::parse(bytes, Path::new("bad.mbsdf")).unwrap_err();
        assert_eq!(e.exit_code(), 2);
        assert!(e.to_string().contains(want), "{e} lacks {want:?}");
    };
    let hdr = 20 + 35 + 23;
    let mut b = good.clone();
    b[hdr] = 2;
    check(&b, "type 2");
    let mut b = good.clone();
    b[hdr + 4..hdr + 8].copy_from_slice(&0u32.to_le_bytes());
    check(&b, "resolution_theta = 0");
    let mut b = good.clone();
    b[hdr + 12..hdr + 16].copy_from_slice(&f32::NAN.to_le_bytes());
    check(&b, "value 0 is NaN");
    check(&good[..good.len() - 1], "truncated");
    let mut b = good.clone();
    b.extend_from_slice(b"junk");
    check(&b, "4 bytes after the reflection block");
    let mut b = good.clone();
    b[25] = 0xe9;
    check(&b, "byte 0xe9");
    check(b"NVIDIA ARC MBSDF V1\nno data\n", "no block identifier");
    check(b"NVIDIA ARC MBSDF V2\n", "not an MBSDF file");
    for cut in 0..good.len() {
        assert!(MbsdfFile::parse(&good[..cut], Path::new("c")).is_err());
    }
}
