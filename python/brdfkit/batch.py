"""Batches of fits and albedo tables on Dask distributed.

    python3 -m brdfkit.batch JOB.json [--scheduler tcp://HOST:PORT] [--workers N]
                                      [--out DIR] [--brdfkit PATH] [--ship-data] [--dry-run]

A job file (schema: brdfkit/batch.schema.json) names data files (globs,
relative to the job file), the models and metrics to cross with them, and
albedo tables to split into slices along their first parameter axis. Each
work unit runs the brdfkit command-line tool as a subprocess (`brdfkit fit
... --json`, `brdfkit albedo ... --slice B:E --json`): the results are the
tool's own JSON, a unit that crashes cannot take its worker down, and the
workers need only Python, Dask and the brdfkit executable.

Each unit's result is written atomically (temporary file, then rename) to
OUT/units/KEY.json as soon as it arrives; KEY is a hash of the unit's inputs
(data file bytes, model, metric, options, brdfkit version). A unit whose file
exists is not recomputed, so a stopped batch resumes where it was. A unit on
a worker that dies is rescheduled by Dask on another worker. The results are
gathered into OUT/results.json, OUT/results.csv, OUT/report.html and one
OUT/tables/NAME.json per albedo table.

Without --scheduler the batch runs on a local cluster of worker processes
(one per core, one thread each) bound to 127.0.0.1.
"""

import argparse
import csv
import difflib
import glob
import hashlib
import html
import io
import json
import os
import shutil
import signal
import socket
import subprocess
import sys
import time

SCHEMA_PATH = os.path.join(os.path.dirname(os.path.abspath(__file__)), "batch.schema.json")
METRICS = ["l2", "relative", "cosine", "log", "cbrt"]
MERL_BYTES = 12 + 3 * 90 * 90 * 180 * 8


class JobError(ValueError):
    """A job file that cannot run; the message names the file and the key path."""


class BatchError(RuntimeError):
    """A batch that cannot start (no brdfkit executable, no scheduler)."""


# --- the brdfkit executable -------------------------------------------------

def find_brdfkit(explicit=None):
    """--brdfkit PATH, else $BRDFKIT_EXE, else `brdfkit` on PATH."""
    for source, value in (("--brdfkit", explicit), ("BRDFKIT_EXE", os.environ.get("BRDFKIT_EXE"))):
        if value:
            path = shutil.which(value) or (value if os.path.isfile(value) else None)
            if not path or not os.access(path, os.X_OK):
                raise BatchError(f"{source}: '{value}' is not an executable file")
            return os.path.abspath(path)
    path = shutil.which("brdfkit")
    if not path:
        raise BatchError("no brdfkit executable: give --brdfkit PATH, set BRDFKIT_EXE, or put brdfkit on PATH")
    return path


def _tool(exe, *args):
    p = subprocess.run([exe, *args], capture_output=True, text=True)
    if p.returncode != 0:
        raise BatchError(f"'{exe} {' '.join(args)}' failed: {p.stderr.strip()}")
    return p.stdout


def brdfkit_version(exe):
    return _tool(exe, "--version").strip()


# --- the job file ------------------------------------------------------------

def _key_path(path):
    out = ""
    for p in path:
        out += f"[{p}]" if isinstance(p, int) else (("." if out else "") + str(p))
    return out or "(top level)"


def _schema_error(job_path, error):
    path = list(error.absolute_path)
    if error.validator == "additionalProperties":
        extra = sorted(set(error.instance) - set(error.schema.get("properties", {})))
        if extra:
            known = sorted(error.schema.get("properties", {}))
            hint = difflib.get_close_matches(extra[0], known, n=1)
            return JobError(f"{job_path}: {_key_path(path + [extra[0]])}: unknown key"
                            + (f" (did you mean {hint[0]}?)" if hint else f" (known: {', '.join(known)})"))
    return JobError(f"{job_path}: {_key_path(path)}: {error.message}")


def _lobes(exe):
    models = json.loads(_tool(exe, "models", "--json"))
    return {m["name"]: [p["name"] for p in m["params"]] for m in models}


def _param_names(lobes, spec):
    """Parameter names of a model or sum of lobes, as the tool names them."""
    parts = spec.split("+")
    if len(parts) == 1:
        return list(lobes[parts[0]])
    names, seen = [], {}
    for lobe in parts:
        seen[lobe] = seen.get(lobe, 0) + 1
        tag = lobe if seen[lobe] == 1 else f"{lobe}#{seen[lobe]}"
        names += [f"{tag}.{p}" for p in lobes[lobe]]
    return names


