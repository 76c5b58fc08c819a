"""One place to add an op: every op registered with warp_op must have what a user and the tests
need, and this test lists what is missing for each (see CONTRIBUTING.md, "Adding an op")."""

from pathlib import Path

from gvnn_warp.kernels.core import kinds
from op_samples import op_samples

import gvnn_warp
from gvnn_warp.ops import bridge as _bridge  # noqa: F401  (registers every op)
from gvnn_warp.ops import geometry as _ops
from gvnn_warp.ops import perpixel as _perpixel_ops
from gvnn_warp.ops import photometric as _photometric_ops

API_DOC = (Path(__file__).resolve().parents[1] / "docs" / "api.md").read_text()


def missing_for(name, spec, public, samples):
    missing = []
    if name not in public:
        return ["an entry in PUBLIC of _ops.py, _perpixel_ops.py or _photometric_ops.py (public function, layer)"]
    function, layer = public[name]
    if function not in gvnn_warp.__all__ or not callable(getattr(gvnn_warp, function, None)):
        missing.append(f"public function gvnn_warp.{function} (functional.py or perpixel.py, listed in __init__.py)")
    if f"### `{function}(" not in API_DOC:
        missing.append(f"docs/api.md entry for {function} (run python docs/gen_api.py)")
    if layer[:1].isupper():
        if layer not in gvnn_warp.__all__:
            missing.append(f"layer gvnn_warp.{layer} (layers.py or perpixel_layers.py, listed in __init__.py)")
        elif f"### `{layer}(" not in API_DOC:
            missing.append(f"docs/api.md entry for {layer}")
    elif not layer.startswith("no layer: "):
        missing.append("a layer, or 'no layer: <why>' in PUBLIC")
    if name not in samples:
        missing.append("sample arguments in tests/op_samples.py (opcheck, AOT/compile and scope tests use them)")
    kernels = [spec.fk, spec.backward_kernel] if spec.select is None else [spec.backward_kernel]
    for fk in kernels:
        if fk is not None and fk not in kinds.registered():
            missing.append(f"FloatKernel(...).set_parallel(...) declaration of {fk.kernel.key}")
    return missing


def test_every_op_has_everything():
    public = {**_ops.PUBLIC, **_perpixel_ops.PUBLIC, **_photometric_ops.PUBLIC}
    samples = op_samples()
    report = {}
    for name, spec in sorted(_bridge.OPS.items()):
        missing = missing_for(name, spec, public, samples)
        if missing:
            report[name] = missing
    assert not report, "ops missing parts:\n" + "\n".join(f"  {n}: {', '.join(m)}" for n, m in report.items())
    assert set(public) <= set(_bridge.OPS), f"PUBLIC names ops that do not exist: {set(public) - set(_bridge.OPS)}"


def test_a_new_op_without_its_parts_is_listed():
    """The check itself: an op registered with nothing else gets every missing part listed."""
    spec = _bridge.OPS["so3_exp"]
    missing = missing_for("new_op", spec, {"new_op": ("new_function", "NewLayer")}, {})
    assert len(missing) == 4, missing
    assert any("gvnn_warp.new_function" in m for m in missing) and any("NewLayer" in m for m in missing)
    assert any("op_samples" in m for m in missing)
