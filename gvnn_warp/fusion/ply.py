"""Binary PLY files (little-endian) of meshes and point clouds, as MeshLab, Open3D and Blender read them."""

from __future__ import annotations

from pathlib import Path

import numpy as np

__all__ = ["read_ply", "write_ply"]


def write_ply(path: str | Path, vertices: np.ndarray, faces: np.ndarray | None = None,
              colours: np.ndarray | None = None, comment: str | None = None) -> None:
    """Write ``vertices`` (N, 3) (float32 x, y, z), optional ``colours`` (N, 3) in [0, 1] (stored as
    8-bit red, green, blue) and optional ``faces`` (M, 3) vertex indices (a triangle list) to ``path``."""
    v = np.asarray(vertices, dtype=np.float32).reshape(-1, 3)
    fields = [("x", "<f4"), ("y", "<f4"), ("z", "<f4")]
    if colours is not None:
        fields += [("red", "u1"), ("green", "u1"), ("blue", "u1")]
    rows = np.empty(v.shape[0], dtype=fields)
    rows["x"], rows["y"], rows["z"] = v[:, 0], v[:, 1], v[:, 2]
    if colours is not None:
        c = np.clip(np.round(np.asarray(colours, dtype=np.float64).reshape(-1, 3) * 255.0), 0, 255).astype(np.uint8)
        if c.shape[0] != v.shape[0]:
            raise ValueError(f"write_ply: {c.shape[0]} colours for {v.shape[0]} vertices")
        rows["red"], rows["green"], rows["blue"] = c[:, 0], c[:, 1], c[:, 2]
    header = ["ply", "format binary_little_endian 1.0"]
    if comment:
        header.append(f"comment {comment}")
    header += [f"element vertex {v.shape[0]}", "property float x", "property float y", "property float z"]
    if colours is not None:
        header += ["property uchar red", "property uchar green", "property uchar blue"]
    tri = None
    if faces is not None:
        f = np.asarray(faces).reshape(-1, 3)
        if f.size and (f.min() < 0 or f.max() >= v.shape[0]):
            raise ValueError(f"write_ply: face indices must be in [0, {v.shape[0]}), got [{f.min()}, {f.max()}]")
        tri = np.empty(f.shape[0], dtype=[("n", "u1"), ("i", "<i4", (3,))])
        tri["n"], tri["i"] = 3, f
        header += [f"element face {f.shape[0]}", "property list uchar int vertex_indices"]
    header.append("end_header")
    with open(path, "wb") as out:
        out.write(("\n".join(header) + "\n").encode("ascii"))
        out.write(rows.tobytes())
        if tri is not None:
            out.write(tri.tobytes())


def read_ply(path: str | Path) -> tuple[np.ndarray, np.ndarray | None, np.ndarray | None]:
    """Read back a file of :func:`write_ply`: (vertices (N, 3) float32, faces (M, 3) int32 or None,
    colours (N, 3) float32 in [0, 1] or None). Only that layout is understood."""
    data = Path(path).read_bytes()
    end = data.index(b"end_header\n") + len(b"end_header\n")
    lines = data[:end].decode("ascii").splitlines()
    if lines[:2] != ["ply", "format binary_little_endian 1.0"]:
        raise ValueError(f"read_ply: {path}: not a binary little-endian PLY")
    n_v = next(int(x.split()[-1]) for x in lines if x.startswith("element vertex"))
    n_f = next((int(x.split()[-1]) for x in lines if x.startswith("element face")), None)
    has_colour = "property uchar red" in lines
    fields = [("x", "<f4"), ("y", "<f4"), ("z", "<f4")]
    fields += [("r", "u1"), ("g", "u1"), ("b", "u1")] if has_colour else []
    rows = np.frombuffer(data, dtype=fields, count=n_v, offset=end)
    v = np.stack([rows["x"], rows["y"], rows["z"]], 1)
    c = np.stack([rows["r"], rows["g"], rows["b"]], 1).astype(np.float32) / 255 if has_colour else None
    f = None
    if n_f is not None:
        tri = np.frombuffer(data, dtype=[("n", "u1"), ("i", "<i4", (3,))], count=n_f, offset=end + rows.nbytes)
        f = tri["i"].astype(np.int32)
    return v, f, c
