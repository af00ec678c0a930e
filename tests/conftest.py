"""Fixtures shared by every test folder."""

import pytest
import torch

#: CPU always; CUDA where present (skipped otherwise), as kornia parametrises its tests.
DEVICES = ["cpu", pytest.param("cuda", marks=pytest.mark.cuda)]


@pytest.fixture(params=DEVICES)
def device(request) -> torch.device:
    """Each device the tensor code must run on: the device follows the inputs."""
    if request.param == "cuda" and not torch.cuda.is_available():
        pytest.skip("no CUDA device")
    return torch.device(request.param)