def _check_model(job_path, where, spec, lobes):
    for lobe in spec.split("+"):
        if lobe not in lobes:
            hint = difflib.get_close_matches(lobe, sorted(lobes), n=1)
            raise JobError(f"{job_path}: {where}: unknown model '{lobe}' in '{spec}'"
                           + (f" (did you mean {hint[0]}?)" if hint else ""))
        if lobe == "merl":
            raise JobError(f"{job_path}: {where}: measured models are data, not models to fit or tabulate: "
                           "list the MERL files under fits.data")


def _first_axis_count(job_path, where, axes, names):
    items = axes.split(",")
    if len(items) < 2 or len(items) > 3 or items[0].split(":")[0] != "mu":
        raise JobError(f"{job_path}: {where}: expected mu:N followed by one or two model parameters "
                       "(e.g. mu:32,alpha:32:0.001:1), got '{axes}'")
    counts = []
    for item in items:
        f = item.split(":")
        if len(f) not in (2, 4) or not f[1].isdigit() or int(f[1]) < 1:
            raise JobError(f"{job_path}: {where}: '{item}' is not name:count[:lower:upper]")
        if f[0] != "mu" and f[0] not in names:
            hint = difflib.get_close_matches(f[0], names, n=1)
            raise JobError(f"{job_path}: {where}: '{f[0]}' is not a parameter of the model"
                           + (f" (did you mean {hint[0]}?)" if hint else f" (parameters: {', '.join(names)})"))
        counts.append(int(f[1]))
    return counts[1]


def load_job(job_path, exe):
    """Reads and checks a job file before any work; raises JobError naming the file and key path."""
    import jsonschema
    try:
        with open(job_path, encoding="utf-8") as f:
            job = json.load(f)
    except OSError as e:
        raise JobError(f"{job_path}: cannot read: {e.strerror}") from None
    except json.JSONDecodeError as e:
        raise JobError(f"{job_path}: not valid JSON: {e.msg} at line {e.lineno}, column {e.colno}") from None
    with open(SCHEMA_PATH, encoding="utf-8") as f:
        schema = json.load(f)
    validator = jsonschema.Draft202012Validator(schema)
    error = jsonschema.exceptions.best_match(validator.iter_errors(job))
    if error is not None:
        raise _schema_error(job_path, error)

    base = os.path.dirname(os.path.abspath(job_path))
    lobes = _lobes(exe)
    fits = job.get("fits")
    if fits:
        files, names = [], {}
        for i, pattern in enumerate(fits["data"]):
            where = f"fits.data[{i}]"
            matched = sorted(glob.glob(os.path.join(base, pattern)))
            if not matched:
                raise JobError(f"{job_path}: {where}: '{pattern}' matches no file (relative to {base})")
            for path in matched:
                stem, ext = os.path.splitext(os.path.basename(path))
                if ext not in (".csv", ".binary"):
                    raise JobError(f"{job_path}: {where}: '{path}': expected a .csv table or a .binary MERL file")
                if ext == ".binary" and os.path.getsize(path) != MERL_BYTES:
                    raise JobError(f"{job_path}: {where}: '{path}' has {os.path.getsize(path)} bytes, a MERL file "
                                   f"has {MERL_BYTES}")
                if stem in names and names[stem] != path:
                    raise JobError(f"{job_path}: {where}: material name '{stem}' is given by two files, "
                                   f"'{names[stem]}' and '{path}'")
                if stem not in names:
                    names[stem] = path
                    files.append((stem, path))
        fits["_files"] = files
        for i, m in enumerate(fits["models"]):
            _check_model(job_path, f"fits.models[{i}]", m, lobes)
        inst = fits.get("options", {}).get("instrument")
        if inst is not None:
            fits["options"]["instrument"] = os.path.join(base, inst)
            if not os.path.isfile(fits["options"]["instrument"]):
                raise JobError(f"{job_path}: fits.options.instrument: file '{inst}' not found (relative to {base})")
    seen = set()
    for i, t in enumerate(job.get("albedo", [])):
        where = f"albedo[{i}]"
        if t["name"] in seen:
            raise JobError(f"{job_path}: {where}.name: '{t['name']}' is given twice")
        seen.add(t["name"])
        _check_model(job_path, f"{where}.model", t["model"], lobes)
        n1 = _first_axis_count(job_path, f"{where}.axes", t["axes"], _param_names(lobes, t["model"]))
        if t.get("slices", n1) > n1:
            raise JobError(f"{job_path}: {where}.slices: {t['slices']} slices of a first axis of {n1} nodes")
        t["_n1"] = n1
    job["_path"] = os.path.abspath(job_path)
    return job


