"""A training pack that is damaged, cut short or no pack at all (``tween train --data-pack``)
is one line naming it, in bounded memory and time: it was an internal error (MemoryError
from a header's size read as asked, JSONDecodeError, LZMAError, KeyError, a reshape's
ValueError), and a pack is written whole or not at all."""

from __future__ import annotations

import json
import lzma
import os
import tracemalloc

import numpy as np
import pytest

from pipeline.data.cache import ClipSet
from pipeline.data.pack import load_pack, pack
from pipeline.errors import TweenError

NOT_A_PACK = "not a training pack written by python -m pipeline.data.pack ("


def tiny_clips(lengths=(70, 50), joints: int = 21, seed: int = 0) -> ClipSet:
    """Clips of random unit quaternions and root positions (cm), as a split's ClipSet."""
    rng = np.random.default_rng(seed)
    lengths = np.array(lengths, np.int64)
    n = int(lengths.sum())
    q = rng.normal(size=(n, joints, 4))
    q /= np.linalg.norm(q, axis=-1, keepdims=True)
    roots = rng.normal(size=(n, 3)) * 100
    starts = np.cumsum(lengths) - lengths
    names = [f"clip_{i}.bvh" for i in range(len(lengths))]
    return ClipSet(names, starts, lengths, q.astype(np.float32), roots.astype(np.float32), 30.0)


def _parts(good: bytes) -> tuple[dict, bytes, bytes]:
    line, rest = good.split(b"\n", 1)
    head = json.loads(line)
    return head, rest[: head["rot_bytes"]], rest[head["rot_bytes"] :]


def _file(head: dict, rot: bytes, root: bytes, sizes: bool = True) -> bytes:
    """A pack of ``head`` and the two blobs (their sizes written into the header)."""
    if sizes:
        head = {**head, "rot_bytes": len(rot), "root_bytes": len(root)}
    return json.dumps(head).encode() + b"\n" + rot + root


def _edit(**changes):
    def edit(good: bytes) -> bytes:
        head, rot, root = _parts(good)
        return _file({**head, **changes}, rot, root, sizes=False)

    return edit


def _bomb(good: bytes) -> bytes:
    """Its rotations' blob swapped for 32 MiB of zeros, xz-compressed to 5 kB."""
    head, _, root = _parts(good)
    return _file(head, lzma.compress(bytes(32 << 20), preset=0), root)


def _not_xz(good: bytes) -> bytes:
    head, rot, root = _parts(good)
    return _file(head, os.urandom(len(rot)), root)


def _swapped(good: bytes) -> bytes:
    head, rot, root = _parts(good)
    return _file(head, root, rot)


def _junk_after_stream(good: bytes) -> bytes:
    head, rot, root = _parts(good)
    return _file(head, rot + b"\x01junk", root)


