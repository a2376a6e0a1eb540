"""Model objects on numpy arrays against the command line and closed forms."""
import threading

import numpy as np
import pytest

import brdfkit
from conftest import cli, cli_error, cli_json, unit_rows


def test_models_match_the_cli_registry():
    assert brdfkit.models() == cli_json("models", "--json")


@pytest.mark.parametrize("spec,params", [
    ("lambert", "albedo=0.3:0.5:0.7"),
    ("ggx", "alpha=0.2,f0=0.04"),
    ("lambert+ggx", "lambert.albedo=0.5,ggx.alpha=0.05"),
    ("oren_nayar_fujii", ""),
    ("ward", ""),
])
def test_eval_equals_cli(spec, params):
    m = brdfkit.Model(spec, params)
    wi = np.array([[0.0, 0.0, 1.0], [0.6, 0.0, 0.8], [0.0, -0.28, 0.96], [-0.352, 0.936, 0.0]])
    wo = np.array([[0.0, 0.8, 0.6], [-0.6, 0.0, 0.8], [0.0, 0.28, 0.96], [0.48, 0.0, 0.877496438739212]])
    wi /= np.linalg.norm(wi, axis=1)[:, None]
    wo /= np.linalg.norm(wo, axis=1)[:, None]
    f = m.eval(wi, wo)
    assert f.shape == (4, 3) and f.dtype == np.float64
    for k in range(4):
        args = ["eval", "--model", spec, "--wi", ",".join(repr(float(x)) for x in wi[k]),
                "--wo", ",".join(repr(float(x)) for x in wo[k]), "--json"]
        if params:
            args += ["--params", params]
        ref = np.array(cli_json(*args)["f"])
        np.testing.assert_allclose(f[k], ref, rtol=1e-15, atol=0)


def test_params_as_dict_and_string_agree():
    a = brdfkit.Model("lambert+ggx", {"lambert.albedo": (0.2, 0.3, 0.4), "ggx.alpha": 0.1})
    b = brdfkit.Model("lambert+ggx", "lambert.albedo=0.2:0.3:0.4,ggx.alpha=0.1")
    assert a.params == b.params
    assert a.params["ggx.alpha"] == 0.1
    assert a.packed_names[:3] == ["lambert.albedo.r", "lambert.albedo.g", "lambert.albedo.b"]


def test_broadcasting_dtype_and_layouts():
    m = brdfkit.Model("ggx", {"alpha": 0.3, "f0": 0.5})
    wi = unit_rows(64, seed=2)
    wo = unit_rows(64, seed=3)
    full = m.eval(wi, wo)
    # One direction for every row, either side.
    one = m.eval(wi, wo[5])
    np.testing.assert_array_equal(one, m.eval(wi, np.repeat(wo[5:6], 64, axis=0)))
    np.testing.assert_array_equal(m.eval(wi[5], wo), m.eval(np.repeat(wi[5:6], 64, axis=0), wo))
    assert m.eval(wi[0], wo[0]).shape == (3,)
    np.testing.assert_array_equal(m.eval(wi[0], wo[0]), full[0])
    # Non-contiguous, Fortran-ordered, read-only and list inputs.
    big = np.zeros((128, 3))
    big[::2] = wi
    np.testing.assert_array_equal(m.eval(big[::2], wo), full)
    np.testing.assert_array_equal(m.eval(np.asfortranarray(wi), wo), full)
    ro = wi.copy()
    ro.setflags(write=False)
    np.testing.assert_array_equal(m.eval(ro, wo), full)
    np.testing.assert_array_equal(m.eval(wi.tolist(), wo), full)
    # float32 in, float32 out, computed in single precision.
    f32 = m.eval(wi.astype(np.float32), wo.astype(np.float32))
    assert f32.dtype == np.float32
    np.testing.assert_allclose(f32, full, rtol=2e-4)
    # Mixed precision runs in double.
    assert m.eval(wi.astype(np.float32), wo).dtype == np.float64


def test_sample_and_pdf_agree():
    m = brdfkit.Model("ggx", {"alpha": 0.3})
    wo = unit_rows(500, seed=4)
    u = np.random.default_rng(5).random((500, 2))
    wi, pdf, valid = m.sample(wo, u)
    assert wi.shape == (500, 3) and pdf.shape == (500,) and valid.dtype == bool
    assert valid.mean() > 0.8
    np.testing.assert_allclose(np.linalg.norm(wi[valid], axis=1), 1, rtol=1e-12)
    np.testing.assert_allclose(m.pdf(wo[valid], wi[valid]), pdf[valid], rtol=1e-12)
    assert np.all(pdf[~valid] == 0)


def test_albedo_closed_forms():
    # Lambert rho / pi: E = rho. GGX alpha = 1, F = 1, height-correlated Smith:
    # E(mu) = 1 - mu ln(1 + 1/mu) (REFERENCE.md).
    mu = np.array([1.0, 0.7, 0.3, 0.05])
    wo = np.stack([np.sqrt(1 - mu * mu), np.zeros(4), mu], axis=1)
    e = brdfkit.Model("lambert", {"albedo": (0.2, 0.5, 0.9)}).albedo(wo)
    np.testing.assert_allclose(e, np.tile([0.2, 0.5, 0.9], (4, 1)), atol=1e-6)
    e = brdfkit.Model("ggx", {"alpha": 1.0}).albedo(wo, tolerance=1e-8)
    np.testing.assert_allclose(e[:, 1], 1 - mu * np.log1p(1 / mu), atol=1e-7)


