"""One place to add an op: every registered op (warp_op or custom_op in gvnn_warp/ops/) must have
what a user and the tests need, and this test lists what is missing for each (see
CONTRIBUTING.md, "Adding an op")."""

from pathlib import Path

from gvnn_warp.kernels.core import kinds
from op_samples import OPS, op_samples

import gvnn_warp

API_DOC = (Path(__file__).resolve().parents[2] / "docs" / "api.md").read_text()


def missing_for(name, spec, samples):
    missing = []
    function, layer = spec.function, spec.layer
    if function not in gvnn_warp.__all__ or not callable(getattr(gvnn_warp, function, None)):
        missing.append(f"public function gvnn_warp.{function} (in a module of gvnn_warp/functional/, in its __all__)")
    if f"### `{function}(" not in API_DOC:
        missing.append(f"docs/api.md entry for {function} (run python docs/gen_api.py)")
    if layer[:1].isupper():
        if layer not in gvnn_warp.__all__:
            missing.append(f"layer gvnn_warp.{layer} (in a module of gvnn_warp/nn/, in its __all__)")
        elif f"### `{layer}(" not in API_DOC:
            missing.append(f"docs/api.md entry for {layer}")
    elif not layer.startswith("no layer: "):
        missing.append("a layer, or layer='no layer: <why>' in its registration")
    if name not in samples:
        missing.append("sample arguments in tests/op_samples.py (opcheck, AOT/compile and scope tests use them)")
    for test, why in spec.untested.items():
        if test not in ("scopes", "gradients") or not why:
            missing.append(f"untested={{{test!r}: ...}}: a test of tests/ops/test_compile.py or test_scopes.py, "
                           "and why")
    params = samples[name][len(spec.inputs):] if name in samples else None
    kernels = [spec.kernel_for(params), spec.backward_kernel_for(params)] if params is not None else []
    for fk in kernels:
        if fk is not None and fk not in kinds.registered():
            missing.append(f"FloatKernel(...).set_parallel(...) declaration of {fk.kernel.key}")
    return missing


def test_every_op_has_everything():
    samples = op_samples()
    report = {}
    for name, spec in sorted(OPS.items()):
        missing = missing_for(name, spec, samples)
        if missing:
            report[name] = missing
    assert not report, "ops missing parts:\n" + "\n".join(f"  {n}: {', '.join(m)}" for n, m in report.items())


def test_a_new_op_without_its_parts_is_listed():
    """The check itself: an op registered with nothing else gets every missing part listed."""
    import dataclasses

    spec = dataclasses.replace(OPS["so3_exp"], name="new_op", function="new_function", layer="NewLayer",
                               untested={"opcheck": ""})
    missing = missing_for("new_op", spec, {})
    assert len(missing) == 5, missing
    assert any("gvnn_warp.new_function" in m for m in missing) and any("NewLayer" in m for m in missing)
    assert any("op_samples" in m for m in missing) and any("untested" in m for m in missing)


def test_every_torch_op_is_registered():
    """Every gvnn_warp::* torch op is in OPS, or is the backward op of one (defining the lazy ones)."""
    import torch

    from gvnn_warp.ops import lens  # noqa: F401  (defines the ops through lens models)

    defined = {n.split("::")[1] for n in torch._C._dispatch_get_all_op_names() if n.startswith("gvnn_warp::")}
    assert set(OPS) <= defined
    backward = {n for n in defined if n.endswith("_backward") and n.removesuffix("_backward") in OPS}
    assert defined - backward == set(OPS), sorted(defined - backward - set(OPS))
