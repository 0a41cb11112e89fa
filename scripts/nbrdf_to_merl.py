#!/usr/bin/env python3
"""MERL-format tables of measured materials this repository does not hold, for the encoder's
acceptance run (docs/compression.md, "Measured materials from NBRDF fits").

Evaluates the published NBRDF fits (Sztrajman et al. 2021, "Neural BRDF Representation and
Importance Sampling"; MIT-licensed weights, 6x21x21x3 ReLU networks whose input is the half
vector with phi_h = 0 and the difference vector, whose output is exp(x) - 1 in 1/sr) at MERL's
sample positions (lower bin edges, sqrt-warped theta_h), and writes MERL .binary files: raw
-1.0 below the horizon, values clamped at >= 0 elsewhere, divided by MERL's channel scales.
This is how ../shared/data/merl/*.binary were made: the two files it holds come out identical
to within 4e-12 relative.

    git clone https://github.com/asztr/Neural-BRDF && unzip Neural-BRDF/data/merl_nbrdf.zip
    python3 -m venv venv && venv/bin/pip install numpy h5py
    venv/bin/python scripts/nbrdf_to_merl.py OUTDIR merl_nbrdf/*.h5

The MERL data these fits derive from is for research and academic use; so are the files.
"""
import os
import struct
import sys

import h5py
import numpy as np

# MERL's reader divides by these (red, green, blue).
SCALE = np.array([1.0 / 1500, 1.15 / 1500, 1.66 / 1500])
N_TH, N_TD, N_PD = 90, 90, 180


def network(path):
    f = h5py.File(path, "r")
    layers = [
        (
            f[f"dense_{i}/dense_{i}/kernel:0"][()].astype(np.float64),
            f[f"dense_{i}/dense_{i}/bias:0"][()].astype(np.float64),
        )
        for i in (1, 2, 3)
    ]

    def forward(x):
        for n, (w, b) in enumerate(layers):
            x = x @ w + b
            if n < 2:
                x = np.maximum(x, 0.0)
        return np.exp(x) - 1.0

    return forward


def merl_table(forward):
    theta_h = (np.arange(N_TH) / N_TH) ** 2 * (np.pi / 2)
    theta_d = np.arange(N_TD) / N_TD * (np.pi / 2)
    phi_d = np.arange(N_PD) / N_PD * np.pi
    th, td, pd = np.meshgrid(theta_h, theta_d, phi_d, indexing="ij")
    half = np.stack([np.sin(th), np.zeros_like(th), np.cos(th)], -1).reshape(-1, 3)
    diff = np.stack(
        [np.sin(td) * np.cos(pd), np.sin(td) * np.sin(pd), np.cos(td)], -1
    ).reshape(-1, 3)
    values = forward(np.concatenate([half, diff], 1))
    # wi: the difference vector rotated by theta_h about y (phi_h = 0); wo its mirror about h.
    c, s = np.cos(th).ravel(), np.sin(th).ravel()
    wi = np.stack([c * diff[:, 0] + s * diff[:, 2], diff[:, 1], -s * diff[:, 0] + c * diff[:, 2]], -1)
    wo = 2 * np.sum(wi * half, -1, keepdims=True) * half - wi
    below = (wi[:, 2] <= 0) | (wo[:, 2] <= 0)
    values = np.maximum(values, 0.0) / SCALE
    values[below] = -1.0
    return values.T.reshape(3, N_TH, N_TD, N_PD)


def main():
    if len(sys.argv) < 3:
        sys.exit(__doc__)
    out_dir = sys.argv[1]
    os.makedirs(out_dir, exist_ok=True)
    for h5 in sys.argv[2:]:
        name = os.path.basename(h5)[: -len(".h5")]
        table = merl_table(network(h5))
        out = os.path.join(out_dir, name + ".binary")
        with open(out + ".tmp", "wb") as f:
            f.write(struct.pack("<3i", N_TH, N_TD, N_PD))
            f.write(table.astype("<f8").tobytes())
        os.replace(out + ".tmp", out)
        print(out)


if __name__ == "__main__":
    main()