# --- work units -----------------------------------------------------------

def _sha256_file(path):
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


def _fit_options(options):
    args = []
    for key, flag in (("max_iterations", "--max-iterations"), ("starts", "--starts"),
                      ("max_theta_deg", "--max-theta-deg"), ("loss", "--loss"), ("solver", "--solver"),
                      ("init", "--init")):
        if key in options:
            args += [flag, str(options[key])]
    if options.get("ignore_sigma"):
        args.append("--ignore-sigma")
    if options.get("no_covariance"):
        args.append("--no-covariance")
    args += ["--threads", str(options.get("threads", 1))]
    return args


def _key(parts):
    return hashlib.sha256(json.dumps(parts, sort_keys=True).encode()).hexdigest()[:24]


def plan(job, version):
    """The job's work units, each with its content key."""
    units = []
    fits = job.get("fits")
    if fits:
        options = fits.get("options", {})
        args = _fit_options(options)
        inst = options.get("instrument")
        inst_hash = _sha256_file(inst) if inst else None
        for material, path in fits["_files"]:
            data_hash = _sha256_file(path)
            for model in fits["models"]:
                for metric in fits.get("metrics", ["l2"]):
                    unit_args = ["--model", model, "--metric", metric] + args
                    if inst:
                        unit_args += ["--instrument", inst]
                    units.append({
                        "kind": "fit", "material": material, "model": model, "metric": metric, "data": path,
                        "data_sha256": data_hash, "args": unit_args,
                        # the instrument by its content, not its path
                        "key": _key(["fit", data_hash, inst_hash, unit_args[:-1] if inst else unit_args, version]),
                    })
    for t in job.get("albedo", []):
        n1, k = t["_n1"], t.get("slices", t["_n1"])
        base = ["--model", t["model"], "--axes", t["axes"], "--nodes", t.get("nodes", "uniform"),
                "--threads", str(t.get("threads", 1))]
        for opt, flag in (("params", "--params"), ("tolerance", "--tolerance"),
                          ("accept_error", "--accept-error"), ("channel", "--channel")):
            if opt in t:
                base += [flag, str(t[opt])]
        for s in range(k):
            b, e = (s * n1) // k, ((s + 1) * n1) // k
            unit_args = base + ["--slice", f"{b}:{e}"]
            units.append({"kind": "albedo", "table": t["name"], "slice": [b, e], "args": unit_args,
                          "key": _key(["albedo", unit_args, version])})
    return units


def _die_with_parent():
    # The unit's process ends with its worker: a killed worker leaves no fit running.
    import ctypes
    ctypes.CDLL("libc.so.6", use_errno=True).prctl(1, signal.SIGKILL)  # PR_SET_PDEATHSIG


def run_unit(unit, exe, version, data=None):
    """Runs one unit on a worker: the tool as a subprocess, its JSON returned."""
    start = time.monotonic()
    where = {"host": socket.gethostname(), "pid": os.getpid()}
    try:
        from distributed import get_worker
        where["worker"] = get_worker().address
    except (ImportError, ValueError):
        where["worker"] = None
    try:
        got = subprocess.run([exe, "--version"], capture_output=True, text=True).stdout.strip()
    except OSError as e:
        return {"status": "failed", "error": f"cannot run '{exe}': {e.strerror}", **where}
    if got != version:
        return {"status": "failed", "error": f"'{exe}' on this worker is '{got}', the batch is keyed by '{version}'",
                **where}
    args = list(unit["args"])
    if unit["kind"] == "fit":
        path = unit["data"]
        if data is not None:  # shipped bytes: a worker-local copy named by content
            path = os.path.join(os.environ.get("TMPDIR", "/tmp"), "brdfkit-batch-data",
                                unit["data_sha256"] + os.path.splitext(unit["data"])[1])
            if not os.path.exists(path):
                os.makedirs(os.path.dirname(path), exist_ok=True)
                tmp = f"{path}.{os.getpid()}.tmp"
                with open(tmp, "wb") as f:
                    f.write(data)
                os.replace(tmp, path)
        cmd = [exe, "fit", "--data", path, *args, "--json"]
    else:
        cmd = [exe, "albedo", *args, "--json"]
    p = subprocess.run(cmd, capture_output=True, text=True, preexec_fn=_die_with_parent)
    wall = time.monotonic() - start
    if p.returncode != 0:
        why = f"killed by signal {-p.returncode}" if p.returncode < 0 else f"exit code {p.returncode}"
        return {"status": "failed", "error": f"{why}: {p.stderr.strip()[-2000:]}", "wall_seconds": wall, **where}
    try:
        result = json.loads(p.stdout)
    except json.JSONDecodeError as e:
        return {"status": "failed", "error": f"output is not JSON: {e}", "wall_seconds": wall, **where}
    return {"status": "ok", "result": result, "wall_seconds": wall, **where}


