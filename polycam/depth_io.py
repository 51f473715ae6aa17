"""Depth files: PLY point clouds, PFM float maps, 16-bit millimetre PNGs and the
``polycam depth`` output folder (docs/formats.md, "Depth output").

Every writer is atomic (a temporary name, then ``os.replace``). Readers are here so
tests and users can parse the files back without other tools (``cv2.imread`` reads the
PFMs and PNGs as well).
"""

from __future__ import annotations

import io
import os
from pathlib import Path

import numpy as np

from .errors import FormatError
from .tomlio import atomic_write_bytes, atomic_write_text

__all__ = ["write_ply", "read_ply", "write_pfm", "read_pfm", "write_png16", "read_png16",
           "write_depth_folder", "MM_PER_UNIT", "PNG_MAX_MM"]

MM_PER_UNIT = 1000.0
"""16-bit PNG depth maps store Z in millimetres."""
PNG_MAX_MM = 65535
"""Largest storable depth [mm]; deeper rays are clamped to it; 0 = no estimate."""


# ----------------------------------------------------------------------------- PLY


def write_ply(path: str | os.PathLike, points, values=None, *, confidence=None, binary: bool = False,
              comment: str = "polycam: rig frame [m]") -> None:
    """PLY point cloud: ``points`` (N, 3) [m]; optional ``values`` (N,) grey or (N, 3) RGB
    in [0, 1] written as uchar red/green/blue; optional ``confidence`` (N,) as a float
    property. ASCII by default, ``binary=True`` for binary little-endian (float32 x y z)."""
    P = np.asarray(points, float).reshape(-1, 3)
    n = len(P)
    cols = None
    if values is not None:
        v = np.asarray(values, float)
        v = np.repeat(v.reshape(-1, 1), 3, axis=1) if v.ndim == 1 or v.shape[-1] != 3 else v.reshape(-1, 3)
        if len(v) != n:
            raise ValueError(f"{len(v)} colours for {n} points")
        cols = np.clip(np.round(v * 255), 0, 255).astype(np.uint8)
    conf = None if confidence is None else np.asarray(confidence, np.float32).reshape(-1)
    if conf is not None and len(conf) != n:
        raise ValueError(f"{len(conf)} confidences for {n} points")
    head = [f"ply\nformat {'binary_little_endian' if binary else 'ascii'} 1.0\n"]
    for line in comment.splitlines():
        head.append(f"comment {line}\n")
    head.append(f"element vertex {n}\nproperty float x\nproperty float y\nproperty float z\n")
    if cols is not None:
        head.append("property uchar red\nproperty uchar green\nproperty uchar blue\n")
    if conf is not None:
        head.append("property float confidence\n")
    head.append("end_header\n")
    header = "".join(head)
    if binary:
        fields = [("x", "<f4"), ("y", "<f4"), ("z", "<f4")]
        if cols is not None:
            fields += [("red", "u1"), ("green", "u1"), ("blue", "u1")]
        if conf is not None:
            fields += [("confidence", "<f4")]
        rec = np.empty(n, dtype=fields)
        rec["x"], rec["y"], rec["z"] = P[:, 0], P[:, 1], P[:, 2]
        if cols is not None:
            rec["red"], rec["green"], rec["blue"] = cols[:, 0], cols[:, 1], cols[:, 2]
        if conf is not None:
            rec["confidence"] = conf
        atomic_write_bytes(path, header.encode("ascii") + rec.tobytes())
        return
    buf = io.StringIO()
    buf.write(header)
    parts = [P]
    fmt = ["%.5f"] * 3
    if cols is not None:
        parts.append(cols.astype(float))
        fmt += ["%d"] * 3
    if conf is not None:
        parts.append(conf.astype(float)[:, None])
        fmt += ["%.6g"]
    if n:
        np.savetxt(buf, np.column_stack(parts), fmt=fmt)
    atomic_write_text(path, buf.getvalue())


