#!/usr/bin/env python3
"""Renders a sphere lit by a constant environment and a point light (256x256, 64 spp, Mitsuba
3, llvm_ad_rgb; by default the `direct` integrator with --emitter-samples and --bsdf-samples
per sample (MIS), `--integrator path` for the path tracer of max depth 3) with an RGL .bsdf on Mitsuba's `measured` plugin and with Mitsuba's own
`roughconductor` (GGX, gold eta/k of brdfpack's `fresnel=au`), and prints the relative RMSE over
the lit pixels: sqrt(mean((a − b)²)) / sqrt(mean(b²)) over pixels whose reference luminance
exceeds 1e-3 of its maximum (the background, lit by the environment, counts too). The noise
floor is the same figure for two reference renders with different seeds; the same over 8×8
pixel blocks, and the ratio of mean luminances, separate bias from noise. The measured render
uses --measured-seed (default 0: the reference's seed, so both share pixel positions and
emitter samples; only the BSDF sampling differs). Writes PNGs (sRGB tone map, clipped) beside
--out.

usage: rgl_render_compare.py gold.bsdf --alpha 0.2 --out docs/img/rgl_gold
"""
import argparse
import json
import os
import sys

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, os.path.join(os.environ.get("BRDFPACK_SHARED", os.path.join(HERE, "..", "..", "shared")), "peers", "mitsuba"))
import mitsuba_ref  # noqa: E402

# brdfpack's `fresnel=au` (docs/models.md): RGB eta and k of gold.
AU_ETA = [0.143, 0.374, 1.442]
AU_K = [3.983, 2.385, 1.603]


def scene(bsdf, integrator):
    return {
        "type": "scene",
        "integrator": integrator,
        "sensor": {
            "type": "perspective", "fov": 30,
            "to_world": mitsuba_ref.mi.ScalarTransform4f().look_at(
                origin=[0, -5, 1.5], target=[0, 0, 0], up=[0, 0, 1]),
            "film": {"type": "hdrfilm", "width": 256, "height": 256,
                     "rfilter": {"type": "box"}},
            "sampler": {"type": "independent", "sample_count": 64},
        },
        "sphere": {"type": "sphere", "radius": 1.0, "bsdf": bsdf},
        "env": {"type": "constant", "radiance": {"type": "rgb", "value": [0.3, 0.3, 0.3]}},
        "light": {"type": "point", "position": [3, -3, 4],
                  "intensity": {"type": "rgb", "value": [40, 40, 40]}},
    }


def render(bsdf, seed, integrator):
    mi = mitsuba_ref.mi
    s = mi.load_dict(scene(bsdf, integrator))
    return np.array(mi.render(s, seed=seed), dtype=np.float64)[..., :3]


def rel_rmse(a, ref):
    y = ref @ [0.2126, 0.7152, 0.0722]
    lit = y > 1e-3 * y.max()
    return float(np.sqrt(np.mean((a[lit] - ref[lit]) ** 2)) / np.sqrt(np.mean(ref[lit] ** 2)))


def blocks(im, k=8):
    h, w, c = im.shape
    return im.reshape(h // k, k, w // k, k, c).mean(axis=(1, 3))


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("bsdf")
    ap.add_argument("--alpha", type=float, default=0.2)
    ap.add_argument("--out", default="rgl_render")
    ap.add_argument("--integrator", choices=["direct", "path"], default="direct")
    ap.add_argument("--emitter-samples", type=int, default=4)
    ap.add_argument("--bsdf-samples", type=int, default=4)
    ap.add_argument("--measured-seed", type=int, default=0)
    a = ap.parse_args()
    if a.integrator == "path":
        integ = {"type": "path", "max_depth": 3}
    else:
        integ = {"type": "direct", "emitter_samples": a.emitter_samples,
                 "bsdf_samples": a.bsdf_samples}
    mitsuba_ref.init("llvm_ad_rgb")
    mi = mitsuba_ref.mi
    rough = {"type": "roughconductor", "distribution": "ggx", "alpha": a.alpha,
             "eta": {"type": "rgb", "value": AU_ETA}, "k": {"type": "rgb", "value": AU_K}}
    measured = {"type": "measured", "filename": os.path.abspath(a.bsdf)}
    ref = render(rough, 0, integ)
    ref2 = render(rough, 1, integ)
    img = render(measured, a.measured_seed, integ)
    y = lambda im: im @ [0.2126, 0.7152, 0.0722]
    lit = y(ref) > 1e-3 * y(ref).max()
    report = {"bsdf": a.bsdf, "integrator": integ, "spp": 64, "measured_seed": a.measured_seed,
              "rel_rmse_lit": rel_rmse(img, ref),
              "noise_floor_rel_rmse_lit": rel_rmse(ref2, ref),
              # 8x8 pixel blocks average the Monte Carlo noise away (not the bias).
              "rel_rmse_lit_8x8_blocks": rel_rmse(blocks(img), blocks(ref)),
              "noise_floor_8x8_blocks": rel_rmse(blocks(ref2), blocks(ref)),
              "mean_ratio_lit": float(y(img)[lit].mean() / y(ref)[lit].mean())}
    os.makedirs(os.path.dirname(os.path.abspath(a.out)), exist_ok=True)
    for name, im in [("roughconductor", ref), ("measured", img)]:
        mi.util.write_bitmap(a.out + "_" + name + ".png", mi.TensorXf(im.astype(np.float32)))
    print(json.dumps(report, indent=1))


if __name__ == "__main__":
    main()
