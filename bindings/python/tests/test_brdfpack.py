"""The Python module against the CLI (issue 25): `eval` gives the bits `brdfpack eval` prints
for every kind of source, arrays have their documented shapes, bad input raises with the
CLI's message, and tabulate -> compress -> save -> load -> eval round-trips.

Needs the installed module and the CLI binary (env BRDFPACK_BIN, default target/debug/brdfpack
of the repository). Files of ../shared (env BRDFPACK_SHARED) are used when present."""

import json
import os
import subprocess
from pathlib import Path

import numpy as np
import pytest

import brdfpack

REPO = Path(__file__).resolve().parents[3]
BIN = os.environ.get("BRDFPACK_BIN", str(REPO / "target" / "debug" / "brdfpack"))
SHARED = Path(os.environ.get("BRDFPACK_SHARED") or REPO.parent / "shared")

MODEL = "ggx:alpha=0.3,fresnel=au"
GRID3 = "halfdiff3:24x12x24"
N_PAIRS = 10_000


def cli(*args, stdin=None, check=True):
    r = subprocess.run([BIN, *args], input=stdin, capture_output=True, text=True)
    if check and r.returncode != 0:
        raise AssertionError(f"brdfpack {' '.join(args)}: exit {r.returncode}: {r.stderr}")
    return r


def random_pairs(n, seed):
    """Vectors of random length and direction, a tenth of them below the horizon."""
    rng = np.random.default_rng(seed)
    wi = rng.normal(size=(n, 3)) * rng.uniform(0.1, 10.0, size=(n, 1))
    wo = rng.normal(size=(n, 3)) * rng.uniform(0.1, 10.0, size=(n, 1))
    wi[:, 2] = np.abs(wi[:, 2])
    wo[:, 2] = np.abs(wo[:, 2])
    wo[::10, 2] *= -1.0
    return wi, wo


def cli_eval(source, wi, wo, *extra):
    """`brdfpack eval SOURCE` on a text stream of the pairs; %.17g round-trips every f64."""
    lines = "".join(
        " ".join(f"{x:.17g}" for x in (*a, *b)) + "\n" for a, b in zip(wi, wo)
    )
    out = cli("eval", source, "--input", "text", *extra, stdin=lines).stdout
    return np.array([[float(x) for x in line.split()] for line in out.splitlines()])


def assert_same_bits(a, b, what):
    assert a.shape == b.shape, f"{what}: shape {a.shape} vs {b.shape}"
    diff = np.flatnonzero(a.view(np.uint64) != b.view(np.uint64))
    assert diff.size == 0, (
        f"{what}: {diff.size} values differ, first at {diff[0]}: "
        f"{a.flat[diff[0]]!r} vs {b.flat[diff[0]]!r}"
    )


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    """Tables written by the CLI: a .bpk of every codec family, EXR, MERL, MDL."""
    d = tmp_path_factory.mktemp("tables")
    out = {}
    codecs = {
        "lossless": "lossless",
        "zstd-f32": "zstd-f32",
        "f16": "f16",
        "uniform": "uniform:bits=12",
        "dct-context": "dct:step=0.05",
        "dct-zstd": "dct:step=0.05,coding=zstd",
        "dct-residual": "dct:step=0.05,residual=0.01",
        "tucker": "tucker:ranks=12x8x12",
    }
    for name, codec in codecs.items():
        p = d / f"{name}.bpk"
        cli("tabulate", MODEL, "--grid", GRID3, "--codec", codec, "-o", str(p))
        out[f"bpk {name}"] = p
    out["exr"] = d / "t.exr"
    cli("tabulate", MODEL, "--grid", "halfdiff4:12x8x12x16", "-o", str(out["exr"]))
    out["merl"] = d / "t.binary"
    cli("tabulate", MODEL, "--grid", "merl", "-o", str(out["merl"]))
    out["mbsdf"] = d / "t.mbsdf"
    cli("tabulate", MODEL, "--grid", "spherical3:16x16x32", "-o", str(out["mbsdf"]))
    out["spherical4 bpk"] = d / "s4.bpk"
    cli("tabulate", MODEL, "--grid", "spherical4:8x12x8x12", "-o", str(out["spherical4 bpk"]))
    return out


def sources(files):
    """(label, spec) of every source kind; shared files only when present."""
    s = [("model", MODEL), ("model sum", "lambert:albedo=0.2/0.4/0.6+phong:albedo=0.3,exponent=20")]
    s += [(k, str(v)) for k, v in files.items()]
    s += [("fixture bpk", str(REPO / "fixtures/codec/ggx-dct-context-v1.bpk"))]
    s += [("rgl fixture", str(REPO / "fixtures/rgl/tiny.bsdf"))]
    s += [("mbsdf fixture", str(REPO / "fixtures/mbsdf/rgb_2x3.mbsdf"))]
    for rel in ["data/merl/gold-metallic-paint.binary", "data/rgl/paper_white_rgb.bsdf"]:
        p = SHARED / rel
        if p.exists():
            s.append((f"shared {rel}", str(p)))
        else:
            print(f"skipping {rel}: {p} not found")
    return s


