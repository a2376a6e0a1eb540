#!/usr/bin/env python3
"""Python Model.eval on 10^6 directions against the C++ batch rate, same run.

    PYTHONPATH=build/python /usr/bin/python3 bench/python_bench.py build/bench/models_bench [model ...]

Runs models_bench's Eval<double>, EvalBatch<double> (1024 pairs, in cache)
and EvalBatch1M<double> (10^6 pairs into a new output, as Python) benchmarks
of each model (Google Benchmark, JSON), then times brdfkit.Model(model).eval on
10^6 random direction pairs (median of 7, CPU time of the calling thread,
as Google Benchmark's rates are CPU time; C++: median of 5 repetitions) and
prints the rates and the ratio Python / C++ batch.
"""
import json
import statistics
import subprocess
import sys
import time

import numpy as np

import brdfkit


def cpp_rates(exe, model):
    out = subprocess.run([exe, f"--benchmark_filter=^Eval(Batch|Batch1M)?<double>/{model}$", "--benchmark_format=json",
                          "--benchmark_min_time=0.5", "--benchmark_repetitions=5",
                          "--benchmark_report_aggregates_only=true"],
                         capture_output=True, text=True, check=True).stdout
    rates = {}
    for b in json.loads(out)["benchmarks"]:
        if b.get("aggregate_name") == "median":
            rates[b["name"].split("<")[0]] = b["items_per_second"]
    return rates


def python_rate(model, n=1_000_000, repeats=7):
    rng = np.random.default_rng(1)

    def dirs():
        z = 0.02 + 0.98 * rng.random(n)
        phi = 2 * np.pi * rng.random(n)
        s = np.sqrt(1 - z * z)
        return np.stack([s * np.cos(phi), s * np.sin(phi), z], axis=1)

    wi, wo = dirs(), dirs()
    m = brdfkit.Model(model)
    times = []
    for _ in range(repeats):
        t0 = time.thread_time()
        m.eval(wi, wo)
        times.append(time.thread_time() - t0)
    return n / statistics.median(times)


def main():
    exe = sys.argv[1]
    for model in sys.argv[2:] or ["ggx", "lambert"]:
        c = cpp_rates(exe, model)
        p = python_rate(model)
        line = (f"{model:10s} C++ Eval {c['Eval'] / 1e6:7.1f} M/s  EvalBatch {c['EvalBatch'] / 1e6:7.1f} M/s  "
                f"Python eval (1e6) {p / 1e6:7.1f} M/s  Python/batch {p / c['EvalBatch']:.2f}")
        if "EvalBatch1M" in c:
            line += f"  EvalBatch1M {c['EvalBatch1M'] / 1e6:7.1f} M/s  Python/batch1M {p / c['EvalBatch1M']:.2f}"
        print(line)


if __name__ == "__main__":
    main()
