"""brdfkit: measure, check and fit BRDFs from Python, on numpy arrays.

The same models, checks, albedo tables, synthetic measurements, fits and
file formats as the ``brdfkit`` command line, with the same results (the
dicts returned here hold what ``--json`` prints) and the same messages
(raised as ``ValueError`` or ``TypeError``).

>>> import numpy as np, brdfkit
>>> m = brdfkit.Model("lambert+ggx", {"lambert.albedo": 0.5, "ggx.alpha": 0.2})
>>> m.eval(np.array([0.0, 0.0, 1.0]), np.array([0.0, 0.0, 1.0])).shape
(3,)

A BRDF of one's own, written with numpy, goes into check, albedo_table,
synth and fit as a :class:`PythonModel`; samples given as arrays as a
:class:`Tabulated`.

Long calls (check, albedo_table, synth, fit, Model.albedo) release the
GIL, stop with KeyboardInterrupt on Ctrl-C and take ``threads``.
"""

import json as _json
import os as _os
import warnings as _warnings

from ._brdfkit import Model, PythonModel, Tabulated, models
from . import _brdfkit

__all__ = ["Model", "PythonModel", "Tabulated", "models", "check", "albedo_table", "albedo_preset", "synth", "fit", "stress", "read", "write", "FORMATS"]


def _existing(path, what):
    """The path as a string; FileNotFoundError naming it when it does not exist."""
    p = _os.fspath(path)
    if not _os.path.exists(p):
        raise FileNotFoundError(f"{what} '{p}' does not exist")
    return p


def check(model, params=None, *, sampling=True, samples=100000, random_pairs=4000, seed=1, albedo_budget=400000,
          threads=0):
    """Physical plausibility of a model, as ``brdfkit check --json``.

    Parameters
    ----------
    model : Model, str, PythonModel or Tabulated
        A Model, a model name or a PythonModel (then ``params`` gives its
        values), or a Tabulated.
    params : dict or str, optional
        Parameter values when ``model`` is a name or a PythonModel.
    sampling : bool
        Run the sampling tests (pdf integral, chi-square); when False, or
        for a PythonModel without sample and pdf, the result's
        ``sampling_note`` says they were not run.
    samples : int
        Samples per direction for the chi-square test.
    random_pairs : int
        Random direction pairs of the reciprocity and value checks.
    seed : int
        Seed of every random draw.
    albedo_budget : int
        Integrand evaluations per directional albedo of the energy search
        (1000 to 1e9); a measured table spends all of it.
    threads : int
        Threads (0: every core).

    Returns
    -------
    dict
        reciprocity_max_rel_error, albedo_max, albedo_max_at_mu, min_value,
        nonfinite_count, pdf_integral, chi2_p_value, plausible, reasons, ...
    """
    return _brdfkit._check(model, params, sampling, samples, random_pairs, seed, albedo_budget, threads)


