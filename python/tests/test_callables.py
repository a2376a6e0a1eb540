"""Models defined in Python (PythonModel) and tabulated functions (Tabulated)
in check, albedo_table, synth and fit, against the built-in models."""
import _thread
import pathlib
import threading
import time

import numpy as np
import pytest

import brdfkit
from conftest import unit_rows


def above(wi, wo):
    return (wi[:, 2] > 0) & (wo[:, 2] > 0)


def lambert(wi, wo, p):
    f = np.zeros((len(wi), 3))
    f[above(wi, wo)] = p["albedo"] / np.pi
    return f


def ggx_scalar(wi, wo, alpha, f0):
    """GGX with height-correlated Smith G2 and Schlick Fresnel (Walter 2007, Heitz 2014)."""
    ok = above(wi, wo)
    h = wi + wo
    h /= np.linalg.norm(h, axis=1, keepdims=True)
    a2 = alpha * alpha
    c2 = h[:, 2] ** 2
    d = a2 / (np.pi * (c2 * (a2 - 1) + 1) ** 2)

    def lam(w):
        z2 = np.clip(w[:, 2] ** 2, 1e-300, None)
        return 0.5 * (np.sqrt(1 + a2 * (1 - z2) / z2) - 1)

    g2 = 1 / (1 + lam(wi) + lam(wo))
    fr = f0 + (1 - f0) * (1 - np.sum(wi * h, axis=1)) ** 5
    with np.errstate(divide="ignore", invalid="ignore"):
        v = np.where(ok, fr * d * g2 / (4 * wi[:, 2] * wo[:, 2]), 0.0)
    return np.repeat(v[:, None], 3, axis=1)


def ggx(wi, wo, p):
    return ggx_scalar(wi, wo, p["alpha"], p["f0"])


def lambert_ggx(wi, wo, p):
    return lambert(wi, wo, p) + ggx(wi, wo, p)


ALBEDO = {"albedo": {"default": 0.5, "lower": 0.0, "upper": 1.0}}
ALPHA_F0 = {"alpha": {"default": 0.2, "lower": 1e-3, "upper": 1.0, "scale": "log"},
            "f0": {"default": 0.04, "lower": 0.0, "upper": 1.0}}
PY_LAMBERT = brdfkit.PythonModel(lambert, ALBEDO, kind="diffuse", name="py_lambert")
PY_GGX = brdfkit.PythonModel(ggx, ALPHA_F0, kind="glossy", width=lambda p: p["alpha"], name="py_ggx")


def cosine_sample(wo, u, p):
    r, phi = np.sqrt(u[:, 0]), 2 * np.pi * u[:, 1]
    wi = np.stack([r * np.cos(phi), r * np.sin(phi), np.sqrt(1 - u[:, 0])], axis=1)
    return wi, wi[:, 2] / np.pi


def cosine_pdf(wo, wi, p):
    return np.where(above(wi, wo), wi[:, 2] / np.pi, 0.0)


def test_numpy_models_equal_the_builtin_ones():
    wi, wo = unit_rows(500, seed=1), unit_rows(500, seed=2)
    ref = brdfkit.Model("ggx", {"alpha": 0.3, "f0": 0.5}).eval(wi, wo)
    np.testing.assert_allclose(ggx_scalar(wi, wo, 0.3, 0.5), ref, rtol=1e-12)
    ref = brdfkit.Model("lambert", {"albedo": 0.7}).eval(wi, wo)
    np.testing.assert_allclose(lambert(wi, wo, {"albedo": 0.7}), ref, rtol=1e-15)


def test_check_of_a_python_model_equals_the_builtin_check():
    py = brdfkit.check(PY_LAMBERT, {"albedo": 0.8}, random_pairs=300, threads=1)
    ref = brdfkit.check("lambert", {"albedo": 0.8}, sampling=False, random_pairs=300, threads=1)
    assert py["model"] == "py_lambert" and py["params"] == "albedo=0.8"
    assert py["plausible"] == ref["plausible"] is True
    # The same adaptive albedo rule on the same function: equal within its error estimate.
    assert abs(py["albedo_max"] - ref["albedo_max"]) < 1e-6
    assert py["reciprocity_max_rel_error"] == 0
    # No sample/pdf given: the sampling tests are skipped, and the result says so.
    assert py["sampling_checked"] is False
    assert "no Sample/Pdf" in py["sampling_note"]
    assert py["pdf_integral"] is None and py["chi2_p_value"] is None


