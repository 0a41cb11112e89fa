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

/// The memory budget of the reader targets (1 MiB): a declared size beyond it must be
/// refused before anything of that size is allocated, and the decodes that pass stay small,
/// so an execution costs microseconds instead of the seconds a table of the 2 GiB default
/// budget would take (the first `sizes` run, under 64 MiB, managed 20 executions a second).
pub const READER_BUDGET: u64 = 1 << 20;

pub fn native(data: &[u8]) {
    brdfpack::memory::set_budget(READER_BUDGET);
    if let Ok(t) = brdfpack::io::native::from_bytes(data, Path::new("fuzz")) {
        check_table(&t, "native");
    }
}

pub fn merl(data: &[u8]) {
    brdfpack::memory::set_budget(READER_BUDGET);
    if let Ok(t) = brdfpack::io::merl::from_bytes(data, Path::new("fuzz")) {
        check_table(&t, "merl");
    }
}

pub fn exr(data: &[u8]) {
    brdfpack::memory::set_budget(READER_BUDGET);
    if let Ok(t) = brdfpack::io::exr::from_bytes(data, Path::new("fuzz")) {
        check_table(&t, "exr");
    }
}

pub fn rgl(data: &[u8]) {
    brdfpack::memory::set_budget(READER_BUDGET);
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

/// MDL `.mbsdf`: block sizes must account for the bytes exactly.
pub fn mbsdf(data: &[u8]) {
    brdfpack::memory::set_budget(READER_BUDGET);
    if let Ok(t) = brdfpack::io::mbsdf::from_bytes(data, Path::new("fuzz")) {
        check_table(&t, "mbsdf");
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

/// A GGX gold conductor (3 channels, values over several decades) tabulated on a small
/// halfdiff3 grid: the table the `codec` and `eval` targets work on (built once).
pub fn small_table() -> &'static Table {
    static TABLE: std::sync::OnceLock<Table> = std::sync::OnceLock::new();
    TABLE.get_or_init(|| {
        let m = brdfpack::model::Model::parse("ggx:alpha=0.15,fresnel=au").expect("GGX spec");
        let g = brdfpack::grid::parse_grid_spec("halfdiff3:6x6x8,warp=sqrt/linear/linear")
            .expect("grid spec");
        brdfpack::tabulate::tabulate(&m, &g, &Default::default()).expect("GGX tabulates")
    })
}

/// The `eval` stream parser (`brdfpack eval SOURCE < pairs`) on arbitrary text, through the
/// binary (the parser is part of the CLI, which the library does not contain): its path is
/// `BRDFPACK_BIN` or, in the crate's tests, the binary cargo built; without either the check
/// is skipped. The first byte picks the input form, output form, `--echo` and the source (the
/// GGX model or its table); the rest is the stream. Asserted: an error is an input error
/// (exit 2); every output number is finite; rows have the channel count (+6 echoed
/// components, which are unit vectors).
pub fn eval(data: &[u8]) {
    use std::io::Write;
    let Some((&mode, rest)) = data.split_first() else {
        return;
    };
    if std::str::from_utf8(rest).is_err() {
        return;
    }
    let Some(bin) = std::env::var_os("BRDFPACK_BIN")
        .map(std::path::PathBuf::from)
        .or_else(|| option_env!("CARGO_BIN_EXE_brdfpack").map(Into::into))
    else {
        return;
    };
    let form = ["auto", "text", "csv", "jsonl"][(mode & 3) as usize];
    let format = ["text", "csv", "jsonl"][((mode >> 2) & 3) as usize % 3];
    let echo = mode & 0x10 != 0;
    static TABLE_FILE: std::sync::OnceLock<std::path::PathBuf> = std::sync::OnceLock::new();
    let table_file = TABLE_FILE.get_or_init(|| {
        let path =
            std::env::temp_dir().join(format!("brdfpack-fuzz-eval-{}.bpk", std::process::id()));
        brdfpack::io::write_table(
            small_table(),
            &path,
            &brdfpack::io::OutputFormat::Native(Default::default()),
        )
        .expect("the small table writes");
        path
    });
    let model_spec = "ggx:alpha=0.15,fresnel=au";
    let (source, channels) = if mode & 0x20 != 0 {
        (
            table_file.to_str().expect("a UTF-8 temp path"),
            small_table().channels().len(),
        )
    } else {
        (model_spec, 3)
    };
    let mut cmd = std::process::Command::new(&bin);
    cmd.args(["eval", source, "--input", form, "--format", format]);
    if echo {
        cmd.arg("--echo");
    }
    let mut child = cmd
        .stdin(std::process::Stdio::piped())
        .stdout(std::process::Stdio::piped())
        .stderr(std::process::Stdio::piped())
        .spawn()
        .expect("brdfpack runs");
    // The binary may stop reading at a bad line: a closed pipe is not a failure here.
    let _ = child.stdin.take().expect("stdin").write_all(rest);
    let run = child.wait_with_output().expect("brdfpack finishes");
    match run.status.code() {
        Some(0) => {}
        Some(2) => return,
        other => panic!(
            "eval: exit {other:?} is not an input error: {}",
            String::from_utf8_lossy(&run.stderr)
        ),
    }
    let out = String::from_utf8(run.stdout).expect("eval output is UTF-8");
    let width = channels + if echo { 6 } else { 0 };
    let mut lines = out.lines();
    if format == "csv" {
        let header = lines.next().expect("csv output starts with a header");
        assert_eq!(
            header.split(',').count(),
            width,
            "eval: csv header {header:?}"
        );
    }
    for line in lines {
        let fields: Vec<&str> = match format {
            "text" => line.split(' ').collect(),
            "csv" => line.split(',').collect(),
            _ => line
                .split(|c: char| "{}[],:".contains(c))
                .filter(|f| !f.is_empty() && !f.starts_with('"'))
                .collect(),
        };
        assert_eq!(fields.len(), width, "eval: row {line:?}");
        let v: Vec<f64> = fields
            .iter()
            .map(|f| {
                let x: f64 = f
                    .parse()
                    .unwrap_or_else(|_| panic!("eval: {f:?} in {line:?} is not a number"));
                assert!(x.is_finite(), "eval: {x} in row {line:?}");
                x
            })
            .collect();
        if echo {
            for w in [&v[0..3], &v[3..6]] {
                let len = w.iter().map(|x| x * x).sum::<f64>().sqrt();
                assert!((len - 1.0).abs() < 1e-12, "eval: echoed {w:?} in {line:?}");
            }
        }
    }
}

/// Grid spec strings (`--grid`): a grid that parses has finite sample angles inside each
/// axis range whose continuous index maps back to the sample index, finite unit directions
/// and non-negative cell measures, and the same grid after its header description.
pub fn grid(data: &[u8]) {
    let Ok(spec) = std::str::from_utf8(data) else {
        return;
    };
    let Ok(g) = brdfpack::grid::parse_grid_spec(spec) else {
        return;
    };
    let back = brdfpack::grid::Grid::from_desc(&g.desc())
        .unwrap_or_else(|e| panic!("grid {spec:?}: its own description fails: {e}"));
    assert_eq!(back, g, "grid {spec:?}: description round trip");
    for a in g.axes() {
        let (lo, hi) = a.range();
        assert!(
            lo.is_finite() && hi.is_finite() && lo < hi,
            "grid {spec:?}: {lo}..{hi}"
        );
        for i in [0, 1, a.n / 2, a.n - 1] {
            let i = i.min(a.n - 1);
            let x = a.sample(i);
            assert!(
                x.is_finite() && lo <= x && x <= hi,
                "grid {spec:?}: sample {i} = {x}"
            );
            let ci = a.continuous_index(x);
            assert!(
                (ci - i as f64).abs() <= 1e-6,
                "grid {spec:?}: axis {:?} index {i} -> {x} -> {ci}",
                a.quantity
            );
        }
    }
    let cells = g.cells();
    let mut idx = vec![0; g.axes().len()];
    for flat in [0, cells / 3, cells / 2, cells - 1] {
        g.unflatten(flat, &mut idx);
        for (k, a) in g.axes().iter().enumerate() {
            assert!(idx[k] < a.n, "grid {spec:?}: cell {flat} -> {idx:?}");
        }
        let (wi, wo) = g.cell_dirs(&idx);
        for w in [wi, wo] {
            assert!(
                w.is_finite() && (w.length() - 1.0).abs() < 1e-12,
                "grid {spec:?}: cell {idx:?} direction {w:?}"
            );
        }
        let m = g.cell_measure(&idx);
        assert!(
            m.is_finite() && m >= 0.0,
            "grid {spec:?}: cell {idx:?} measure {m}"
        );
        if let Some(c) = g.coords_of(wi, wo) {
            for (k, a) in g.axes().iter().enumerate() {
                let (lo, hi) = a.range();
                let slack = 1e-9 * (hi - lo);
                assert!(
                    c[k].is_finite() && c[k] >= lo - slack && c[k] <= hi + slack,
                    "grid {spec:?}: cell {idx:?} coordinate {k} = {}",
                    c[k]
                );
            }
        }
    }
}

/// Codec request strings (`--codec`): a request that parses prints as a spec that parses back
/// to it, resolves for the small table, encodes it (an error only for a predictor whose
/// orders do not match the grid's 3 axes) and decodes its own payload to finite values, bit
/// for bit for the lossless codecs and 0 in invalid cells. zstd runs at level ≤ 3 here.
pub fn codec(data: &[u8]) {
    use brdfpack::codec::{CodecRequest, Layout};
    let Ok(spec) = std::str::from_utf8(data) else {
        return;
    };
    let Ok(req) = CodecRequest::parse(spec) else {
        return;
    };
    let text = req.to_string();
    let again = CodecRequest::parse(&text)
        .unwrap_or_else(|e| panic!("codec {spec:?}: its text {text:?} fails: {e}"));
    assert_eq!(again, req, "codec {spec:?}: text {text:?}");
    let req = match req.level() {
        Some(level) => req.with_level(level.min(3)),
        None => req,
    };
    let t = small_table();
    let resolved = match req.resolve(t) {
        Ok(r) => r,
        // Tucker ranks are checked against the grid: more ranks than axes or a rank beyond
        // an axis resolution is refused, naming the rank.
        Err(e)
            if matches!(&req, CodecRequest::Tucker { ranks, .. }
                if ranks.len() != t.grid().axes().len()
                    || ranks.iter().zip(t.grid().shape()).any(|(r, n)| *r > n))
                && e.to_string().contains("tucker rank") =>
        {
            return;
        }
        Err(e) => panic!("codec {spec:?}: resolve fails: {e}"),
    };
    let payload = match resolved.encode(t) {
        Ok(p) => p,
        Err(e) => {
            let wrong_orders = matches!(&req, CodecRequest::Lossless { predict: Some(p), .. }
                if p.orders.len() != t.grid().axes().len());
            // A DCT step so small that a coefficient needs more than 2^30 levels is refused
            // by the encoder (dct::check_range), not clamped.
            let dct_range = matches!(&req, CodecRequest::Dct { .. } | CodecRequest::Tucker { .. })
                && e.to_string().contains("exceeds 2^30 levels");
            assert!(
                wrong_orders || dct_range,
                "codec {spec:?}: encode fails: {e}"
            );
            return;
        }
    };
    let decoded = resolved
        .decode(&payload, &Layout::of(t))
        .unwrap_or_else(|e| panic!("codec {spec:?}: own payload fails to decode: {e}"));
    assert_eq!(decoded.len(), t.data().len(), "codec {spec:?}");
    let c = t.channels().len();
    for (cell, &ok) in t.valid().iter().enumerate() {
        for k in 0..c {
            let (a, b) = (decoded[cell * c + k], t.data()[cell * c + k]);
            assert!(a.is_finite(), "codec {spec:?}: cell {cell} decodes to {a}");
            if !ok {
                assert_eq!(a, 0.0, "codec {spec:?}: invalid cell {cell}");
            } else if resolved.is_lossless() {
                assert_eq!(a.to_bits(), b.to_bits(), "codec {spec:?}: cell {cell}");
            }
        }
    }
    assert_eq!(
        resolved.is_lossless(),
        matches!(
            req,
            CodecRequest::ZstdF32 { .. } | CodecRequest::Lossless { .. }
        )
    );
}

/// One fuzz target's check: panics when the library breaks a promise on `data`.
pub type Check = fn(&[u8]);

/// Every target by its directory name under `fuzz/corpus/`.
pub const TARGETS: [(&str, Check); 11] = [
    ("native", native),
    ("native_framed", native_framed),
    ("merl", merl),
    ("exr", exr),
    ("rgl", rgl),
    ("model", model),
    ("eval", eval),
    ("grid", grid),
    ("codec", codec),
    ("sizes", sizes),
    ("mbsdf", mbsdf),
];

/// Size-lying headers (issue 20): the first 8 bytes declare a halfdiff3 grid (three u16
/// axis sizes + 1, so up to 2⁴⁸ cells within the per-axis limit) and a channel count (u16
/// mod 4096 + 1 when bits 1–6 of byte 8 are all set, else mod 8 + 1: a header naming
/// thousands of channels takes ~20 ms to parse under the sanitizers, so they are one input in
/// 64); bit 0 of byte 8 picks the mask kind, the rest is a zstd-f32 payload. Under a
/// 64 KiB budget, a declared table whose decoding needs more must be
/// refused by the budget check (`needs about`), before anything of its size is allocated;
/// libFuzzer's RSS limit catches an allocation that slips through.
pub fn sizes(data: &[u8]) {
    // 64 KiB, not the readers' 1 MiB: the checks are the same at any budget, and what is
    // accepted builds its geometric mask cell by cell under the sanitizers (most of a run's
    // time at 1 MiB: ~220 executions a second).
    const BUDGET: u64 = 64 << 10;
    brdfpack::memory::set_budget(BUDGET);
    if data.len() < 9 {
        return;
    }
    let u = |k: usize| u16::from_le_bytes([data[2 * k], data[2 * k + 1]]) as usize;
    let dims = [u(0) + 1, u(1) + 1, u(2) + 1];
    let channels = if data[8] & 0x7e == 0x7e {
        u(3) % 4096 + 1
    } else {
        u(3) % 8 + 1
    };
    let explicit = data[8] & 1 == 1;
    // Written by hand: the fuzz crate has no serde_json of its own.
    let axes: Vec<String> = ["theta_h", "theta_d", "phi_d"]
        .iter()
        .zip(dims)
        .map(|(q, n)| {
            format!(r#"{{"quantity":"{q}","n":{n},"warp":"linear","placement":"center"}}"#)
        })
        .collect();
    let names: Vec<String> = (0..channels).map(|i| format!("\"c{i}\"")).collect();
    let head = format!(
        r#"{{"format":"brdfpack-table","grid":{{"kind":"halfdiff3","axes":[{}]}},"channels":{{"names":[{}]}},"provenance":{{"source":"fuzz","tool":"fuzz"}},"codec":{{"kind":"zstd_f32","level":3}},"mask":"{}","valid_cells":1}}"#,
        axes.join(","),
        names.join(","),
        if explicit { "explicit" } else { "geometric" }
    )
    .into_bytes();
    let mut framed = (head.len() as u16).to_le_bytes().to_vec();
    framed.extend_from_slice(&head);
    framed.extend_from_slice(&data[9..]);
    let cells = dims.iter().product::<usize>();
    let needs = brdfpack::memory::table_bytes(cells, channels).saturating_mul(2);
    match brdfpack::io::native::from_bytes(&frame_native(&framed), Path::new("fuzz")) {
        Ok(t) => {
            assert!(
                needs <= BUDGET,
                "{needs} bytes decoded under a {BUDGET}-byte budget"
            );
            assert!(t.data().iter().all(|x| x.is_finite()));
        }
        Err(e) => {
            assert_eq!(e.exit_code(), 2, "{e}");
            // Refused up front: by the budget, or by the grid's cell limit (2³¹).
            let m = e.to_string();
            if needs > BUDGET {
                assert!(
                    m.contains("needs about") || m.contains("exceed the limit"),
                    "{dims:?} × {channels}: {m}"
                );
            }
        }
    }
}
