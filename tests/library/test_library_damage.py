"""A library whose array files are damaged with their sizes right (random bytes, another
library's numbers): `tween fill-local --library` and `tween library info` are one error line
naming the file, exit 2, nothing written, and no numpy warning before it."""

from __future__ import annotations

import shutil
import sys
import warnings
from pathlib import Path

import numpy as np
import pytest

from pipeline.cli import main
from pipeline.library.store import ARRAYS

SHOT = Path(__file__).resolve().parents[2] / "examples" / "sh010_walk.usda"


def tween(monkeypatch, capsys, *args) -> tuple[int, str, list]:
    """The `tween` entry point in this process: (exit status, stderr, the warnings raised;
    pytest keeps those off stderr, so they are recorded here)."""
    monkeypatch.setattr(sys, "argv", ["tween", *map(str, args)])
    capsys.readouterr()
    with warnings.catch_warnings(record=True) as seen, pytest.raises(SystemExit) as e:
        warnings.simplefilter("always")
        main()
    return e.value.code or 0, capsys.readouterr().err, [str(w.message) for w in seen]


def _random_bytes(name: str):
    def damage(folder: Path) -> None:
        f = folder / f"{name}.bin"
        f.write_bytes(np.random.default_rng(7).bytes(f.stat().st_size))

    return damage


def _finite(name: str):
    """Finite numbers of the right size that no library holds (uniform in -2..2)."""

    def damage(folder: Path) -> None:
        f = folder / f"{name}.bin"
        n = f.stat().st_size // np.dtype(ARRAYS[name][0]).itemsize
        f.write_bytes(np.random.default_rng(7).uniform(-2, 2, n).astype(ARRAYS[name][0]).tobytes())

    return damage


def _damaged(library: Path, tmp_path: Path, damage) -> Path:
    copy = tmp_path / "lib"
    shutil.copytree(library, copy)
    damage(copy)
    return copy


def _one_error(rc: int, err: str, seen: list, *names: str) -> str:
    """Exit 2, no warning, one error line (the last; lines before it are the fill's own
    `tween:` lines), naming ``names``. Returns the error line."""
    assert rc == 2 and not seen, (err, seen)
    lines = [ln for ln in err.splitlines() if ln.strip()]
    assert all(ln.startswith("tween: ") for ln in lines), err
    errors = [ln for ln in lines if ln.startswith("tween: error: ")]
    assert len(errors) == 1 and errors[0] == lines[-1], err
    assert all(n in errors[0] for n in names), err
    return errors[0]


@pytest.mark.parametrize(
    "damage, names",
    [
        (_random_bytes("features"), ["features.bin", "not finite numbers"]),
        (_random_bytes("roots"), ["roots.bin", "not finite numbers"]),
        (_random_bytes("rotations"), ["rotations.bin", "not finite numbers"]),
        (_random_bytes("contacts"), ["contacts.bin, frames", "foot contacts other than 0 and 1"]),
        (_finite("facing"), ["facing.bin", "quaternions that are not of length 1"]),
        (_finite("sqnorm"), ["features.bin or sqnorm.bin", "squared lengths that are not the features'"]),
    ],
)
def test_a_fill_from_a_library_damaged_inside_its_arrays_is_one_line_naming_the_file(
    library, tmp_path, monkeypatch, capsys, damage, names
):
    """Before: numpy's overflow warnings (two to four lines) came before the error, and
    damaged contacts were filled with (each byte over 0 a foot planted)."""
    copy = _damaged(library, tmp_path, damage)
    out = tmp_path / "out"
    rc, err, seen = tween(monkeypatch, capsys, "fill-local", SHOT, "--library", copy, "--out-dir", out)
    line = _one_error(rc, err, seen, str(copy), *names)
    assert line.endswith("(the library is damaged; build it again)")
    assert not out.exists()


@pytest.mark.parametrize(
    "damage, names",
    [
        *[
            (_random_bytes(n), [f"{n}.bin, frames 0-", "not finite numbers"])
            for n in ARRAYS
            if ARRAYS[n][0] == "<f4"
        ],
        (_random_bytes("contacts"), ["contacts.bin, frames 0-", "foot contacts other than 0 and 1"]),
        (_random_bytes("take_end"), ["take_end.bin, frames 0-", "take ends that are not the manifest's"]),
        (_finite("rotations"), ["rotations.bin", "quaternions that are not of length 1"]),
        (_finite("features"), ["features.bin or sqnorm.bin", "squared lengths that are not the features'"]),
    ],
)
def test_library_info_checks_every_frame_and_says_the_first_damage_in_one_line(
    library, tmp_path, monkeypatch, capsys, damage, names
):
    """`tween library info` is what a TD runs to check a library: it read only the manifest
    and said 0 on every library damaged inside its arrays."""
    copy = _damaged(library, tmp_path, damage)
    rc, err, seen = tween(monkeypatch, capsys, "library", "info", copy)
    assert err.count("\n") == 1, err  # nothing before the error: not even the library's lines
    _one_error(rc, err, seen, str(copy), *names)


def test_library_info_of_a_sound_library_still_lists_its_takes(library, monkeypatch, capsys):
    rc, err, seen = tween(monkeypatch, capsys, "library", "info", library)
    assert rc == 0 and not err and not seen
