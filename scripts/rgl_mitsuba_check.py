#!/usr/bin/env python3
"""Checks an RGL .bsdf written by `brdfpack convert SOURCE -o out.bsdf` with Mitsuba 3's own
`measured` plugin (docs/rgl.md, "Writing RGL files"):

1. eval: N uniform direction pairs (wi, wo independent, uniform in solid angle on the upper
   hemisphere, numpy seed --seed); f_ref from `brdfpack eval SOURCE`, f_mitsuba = Mitsuba's
   eval / wo.z; log_rmse and p99_rel_core as spec/metrics.md defines them (channels pooled,
   eps = 1e-3 mean|f_ref|, core = cos θi >= 0.1 and cos θo >= 0.1, p99 by numpy's linear
   percentile).
2. chi2: mitsuba.chi2.ChiSquareTest with the BSDF adapter (default significance 0.01) for
   θi in --chi2-theta (degrees); --chi2-ires sets the points per bin and axis of the test's
   quadrature of pdf() (default 4, Mitsuba's); --chi2-phi the azimuth of wi (default 0).
   --chi2-plugin JSON runs the same test on a Mitsuba plugin instead (e.g. roughconductor).
3. --against-bsdf FILE: instead of a brdfpack source, compare with Mitsuba's evaluation of
   another .bsdf (the re-written RGL files): max and p99 of the fixture metric
   |f − f_ref| / (|f_ref| + 1e-3·mean|f_ref|).

Prints one JSON object. Mitsuba from ../shared/peers/README.md (pip install mitsuba==3.9.1
into a venv); the llvm variant needs libLLVM 19 (DRJIT_LIBLLVM_PATH is set when found).
"""
import argparse
import json
import os
import subprocess
import sys

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(HERE)
sys.path.insert(0, os.path.join(os.environ.get("BRDFPACK_SHARED", os.path.join(ROOT, "..", "shared")), "peers", "mitsuba"))
import mitsuba_ref  # noqa: E402  (Mitsuba setup and the measured-plugin fold workaround)


def uniform_dirs(rng, n):
    z = rng.random(n)
    phi = 2 * np.pi * rng.random(n)
    s = np.sqrt(np.maximum(0.0, 1 - z * z))
    return np.stack([s * np.cos(phi), s * np.sin(phi), z], 1)


def brdfpack_eval(exe, source, wi, wo):
    lines = "\n".join(" ".join(repr(float(x)) for x in np.r_[a, b]) for a, b in zip(wi, wo))
    out = subprocess.run([exe, "eval", source], input=lines, capture_output=True, text=True)
    if out.returncode != 0:
        sys.exit("brdfpack eval failed: " + out.stderr)
    v = np.array([[float(x) for x in l.split()] for l in out.stdout.strip().split("\n")])
    if v.shape[1] == 1:
        v = np.repeat(v, 3, axis=1)
    return v


def load_measured(path):
    """Mitsuba 3.9.1 may fold isotropic files by pi (uninitialised m_reduction); the peer helper
    reloads until its canaries show no fold. Files written from isotropic sources are
    symmetric under that fold (the canaries cannot tell: 'undecided'), so any load will do."""
    try:
        return mitsuba_ref.load_measured({"model": "measured", "file": path}, max_tries=20)
    except RuntimeError:
        return mitsuba_ref.mi.load_dict({"type": "measured", "filename": path})


def mitsuba_eval(bsdf, wi, wo):
    ctx = mitsuba_ref.mi.BSDFContext()
    if mitsuba_ref.VARIANT.startswith("scalar"):
        return mitsuba_ref.eval_scalar(bsdf, ctx, wi, wo)[1]
    return mitsuba_ref.eval_vector(bsdf, ctx, wi, wo)[1]


