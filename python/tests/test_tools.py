"""check, albedo_table, synth, fit, stress and files against the command line."""
import _thread
import threading
import time

import numpy as np
import pytest

import brdfkit
from conftest import cli, cli_error, cli_json, unit_rows, without_times


def test_check_equals_cli():
    py = brdfkit.check("ggx", {"alpha": 0.3}, samples=20000)
    ref = cli_json("check", "--model", "ggx", "--params", "alpha=0.3", "--samples", 20000, "--json")
    assert without_times(py) == without_times(ref)
    assert py["plausible"] is True and py["sampling_checked"] is True


def test_check_without_sampling_says_so():
    r = brdfkit.check(brdfkit.Model("lambert"), sampling=False)
    assert r["sampling_checked"] is False
    assert r["pdf_integral"] is None and r["chi2_p_value"] is None


def test_check_albedo_budget_reaches_the_search(tmp):
    # A MERL table's nearest-bin lookup is a step function: the adaptive
    # rule cannot reach the check's 1e-8 and spends each albedo's budget.
    m = brdfkit.Model("lambert+ggx", {"lambert.albedo": 0.2, "ggx.alpha": 0.3, "ggx.f0": 0.04})
    brdfkit.write(tmp / "m.binary", m)
    model = "merl:" + str(tmp / "m.binary")
    small = brdfkit.check(model, sampling=False, albedo_budget=20000)
    ref = cli_json("check", "--model", model, "--no-sampling", "--albedo-budget", 20000, "--json")
    assert without_times(small) == without_times(ref)
    large = brdfkit.check(model, sampling=False, albedo_budget=200000)
    per_albedo = [r["albedo_integrand_evaluations"] / r["albedo_evaluations"] for r in (small, large)]
    assert per_albedo[0] < 50000 and per_albedo[1] > 150000
    assert large["albedo_max_error"] <= small["albedo_max_error"]
    # The two estimates of the table's largest albedo agree within their bars.
    assert abs(small["albedo_max"] - large["albedo_max"]) <= small["albedo_max_error"] + large["albedo_max_error"]
    with pytest.raises(ValueError, match="albedo_budget"):
        brdfkit.check(model, sampling=False, albedo_budget=10)


def test_albedo_table_equals_cli():
    py = brdfkit.albedo_table("ggx", axes="mu:5,alpha:3:0.1:1", tolerance=1e-5)
    ref = cli_json("albedo", "--model", "ggx", "--axes", "mu:5,alpha:3:0.1:1", "--tolerance", 1e-5, "--json")
    assert isinstance(py["E"], np.ndarray) and py["E"].shape == (15,)
    for key in ("mu", "E", "E_avg", "ms_norm"):
        np.testing.assert_array_equal(py[key], np.array(ref[key]))
    assert py["axes"][0]["name"] == "alpha"
    np.testing.assert_array_equal(py["axes"][0]["nodes"], ref["axes"][0]["nodes"])
    # alpha = 1 column against the closed form 1 - mu ln(1 + 1/mu) (mu > 0).
    mu = py["mu"][1:]
    np.testing.assert_allclose(py["E"][10 + 1:], 1 - mu * np.log1p(1 / mu), atol=2e-5)


def test_albedo_table_over_mu_alone_of_a_measured_table(tmp_path):
    # A lambert table read back through ASTM: E(mu) is its albedo, as the
    # command line gives it; the budget is passed on (too small a budget
    # for a lobe leaves entries above the tolerance, a ValueError).
    path = str(tmp_path / "l.astm")
    brdfkit.write(path, brdfkit.Model("lambert", {"albedo": 0.25}))
    py = brdfkit.albedo_table("astm:" + path, axes="mu:4")
    ref = cli_json("albedo", "--model", "astm:" + path, "--axes", "mu:4", "--json")
    assert py["axes"] == [] and py["E"].shape == (4,) and py["E_avg"].shape == (1,)
    np.testing.assert_allclose(py["E"], 0.25, atol=1e-6)
    for key in ("mu", "E", "E_avg", "ms_norm"):
        np.testing.assert_array_equal(py[key], np.array(ref[key]))
    with pytest.raises(ValueError, match=r"Ask for a looser tolerance .*: tolerance=1e-3\)"):
        brdfkit.albedo_table("ggx", {"alpha": 0.001}, axes="mu:3", albedo_budget=1000)
    with pytest.raises(ValueError, match="albedo_budget"):
        brdfkit.albedo_table("ggx", axes="mu:3", albedo_budget=10)
    # A lobe read back through UTIA's 15 degree cells: at the 1e-6 contract
    # the integrals cannot converge and E_avg gives up (refused, no minutes
    # of refinement first); those cells' integrals meet 1e-2.
    g = str(tmp_path / "g.utia")
    brdfkit.write(g, brdfkit.Model("ggx", {"alpha": 0.5}))
    with pytest.raises(ValueError, match="E_avg: error estimate"):
        brdfkit.albedo_table("utia:" + g, axes="mu:3")
    loose = brdfkit.albedo_table("utia:" + g, axes="mu:3", tolerance=1e-2)
    ref = cli_json("albedo", "--model", "utia:" + g, "--axes", "mu:3", "--tolerance", "1e-2", "--json")
    assert loose["max_error"] <= 1e-2
    np.testing.assert_array_equal(loose["E_avg"], np.array(ref["E_avg"]))


