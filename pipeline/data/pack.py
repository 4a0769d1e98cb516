"""A split packed small enough to travel to a training host that cannot read ``../shared``.

The parsed train split is 116 MB as float32; a GPU host receives at most a few tens of MB.
Quaternions are quantised to 1/4096 (at most 0.014° per joint), root positions to 1/100 cm;
both are delta-coded along time within each clip, byte-shuffled per channel and
xz-compressed (lzma). Numpy has no codec for this and mocap deltas compress about 6×
with it, so it is written here. The result is an ordinary :class:`ClipSet`; a file that is
not a whole pack is one line naming it, found in bounded memory.
"""

from __future__ import annotations

import hashlib
import json
import lzma
import math
import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from pipeline.arguments import Parser
from pipeline.atomic import naming, replacing
from pipeline.data.cache import ClipSet
from pipeline.errors import TweenError

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


def _decode(raw, n: int, channels: int, lengths: np.ndarray, scale: float) -> np.ndarray:
    """The (n, channels) values :func:`_encode` coded, from its decompressed bytes ``raw``."""
    planes = np.frombuffer(raw, np.uint8).reshape(4, channels, n)
    d = np.ascontiguousarray(planes.transpose(1, 2, 0)).view(np.int32).reshape(channels, n)
    c = np.cumsum(d, axis=1, dtype=np.int64)  # channel-major: each row summed along time
    del d
    # Each clip starts from an absolute value: restart the running sum at every clip start.
    starts = np.cumsum(lengths) - lengths
    before = c[:, np.maximum(starts - 1, 0)] * (starts > 0)
    for i in np.flatnonzero(starts > 0):
        c[:, starts[i] : starts[i] + lengths[i]] -= before[:, i : i + 1]
    return np.divide(c.T, scale, order="C")  # (n, channels), as training reads it


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
    with naming(path), replacing(path) as tmp, open(tmp, "wb") as f:  # whole or not at all
        f.write(json.dumps(head).encode() + b"\n")
        f.write(rot)
        f.write(root)
    return path


#: The longest header line read: the train split's (2451 clip names) is 110 kB.
HEAD_MAX = 16 << 20
#: The most memory the xz decoder may take: pack()'s preset 6 needs 9 MiB.
XZ_MEMLIMIT = 256 << 20
#: Bytes decompressed at a time (up to what the header implies).
STEP = 16 << 20
#: The header's fields and their JSON types.
HEAD_KEYS = {"names": list, "lengths": list, "fps": (int, float), "frames": int, "joints": int,
             "rot_bytes": int, "root_bytes": int}  # fmt: skip


@dataclass(frozen=True)
class PackHead:
    """A pack's header, checked against itself and the file's size."""

    names: list[str]
    lengths: np.ndarray
    fps: float
    frames: int
    joints: int
    rot_bytes: int
    root_bytes: int


def _damaged(path, option: str | None, why: str) -> TweenError:
    where = f"{path}: {option}" if option else str(path)
    return TweenError(
        f"{where}: not a training pack written by python -m pipeline.data.pack ({why}); pack the split again"
    )


def _head(line: bytes, size: int, bad) -> PackHead:
    """The header line ``line`` of a file of ``size`` bytes, every field checked (``bad(why)``:
    the error to raise)."""
    if not line.endswith(b"\n"):
        raise bad(
            f"no header line in its first {HEAD_MAX >> 20} MiB"
            if len(line) > HEAD_MAX
            else "cut short in its header"
        )
    try:
        head = json.loads(line)
    except (ValueError, RecursionError):  # not JSON, not UTF-8, nested past Python's stack
        raise bad("its first line is no JSON header") from None
    if not isinstance(head, dict):
        raise bad(f"its header is a JSON {type(head).__name__}, not an object")
    missing = [k for k in HEAD_KEYS if k not in head]
    if missing:
        raise bad(f"its header has no {', '.join(missing)}")
    for key, kind in HEAD_KEYS.items():
        v = head[key]
        if not isinstance(v, kind) or isinstance(v, bool) or (kind is int and v < 0):
            want = {list: "a list", int: "a whole number, 0 or more"}.get(kind, "a number")
            raise bad(f"its header's {key} is {str(v)[:40]!r}, not {want}")
    if not all(isinstance(x, str) for x in head["names"]):
        raise bad("its header's names are not all strings")
    if not all(isinstance(x, int) and not isinstance(x, bool) and x > 0 for x in head["lengths"]):
        raise bad("its header's clip lengths are not all whole numbers of frames, 1 or more")
    if not (math.isfinite(head["fps"]) and head["fps"] > 0):
        raise bad(f"its header's fps is {head['fps']}, not a number of frames a second")
    if head["joints"] < 1:
        raise bad("its header's joints is 0")
    if len(head["names"]) != len(head["lengths"]) or not head["lengths"]:
        raise bad(f"its header names {len(head['names'])} clips and gives {len(head['lengths'])} lengths")
    if sum(head["lengths"]) != head["frames"]:
        raise bad(
            f"its clip lengths add up to {sum(head['lengths'])} frames, its header says {head['frames']}"
        )
    left = size - len(line)
    if head["rot_bytes"] + head["root_bytes"] != left:
        raise bad(
            f"its header counts {head['rot_bytes'] + head['root_bytes']} bytes of data after it, the file "
            f"holds {left}: cut short, or added to"
        )
    fields = {k: head[k] for k in HEAD_KEYS if k not in ("lengths", "fps")}
    return PackHead(**fields, lengths=np.array(head["lengths"], np.int64), fps=float(head["fps"]))