def test_errors_carry_the_cli_messages():
    with pytest.raises(ValueError) as e:
        brdfkit.Model("nosuch")
    assert str(e.value) == cli_error("eval", "--model", "nosuch", "--wi", "0,0,1", "--wo", "0,0,1")
    with pytest.raises(ValueError) as e:
        brdfkit.Model("ggx", {"alpha": 2.0})
    assert str(e.value) == cli_error("eval", "--model", "ggx", "--params", "alpha=2", "--wi", "0,0,1", "--wo", "0,0,1")
    assert "outside its range" in str(e.value)
    with pytest.raises(ValueError, match="unknown parameter 'beta'"):
        brdfkit.Model("ggx", {"beta": 1})
    with pytest.raises(ValueError, match="not a finite number"):
        brdfkit.Model("ggx", {"alpha": float("nan")})
    m = brdfkit.Model("lambert")
    z = np.array([0.0, 0.0, 1.0])
    with pytest.raises(ValueError, match=r"wi must have shape \(N, 3\) or \(3,\), got \(4, 2\)"):
        m.eval(np.zeros((4, 2)), z)
    with pytest.raises(ValueError, match="wi has 3 rows and wo has 2"):
        m.eval(unit_rows(3), unit_rows(2))
    with pytest.raises(ValueError, match="wo row 1 is not finite"):
        m.eval(z, np.array([[0, 0, 1.0], [np.nan, 0, 1]]))
    with pytest.raises(ValueError, match="not a unit vector"):
        m.eval(z, np.array([0.0, 0.0, 2.0]))
    with pytest.raises(TypeError, match="real numbers"):
        m.eval(np.array(["a", "b", "c"]), z)
    with pytest.raises(TypeError, match="real numbers"):
        m.eval(np.array([1j, 0, 0]), z)
    with pytest.raises(ValueError, match=r"u must lie in \[0, 1\)"):
        m.sample(z, np.array([0.5, 1.0]))
    with pytest.raises(ValueError, match="tolerance"):
        m.albedo(z, tolerance=0)
    with pytest.raises(TypeError):
        brdfkit.Model("ggx", 3)


def test_eval_checks_rows_of_every_chunk_in_order():
    # eval checks the rows chunk by chunk as it evaluates; a bad row anywhere
    # raises the message of a check of all of wi, then all of wo.
    m = brdfkit.Model("ggx")
    wi, wo = unit_rows(10000, seed=4), unit_rows(10000, seed=5)
    bad_wo = wo.copy()
    bad_wo[7000] = [0.0, 0.0, 2.0]
    with pytest.raises(ValueError, match="wo row 7000 is not a unit vector"):
        m.eval(wi, bad_wo)
    bad_wi = wi.copy()
    bad_wi[9999, 1] = np.inf
    with pytest.raises(ValueError, match="wi row 9999 is not finite"):
        m.eval(bad_wi, wo)
    with pytest.raises(ValueError, match="wi row 9999 is not finite"):
        m.eval(bad_wi.astype(np.float32), wo.astype(np.float32))
    bad_wo[100] = [0.0, np.nan, 1.0]  # a bad wo row in an earlier chunk than wi's
    with pytest.raises(ValueError, match="wi row 9999 is not finite"):
        m.eval(bad_wi, bad_wo)
    with pytest.raises(ValueError, match="wo row 100 is not finite"):
        m.eval(wi[0], bad_wo)
    # The values before a wrong shape of wo or a different row count.
    with pytest.raises(ValueError, match="wi row 9999 is not finite"):
        m.eval(bad_wi, np.zeros((4, 2)))
    with pytest.raises(ValueError, match="wi row 9999 is not finite"):
        m.eval(bad_wi, wo[:5])
    with pytest.raises(ValueError, match="wo row 100 is not finite"):
        m.eval(wi[:5], bad_wo)
    # Zero rows: an empty result.
    assert m.eval(np.zeros((0, 3)), wo[0]).shape == (0, 3)


def test_models_from_several_threads():
    # One shared model, eight Python threads: each result equals the serial one.
    m = brdfkit.Model("lambert+ggx", {"ggx.alpha": 0.1})
    inputs = [(unit_rows(20000, seed=10 + k), unit_rows(20000, seed=30 + k)) for k in range(8)]
    serial = [m.eval(a, b) for a, b in inputs]
    results = [None] * 8
    start = threading.Barrier(8)

    def work(k):
        start.wait()
        for _ in range(5):
            results[k] = m.eval(*inputs[k])
            m.pdf(inputs[k][1], inputs[k][0])

    threads = [threading.Thread(target=work, args=(k,)) for k in range(8)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    for k in range(8):
        np.testing.assert_array_equal(results[k], serial[k])