def test_albedo_preset_equals_cli_in_the_renderers_layout():
    py = brdfkit.albedo_preset("filament", size=4)
    ref = cli_json("albedo", "--preset", "filament", "--size", 4, "--json")
    dfg = py["tables"]["DFG_LUT"]
    assert dfg["value"].shape == (4, 4, 3)  # row (roughness), texel (NoV), channel
    np.testing.assert_array_equal(dfg["value"].ravel(), np.array(ref["tables"][0]["value"]))
    assert py["max_error"] <= 1e-7
    # Cycles' GGX average at roughness 1 (alpha 1): 4 (1 - ln 2) / 3.
    c = brdfkit.albedo_preset("cycles", tables=["table_ggx_Eavg"])
    assert list(c["tables"]) == ["table_ggx_Eavg"]
    e = c["tables"]["table_ggx_Eavg"]["value"]
    assert e.shape == (32,)
    assert abs(e[31] - 4 * (1 - np.log(2)) / 3) < 1e-7
    # Kulla-Conty: the two sides' Fresnel averages obey ior^2 (1 - F_in) = 1 - F_out.
    k = brdfkit.albedo_preset("kulla_conty", size=4, tables=["kc_Favg", "kc_inv_Favg"])
    z = k["tables"]["kc_Favg"]["axes"][0]["evaluated"]
    ior = (1 + z * z) / (1 - z * z)
    f_out, f_in = k["tables"]["kc_Favg"]["value"], k["tables"]["kc_inv_Favg"]["value"]
    np.testing.assert_allclose(ior[1:] ** 2 * (1 - f_in[1:]), 1 - f_out[1:], rtol=0, atol=1e-12)
    # F_avg outside against the classical closed form of the hemispherical Fresnel average.
    n = ior[1:]
    closed = (0.5 + (n - 1) * (3 * n + 1) / (6 * (n + 1) ** 2)
              + n**2 * (n**2 - 1) ** 2 / (n**2 + 1) ** 3 * np.log((n - 1) / (n + 1))
              - 2 * n**3 * (n**2 + 2 * n - 1) / ((n**2 + 1) * (n**4 - 1))
              + 8 * n**4 * (n**4 + 1) / ((n**2 + 1) * (n**4 - 1) ** 2) * np.log(n))
    np.testing.assert_allclose(f_out[1:], closed, rtol=0, atol=1e-9)


def test_albedo_preset_refuses_bad_arguments():
    with pytest.raises(ValueError, match="unknown table preset 'unreal'"):
        brdfkit.albedo_preset("unreal")
    with pytest.raises(ValueError, match="fixed sizes"):
        brdfkit.albedo_preset("cycles", size=8)
    with pytest.raises(ValueError, match="size 2 is outside"):
        brdfkit.albedo_preset("kulla_conty", size=2)
    with pytest.raises(ValueError, match="has no table 'table_ggx_F'"):
        brdfkit.albedo_preset("cycles", tables=["table_ggx_F"])


def test_synth_writes_what_the_cli_writes(tmp):
    py = brdfkit.synth("lambert+ggx", {"ggx.alpha": 0.2}, seed=7, out=[tmp / "py.csv"])
    cli("synth", "--model", "lambert+ggx", "--params", "ggx.alpha=0.2", "--seed", 7, "--out", tmp / "cli.csv", "-q")
    assert (tmp / "py.csv").read_bytes() == (tmp / "cli.csv").read_bytes()
    assert py["f"].shape == py["wi"].shape == (len(py["valid"]), 3)
    assert "report" in py or "synth" in py or "instrument" in py
    # Noise-free built-in instrument: the measured f is the model's within the aperture blur.
    m = brdfkit.Model("lambert+ggx", {"ggx.alpha": 0.2})
    v = py["valid"]
    np.testing.assert_allclose(py["f"][v], m.eval(py["wi"][v], py["wo"][v]), rtol=0.05)


