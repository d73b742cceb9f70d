"""``HEVR_TEST_FAKE_CUPY=1``: the kernel suites (``HEVR_TEST_KERNELS``) run on the ``cuda``
backend over ``_fake_cupy.FakeCupy`` — CuPy played by the host build — so the CUDA launcher's
whole path (device arrays, marshalling, the key holder's kernels) runs without a GPU.
``test_cuda_device.py`` runs the three kernel suites this way in a subprocess."""

from __future__ import annotations

import os
import sys

if os.environ.get("HEVR_TEST_FAKE_CUPY") == "1":
    from _fake_cupy import FakeCupy

    sys.modules["cupy"] = FakeCupy  # before any test module asks for the cuda backend
    os.environ["HEVR_TEST_KERNELS"] = "cuda"
