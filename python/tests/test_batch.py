"""brdfkit.batch on a local Dask cluster bound to 127.0.0.1.

The executable is $BRDFKIT_EXE and the package is found on $PYTHONPATH (ctest
sets both), else build/brdfkit and build/python of the source tree. Every wait is bounded: subprocesses by timeouts, polls by
deadlines.
"""

import json
import os
import signal
import subprocess
import sys
import time

import pytest

ROOT = os.path.abspath(os.path.join(os.path.dirname(__file__), "..", ".."))
EXE = os.environ.get("BRDFKIT_EXE", os.path.join(ROOT, "build", "brdfkit"))
PY = sys.executable
ENV = dict(os.environ, PYTHONPATH=os.environ.get("PYTHONPATH") or os.path.join(ROOT, "build", "python"), BRDFKIT_EXE=EXE)
FIT_OPTIONS = {"max_iterations": 50, "starts": 2}
ALBEDO = {"name": "ggx", "model": "ggx", "axes": "mu:6,alpha:5:0.2:1", "slices": 3}


def batch(*args, timeout=120, **kw):
    return subprocess.run([PY, "-m", "brdfkit.batch", *args], env=ENV, capture_output=True, text=True,
                          timeout=timeout, **kw)


def start_batch(*args):
    return subprocess.Popen([PY, "-m", "brdfkit.batch", *args], env=ENV, stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True)


def write_job(folder, name, **extra):
    job = {"fits": {"data": ["tables/*.csv"], "models": ["lambert+ggx", "lambert+beckmann"],
                    "metrics": ["l2", "cbrt"], "options": FIT_OPTIONS}, **extra}
    path = os.path.join(folder, name)
    with open(path, "w") as f:
        json.dump(job, f)
    return path


@pytest.fixture(scope="module")
def data(tmp_path_factory):
    """Three synthetic materials (CSV tables of 210 samples) and their fits run one by one."""
    folder = tmp_path_factory.mktemp("batch")
    os.makedirs(folder / "tables")
    for alpha in ("0.05", "0.1", "0.3"):
        subprocess.run([EXE, "synth", "-q", "-m", "lambert+ggx", "-p",
                        f"lambert.albedo=0.2,ggx.alpha={alpha},ggx.f0=0.04",
                        "--out", str(folder / "tables" / f"a{alpha}.csv")], check=True, timeout=60)
    reference = {}
    for alpha in ("0.05", "0.1", "0.3"):
        for model in ("lambert+ggx", "lambert+beckmann"):
            for metric in ("l2", "cbrt"):
                p = subprocess.run([EXE, "fit", "--data", str(folder / "tables" / f"a{alpha}.csv"), "--model", model,
                                    "--metric", metric, "--max-iterations", "50", "--starts", "2",
                                    "--threads", "1", "--json"], capture_output=True, text=True, timeout=60,
                                   check=True)
                reference[(f"a{alpha}", model, metric)] = json.loads(p.stdout)
    return folder, reference


@pytest.fixture(scope="module")
def cluster():
    import dask
    import distributed
    dask.config.set({"distributed.worker.multiprocessing-method": "fork"})
    with distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True, host="127.0.0.1",
                                  dashboard_address=None) as c, distributed.Client(c) as client:
        yield c.scheduler_address, client


def check_results(out, reference):
    with open(os.path.join(out, "results.json")) as f:
        summary = json.load(f)
    fits = summary["fits"]
    keys = [(r["material"], r["model"], r["metric"]) for r in fits]
    assert sorted(keys) == sorted(reference), "every unit exactly once"
    for r in fits:
        ref = reference[(r["material"], r["model"], r["metric"])]
        for field in ("params", "stddev", "cost", "rmse", "iterations", "converged"):
            assert r["result"][field] == ref[field], (r["material"], r["model"], r["metric"], field)
    with open(os.path.join(out, "results.csv")) as f:
        lines = f.read().splitlines()
    assert len(lines) == 1 + len(reference)
    assert lines[0].startswith("material,model,metric,params,stddev,cost")
    assert len(os.listdir(os.path.join(out, "units"))) == summary["units"]
    return summary


def test_local_cluster_matches_one_by_one(data):
    folder, reference = data
    job = write_job(folder, "job.json", albedo=[ALBEDO])
    out = str(folder / "out-local")
    p = batch(job, "--workers", "2", "--out", out)
    assert p.returncode == 0, p.stderr
    summary = check_results(out, reference)
    assert summary["workers"] == 2 and summary["complete"]
    # The gathered table is the unsplit one.
    whole = subprocess.run([EXE, "albedo", "--model", "ggx", "--axes", ALBEDO["axes"], "--json"], capture_output=True,
                           text=True, timeout=120, check=True)
    want = json.loads(whole.stdout)
    with open(os.path.join(out, "tables", "ggx.json")) as f:
        got = json.load(f)
    want.pop("seconds")
    got.pop("seconds")
    assert got == want
    with open(os.path.join(out, "report.html")) as f:
        page = f.read()
    assert page.count("<tr><td>a0.") == len(reference)


