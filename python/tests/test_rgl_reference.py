"""brdfkit's RGL reader against a second implementation of the format's
reconstruction, written here in NumPy from the format's definition (Dupuy &
Jakob 2018 and the behaviour of the format's reference loader and Mitsuba's
`measured` plugin): its own container parser, its own marginal-conditional
warp (CDFs of the bilinear density, built per slice and blended linearly
across the slices' parameters, inverted cell by cell), and the evaluation
f_r cos(theta_o) = max(0, value(s)) ndf(u_m) / (4 sigma(u_i)), the last
factor only where the file's jacobian flag is 1, after folding the query
into the azimuths of a reduced anisotropic file (Mitsuba 3's measured
plugin). Files brdfkit writes must also pass the structure checks of the
format's loaders (Mitsuba 3, powitacq).

The two must agree to rounding on files brdfkit writes and, more telling,
on files written here with random tables of unequal shapes, which no choice
of brdfkit's writer has shaped."""
import struct

import numpy as np
import pytest

import brdfkit
from conftest import unit_rows

# dtype codes of the container (the format's own enumeration)
U8, F32 = 1, 10


def parse_tensor_file(raw):
    """{name: ndarray} of a tensor file's bytes: magic, version 1.0, a field
    table (name, ndim, dtype, offset, shape), little-endian, C order."""
    assert raw[:12] == b"tensor_file\0" and raw[12:14] == bytes([1, 0])
    (n_fields,) = struct.unpack_from("<I", raw, 14)
    at, fields = 18, {}
    for _ in range(n_fields):
        (name_len,) = struct.unpack_from("<H", raw, at)
        name = raw[at + 2:at + 2 + name_len].decode()
        at += 2 + name_len
        ndim, dtype, offset = struct.unpack_from("<HBQ", raw, at)
        at += 11
        shape = struct.unpack_from("<" + "Q" * ndim, raw, at)
        at += 8 * ndim
        np_type = {U8: np.uint8, F32: np.float32}[dtype]
        count = int(np.prod(shape))
        fields[name] = np.frombuffer(raw, np_type, count, offset).reshape(shape)
    return fields


def tensor_file_bytes(fields):
    """The container holding `fields` ({name: uint8 or float32 ndarray})."""
    header = b"tensor_file\0" + bytes([1, 0]) + struct.pack("<I", len(fields))
    table_size = sum(2 + len(n) + 11 + 8 * a.ndim for n, a in fields.items())
    offset, table, body = len(header) + table_size, b"", b""
    for name, a in fields.items():
        dtype = U8 if a.dtype == np.uint8 else F32
        table += struct.pack("<H", len(name)) + name.encode() + struct.pack("<HBQ", a.ndim, dtype, offset + len(body))
        table += struct.pack("<" + "Q" * a.ndim, *a.shape)
        body += np.ascontiguousarray(a).astype("<" + a.dtype.str[1:]).tobytes()
    return header + table + body


