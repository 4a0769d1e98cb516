"""Fully-convolutional LSGAN discriminator over sub-sequences (Generative Tweening §3.3, eqs. 7–8).

Input: root-relative joint positions ((J−1)·3 channels, metres) of a whole window, with the
key poses re-inserted into fakes before it sees them. Output: one score per sub-sequence
(length / 2**levels of them), each seeing ``receptive_field`` frames.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch
from torch import nn

from pipeline.networks.layers import ResLayer

REAL, FAKE, GEN_TARGET = 1.0, -1.0, 0.2361  # the paper's labels and generator target


@dataclass
class DiscriminatorConfig:
    n_joints: int = 21
    channels: tuple[int, ...] = (96, 128, 160, 192)


class Discriminator(nn.Module):
    def __init__(self, cfg: DiscriminatorConfig):
        super().__init__()
        chans = [(cfg.n_joints - 1) * 3, *cfg.channels]
        self.net = nn.Sequential(
            *(
                ResLayer(chans[i], chans[i + 1], 4, stride=2, sigma=1.0 / (i + 1))
                for i in range(len(cfg.channels))
            )
        )
        self.out = nn.Conv1d(chans[-1], 1, 1)

    def res_layers(self):
        return [m for m in self.modules() if isinstance(m, ResLayer)]

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.out(self.net(x)).squeeze(1)


def d_loss(real_scores: torch.Tensor, fake_scores: torch.Tensor) -> torch.Tensor:
    """Eq. 7."""
    return (real_scores - REAL).square().mean() + (fake_scores - FAKE).square().mean()


def g_loss(fake_scores: torch.Tensor) -> torch.Tensor:
    """Eq. 8."""
    return (fake_scores - GEN_TARGET).square().mean()
