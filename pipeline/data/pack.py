"""A split packed small enough to travel to a training host that cannot read ``../shared``.

The parsed train split is 116 MB as float32; a GPU host receives at most a few tens of MB.
Quaternions are quantised to 1/4096 (at most 0.014° per joint), root positions to 1/100 cm;
both are delta-coded along time within each clip, byte-shuffled per channel and
xz-compressed (lzma). Numpy has no codec for this and mocap deltas compress about 6×
with it, so it is written here. The result is an ordinary :class:`ClipSet`.
"""

from __future__ import annotations

import hashlib
import json
import lzma
import os
from pathlib import Path

import numpy as np

from pipeline.arguments import Parser
from pipeline.data.cache import ClipSet
from pipeline.errors import TweenError
from pipeline.motion.rotations import quat_normalize

ROT_SCALE = 4096.0
ROOT_SCALE = 100.0


def _encode(values: np.ndarray, starts: np.ndarray, scale: float) -> bytes:
    q = np.round(values.reshape(len(values), -1) * scale).astype(np.int64)
    d = np.diff(q, axis=0, prepend=0)
    d[starts] = q[starts]
    if np.abs(d).max() >= 2**31:
        raise ValueError("pack: values out of range")
    d = np.ascontiguousarray(d.T.astype(np.int32))  # channel-major: similar deltas adjacent
    shuffled = d.view(np.uint8).reshape(d.shape + (4,)).transpose(2, 0, 1)  # byte planes
    return lzma.compress(np.ascontiguousarray(shuffled).tobytes(), preset=6)


def _decode(blob: bytes, n: int, channels: int, lengths: np.ndarray, scale: float) -> np.ndarray:
    planes = np.frombuffer(lzma.decompress(blob), np.uint8).reshape(4, channels, n)
    d = np.ascontiguousarray(planes.transpose(1, 2, 0)).view(np.int32).reshape(channels, n).T
    c = np.cumsum(d.astype(np.int64), axis=0)
    # Each clip starts from an absolute value: restart the running sum at every clip start.
    ends = np.cumsum(lengths)
    before = np.concatenate([np.zeros((1, channels), np.int64), c[ends[:-1] - 1]])
    return (c - np.repeat(before, lengths, axis=0)) / scale


def pack(clips: ClipSet, path: Path) -> Path:
    """Writes ``clips`` to ``path`` (one file: a JSON header line, then two lzma blobs)."""
    n, J = clips.rotations.shape[:2]
    rot = _encode(clips.rotations, clips.starts, ROT_SCALE)
    root = _encode(clips.roots, clips.starts, ROOT_SCALE)
    head = {
        "names": list(clips.names),
        "lengths": clips.lengths.tolist(),
        "fps": clips.fps,
        "frames": n,
        "joints": J,
        "rot_bytes": len(rot),
        "root_bytes": len(root),
    }
    tmp = path.with_suffix(".tmp")
    with open(tmp, "wb") as f:
        f.write(json.dumps(head).encode() + b"\n")
        f.write(rot)
        f.write(root)
    os.replace(tmp, path)
    return path


def load_pack(path: str | Path) -> ClipSet:
    with open(path, "rb") as f:
        head = json.loads(f.readline())
        rot_blob = f.read(head["rot_bytes"])
        root_blob = f.read(head["root_bytes"])
    lengths = np.array(head["lengths"], np.int64)
    starts = np.concatenate([[0], np.cumsum(lengths)[:-1]]).astype(np.int64)
    n, J = head["frames"], head["joints"]
    rot = _decode(rot_blob, n, J * 4, lengths, ROT_SCALE).reshape(n, J, 4)
    roots = _decode(root_blob, n, 3, lengths, ROOT_SCALE)
    rot = quat_normalize(rot).astype(np.float32)
    return ClipSet(head["names"], starts, lengths, rot, roots.astype(np.float32), float(head["fps"]))


def main(argv=None) -> int:
    """``python -m pipeline.data.pack OUT`` packs the train split (with its checksum printed)."""
    from pipeline.data.cache import load_split

    ap = Parser(prog="python -m pipeline.data.pack", description=__doc__.splitlines()[0])
    ap.add_argument("out", type=Path, help="the packed file to write (.npz)")
    a = ap.parse_args(argv)
    if not a.out.parent.is_dir():  # before the split is read: a minute of parsing otherwise
        raise TweenError(f"{a.out}: its folder {a.out.parent} is not a folder that exists")
    out = pack(load_split("train"), a.out)
    print(out, hashlib.sha256(out.read_bytes()).hexdigest()[:16], f"{out.stat().st_size / 1e6:.1f} MB")
    return 0


if __name__ == "__main__":
    from pipeline.command import run_main

    run_main(main)
