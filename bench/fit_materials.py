#!/usr/bin/env python3
"""The realistic benchmark set: materials from outside the fitted families,
written as full MERL files, fitted by lambert plus 1, 2 and 3 GGX lobes under
each metric, against an independent brute-force optimum.

    PYTHONPATH=build/python /usr/bin/python3 bench/fit_materials.py EXE \
        [--materials a,b] [--lobes 1,2,3] [--metrics l2,relative,cosine,log,cbrt] \
        [--random-starts 8] [--stride 1] [--out DIR]

The materials and their noise are bench/fit_materials.json (shared with
tests/fit_materials_test.cpp, which runs a reduced-size version): each is
tabulated at the MERL bin centres (brdfkit.write of the model), then every
cell is multiplied by exp(N(0, sd)) (one factor for the three channels), a
fraction of the cells is marked missing and a fraction of the cells beyond
the grazing angle (theta_i or theta_o) is multiplied by a factor. Each
material's file is written into DIR (default fit_materials_data/) unless it
is there.

Each fit is a whole `EXE fit --threads 2 --json` process (uncertainties
included): wall and CPU seconds (wait4), peak resident memory, cost,
iterations. The brute force is `EXE fit --random-starts N x lobes
--no-covariance` (random starts drawn in the whole parameter space, each
solved to convergence on the 65,536-sample middle subset, the best refined
on all samples): the table gives its cost and the relative gap
(fit - brute force) / brute force; a negative gap means the default search
found the lower optimum.
"""
import argparse
import json
import math
import os
import sys

import numpy as np

import brdfkit
from fit_speed import timed_fit as run

HERE = os.path.dirname(os.path.abspath(__file__))


def grazing_mask(theta_deg):
    """Cells (90, 90, 180) whose bin-centre directions (phi_h = 0) have
    theta_i or theta_o beyond theta_deg, by the MERL bin convention."""
    i, j, k = np.meshgrid(np.arange(90), np.arange(90), np.arange(180), indexing="ij")
    th = (i / 90.0) ** 2 * (math.pi / 2)
    td = j / 90.0 * (math.pi / 2)
    pd = k / 180.0 * math.pi
    dx, dz = np.sin(td) * np.cos(pd), np.cos(td)
    zi = -np.sin(th) * dx + np.cos(th) * dz
    zo = np.sin(th) * dx + np.cos(th) * dz
    return np.minimum(zi, zo) < math.cos(math.radians(theta_deg))


def kept_bins(stride):
    """Cells (90, 90, 180) on every stride-th bin of each axis, from stride // 2
    (the reduced-size set of tests/fit_materials_test.cpp)."""
    i, j, k = np.meshgrid(np.arange(90), np.arange(90), np.arange(180), indexing="ij")
    o = stride // 2
    return ((i - o) % stride == 0) & (j >= o) & ((j - o) % stride == 0) & (k >= o) & ((k - o) % stride == 0) & (i >= o)


def write_material(path, m, noise, stride=1):
    model = brdfkit.Model(m["model"], {k: tuple(v) if isinstance(v, list) else v for k, v in m["params"].items()})
    clean = path + ".clean.binary"
    brdfkit.write(clean, model)
    raw = open(clean, "rb").read()
    os.remove(clean)
    v = np.frombuffer(raw[12:], dtype=np.float64).copy().reshape(3, -1)
    n = v.shape[1]
    rng = np.random.default_rng(m["seed"])
    v *= np.exp(rng.normal(0, noise["lognormal_sd"], n))
    missing = rng.random(n) < noise["missing"]
    outlier = (rng.random(n) < noise["grazing_fraction"]) & grazing_mask(noise["grazing_theta_deg"]).ravel()
    v[:, outlier & (v[0] >= 0)] *= noise["grazing_factor"]
    v[:, missing] = -1
    if stride > 1:
        v[:, ~kept_bins(stride).ravel()] = -1
    with open(path + ".part", "wb") as f:
        f.write(raw[:12] + v.tobytes())
    os.replace(path + ".part", path)


def main():
    spec = json.load(open(os.path.join(HERE, "fit_materials.json")))
    fits = spec["fits"]
    ap = argparse.ArgumentParser()
    ap.add_argument("exe")
    ap.add_argument("--materials", default=",".join(m["name"] for m in spec["materials"]))
    ap.add_argument("--lobes", default=",".join(str(k) for k in fits["lobes"]))
    ap.add_argument("--metrics", default=",".join(fits["metrics"]))
    ap.add_argument("--random-starts", type=int, default=8, help="brute-force starts per lobe (0: none)")
    ap.add_argument("--stride", type=int, default=1,
                    help="keep every N-th bin of each axis (the rest missing): the test's reduced size")
    ap.add_argument("--out", default="fit_materials_data")
    a = ap.parse_args()
    os.makedirs(a.out, exist_ok=True)
    by_name = {m["name"]: m for m in spec["materials"]}
    print("| material | model | metric | wall s | CPU s | peak MiB | iterations | cost | brute force cost | gap | brute force wall s |")
    print("|---|---|---|---|---|---|---|---|---|---|---|")
    for name in a.materials.split(","):
        if name not in by_name:
            raise SystemExit(f"unknown material '{name}' (known: {', '.join(by_name)})")
        data = os.path.join(a.out, name + (f"_stride{a.stride}" if a.stride > 1 else "") + ".binary")
        if not os.path.exists(data):
            write_material(data, by_name[name], spec["noise"], a.stride)
        for lobes in (int(x) for x in a.lobes.split(",")):
            model = "+".join([fits["diffuse"]] + [fits["lobe"]] * lobes)
            for metric in a.metrics.split(","):
                base = [a.exe, "fit", "--model", model, "--data", data, "--metric", metric, "--threads", "2", "--json"]
                stem = os.path.splitext(data)[0] + f"_{lobes}_{metric}"
                r = run(base, stem + ".json")
                brute, gap, brute_wall = "", "", ""
                if a.random_starts > 0:
                    b = run(base + ["--random-starts", str(a.random_starts * lobes), "--no-covariance"],
                            stem + "_brute.json")
                    brute, brute_wall = f"{b['cost']:.8g}", f"{b['wall']:.1f}"
                    gap = f"{(r['cost'] - b['cost']) / b['cost']:+.1e}"
                print(f"| {name} | {model} | {metric} | {r['wall']:.2f} | {r['cpu']:.2f} | {r['rss_mib']:.0f} | "
                      f"{r['iterations']} | {r['cost']:.8g} | {brute} | {gap} | {brute_wall} |", flush=True)


if __name__ == "__main__":
    sys.exit(main())
