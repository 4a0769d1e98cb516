"""Global path predictor Y: root velocity from the local motion (Generative Tweening §3.4).

Input: root-relative joint positions in the world's orientation ((J−1)·3 channels, metres),
output: the root's per-frame velocity (3 channels, metres/frame). Scaled-down Table 5:
four strided residual layers (k=12), four transposed ones (k=8), a final k=5 layer.
Length must be a multiple of 16.
"""

from __future__ import annotations

from dataclasses import dataclass

from torch import nn

from pipeline.networks.layers import ResLayer


@dataclass
class PathConfig:
    n_joints: int = 21
    channels: tuple[int, int] = (96, 160)


class PathPredictor(nn.Module):
    multiple = 16

    def __init__(self, cfg: PathConfig):
        super().__init__()
        self.cfg = cfg
        a, b = cfg.channels
        cin = (cfg.n_joints - 1) * 3
        self.net = nn.Sequential(
            ResLayer(cin, a, 12, stride=2, sigma=1.0),
            ResLayer(a, a, 12, stride=2, sigma=1 / 2),
            ResLayer(a, b, 12, stride=2, sigma=1 / 3),
            ResLayer(b, b, 12, stride=2, sigma=1 / 4),
            ResLayer(b, b, 8, stride=2, sigma=1 / 5, transposed=True),
            ResLayer(b, b, 8, stride=2, sigma=1 / 6, transposed=True),
            ResLayer(b, a, 8, stride=2, sigma=1 / 7, transposed=True),
            ResLayer(a, a, 8, stride=2, sigma=1 / 8, transposed=True),
        )
        # The output layer is plain: a 3-channel residual skip from 128 channels is meaningless.
        self.out = nn.Conv1d(a, 3, 5, padding=2)

    def res_layers(self):
        return [m for m in self.modules() if isinstance(m, ResLayer)]

    def forward(self, x):
        return self.out(self.net(x))