class Marginal2D:
    """A density over [0,1]^2, bilinear on the h x w nodes of the last two
    axes, one per slice of the leading (parameter) axes, linear between
    parameter nodes and constant beyond the end ones. With cdf=True each
    slice is normalised and its conditional (per row) and marginal CDFs are
    built for the inversion; otherwise the values are interpolated as they
    are."""

    def __init__(self, data, params, cdf):
        d = np.asarray(data, np.float64)
        self.params = [np.asarray(p, np.float64) for p in params]
        assert d.shape[:-2] == tuple(len(p) for p in self.params)
        self.h, self.w = d.shape[-2:]
        if cdf:
            cond = np.zeros_like(d)
            cond[..., 1:] = np.cumsum(0.5 * (d[..., :-1] + d[..., 1:]), axis=-1)
            rows = cond[..., -1]
            marg = np.zeros(d.shape[:-1])
            marg[..., 1:] = np.cumsum(0.5 * (rows[..., :-1] + rows[..., 1:]), axis=-1)
            total = marg[..., -1]
            self.cond, self.marg = cond / total[..., None, None], marg / total[..., None]
            d = d / total[..., None, None]
        else:
            d = d / ((self.h - 1) * (self.w - 1))
        # As stored: a density over the nodes' index square; eval scales it to [0,1]^2.
        self.data = d

    def _corners(self, p):
        """[(index tuple, weight)] of the slices blended at parameters p
        (one array of n values per parameter axis)."""
        out = [((), np.ones(len(p[0]) if p else 1))]
        for values, q in zip(self.params, p):
            if len(values) == 1:
                out = [(ix + (np.zeros(len(q), int),), w) for ix, w in out]
                continue
            i = np.clip(np.searchsorted(values, q, side="right") - 1, 0, len(values) - 2)
            t = np.clip((q - values[i]) / (values[i + 1] - values[i]), 0, 1)
            out = [(ix + (i + b,), w * (t if b else 1 - t)) for ix, w in out for b in (0, 1)]
        return out

    def _lookup(self, table, corners, *rest):
        return sum(w * table[ix + rest] for ix, w in corners)

    def _cell(self, u):
        s = u * np.array([self.w - 1, self.h - 1])
        pos = np.minimum(np.floor(s).astype(int), [self.w - 2, self.h - 2])
        return pos[:, 0], pos[:, 1], s[:, 0] - pos[:, 0], s[:, 1] - pos[:, 1]

    def eval(self, u, p):
        c = self._corners(p)
        x, y, fx, fy = self._cell(u)
        v = lambda dy, dx: self._lookup(self.data, c, y + dy, x + dx)
        bilinear = (1 - fy) * ((1 - fx) * v(0, 0) + fx * v(0, 1)) + fy * ((1 - fx) * v(1, 0) + fx * v(1, 1))
        return bilinear * ((self.h - 1) * (self.w - 1))

    def invert(self, u, p):
        """The square point that the warp maps onto u."""
        c = self._corners(p)
        x, y, fx, fy = self._cell(u)
        v = lambda dy, dx: self._lookup(self.data, c, y + dy, x + dx)
        c0 = (1 - fy) * v(0, 0) + fy * v(1, 0)
        c1 = (1 - fy) * v(0, 1) + fy * v(1, 1)
        sx = fx * (c0 + 0.5 * fx * (c1 - c0))
        sx += (1 - fy) * self._lookup(self.cond, c, y, x) + fy * self._lookup(self.cond, c, y + 1, x)
        r0, r1 = self._lookup(self.cond, c, y, self.w - 1), self._lookup(self.cond, c, y + 1, self.w - 1)
        sx /= (1 - fy) * r0 + fy * r1
        sy = fy * (r0 + 0.5 * fy * (r1 - r0)) + self._lookup(self.marg, c, y)
        return np.stack([sx, sy], axis=1)


class ReferenceRgl:
    def __init__(self, raw):
        f = parse_tensor_file(raw)
        self.isotropic = len(f["phi_i"]) <= 2
        phi, theta = f["phi_i"], f["theta_i"]
        self.jacobian = bool(f["jacobian"][0])
        self.reduction = 1 if self.isotropic else int(np.rint(2 * np.pi / (float(phi[-1]) - float(phi[0]))))
        self.ndf = Marginal2D(f["ndf"], [], cdf=False)
        self.sigma = Marginal2D(f["sigma"], [], cdf=False)
        self.vndf = Marginal2D(f["vndf"], [phi, theta], cdf=True)
        self.rgb = Marginal2D(f["rgb"], [phi, theta, np.arange(3.0)], cdf=False)

    def fold(self, wi, wo):
        """A reduced file (2 pi / k of the azimuths from -pi) holds a
        symmetric material: k = 2 turns the pair by pi where wi.y >= 0, k = 4
        mirrors x where wi.x >= 0 and y where wi.y >= 0."""
        if self.reduction < 2:
            return wi, wo
        wi, wo = wi.copy(), wo.copy()
        flip_y = ~np.signbit(wi[:, 1])
        flip_x = ~np.signbit(wi[:, 0]) if self.reduction == 4 else flip_y
        for v in (wi, wo):
            v[flip_x, 0] *= -1
            v[flip_y, 1] *= -1
        return wi, wo

    def fr_cos(self, wi, wo):
        wi, wo = self.fold(wi, wo)
        wm = wi + wo
        wm /= np.linalg.norm(wm, axis=1)[:, None]
        theta_i, phi_i = np.arccos(wi[:, 2]), np.arctan2(wi[:, 1], wi[:, 0])
        theta_m, phi_m = np.arccos(np.minimum(wm[:, 2], 1)), np.arctan2(wm[:, 1], wm[:, 0])
        theta2u = lambda t: np.sqrt(t * 2 / np.pi)
        phi2u = lambda p: np.mod((p + np.pi) / (2 * np.pi), 1.0)
        u_i = np.stack([theta2u(theta_i), phi2u(phi_i)], axis=1)
        u_m = np.stack([theta2u(theta_m), phi2u(phi_m - phi_i if self.isotropic else phi_m)], axis=1)
        s = self.vndf.invert(u_m, [phi_i, theta_i])
        scale = self.ndf.eval(u_m, []) / (4 * self.sigma.eval(u_i, [])) if self.jacobian else 1.0
        return np.stack([np.maximum(self.rgb.eval(s, [phi_i, theta_i, np.full(len(wi), c)]), 0) * scale
                         for c in range(3)], axis=1)