_PLY_TYPES = {"float": "<f4", "float32": "<f4", "double": "<f8", "float64": "<f8", "uchar": "u1",
              "uint8": "u1", "char": "i1", "int8": "i1", "ushort": "<u2", "uint16": "<u2", "short": "<i2",
              "int16": "<i2", "uint": "<u4", "uint32": "<u4", "int": "<i4", "int32": "<i4"}


def read_ply(path: str | os.PathLike) -> dict[str, np.ndarray]:
    """Vertex properties of a PLY file (ASCII or binary little-endian, vertex element with
    scalar properties only, as :func:`write_ply` writes): property name → (N,) array."""
    path = Path(path)
    data = path.read_bytes()
    end = data.find(b"end_header\n")
    if not data.startswith(b"ply\n") or end < 0:
        raise FormatError(path, "not a PLY file (no 'ply' / 'end_header')")
    lines = data[:end].decode("ascii", "replace").splitlines()
    body = data[end + len(b"end_header\n"):]
    fmt, n, props, in_vertex = None, None, [], False
    for line in lines[1:]:
        tok = line.split()
        if not tok or tok[0] == "comment":
            continue
        if tok[0] == "format":
            fmt = tok[1]
        elif tok[0] == "element":
            in_vertex = tok[1] == "vertex"
            if in_vertex:
                n = int(tok[2])
            elif n is None:
                raise FormatError(path, f"element {tok[1]!r} before the vertices is not supported")
        elif tok[0] == "property" and in_vertex:
            if tok[1] == "list" or tok[1] not in _PLY_TYPES:
                raise FormatError(path, f"unsupported property {' '.join(tok[1:])!r}")
            props.append((tok[2], _PLY_TYPES[tok[1]]))
    if n is None or fmt not in ("ascii", "binary_little_endian"):
        raise FormatError(path, f"need a vertex element and ascii / binary_little_endian format, got {fmt!r}")
    if fmt == "ascii":
        rows = np.loadtxt(io.StringIO(body.decode("ascii")), ndmin=2) if n else np.zeros((0, len(props)))
        if rows.shape != (n, len(props)):
            raise FormatError(path, f"expected {n} vertices of {len(props)} values, got {rows.shape}")
        return {name: rows[:, i].astype(dt) for i, (name, dt) in enumerate(props)}
    rec = np.frombuffer(body, dtype=np.dtype(props), count=n)
    return {name: np.array(rec[name]) for name, _ in props}


# ----------------------------------------------------------------------------- PFM / PNG


def write_pfm(path: str | os.PathLike, image) -> None:
    """Grey PFM (``Pf``, little-endian float32, rows stored bottom to top as the format
    requires); ``image`` (H, W) with row 0 at the top. NaN is stored as NaN."""
    a = np.asarray(image, np.float32)
    if a.ndim != 2:
        raise ValueError(f"PFM image must be (H, W), got {a.shape}")
    H, W = a.shape
    header = f"Pf\n{W} {H}\n-1.0\n".encode("ascii")
    atomic_write_bytes(path, header + np.ascontiguousarray(a[::-1]).astype("<f4").tobytes())


def read_pfm(path: str | os.PathLike) -> np.ndarray:
    """(H, W) float32 of a grey PFM file (row 0 at the top)."""
    path = Path(path)
    data = path.read_bytes()
    parts = data.split(b"\n", 3)
    if len(parts) < 4 or parts[0].strip() != b"Pf":
        raise FormatError(path, "not a grey PFM file (expected 'Pf')")
    try:
        W, H = (int(t) for t in parts[1].split())
        scale = float(parts[2])
    except ValueError:
        raise FormatError(path, "bad PFM header") from None
    dt = "<f4" if scale < 0 else ">f4"
    if len(parts[3]) != 4 * W * H:
        raise FormatError(path, f"expected {W}x{H} float32 samples, got {len(parts[3])} bytes")
    return np.frombuffer(parts[3], dtype=dt).reshape(H, W)[::-1].astype(np.float32)


