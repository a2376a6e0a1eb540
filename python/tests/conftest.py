"""Shared helpers: the command-line tool the results are compared with."""
import json
import os
import subprocess

import numpy as np
import pytest

EXE = os.environ.get("BRDFKIT_EXE", "brdfkit")


def cli(*args, check=True):
    """Runs the tool; returns (returncode, stdout, stderr)."""
    p = subprocess.run([EXE, *map(str, args)], capture_output=True, text=True)
    if check and p.returncode != 0:
        raise AssertionError(f"brdfkit {' '.join(map(str, args))} failed: {p.stderr}")
    return p.returncode, p.stdout, p.stderr


def cli_json(*args):
    return json.loads(cli(*args)[1])


def cli_error(*args):
    """The message of a failing command (after 'brdfkit: error: ')."""
    rc, _, err = cli(*args, check=False)
    assert rc != 0, f"brdfkit {' '.join(map(str, args))} did not fail"
    line = [l for l in err.splitlines() if "error" in l][0]
    return line.split("error: ", 1)[1]


def unit_rows(n, seed=1, min_z=0.05):
    """n random unit directions in the upper hemisphere."""
    rng = np.random.default_rng(seed)
    z = min_z + (1 - min_z) * rng.random(n)
    phi = 2 * np.pi * rng.random(n)
    s = np.sqrt(1 - z * z)
    return np.stack([s * np.cos(phi), s * np.sin(phi), z], axis=1)


def without_times(d):
    """A result without its wall-clock fields (they differ between runs)."""
    if isinstance(d, dict):
        return {k: without_times(v) for k, v in d.items() if k not in ("seconds", "sweep_seconds")}
    if isinstance(d, list):
        return [without_times(v) for v in d]
    return d


@pytest.fixture
def tmp(tmp_path):
    return tmp_path
