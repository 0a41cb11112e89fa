//! Entry points shared by the fuzz targets (`fuzz/fuzz_targets/*.rs`) and the corpus replay
//! test (`tests/fuzz_corpus.rs`): each takes arbitrary bytes, calls one library reader or
//! parser, and panics when the library breaks a promise (a panic inside it, or a NaN/Inf or
//! negative value where the contract forbids one). Errors are the expected outcome for junk.

use brdfpack::brdf::Brdf;
use brdfpack::geometry::Vec3;
use brdfpack::table::{Interp, Table};
use std::path::Path;

/// Fixed (wi, wo) pairs as (θi, φi, θo, φo) in radians: normal, grazing, retro, mirror,
/// off-plane, and one below the horizon (must give 0, never NaN).
const PAIRS: [(f64, f64, f64, f64); 7] = [
    (0.0, 0.0, 0.0, 0.0),
    (0.3, 0.0, 0.3, std::f64::consts::PI),
    (1.2, 0.4, 1.2, 0.4),
    (1.55, 0.0, 1.55, std::f64::consts::PI),
    (0.7, 1.0, 0.2, 2.5),
    (1.0, 5.9, 0.05, 3.0),
    (2.0, 0.0, 0.5, 1.0),
];

pub fn pairs() -> impl Iterator<Item = (Vec3, Vec3)> {
    PAIRS
        .iter()
        .map(|&(ti, pi, to, po)| (Vec3::from_spherical(ti, pi), Vec3::from_spherical(to, po)))
}

/// A decoded table must hold finite samples and interpolate to finite values.
fn check_table(t: &Table, what: &str) {
    for (i, v) in t.data().iter().enumerate() {
        assert!(v.is_finite(), "{what}: sample {i} is {v}");
    }
    let mut out = vec![0.0; t.channels().len()];
    for (wi, wo) in pairs() {
        for interp in [Interp::Linear, Interp::Nearest] {
            t.eval_into(wi, wo, interp, &mut out);
            for v in &out {
                assert!(
                    v.is_finite(),
                    "{what}: eval {interp:?} at {wi:?},{wo:?} = {v}"
                );
            }
        }
    }
}

pub fn native(data: &[u8]) {
    if let Ok(t) = brdfpack::io::native::from_bytes(data, Path::new("fuzz")) {
        check_table(&t, "native");
    }
}

pub fn merl(data: &[u8]) {
    if let Ok(t) = brdfpack::io::merl::from_bytes(data, Path::new("fuzz")) {
        check_table(&t, "merl");
    }
}

pub fn exr(data: &[u8]) {
    if let Ok(t) = brdfpack::io::exr::from_bytes(data, Path::new("fuzz")) {
        check_table(&t, "exr");
    }
}

pub fn rgl(data: &[u8]) {
    if let Ok(b) = brdfpack::io::rgl::RglBsdf::from_bytes(data, "fuzz") {
        let mut out = vec![0.0; b.channels().len()];
        for (wi, wo) in pairs() {
            b.eval(wi, wo, &mut out);
            for v in &out {
                assert!(v.is_finite(), "rgl: eval at {wi:?},{wo:?} = {v}");
            }
        }
    }
}

pub fn model(data: &[u8]) {
    let Ok(spec) = std::str::from_utf8(data) else {
        return;
    };
    // `@path` reads a file from disk: not a parser input worth fuzzing (and not hermetic).
    if spec.trim_start().starts_with('@') {
        return;
    }
    if let Ok(m) = brdfpack::model::Model::parse(spec) {
        let mut out = vec![0.0; m.channels().len()];
        for (wi, wo) in pairs() {
            m.eval(wi, wo, &mut out);
            for v in &out {
                assert!(
                    v.is_finite() && *v >= 0.0,
                    "model {spec:?}: eval at {wi:?},{wo:?} = {v}"
                );
            }
        }
    }
}

/// Frames `[u16 LE header length][header JSON][payload]` as a native file with correct
/// checksums (HEAD, DATA, END), so mutations reach the header and codec decoders instead of
/// stopping at a CRC mismatch.
pub fn frame_native(data: &[u8]) -> Vec<u8> {
    let (head, payload) = if data.len() >= 2 {
        let n = (u16::from_le_bytes([data[0], data[1]]) as usize).min(data.len() - 2);
        (&data[2..2 + n], &data[2 + n..])
    } else {
        (data, &[][..])
    };
    let mut out = Vec::new();
    out.extend_from_slice(&brdfpack::io::native::MAGIC);
    out.extend_from_slice(&1u16.to_le_bytes());
    out.extend_from_slice(&0u16.to_le_bytes());
    out.extend_from_slice(&3u32.to_le_bytes());
    let crc = crc32fast::hash(&out);
    out.extend_from_slice(&crc.to_le_bytes());
    for (tag, p) in [(b"HEAD", head), (b"DATA", payload), (b"END ", &[][..])] {
        out.extend_from_slice(tag);
        out.extend_from_slice(&(p.len() as u64).to_le_bytes());
        out.extend_from_slice(&crc32fast::hash(p).to_le_bytes());
        out.extend_from_slice(p);
    }
    out
}

/// Header + codec payload decode through a correctly framed native file.
pub fn native_framed(data: &[u8]) {
    native(&frame_native(data));
}

/// One fuzz target's check: panics when the library breaks a promise on `data`.
pub type Check = fn(&[u8]);

/// Every target by its directory name under `fuzz/corpus/`.
pub const TARGETS: [(&str, Check); 6] = [
    ("native", native),
    ("native_framed", native_framed),
    ("merl", merl),
    ("exr", exr),
    ("rgl", rgl),
    ("model", model),
];
