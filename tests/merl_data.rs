//! The MERL-format files of ../shared/data/merl: the reference lookup returns each file's own
//! values, and every route back to MERL (direct, native, EXR f32) reproduces the file byte
//! for byte. Skipped, with a printed reason, when ../shared is absent.

mod common;

use brdfpack::brdf::Brdf;
use brdfpack::codec::CodecSpec;
use brdfpack::geometry::HalfDiff;
use brdfpack::io::exr::{ExrCompression, ExrOptions, ExrSampleType};
use brdfpack::io::merl::{MerlLookup, MerlTable, SCALE};
use brdfpack::io::{self, Format, OutputFormat};
use brdfpack::math::PI;
use std::path::{Path, PathBuf};

use common::shared_dir;

/// The MERL files, or `None` (after printing why) when the data are absent.
fn merl_files(test: &str) -> Option<Vec<PathBuf>> {
    let Some(dir) = shared_dir().map(|d| d.join("data/merl")) else {
        eprintln!("{test}: skipped: ../shared not found (set BRDFPACK_SHARED)");
        return None;
    };
    let mut files: Vec<PathBuf> = std::fs::read_dir(&dir)
        .ok()?
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| p.extension().is_some_and(|x| x == "binary"))
        .collect();
    files.sort();
    if files.is_empty() {
        eprintln!("{test}: skipped: no .binary files in {}", dir.display());
        return None;
    }
    Some(files)
}

#[test]
fn reference_lookup_at_bin_midpoints_returns_the_files_values() {
    let Some(files) = merl_files("reference_lookup_at_bin_midpoints") else {
        return;
    };
    for f in files {
        let bytes = std::fs::read(&f).unwrap();
        assert_eq!(io::detect(&bytes, &f), Format::Merl);
        let m = MerlTable::from_bytes(&bytes, &f).unwrap();
        assert_eq!(m.dims, [90, 90, 180]);
        let n = m.cells();
        let lookup = MerlLookup::new(m.clone());
        let mut out = [0.0; 3];
        let mut above = 0;
        for i in 0..90 {
            for j in 0..90 {
                for k in 0..180 {
                    // Index-space midpoints: every bin maps back to itself (spec/formats.md).
                    let hd = HalfDiff {
                        theta_h: ((i as f64 + 0.5) / 90.0).powi(2) * PI / 2.0,
                        phi_h: 0.0,
                        theta_d: (j as f64 + 0.5) * PI / 180.0,
                        phi_d: (k as f64 + 0.5) * PI / 180.0,
                    };
                    let (wi, wo) = hd.to_dirs();
                    let got = lookup.lookup_angles(wi.theta(), wi.phi(), wo.theta(), wo.phi());
                    let cell = (i * 90 + j) * 180 + k;
                    for c in 0..3 {
                        let want = m.raw[c * n + cell] * SCALE[c];
                        assert_eq!(
                            got[c].to_bits(),
                            want.to_bits(),
                            "{}: bin ({i}, {j}, {k}) channel {c}: {} vs {want}",
                            f.display(),
                            got[c]
                        );
                    }
                    // As a Brdf: the same values above the horizon (negatives included).
                    if wi.z > 0.0 && wo.z > 0.0 {
                        above += 1;
                        lookup.eval(wi, wo, &mut out);
                        assert_eq!(out, got, "{}: eval at bin ({i}, {j}, {k})", f.display());
                    }
                }
            }
        }
        assert!(above > n / 2, "{above} of {n} midpoints above the horizon");
    }
}

#[test]
fn read_then_write_reproduces_the_file_byte_for_byte() {
    let Some(files) = merl_files("read_then_write") else {
        return;
    };
    for f in files {
        let bytes = std::fs::read(&f).unwrap();
        let t = io::decode_table(&bytes, &f).unwrap();
        assert!(t.exact().is_some());
        // Every valid cell's f32 sample is the file's value × scale rounded once.
        let stored = MerlTable::from_bytes(&bytes, &f).unwrap();
        let n = stored.cells();
        for cell in (0..n).step_by(997) {
            for (c, scale) in SCALE.iter().enumerate() {
                let want = (stored.raw[c * n + cell] * scale) as f32;
                if t.valid()[cell] {
                    assert_eq!(t.cell(cell)[c].to_bits(), want.to_bits());
                } else {
                    assert!(stored.raw[c * n + cell] < 0.0 || t.cell(cell)[c] == 0.0);
                }
            }
        }
        let out = io::encode_table(&t, &OutputFormat::Merl).unwrap();
        assert!(out == bytes, "{}: MERL → table → MERL differs", f.display());
    }
}

#[test]
fn read_then_native_then_merl_is_byte_for_byte() {
    let Some(files) = merl_files("read_then_native_then_merl") else {
        return;
    };
    for f in files {
        let bytes = std::fs::read(&f).unwrap();
        let t = io::decode_table(&bytes, &f).unwrap();
        // Level 1: the test is about exactness, not ratio.
        let native =
            io::encode_table(&t, &OutputFormat::Native(CodecSpec::ZstdF32 { level: 1 })).unwrap();
        let back = io::decode_table(&native, Path::new("x.bpk")).unwrap();
        assert_eq!(back, t);
        let out = io::encode_table(&back, &OutputFormat::Merl).unwrap();
        assert!(
            out == bytes,
            "{}: MERL → native → MERL differs",
            f.display()
        );
    }
}

#[test]
fn read_then_exr_f32_then_merl_is_byte_for_byte() {
    let Some(files) = merl_files("read_then_exr_f32_then_merl") else {
        return;
    };
    for f in files {
        let bytes = std::fs::read(&f).unwrap();
        let t = io::decode_table(&bytes, &f).unwrap();
        // RLE: lossless and fast (ZIP of the incompressible f64 planes takes seconds).
        let opts = ExrOptions {
            sample_type: ExrSampleType::F32,
            compression: ExrCompression::Rle,
        };
        let exr = io::encode_table(&t, &OutputFormat::Exr(opts)).unwrap();
        assert_eq!(io::detect(&exr, Path::new("x")), Format::Exr);
        let back = io::decode_table(&exr, Path::new("x.exr")).unwrap();
        assert_eq!(back, t);
        let out = io::encode_table(&back, &OutputFormat::Merl).unwrap();
        assert!(out == bytes, "{}: MERL → EXR → MERL differs", f.display());
    }
}