def test_sampling_checks_run_when_sampling_is_given():
    good = brdfkit.PythonModel(lambert, ALBEDO, sample=cosine_sample, pdf=cosine_pdf, kind="diffuse")
    r = brdfkit.check(good, {"albedo": 0.8}, samples=5000, random_pairs=200, threads=1)
    assert r["sampling_checked"] is True and r["plausible"] is True
    assert abs(r["pdf_integral"] - 1) < 1e-3
    assert abs(r["albedo_max"] - 0.8) < 1e-6
    # A pdf twice the density of the samples fails the checks it now runs.
    bad = brdfkit.PythonModel(lambert, ALBEDO, sample=cosine_sample, pdf=lambda wo, wi, p: 2 * cosine_pdf(wo, wi, p),
                              kind="diffuse")
    r = brdfkit.check(bad, samples=5000, random_pairs=200, threads=1)
    assert r["sampling_checked"] is True and r["plausible"] is False
    assert abs(r["pdf_integral"] - 2) < 2e-3
    with pytest.raises(ValueError, match="give both sample and pdf"):
        brdfkit.PythonModel(lambert, ALBEDO, sample=cosine_sample)


def test_albedo_table_of_a_python_model_equals_the_builtin_table():
    axes = "mu:4,albedo:3:0.2:0.8"
    py = brdfkit.albedo_table(PY_LAMBERT, axes=axes, tolerance=1e-6, threads=1)
    ref = brdfkit.albedo_table("lambert", axes=axes, tolerance=1e-6, threads=1)
    assert py["model"] == "py_lambert"
    np.testing.assert_array_equal(py["mu"], ref["mu"])
    np.testing.assert_array_equal(py["axes"][0]["nodes"], ref["axes"][0]["nodes"])
    np.testing.assert_allclose(py["E"], ref["E"], atol=2e-6)
    np.testing.assert_allclose(py["E_avg"], ref["E_avg"], atol=2e-6)
    # E = albedo for every mu.
    np.testing.assert_allclose(py["E"].reshape(3, 4), np.repeat(py["axes"][0]["nodes"][:, None], 4, axis=1), atol=2e-6)


def test_albedo_of_a_glossy_python_model_is_batched_and_equals_the_builtin_table():
    seen = []

    def counted(wi, wo, p):
        seen.append(len(wi))
        return ggx(wi, wo, p)

    model = brdfkit.PythonModel(counted, ALPHA_F0, kind="glossy", width=lambda p: p["alpha"], name="counted_ggx")
    axes = "mu:5,alpha:3:0.1:0.6"
    py = brdfkit.albedo_table(model, {"f0": 1.0}, axes=axes, tolerance=1e-6, threads=1)
    ref = brdfkit.albedo_table("ggx", {"f0": 1.0}, axes=axes, tolerance=1e-6, threads=1)
    np.testing.assert_allclose(py["E"], ref["E"], atol=2e-6)
    np.testing.assert_allclose(py["E_avg"], ref["E_avg"], atol=2e-6)
    # Each Gauss-Kronrod rule (15 nodes; a first pass several rules) in one call.
    assert len(seen) > 0 and sum(seen) / len(seen) >= 15
    # check's reciprocity pairs in two calls of as many rows as pairs.
    seen.clear()
    r = brdfkit.check(model, {"alpha": 0.3, "f0": 1.0}, sampling=False, random_pairs=300, threads=1)
    assert r["reciprocity_max_rel_error"] < 1e-12
    assert seen.count(r["reciprocity_pairs"]) == 2


def test_synth_of_a_python_model_equals_the_builtin_synth():
    model = brdfkit.PythonModel(lambert_ggx, {**ALBEDO, **ALPHA_F0}, kind="diffuse+glossy",
                                width=lambda p: p["alpha"])
    params = {"albedo": 0.4, "alpha": 0.3, "f0": 0.2}
    py = brdfkit.synth(model, params, seed=3)
    ref = brdfkit.synth("lambert+ggx", {"lambert.albedo": 0.4, "ggx.alpha": 0.3, "ggx.f0": 0.2}, seed=3)
    np.testing.assert_array_equal(py["valid"], ref["valid"])
    np.testing.assert_allclose(py["f"], ref["f"], rtol=1e-9)
    assert py["model"] == "python"