def killed_worker_run(out, job, client, address, reference):
    """One batch whose busy worker is killed mid-run: (summary, units the victim held, victim), or None
    when the batch ended before a worker could be seen busy."""
    proc = start_batch(job, "--scheduler", address, "--out", out)
    try:
        deadline = time.monotonic() + 90
        victim, on_victim = None, set()
        while not on_victim and time.monotonic() < deadline and proc.poll() is None:
            units = os.path.join(out, "units")
            if os.path.isdir(units) and len(os.listdir(units)) >= 1:
                busy = {w: ts for w, ts in client.processing().items() if ts}
                if busy:
                    victim = sorted(busy)[0]
                    on_victim = {k[len("brdfkit-unit-"):] for k in busy[victim] if k.startswith("brdfkit-unit-")}
            if not on_victim:
                time.sleep(0.05)
        if on_victim:
            os.kill(client.run(os.getpid)[victim], signal.SIGKILL)
        stdout, stderr = proc.communicate(timeout=120)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    assert proc.returncode == 0, stderr
    return (check_results(out, reference), on_victim, victim) if on_victim else None


def test_killed_worker_unit_retried_elsewhere(data, cluster):
    folder, reference = data
    address, client = cluster
    job = write_job(folder, "job.json")
    # The kill races the victim: a unit that ends between the look and the kill stands, by the victim,
    # and leaves nothing to retry (more likely on a loaded machine), so the run is repeated on a fresh
    # folder, a few times at most, until one unit was retried.
    tries = []
    for attempt in range(4):
        run = killed_worker_run(str(folder / f"out-kill{attempt}"), job, client, address, reference)
        if run is None:
            tries.append("the batch ended before a worker was seen busy")
            continue
        summary, on_victim, victim = run
        assert summary["complete"] and not summary["failed"]
        retried = [r for r in summary["fits"] if r["key"] in on_victim and r["worker"] != victim]
        if retried:
            return
        tries.append(f"the units {sorted(on_victim)} ended on the victim before the kill")
    pytest.fail("no unit was retried: " + "; ".join(tries))


def finished(units):
    return sorted(n for n in os.listdir(units) if n.endswith(".json"))


def stopped_run(out, job, address):
    """One batch stopped by SIGINT once 3 units are done: its exit status."""
    units = os.path.join(out, "units")
    proc = start_batch(job, "--scheduler", address, "--out", out)
    try:
        deadline = time.monotonic() + 90
        while time.monotonic() < deadline and proc.poll() is None:
            if os.path.isdir(units) and len(finished(units)) >= 3:
                break
            time.sleep(0.02)
        proc.send_signal(signal.SIGINT)
        proc.communicate(timeout=60)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    return proc.returncode


def test_stopped_batch_resumes(data, cluster):
    folder, reference = data
    address, _ = cluster
    job = write_job(folder, "job.json")
    # The stop races the batch's last units: on a loaded machine all may end before the signal lands,
    # and the batch exits 0 with nothing left to resume; the run is then repeated on a fresh folder.
    for attempt in range(4):
        out = str(folder / f"out-resume{attempt}")
        units = os.path.join(out, "units")
        code = stopped_run(out, job, address)
        if code == 0 and len(finished(units)) == len(reference):
            continue
        break
    else:
        pytest.fail("every batch ended before the stop reached it")
    assert code == 130
    assert finished(units) == sorted(os.listdir(units)), "the stop left a partial file behind"
    before = {n: os.stat(os.path.join(units, n)).st_mtime_ns for n in finished(units)}
    assert 3 <= len(before) < len(reference)
    p = batch(job, "--scheduler", address, "--out", out)
    assert p.returncode == 0, p.stderr
    assert f"{len(reference)} units, {len(before)} done before, {len(reference) - len(before)} to run" in p.stderr
    for n, t in before.items():
        assert os.stat(os.path.join(units, n)).st_mtime_ns == t, "a finished unit was recomputed"
    check_results(out, reference)
    # A third run recomputes nothing.
    p = batch(job, "--scheduler", address, "--out", out)
    assert p.returncode == 0 and f"{len(reference)} done before, 0 to run" in p.stderr


@pytest.mark.parametrize("job, message", [
    ({"fits": {"data": ["tables/*.csv"], "models": ["ggx"], "metirc": ["l2"]}}, "fits.metirc: unknown key"),
    ({"fits": {"data": ["tables/*.csv"], "models": ["ggx"], "metrics": ["l2", "l3"]}}, "fits.metrics[1]: 'l3'"),
    ({"fits": {"data": ["nothing/*.binary"], "models": ["ggx"]}}, "fits.data[0]: 'nothing/*.binary' matches no file"),
    ({"fits": {"data": ["tables/*.csv"], "models": ["lambert+ggxx"]}}, "fits.models[0]: unknown model 'ggxx'"),
    ({"fits": {"data": ["tables/*.csv"], "models": ["ggx"], "options": {"starts": 0}}}, "fits.options.starts: 0"),
    ({"albedo": [{"name": "t", "model": "ggx", "axes": "mu:8,roughness:4"}]}, "albedo[0].axes: 'roughness'"),
    ({"albedo": [{"name": "t", "model": "ggx", "axes": "mu:8,alpha:4", "slices": 5}]}, "albedo[0].slices"),
    ({"output": "x"}, "(top level):"),
])
def test_bad_job_rejected_before_work(data, job, message):
    folder, _ = data
    path = os.path.join(folder, "bad.json")
    with open(path, "w") as f:
        json.dump(job, f)
    out = str(folder / "out-bad")
    p = batch(path, "--out", out, timeout=60)
    assert p.returncode == 2
    assert f"bad.json: {message}" in p.stderr, p.stderr
    assert not os.path.exists(out)


def test_bad_json_named(data):
    folder, _ = data
    path = os.path.join(folder, "broken.json")
    with open(path, "w") as f:
        f.write('{"fits": {"data": [}\n')
    p = batch(path, timeout=60)
    assert p.returncode == 2 and "broken.json: not valid JSON" in p.stderr and "line 1" in p.stderr
