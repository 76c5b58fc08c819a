"""Write docs/api.md, the API reference, from the public functions' and layers' docstrings.

Run ``python docs/gen_api.py`` after changing a docstring; a test checks the file is current.
"""

from __future__ import annotations

import importlib
import inspect
import sys
from pathlib import Path

SECTIONS = [
    ("Global transformations: rotations, rigid motions, similarities", "gvnn_warp.functional.lie"),
    ("The pinhole camera: the 3D grid generator, projection", "gvnn_warp.functional.camera"),
    ("Sampling: the bilinear sampler and the 3D spatial transformer", "gvnn_warp.functional.sampling"),
    ("Camera models: pinhole, radial-tangential, fisheye", "gvnn_warp.cameras"),
    ("Per-pixel transformations, M-estimators and smoothness", "gvnn_warp.functional.perpixel"),
    ("The fused photometric objective (direct RGB-D alignment)", "gvnn_warp.functional.photometric"),
    ("Depth and motion without labels: the reprojection objective, smoothness", "gvnn_warp.functional.reprojection"),
    ("Layers of the global transformations (nn.Module)", "gvnn_warp.nn.lie"),
    ("Layers of the pinhole camera (nn.Module)", "gvnn_warp.nn.camera"),
    ("Sampling layers (nn.Module)", "gvnn_warp.nn.sampling"),
    ("Per-pixel layers (nn.Module)", "gvnn_warp.nn.perpixel"),
    ("The photometric loss layer (nn.Module)", "gvnn_warp.nn.photometric"),
    ("The reprojection and smoothness layers (nn.Module)", "gvnn_warp.nn.reprojection"),
    ("Threads and diagnostics", "gvnn_warp", ["get_num_threads", "info", "set_num_threads"]),
    (
        "Pure Warp: the fused photometric objective on wp.arrays (from gvnn_warp.kernels, no torch)",
        "gvnn_warp.kernels.photometric.pipeline",
        ["NormalEquations", "photometric_error", "photometric_normal_equations"],
    ),
    ("Direct RGB-D odometry (from gvnn_warp.odometry; numpy or torch, no torch needed)", "gvnn_warp.odometry"),
    ("Dense fusion: a TSDF in hashed voxel blocks (from gvnn_warp.fusion; no torch)", "gvnn_warp.fusion"),
]
# the sections up to this one document names that gvnn_warp itself exports
_TOP_LEVEL = next(i for i, (_, modname, *_) in enumerate(SECTIONS) if modname == "gvnn_warp") + 1
_COUNT = ("zero one two three four five six seven eight nine ten eleven twelve thirteen fourteen fifteen "
          "sixteen").split()


def render() -> str:
    out = [
        "# API reference",
        "",
        "Generated from the docstrings by `docs/gen_api.py`. Conventions (pixel centres, (x, y) order,",
        "`[omega, t]` order, quaternion order, units, valid masks, minimum depth):",
        "[conventions.md](conventions.md). Each section names the module it documents; the functions",
        f"and layers of the first {_COUNT[_TOP_LEVEL]} (all but the cameras' base class `Camera`) are also importable",
        "from `gvnn_warp` itself.",
        "",
    ]
    for title, modname, *names in SECTIONS:
        mod = importlib.import_module(modname)
        out += [f"## {title}", "", f"`{modname}`", ""]
        for name in sorted(names[0] if names else mod.__all__):
            obj = getattr(mod, name)
            if not (inspect.isfunction(obj) or inspect.isclass(obj)):
                continue
            try:
                sig = str(inspect.signature(obj)).replace("torch.Tensor", "Tensor")
            except ValueError:  # (an exception class: no signature of its own)
                sig = ""
            if inspect.isclass(obj) and sig == "(*args: Any, **kwargs: Any) -> None":
                sig = "()"  # (a layer with no constructor arguments: nn.Module's own __init__)
            out += [f"### `{name}{sig}`", "", inspect.cleandoc(obj.__doc__ or "(undocumented)"), ""]
            if inspect.isclass(obj) and getattr(obj, "forward", None) and obj.forward.__doc__:
                out += [inspect.cleandoc(obj.forward.__doc__), ""]
    return "\n".join(out)


if __name__ == "__main__":
    path = Path(__file__).with_name("api.md")
    path.write_text(render())
    print(f"wrote {path}", file=sys.stderr)
