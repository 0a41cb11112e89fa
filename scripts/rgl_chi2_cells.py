#!/usr/bin/env python3
"""Where Mitsuba's chi2 test of a BSDF's sampling fails (docs/rgl.md, "What the χ² failures are").

Runs mitsuba.chi2.ChiSquareTest (BSDF adapter, SphericalDomain: 50 azimuth x 101 cos θ bins)
at one wi with the test's default quadrature of pdf() (ires 4) and with ires 16, on the same
histogram (the sample seed is the test's), and prints:

* the p-values and the chi2 sums over the bins both tests count (expected count > 5);
* the azimuth columns and cos θ rows where ires 4 adds the most chi2 over ires 16, i.e. where
  the test's trapezoid rule, not the sampling, makes the difference; per cell the ratio of the
  two quadratures and of the histogram to the ires-16 integral.

--smooth-pole SOURCE: also runs the ires-4 test with pdf() within --pole-radius degrees of the
mirror direction replaced by its trend, pdf(at the radius, same azimuth about the mirror
direction) × L(wo)/L(at the radius), L = luminance of f·cos θo of the brdfpack SOURCE
(`brdfpack eval`): what the test gives for a file whose pdf is smooth next to the pole;
--pole-keep F keeps the fraction F of pdf()'s departure from that trend.

  .venv/bin/python scripts/rgl_chi2_cells.py gold.bsdf --theta 80
  .venv/bin/python scripts/rgl_chi2_cells.py x --theta 80 --plugin \\
      '{"type":"roughconductor","distribution":"ggx","alpha":0.2}'
  .venv/bin/python scripts/rgl_chi2_cells.py aniso.bsdf --theta 0 --smooth-pole "$S2"
"""
import argparse
import json
import os
import sys

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(HERE)
sys.path.insert(0, os.path.join(os.environ.get("BRDFPACK_SHARED", os.path.join(ROOT, "..", "shared")), "peers", "mitsuba"))
import mitsuba_ref  # noqa: E402

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from rgl_mitsuba_check import brdfpack_eval  # noqa: E402

LUM = np.array([0.2126, 0.7152, 0.0722])


def run(plugin, wi, ires, pdf_wrap=None):
    from mitsuba.chi2 import BSDFAdapter, ChiSquareTest, SphericalDomain
    sample, pdf = BSDFAdapter(plugin["type"], plugin, wi=wi)
    test = ChiSquareTest(domain=SphericalDomain(), sample_func=sample,
                         pdf_func=pdf_wrap(pdf) if pdf_wrap else pdf, sample_dim=3, ires=ires)
    test.run(quiet=True)
    shape = (int(test.res.y), int(test.res.x))
    return (np.array(test.histogram).reshape(shape), np.array(test.pdf).reshape(shape),
            float(test.p_value))


