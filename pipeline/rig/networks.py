"""GANimator's networks: skeleton-aware 1D convolutions, per-level generator and
discriminator (Table 4 of the paper), and differentiable forward kinematics for the
contact-consistency loss. Needs torch (training and export only).
"""

from __future__ import annotations

import math

import numpy as np
import torch
from torch import nn

from pipeline.rig.topology import vertex_mask

KERNEL = 5
SLOPE = 0.2


class SkeletonConv(nn.Module):
    """A Conv1d whose weight is masked so that output vertex i reads only its neighbours.

    Channels are split evenly over the V vertices; reflect padding keeps the length, so
    the network is fully convolutional in time.
    """

    def __init__(self, nb: list[list[int]], c_in: int, c_out: int, kernel: int = KERNEL):
        super().__init__()
        V = len(nb)
        if c_in % V or c_out % V:
            raise ValueError(f"channels {c_in}->{c_out} are not multiples of {V} vertices")
        ci, co = c_in // V, c_out // V
        vm = torch.from_numpy(vertex_mask(nb))
        self.register_buffer("mask", vm.repeat_interleave(co, 0).repeat_interleave(ci, 1)[:, :, None])
        self.weight = nn.Parameter(torch.empty(c_out, c_in, kernel))
        self.bias = nn.Parameter(torch.empty(c_out))
        self.pad = kernel // 2
        self.baked = False  # export: the weight is already masked (masked entries get no gradient)
        # PyTorch's default conv init, but with each output vertex's real fan-in.
        with torch.no_grad():
            for i, s in enumerate(nb):
                bound = 1.0 / math.sqrt(len(s) * ci * kernel)
                self.weight[i * co : (i + 1) * co].uniform_(-bound, bound)
                self.bias[i * co : (i + 1) * co].uniform_(-bound, bound)
            self.weight.mul_(self.mask)

    def forward(self, x):
        x = nn.functional.pad(x, (self.pad, self.pad), mode="reflect")
        return nn.functional.conv1d(x, self.weight if self.baked else self.weight * self.mask, self.bias)

    def effective_parameters(self) -> int:
        return int(self.mask.sum().item()) * self.weight.shape[-1] + self.bias.numel()


def _widths(channels: int, hidden: tuple[int, int, int], V: int) -> list[int]:
    up = [int(math.ceil(h / V) * V) for h in hidden]  # round to whole vertices
    return [channels, *up]


class LevelGenerator(nn.Module):
    """g_i: four skeleton convs (LeakyReLU between); the level's output is g(x) + base.

    ``forward(up, z)`` = g(up + z) + up, with ``up`` the upsampled coarser output (zeros at
    level 1) and ``z`` (B, 1, T) noise shared across channels.
    """

    def __init__(self, nb, channels: int, hidden: tuple[int, int, int]):
        super().__init__()
        w = _widths(channels, hidden, len(nb))
        dims = [(w[0], w[1]), (w[1], w[2]), (w[2], w[3]), (w[3], channels)]
        self.convs = nn.ModuleList(SkeletonConv(nb, a, b) for a, b in dims)

    def forward(self, up, z):
        x = up + z
        for i, conv in enumerate(self.convs):
            x = conv(x)
            if i < len(self.convs) - 1:
                x = nn.functional.leaky_relu(x, SLOPE)
        return x + up


class LevelDiscriminator(nn.Module):
    """Three skeleton convs then a plain conv to one channel: a PatchGAN score per frame."""

    def __init__(self, nb, channels: int, hidden: tuple[int, int, int]):
        super().__init__()
        w = _widths(channels, hidden, len(nb))
        self.convs = nn.ModuleList(
            SkeletonConv(nb, a, b) for a, b in [(w[0], w[1]), (w[1], w[2]), (w[2], w[3])]
        )
        self.out = nn.Conv1d(w[3], 1, KERNEL)

    def forward(self, x):
        for conv in self.convs:
            x = nn.functional.leaky_relu(conv(x), SLOPE)
        x = nn.functional.pad(x, (KERNEL // 2, KERNEL // 2), mode="reflect")
        return self.out(x)


def count_parameters(net: nn.Module) -> tuple[int, int]:
    """(stored, effective): all weights, and those the skeleton masks leave non-zero."""
    stored = sum(p.numel() for p in net.parameters())
    eff = 0
    for m in net.modules():
        if isinstance(m, SkeletonConv):
            eff += m.effective_parameters()
        elif isinstance(m, nn.Conv1d):
            eff += sum(p.numel() for p in m.parameters())
    return stored, eff


def upsample(x, n: int):
    return nn.functional.interpolate(x, size=n, mode="linear", align_corners=False)


def sixd_to_matrix(d6):
    """Gram–Schmidt (…, 6) → (…, 3, 3), columns like pipeline.motion.rotations (no roma)."""
    a1, a2 = d6[..., :3], d6[..., 3:]
    b1 = nn.functional.normalize(a1, dim=-1)
    b2 = nn.functional.normalize(a2 - (b1 * a2).sum(-1, keepdim=True) * b1, dim=-1)
    b3 = torch.cross(b1, b2, dim=-1)
    return torch.stack([b1, b2, b3], dim=-1)


class ContactFK(nn.Module):
    """Positions of the contact joints (in rig sizes, Y-up) from features (B, F0, T)."""

    def __init__(self, parents, offsets, contacts, scale: float):
        super().__init__()
        self.parents = [int(p) for p in parents]
        self.register_buffer("offsets", torch.as_tensor(np.asarray(offsets) / scale, dtype=torch.float32))
        self.contacts = [int(c) for c in contacts]
        # Only the chains that reach a contact joint matter.
        need = set()
        for c in self.contacts:
            j = c
            while j >= 0:
                need.add(j)
                j = self.parents[j]
        self.need = sorted(need)

    def forward(self, feat):
        B, F, T = feat.shape
        V = F // 6
        f = feat.transpose(1, 2).reshape(B, T, V, 6)
        vel = f[:, :, -1]
        x = torch.cumsum(torch.cat([torch.zeros_like(vel[:, :1, 0]), vel[:, 1:, 0]], 1), 1)
        z = torch.cumsum(torch.cat([torch.zeros_like(vel[:, :1, 2]), vel[:, 1:, 2]], 1), 1)
        root = torch.stack([x, vel[..., 1], z], -1)
        g_rot, g_pos = {}, {}
        for j in self.need:
            m = sixd_to_matrix(f[:, :, j])
            p = self.parents[j]
            if p < 0:
                g_rot[j], g_pos[j] = m, root
            else:
                g_rot[j] = g_rot[p] @ m
                g_pos[j] = g_pos[p] + (g_rot[p] @ self.offsets[j]).squeeze(-1)
        return torch.stack([g_pos[c] for c in self.contacts], 2)  # (B, T, C, 3)


def contact_loss(fk: ContactFK, feat, n_joints: int):
    """L_con: mean over frames and contact joints of |foot velocity| · s(label).

    The official code's form (plain velocity, s(x) = sigmoid(12(x − 0.5))); the paper writes
    squared velocity and sigmoid(10x − 5). Velocities here are in rig sizes per frame.
    """
    if not fk.contacts:
        return feat.new_zeros(())
    pos = fk(feat)
    vel = torch.linalg.vector_norm(pos[:, 1:] - pos[:, :-1], dim=-1)
    C = len(fk.contacts)
    label = feat[:, 6 * n_joints : 6 * (n_joints + C) : 6, 1:].transpose(1, 2)
    return (vel * torch.sigmoid(12.0 * (label - 0.5))).mean()