def test_eval_equals_the_cli_bit_for_bit(files):
    wi, wo = random_pairs(N_PAIRS, 7)
    for label, spec in sources(files):
        src = brdfpack.open(spec)
        want = cli_eval(spec, wi, wo)
        got = src.eval(wi, wo, exact=True)
        assert got.dtype == np.float64
        assert got.shape == (N_PAIRS, len(src.channels)), label
        assert_same_bits(got, want, label)
        # The default, batched path: the same bits for every source, tables included.
        assert_same_bits(src.eval(wi, wo), want, f"{label} (batched)")


def test_lookups_match_the_cli(files):
    wi, wo = random_pairs(2000, 11)
    spec = str(files["merl"])
    for interp in ["nearest", "merl"]:
        src = brdfpack.open(spec, interp=interp)
        want = cli_eval(spec, wi, wo, "--interp", interp)
        assert_same_bits(src.eval(wi, wo, exact=True), want, interp)
    rgl = str(REPO / "fixtures/rgl/tiny.bsdf")
    want = cli_eval(rgl, wi, wo, "--clamp-negative")
    got = brdfpack.open(rgl, clamp_negative=True).eval(wi, wo)
    assert_same_bits(got, want, "rgl clamp_negative")


def test_a_table_as_arrays(files):
    t = brdfpack.load(files["exr"])
    assert t.kind == "table"
    assert t.shape == [12, 8, 12, 16]
    assert t.channels == ["R", "G", "B"]
    assert t.data.shape == (12, 8, 12, 16, 3) and t.data.dtype == np.float32
    assert t.valid.shape == (12, 8, 12, 16) and t.valid.dtype == np.bool_
    assert t.grid_desc["kind"] == "halfdiff4"
    assert [a["n"] for a in t.axes] == t.shape
    for a in t.axes:
        assert a["samples"].shape == (a["n"],)
        lo, hi = a["range"]
        assert lo <= a["samples"][0] and a["samples"][-1] <= hi
    # A cell's value is the table's value at that cell's sample directions: the data are
    # the samples, not a copy in another order.
    bpk = brdfpack.load(files["bpk lossless"])
    d = bpk.data
    i = (5, 3, 7)
    th, td, pd = (bpk.axes[k]["samples"][i[k]] for k in range(3))
    assert bpk.valid[i]
    # Rusinkiewicz: wi, wo of (θh, θd, φd) with φh = 0.
    h = np.array([np.sin(th), 0.0, np.cos(th)])
    dvec = np.array([np.sin(td) * np.cos(pd), np.sin(td) * np.sin(pd), np.cos(td)])
    rot_y = np.array([[np.cos(th), 0, np.sin(th)], [0, 1, 0], [-np.sin(th), 0, np.cos(th)]])
    wi = rot_y @ dvec
    wo = 2 * np.dot(wi, h) * h - wi
    f = bpk.eval(wi[None, :], wo[None, :], exact=True)[0]
    np.testing.assert_allclose(f, d[i], rtol=1e-6)
    # Sample pairs are unit vectors of the documented shape.
    a, b = brdfpack.sample_pairs(1000, kind="grazing", seed=3)
    assert a.shape == b.shape == (1000, 3)
    np.testing.assert_allclose(np.linalg.norm(a, axis=1), 1.0, atol=1e-12)
    # Into a caller's array: the same values, the same object returned.
    buf = np.full((1000, 3), np.nan)
    assert bpk.eval(a, b, out=buf) is buf
    assert_same_bits(buf, bpk.eval(a, b), "out=")
    with pytest.raises(brdfpack.BrdfpackError, match=r"out: shape \[1000, 2\], expected \(1000, 3\)"):
        bpk.eval(a, b, out=np.empty((1000, 2)))
    src = brdfpack.open(MODEL)
    assert src.kind == "model" and src.table() is None
    assert src.eval(np.zeros((0, 3)), np.zeros((0, 3))).shape == (0, 3)


def cli_error(*args):
    r = cli(*args, check=False)
    assert r.returncode == 2, r
    return r.stderr.strip()


