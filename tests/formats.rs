//! MERL and EXR writers and readers on generated data: models written as MERL and looked up
//! by the reference rule, exact EXR round trips, f16 range handling, malformed files.

use brdfpack::brdf::{Brdf, Channels};
use brdfpack::codec::CodecSpec;
use brdfpack::geometry::{HalfDiff, Vec3};
use brdfpack::grid::{Grid, parse_grid_spec};
use brdfpack::io::exr::{self, ExrCompression, ExrOptions, ExrSampleType};
use brdfpack::io::merl::{self, MerlLookup, MerlTable, SCALE};
use brdfpack::io::{self, OutputFormat, native};
use brdfpack::math::PI;
use brdfpack::model::Model;
use brdfpack::table::{ExactValues, Provenance, Table};
use brdfpack::tabulate::{TabulateOptions, tabulate};
use std::path::Path;

/// A smooth isotropic test BRDF whose value tells the bins apart on every axis (including
/// φd from π − φd, which cos 2φd alone would not).
struct Graded {
    ch: Channels,
}

impl Graded {
    fn new() -> Graded {
        Graded {
            ch: Channels::default_for(3),
        }
    }
}

impl Brdf for Graded {
    fn channels(&self) -> &Channels {
        &self.ch
    }
    fn eval(&self, wi: Vec3, wo: Vec3, out: &mut [f64]) {
        let Some(hd) = HalfDiff::from_dirs(wi, wo).filter(|_| wi.z > 0.0 && wo.z > 0.0) else {
            out.fill(0.0);
            return;
        };
        let base = 2.0 + hd.theta_h + 0.5 * hd.theta_d + 0.25 * (2.0 * hd.phi_d).sin();
        out[0] = base;
        out[1] = 0.5 * base + 0.1 * (2.0 * hd.phi_d).cos();
        out[2] = 30.0 * base * base;
    }
    fn is_isotropic(&self) -> bool {
        true
    }
    fn describe(&self) -> String {
        "graded test BRDF".into()
    }
}

/// Midpoint query of bin (i, j, k) of a MERL grid with dims `d`.
fn midpoint_dirs(i: usize, j: usize, k: usize, d: [usize; 3]) -> (Vec3, Vec3) {
    HalfDiff {
        theta_h: ((i as f64 + 0.5) / d[0] as f64).powi(2) * PI / 2.0,
        phi_h: 0.3,
        theta_d: (j as f64 + 0.5) * PI / 2.0 / d[1] as f64,
        phi_d: (k as f64 + 0.5) * PI / d[2] as f64,
    }
    .to_dirs()
}

/// Writes `src` as MERL on `grid` and checks that the reference lookup at every bin
/// midpoint returns the tabulated value at that bin's sample (f32, as stored), and the
/// negative marker × scale for bins whose sample is below the horizon.
fn model_as_merl_looks_up_its_samples(src: &dyn Brdf, grid: &Grid) {
    let t = tabulate(src, grid, &TabulateOptions::default()).unwrap();
    let bytes = merl::to_bytes(&t).unwrap();
    let m = MerlTable::from_bytes(&bytes, Path::new("m.binary")).unwrap();
    let d = m.dims;
    let lookup = MerlLookup::new(m);
    let mut idx = [0usize; 3];
    let mut exact = [0.0; 3];
    for cell in 0..grid.cells() {
        grid.unflatten(cell, &mut idx);
        let [i, j, k] = idx;
        let (wi, wo) = midpoint_dirs(i, j, k, d);
        let got = lookup.lookup_angles(wi.theta(), wi.phi(), wo.theta(), wo.phi());
        let (si, so) = grid.cell_dirs(&idx);
        if t.valid()[cell] {
            src.eval(si, so, &mut exact);
            for c in 0..3 {
                assert_eq!(
                    got[c] as f32,
                    t.cell(cell)[c],
                    "bin ({i}, {j}, {k}) channel {c}"
                );
                // …which is the model's value at the bin's sample position.
                assert!(
                    (got[c] - exact[c]).abs() <= 1e-7 * exact[c].abs(),
                    "bin ({i}, {j}, {k}) channel {c}: {} vs {}",
                    got[c],
                    exact[c]
                );
            }
        } else {
            assert_eq!(got, [0, 1, 2].map(|c| merl::INVALID_RAW * SCALE[c]));
        }
    }
}