def test_fit_of_a_python_model_recovers_the_parameters():
    truth = brdfkit.Model("lambert+ggx", {"lambert.albedo": 0.4, "ggx.alpha": 0.15, "ggx.f0": 0.6})
    wi, wo = unit_rows(2000, seed=11, min_z=0.1), unit_rows(2000, seed=12, min_z=0.1)
    f = truth.eval(wi, wo)
    sizes = []

    def counted(wi, wo, p):
        sizes.append(len(wi))
        return lambert_ggx(wi, wo, p)

    model = brdfkit.PythonModel(counted, {**ALBEDO, **ALPHA_F0}, name="lg")
    r = brdfkit.fit(model, wi, wo, f, threads=1)
    # The function sees whole data sets (values, then central differences),
    # never one pair at a time: a few hundred calls, not hundreds of thousands.
    assert set(sizes) == {2000} and len(sizes) < 1000, (len(sizes), sorted(set(sizes))[:5])
    assert r["model"] == "lg" and r["model_object"] is model
    assert r["converged"] is True
    np.testing.assert_allclose([r["params"][k] for k in ("albedo", "alpha", "f0")], [0.4, 0.15, 0.6], rtol=1e-6)
    assert r["rmse"] < 1e-8
    # The same fit of the built-in model: the same optimum and uncertainties of the same size.
    ref = brdfkit.fit("lambert+ggx", wi, wo, f, threads=1)
    np.testing.assert_allclose(r["params"]["alpha"], ref["params"]["ggx.alpha"], rtol=1e-6)
    # From a starting point and on two threads.
    r2 = brdfkit.fit(model, wi, wo, f, init={"alpha": 0.3, "f0": 0.5, "albedo": 0.5}, threads=2)
    np.testing.assert_allclose(r2["packed_params"], [0.4, 0.15, 0.6], rtol=1e-6)
    assert r2["covariance"].shape == (3, 3)


def test_fit_through_an_instrument_calls_the_function_with_whole_apertures():
    lab = pathlib.Path(__file__).resolve().parents[2] / "examples" / "instruments" / "lab.json"
    truth = brdfkit.Model("lambert+ggx", {"lambert.albedo": 0.4, "ggx.alpha": 0.3, "ggx.f0": 0.6})
    s = brdfkit.synth(truth, instrument=str(lab), seed=3)
    keep = np.arange(0, len(s["wi"]), 8)  # 27 of the plan's pairs
    wi, wo, f = s["wi"][keep], s["wo"][keep], s["f"][keep]
    sizes = []

    def counted(wi, wo, p):
        sizes.append(len(wi))
        return lambert_ggx(wi, wo, p)

    model = brdfkit.PythonModel(counted, {**ALBEDO, **ALPHA_F0}, name="lg")
    r = brdfkit.fit(model, wi, wo, f, instrument=str(lab), threads=1)
    ref = brdfkit.fit("lambert+ggx", wi, wo, f, instrument=str(lab), threads=1)
    # Every call holds an aperture's detector nodes (4 or more), not one pair.
    assert min(sizes) >= 4, sorted(set(sizes))[:5]
    # The truth to the noise of the measurement (measured: 1e-4), and the
    # built-in model's width through the same quadrature (its albedo and f0
    # are colours, fitted per channel).
    np.testing.assert_allclose([r["params"][k] for k in ("albedo", "alpha", "f0")], [0.4, 0.3, 0.6], rtol=1e-3)
    np.testing.assert_allclose(r["params"]["alpha"], ref["params"]["ggx.alpha"], rtol=1e-4)


class Boom(Exception):
    pass


def raising(wi, wo, p):
    raise Boom("inside the model")


def test_exceptions_of_the_function_raise_as_themselves():
    m = brdfkit.PythonModel(raising, ALBEDO)
    wi, wo = unit_rows(50, seed=1), unit_rows(50, seed=2)
    f = np.full((50, 3), 0.1)
    with pytest.raises(Boom, match="inside the model"):
        brdfkit.check(m)
    with pytest.raises(Boom):
        brdfkit.albedo_table(m, axes="mu:3,albedo:2")
    with pytest.raises(Boom):
        brdfkit.synth(m)
    with pytest.raises(Boom):
        brdfkit.fit(m, wi, wo, f)
    # Only after some calls: the tool stops and raises it.
    calls = []

    def later(wi, wo, p):
        calls.append(len(wi))
        if len(calls) > 3:
            raise Boom("late")
        return lambert(wi, wo, p)

    with pytest.raises(Boom, match="late"):
        brdfkit.fit(brdfkit.PythonModel(later, ALBEDO), wi, wo, f)