def test_fit_equals_cli_fit(tmp):
    truth = brdfkit.Model("lambert+ggx", {"lambert.albedo": 0.4, "ggx.alpha": 0.15, "ggx.f0": 0.6})
    wi, wo = unit_rows(3000, seed=11, min_z=0.1), unit_rows(3000, seed=12, min_z=0.1)
    f = truth.eval(wi, wo)
    brdfkit.write(tmp / "data.csv", {"wi": wi, "wo": wo, "f": f})
    py = brdfkit.fit("lambert+ggx", tmp / "data.csv", threads=1)
    ref = cli_json("fit", "--data", tmp / "data.csv", "--model", "lambert+ggx", "--threads", 1, "--json")
    assert py["params"] == ref["params"]
    assert py["stddev"] == ref["stddev"]
    assert py["iterations"] == ref["iterations"] and py["cost"] == ref["cost"]
    assert [t["cost"] for t in py["trace"]] == [t["cost"] for t in ref["trace"]]
    np.testing.assert_allclose(py["params"]["ggx.alpha"], 0.15, rtol=1e-6)
    # Covariance from the correlation and the standard deviations.
    c = py["covariance"]
    n = len(py["packed_names"])
    assert c.shape == (n, n)
    np.testing.assert_allclose(np.sqrt(np.diag(c)), py["packed_stddev"], rtol=1e-12)
    # The same fit from arrays.
    arr = brdfkit.fit("lambert+ggx", wi, wo, f, threads=1)
    np.testing.assert_allclose(arr["packed_params"], py["packed_params"], rtol=1e-6)
    assert isinstance(arr["model_object"], brdfkit.Model)


def test_fit_with_sigma_and_errors(tmp):
    truth = brdfkit.Model("lambert", {"albedo": 0.5})
    wi, wo = unit_rows(200, seed=1), unit_rows(200, seed=2)
    f = truth.eval(wi, wo)
    r = brdfkit.fit("lambert", wi, wo, f, np.full_like(f, 1e-3))
    np.testing.assert_allclose(r["params"]["albedo"], [0.5, 0.5, 0.5], rtol=1e-9)
    with pytest.raises(ValueError, match="sigma row 0 must be positive"):
        brdfkit.fit("lambert", wi, wo, f, np.zeros_like(f))
    with pytest.raises(ValueError, match="same N"):
        brdfkit.fit("lambert", wi, wo[:10], f)
    with pytest.raises(ValueError, match="unknown metric|metric"):
        brdfkit.fit("lambert", wi, wo, f, metric="l3")
    with pytest.raises(ValueError) as e:
        brdfkit.fit("lambert", wi, wo, f, loss="quadratic")
    assert str(e.value) == cli_error("fit", "--data", "x.csv", "--model", "lambert", "--loss", "quadratic")
    with pytest.raises(FileNotFoundError, match="nosuch.csv"):
        brdfkit.fit("lambert", tmp / "nosuch.csv")