#[test]
fn graded_model_written_as_merl_is_looked_up_at_every_bin() {
    model_as_merl_looks_up_its_samples(&Graded::new(), &Grid::merl());
}

#[test]
fn lambert_written_as_merl_is_looked_up_at_every_bin() {
    let m = Model::parse("lambert:albedo=0.8/0.5/0.2").unwrap();
    model_as_merl_looks_up_its_samples(&m, &Grid::merl());
}

#[test]
fn non_standard_merl_dims_work_end_to_end() {
    let g = parse_grid_spec("halfdiff3:12x10x24,warp=sqrt/linear/linear,at=edge").unwrap();
    assert_eq!(merl::merl_dims(&g), Some([12, 10, 24]));
    model_as_merl_looks_up_its_samples(&Graded::new(), &g);
}

fn graded_table(spec: &str) -> Table {
    let g = parse_grid_spec(spec).unwrap();
    tabulate(&Graded::new(), &g, &TabulateOptions::default()).unwrap()
}

#[test]
fn model_to_exr_f32_to_table_is_exact_for_every_lossless_compression() {
    let m = Model::parse("lambert:albedo=0.8/0.5/0.2").unwrap();
    let g = parse_grid_spec("halfdiff3:30x30x60,warp=sqrt/linear/linear,at=edge").unwrap();
    let lambert = tabulate(&m, &g, &TabulateOptions::default()).unwrap();
    let graded = graded_table("halfdiff4:8x16x8x16");
    let all = [
        ExrCompression::None,
        ExrCompression::Rle,
        ExrCompression::Zips,
        ExrCompression::Zip,
        ExrCompression::Piz,
    ];
    for t in [&lambert, &graded] {
        for compression in all {
            let opts = ExrOptions {
                sample_type: ExrSampleType::F32,
                compression,
            };
            let bytes = exr::to_bytes(t, &opts).unwrap();
            let back = exr::from_bytes(&bytes, Path::new("t.exr")).unwrap();
            assert_eq!(&back, t, "{compression:?}");
            // Reproducible: the same table gives the same bytes.
            assert!(
                exr::to_bytes(&back, &opts).unwrap() == bytes,
                "{compression:?}"
            );
        }
    }
}

#[test]
fn exr_f16_and_pxr24_are_lossy_but_bounded_and_say_so() {
    let t = graded_table("halfdiff3:16x16x32");
    for (sample_type, compression, rel) in [
        // f16: 11 significant bits → relative error ≤ 2^-11.
        (ExrSampleType::F16, ExrCompression::Zip, 1.0 / 2048.0),
        // PXR24: 24-bit floats (16 significant bits) → ≤ 2^-16.
        (ExrSampleType::F32, ExrCompression::Pxr24, 1.0 / 65536.0),
    ] {
        let opts = ExrOptions {
            sample_type,
            compression,
        };
        assert!(!opts.is_lossless());
        let back = exr::from_bytes(&exr::to_bytes(&t, &opts).unwrap(), Path::new("x")).unwrap();
        assert_eq!(back.valid(), t.valid());
        for (a, b) in back.data().iter().zip(t.data()) {
            assert!((a - b).abs() <= rel * b.abs(), "{opts:?}: {a} vs {b}");
        }
        assert!(
            back.provenance().notes.len() == t.provenance().notes.len() + 1,
            "{:?}",
            back.provenance().notes
        );
    }
}

#[test]
fn exr_f16_scales_values_beyond_its_range_instead_of_writing_inf() {
    let g = parse_grid_spec("halfdiff3:4x4x8").unwrap();
    let valid = g.geometric_mask();
    let data: Vec<f32> = (0..g.cells()).map(|i| 1e6 + i as f32 * 1000.0).collect();
    let t = Table::new(
        g,
        Channels::default_for(1),
        Provenance::default(),
        data,
        valid,
    )
    .unwrap();
    let opts = ExrOptions {
        sample_type: ExrSampleType::F16,
        compression: ExrCompression::None,
    };
    let bytes = exr::to_bytes(&t, &opts).unwrap();
    let h = exr::read_header(&bytes, Path::new("x")).unwrap();
    // max ≈ 1.127e6 needs 2^-5 (× 1/32 → 35,200 ≤ 65,504).
    assert_eq!(h.value_scale_log2, -5);
    let back = exr::from_bytes(&bytes, Path::new("x")).unwrap();
    for (a, b) in back.data().iter().zip(t.data()) {
        assert!(
            a.is_finite() && (a - b).abs() <= b.abs() / 2048.0,
            "{a} vs {b}"
        );
    }
}