def albedo_table(model, params=None, *, axes="mu:32,alpha:32:0.001:1", nodes="uniform", tolerance=1e-6,
                 accept_error=None, channel=0, part="total", albedo_budget=1000000, threads=0):
    """Directional albedo table E(mu, p), E_avg(p) and the Kulla-Conty terms.

    As ``brdfkit albedo --json``; the tables are numpy arrays.

    Parameters
    ----------
    model : Model, str or PythonModel
    params : dict or str, optional
        Values of the parameters that are not axes.
    axes : str
        ``mu:N`` then up to two parameters ``name:count[:lower:upper]``;
        ``roughness`` sets ``alpha = roughness**2``. ``mu:N`` alone
        tabulates E(mu) of the model as given (a measured table such as
        ``"rgl:FILE"``, whose interpolation keeps the integrals from
        converging much below 1e-4: ask for ``tolerance=1e-3``).
    nodes : {"uniform", "gauss"}
    tolerance : float
        Absolute error target per entry: the table's contract. A table with
        an entry whose error estimate exceeds it raises ValueError naming
        the entries.
    accept_error : float, optional
        Accept entries whose error estimate is up to this instead.
    channel : int
        RGB channel tabulated.
    part : {"total", "reflected", "transmitted"}
        For a transmitting model: E_R + E_T, E_R or E_T (other models: E).
    albedo_budget : int
        Evaluations per directional albedo after which the adaptive rule
        stops refining (an entry above the tolerance by then is reported).
    threads : int
        Threads (0: every core).

    Returns
    -------
    dict
        model, params (the fixed ones), part, mu, axes (name, nodes), E (n1 [x n2] x n_mu, mu
        fastest), E_avg, ms_norm, max_error, limit_error, seconds, and
        with an f0 axis F_avg, E1, E1_avg, F_ms.
    """
    import numpy as np

    t = _brdfkit._albedo_table(model, params, axes, nodes, tolerance, 0.0 if accept_error is None else accept_error,
                               channel, part, albedo_budget, threads)
    for key in ("mu", "E", "E_avg", "ms_norm", "F_avg", "E1", "E1_avg", "F_ms"):
        if key in t:
            t[key] = np.asarray(t[key], dtype=float)
    for a in t["axes"]:
        a["nodes"] = np.asarray(a["nodes"], dtype=float)
    return t


def albedo_preset(name, *, size=0, tables=None, tolerance=1e-7, accept_error=None, threads=0):
    """A renderer's table set, as ``brdfkit albedo --preset NAME --json``.

    Parameters
    ----------
    name : {"cycles", "filament", "kulla_conty"}
    size : int
        Nodes per axis of ``filament`` (default 128) and ``kulla_conty``
        (3 to 256, default 16); 0 takes the default. Cycles' sizes are fixed.
    tables : list of str, optional
        Only these tables (array names).
    tolerance : float
        Absolute error target per entry (the presets' 1e-7 by default); a
        table with an entry above it raises ValueError naming the entries.
    accept_error : float, optional
        Accept entries whose error estimate is up to this instead.
    threads : int
        Threads (0: every core).

    Returns
    -------
    dict
        preset, max_error, seconds and tables: {array name: {definition,
        axes (name, nodes, evaluated), channels, value, error, derived}}
        (a derived table, kulla_conty's x, propagates the errors of the
        tables it is made from and is not held to the tolerance). value and
        error are numpy arrays indexed slowest axis first, the renderer's
        array order: [z, mu, roughness] for Cycles' glass tables, [row,
        texel, channel] for Filament's; a channel axis only where there are
        several.
    """
    import numpy as np

    r = _brdfkit._albedo_preset(name, size, list(tables or []), tolerance,
                                0.0 if accept_error is None else accept_error, threads)
    out = {}
    for t in r["tables"]:
        shape = tuple(len(a["nodes"]) for a in reversed(t["axes"]))
        if len(t["channels"]) > 1:
            shape += (len(t["channels"]),)
        for key in ("value", "error"):
            t[key] = np.asarray(t[key], dtype=float).reshape(shape)
        for a in t["axes"]:
            a["nodes"] = np.asarray(a["nodes"], dtype=float)
            a["evaluated"] = np.asarray(a["evaluated"], dtype=float)
        out[t.pop("name")] = t
    r["tables"] = out
    return r


def synth(model, params=None, *, instrument=None, seed=0, out=(), threads=0):
    """A synthetic gonioreflectometer measurement, as ``brdfkit synth``.

    Parameters
    ----------
    model : Model, str, PythonModel or Tabulated
    params : dict or str, optional
    instrument : str, os.PathLike or dict, optional
        Instrument JSON file or its content; default the built-in one.
    seed : int
        Seed of every random draw (noise, jitter).
    out : sequence of str
        Files to write as the command line's ``--out`` (.csv, .binary, .exr),
        each with its FILE.json.
    threads : int
        Threads (0: every core).

    Returns
    -------
    dict
        The FILE.json content (instrument, model, params, seed, report) and
        arrays wi, wo, f, sigma of shape (N, 3) and valid, saturated (N,).
    """
    if isinstance(out, (str, _os.PathLike)):
        out = [out]
    return _brdfkit._synth(model, params, instrument, seed, [_os.fspath(p) for p in out], threads)


