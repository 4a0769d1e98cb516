"""`tween review --force` replaces a take's earlier media whole: it replaced only the files of the
same names, so an earlier review's numbered frames outside a narrower ``--frames`` range, or in
the other format after ``--exr``, stayed in ``--out`` beside the new ones (a full review, then
``--force --frames 1001:1010 --exr``, left 10 EXR frames next to 97 old PNGs) for editorial to
pick up. The other takes' media and the folder's other files stay; a review that fails as it
moves its media in puts the earlier ones back."""

from __future__ import annotations

import errno
import re
from pathlib import Path

import pytest
from usd_fixtures import bandai_shot, tree_hashes, tween

from pipeline.fill.api import FillOptions, fill_shot

SIZE = "160x96"
TAKE1 = "sh090_v001_take1"
#: Beside the media, named like them but not what a review of take 1 writes: kept.
UNRELATED = {
    "notes.txt": "mine",
    f"{TAKE1}.1001.png.bak": "a copy",
    f"{TAKE1}.01001.exr": "not a review's padding",
    f"{TAKE1}.1001.jpg": "a conversion",
    "sh090_v001_take10.1001.png": "another take's",
}


@pytest.fixture()
def reviewed(tmp_path, monkeypatch, capsys):
    """A two-take fill (21 frames, 1001-1021) with both takes reviewed as PNG frames into
    ``media``, and the unrelated files beside them."""
    shot = bandai_shot(tmp_path / "sh090.usda", frames=21)
    fill_shot(str(shot), FillOptions(model="interp", takes=2))
    media = tmp_path / "media"
    for take in (0, 1):
        code, err = tween(monkeypatch, capsys, "review", shot, "--take", take, "--size", SIZE, "--out", media)
        assert code == 0, err
    for name, text in UNRELATED.items():
        (media / name).write_text(text)
    assert _frames(media, TAKE1) == [f"{TAKE1}.{f}.png" for f in range(1001, 1022)]
    return shot, media


def _frames(media: Path, stem: str) -> list[str]:
    """The numbered frames of ``stem`` in ``media`` (four-digit frame numbers here), either format."""
    return sorted(p.name for p in media.iterdir() if re.fullmatch(rf"{stem}\.\d{{4}}\.(png|exr)", p.name))


def _others(media: Path) -> dict[str, str]:
    """Every file of ``media`` that is not take 1's media or the shot's timeline, hashed."""
    take1 = {f"{TAKE1}.mp4", f"{TAKE1}_contact.png", "sh090_v001.otio", *_frames(media, TAKE1)}
    return {k: v for k, v in tree_hashes(media).items() if Path(k).name not in take1}


def test_force_replaces_every_earlier_frame_of_the_take(reviewed, monkeypatch, capsys):
    shot, media = reviewed
    others = _others(media)
    assert len(others) == 2 + 21 + len(UNRELATED)  # take 0's MP4, sheet and frames
    code, err = tween(monkeypatch, capsys, "review", shot, "--take", 1, "--size", SIZE, "--out", media,
                      "--force", "--frames", "1004:1008")  # fmt: skip
    assert code == 0, err
    assert _frames(media, TAKE1) == [f"{TAKE1}.{f}.png" for f in range(1004, 1009)]  # not 21
    code, err = tween(monkeypatch, capsys, "review", shot, "--take", 1, "--size", SIZE, "--out", media,
                      "--force", "--frames", "1010:1012", "--exr")  # fmt: skip
    assert code == 0, err
    assert _frames(media, TAKE1) == [f"{TAKE1}.{f}.exr" for f in range(1010, 1013)]  # no PNG left
    assert (media / f"{TAKE1}.mp4").is_file() and (media / f"{TAKE1}_contact.png").is_file()
    assert _others(media) == others  # take 0's media and the unrelated files as they were
    assert not [p for p in media.iterdir() if p.name.startswith(".tween-review")]  # no scratch left

    # Without --force nothing of the user's goes: take 1's MP4 and sheet moved away, its EXR
    # frames are not an earlier review of a PNG render (not refused, as before), and stay.
    for name in (f"{TAKE1}.mp4", f"{TAKE1}_contact.png"):
        (media / name).rename(media.parent / name)
    code, err = tween(monkeypatch, capsys, "review", shot, "--take", 1, "--size", SIZE, "--out", media,
                      "--frames", "1001:1002")  # fmt: skip
    assert code == 0, err
    assert _frames(media, TAKE1) == [f"{TAKE1}.{f}.{e}" for f, e in
                                     [(1001, "png"), (1002, "png"), (1010, "exr"), (1011, "exr"), (1012, "exr")]]  # fmt: skip
    # --no-frames --force: a movie and sheet only, and none of the frames of the review it replaces.
    code, err = tween(monkeypatch, capsys, "review", shot, "--take", 1, "--size", SIZE, "--out", media,
                      "--force", "--no-frames")  # fmt: skip
    assert code == 0, err
    assert _frames(media, TAKE1) == [] and _others(media) == others


@pytest.mark.parametrize("failure", [OSError(errno.ENOSPC, "No space left on device"), KeyboardInterrupt()])
def test_a_force_review_failing_as_it_moves_in_puts_the_earlier_media_back(
    reviewed, monkeypatch, capsys, failure
):
    """The last medium's move into ``--out`` fails (a full disk) or is interrupted (Ctrl-C):
    the earlier frames set aside by then (every one: the new render has 3 EXR frames) are put
    back with the replaced movie, sheet and timeline, byte for byte."""
    shot, media = reviewed
    before = tree_hashes(media)
    real, seen = Path.replace, []

    def replace(self, target):
        # The move out of the scratch only, not the one putting the earlier sheet back.
        if Path(target) == media / f"{TAKE1}_contact.png" and self.parent.name.startswith(".tween-review"):
            seen.append(_frames(media, TAKE1))  # what --out holds as the last medium moves in
            raise failure
        return real(self, target)

    monkeypatch.setattr(Path, "replace", replace)
    code, err = tween(monkeypatch, capsys, "review", shot, "--take", 1, "--size", SIZE, "--out", media,
                      "--force", "--frames", "1010:1012", "--exr")  # fmt: skip
    assert code != 0, err
    # By then the earlier PNG frames were aside (the old code left them in place)...
    assert seen == [[f"{TAKE1}.{f}.exr" for f in range(1010, 1013)]]
    # ...and now they, and everything else, are back as they were; no scratch left.
    assert tree_hashes(media) == before
    assert sorted(p.name for p in media.iterdir()) == sorted(Path(k).name for k in before)
