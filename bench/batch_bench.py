"""Scale figures of brdfkit.batch, measured in one run on this machine.

    PYTHONPATH=build/python /usr/bin/python3 bench/batch_bench.py build/brdfkit [WORKDIR]

1. Throughput of one batch (6 CSV materials x 2 models x 2 metrics) on a
   local cluster of 1 and of 2 worker processes: the ratio.
2. Unit costs for the full MERL batch: one fit of a 35 MB MERL file per
   lobe count (1, 2, 3 specular lobes) with the cbrt metric, hashing the
   file, and shipping it to a worker through Dask (scatter), plus the
   scheduler's cost per task (no-op tasks).
3. The model: wall time of 100 materials x 3 x 4 on 2 cores and on 64.
"""

import json
import os
import shutil
import subprocess
import sys
import tempfile
import time



def timed(f):
    t = time.monotonic()
    r = f()
    return time.monotonic() - t, r


def main():
    exe = os.path.abspath(sys.argv[1])
    # The package built next to the tool (BUILD/python), as the tests use it.
    sys.path.insert(0, os.path.join(os.path.dirname(exe), "python"))
    global batch
    from brdfkit import batch
    work = sys.argv[2] if len(sys.argv) > 2 else tempfile.mkdtemp(prefix="brdfkit-batch-bench-")
    os.makedirs(os.path.join(work, "tables"), exist_ok=True)
    for i, alpha in enumerate((0.03, 0.05, 0.1, 0.2, 0.3, 0.5)):
        subprocess.run([exe, "synth", "-q", "-m", "lambert+ggx", "-p", f"lambert.albedo=0.2,ggx.alpha={alpha}",
                        "--out", os.path.join(work, "tables", f"m{i}.csv")], check=True)
    job_path = os.path.join(work, "job.json")
    with open(job_path, "w") as f:
        json.dump({"fits": {"data": ["tables/*.csv"], "models": ["lambert+ggx", "lambert+ggx+ggx"],
                            "metrics": ["l2", "cbrt"]}}, f)
    job = batch.load_job(job_path, exe)
    walls = {}
    for n in (1, 2):
        out = os.path.join(work, f"out{n}")
        shutil.rmtree(out, ignore_errors=True)
        walls[n], summary = timed(lambda: batch.run(job, exe, out, workers=n, log=lambda m: None))
        unit_sum = sum(r["wall_seconds"] for r in summary["fits"])
        print(f"{n} worker(s): {summary['units']} units in {walls[n]:.2f} s (cluster start and stop included), "
              f"sum of unit walls {unit_sum:.2f} s")
    print(f"throughput ratio 2 workers / 1 worker: {walls[1] / walls[2]:.2f}")

    merl = os.path.join(work, "paint.binary")
    subprocess.run([exe, "synth", "-q", "-m", "lambert+ggx", "-p", "lambert.albedo=0.1,ggx.alpha=0.08,ggx.f0=0.04",
                    "-i", os.path.join(os.path.dirname(exe), "..", "examples", "instruments", "merl_grid.json")
                    if os.path.exists(os.path.join(os.path.dirname(exe), "..", "examples")) else
                    "examples/instruments/merl_grid.json", "--out", merl], check=True)
    t_hash, _ = timed(lambda: batch._sha256_file(merl))
    print(f"sha256 of a {os.path.getsize(merl) / 1e6:.1f} MB MERL file: {t_hash:.3f} s")
    fit_costs = {}
    for model in ("lambert+ggx", "lambert+ggx+ggx", "lambert+ggx+ggx+ggx"):
        t, p = timed(lambda: subprocess.run([exe, "fit", "--data", merl, "--model", model, "--metric", "cbrt",
                                             "--threads", "1", "--json"], capture_output=True, text=True))
        fit_costs[model] = t
        print(f"MERL fit {model} cbrt, 1 thread: {t:.1f} s (exit {p.returncode})")

    import dask
    import distributed
    dask.config.set({"distributed.worker.multiprocessing-method": "fork"})
    with distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True, host="127.0.0.1",
                                  dashboard_address=None) as c, distributed.Client(c) as client:
        with open(merl, "rb") as f:
            blob = f.read()
        t_scatter, fut = timed(lambda: client.scatter(blob, broadcast=False))
        t_move, _ = timed(lambda: client.submit(len, fut, workers=[w for w in client.scheduler_info()["workers"]
                                                                    if w not in client.who_has(fut)[fut.key]][:1],
                                                pure=False).result())
        print(f"scatter 35 MB to a worker: {t_scatter:.3f} s; worker-to-worker copy and use: {t_move:.3f} s")
        n = 2000
        t_tasks, _ = timed(lambda: client.gather(client.map(lambda x: x, range(n), pure=False)))
        print(f"scheduler: {n} no-op tasks in {t_tasks:.2f} s, {1e3 * t_tasks / n:.2f} ms per task")

    per_material = 4 * sum(fit_costs.values())  # 3 lobe counts x 4 metrics, metric costs taken as cbrt's
    total = 100 * per_material
    overhead = 100 * (t_hash + t_scatter) + 1200 * t_tasks / n
    print(f"model: 1200 units, {total:.0f} s of fitting; on 2 cores {(total / 2 + overhead) / 3600:.2f} h, "
          f"on 64 cores {(total / 64 + overhead) / 60:.1f} min (overhead {overhead:.0f} s: hashing, shipping, "
          f"scheduling)")


if __name__ == "__main__":
    main()