def test_fit_fix_tie_bounds_as_the_cli(tmp):
    truth = brdfkit.Model("lambert+ggx+ggx", {"lambert.albedo": 0.3, "ggx.alpha": 0.05, "ggx.f0": (0.9, 0.7, 0.5),
                                              "ggx#2.alpha": 0.35, "ggx#2.f0": (0.9, 0.7, 0.5), "ggx#2.weight": 0.4})
    wi, wo = unit_rows(2000, seed=21, min_z=0.1), unit_rows(2000, seed=22, min_z=0.1)
    f = truth.eval(wi, wo)
    brdfkit.write(tmp / "data.csv", {"wi": wi, "wo": wo, "f": f})
    kw = dict(fix={"ggx.weight": 1, "lambert.albedo": (0.3, 0.3, 0.3)}, tie={"ggx#2.f0": "ggx.f0"},
              bounds={"ggx#2.alpha": (0.2, 0.5)}, threads=1)
    py = brdfkit.fit("lambert+ggx+ggx", tmp / "data.csv", **kw)
    ref = cli_json("fit", "--data", tmp / "data.csv", "--model", "lambert+ggx+ggx", "--threads", 1, "--json",
                   "--fix", "ggx.weight=1,lambert.albedo=0.3:0.3:0.3", "--tie", "ggx#2.f0=ggx.f0",
                   "--bounds", "ggx#2.alpha=0.2:0.5")
    assert py["params"] == ref["params"]
    assert py["fixed"] == ["lambert.albedo", "ggx.weight"] and py["tied"] == {"ggx#2.f0": "ggx.f0"}
    assert py["stddev"]["ggx.weight"] == 0 and py["stddev"]["lambert.albedo"] == [0, 0, 0]
    assert py["stddev"]["ggx#2.f0"] == py["stddev"]["ggx.f0"]
    np.testing.assert_allclose(py["params"]["ggx.f0"], [0.9, 0.7, 0.5], rtol=1e-6)
    np.testing.assert_allclose(py["params"]["ggx#2.alpha"], 0.35, rtol=1e-6)
    assert py["local_optima"] and 0 <= py["kept"] < len(py["local_optima"])
    assert py["local_optima"][py["kept"]]["cost"] == min(o["cost"] for o in py["local_optima"])
    # Text as on the command line works the same.
    text = brdfkit.fit("lambert+ggx+ggx", tmp / "data.csv", fix="ggx.weight=1,lambert.albedo=0.3:0.3:0.3",
                       tie="ggx#2.f0=ggx.f0", bounds="ggx#2.alpha=0.2:0.5", threads=1)
    assert text["params"] == py["params"]
    with pytest.raises(ValueError, match="fix: unknown parameter 'ggx.f00'.*did you mean ggx.f0"):
        brdfkit.fit("lambert+ggx", wi, wo, f, fix={"ggx.f00": 0.04})
    with pytest.raises(ValueError, match="different kinds"):
        brdfkit.fit("lambert+ggx", wi, wo, f, tie={"ggx.alpha": "lambert.albedo"})
    with pytest.raises(ValueError, match=r"bounds: 'ggx.alpha' = \[0.5, 0.1\] is inverted"):
        brdfkit.fit("lambert+ggx", wi, wo, f, bounds={"ggx.alpha": (0.5, 0.1)})
    with pytest.raises(ValueError, match="nothing left to fit"):
        brdfkit.fit("lambert", wi, wo, f, fix={"albedo": 0.2})


def test_fit_random_starts_as_the_cli(tmp):
    truth = brdfkit.Model("lambert+ggx", {"lambert.albedo": (0.2, 0.3, 0.4), "ggx.alpha": 0.12,
                                          "ggx.f0": (0.9, 0.7, 0.5), "ggx.weight": 1})
    wi, wo = unit_rows(800, seed=31, min_z=0.1), unit_rows(800, seed=32, min_z=0.1)
    brdfkit.write(tmp / "data.csv", {"wi": wi, "wo": wo, "f": truth.eval(wi, wo)})
    py = brdfkit.fit("lambert+ggx", tmp / "data.csv", random_starts=5, seed=3, threads=1, covariance=False)
    ref = cli_json("fit", "--data", tmp / "data.csv", "--model", "lambert+ggx", "--threads", 1, "--json",
                   "--no-covariance", "--random-starts", 5, "--seed", 3)
    assert py["params"] == ref["params"] and py["starts"] == 5
    assert {o["origin"] for o in py["local_optima"]} == {"random start"}
    # Noiseless data: the random starts reach the truth's zero cost.
    assert py["cost"] < 1e-20
    np.testing.assert_allclose(py["params"]["ggx.alpha"], 0.12, rtol=1e-6)
    with pytest.raises(ValueError, match=r"random_starts must be in \[0, 100000\]"):
        brdfkit.fit("lambert+ggx", wi, wo, truth.eval(wi, wo), random_starts=-1)