#[test]
fn exr_header_survives_non_ascii_provenance() {
    let mut t = graded_table("halfdiff3:4x4x8");
    t.provenance_mut()
        .notes
        .push("φh = 0 for θ ≤ 90°, emoji 🦀".into());
    let bytes = exr::to_bytes(&t, &ExrOptions::default()).unwrap();
    let back = exr::from_bytes(&bytes, Path::new("x")).unwrap();
    assert_eq!(back, t);
}

#[test]
fn native_carries_exact_values_and_detects_their_damage() {
    let m = MerlTable {
        dims: [3, 2, 4],
        raw: (0..72)
            .map(|i| {
                if i % 5 == 0 {
                    -1.0
                } else {
                    0.1 + i as f64 / 7.0
                }
            })
            .collect(),
    };
    let t = m.to_table("small").unwrap();
    let bytes = native::to_bytes(&t, &CodecSpec::default()).unwrap();
    // 1.1 for the F64X section; 1.2 since the header is compressed (HEAZ), which covers it.
    assert_eq!(
        u16::from_le_bytes([bytes[10], bytes[11]]),
        native::VERSION_MINOR_HEAZ,
        "minor version"
    );
    let back = native::from_bytes(&bytes, Path::new("x.bpk")).unwrap();
    assert_eq!(back, t);
    assert_eq!(merl::to_bytes(&back).unwrap(), m.to_bytes());
    for i in 0..bytes.len() {
        let mut b = bytes.clone();
        b[i] ^= 0x04;
        let e = native::from_bytes(&b, Path::new("x")).unwrap_err();
        assert_eq!(e.exit_code(), 2, "flip at {i}: {e}");
    }
    // Tables without exact values write no F64X section (their version is the compressed
    // header's, 1.2; 1.0 before it).
    let plain = native::to_bytes(&t.clone().without_exact(), &CodecSpec::default()).unwrap();
    assert_eq!(
        u16::from_le_bytes([plain[10], plain[11]]),
        native::VERSION_MINOR_HEAZ
    );
    assert!(bytes.windows(4).any(|w| w == b"F64X"));
    assert!(!plain.windows(4).any(|w| w == b"F64X"));
}

#[test]
fn exact_values_that_disagree_with_the_samples_are_refused() {
    let t = graded_table("halfdiff3:4x4x8");
    let cell = t.valid().iter().position(|&v| v).unwrap();
    let mut raw: Vec<f64> = t.data().iter().map(|&v| v as f64).collect();
    raw[cell * 3 + 1] *= 1.001;
    let e = t
        .clone()
        .with_exact(ExactValues {
            scale: vec![1.0; 3],
            raw,
        })
        .unwrap_err()
        .to_string();
    assert!(e.contains(&format!("cell {cell} channel 1")), "{e}");
}