def metrics(f, g, wi, wo):
    eps = 1e-3 * np.mean(np.abs(f))
    rel = np.abs(g - f) / (np.abs(f) + eps)
    core = (wi[:, 2] >= 0.1) & (wo[:, 2] >= 0.1)
    with np.errstate(invalid="ignore"):
        le = np.log1p(g * wi[:, 2:3]) - np.log1p(f * wi[:, 2:3])
    # A grazing wo (θo > 89.5°) is where eval / wo.z amplifies the representation's error.
    graze = wo[:, 2] < np.cos(np.radians(89.5))
    return {
        "log_rmse": float(np.sqrt(np.mean(le ** 2))),
        "log_rmse_without_theta_o_above_89.5": float(np.sqrt(np.mean(le[~graze] ** 2))),
        "p99_rel_core": float(np.percentile(rel[core], 99)),
        "rel_rmse_core": float(np.sqrt(np.mean(rel[core] ** 2))),
        "median_rel_core": float(np.median(rel[core])),
        "nonfinite": int(np.sum(~np.isfinite(g))),
        "negative": int(np.sum(g < 0)),
        "epsilon": float(eps),
    }


def chi2(plugin, thetas, ires=4, phi=0.0):
    from mitsuba.chi2 import BSDFAdapter, ChiSquareTest, SphericalDomain
    out = {}
    ph = np.radians(phi)
    for t in thetas:
        th = np.radians(t)
        wi = [float(np.sin(th) * np.cos(ph)), float(np.sin(th) * np.sin(ph)), float(np.cos(th))]
        sample, pdf = BSDFAdapter(plugin["type"], plugin, wi=wi)
        test = ChiSquareTest(domain=SphericalDomain(), sample_func=sample, pdf_func=pdf,
                             sample_dim=3, ires=ires)
        ok = bool(test.run(quiet=True))
        out["%g" % t] = {"pass": ok, "p_value": float(test.p_value)
                         if getattr(test, "p_value", None) is not None else None}
    return out


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("bsdf", help="the written .bsdf")
    ap.add_argument("--source", help="the brdfpack source it was written from")
    ap.add_argument("--against-bsdf", help="compare with Mitsuba's evaluation of this .bsdf")
    ap.add_argument("--n", type=int, default=100000)
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--variant", default="llvm_ad_rgb")
    ap.add_argument("--chi2-theta", default="0,30,60,80",
                    help="θi in degrees for the chi2 test ('' to skip)")
    ap.add_argument("--chi2-ires", type=int, default=4,
                    help="points per bin and axis of the test's trapezoid quadrature of pdf() "
                    "(Mitsuba's default 4; 16 resolves lobes narrower than a bin)")
    ap.add_argument("--chi2-phi", type=float, default=0.0,
                    help="azimuth of wi in degrees for the chi2 test (default 0: wi in the "
                    "xz-plane)")
    ap.add_argument("--chi2-plugin", help="run the chi2 test on this Mitsuba BSDF (JSON dict, "
                    "e.g. roughconductor) instead of the file, to see what the test does with "
                    "Mitsuba's own material")
    ap.add_argument("--brdfpack", default=os.path.join(ROOT, "target", "release", "brdfpack"))
    a = ap.parse_args()
    mitsuba_ref.init(a.variant)
    rng = np.random.default_rng(a.seed)
    wi = uniform_dirs(rng, a.n)
    wo = uniform_dirs(rng, a.n)
    report = {"bsdf": a.bsdf, "pairs": a.n, "seed": a.seed, "variant": a.variant}
    b = load_measured(a.bsdf)
    g = mitsuba_eval(b, wi, wo)
    if a.source:
        f = brdfpack_eval(a.brdfpack, a.source, wi, wo)
        report["source"] = a.source
        report["eval"] = metrics(f, g, wi, wo)
    if a.against_bsdf:
        f = mitsuba_eval(load_measured(a.against_bsdf), wi, wo)
        eps = 1e-3 * np.mean(np.abs(f))
        err = np.max(np.abs(g - f) / (np.abs(f) + eps), axis=1)
        report["against"] = a.against_bsdf
        report["fixture_err"] = {"max": float(err.max()),
                                 "p99": float(np.percentile(err, 99)),
                                 "median": float(np.median(err))}
    if a.chi2_theta:
        plugin = {"type": "measured", "filename": a.bsdf}
        if a.chi2_plugin:
            plugin = json.loads(a.chi2_plugin)
            report["chi2_plugin"] = plugin
        report["chi2_ires"] = a.chi2_ires
        report["chi2_phi"] = a.chi2_phi
        report["chi2"] = chi2(plugin, [float(t) for t in a.chi2_theta.split(",")], a.chi2_ires,
                              a.chi2_phi)
    print(json.dumps(report, indent=1))


if __name__ == "__main__":
    main()