def fit(model, data, wo=None, f=None, sigma=None, *, init=None, metric="l2", loss="none", solver="dense_qr",
        max_theta_deg=-1.0, threads=2, max_iterations=200, starts=5, covariance=True, use_sigma=True,
        instrument=None, aperture_order=0, fix=None, tie=None, bounds=None, random_starts=0, seed=1):
    """Least-squares fit of a model to measured reflectance, as ``brdfkit fit --json``.

    Parameters
    ----------
    model : Model, str or PythonModel
        A model name or sum (``"lambert+ggx"``), ``"fit:FILE"`` to refine a
        previous fit, a Model (its values are the starting point), or a
        PythonModel (its parameter table gives the bounds, the log-scale
        parameters the multi-start; derivatives by central differences).
    data : str, os.PathLike or array_like
        A CSV table, or a MERL, RGL, UTIA or ASTM file (samples at the file's
        own nodes), or the array wi (N, 3) with ``wo`` and ``f``.
    wo, f, sigma : array_like, shape (N, 3), optional
        With array data: directions towards the detector, f_r in 1/sr and
        optionally its standard deviation (weights 1/sigma).
    init : dict or str, optional
        Starting point; default multi-start over roughness-like parameters.
    metric : {"l2", "relative", "cosine", "log", "cbrt"}
    loss : str
        ``"none"``, ``"huber"`` or ``"cauchy"``, optionally ``:scale``.
    solver : {"dense_qr", "dense_normal_cholesky", "iterative_schur", "cgnr"}
    max_theta_deg : float
        Drop samples with theta_i or theta_o above this (-1: none; 80 for cosine).
    threads, max_iterations, starts : int
    covariance : bool
        Compute uncertainties.
    use_sigma : bool
        Weight by sigma when the data has it.
    instrument : str or dict, optional
        Fit through this instrument's finite apertures.
    aperture_order : int
        Aperture quadrature order with ``instrument``; 0 (default): the
        instrument's own, whose automatic order is synth's per-pair adaptive rule.
    fix : dict or str, optional
        Parameters held fixed, e.g. ``{"ggx.f0": 0.04, "lambert.albedo": (0.2, 0.3, 0.4)}``
        (stddev 0, listed in the result's ``fixed``).
    tie : dict or str, optional
        Parameters that follow another, e.g. ``{"ggx#2.f0": "ggx.f0"}``: same kind and
        size; a follower reports its leader's stddev.
    bounds : dict or str, optional
        Narrower ranges, e.g. ``{"ggx.alpha": (0.01, 0.5)}``, within the model's.
        Each of fix, tie and bounds may also be the command line's text
        (``"ggx.f0=0.04,lambert.albedo=0.2:0.3:0.4"``). A name that does not
        exist, a value or bounds out of range, a tie between different kinds,
        a tie cycle or nothing left to fit raise ValueError naming the parameter.
    random_starts, seed : int
        When random_starts > 0, the start strategy is replaced by that many
        random starts (drawn with seed), each solved to convergence: an
        independent check that the default search finds the global optimum.

    Returns
    -------
    dict
        The command line's JSON (model, params, stddev, correlation, cost,
        rmse, iterations, trace, local_optima and kept, fixed, tied, ...)
        plus packed_names, packed_params, packed_stddev, covariance (numpy)
        and model_object (the fitted Model; for a PythonModel, the
        PythonModel itself).
    """
    if isinstance(data, (str, _os.PathLike)):
        data = _existing(data, "data file")
    return _brdfkit._fit(model, data, wo, f, sigma, init, metric, loss, solver, max_theta_deg, threads,
                         max_iterations, starts, covariance, use_sigma, instrument, aperture_order,
                         _assignments(fix, "fix", _values), _assignments(tie, "tie", str),
                         _assignments(bounds, "bounds", _range), random_starts, seed)