# --- results on disk --------------------------------------------------------

def write_atomic(path, text):
    tmp = f"{path}.{os.getpid()}.tmp"
    try:
        with open(tmp, "w", encoding="utf-8") as f:
            f.write(text)
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, path)
    except BaseException:
        # A stop (Ctrl-C) or a full disk mid-write leaves no partial file behind.
        if os.path.exists(tmp):
            os.remove(tmp)
        raise


def _remove_stale_temporaries(folder):
    """Temporaries of a process killed outright (SIGKILL) mid-write."""
    for name in os.listdir(folder):
        if name.endswith(".tmp"):
            os.remove(os.path.join(folder, name))


def _unit_file(out, unit):
    return os.path.join(out, "units", unit["key"] + ".json")


def load_done(out, unit):
    """The stored result of a unit, or None."""
    try:
        with open(_unit_file(out, unit), encoding="utf-8") as f:
            r = json.load(f)
    except (OSError, json.JSONDecodeError):
        return None
    return r if r.get("key") == unit["key"] and r.get("status") == "ok" else None


def _params_text(params):
    def v(x):
        return ":".join(repr(c) for c in x) if isinstance(x, list) else repr(x)
    return ",".join(f"{k}={v(x)}" for k, x in params.items())


ALONG_FIRST = ("E", "E_avg", "ms_norm", "F_ms")


def gather_table(slices):
    """Joins slice results (in slice order) along the first parameter axis."""
    first = slices[0]
    out = dict(first)
    f0 = [a["name"] for a in first["axes"]].index("f0") if any(a["name"] == "f0" for a in first["axes"]) else -1
    along = list(ALONG_FIRST) + (["F_avg"] if f0 == 0 else []) + (["E1", "E1_avg"] if f0 == 1 else [])
    for k in along:
        if k in first:
            out[k] = [x for s in slices for x in s[k]]
    axes = [dict(a) for a in first["axes"]]
    axes[0]["nodes"] = [x for s in slices for x in s["axes"][0]["nodes"]]
    out["axes"] = axes
    out["max_error"] = max(s["max_error"] for s in slices)
    out["limit_error"] = max(s["limit_error"] for s in slices)
    out["seconds"] = sum(s["seconds"] for s in slices)
    return out


def gather(job, units, out, wall, workers, failed):
    records, tables = [], []
    by_table = {}
    for u in units:
        r = load_done(out, u)
        if r is None:
            continue
        if u["kind"] == "fit":
            f = r["result"]
            records.append({"material": u["material"], "model": u["model"], "metric": u["metric"],
                            "data": u["data"], "key": u["key"], "params": f["params"], "stddev": f["stddev"],
                            "cost": f["cost"], "rmse": f["rmse"], "chi2_reduced": f["chi2_reduced"],
                            "converged": f["converged"], "seconds": f["seconds"],
                            "wall_seconds": r["wall_seconds"], "worker": r["worker"], "result": f})
        else:
            by_table.setdefault(u["table"], []).append((u["slice"][0], r["result"]))
    os.makedirs(os.path.join(out, "tables"), exist_ok=True)
    for t in job.get("albedo", []):
        parts = sorted(by_table.get(t["name"], []), key=lambda p: p[0])
        if len(parts) != t.get("slices", t["_n1"]):
            continue
        table = gather_table([p[1] for p in parts])
        path = os.path.join(out, "tables", t["name"] + ".json")
        write_atomic(path, json.dumps(table) + "\n")
        tables.append({"name": t["name"], "model": table["model"], "file": path, "slices": len(parts),
                       "entries": len(table["E"]), "max_error": table["max_error"], "seconds": table["seconds"]})
    summary = {"job": job["_path"], "units": len(units), "fits": records, "tables": tables, "failed": failed,
               "wall_seconds": wall, "workers": workers, "complete": not failed and len(records) + sum(
                   t["slices"] for t in tables) == len(units)}
    wanted = job.get("outputs", ["json", "csv", "report"])
    if "json" in wanted:
        write_atomic(os.path.join(out, "results.json"), json.dumps(summary, indent=1) + "\n")
    if "csv" in wanted:
        s = io.StringIO()
        w = csv.writer(s, lineterminator="\n")
        w.writerow(["material", "model", "metric", "params", "stddev", "cost", "rmse", "chi2_reduced", "converged",
                    "seconds", "wall_seconds", "data", "key"])
        for r in records:
            w.writerow([r["material"], r["model"], r["metric"], _params_text(r["params"]),
                        _params_text(r["stddev"]), repr(r["cost"]), repr(r["rmse"]),
                        "" if r["chi2_reduced"] is None else repr(r["chi2_reduced"]), r["converged"],
                        repr(r["seconds"]), repr(r["wall_seconds"]), r["data"], r["key"]])
        write_atomic(os.path.join(out, "results.csv"), s.getvalue())
    if "report" in wanted:
        write_atomic(os.path.join(out, "report.html"), report_html(summary))
    return summary


