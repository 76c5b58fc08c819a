"""pytest configuration: thread count and the dtype fixture."""

import os

# Idle OpenMP threads sleep instead of spinning (as in the VO demo), set before torch is imported and
# inherited by the tests' subprocesses. With spinning, torch's two workers kept the cores busy
# between ops, and on 2 shared cores the Warp launches and the other processes waited for them: the
# short VO training test took 68 s instead of 11 s on a busy host (35 s of CPU instead of 6).
os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")

import pytest  # noqa: E402
import torch  # noqa: E402

torch.set_num_threads(2)


@pytest.fixture(params=[torch.float32, torch.float64], ids=["f32", "f64"])
def dtype(request):
    return request.param

