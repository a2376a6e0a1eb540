#!/usr/bin/env python3
"""Models defined in Python through the tools, against the built-in model, same run.

    PYTHONPATH=build/python /usr/bin/python3 bench/python_models_bench.py

A numpy GGX (Schlick Fresnel, height-correlated Smith: the built-in `ggx`) as a
brdfkit.PythonModel goes through albedo_table (mu:8, alpha:4), check and a fit
of 20,000 pairs; the built-in `ggx` does the same. Prints wall seconds, the number of calls
of the Python function and the directions per call, and the cost of the
same directions pair by pair (one-row calls, timed in this run).
"""
import time

import numpy as np

import brdfkit

calls = {"n": 0, "rows": 0}


def ggx(wi, wo, p):
    calls["n"] += 1
    calls["rows"] += len(wi)
    a2 = p["alpha"] ** 2
    h = wi + wo
    h /= np.linalg.norm(h, axis=1, keepdims=True)
    c = h[:, 2]
    d = a2 / (np.pi * (c * c * (a2 - 1) + 1) ** 2)

    def lam(w):
        z2 = np.clip(w[:, 2] ** 2, 1e-300, None)
        return 0.5 * (np.sqrt(1 + a2 * (1 - z2) / z2) - 1)

    f = p["f0"] + (1 - p["f0"]) * (1 - np.clip(np.sum(wi * h, axis=1), 0, 1)) ** 5
    with np.errstate(divide="ignore", invalid="ignore"):
        v = np.where((wi[:, 2] > 0) & (wo[:, 2] > 0), d * f / ((1 + lam(wi) + lam(wo)) * 4 * wi[:, 2] * wo[:, 2]), 0.0)
    return np.repeat(v[:, None], 3, axis=1)


PARAMS = {"alpha": {"default": 0.2, "lower": 1e-3, "upper": 1.0, "scale": "log"},
          "f0": {"default": 0.04, "lower": 0.0, "upper": 1.0}}
MODEL = brdfkit.PythonModel(ggx, PARAMS, kind="glossy", width=lambda p: p["alpha"], name="py_ggx")


def directions(n, seed):
    rng = np.random.default_rng(seed)
    z = 0.1 + 0.9 * rng.random(n)
    phi = 2 * np.pi * rng.random(n)
    return np.stack([np.sqrt(1 - z * z) * np.cos(phi), np.sqrt(1 - z * z) * np.sin(phi), z], axis=1)


# The data of the fit: the built-in ggx (alpha 0.25, f0 0.7) at 20,000 random pairs.
FIT_WI, FIT_WO = directions(20000, 1), directions(20000, 2)
FIT_F = brdfkit.Model("ggx", {"alpha": 0.25, "f0": 0.7}).eval(FIT_WI, FIT_WO)


def timed(fn):
    calls["n"] = calls["rows"] = 0
    t0 = time.perf_counter()
    out = fn()
    return out, time.perf_counter() - t0, calls["n"], calls["rows"]


def main():
    axes = "mu:8,alpha:4:0.05:0.8"
    rows = []
    for name, model in (("python", MODEL), ("built-in", "ggx")):
        t, secs, n, r = timed(lambda: brdfkit.albedo_table(model, {"f0": 1.0}, axes=axes, threads=1))
        rows.append((f"albedo_table {axes}", name, secs, n, r, t["E"]))
        c, secs, n, r = timed(lambda: brdfkit.check(model, {"alpha": 0.3, "f0": 1.0}, sampling=False, threads=1))
        rows.append(("check alpha=0.3", name, secs, n, r, c["albedo_max"]))
        fr, secs, n, r = timed(lambda: brdfkit.fit(model, FIT_WI, FIT_WO, FIT_F, threads=1))
        rows.append((f"fit {len(FIT_WI)} pairs", name, secs, n, r, fr["cost"]))
    # One-row calls: what the pair-by-pair evaluation of the same rows costs.
    wi, wo = np.array([[0.1, 0.2, 0.97]]), np.array([[-0.1, 0.1, 0.99]])
    p = {"alpha": 0.3, "f0": 1.0}
    reps = 20000
    t0 = time.perf_counter()
    for _ in range(reps):
        ggx(wi, wo, p)
    per_call = (time.perf_counter() - t0) / reps
    print(f"{'task':34s} {'model':9s} {'wall s':>8s} {'calls':>8s} {'rows/call':>9s} {'pair by pair (est.) s':>22s}")
    for task, name, secs, n, r, _ in rows:
        est = f"{r * per_call:.1f}" if name == "python" else ""
        per = f"{r / n:.1f}" if n else ""
        print(f"{task:34s} {name:9s} {secs:8.2f} {n if name == 'python' else '':>8} {per:>9s} {est:>22s}")
    print(f"one-row call of the numpy function: {per_call * 1e6:.1f} us")
    e_py, e_ref = rows[0][5], rows[3][5]
    print(f"max |E_python - E_builtin| = {np.max(np.abs(np.asarray(e_py) - np.asarray(e_ref))):.2e}")
    print(f"fit cost: python {rows[2][5]:.3e}, built-in {rows[5][5]:.3e}")


if __name__ == "__main__":
    main()