def brdfkit_fr_cos(path, wi, wo):
    return brdfkit.Model("rgl", {"path": str(path)}).eval(wi, wo) * wo[:, 2:3]


def directions(n, seed):
    return unit_rows(n, seed=seed, min_z=0.02), unit_rows(n, seed=seed + 1, min_z=0.02)


@pytest.mark.parametrize("source,rgl", [
    (brdfkit.Model("ggx", {"alpha": 0.2, "f0": (0.9, 0.5, 0.2)}),
     {"theta_i": 9, "ndf": 48, "sigma": 16, "vndf": 24, "vndf_theta": 20, "samples": 18}),
    (brdfkit.Model("lambert+ggx_aniso", {"lambert.albedo": 0.3, "ggx_aniso.alpha_x": 0.15, "ggx_aniso.alpha_y": 0.4}),
     {"theta_i": 6, "phi_i": 7, "ndf": 40, "sigma": 12, "vndf": 16, "vndf_theta": 12, "samples": 12}),
    # A quarter of the azimuths (the source has both mirror symmetries): the
    # reference folds the queries into it as Mitsuba 3 does.
    (brdfkit.Model("lambert+ggx_aniso", {"lambert.albedo": 0.3, "ggx_aniso.alpha_x": 0.15, "ggx_aniso.alpha_y": 0.4}),
     {"theta_i": 6, "phi_i": 5, "symmetry": 4, "ndf": 40, "sigma": 12, "vndf": 16, "vndf_theta": 12, "samples": 12}),
    (brdfkit.Model("ggx_aniso", {"alpha_x": 0.3, "alpha_y": 0.1}),
     {"theta_i": 6, "phi_i": 4, "symmetry": 2, "ndf": 40, "sigma": 12, "vndf": 16, "vndf_theta": 12, "samples": 12}),
])
def test_files_brdfkit_writes_reconstruct_as_the_reference_computes(tmp, source, rgl):
    path = tmp / "written.bsdf"
    brdfkit.write(path, source, rgl=rgl)
    ref = ReferenceRgl(path.read_bytes())
    assert ref.isotropic == ("phi_i" not in rgl)
    assert ref.reduction == rgl.get("symmetry", 1)
    wi, wo = directions(20000, seed=11)
    want, got = ref.fr_cos(wi, wo), brdfkit_fr_cos(path, wi, wo)
    # brdfkit keeps the vndf's normalised density in float (as the format's
    # loaders do) and integrates its CDFs from it; this reference normalises in
    # double: measured, median 1e-9 and at most 1e-5 relative.
    big = want > 1e-6 * want.max()
    assert big.mean() > 0.07
    np.testing.assert_allclose(got[big], want[big], rtol=5e-5)
    np.testing.assert_allclose(got, want, rtol=0, atol=1e-7 * want.max())
    assert np.median(np.abs(got[big] / want[big] - 1)) < 1e-7


@pytest.mark.parametrize("n_phi,reduction,jacobian", [(1, 1, 1), (2, 1, 1), (5, 1, 1), (5, 1, 0), (4, 2, 1), (3, 4, 0)])
def test_random_tables_of_unequal_shapes_reconstruct_as_the_reference_computes(tmp, n_phi, reduction, jacobian):
    rng = np.random.default_rng(n_phi + 10 * reduction + 100 * jacobian)
    theta = np.sort(rng.uniform(0.05, 1.45, 4)).astype(np.float32)
    phi = (np.linspace(-np.pi, -np.pi + 2 * np.pi / reduction, n_phi).astype(np.float32) if n_phi > 1
           else np.zeros(1, np.float32))
    positive = lambda *shape: rng.uniform(0.2, 2.0, shape).astype(np.float32)
    rgb = rng.uniform(-1.0, 1.5, (n_phi, 4, 3, 6, 7)).astype(np.float32)  # negatives: out-of-gamut values, clipped
    fields = {
        "description": np.frombuffer(b"random tables", np.uint8),
        "jacobian": np.array([jacobian], np.uint8),
        "theta_i": theta, "phi_i": phi,
        "ndf": positive(9, 11), "sigma": positive(5, 4),
        "vndf": positive(n_phi, 4, 7, 5),
        "luminance": positive(n_phi, 4, 6, 7), "rgb": rgb,
    }
    path = tmp / "random.bsdf"
    path.write_bytes(tensor_file_bytes(fields))
    ref = ReferenceRgl(path.read_bytes())
    assert ref.reduction == reduction
    wi, wo = directions(20000, seed=n_phi + 20)
    want, got = ref.fr_cos(wi, wo), brdfkit_fr_cos(path, wi, wo)
    assert (want > 0).mean() > 0.5 and (want == 0).mean() > 0.1  # both sides of the clipping
    # Measured: 5e-8 of the maximum at most, median 1.5e-8 relative (float
    # against double normalisation; relative differences grow only where the
    # interpolated value nears its zero crossing).
    np.testing.assert_allclose(got, want, rtol=0, atol=2e-7 * want.max())
    big = want > 1e-3 * want.max()
    assert np.median(np.abs(got[big] / want[big] - 1)) < 1e-7


