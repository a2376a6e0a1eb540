"""The measured-data formats from Python: read and write RGL, UTIA and ASTM
files as MERL and CSV, against closed forms, the model that wrote them and
the command line's convert."""
import warnings

import numpy as np
import pytest

import brdfkit
from conftest import cli, unit_rows

# A reduced RGL resolution keeps the tests fast; the file is still exact at
# its nodes and a few per cent between them.
SMALL_RGL = {"theta_i": 8, "samples": 16, "vndf": 32, "ndf": 64, "sigma": 16}
LAMBERT = brdfkit.Model("lambert", {"albedo": (0.5, 0.3, 0.2)})


@pytest.mark.parametrize("suffix", [".bsdf", ".utia", ".astm", ".binary", ".csv"])
def test_lambert_through_every_format_reads_rho_over_pi(tmp, suffix):
    path = tmp / ("lambert" + suffix)
    described = brdfkit.write(path, LAMBERT, rgl=SMALL_RGL)
    assert described["target"]["format"] == brdfkit.read(path)["format"]
    assert described["source"] == {"model": "lambert", "params": "albedo=0.5:0.3:0.2", "anisotropic": False}
    r = brdfkit.read(path)
    assert len(r["f"]) > 1000
    rho = np.array([0.5, 0.3, 0.2]) / np.pi
    # RGL stores f cos(theta_o) through its own warps; the nodes read back to rounding.
    np.testing.assert_allclose(r["f"], np.tile(rho, (len(r["f"]), 1)), rtol=1e-6 if suffix == ".bsdf" else 1e-13)
    assert np.all(r["wi"][:, 2] > 0) and np.all(r["wo"][:, 2] > 0)


@pytest.mark.parametrize("suffix", [".utia", ".astm"])
def test_a_glossy_model_reads_back_at_the_files_nodes(tmp, suffix):
    ggx = brdfkit.Model("ggx", {"alpha": 0.3, "f0": (0.9, 0.6, 0.3)})
    path = tmp / ("ggx" + suffix)
    brdfkit.write(path, ggx, step_deg=7.5)
    r = brdfkit.read(path)
    np.testing.assert_allclose(r["f"], ggx.eval(r["wi"], r["wo"]), rtol=1e-12, atol=1e-300)
    if suffix == ".astm":  # 7.5 degree steps: 12 theta_i x 12 theta_o x 48 phi_o
        assert len(r["f"]) + r["missing"] == 12 * 12 * 48


def test_rgl_written_from_python_reconstructs_the_model(tmp):
    ggx = brdfkit.Model("ggx", {"alpha": 0.3})
    path = tmp / "ggx.bsdf"
    described = brdfkit.write(path, ggx, rgl=SMALL_RGL)
    rec = described["target"]["reconstruction"]
    # At this reduced resolution the writer measured a 99th percentile of 10.6 %.
    assert 0 < rec["p99_relative"] < 0.14
    back = brdfkit.Model("rgl", {"path": str(path)})
    wi = unit_rows(4000, seed=3, min_z=np.cos(np.radians(75)))
    wo = unit_rows(4000, seed=4, min_z=0.2)
    ref = ggx.eval(wi, wo)[:, 1]
    got = back.eval(wi, wo)[:, 1]
    keep = ref * wo[:, 2] > 0.01 * np.max(ref * wo[:, 2])
    err = np.abs(got[keep] / ref[keep] - 1)
    # Measured: median 0.51 %, 99th percentile 4.2 % (the default resolution is
    # far finer; its figures are in the README).
    assert np.median(err) < 0.0075, np.median(err)
    assert np.percentile(err, 99) < 0.052, np.percentile(err, 99)


@pytest.mark.parametrize("name,options", [("ggx.bsdf", ["--rgl-theta-i", "8", "--rgl-samples", "16", "--rgl-vndf", "32",
                                                          "--rgl-ndf", "64"]),
                                          ("ggx.astm", ["--step", "15"]), ("ggx.utia", [])])
def test_the_same_file_as_convert(tmp, name, options):
    ggx = brdfkit.Model("ggx", {"alpha": 0.3, "f0": 0.5})
    rgl = {"theta_i": 8, "samples": 16, "vndf": 32, "ndf": 64}
    brdfkit.write(tmp / name, ggx, rgl=rgl, step_deg=15)
    cli("convert", "--model", "ggx", "--params", "alpha=0.3,f0=0.5", *options, tmp / ("cli_" + name))
    assert (tmp / name).read_bytes() == (tmp / ("cli_" + name)).read_bytes()