def smooth_pole(exe, source, wi, radius, keep):
    mi = mitsuba_ref.mi
    wi = np.array(wi)
    mirror = np.array([-wi[0], -wi[1], wi[2]])
    r = np.radians(radius)

    def lum_f_cos(wos):
        f = brdfpack_eval(exe, source, np.repeat(np.asarray(wi)[None, :], len(wos), axis=0), wos)
        return f @ LUM * wos[:, 2]

    def wrap(pdf):
        def smoothed(wo, *args):
            p = np.array(pdf(wo, *args))
            w = np.stack([np.array(wo[i]) for i in range(3)], 1).astype(np.float64)
            d = np.arccos(np.clip(w @ mirror, -1, 1))
            near = np.where((d < r) & (d > 0))[0]
            if len(near):
                wn = w[near]
                t = wn - np.outer(wn @ mirror, mirror)
                t /= np.linalg.norm(t, axis=1)[:, None]
                ring = np.cos(r) * mirror + np.sin(r) * t
                ring32 = ring.astype(np.float32)
                p_ring = np.array(pdf(mi.Vector3f(*[mi.Float(np.ascontiguousarray(ring32[:, i]))
                                                    for i in range(3)]), *args))
                lf = lum_f_cos(np.vstack([wn, ring]))
                trend = lf[:len(near)] * p_ring / lf[len(near):]
                smoothed.ratio = float(np.mean(p[near] / trend))
                p[near] = trend + keep * (p[near] - trend)
            return mi.Float(p.astype(np.float32))
        smoothed.ratio = None
        wrap.last = smoothed
        return smoothed
    return wrap


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("bsdf", help="the .bsdf (ignored with --plugin)")
    ap.add_argument("--theta", type=float, default=0.0, help="θi in degrees")
    ap.add_argument("--phi", type=float, default=0.0, help="φi in degrees")
    ap.add_argument("--plugin", help="a Mitsuba BSDF as a JSON dict instead of the file")
    ap.add_argument("--variant", default="llvm_ad_rgb")
    ap.add_argument("--top", type=int, default=8)
    ap.add_argument("--smooth-pole", metavar="SOURCE")
    ap.add_argument("--pole-radius", type=float, default=0.4, help="degrees (default 0.4)")
    ap.add_argument("--pole-keep", type=float, default=0.0, metavar="F")
    ap.add_argument("--brdfpack", default=os.path.join(ROOT, "target", "release", "brdfpack"))
    a = ap.parse_args()
    mitsuba_ref.init(a.variant)
    plugin = json.loads(a.plugin) if a.plugin else {"type": "measured", "filename": a.bsdf}
    th, ph = np.radians(a.theta), np.radians(a.phi)
    wi = [float(np.sin(th) * np.cos(ph)), float(np.sin(th) * np.sin(ph)), float(np.cos(th))]
    h, p4, pv4 = run(plugin, wi, 4)
    _, p16, pv16 = run(plugin, wi, 16)
    counted = (p4 > 5) & (p16 > 5)
    c4 = np.where(counted, (h - p4) ** 2 / np.where(counted, p4, 1), 0)
    c16 = np.where(counted, (h - p16) ** 2 / np.where(counted, p16, 1), 0)
    print("p ires 4: %.3g, ires 16: %.3g; chi2 over %d bins: %.0f (ires 4), %.0f (ires 16)"
          % (pv4, pv16, counted.sum(), c4.sum(), c16.sum()))
    extra = c4 - c16
    rows, cols = extra.shape

    def phi_c(q):
        return np.degrees(-np.pi + 2 * np.pi * (q + 0.5) / cols)

    def theta_r(r):
        return np.degrees(np.arccos(np.clip([1 - 2 * r / rows, 1 - 2 * (r + 1) / rows], -1, 1)))

    print("azimuth columns where ires 4 adds the most chi2:")
    for q in np.argsort(extra.sum(0))[::-1][:a.top]:
        print("  col %2d (φo %6.1f°): %+.1f" % (q, phi_c(q), extra[:, q].sum()))
    print("cos θ rows where ires 4 adds the most chi2:")
    for r in np.argsort(extra.sum(1))[::-1][:a.top]:
        t0, t1 = theta_r(r)
        print("  row %3d (θo %5.2f–%5.2f°): %+.1f; histogram %.0f, ires 4 %.1f, ires 16 %.1f"
              % (r, t0, t1, extra[r].sum(), h[r].sum(), p4[r].sum(), p16[r].sum()))
    print("cells:")
    for k in np.argsort(extra.ravel())[::-1][:a.top]:
        r, q = divmod(k, cols)
        print("  row %3d col %2d: histogram %.0f, ires 4 %.1f, ires 16 %.1f; ires 4 / ires 16 %.3f,"
              " histogram / ires 16 %.3f" % (r, q, h[r, q], p4[r, q], p16[r, q],
                                              p4[r, q] / p16[r, q], h[r, q] / p16[r, q]))
    if a.smooth_pole:
        wrap = smooth_pole(a.brdfpack, a.smooth_pole, wi, a.pole_radius, a.pole_keep)
        _, ps, pvs = run(plugin, wi, 4, wrap)
        print("ires 4 with pdf() within %g° of the mirror direction at its trend + %g of its "
              "departure: p %.3g (pdf there was %.3f × its trend; integral %.5f, histogram %.5f)"
              % (a.pole_radius, a.pole_keep, pvs, wrap.last.ratio or float("nan"),
                 ps.sum() / 1e6, h.sum() / 1e6))
    print("integral of pdf(): %.5f (ires 4), %.5f (ires 16); histogram %.5f"
          % (p4.sum() / 1e6, p16.sum() / 1e6, h.sum() / 1e6))


if __name__ == "__main__":
    main()