def test_wrong_results_raise_naming_the_function():
    def flat(wi, wo, p):
        return np.zeros(len(wi))

    def nan(wi, wo, p):
        return np.full((len(wi), 3), np.nan)

    def text(wi, wo, p):
        return np.full((len(wi), 3), "x")

    with pytest.raises(ValueError, match=r"eval function 'test_wrong_results_raise_naming_the_function.<locals>.flat' "
                                         r"of PythonModel 'python' returned shape \(\d+,\) for \d+ directions"):
        brdfkit.check(brdfkit.PythonModel(flat, ALBEDO))
    with pytest.raises(ValueError, match="'.*nan' of PythonModel 'python' returned a non-finite value"):
        brdfkit.synth(brdfkit.PythonModel(nan, ALBEDO))
    with pytest.raises(TypeError, match="text' of PythonModel 'python' returned dtype <U1"):
        brdfkit.fit(brdfkit.PythonModel(text, ALBEDO), unit_rows(10), unit_rows(10, seed=2), np.ones((10, 3)))
    with pytest.raises(ValueError, match="parameter 'alpha': missing 'upper'"):
        brdfkit.PythonModel(ggx, {"alpha": {"default": 0.1, "lower": 0}})
    with pytest.raises(ValueError, match="parameter 'albedo' = 2 is outside"):
        brdfkit.check(PY_LAMBERT, {"albedo": 2})
    with pytest.raises(ValueError, match="kind must be"):
        brdfkit.PythonModel(lambert, kind="shiny")


def test_keyboard_interrupt_in_and_around_the_function():
    def interrupted(wi, wo, p):
        raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        brdfkit.albedo_table(brdfkit.PythonModel(interrupted, ALBEDO), axes="mu:3,albedo:2")

    # Ctrl-C (a simulated SIGINT) while the tool runs Python functions on its threads.
    def slow(wi, wo, p):
        time.sleep(1e-3)
        return ggx(wi, wo, p)

    timer = threading.Timer(0.3, _thread.interrupt_main)
    t0 = time.monotonic()
    timer.start()
    with pytest.raises(KeyboardInterrupt):
        brdfkit.albedo_table(brdfkit.PythonModel(slow, ALPHA_F0, width=0.2), axes="mu:16,alpha:16:0.01:1", threads=2)
    assert time.monotonic() - t0 < 5
    timer.join()


def test_tabulated_function():
    # A Lambertian surface sampled on a grid: every lookup returns albedo / pi.
    wi, wo = unit_rows(400, seed=5), unit_rows(400, seed=6)
    f = np.full((400, 3), 0.6 / np.pi)
    tab = brdfkit.Tabulated(wi, wo, f)
    assert tab.size == 400 and tab.interp == "nearest"
    np.testing.assert_array_equal(tab.eval(unit_rows(10, seed=9), unit_rows(10, seed=10)), np.full((10, 3), 0.6 / np.pi))
    r = brdfkit.check(tab, random_pairs=200, samples=5000)
    assert abs(r["albedo_max"] - 0.6) < 1e-6
    assert r["sampling_checked"] is True  # cosine-weighted sampling
    # Exact at its own samples; idw between them.
    g = brdfkit.Model("ggx", {"alpha": 0.5}).eval(wi, wo)
    tab = brdfkit.Tabulated(wi, wo, g, interp="idw")
    np.testing.assert_allclose(tab.eval(wi, wo), g, rtol=1e-12)
    s = brdfkit.synth(brdfkit.Tabulated(wi, wo, f))
    np.testing.assert_allclose(s["f"][s["valid"]], 0.6 / np.pi, rtol=1e-12)
    with pytest.raises(ValueError, match="no parameters to fit"):
        brdfkit.fit(tab, wi, wo, g)
    with pytest.raises(ValueError, match="same N"):
        brdfkit.Tabulated(wi, wo[:5], f)


def python_thread_states():
    """The number of Python thread states of this interpreter."""
    import ctypes
    api = ctypes.pythonapi
    api.PyInterpreterState_Get.restype = ctypes.c_void_p
    api.PyInterpreterState_ThreadHead.restype = ctypes.c_void_p
    api.PyInterpreterState_ThreadHead.argtypes = [ctypes.c_void_p]
    api.PyThreadState_Next.restype = ctypes.c_void_p
    api.PyThreadState_Next.argtypes = [ctypes.c_void_p]
    n, ts = 0, api.PyInterpreterState_ThreadHead(api.PyInterpreterState_Get())
    while ts:
        n, ts = n + 1, api.PyThreadState_Next(ts)
    return n


def test_tool_calls_leave_no_python_thread_states_behind():
    # Each call runs on a worker thread of its own, which calls the function:
    # its Python state must go with it.
    for _ in range(3):
        brdfkit.check(PY_LAMBERT, random_pairs=20, threads=2)
    before = python_thread_states()
    for _ in range(20):
        brdfkit.check(PY_LAMBERT, random_pairs=20, threads=2)
    assert python_thread_states() - before < 3