def test_files_round_trip_and_bad_files(tmp):
    wi, wo = unit_rows(50, seed=3), unit_rows(50, seed=4)
    f = brdfkit.Model("ggx").eval(wi, wo)
    brdfkit.write(tmp / "t.csv", {"wi": wi, "wo": wo, "f": f, "sigma": f * 0.01 + 1e-6})
    d = brdfkit.read(tmp / "t.csv")
    assert d["format"] == "csv"
    np.testing.assert_allclose(d["wi"], wi, atol=1e-15)
    np.testing.assert_array_equal(d["f"], f)
    assert d["sigma"] is not None
    m = brdfkit.Model("lambert+ggx", {"ggx.alpha": 0.3})
    brdfkit.write(tmp / "m.binary", m)
    merl = brdfkit.read(tmp / "m.binary")
    assert merl["values"].shape == (3, 90, 90, 180)
    # The cells hold the model at their centres; the merl model on this file
    # looks them up (a centre is its bin's lower edge, so rounding puts about
    # half of the lookups into the neighbouring bin: a nearby value).
    k = slice(0, None, 37)
    np.testing.assert_allclose(merl["f"][k], m.eval(merl["wi"][k], merl["wo"][k]), rtol=1e-12)
    mm = brdfkit.Model("merl:" + str(tmp / "m.binary"))
    looked_up = mm.eval(merl["wi"][k], merl["wo"][k])
    assert np.isclose(looked_up, merl["f"][k], rtol=1e-12, atol=0).mean() > 0.3
    assert np.median(np.abs(looked_up / merl["f"][k] - 1)) < 0.02
    (tmp / "bad.binary").write_bytes(b"\x01\x00\x00\x00" * 3)
    with pytest.raises(ValueError, match="bad.binary"):
        brdfkit.read(tmp / "bad.binary")
    (tmp / "bad.csv").write_text("theta_i,phi_i,theta_o,phi_o,f_r,f_g,f_b\n0,0,0,0,1,1\n")
    with pytest.raises(ValueError, match="bad.csv"):
        brdfkit.read(tmp / "bad.csv")
    with pytest.raises(ValueError, match="unknown file suffix"):
        brdfkit.read(tmp / "t.xyz")
    with pytest.raises(FileNotFoundError):
        brdfkit.read(tmp / "none.csv")
    with pytest.raises(ValueError, match="missing 'f'"):
        brdfkit.write(tmp / "x.csv", {"wi": wi, "wo": wo})
    assert not (tmp / "x.csv").exists()


def test_stress_equals_cli():
    py = brdfkit.stress(["lambert", "ggx"], sweep_only=True)
    ref = cli_json("stress", "-m", "lambert", "-m", "ggx", "--sweep-only", "--json")
    assert without_times(py) == without_times(ref)
    with pytest.raises(ValueError, match="unknown model 'nosuch'"):
        brdfkit.stress(["nosuch"])


def test_stress_takes_a_measured_table_by_its_model_text(tmp_path):
    # A table written from lambert: swept through "utia:FILE" exactly as the
    # command line sweeps it; a missing file is named.
    path = str(tmp_path / "l.utia")
    brdfkit.write(path, brdfkit.Model("lambert"))
    py = brdfkit.stress(["utia:" + path], sweep_only=True)
    ref = cli_json("stress", "-m", "utia:" + path, "--sweep-only", "--json")
    assert without_times(py) == without_times(ref)
    assert [r["type"] for r in py["models"]] == ["float", "double", "jet"]
    assert py["models"][1]["evaluations"] > 1000 and py["clean"]
    with pytest.raises(ValueError, match="none.utia"):
        brdfkit.stress(["utia:" + str(tmp_path / "none.utia")])


def test_ctrl_c_interrupts_a_long_call():
    # interrupt_main() delivers a simulated SIGINT to the main thread while
    # the table is being built (several seconds of work uninterrupted).
    timer = threading.Timer(0.3, _thread.interrupt_main)
    t0 = time.monotonic()
    timer.start()
    with pytest.raises(KeyboardInterrupt):
        brdfkit.albedo_table("ggx", axes="mu:64,alpha:64:0.001:1", threads=1)
    assert time.monotonic() - t0 < 5
    timer.join()


def test_albedo_table_above_its_tolerance_raises():
    # alpha down to 1e-7 (the default range) misses 1e-6 at grazing, as on the command line.
    with pytest.raises(ValueError, match="miss the error tolerance"):
        brdfkit.albedo_table("ggx", axes="mu:4,alpha:3")
    t = brdfkit.albedo_table("ggx", axes="mu:4,alpha:3", accept_error=1.0)
    assert t["max_error"] > 1e-6


def test_threads_argument_gives_the_same_table():
    a = brdfkit.albedo_table("ggx", axes="mu:4,alpha:2:0.2:0.5", threads=1)
    b = brdfkit.albedo_table("ggx", axes="mu:4,alpha:2:0.2:0.5", threads=2)
    np.testing.assert_array_equal(a["E"], b["E"])


def test_albedo_table_part_of_a_glass():
    t = brdfkit.albedo_table("ggx_glass", {"alpha": 0.3}, axes="mu:2:0.8:1,eta:1:1.5:1.5", part="reflected",
                             tolerance=1e-5, threads=1)
    assert t["part"] == "E_R" and t["params"] == "alpha=0.3"
    assert abs(t["E"][-1] - 0.04) < 5e-3  # normal incidence: about the Fresnel reflectance
    with pytest.raises(ValueError, match="part 'both'"):
        brdfkit.albedo_table("ggx_glass", axes="mu:2,eta:1:1.5:1.5", part="both")
