"""Triangle meshes: OBJ / STL (ASCII or binary) / PLY (ASCII or binary) readers and procedural
surfaces (height fields, steps, random smooth blobs), all as ``(vertices (V,3), faces (F,3))``
float64 / int64 numpy arrays in the object's own units.
"""
from __future__ import annotations

import struct
from pathlib import Path

import numpy as np

from ..errors import SynthError


def load_mesh(path) -> tuple[np.ndarray, np.ndarray]:
    """Read an OBJ, STL or PLY file -> (vertices (V,3) float64, faces (F,3) int64). Polygons are
    fanned into triangles. Raises SynthError naming the file and the defect."""
    path = Path(path)
    if not path.is_file():
        raise SynthError(f"mesh file {path}: no such file")
    suffix = path.suffix.lower()
    try:
        if suffix == ".obj":
            V, F = _read_obj(path)
        elif suffix == ".stl":
            V, F = _read_stl(path)
        elif suffix == ".ply":
            V, F = _read_ply(path)
        else:
            raise SynthError(f"mesh file {path}: unsupported format {suffix!r} (OBJ, STL, PLY)")
    except SynthError:
        raise
    except (ValueError, IndexError, struct.error, UnicodeDecodeError) as exc:
        raise SynthError(f"mesh file {path}: cannot be parsed ({exc})") from None
    if V.shape[0] == 0 or F.shape[0] == 0:
        raise SynthError(f"mesh file {path}: no vertices or no faces")
    if F.min() < 0 or F.max() >= V.shape[0]:
        raise SynthError(f"mesh file {path}: face index out of range [0, {V.shape[0]})")
    if not np.all(np.isfinite(V)):
        raise SynthError(f"mesh file {path}: non-finite vertex coordinates")
    return V, F


def _fan(polys) -> np.ndarray:
    tris = [(p[0], p[i], p[i + 1]) for p in polys for i in range(1, len(p) - 1)]
    return np.asarray(tris, dtype=np.int64).reshape(-1, 3)


def _read_obj(path):
    verts, polys = [], []
    with open(path, "r", errors="replace") as fh:
        for line in fh:
            if line.startswith("v "):
                verts.append([float(x) for x in line.split()[1:4]])
            elif line.startswith("f "):
                idx = [int(tok.split("/")[0]) for tok in line.split()[1:]]
                n = len(verts)
                polys.append([i - 1 if i > 0 else n + i for i in idx])
    return np.asarray(verts, dtype=np.float64).reshape(-1, 3), _fan(polys)


def _read_stl(path):
    data = path.read_bytes()
    if len(data) >= 84:
        n = struct.unpack("<I", data[80:84])[0]
        if 84 + 50 * n == len(data):
            rec = np.frombuffer(data, dtype=np.dtype([("n", "<f4", 3), ("v", "<f4", (3, 3)), ("a", "<u2")]),
                                count=n, offset=84)
            V = rec["v"].reshape(-1, 3).astype(np.float64)
            return V, np.arange(3 * n, dtype=np.int64).reshape(-1, 3)
    text = data.decode("ascii")
    V = [[float(x) for x in ln.split()[1:4]] for ln in text.splitlines() if ln.strip().startswith("vertex")]
    V = np.asarray(V, dtype=np.float64).reshape(-1, 3)
    if V.shape[0] % 3:
        raise SynthError(f"mesh file {path}: ASCII STL vertex count {V.shape[0]} not a multiple of 3")
    return V, np.arange(V.shape[0], dtype=np.int64).reshape(-1, 3)


_PLY_TYPES = {"char": "i1", "uchar": "u1", "short": "i2", "ushort": "u2", "int": "i4", "uint": "u4",
              "float": "f4", "double": "f8", "int8": "i1", "uint8": "u1", "int16": "i2", "uint16": "u2",
              "int32": "i4", "uint32": "u4", "float32": "f4", "float64": "f8"}


def _read_ply(path):
    data = path.read_bytes()
    end = data.find(b"end_header")
    if not data.startswith(b"ply") or end < 0:
        raise SynthError(f"mesh file {path}: not a PLY file (no 'ply' magic / end_header)")
    header = data[:end].decode("ascii").splitlines()
    body_start = data.index(b"\n", end) + 1
    fmt, elements = None, []
    for ln in header:
        tok = ln.split()
        if not tok:
            continue
        if tok[0] == "format":
            fmt = tok[1]
        elif tok[0] == "element":
            elements.append([tok[1], int(tok[2]), []])
        elif tok[0] == "property":
            elements[-1][2].append(tok[1:])
    if fmt not in ("ascii", "binary_little_endian", "binary_big_endian"):
        raise SynthError(f"mesh file {path}: PLY format {fmt!r} unsupported")
    V = F = None
    if fmt == "ascii":
        lines = data[body_start:].decode("ascii").split("\n")
        pos = 0
        for name, count, props in elements:
            rows = lines[pos:pos + count]
            pos += count
            if name == "vertex":
                names = [p[-1] for p in props]
                arr = np.array([[float(x) for x in r.split()[:len(names)]] for r in rows])
                V = arr[:, [names.index("x"), names.index("y"), names.index("z")]]
            elif name == "face":
                F = _fan([[int(x) for x in r.split()[1:1 + int(r.split()[0])]] for r in rows])
        return V, F
    end_ch = "<" if fmt == "binary_little_endian" else ">"
    off = body_start
    for name, count, props in elements:
        if any(p[0] == "list" for p in props):
            if len(props) != 1:
                raise SynthError(f"mesh file {path}: PLY element {name!r} mixes lists and scalars")
            _, ct, it, _pname = props[0]
            ct_dt, it_dt = np.dtype(end_ch + _PLY_TYPES[ct]), np.dtype(end_ch + _PLY_TYPES[it])
            polys = []
            for _ in range(count):
                n = int(np.frombuffer(data, ct_dt, 1, off)[0])
                off += ct_dt.itemsize
                polys.append(np.frombuffer(data, it_dt, n, off).astype(np.int64).tolist())
                off += n * it_dt.itemsize
            if name == "face":
                F = _fan(polys)
        else:
            dt = np.dtype([(p[1], end_ch + _PLY_TYPES[p[0]]) for p in props])
            arr = np.frombuffer(data, dt, count, off)
            off += dt.itemsize * count
            if name == "vertex":
                V = np.stack([arr["x"], arr["y"], arr["z"]], axis=1).astype(np.float64)
    return V, F