def report_html(summary):
    e = html.escape
    rows = "".join(
        f"<tr><td>{e(r['material'])}</td><td>{e(r['model'])}</td><td>{e(r['metric'])}</td>"
        f"<td>{r['rmse']:.4g}</td><td>{r['cost']:.4g}</td><td>{'yes' if r['converged'] else 'NO'}</td>"
        f"<td>{r['wall_seconds']:.2f}</td><td class=p>{e(_params_text(r['params']))}</td></tr>"
        for r in sorted(summary["fits"], key=lambda r: (r["material"], r["metric"], r["rmse"])))
    tables = "".join(
        f"<tr><td>{e(t['name'])}</td><td>{e(t['model'])}</td><td>{t['entries']}</td><td>{t['slices']}</td>"
        f"<td>{t['max_error']:.2g}</td><td>{t['seconds']:.1f}</td><td>{e(t['file'])}</td></tr>"
        for t in summary["tables"])
    failed = "".join(f"<li>{e(f['unit'])}: {e(f['error'])}</li>" for f in summary["failed"])
    return f"""<!DOCTYPE html>
<html lang="en"><head><meta charset="utf-8"><title>brdfkit batch</title>
<style>body{{font-family:sans-serif;margin:2em}}table{{border-collapse:collapse}}
td,th{{border:1px solid #ccc;padding:2px 6px;text-align:left}}td.p{{font-family:monospace;font-size:smaller}}</style>
</head><body><h1>brdfkit batch</h1>
<p>{e(summary['job'])}: {summary['units']} units on {summary['workers']} workers in {summary['wall_seconds']:.1f} s;
{len(summary['fits'])} fits, {len(summary['tables'])} tables, {len(summary['failed'])} failed.</p>
<h2>Fits</h2><p>Sorted by material, metric and rmse (best model first).</p>
<table><tr><th>material</th><th>model</th><th>metric</th><th>rmse</th><th>cost</th><th>converged</th>
<th>wall s</th><th>parameters</th></tr>{rows}</table>
<h2>Albedo tables</h2><table><tr><th>name</th><th>model</th><th>entries</th><th>slices</th><th>max error</th>
<th>seconds</th><th>file</th></tr>{tables}</table>
{'<h2>Failed units</h2><ul>' + failed + '</ul>' if failed else ''}
</body></html>
"""


# --- running -----------------------------------------------------------------

def _describe(u):
    if u["kind"] == "fit":
        return f"fit {u['material']} {u['model']} {u['metric']}"
    return f"albedo {u['table']} slice {u['slice'][0]}:{u['slice'][1]}"