def _values(v):
    """A value or (r, g, b) as the command line's text."""
    if isinstance(v, (list, tuple)):
        return ":".join(repr(float(x)) for x in v)
    return repr(float(v))


def _range(v):
    """(lo, hi) as the command line's text."""
    if not isinstance(v, (list, tuple)) or len(v) != 2:
        raise ValueError(f"bounds: expected (lo, hi), got {v!r}")
    return f"{float(v[0])!r}:{float(v[1])!r}"


def _assignments(arg, what, text):
    """None, "name=...,name=..." or a dict as "name=...,name=..."."""
    if arg is None:
        return ""
    if isinstance(arg, str):
        return arg
    if not isinstance(arg, dict):
        raise TypeError(f"{what} must be a dict or a 'name=...' string (got {type(arg).__name__})")
    return ",".join(f"{k}={text(v)}" for k, v in arg.items())


def stress(models=(), *, merl=None, sweep_only=False):
    """Robustness sweep over extreme parameters and directions, as ``brdfkit stress --json``.

    Parameters
    ----------
    models : sequence of str
        Registered model names (default every model); a measured table
        with its file as ``"rgl:FILE"`` (likewise merl, utia, astm).
    merl : str, optional
        A MERL file for the merl model (otherwise it is skipped).
    sweep_only : bool
        Skip the stiff integrals and fits (they run only over every model).

    Returns
    -------
    dict
        models (one row per model and scalar type), sweep_seconds, clean,
        stiff_integrals, stiff_fits.
    """
    if isinstance(models, str):
        models = [models]
    return _brdfkit._stress(list(models), "" if merl is None else _existing(merl, "MERL file"), sweep_only)


class Format:
    """A measured-data file format: name, file suffixes, reader and writer
    of arrays (None: written from a model only, see write); named: files
    of the format must carry one of its suffixes (its reader goes by it)."""

    def __init__(self, name, suffixes, reader, writer, named=False):
        self.name = name
        self.suffixes = tuple(suffixes)
        self.reader = reader
        self.writer = writer
        self.named = named

    def __repr__(self):
        return f"brdfkit.Format({self.name!r}, {self.suffixes!r})"


#: Known formats by name. A new format is one entry here.
FORMATS = {
    "merl": Format("merl", (".binary",), _brdfkit._read_merl, _brdfkit._write_merl),
    "csv": Format("csv", (".csv",), _brdfkit._read_csv, _brdfkit._write_csv),
    "rgl": Format("rgl", (".bsdf",), _brdfkit._read_samples, None, named=True),
    "utia": Format("utia", (".utia", ".bin"), _brdfkit._read_samples, None, named=True),
    "astm": Format("astm", (".astm",), _brdfkit._read_samples, None, named=True),
}


def _format(path, format, by_suffix=False):
    """The Format of path: format if given, else by suffix. The suffix must
    be the format's where the format is named, or by_suffix (a model's
    target, whose format the suffix decides)."""
    if format is not None:
        if format not in FORMATS:
            raise ValueError(f"unknown format '{format}' (known formats: {', '.join(FORMATS)})")
        fmt = FORMATS[format]
        suffix = _os.path.splitext(_os.fspath(path))[1].lower()
        if (by_suffix or fmt.named) and suffix not in fmt.suffixes:
            raise ValueError(f"'{_os.fspath(path)}': {format} files are named *{' or *'.join(fmt.suffixes)}")
        return fmt
    suffix = _os.path.splitext(_os.fspath(path))[1].lower()
    for fmt in FORMATS.values():
        if suffix in fmt.suffixes:
            return fmt
    known = ", ".join(s for f in FORMATS.values() for s in f.suffixes)
    raise ValueError(f"'{_os.fspath(path)}': unknown file suffix '{suffix}' (known: {known}; or give format=)")


