"""pytest configuration: thread count, the dtype fixture, and what keeps ``pytest -n 2`` short.

- torch is imported by the processes that run tests, not by pytest-xdist's controller, which only
  starts the workers and gathers their reports: imported there (3-4 s), it delayed their start;
- the tests marked ``long`` (5 s or more) run first, so that the workers end on short tests;
- at exit, objects are frozen before Python's last garbage collections (see ``pytest_configure``).
"""

import atexit
import gc
import os

# Idle OpenMP threads sleep instead of spinning (as in the VO demo), set before torch is imported and
# inherited by the tests' subprocesses. With spinning, torch's two workers kept the cores busy
# between ops, and on 2 shared cores the Warp launches and the other processes waited for them: the
# short VO training test took 68 s instead of 11 s on a busy host (35 s of CPU instead of 6).
os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")

import pytest  # noqa: E402


def pytest_configure(config):
    # At exit, Python's last garbage collections walked every object a worker still held: 5-7 s after
    # its share of the suite, while the controller waited. Frozen objects are skipped by them.
    atexit.register(gc.freeze)
    if config.getoption("numprocesses", None) and not hasattr(config, "workerinput"):
        return  # (pytest-xdist's controller: it runs no test)
    import torch

    torch.set_num_threads(2)


@pytest.fixture(params=["float32", "float64"], ids=["f32", "f64"])
def dtype(request):
    import torch

    return getattr(torch, request.param)


def pytest_collection_modifyitems(config, items):
    # The tests marked ``long`` first (the order is otherwise kept): pytest-xdist's workers then end
    # on short tests, which they share, instead of one waiting up to ~25 s for the other's last.
    items.sort(key=lambda item: item.get_closest_marker("long") is None)