def run(job, exe, out, scheduler=None, workers=None, ship_data=False, log=print):
    """Runs the job's units not yet done; returns the gathered summary."""
    version = brdfkit_version(exe)
    units = plan(job, version)
    os.makedirs(os.path.join(out, "units"), exist_ok=True)
    _remove_stale_temporaries(os.path.join(out, "units"))
    todo = [u for u in units if load_done(out, u) is None]
    log(f"{len(units)} units, {len(units) - len(todo)} done before, {len(todo)} to run")
    start = time.monotonic()
    failed = []
    import dask
    import distributed
    import cloudpickle
    cloudpickle.register_pickle_by_value(sys.modules[__name__])  # workers need no brdfkit Python package
    cluster = None
    if scheduler is None:
        # Forked workers start from this interpreter's imports: seconds, not a fresh import each.
        dask.config.set({"distributed.worker.multiprocessing-method": "fork"})
        cluster = distributed.LocalCluster(n_workers=workers or os.cpu_count(), threads_per_worker=1,
                                           processes=True, host="127.0.0.1", dashboard_address=None)
    client = distributed.Client(cluster if cluster is not None else scheduler)
    try:
        n_workers = len(client.scheduler_info()["workers"])
        shipped = {}
        futures = {}
        for u in todo:
            data = None
            if ship_data and u["kind"] == "fit":
                if u["data_sha256"] not in shipped:
                    with open(u["data"], "rb") as f:
                        shipped[u["data_sha256"]] = client.scatter(f.read())
                data = shipped[u["data_sha256"]]
            fut = client.submit(run_unit, u, exe, version, data, key=f"brdfkit-unit-{u['key']}", pure=False,
                                retries=2)
            futures[fut] = u
        done = 0
        for fut in distributed.as_completed(futures):
            u = futures[fut]
            try:
                r = fut.result()
            except Exception as e:  # a unit whose workers kept dying (KilledWorker), or lost data
                r = {"status": "failed", "error": f"{type(e).__name__}: {e}", "worker": None}
            done += 1
            if r["status"] == "ok":
                write_atomic(_unit_file(out, u), json.dumps({"key": u["key"], "unit": u, **r}) + "\n")
                log(f"[{done}/{len(todo)}] {_describe(u)}: {r['wall_seconds']:.2f} s on {r['worker']}")
            else:
                failed.append({"unit": _describe(u), "key": u["key"], "error": r["error"], "worker": r["worker"]})
                log(f"[{done}/{len(todo)}] {_describe(u)}: FAILED: {r['error']}")
            fut.release()
    finally:
        client.close()
        if cluster is not None:
            cluster.close()
    return gather(job, units, out, time.monotonic() - start, n_workers, failed)


def main(argv=None):
    ap = argparse.ArgumentParser(prog="python3 -m brdfkit.batch", description=__doc__.split("\n\n")[0])
    ap.add_argument("job", help="job file (JSON, brdfkit/batch.schema.json)")
    ap.add_argument("--scheduler", help="tcp://HOST:PORT of a running dask scheduler (default: a local cluster)")
    ap.add_argument("--workers", type=int, help="worker processes of the local cluster (default: one per core)")
    ap.add_argument("--out", help="output folder (default: the job's \"output\", or batch-out)")
    ap.add_argument("--brdfkit", help="the brdfkit executable (default: $BRDFKIT_EXE, else brdfkit on PATH)")
    ap.add_argument("--ship-data", action="store_true",
                    help="send data files to the workers through Dask (workers without the job's file system)")
    ap.add_argument("--dry-run", action="store_true", help="check the job and list its units; run nothing")
    ap.add_argument("--quiet", action="store_true", help="no progress lines on stderr")
    a = ap.parse_args(argv)
    log = (lambda *x: None) if a.quiet else (lambda m: print(m, file=sys.stderr, flush=True))
    try:
        if a.workers is not None and a.workers < 1:
            raise BatchError("--workers must be at least 1")
        exe = find_brdfkit(a.brdfkit)
        job = load_job(a.job, exe)
        out = a.out or job.get("output", "batch-out")
        if a.dry_run:
            units = plan(job, brdfkit_version(exe))
            for u in units:
                state = "done" if load_done(out, u) else "run "
                print(f"{state} {u['key']} {_describe(u)}")
            return 0
        signal.signal(signal.SIGTERM, signal.default_int_handler)
        summary = run(job, exe, out, a.scheduler, a.workers, a.ship_data, log)
    except (JobError, BatchError) as e:
        print(f"brdfkit.batch: error: {e}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("brdfkit.batch: stopped; finished units are kept, run again to resume", file=sys.stderr)
        return 130
    log(f"{len(summary['fits'])} fits, {len(summary['tables'])} tables, {len(summary['failed'])} failed, "
        f"{summary['wall_seconds']:.1f} s; results in {out}")
    return 0 if summary["complete"] else 1


if __name__ == "__main__":
    import brdfkit.batch as _batch  # the module under its own name, so that workers unpickle one copy
    sys.exit(_batch.main())