def _cut_stream(good: bytes) -> bytes:
    """The rotations' stream cut short, the header's sizes made to agree with the file."""
    head, rot, root = _parts(good)
    return _file(head, rot[: len(rot) // 2], root)


DAMAGED = {
    "empty": (lambda g: b"", "cut short in its header"),
    "garbage": (lambda g: b"garbage\n", "its first line is no JSON header"),
    "not UTF-8": (lambda g: b"\xff\xfe\x00{\n" + g, "its first line is no JSON header"),
    "nested past the stack": (lambda g: b"[" * 200_000 + b"\n", "its first line is no JSON header"),
    "no newline": (lambda g: b"{" + b" " * (17 << 20), "no header line in its first 16 MiB"),
    "a list": (lambda g: b"[1, 2]\n" + g, "its header is a JSON list, not an object"),
    "huge sizes": (
        lambda g: b'{"rot_bytes": 99999999999, "root_bytes": 1}\nxx',
        "its header has no names, lengths, fps, frames, joints",
    ),
    "huge size, full header": (_edit(rot_bytes=99999999999), "bytes of data after it, the file holds"),
    "cut short": (lambda g: g[:-100], "bytes of data after it, the file holds"),
    "cut in its header": (lambda g: g[:30], "cut short in its header"),
    "added to": (lambda g: g + b"more", "cut short, or added to"),
    "frames not a number": (_edit(frames="many"), "its header's frames is 'many', not a whole number"),
    "joints below 0": (_edit(joints=-4), "its header's joints is '-4', not a whole number, 0 or more"),
    "fps NaN": (_edit(fps=float("nan")), "its header's fps is nan"),
    "lengths not the frames": (
        _edit(frames=119),
        "its clip lengths add up to 120 frames, its header says 119",
    ),
    "a length below 1": (
        _edit(lengths=[121, -1]),
        "clip lengths are not all whole numbers of frames, 1 or more",
    ),
    "a name short": (_edit(names=["a"]), "its header names 1 clips and gives 2 lengths"),
    "more joints than coded": (_edit(joints=22), "its rotations inflate to 40320 bytes, not the 42240"),
    "blobs not xz": (_not_xz, "its rotations are not the xz data it wrote"),
    "blobs swapped": (_swapped, "its rotations inflate to 1440 bytes, not the 40320"),
    "junk after a stream": (_junk_after_stream, "and 5 bytes after its end"),
    "a stream cut short": (_cut_stream, "its rotations are cut short"),
    "an xz bomb": (_bomb, "its rotations inflate past the 40320 bytes its header implies"),
}


@pytest.fixture(scope="module")
def good(tmp_path_factory) -> bytes:
    return pack(tiny_clips(), tmp_path_factory.mktemp("pack") / "good.pack").read_bytes()


@pytest.mark.parametrize("case", list(DAMAGED))
def test_a_damaged_pack_is_one_error_naming_it(case, good, tmp_path):
    make, why = DAMAGED[case]
    path = tmp_path / "train.pack"
    path.write_bytes(make(good))
    tracemalloc.start()
    try:
        with pytest.raises(TweenError) as e:
            load_pack(path)
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    msg = str(e.value)
    assert msg.startswith(f"{path}: {NOT_A_PACK}") and why in msg, msg
    assert "\n" not in msg and msg.endswith("; pack the split again")
    # Never more than the file's size and what its header implies: a 32 MiB xz bomb or a
    # header asking 100 GB is refused within the xz decoder's 8 MiB (its dictionary) and a
    # few more; the unended line within twice the 16 MiB read of it.
    assert peak < (40 << 20 if case == "no newline" else 12 << 20), peak


def test_a_pack_of_a_rotation_of_length_0_is_refused(tmp_path):
    """quat_normalize made NaN of it, which trained on with NaN losses."""
    clips = tiny_clips()
    clips.rotations[5, 3] = 0
    path = pack(clips, tmp_path / "zero.pack")
    with pytest.raises(TweenError, match="it holds a rotation of length 0"):
        load_pack(path)


def test_a_pack_that_is_not_a_file_names_it(tmp_path):
    for path, why in ((tmp_path / "missing.pack", "No such file or directory"), (tmp_path, "Is a directory")):
        with pytest.raises(TweenError) as e:
            load_pack(path)
        assert str(e.value) == f"{path}: cannot read it: {why}", e.value


def test_a_good_pack_loads_as_it_was_packed(good, tmp_path):
    (tmp_path / "good.pack").write_bytes(good)
    clips, out = tiny_clips(), load_pack(tmp_path / "good.pack")
    assert out.names == clips.names and np.array_equal(out.lengths, clips.lengths)
    assert np.array_equal(out.starts, clips.starts) and out.fps == clips.fps
    assert np.abs(out.rotations - clips.rotations).max() < 2.5e-4
    assert np.abs(out.roots - clips.roots).max() <= 0.0051
    assert out.rotations.flags.c_contiguous and out.roots.flags.c_contiguous


def test_a_pack_is_written_whole_or_not_at_all(tmp_path, monkeypatch):
    """It was written to OUT.tmp and renamed by hand: an interrupted pack left the .tmp, two
    packers into one folder shared it, and a file of the user's named so was taken over."""
    out, mine = tmp_path / "train.pack", tmp_path / "train.tmp"
    out.write_bytes(b"the pack before")
    mine.write_bytes(b"the user's own file")

    def interrupted(src, dst):
        raise KeyboardInterrupt

    with monkeypatch.context() as m:
        m.setattr(os, "replace", interrupted)
        with pytest.raises(KeyboardInterrupt):
            pack(tiny_clips(), out)
    assert out.read_bytes() == b"the pack before" and mine.read_bytes() == b"the user's own file"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["train.pack", "train.tmp"]
    pack(tiny_clips(), out)
    assert load_pack(out).names == tiny_clips().names and mine.read_bytes() == b"the user's own file"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["train.pack", "train.tmp"]