def _inflate(blob: bytes, expected: int, what: str, bad) -> bytearray:
    """The xz ``blob`` decompressed: exactly ``expected`` bytes, or ``bad(why)`` raised. It is
    decompressed :data:`STEP` bytes at a time, never one byte past ``expected`` (a small blob
    can inflate thousands of times) nor past what the blob holds (a header can claim any size)."""
    dec = lzma.LZMADecompressor(lzma.FORMAT_XZ, memlimit=XZ_MEMLIMIT)
    out, data = bytearray(), blob
    try:
        while not dec.eof and len(out) <= expected:
            chunk = dec.decompress(data, max_length=min(STEP, expected + 1 - len(out)))
            data = b""
            if not chunk and not dec.eof:  # the blob ends before its stream does
                break
            out += chunk
    except lzma.LZMAError as e:
        raise bad(f"its {what} are not the xz data it wrote: {e}") from None
    if len(out) > expected:
        raise bad(f"its {what} inflate past the {expected} bytes its header implies")
    if not dec.eof:
        raise bad(f"its {what} are cut short")
    if len(out) != expected or dec.unused_data:
        more = f" and {len(dec.unused_data)} bytes after its end" if dec.unused_data else ""
        raise bad(f"its {what} inflate to {len(out)} bytes{more}, not the {expected} its header implies")
    return out


def load_pack(path: str | Path, option: str | None = None) -> ClipSet:
    """The ClipSet :func:`pack` wrote to ``path``. A file that is not one, or is damaged (cut
    short, another's, hand-edited), is a TweenError naming ``path`` (and ``option``, the flag
    that gave it); memory stays within what the file's header and sizes imply."""

    def bad(why: str) -> TweenError:
        return _damaged(path, option, why)

    try:
        with open(path, "rb") as f:
            size = os.fstat(f.fileno()).st_size
            return _clips(f, _head(f.readline(HEAD_MAX + 1), size, bad), bad)
    except OSError as e:
        where = f"{path}: {option}" if option else str(path)
        raise TweenError(f"{where}: cannot read it: {e.strerror or e}") from None


def _clips(f, head: PackHead, bad) -> ClipSet:
    """The clips of the pack open as ``f`` (just after its header ``head``)."""
    n, J = head.frames, head.joints
    rot_raw = _inflate(f.read(head.rot_bytes), 16 * J * n, "rotations", bad)
    root_raw = _inflate(f.read(head.root_bytes), 12 * n, "root positions", bad)
    rot = _decode(rot_raw, n, J * 4, head.lengths, ROT_SCALE).reshape(n, J, 4)
    del rot_raw
    norm = np.linalg.norm(rot, axis=-1, keepdims=True)
    if not norm.all():
        raise bad("it holds a rotation of length 0")
    rot = (rot / norm).astype(np.float32)
    roots = _decode(root_raw, n, 3, head.lengths, ROOT_SCALE).astype(np.float32)
    starts = (np.cumsum(head.lengths) - head.lengths).astype(np.int64)
    return ClipSet(head.names, starts, head.lengths, rot, roots, head.fps)


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