#[test]
fn malformed_exr_files_are_errors_with_exit_code_2() {
    let t = graded_table("halfdiff3:4x4x8");
    let opts = ExrOptions {
        sample_type: ExrSampleType::F32,
        compression: ExrCompression::None,
    };
    let bytes = exr::to_bytes(&t, &opts).unwrap();
    let p = Path::new("bad.exr");
    // Truncation at every length.
    for n in 0..bytes.len() {
        let e = io::decode_table(&bytes[..n], p).unwrap_err();
        assert_eq!(e.exit_code(), 2, "cut at {n}: {e}");
    }
    // Wrong magic: no longer an EXR at all.
    let mut b = bytes.clone();
    b[0] = b'X';
    let e = io::decode_table(&b, p).unwrap_err().to_string();
    assert!(e.contains("unknown format"), "{e}");
    // A NaN in a valid cell: patch the one cell holding a unique value.
    let cell = t.valid().iter().rposition(|&v| v).unwrap();
    let v = t.cell(cell)[2];
    let pos: Vec<usize> = bytes
        .windows(4)
        .enumerate()
        .filter(|(_, w)| *w == v.to_le_bytes())
        .map(|(i, _)| i)
        .collect();
    assert_eq!(pos.len(), 1, "the value must occur once");
    let mut b = bytes.clone();
    b[pos[0]..pos[0] + 4].copy_from_slice(&f32::NAN.to_le_bytes());
    let e = io::decode_table(&b, p).unwrap_err();
    assert_eq!(e.exit_code(), 2);
    assert!(e.to_string().contains(&format!("cell {cell}")), "{e}");
    // A plain image (no brdfpack attribute) is refused by name.
    let plain = {
        use ::exr::prelude::*;
        let mut out = Vec::new();
        Image::from_channels(
            (2, 2),
            SpecificChannels::rgb(|_: Vec2<usize>| (0.5f32, 0.5f32, 0.5f32)),
        )
        .write()
        .to_buffered(std::io::Cursor::new(&mut out))
        .unwrap();
        out
    };
    let e = io::decode_table(&plain, p).unwrap_err().to_string();
    assert!(e.contains("no `brdfpack` attribute"), "{e}");
}

#[test]
fn malformed_merl_files_are_errors_with_exit_code_2() {
    let m = MerlTable {
        dims: [2, 3, 4],
        raw: vec![0.25; 72],
    };
    let bytes = m.to_bytes();
    let p = Path::new("bad.binary");
    for n in [0, 5, 12, 13, bytes.len() - 1] {
        let e = io::decode_table(&bytes[..n], p).unwrap_err();
        assert_eq!(e.exit_code(), 2, "cut at {n}: {e}");
    }
    let mut wrong = bytes.clone();
    wrong[8..12].copy_from_slice(&5i32.to_le_bytes());
    let e = io::decode_table(&wrong, p).unwrap_err();
    assert_eq!(e.exit_code(), 2);
    assert!(e.to_string().contains("does not match dims 2 3 5"), "{e}");
    let mut inf = bytes.clone();
    inf[12 + 8 * 50..12 + 8 * 51].copy_from_slice(&f64::INFINITY.to_le_bytes());
    let e = io::decode_table(&inf, p).unwrap_err();
    assert_eq!(e.exit_code(), 2);
    assert!(
        e.to_string()
            .contains("value 50 (channel blue, cell 2) is inf"),
        "{e}"
    );
    // MERL output refuses a table it cannot hold.
    let e = io::encode_table(&graded_table("halfdiff3:4x4x8"), &OutputFormat::Merl).unwrap_err();
    assert_eq!(e.exit_code(), 2);
    assert!(e.to_string().contains("--grid merl"), "{e}");
}

#[test]
fn lossy_codecs_drop_exact_values_and_the_file_reads_back() {
    use brdfpack::codec::CodecRequest;
    // A MERL-grid table carrying exact f64 values, as read from a MERL file.
    let m = brdfpack::model::Model::parse("lambert:albedo=0.8/0.5/0.2").unwrap();
    let grid = brdfpack::grid::Grid::merl();
    let t = brdfpack::tabulate::tabulate(&m, &grid, &Default::default()).unwrap();
    let merl = brdfpack::io::merl::to_bytes(&t).unwrap();
    let with_exact =
        brdfpack::io::merl::from_bytes(&merl, std::path::Path::new("m.binary")).unwrap();
    assert!(with_exact.exact().is_some());
    for (spec, keeps) in [("lossless", true), ("dct:step=0.05", false), ("f16", false)] {
        let codec = CodecRequest::parse(spec)
            .unwrap()
            .resolve(&with_exact)
            .unwrap();
        let bytes = brdfpack::io::native::to_bytes(&with_exact, &codec).unwrap();
        let back = brdfpack::io::native::from_bytes(&bytes, std::path::Path::new("x.bpk")).unwrap();
        assert_eq!(back.exact().is_some(), keeps, "{spec}");
    }
}
