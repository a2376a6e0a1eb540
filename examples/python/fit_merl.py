#!/usr/bin/env python3
"""Fit lambert+ggx to a MERL file and plot measured against fitted slices.

    python3 examples/python/fit_merl.py MATERIAL.binary [figure.png] [--samples N]

Reads the MERL table, fits lambert+ggx on a random subset of its valid
cells, prints the fit (JSON) and draws f_r in the plane of incidence,
measured (the MERL table) and fitted, for four incidence angles.
"""
import argparse
import json

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

import brdfkit  # noqa: E402


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("merl", help="MERL .binary file")
    ap.add_argument("figure", nargs="?", default="fit_merl.png", help="output figure (PNG, SVG, PDF)")
    ap.add_argument("--samples", type=int, default=20000, help="cells used by the fit (default 20000)")
    ap.add_argument("--seed", type=int, default=1)
    args = ap.parse_args()

    data = brdfkit.read(args.merl)
    rng = np.random.default_rng(args.seed)
    pick = rng.choice(len(data["f"]), size=min(args.samples, len(data["f"])), replace=False)
    result = brdfkit.fit("lambert+ggx", data["wi"][pick], data["wo"][pick], data["f"][pick], metric="log")
    fitted = result["model_object"]
    print(json.dumps({"params": result["params"], "stddev": result["stddev"], "rmse": result["rmse"],
                      "converged": result["converged"], "samples": result["samples"]}))

    measured = brdfkit.Model("merl:" + args.merl)
    theta_o = np.radians(np.linspace(-89, 89, 357))
    wo = np.stack([np.sin(theta_o), np.zeros_like(theta_o), np.cos(theta_o)], axis=1)
    fig, axes = plt.subplots(1, 4, figsize=(14, 3.5), sharey=True)
    for ax, theta_i_deg in zip(axes, (0, 30, 50, 70)):
        t = np.radians(theta_i_deg)
        wi = np.array([-np.sin(t), 0.0, np.cos(t)])  # mirror direction at theta_o = +theta_i
        ax.semilogy(np.degrees(theta_o), measured.eval(wi, wo)[:, 1], "k.", ms=2, label="measured (MERL)")
        ax.semilogy(np.degrees(theta_o), fitted.eval(wi, wo)[:, 1], "r-", lw=1, label="lambert+ggx fit")
        ax.set_title(f"theta_i = {theta_i_deg} deg")
        ax.set_xlabel("theta_o in the plane of incidence (deg)")
    axes[0].set_ylabel("f_r, green (1/sr)")
    axes[0].legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(args.figure, dpi=100)


if __name__ == "__main__":
    main()
