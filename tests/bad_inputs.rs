//! The bad-input catalogue (issue 7): every case is an end-to-end CLI run that must exit with
//! code 2 (bad input), print one `brdfpack:` message naming the problem on stderr, print
//! nothing on stdout, and write nothing to the output path.

use assert_cmd::Command;
use std::path::Path;

/// Writes the malformed files the cases refer to into `dir`.
fn make_files(dir: &Path) {
    let ok = Command::cargo_bin("brdfpack")
        .unwrap()
        .args([
            "tabulate",
            "lambert:albedo=0.8/0.5/0.2",
            "--grid",
            "halfdiff3:4",
            "-o",
            "-",
        ])
        .output()
        .unwrap()
        .stdout;
    assert!(ok.starts_with(b"\x89BPK"));
    let exr = Command::cargo_bin("brdfpack")
        .unwrap()
        .args([
            "convert",
            "lambert",
            "--grid",
            "halfdiff3:4",
            "--format",
            "exr",
            "-o",
            "-",
        ])
        .output()
        .unwrap()
        .stdout;
    let mono = Command::cargo_bin("brdfpack")
        .unwrap()
        .args(["tabulate", "lambert", "--grid", "halfdiff3:4", "-o", "-"])
        .output()
        .unwrap()
        .stdout;
    let w = |name: &str, bytes: &[u8]| std::fs::write(dir.join(name), bytes).unwrap();
    w("ok.bpk", &ok);
    w("mono.bpk", &mono);
    w("truncated.bpk", &ok[..ok.len() / 2]);
    let mut flipped = ok.clone();
    let mid = flipped.len() / 2;
    flipped[mid] ^= 0x01;
    w("flipped.bpk", &flipped);
    let mut oversized = ok.clone();
    oversized.extend_from_slice(b"trailing garbage");
    w("oversized.bpk", &oversized);
    w("empty.bpk", b"");
    let mut wrong_magic = ok.clone();
    wrong_magic[1] = b'X';
    w("wrong-magic.bpk", &wrong_magic);
    w("truncated.exr", &exr[..exr.len() / 2]);
    w("empty.exr", b"");
    // MERL: right dims, too few values; wrong dims; a NaN value.
    let mut merl = Vec::new();
    for d in [90i32, 90, 180] {
        merl.extend_from_slice(&d.to_le_bytes());
    }
    merl.extend_from_slice(&[0u8; 800]);
    w("truncated.binary", &merl);
    let mut dims = Vec::new();
    for d in [2i32, 2, 2] {
        dims.extend_from_slice(&d.to_le_bytes());
    }
    let mut wrong_dims = dims.clone();
    wrong_dims.extend_from_slice(&[0u8; 8 * 3 * 7]);
    w("wrong-dims.binary", &wrong_dims);
    let mut nan = dims;
    for i in 0..24 {
        let v = if i == 5 { f64::NAN } else { 1.0 };
        nan.extend_from_slice(&v.to_le_bytes());
    }
    w("nan.binary", &nan);
    // Tucker files whose header was edited (checksums recomputed): a rank beyond the axis
    // resolution, a zero rank, a factor step out of range, a NaN core step.
    let tucker = Command::cargo_bin("brdfpack")
        .unwrap()
        .args([
            "compress",
            &dir.join("ok.bpk").display().to_string(),
            "--codec",
            "tucker:ranks=2x2x2,step=0.01",
            "-o",
            "-",
        ])
        .output()
        .unwrap()
        .stdout;
    assert!(tucker.starts_with(b"\x89BPK"));
    let edit = |f: &dyn Fn(&mut serde_json::Value)| {
        with_header(&tucker, |h| {
            let mut v: serde_json::Value = serde_json::from_str(h).unwrap();
            f(&mut v["codec"]["tucker"]);
            v.to_string()
        })
    };
    w(
        "tucker-rank.bpk",
        &edit(&|t| t["ranks"] = serde_json::json!([99, 2, 2])),
    );
    w(
        "tucker-zero.bpk",
        &edit(&|t| t["ranks"] = serde_json::json!([2, 0, 2])),
    );
    w(
        "tucker-factor.bpk",
        &edit(&|t| t["factor_step"] = serde_json::json!(1e9)),
    );
    w(
        "tucker-step.bpk",
        &edit(&|t| t["step"] = serde_json::json!([0.01, -1.0, 0.01])),
    );
    w("truncated.bsdf", b"tensor_file\0\x01\x00\x05\x00");
    w("not-a-table.txt", b"hello");
    w("model.json", br#"{"model": "ggx", "alpha": "rough"}"#);
    w("broken.json", b"{\"model\": ");
}

/// `file` (a native table) with its header JSON replaced by `edit(header)`, every length and
/// checksum recomputed, so that only the header's content is wrong. A compressed `HEAZ`
/// header is written back as a plain `HEAD` (readers take either).
fn with_header(file: &[u8], edit: impl Fn(&str) -> String) -> Vec<u8> {
    let mut out = file[..20].to_vec();
    let mut pos = 20;
    while pos < file.len() {
        let tag = &file[pos..pos + 4];
        let len = u64::from_le_bytes(file[pos + 4..pos + 12].try_into().unwrap()) as usize;
        let mut payload = file[pos + 16..pos + 16 + len].to_vec();
        let mut tag = tag;
        if tag == b"HEAZ" {
            payload = zstd::decode_all(&payload[..]).unwrap();
            tag = b"HEAD";
        }
        if tag == b"HEAD" {
            payload = edit(std::str::from_utf8(&payload).unwrap()).into_bytes();
        }
        out.extend_from_slice(tag);
        out.extend_from_slice(&(payload.len() as u64).to_le_bytes());
        out.extend_from_slice(&crc32fast::hash(&payload).to_le_bytes());
        out.extend_from_slice(&payload);
        pos += 16 + len;
        // `compress -o -` prints its report after the file.
        if tag == b"END " {
            break;
        }
    }
    out
}

/// (arguments, a phrase the message must contain). `OUT` is replaced by the output path and
/// `DIR/` by the folder of malformed files.
const CASES: &[(&str, &str)] = &[
    // Model specs and parameters.
    ("tabulate nosuchmodel -o OUT", "unknown model"),
    ("tabulate ggx:alpha=-1 -o OUT", "alpha = -1 is out of range"),
    ("tabulate ggx:alpha=nan -o OUT", "alpha = nan"),
    ("tabulate ggx:alpha=inf -o OUT", "alpha"),
    ("tabulate ggx:alpha=0.2,alpha_x=0.1 -o OUT", "both given"),
    ("tabulate ggx:roughness=0.2 -o OUT", "roughness"),
    ("tabulate lambert:albedo=1.5 -o OUT", "albedo = 1.5"),
    ("tabulate lambert:albedo=0.5/x/0.2 -o OUT", "albedo"),
    ("tabulate phong:exponent=-3 -o OUT", "exponent"),
    (
        "tabulate ggx:alpha=0.2,fresnel=unobtainium -o OUT",
        "unobtainium",
    ),
    (
        "tabulate ggx:alpha=0.2,fresnel=conductor,eta=0.2/0.9,k=3.9/2.4/2.1 -o OUT",
        "eta",
    ),
    ("tabulate ggx:alpha=0.2,ior=1.5 -o OUT", "ior"),
    ("tabulate mirror -o OUT", "mirror"),
    (
        "tabulate {\"model\":\"lambert\",\"albedo\":-1} -o OUT",
        "albedo",
    ),
    ("tabulate @DIR/model.json -o OUT", "alpha"),
    ("tabulate @DIR/broken.json -o OUT", "broken.json"),
    ("tabulate lafortune:norm=ngan,lobe=1:2:1:10 -o OUT", "ngan"),
    // Grid specs.
    ("tabulate lambert --grid cube:4 -o OUT", "unknown kind"),
    (
        "tabulate lambert --grid halfdiff3:0x4x4 -o OUT",
        "resolution 0",
    ),
    (
        "tabulate lambert --grid halfdiff3:4x4 -o OUT",
        "2 resolution values",
    ),
    ("tabulate lambert --grid halfdiff3:4,warp=log -o OUT", "log"),
    (
        "tabulate lambert --grid halfdiff3:4,theta-max=95 -o OUT",
        "theta-max",
    ),
    (
        "tabulate lambert --grid halfdiff3:4,warp=linear/linear/sqrt -o OUT",
        "periodic",
    ),
    (
        "tabulate ggx:alpha_x=0.1,alpha_y=0.3 --grid halfdiff3:4 -o OUT",
        "anisotropic",
    ),
    // Outputs and flags.
    (
        "tabulate lambert --grid halfdiff3:4 -o DIR/missing-dir/x.bpk",
        "does not exist",
    ),
    (
        "tabulate lambert --grid halfdiff3:4 -o DIR/name.unknown",
        "cannot tell the output format",
    ),
    (
        "convert lambert --grid halfdiff3:4 -o DIR/x.binary",
        "MERL .binary needs",
    ),
    (
        "convert DIR/mono.bpk -o DIR/x.binary --grid merl",
        "3 channels",
    ),
    (
        "pack lambert --grid halfdiff3:4 --samples 0 -o OUT",
        "--samples 0",
    ),
    (
        "check DIR/ok.bpk --against lambert --max-log-rmse=-1",
        "max-log-rmse",
    ),
    ("compress DIR/ok.bpk -o OUT --codec dct:step=-1", "step"),
    (
        "compress DIR/ok.bpk -o OUT --codec nosuchcodec",
        "nosuchcodec",
    ),
    (
        "compress DIR/ok.bpk -o OUT --codec tucker:ranks=2x2",
        "tucker ranks [2, 2]: expected 3",
    ),
    (
        "compress DIR/ok.bpk -o OUT --codec tucker:ranks=2x2x999",
        "tucker rank 999 on axis 2",
    ),
    (
        "convert DIR/tucker-rank.bpk -o OUT",
        "tucker rank 99 on axis 0",
    ),
    (
        "convert DIR/tucker-zero.bpk -o OUT",
        "tucker rank 0 on axis 1",
    ),
    ("convert DIR/tucker-factor.bpk -o OUT", "factor_step"),
    ("convert DIR/tucker-step.bpk -o OUT", "tucker steps"),
    (
        "compress DIR/ok.bpk -o OUT --max-error foo=1",
        "unknown metric",
    ),
    // Files of each format: truncated, bit-flipped, oversized, zero-length, wrong magic,
    // wrong dimensions, non-finite data.
    ("convert DIR/truncated.bpk -o OUT", "truncated"),
    ("convert DIR/flipped.bpk -o OUT", "checksum"),
    ("convert DIR/oversized.bpk -o OUT", "unexpected bytes"),
    ("convert DIR/empty.bpk -o OUT", "0 bytes"),
    ("convert DIR/wrong-magic.bpk -o OUT", "wrong-magic.bpk"),
    ("convert DIR/truncated.exr -o OUT", "truncated.exr"),
    ("convert DIR/empty.exr -o OUT", "empty.exr"),
    ("convert DIR/truncated.binary -o OUT", "truncated.binary"),
    ("convert DIR/wrong-dims.binary -o OUT", "wrong-dims.binary"),
    ("convert DIR/nan.binary -o OUT", "NaN"),
    ("convert DIR/truncated.bsdf -o OUT", "truncated.bsdf"),
    ("convert DIR/not-a-table.txt -o OUT", "not-a-table.txt"),
    ("check DIR/truncated.bpk --against lambert", "truncated"),
    ("inspect DIR/flipped.bpk", "checksum"),
    // Directions.
    ("eval lambert --wi 0,0,0 --wo 0,0,1", "zero length"),
    ("eval lambert --wi nan,0,1 --wo 0,0,1", "nan"),
    ("eval lambert --wi 0,0 --wo 0,0,1", "--wi"),
    (
        "eval DIR/ok.bpk --interp merl --wi 0,0,1 --wo 0,0,1",
        "MERL",
    ),
];

#[test]
fn every_bad_input_exits_2_with_a_message_and_writes_nothing() {
    let dir = tempfile::tempdir().unwrap();
    make_files(dir.path());
    let out = dir.path().join("out.bpk");
    let d = format!("{}/", dir.path().display());
    assert!(CASES.len() >= 40);
    for (args, needle) in CASES {
        let args: Vec<String> = args
            .split(' ')
            .map(|a| {
                if a == "OUT" {
                    out.display().to_string()
                } else {
                    a.replace("DIR/", &d)
                }
            })
            .collect();
        let o = Command::cargo_bin("brdfpack")
            .unwrap()
            .args(&args)
            .output()
            .unwrap();
        let stderr = String::from_utf8_lossy(&o.stderr);
        assert_eq!(o.status.code(), Some(2), "{args:?}: {stderr}");
        assert!(o.stdout.is_empty(), "{args:?}: stdout not empty");
        assert!(stderr.starts_with("brdfpack: "), "{args:?}: {stderr}");
        assert!(
            stderr.contains(needle),
            "{args:?}: {stderr:?} lacks {needle:?}"
        );
        assert!(!out.exists(), "{args:?} wrote {}", out.display());
        for name in ["x.binary", "name.unknown"] {
            assert!(!dir.path().join(name).exists(), "{args:?} wrote {name}");
        }
    }
}
