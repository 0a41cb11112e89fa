#!/usr/bin/env python3
"""A MERL-format file with holes, from one without: what a measurement's missing samples look
like to brdfpack (docs/benchmarks.md, "Holes of a measured table").

A hole is a cell above the horizon whose stored values are negative (MERL's marker, -1.0 raw).
Two kinds, reproducible from the seed:

    python3 scripts/merl_holes.py IN.binary OUT.binary random --share 0.005 --noise 0.02 --seed 1
    python3 scripts/merl_holes.py IN.binary OUT.binary blocks

`random`: that share of the valid cells, at random, plus multiplicative log-normal noise of
that sigma on every valid value (a measurement's noise; 0 for none). `blocks`: every valid cell
with theta_d index >= 80 and phi_d index in [60, 120), and with theta_h index >= 70,
theta_d index >= 60 and phi_d index < 20 (regions a gantry did not reach), no noise. Needs numpy.
"""
import argparse

import numpy as np


def main():
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("input")
    p.add_argument("output")
    p.add_argument("kind", choices=["random", "blocks"])
    p.add_argument("--share", type=float, default=0.005)
    p.add_argument("--noise", type=float, default=0.0)
    p.add_argument("--seed", type=int, default=1)
    a = p.parse_args()
    with open(a.input, "rb") as f:
        dims = np.fromfile(f, np.int32, 3)
        d = np.fromfile(f, np.float64)
    n_th, n_td, n_pd = (int(x) for x in dims)
    d = d.reshape(3, n_th, n_td, n_pd)
    valid = (d >= 0).all(axis=0)
    if a.kind == "random":
        rng = np.random.default_rng(a.seed)
        if a.noise > 0:
            d = np.where(d >= 0, d * np.exp(rng.normal(0.0, a.noise, d.shape)), d)
        holes = valid & (rng.random(valid.shape) < a.share)
    else:
        holes = np.zeros_like(valid)
        holes[:, 80:, 60:120] = True
        holes[70:, 60:, :20] = True
        holes &= valid
    d[:, holes] = -1.0
    with open(a.output, "wb") as f:
        dims.tofile(f)
        d.astype(np.float64).ravel().tofile(f)
    print(f"{int(holes.sum())} holes of {int(valid.sum())} valid cells")


if __name__ == "__main__":
    main()