def test_the_test_parser_reads_what_brdfkit_writes(tmp):
    path = tmp / "small.bsdf"
    brdfkit.write(path, brdfkit.Model("lambert", {"albedo": 0.5}),
                  rgl={"theta_i": 3, "ndf": 8, "sigma": 4, "vndf": 6, "samples": 5})
    f = parse_tensor_file(path.read_bytes())
    assert set(f) == {"description", "jacobian", "theta_i", "phi_i", "ndf", "sigma", "vndf", "luminance", "rgb"}
    assert f["vndf"].shape == (1, 3, 6, 6) and f["rgb"].shape == (1, 3, 3, 5, 5) and f["jacobian"][0] == 1
    # brdfkit aligns each data block to 8 bytes, this test's writer does not:
    # the same fields either way.
    again = parse_tensor_file(tensor_file_bytes(f))
    assert len(tensor_file_bytes(f)) < len(path.read_bytes())
    for name, a in f.items():
        np.testing.assert_array_equal(again[name], a)


def loaders_refuse(f):
    """What the format's loaders would refuse in an RGB file ({name: array}):
    the structure checks of Mitsuba 3's measured plugin (RGB variants) and of
    the authors' loader powitacq_rgb, restated from their definitions:
    dtypes and ranks, the slice axes of vndf, luminance and rgb, luminance
    and rgb tables square and of one size, a one-byte jacobian, no
    wavelengths (which would make the file spectral); powitacq also refuses
    an anisotropic file whose azimuths span less than the circle."""
    problems = []

    def need(ok, what):
        if not ok:
            problems.append(what)

    for name, ndim, dtype in [("description", 1, np.uint8), ("jacobian", 1, np.uint8), ("theta_i", 1, np.float32),
                              ("phi_i", 1, np.float32), ("ndf", 2, np.float32), ("sigma", 2, np.float32),
                              ("vndf", 4, np.float32), ("luminance", 4, np.float32), ("rgb", 5, np.float32)]:
        need(name in f and f[name].ndim == ndim and f[name].dtype == dtype, f"{name}: rank {ndim}, {dtype.__name__}")
    if problems:
        return problems
    n_phi, n_theta = len(f["phi_i"]), len(f["theta_i"])
    vndf, lum, rgb = f["vndf"].shape, f["luminance"].shape, f["rgb"].shape
    need(vndf[:2] == (n_phi, n_theta), "vndf slices")
    need(lum[:2] == (n_phi, n_theta) and lum[2] == lum[3], "luminance: slices, square")
    need(rgb[:3] == (n_phi, n_theta, 3) and rgb[3] == rgb[4], "rgb: slices, 3 channels, square")
    need(lum[2:] == rgb[3:], "luminance and rgb of one size")
    need(f["jacobian"].shape == (1,), "jacobian: one byte")
    need("wavelengths" not in f, "no wavelengths in an RGB file")
    if n_phi > 2:
        need(np.rint(2 * np.pi / (float(f["phi_i"][-1]) - float(f["phi_i"][0]))) == 1, "azimuths over the circle")
    return problems


@pytest.mark.parametrize("source,rgl", [
    (brdfkit.Model("lambert", {"albedo": 0.5}), None),  # the default isotropic resolution
    (brdfkit.Model("ggx_aniso", {"alpha_x": 0.1, "alpha_y": 0.3}),
     {"theta_i": 4, "ndf": 16, "sigma": 8, "vndf": 12, "vndf_theta": 10, "samples": 9}),
])
def test_the_format_loaders_accept_what_brdfkit_writes(tmp, source, rgl):
    path = tmp / "written.bsdf"
    brdfkit.write(path, source, rgl=rgl)
    f = parse_tensor_file(path.read_bytes())
    assert loaders_refuse(f) == []
    # A file of a quarter of the azimuths passes Mitsuba 3's checks; powitacq
    # refuses it, as brdfkit's help and README say.
    if rgl is not None:
        reduced = tmp / "reduced.bsdf"
        brdfkit.write(reduced, source, rgl={**rgl, "phi_i": 5, "symmetry": 4})
        assert loaders_refuse(parse_tensor_file(reduced.read_bytes())) == ["azimuths over the circle"]
    # The check itself refuses the tables brdfkit wrote before they were square.
    f["rgb"], f["luminance"] = f["rgb"][..., :-1], f["luminance"][..., :-1]
    assert loaders_refuse(f) == ["luminance: slices, square", "rgb: slices, 3 channels, square"]