def write_png16(path: str | os.PathLike, Z) -> None:
    """16-bit grey PNG of depth ``Z`` (H, W) [m] in millimetres (0 = no estimate / NaN,
    clamped to :data:`PNG_MAX_MM`)."""
    import cv2

    z = np.asarray(Z, float)
    mm = np.where(np.isfinite(z) & (z > 0), np.clip(np.round(z * MM_PER_UNIT), 1, PNG_MAX_MM), 0)
    ok, buf = cv2.imencode(".png", mm.astype(np.uint16))
    if not ok:
        raise OSError(f"PNG encoding failed for {path}")
    atomic_write_bytes(path, buf.tobytes())


def read_png16(path: str | os.PathLike) -> np.ndarray:
    """(H, W) float32 depth [m] of a :func:`write_png16` file (NaN where 0)."""
    import cv2

    a = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if a is None or a.dtype != np.uint16 or a.ndim != 2:
        raise FormatError(path, "not a 16-bit grey PNG")
    return np.where(a > 0, a.astype(np.float32) / np.float32(MM_PER_UNIT), np.nan).astype(np.float32)


# ----------------------------------------------------------------------------- output folder


def write_depth_folder(out: str | os.PathLike, grid, dm, *, intensity, mask, views: np.ndarray,
                       meta: dict, binary_ply: bool = True) -> dict:
    """The ``polycam depth`` folder (docs/formats.md, "Depth output").

    ``grid``: the LightFieldGrid; ``dm``: :class:`polycam.depth.DepthMap`; ``intensity``
    (F, Ny, Nx, Nv, Nu) or with a trailing colour axis, values in [0, 1] of frame I (PLY
    colours); ``mask`` (F, Ny, Nx, Nv, Nu) bool: the rays kept (confident); ``views``
    (F, Ny, Nx) bool: the viewpoints to write maps for and take points from; ``meta``:
    extra ``[depth]`` keys for depth.toml (TOML-serialisable). Returns a summary dict.
    """
    import tomli_w

    from .depth import depth_points

    out = Path(out)
    (out / "views").mkdir(parents=True, exist_ok=True)
    F, Ny, Nx, Nv, Nu = grid.shape
    Zkeep = np.where(mask, dm.Z, np.nan).astype(np.float32)
    files = []
    for k, j, i in zip(*np.nonzero(views)):
        d = out / "views" / f"face{k}"
        d.mkdir(exist_ok=True)
        stem = f"y{j:02d}_x{i:02d}"
        write_pfm(d / f"{stem}_depth.pfm", Zkeep[k, j, i])
        write_png16(d / f"{stem}_depth_mm.png", Zkeep[k, j, i])
        write_pfm(d / f"{stem}_confidence.pfm", dm.confidence[k, j, i])
        files.append(f"views/face{k}/{stem}")
    sel = mask & views[..., None, None]
    P, idx = depth_points(dm, grid, sel)
    inten = np.asarray(intensity, np.float32)
    vals = inten.reshape(-1, inten.shape[-1])[idx] if inten.ndim == 6 else inten.reshape(-1)[idx]
    conf = dm.confidence.reshape(-1)[idx]
    write_ply(out / "points.ply", P, vals, confidence=conf, binary=binary_ply,
              comment="polycam depth: points in the rig frame of frame I [m], colour = intensity")
    doc = {"depth": {**meta, "points": int(len(P)), "views_written": len(files),
                     "Z": "metres along the face z axis from its focal plane (view z-depth)",
                     "png_unit_mm": 1.0, "png_no_estimate": 0},
           "grid": grid.attrs(),
           "views": [{"face": int(k), "face_name": grid.faces[k].name, "y_index": int(j), "x_index": int(i),
                      "x": float(grid.x.values[i]), "y": float(grid.y.values[j]), "files": f}
                     for (k, j, i), f in zip(zip(*np.nonzero(views)), files)]}
    atomic_write_text(out / "depth.toml", tomli_w.dumps(doc))
    zc = Zkeep[sel]
    return {"points": int(len(P)), "views": len(files),
            "median_depth_m": float(np.median(zc)) if zc.size else float("nan"),
            "confident_fraction": float(np.mean(mask[views])) if views.any() else 0.0}
