from os import PathLike
from typing import Any, Callable, Mapping, Optional, Sequence, Union

import numpy as np
import numpy.typing as npt

ArrayLike = npt.ArrayLike
Params = Union[None, str, Mapping[str, Union[float, Sequence[float], str]]]
PathArg = Union[str, PathLike]

class Model:
    """A BRDF model (one lobe or a sum of lobes) with its parameter values."""

    def __init__(self, spec: str, params: Params = None) -> None: ...
    @property
    def spec(self) -> str: ...
    @property
    def params(self) -> dict[str, Union[float, tuple[float, float, float]]]: ...
    @property
    def packed(self) -> np.ndarray: ...
    @property
    def packed_names(self) -> list[str]: ...
    @property
    def info(self) -> dict[str, Any]: ...
    def eval(self, wi: ArrayLike, wo: ArrayLike) -> np.ndarray:
        """f_r(wi, wo) in 1/sr, shape (N, 3) or (3,); float32 for float32 inputs."""
    def sample(self, wo: ArrayLike, u: ArrayLike) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(wi (N, 3), pdf (N,), valid (N,)) for wo (N, 3) and u (N, 2) in [0, 1)."""
    def pdf(self, wo: ArrayLike, wi: ArrayLike) -> np.ndarray:
        """Solid-angle density of sample(), shape (N,)."""
    def albedo(self, wo: ArrayLike, tolerance: float = 1e-6, threads: int = 0) -> np.ndarray:
        """Directional albedo per channel, shape (N, 3) or (3,)."""

class PythonModel:
    """A BRDF defined by Python functions on numpy arrays (see help(brdfkit.PythonModel))."""

    def __init__(self, eval: Callable[..., ArrayLike],
                 params: Optional[Mapping[str, Mapping[str, Union[float, str]]]] = None,
                 sample: Optional[Callable[..., tuple[ArrayLike, ArrayLike]]] = None,
                 pdf: Optional[Callable[..., ArrayLike]] = None, kind: str = "diffuse+glossy",
                 width: Union[None, float, Callable[..., Union[float, tuple[float, float]]]] = None,
                 name: str = "python") -> None:
        """eval(wi, wo[, params]) -> (N, 3); params {name: {default, lower, upper[, scale, meaning]}};
        sample(wo, u[, params]) -> (wi, pdf) and pdf(wo, wi[, params]) -> (N,), both or neither."""
    @property
    def name(self) -> str: ...
    @property
    def params(self) -> list[dict[str, Any]]: ...
    @property
    def can_sample(self) -> bool: ...

class Tabulated:
    """A BRDF given as samples f (N, 3) at direction pairs wi, wo (N, 3); nearest or idw lookup."""

    def __init__(self, wi: ArrayLike, wo: ArrayLike, f: ArrayLike, interp: str = "nearest") -> None: ...
    @property
    def size(self) -> int: ...
    @property
    def interp(self) -> str: ...
    def eval(self, wi: ArrayLike, wo: ArrayLike) -> np.ndarray:
        """The looked-up f_r, shape (N, 3) or (3,)."""

AnyModel = Union[Model, str, PythonModel, Tabulated]

def models() -> list[dict[str, Any]]:
    """The registered models with their parameter tables."""

def check(model: AnyModel, params: Params = None, *, sampling: bool = True, samples: int = 100000,
          random_pairs: int = 4000, seed: int = 1, threads: int = 0) -> dict[str, Any]:
    """Physical plausibility, as ``brdfkit check --json``."""

def albedo_table(model: Union[Model, str, PythonModel], params: Params = None, *, axes: str = "mu:32,alpha:32:0.001:1",
                 nodes: str = "uniform", tolerance: float = 1e-6, accept_error: Optional[float] = None,
                 channel: int = 0, part: str = "total", threads: int = 0) -> dict[str, Any]:
    """Albedo tables, as ``brdfkit albedo --json`` (tables as numpy arrays)."""

def albedo_preset(name: str, *, size: int = 0, tables: Optional[Sequence[str]] = None, tolerance: float = 1e-7,
                  accept_error: Optional[float] = None, threads: int = 0) -> dict[str, Any]:
    """A renderer's table set, as ``brdfkit albedo --preset NAME --json`` (values as numpy arrays)."""

def synth(model: AnyModel, params: Params = None, *, instrument: Union[None, PathArg, dict] = None,
          seed: int = 0, out: Union[PathArg, Sequence[PathArg]] = (), threads: int = 0) -> dict[str, Any]:
    """A synthetic measurement: the FILE.json content plus arrays wi, wo, f, sigma, valid, saturated."""

def fit(model: Union[Model, str, PythonModel], data: Union[PathArg, ArrayLike], wo: ArrayLike = None, f: ArrayLike = None,
        sigma: ArrayLike = None, *, init: Params = None, metric: str = "l2", loss: str = "none",
        solver: str = "dense_qr", max_theta_deg: float = -1.0, threads: int = 2, max_iterations: int = 200,
        starts: int = 5, covariance: bool = True, use_sigma: bool = True,
        instrument: Union[None, PathArg, dict] = None, aperture_order: int = 0,
        fix: Union[None, str, Mapping[str, Union[float, Sequence[float]]]] = None,
        tie: Union[None, str, Mapping[str, str]] = None,
        bounds: Union[None, str, Mapping[str, tuple[float, float]]] = None,
        random_starts: int = 0, seed: int = 1) -> dict[str, Any]:
    """A fit, as ``brdfkit fit --json``, plus packed arrays, covariance and the fitted Model.

    fix {"ggx.f0": 0.04} holds parameters, tie {"ggx#2.f0": "ggx.f0"} makes one follow
    another, bounds {"ggx.alpha": (0.01, 0.5)} narrows a range (or the command line's
    "name=value,..." text); ValueError naming the parameter when one does not apply.
    The result lists local_optima (cost, params, origin) and kept (the index of the one
    refined into the result); fixed (names) and tied (follower: leader). random_starts > 0
    replaces the start search by that many random starts (seed), each solved to convergence."""

def stress(models: Union[str, Sequence[str]] = (), *, merl: Union[None, PathArg] = None,
           sweep_only: bool = False) -> dict[str, Any]:
    """Robustness sweep, as ``brdfkit stress --json``."""

class Format:
    name: str
    suffixes: tuple[str, ...]
    reader: Callable[[str], dict[str, Any]]
    writer: Optional[Callable[[str, Any], None]]
    named: bool
    def __init__(self, name: str, suffixes: Sequence[str], reader: Callable[[str], dict[str, Any]],
                 writer: Optional[Callable[[str, Any], None]], named: bool = False) -> None: ...

FORMATS: dict[str, Format]

def read(path: PathArg, format: Union[None, str] = None) -> dict[str, Any]:
    """Measured data at the file's nodes: format, wi, wo, f, sigma, missing (MERL: values too)."""

def write(path: PathArg, data: Union[dict[str, Any], Model, PythonModel, Tabulated], format: Union[None, str] = None, *,
          rgl: Optional[dict[str, int]] = None, step_deg: float = 5.0, phi_i: Optional[int] = None,
          anisotropic: bool = False, threads: int = 0) -> Optional[dict[str, Any]]:
    """Writes measured data atomically: a model tabulated in any format (returns what convert's
    sidecar says), or arrays as CSV samples or MERL values."""
