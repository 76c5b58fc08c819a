"""docs/api.md is generated from the docstrings and must be current; every public name is documented."""

import importlib.util
from pathlib import Path

DOCS = Path(__file__).resolve().parents[1] / "docs"


def _generator():
    spec = importlib.util.spec_from_file_location("gen_api", DOCS / "gen_api.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def test_api_reference_is_current():
    assert (DOCS / "api.md").read_text() == _generator().render(), "run: python docs/gen_api.py"


def test_every_public_name_documented_with_shapes():
    import gvnn_warp

    text = (DOCS / "api.md").read_text()
    for name in gvnn_warp.__all__:
        submodules = ("functional", "layers", "perpixel", "perpixel_layers", "photometric", "kernels")
        if name[0].isupper() or name in submodules:
            continue
        assert f"### `{name}(" in text or name == "MIN_DEPTH", name
    assert "(undocumented)" not in text


def test_lazy_export_lists_match_modules():
    # gvnn_warp/__init__.py lists the torch-facing names statically (so importing it stays free of
    # torch); they must be exactly the modules' public names.
    import gvnn_warp
    from gvnn_warp import functional, layers, perpixel, perpixel_layers, photometric

    for listed, module in [
        (gvnn_warp._FUNCTIONAL, functional),
        (gvnn_warp._LAYERS, layers),
        (gvnn_warp._PERPIXEL, perpixel),
        (gvnn_warp._PERPIXEL_LAYERS, perpixel_layers),
        (gvnn_warp._PHOTOMETRIC, photometric),
    ]:
        constants = ("HOMOGRAPHY_MIN_DEN", "ROBUST_KINDS", "ERROR_KINDS", "NORMAL_EQUATIONS_KINDS")
        public = {n for n in module.__all__ if n not in constants}
        assert set(listed) == public, module.__name__