def test_bad_input_raises_with_the_cli_message(tmp_path):
    out = str(tmp_path / "x.bpk")
    cases = []
    with pytest.raises(brdfpack.BrdfpackError) as e:
        brdfpack.open("no-such-model:alpha=1")
    cases.append((e, cli_error("tabulate", "no-such-model:alpha=1", "-o", out)))
    bad = tmp_path / "bad.bpk"
    bad.write_bytes(b"\x89BPK\r\n\x1a\n" + b"\x00" * 40)
    with pytest.raises(brdfpack.BrdfpackError) as e:
        brdfpack.open(str(bad))
    cases.append((e, cli_error("tabulate", str(bad), "--grid", "halfdiff3:4x4x4", "-o", out)))
    with pytest.raises(brdfpack.BrdfpackError) as e:
        brdfpack.load(bad)
    cases.append((e, cli_error("inspect", str(bad))))
    with pytest.raises(brdfpack.BrdfpackError) as e:
        brdfpack.tabulate(MODEL, grid="halfdiff3:0x4x4")
    cases.append((e, cli_error("tabulate", MODEL, "--grid", "halfdiff3:0x4x4", "-o", out)))
    with pytest.raises(brdfpack.BrdfpackError) as e:
        brdfpack.compress(MODEL, grid="halfdiff3:8x4x8", codec="dct:step=-1")
    cases.append(
        (e, cli_error("compress", MODEL, "--grid", "halfdiff3:8x4x8", "--codec", "dct:step=-1", "-o", out))
    )
    for err, want in cases:
        assert str(err.value) == want
        assert err.value.exit_code == 2
    # Directions: the row and what is wrong with it.
    src = brdfpack.open(MODEL)
    wi = np.array([[0.0, 0.0, 1.0], [0.0, 0.0, 1.0]])
    with pytest.raises(brdfpack.BrdfpackError, match=r"row 1: wo has zero length"):
        src.eval(wi, np.array([[0.0, 0.0, 1.0], [0.0, 0.0, 0.0]]))
    with pytest.raises(brdfpack.BrdfpackError, match=r"row 0: wi has a NaN"):
        src.eval(np.array([[np.nan, 0.0, 1.0]]), np.array([[0.0, 0.0, 1.0]]))
    with pytest.raises(brdfpack.BrdfpackError, match=r"shape \(N, 3\), got shape \[2, 2\]"):
        src.eval(np.zeros((2, 2)), np.zeros((2, 2)))
    with pytest.raises(brdfpack.BrdfpackError, match=r"wi has 6 numbers and wo 3"):
        src.eval(wi, wi[:1])
    # Beyond a stored θmax: refused unless asked for 0, like `eval --outside-domain-zero`.
    t = brdfpack.tabulate(MODEL, grid="spherical3:8,theta-max=60")
    high = np.array([[np.sin(1.3), 0.0, np.cos(1.3)]])
    with pytest.raises(brdfpack.BrdfpackError, match="outside the stored domain"):
        t.eval(high, high)
    assert t.eval(high, high, outside_domain_zero=True).tolist() == [[0.0, 0.0, 0.0]]


def test_round_trip_tabulate_compress_save_load_eval(tmp_path):
    t = brdfpack.tabulate(MODEL, grid=GRID3)
    assert t.codec is None and t.provenance["source"]
    # The same cells as the CLI's table (a lossless file keeps every f32).
    ref = tmp_path / "ref.bpk"
    cli("tabulate", MODEL, "--grid", GRID3, "-o", str(ref))
    assert_same_bits(t.data.astype(np.float64), brdfpack.load(ref).data.astype(np.float64), "tabulate")
    c = brdfpack.compress(t, codec="dct:step=0.05")
    assert c.codec["kind"] == "dct_context" and c.codec["dct"]["step"] == [0.05] * 3
    assert set(c.metrics) >= {"log_rmse", "p99_rel_core", "rmse"}
    p = tmp_path / "c.bpk"
    c.save(p)
    # The same bytes as `brdfpack compress` of the same table.
    cp = tmp_path / "cli.bpk"
    cli("compress", str(ref), "--codec", "dct:step=0.05", "-o", str(cp))
    assert p.read_bytes() == cp.read_bytes()
    back = brdfpack.load(p)
    assert back.codec == c.codec
    wi, wo = random_pairs(N_PAIRS, 5)
    assert_same_bits(back.eval(wi, wo), c.eval(wi, wo), "load after save")
    assert_same_bits(back.eval(wi, wo, exact=True), cli_eval(str(p), wi, wo), "CLI of the saved file")
    assert_same_bits(brdfpack.loads(p.read_bytes()).data.astype(np.float64), back.data.astype(np.float64), "loads")
    # Other formats by extension.
    for ext in ["exr", "bpk"]:
        q = tmp_path / f"other.{ext}"
        back.save(q, codec="lossless" if ext == "bpk" else None)
        assert_same_bits(brdfpack.load(q).data.astype(np.float64), back.data.astype(np.float64), ext)
    # check: the CLI's report, as a dict.
    report = brdfpack.check(MODEL, back, samples=4096, seed=2)
    want = json.loads(cli("check", str(p), "--against", MODEL, "--samples", "4096", "--seed", "2", "--json").stdout)
    assert report["uniform"]["combined"] == want["uniform"]["combined"]
    assert report["albedo_err"] == want["albedo_err"]
    # A budget instead of a codec: the planner's smallest file within it.
    b = brdfpack.compress(t, max_error="log_rmse=0.05", samples=4096)
    assert b.metrics["log_rmse"] <= 0.05
    with pytest.raises(brdfpack.BrdfpackError, match="exclude each other"):
        brdfpack.compress(t, codec="f16", max_error="log_rmse=0.05")