def read(path, format=None):
    """Reads measured data: the samples at the file's own nodes, as
    ``brdfkit fit --data`` reads them.

    Parameters
    ----------
    path : str or os.PathLike
    format : str, optional
        A key of FORMATS; default from the suffix (.binary MERL, .csv table,
        .bsdf RGL, .utia or .bin UTIA, .astm ASTM E1392). RGL, UTIA and
        ASTM files must carry their suffix, and their header must agree.

    Returns
    -------
    dict
        format, wi, wo, f (N, 3) of the valid samples (f_r in 1/sr; for RGL
        the stored f_r cos(theta_o) divided by the cosine), sigma (N, 3) or
        None, missing (samples skipped), and for MERL values (3, 90, 90, 180).
    """
    fmt = _format(path, format)
    return fmt.reader(_existing(path, "file"))


def write(path, data, format=None, *, rgl=None, step_deg=5.0, phi_i=None, anisotropic=False, threads=0):
    """Writes measured data atomically (a complete file or none).

    Parameters
    ----------
    path : str or os.PathLike
    data : dict, Model, PythonModel or Tabulated
        A model (any of the three) is tabulated at the target format's own
        nodes, as ``brdfkit convert --model`` does: MERL bin centres, an RGL
        file fitted to the model, UTIA's 6 x 48 x 6 x 48 grid, or an ASTM /
        CSV grid of step_deg. Arrays: CSV, a dict with wi, wo, f (N, 3) and
        optional sigma; MERL, a dict with values (3, 90, 90, 180).
    format : str, optional
        A key of FORMATS; default from the suffix. A model is written in
        the format of the suffix, which must agree with format.
    rgl : dict, optional
        RGL resolutions, the convert command's --rgl-* options: theta_i,
        phi_i (0 isotropic; default 0, or for an anisotropic model 64, 33 or
        17 with symmetry 1, 2 or 4),
        ndf, sigma, vndf, vndf_theta, samples (the value tables are samples x
        samples: the format's readers require square ones), symmetry (1; 2
        or 4 for the incident azimuths over pi or pi / 2 of an anisotropic
        source unchanged by a turn by pi or by both mirrors).
    step_deg : float
        ASTM and CSV grid step in degrees (0.5 to 45).
    phi_i : int, optional
        ASTM and CSV incident azimuths (default 1, or 8 for an anisotropic
        model).
    anisotropic : bool
        Treat the model as anisotropic even where it does not vary as the
        surface turns.
    threads : int
        Worker threads (0: all cores).

    Returns
    -------
    dict or None
        For a model: what ``convert``'s sidecar says (source: model,
        params, anisotropic, and the model's settings such as a measured
        file's path; target: format, resolution, path, for RGL the
        reconstruction error, and a warning where the format cannot hold the
        model, which is also issued as a UserWarning). None for arrays.
    """
    if isinstance(data, (Model, PythonModel, Tabulated)):
        _format(path, format, by_suffix=True)
        if rgl is not None and not isinstance(rgl, dict):
            raise TypeError(f"rgl must be a dict of resolutions (got {type(rgl).__name__})")
        if phi_i is not None and (not isinstance(phi_i, int) or phi_i < 1):
            raise ValueError(f"phi_i must be a positive int, got {phi_i!r}")
        try:
            step = float(step_deg)
        except (TypeError, ValueError):
            raise ValueError(f"step_deg must be a number of degrees, got {step_deg!r}") from None
        described = _json.loads(_brdfkit._write_model(
            _os.fspath(path), data, None, dict(rgl or {}), step, -1 if phi_i is None else phi_i,
            bool(anisotropic), threads))
        if "warning" in described["target"]:
            _warnings.warn(f"{_os.fspath(path)}: {described['target']['warning']}", UserWarning, stacklevel=2)
        return described
    fmt = _format(path, format)
    if fmt.writer is None:
        raise TypeError(f"{fmt.name} files are written from a model (a Model, PythonModel or Tabulated), "
                        f"tabulated at the format's own nodes; got {type(data).__name__}")
    fmt.writer(_os.fspath(path), data)
    return None
