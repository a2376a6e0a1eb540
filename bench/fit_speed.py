#!/usr/bin/env python3
"""Whole `brdfkit fit` runs on a full MERL-size file: wall time, CPU time and
peak memory of the process, for two builds in the same run.

    PYTHONPATH=build/python /usr/bin/python3 bench/fit_speed.py NEW_EXE [BASELINE_EXE] \
        [--models lambert+ggx,lambert+ggx+ggx] [--metrics l2,relative,cosine,log,cbrt] [--out DIR]

Writes two MERL binaries (90 x 90 x 180 bins) into DIR (default
fit_speed_data/) unless they are there:
- `outside.binary`, the material of issue 14, from outside every fitted
  family: Oren-Nayar diffuse (albedo 0.5:0.3:0.2, sigma 0.3), a Beckmann
  lobe (alpha 0.07, F0 0.04) and a 25 % GGX haze (alpha 0.35, F0 0.04);
  2 % lognormal noise per cell, 2 % of the cells missing, 0.05 % fivefold
  spikes (seed 7);
- `beckmann.binary`, noiseless lambert+beckmann (albedo 0.12:0.09:0.05,
  alpha 0.08, F0 0.9:0.75:0.55), the case whose l2 optimum under
  lambert+ggx puts the albedos on their upper bound.
Then runs each executable on each (model, metric) of the outside material,
and lambert+ggx under l2 on the Beckmann material, one process at a time
with `--threads 2 --json` (uncertainties included), and prints a Markdown
table: wall and CPU seconds (user + system, from wait4), peak resident
memory, final cost, iterations. Each run's JSON goes to DIR too.
"""
import argparse
import json
import os
import subprocess
import sys
import time

import numpy as np

import brdfkit


def write_outside(path):
    m = brdfkit.Model("oren_nayar+beckmann+ggx", {
        "oren_nayar.albedo": (0.5, 0.3, 0.2), "oren_nayar.sigma": 0.3,
        "beckmann.alpha": 0.07, "beckmann.f0": 0.04,
        "ggx.alpha": 0.35, "ggx.f0": 0.04, "ggx.weight": 0.25})
    clean = path + ".clean.binary"
    brdfkit.write(clean, m)
    raw = open(clean, "rb").read()
    os.remove(clean)
    v = np.frombuffer(raw[12:], dtype=np.float64).copy()
    rng = np.random.default_rng(7)
    n = v.size // 3
    v *= np.tile(np.exp(rng.normal(0, 0.02, n)), 3)
    missing = rng.random(n) < 0.02
    spike = (rng.random(n) < 0.0005) & ~missing
    for c in range(3):
        plane = v[c * n:(c + 1) * n]
        plane[spike] *= 5
        plane[missing] = -1
    with open(path, "wb") as f:
        f.write(raw[:12] + v.tobytes())


def write_beckmann(path):
    brdfkit.write(path, brdfkit.Model("lambert+beckmann", {
        "lambert.albedo": (0.12, 0.09, 0.05), "beckmann.alpha": 0.08, "beckmann.f0": (0.9, 0.75, 0.55)}))


def timed_fit(args, out_json):
    """Runs one `brdfkit fit --json` command line (args), its JSON to out_json:
    wall and CPU seconds (user + system, from wait4), peak resident MiB, cost,
    iterations and starts."""
    t0 = time.monotonic()
    with open(out_json, "w") as out:
        p = subprocess.Popen(args, stdout=out, stderr=subprocess.DEVNULL)
        _, status, usage = os.wait4(p.pid, 0)
    wall = time.monotonic() - t0
    if status != 0:
        raise SystemExit(f"{' '.join(args)} failed ({status})")
    r = json.load(open(out_json))
    return {"wall": wall, "cpu": usage.ru_utime + usage.ru_stime, "rss_mib": usage.ru_maxrss / 1024,
            "cost": r["cost"], "iterations": r["iterations"], "starts": r["starts"]}


def run(exe, model, data, metric, out_json):
    return timed_fit([exe, "fit", "--model", model, "--data", data, "--metric", metric, "--threads", "2", "--json"],
                     out_json)


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("exes", nargs="+")
    ap.add_argument("--models", default="lambert+ggx,lambert+ggx+ggx")
    ap.add_argument("--metrics", default="l2,relative,cosine,log,cbrt")
    ap.add_argument("--baseline-models", default="lambert+ggx",
                    help="models the second executable (the baseline) runs")
    ap.add_argument("--out", default="fit_speed_data")
    a = ap.parse_args()
    os.makedirs(a.out, exist_ok=True)
    outside, beckmann = os.path.join(a.out, "outside.binary"), os.path.join(a.out, "beckmann.binary")
    if not os.path.exists(outside):
        write_outside(outside)
    if not os.path.exists(beckmann):
        write_beckmann(beckmann)
    cases = [(m, outside, metric) for m in a.models.split(",") for metric in a.metrics.split(",")]
    cases.append(("lambert+ggx", beckmann, "l2"))
    print("| data | model | metric | build | wall s | CPU s | peak MiB | cost | iterations | starts |")
    print("|---|---|---|---|---|---|---|---|---|---|")
    for model, data, metric in cases:
        for k, exe in enumerate(a.exes):
            if k > 0 and model not in a.baseline_models.split(","):
                continue
            tag = "new" if k == 0 else "baseline"
            out_json = os.path.join(a.out, f"{tag}_{os.path.basename(data)}_{model}_{metric}.json")
            r = run(exe, model, data, metric, out_json)
            print(f"| {os.path.basename(data)} | {model} | {metric} | {tag} | {r['wall']:.2f} | {r['cpu']:.2f} | "
                  f"{r['rss_mib']:.0f} | {r['cost']:.8g} | {r['iterations']} | {r['starts']} |", flush=True)


if __name__ == "__main__":
    sys.exit(main())
