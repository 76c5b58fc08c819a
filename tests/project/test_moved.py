"""The module paths of earlier releases keep working (kernels/core/moved.py): each old path imports
as its new module, or, where the old module's names now live in several, as a module that finds
each of their public names; old names reach the same objects as the new paths."""

import importlib
import json

import gvnn_warp.kernels as gk
import pytest
from processes import run_python

import gvnn_warp

OLD = [(f"gvnn_warp.{old}", new, "gvnn_warp") for old, new in gvnn_warp._MOVED.items()] + [
    (f"gvnn_warp.kernels.{old}", new, "gvnn_warp.kernels") for old, new in gk._MOVED.items()]


@pytest.mark.parametrize("old, new, package", OLD, ids=[o for o, _, _ in OLD])
def test_old_path_imports_as_its_new_modules(old, new, package):
    module = importlib.import_module(old)
    if isinstance(new, str):
        assert module is importlib.import_module(f"{package}.{new}")
        return
    sources = [importlib.import_module(f"{package}.{s}") for s in new]
    names = [n for source in sources for n in getattr(source, "__all__", ())]
    for name in names:  # found in the first source that has it
        assert getattr(module, name) is getattr(next(s for s in sources if hasattr(s, name)), name)
    assert sorted(module.__all__) == sorted(names)  # what `from <old path> import *` binds


def test_old_names_on_the_packages():
    assert gvnn_warp.layers.SO3 is gvnn_warp.SO3  # an old module as an attribute
    assert gvnn_warp.photometric.PhotometricLoss is gvnn_warp.PhotometricLoss
    assert gk.lie.so3_exp is gk.geometry.lie.so3_exp
    # the packages that took the place of modules of the same name answer with those modules' names
    assert gk.photometric.KINDS is gk.photometric.residual.KINDS
    assert gk.photometric.load8 is gk.core.lanes.load8
    assert gk.perpixel.pixel_index is gk.perpixel.transforms.pixel_index
    with pytest.raises(AttributeError, match="no attribute 'nothing'"):
        getattr(gk.photometric, "nothing")  # noqa: B009


def test_star_import_binds_the_front_and_no_subpackage_named_like_a_user_name():
    namespace = {}
    exec("from gvnn_warp import *", namespace)
    assert {"SO3", "warp_frame_depth", "PinholeCamera", "layers", "kernels"} <= set(namespace)
    assert "nn" not in namespace and "vo" not in namespace  # `nn` would shadow torch.nn


FRESH_PROCESS = """if True:
    import json, sys
    import gvnn_warp as G
    facts = {}
    G.warp_frame_depth
    others = ("functional.perpixel", "functional.photometric", "ops.perpixel", "ops.photometric", "nn.lie")
    facts["loaded with warp_frame_depth"] = [m for m in others if f"gvnn_warp.{m}" in sys.modules]
    facts["exports"] = ["PhotometricLoss" in G.__all__, "warp_frame_depth" in dir(G.functional)]
    import gvnn_warp.kernels as gk
    facts["submodule loaded before"] = "gvnn_warp.kernels.photometric.pipeline" in sys.modules
    facts["submodule"] = gk.photometric.pipeline.__name__
    print(json.dumps(facts))
"""


@pytest.fixture(scope="module")
def fresh_process_facts():
    """What a fresh process loads for one public name, then what a replacing package serves (one
    process for both tests below)."""
    out = run_python(FRESH_PROCESS, timeout=120)
    assert out.returncode == 0, out.stderr[-3000:]
    return json.loads(out.stdout.strip().splitlines()[-1])


def test_a_public_name_loads_only_its_own_module(fresh_process_facts):
    # the front's packages serve their modules' names lazily (gvnn_warp/_exports.py): the 3D spatial
    # transformer does not load the per-pixel or photometric functions, nor their op registrations
    assert fresh_process_facts["loaded with warp_frame_depth"] == []
    assert fresh_process_facts["exports"] == [True, True]


def test_submodule_of_a_replacing_package_loads_on_first_attribute_access(fresh_process_facts):
    # gk.photometric's __getattr__ serves the old module's names, but a submodule comes first
    assert fresh_process_facts["submodule loaded before"] is False
    assert fresh_process_facts["submodule"] == "gvnn_warp.kernels.photometric.pipeline"
