"""pytest configuration: thread count and the dtype fixture."""

import pytest
import torch

torch.set_num_threads(2)


@pytest.fixture(params=[torch.float32, torch.float64], ids=["f32", "f64"])
def dtype(request):
    return request.param

