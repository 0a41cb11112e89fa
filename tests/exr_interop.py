#!/usr/bin/env python3
"""Interoperability check of brdfpack's EXR tables with the reference OpenEXR library.

Usage: exr_interop.py TABLE.exr SAME_TABLE.binary [--exact]

TABLE.exr must be an f32, lossless brdfpack EXR of a table on a MERL grid, and
SAME_TABLE.binary the same table written as a MERL file by brdfpack. This script reads both
with independent code (PyPI `openexr`, numpy, and the MERL layout of spec/formats.md) and
checks: channel names and types, image size, the `brdfpack` header attribute, every value
channel bit for bit against the MERL values x scale rounded to f32 (0 where invalid), the
`valid` channel against the MERL negative markers, and (--exact) that the f64hi/f64lo
channels reassemble the MERL file's f64 values bit for bit.
Exit 0 when every check passes, 1 otherwise (with the failed check printed).
"""

import json
import sys

import numpy as np
import OpenEXR

MERL_SCALE = (1.0 / 1500.0, 1.15 / 1500.0, 1.66 / 1500.0)


def fail(msg):
    print(f"exr_interop: FAIL: {msg}")
    sys.exit(1)


def check(cond, msg):
    if not cond:
        fail(msg)


def read_merl(path):
    b = open(path, "rb").read()
    dims = np.frombuffer(b[:12], "<i4").astype(int)
    n = int(np.prod(dims))
    check(len(b) == 12 + 24 * n, f"{path}: size {len(b)} does not match dims {dims}")
    raw = np.frombuffer(b[12:], "<f8").reshape(3, n)
    return dims, raw


def main():
    args = [a for a in sys.argv[1:] if not a.startswith("--")]
    exact = "--exact" in sys.argv
    if len(args) != 2:
        print(__doc__)
        sys.exit(2)
    exr_path, merl_path = args
    dims, raw = read_merl(merl_path)
    n = int(np.prod(dims))
    width, height = int(dims[2]), int(dims[0] * dims[1])

    with OpenEXR.File(exr_path, separate_channels=True) as f:
        header = f.header()
        channels = f.channels()

        # Size: x = phi_d (fastest axis), y = theta_h * n_theta_d + theta_d.
        lo, hi = header["dataWindow"]
        check(list(lo) == [0, 0] and list(hi) == [width - 1, height - 1],
              f"dataWindow {lo}..{hi}, expected 0..({width - 1}, {height - 1})")

        # Channels and their types.
        want = {"brdf.R": np.float32, "brdf.G": np.float32, "brdf.B": np.float32,
                "valid": np.float16}
        if exact:
            for c in "RGB":
                want[f"f64hi.{c}"] = np.uint32
                want[f"f64lo.{c}"] = np.uint32
        check(set(channels) == set(want), f"channels {sorted(channels)}, expected {sorted(want)}")
        for name, dt in want.items():
            px = channels[name].pixels
            check(px.dtype == dt, f"channel {name} has type {px.dtype}, expected {dt}")
            check(px.shape == (height, width), f"channel {name} shape {px.shape}")

        # The header attribute.
        check(header.get("software", "").startswith("brdfpack"), "software attribute")
        h = json.loads(header["brdfpack"])
        check(h["format"] == "brdfpack-exr" and h["version"] == 1, f"format {h['format']}")
        check(h["units"] == "1/sr", f"units {h['units']}")
        check(h["sample_type"] == "f32" and h["value_scale_log2"] == 0, "sample type / scale")
        check(h["channels"]["names"] == ["R", "G", "B"], f"channels {h['channels']}")
        axes = h["grid"]["axes"]
        check(h["grid"]["kind"] == "halfdiff3", f"grid kind {h['grid']['kind']}")
        check([(a["quantity"], a["n"], a["warp"], a["placement"]) for a in axes] ==
              [("theta_h", int(dims[0]), "sqrt", "lower_edge"),
               ("theta_d", int(dims[1]), "linear", "lower_edge"),
               ("phi_d", int(dims[2]), "linear", "lower_edge")], f"grid axes {axes}")
        check(h["provenance"]["tool"].startswith("brdfpack"), "provenance tool")
        check(("exact" in h) == exact, "exact field presence")

        # Values: MERL stored x scale, rounded once to f32; 0 in invalid cells.
        valid = np.all(raw >= 0.0, axis=0)
        got_valid = channels["valid"].pixels.reshape(n)
        check(np.array_equal(got_valid == 1.0, valid) and
              np.all((got_valid == 0.0) | (got_valid == 1.0)), "valid channel")
        for c, name in enumerate("RGB"):
            want_v = np.where(valid, (raw[c] * MERL_SCALE[c]).astype(np.float32), np.float32(0))
            got = channels[f"brdf.{name}"].pixels.reshape(n)
            bad = np.flatnonzero(got.view(np.uint32) != want_v.view(np.uint32))
            check(bad.size == 0,
                  f"brdf.{name}: {bad.size} values differ, first at cell {bad[:1]}: "
                  f"{got[bad[:1]]} vs {want_v[bad[:1]]}")
            if exact:
                hi_b = channels[f"f64hi.{name}"].pixels.reshape(n).astype(np.uint64)
                lo_b = channels[f"f64lo.{name}"].pixels.reshape(n).astype(np.uint64)
                bits = (hi_b << np.uint64(32)) | lo_b
                check(np.array_equal(bits, raw[c].view(np.uint64)),
                      f"f64 channels of {name} do not reassemble the MERL values")
    print(f"exr_interop: ok: {exr_path} ({width}x{height}, "
          f"{int(valid.sum())} valid cells{', exact f64' if exact else ''})")


if __name__ == "__main__":
    main()
