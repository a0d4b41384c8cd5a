"""The fused stage's shared parts (``ftgspp.render.prepare``): the camera row its kernels read.

The kernels themselves are checked per method against PyTorch autograd
(``tests/methods/test_freetime_fused.py``).
"""

from __future__ import annotations

import numpy as np
import torch


def test_camera_row_is_remembered_per_camera_but_never_shared() -> None:
    from ftgspp.render import prepare_kernels as _pk
    from ftgspp.render.prepare import _camera_row, camera_row
    from ftgspp.render.project import tangent_limits

    K = torch.tensor([[101.3, 0.0, 63.7], [0.0, 99.1, 48.2], [0.0, 0.0, 1.0]])
    first = camera_row(K, 128, 96, 0.01, 0.3)
    first[:] = -1.0  # a caller's edit must not reach the next caller
    again = camera_row(K, 128, 96, 0.01, 0.3)
    assert _camera_row.cache_info().hits >= 1
    assert np.array_equal(again[[_pk.CAM_LOX, _pk.CAM_HIX, _pk.CAM_LOY, _pk.CAM_HIY]],
                          np.array(tangent_limits(K, 128, 96), np.float32))
    assert again[_pk.CAM_W] == 128 and again[_pk.CAM_FX] == np.float32(101.3)
    other = camera_row(K * 2.0, 128, 96, 0.01, 0.3)  # another camera: its own row
    assert other[_pk.CAM_FX] == np.float32(202.6)
