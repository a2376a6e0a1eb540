"""examples/python/fit_merl.py on a MERL file written from a known model."""
import json
import os
import subprocess
import sys

import numpy as np

import brdfkit

EXAMPLE = os.path.join(os.path.dirname(__file__), "..", "..", "examples", "python", "fit_merl.py")


def test_fit_merl_example(tmp_path):
    truth = brdfkit.Model("lambert+ggx", {"lambert.albedo": (0.1, 0.2, 0.3), "ggx.alpha": 0.2, "ggx.f0": 0.5})
    brdfkit.write(tmp_path / "plastic.binary", truth)
    figure = tmp_path / "slices.png"
    p = subprocess.run([sys.executable, EXAMPLE, str(tmp_path / "plastic.binary"), str(figure), "--samples", "4000"],
                       capture_output=True, text=True, env=dict(os.environ, MPLBACKEND="Agg"))
    assert p.returncode == 0, p.stderr
    out = json.loads(p.stdout)
    # MERL cells hold the model at their centres: the fit finds it again.
    np.testing.assert_allclose(out["params"]["ggx.alpha"], 0.2, rtol=1e-3)
    np.testing.assert_allclose(out["params"]["lambert.albedo"], [0.1, 0.2, 0.3], rtol=1e-3)
    assert figure.stat().st_size > 10000
    assert figure.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