def test_an_anisotropic_model_into_merl_warns(tmp):
    aniso = brdfkit.Model("ggx_aniso", {"alpha_x": 0.1, "alpha_y": 0.4})
    with pytest.warns(UserWarning, match="anisotropic and MERL isotropic"):
        described = brdfkit.write(tmp / "a.binary", aniso)
    assert described["source"]["anisotropic"] is True
    assert "warning" in described["target"]
    # Into ASTM: incident azimuths for the anisotropy, no warning.
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        described = brdfkit.write(tmp / "a.astm", aniso, step_deg=15)
    assert described["target"]["resolution"]["phi_i"] == 8
    # An isotropic model says so.
    assert brdfkit.write(tmp / "i.astm", LAMBERT, step_deg=15)["source"]["anisotropic"] is False


def test_a_python_model_into_utia(tmp):
    def lam(wi, wo, p):
        return np.full((len(wi), 3), p["albedo"] / np.pi)

    model = brdfkit.PythonModel(lam, {"albedo": {"default": 0.4, "lower": 0.0, "upper": 1.0}}, kind="diffuse")
    brdfkit.write(tmp / "p.utia", model, threads=2)
    np.testing.assert_allclose(brdfkit.read(tmp / "p.utia")["f"], 0.4 / np.pi, rtol=1e-15)


def test_a_measured_file_into_utia_names_its_source(tmp):
    brdfkit.write(tmp / "l.utia", LAMBERT)
    described = brdfkit.write(tmp / "again.utia", brdfkit.Model("utia", {"path": str(tmp / "l.utia")}))
    assert described["source"]["model"] == "utia"
    assert described["source"]["settings"] == {"path": str(tmp / "l.utia")}
    np.testing.assert_allclose(brdfkit.read(tmp / "again.utia")["f"], brdfkit.read(tmp / "l.utia")["f"], rtol=1e-15)


def test_bad_options_and_files_are_named_and_write_nothing(tmp):
    with pytest.raises(ValueError, match="vndf_theta must be 2 to 4096, got 1"):
        brdfkit.write(tmp / "x.bsdf", LAMBERT, rgl={"vndf_theta": 1})
    with pytest.raises(ValueError, match="unknown resolution 'rows'"):
        brdfkit.write(tmp / "x.bsdf", LAMBERT, rgl={"rows": 8})
    with pytest.raises(ValueError, match="step_deg must be 0.5 to 45 degrees, got 0.1"):
        brdfkit.write(tmp / "x.astm", LAMBERT, step_deg=0.1)
    with pytest.raises(ValueError, match="step_deg must be a number of degrees, got 'x'"):
        brdfkit.write(tmp / "x.astm", LAMBERT, step_deg="x")
    with pytest.raises(ValueError, match="unknown resolution 'rows' \\(known: .*samples, sigma"):
        brdfkit.write(tmp / "x.bsdf", LAMBERT, rgl={"rows": 8})
    with pytest.raises(ValueError, match="phi_i must be a positive int"):
        brdfkit.write(tmp / "x.astm", LAMBERT, phi_i=0)
    with pytest.raises(TypeError, match="rgl files are written from a model"):
        brdfkit.write(tmp / "x.bsdf", {"wi": np.zeros((1, 3))})
    with pytest.raises(ValueError, match="rgl files are named"):
        brdfkit.write(tmp / "x.dat", LAMBERT, format="rgl")
    with pytest.raises(ValueError, match="unknown file suffix '.dat'"):
        brdfkit.write(tmp / "x.dat", LAMBERT)
    assert list(tmp.iterdir()) == []
    # Files whose header disagrees with their name, or that are cut short.
    (tmp / "fake.bsdf").write_bytes(b"not a tensor file")
    with pytest.raises(ValueError, match="fake.bsdf.*tensor_file"):
        brdfkit.read(tmp / "fake.bsdf")
    (tmp / "short.utia").write_bytes(b"\0" * 800)
    with pytest.raises(ValueError, match="short.utia.*800 bytes"):
        brdfkit.read(tmp / "short.utia")
    with pytest.raises(ValueError, match="utia files are named"):
        brdfkit.read(tmp / "fake.bsdf", format="utia")
    with pytest.raises(FileNotFoundError, match="missing.astm"):
        brdfkit.read(tmp / "missing.astm")