# -- procedural surfaces (object frame: z up = height, mm) -------------------------------------

def grid_mesh(xs: np.ndarray, ys: np.ndarray, heights: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Height field ``z = heights[iy, ix]`` over grid coordinates ``xs`` (nx,), ``ys`` (ny,) (mm)."""
    X, Y = np.meshgrid(xs, ys)
    V = np.stack([X.ravel(), Y.ravel(), np.asarray(heights, dtype=np.float64).ravel()], axis=1)
    nx, ny = xs.size, ys.size
    i = np.arange(ny - 1)[:, None] * nx + np.arange(nx - 1)[None, :]
    a, b, c, d = i, i + 1, i + nx, i + nx + 1
    F = np.concatenate([np.stack([a, b, d], -1).reshape(-1, 3), np.stack([a, d, c], -1).reshape(-1, 3)])
    return V, F.astype(np.int64)


def heightfield_mesh(heights, size_mm) -> tuple[np.ndarray, np.ndarray]:
    """A (ny, nx) height array (mm) spread over ``size_mm = (w, h)`` centred at the origin."""
    H = np.asarray(heights, dtype=np.float64)
    if H.ndim != 2 or min(H.shape) < 2 or not np.all(np.isfinite(H)):
        raise SynthError(f"heightfield.heights: expected a finite 2-D array of at least 2x2, got shape {H.shape}")
    w, h = size_mm
    return grid_mesh(np.linspace(-w / 2, w / 2, H.shape[1]), np.linspace(-h / 2, h / 2, H.shape[0]), H)


def steps_mesh(size_mm, heights_mm, resolution: int = 2) -> tuple[np.ndarray, np.ndarray]:
    """A staircase: ``len(heights_mm)`` equal bands along x with vertical walls between them."""
    w, h = size_mm
    hs = [float(v) for v in heights_mm]
    if not hs:
        raise SynthError("steps.heights_mm: expected at least one height")
    edges = np.linspace(-w / 2, w / 2, len(hs) + 1)
    xs, zs = [], []
    for k, z in enumerate(hs):  # every wall gets two vertices at the same x
        xs += [edges[k], edges[k + 1]]
        zs += [z, z]
    ys = np.linspace(-h / 2, h / 2, max(2, int(resolution)))
    return grid_mesh(np.asarray(xs), ys, np.tile(np.asarray(zs), (ys.size, 1)))


def blobs_heights(size_mm, resolution, count: int, amplitude_mm: float, width_mm: float, seed: int) -> np.ndarray:
    """Random smooth surface: a sum of ``count`` Gaussian bumps (seeded) -> (ny, nx) heights."""
    rng = np.random.default_rng(seed)
    w, h = size_mm
    nx, ny = resolution
    X, Y = np.meshgrid(np.linspace(-w / 2, w / 2, nx), np.linspace(-h / 2, h / 2, ny))
    Z = np.zeros_like(X)
    for _ in range(int(count)):
        c = rng.uniform([-w / 2, -h / 2], [w / 2, h / 2])
        a = amplitude_mm * rng.uniform(-1, 1)
        s = width_mm * rng.uniform(0.5, 1.5)
        Z += a * np.exp(-((X - c[0]) ** 2 + (Y - c[1]) ** 2) / (2 * s * s))
    return Z


def sphere_mesh(radius: float, n_lon: int = 64, n_lat: int = 32) -> tuple[np.ndarray, np.ndarray]:
    """A UV sphere (used for tests and Blender; the renderer's sphere is analytic)."""
    th = np.linspace(0, np.pi, n_lat + 1)
    ph = np.linspace(0, 2 * np.pi, n_lon + 1)
    T, P = np.meshgrid(th, ph, indexing="ij")
    V = radius * np.stack([np.sin(T) * np.cos(P), np.sin(T) * np.sin(P), np.cos(T)], -1).reshape(-1, 3)
    _, F = grid_mesh(np.arange(n_lon + 1.0), np.arange(n_lat + 1.0), np.zeros((n_lat + 1, n_lon + 1)))
    return V, F
