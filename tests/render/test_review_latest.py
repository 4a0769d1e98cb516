"""`tween review SHOT` finds the shot's latest fill by itself (and says so)."""

import json
import subprocess
import sys
from pathlib import Path

import pytest
from usd_fixtures import bandai_shot, tree_hashes

from pipeline.fill.api import FillOptions, fill_shot
from pipeline.usd.files import owner_tag


def _review(cwd, *args):
    return subprocess.run([sys.executable, "-m", "pipeline.cli", "review", *map(str, args), "--no-frames",
                           "--size", "160x96"], cwd=cwd, capture_output=True, text=True, timeout=300)  # fmt: skip


def test_review_of_a_shot_renders_its_latest_fill(tmp_path):
    shot = bandai_shot(tmp_path / "sh060.usda", frames=21)
    r = _review(tmp_path, shot)  # no fill yet: the shot as it is, said
    assert r.returncode == 0, r.stderr
    assert "no fill of it yet" in r.stderr
    fill_shot(str(shot), FillOptions(model="interp"))
    latest = fill_shot(str(shot), FillOptions(model="interp", takes=2))  # v002, two takes
    r = _review(tmp_path, shot, "--take", 1)
    assert r.returncode == 0, r.stderr
    assert f"its latest fill, {latest['review']}" in r.stderr
    out = json.loads(r.stdout)
    assert out["mp4"].endswith("sh060_v002_take1.mp4") and (tmp_path / out["mp4"]).stat().st_size > 1000


def _filled(tmp_path, takes=2):
    shot = bandai_shot(tmp_path / "sh070.usda", frames=21)
    res = fill_shot(str(shot), FillOptions(model="interp", takes=takes))
    return shot, Path(res["layer"]), Path(res["review"])


def _refused(tmp_path, *args) -> str:
    """One error line, exit 2, and nothing written into the shot's folder or --out."""
    before = tree_hashes(tmp_path)
    r = _review(tmp_path, *args, "--out", tmp_path / "media")
    assert r.returncode == 2 and r.stdout == "", r.stderr
    assert len(r.stderr.splitlines()) == 1 and r.stderr.startswith("tween: error: "), r.stderr
    assert tree_hashes(tmp_path) == before
    return r.stderr


def test_a_review_whose_layers_are_missing_is_refused_not_rendered_unfilled(tmp_path):
    """USD composes without a missing sublayer: the review showed the shot unfilled (exit 0)."""
    shot, layer, review = _filled(tmp_path)
    layer.rename(tmp_path / "aside.usda")
    err = _refused(tmp_path, review)
    assert f"{review.name}: the layer it stacks, {layer.name}, is not there" in err
    (tmp_path / "aside.usda").rename(layer)
    shot.rename(tmp_path / "aside.usda")  # the shot under its fill
    assert f"the layer it stacks, {shot.name}, is not there" in _refused(tmp_path, review)


def test_a_latest_fill_without_its_review_layer_is_refused(tmp_path):
    """A newer fill version USD cannot read has no review layer: before, the shot was rendered
    as if it had no fill at all."""
    shot, _, _ = _filled(tmp_path)
    (tmp_path / "sh070.tween.v002.usda").write_text("garbage\n")
    err = _refused(tmp_path, shot)
    assert "sh070.tween.v002.usda: its review layer" in err and "sh070.review.v002.usda is not there" in err


def test_a_review_layer_usd_cannot_read_is_one_line_naming_it(tmp_path):
    shot, _, review = _filled(tmp_path)
    review.write_text("garbage\n")
    for given in (shot, review):  # found as the latest fill's, or named
        err = _refused(tmp_path, given)
        assert (
            err.startswith(f"tween: error: {review}: cannot read the review layer: ") and "not a valid" in err
        )


def test_a_read_only_or_empty_out_is_refused_before_anything_renders(tmp_path):
    """Read-only by its mode bits counts even for root (the media went in): as every command."""
    shot, _, _ = _filled(tmp_path)
    ro = tmp_path / "published"
    ro.mkdir()
    ro.chmod(0o555)
    try:
        for out, says in (
            (ro, f"{ro}: --out is read-only"),
            (ro / "sub", f"--out is in {ro}, which is read-only"),
        ):
            r = _review(tmp_path, shot, "--out", out)
            assert r.returncode == 2 and r.stderr.count("\n") == 1 and says in r.stderr, r.stderr
        assert not list(ro.iterdir())
    finally:
        ro.chmod(0o755)
    r = _review(tmp_path, shot, "--out", "")
    assert r.returncode == 2 and r.stderr.startswith("tween: error: --out '': give a folder"), r.stderr


def test_a_fill_layer_is_reviewed_through_its_review_layer(tmp_path):
    shot, layer, review = _filled(tmp_path)
    r = _review(tmp_path, layer, "--take", 1, "--out", tmp_path / "media")
    assert r.returncode == 0, r.stderr
    assert f"rendered through its review layer, {review}" in r.stderr
    assert json.loads(r.stdout)["model"]  # the fill, not an empty stage


def test_a_single_take_fill_is_its_take_and_refusals_are_one_line(tmp_path):
    """A one-take fill has no variant set: --take 0 is it, as approve says; any refusal after
    the latest fill is found is the only line (it was said before the error)."""
    shot, _, _ = _filled(tmp_path, takes=1)
    r = _review(tmp_path, shot, "--take", 0, "--out", tmp_path / "media")
    assert r.returncode == 0, r.stderr
    assert "--take 1 given but its fill is take 0 alone" in _refused(tmp_path, shot, "--take", 1)
    assert "is outside the shot" in _refused(tmp_path, shot, "--frames", "5:9", "--force")
    (tmp_path / "afile").write_text("")
    r = _review(tmp_path, shot, "--out", tmp_path / "afile")
    assert r.returncode == 2 and r.stderr.strip().splitlines() == [
        f"tween: error: {tmp_path / 'afile'}: is a file, not a folder for the review's media"
    ]
    r = _review(tmp_path, shot, "--out", tmp_path / "afile" / "media")  # said "Not a directory"
    assert r.returncode == 2 and r.stderr.strip().splitlines() == [
        f"tween: error: {tmp_path / 'afile' / 'media'}: cannot make the folder for the review's media: "
        f"{tmp_path / 'afile'} is a file, not a folder"
    ]


def test_a_span_beyond_the_fills_bound_is_refused_before_rendering(tmp_path):
    """A stage range of 10^8 frames ran out of memory (47 GiB) as an internal error."""
    from pxr import Sdf

    shot = bandai_shot(tmp_path / "sh080.usda", frames=21)
    layer = Sdf.Layer.FindOrOpen(str(shot))
    layer.endTimeCode = 1e8
    assert layer.Save()
    err = _refused(tmp_path, shot)
    assert "the range to render" in err and "spans more than 1,000,000 frames" in err


def test_media_move_in_all_or_none(tmp_path):
    """A folder where a medium goes is refused before anything moves; a move that fails
    midway puts the earlier render's media back (no timeline naming a movie not there)."""
    shot, _, review = _filled(tmp_path)
    media = tmp_path / "media"
    r = _review(tmp_path, review, "--take", 0, "--out", media)
    assert r.returncode == 0, r.stderr
    (media / "sh070_v001_take1.mp4").mkdir()
    (media / "sh070_v001_take1.mp4" / "x").write_text("keep")
    before = tree_hashes(media)
    r = _review(tmp_path, review, "--take", 1, "--out", media)
    assert r.returncode == 2 and "sh070_v001_take1.mp4: is a folder" in r.stderr, r.stderr
    assert tree_hashes(media) == before  # take 0's media and timeline as they were, the folder kept


def test_move_in_puts_back_what_it_replaced_when_a_move_fails(tmp_path, monkeypatch):
    from render import review as rv

    out, tmp = tmp_path / "out", tmp_path / "out" / ".scratch"
    tmp.mkdir(parents=True)
    for name, text in (("a.mp4", "old a"), ("b.otio", "old b")):
        (out / name).write_text(text)
    for name in ("a.mp4", "b.otio", "c.png"):
        (tmp / name).write_text(f"new {name}")
    real = Path.replace

    def replace(self, target):
        if self.name == "c.png" and Path(target).parent == out:
            raise OSError(28, "No space left on device", str(target))
        return real(self, target)

    monkeypatch.setattr(Path, "replace", replace)
    with pytest.raises(OSError):
        rv._move_in(tmp, out)
    assert sorted(p.name for p in out.iterdir() if p.is_file()) == ["a.mp4", "b.otio"]
    assert (out / "a.mp4").read_text() == "old a" and (out / "b.otio").read_text() == "old b"


def test_a_latest_fill_deleted_by_hand_is_refused_not_its_predecessor_rendered(tmp_path):
    """The latest fill layer removed by hand (its review layer left): ``tween review SHOT``
    rendered the fill before it as "its latest fill" (exit 0). Refused naming the missing
    layer; the earlier fill is still reviewed by its layer, and a writer's unfinished version
    (its temp there) is not taken for a deleted one."""
    shot, layer, review = _filled(tmp_path, takes=1)
    newer = fill_shot(str(shot), FillOptions(model="interp"))
    Path(newer["layer"]).unlink()
    err = _refused(tmp_path, shot)
    assert err.startswith(f"tween: error: {newer['layer']}: the latest fill of {shot} is not there"), err
    assert f"run tween fill again, or review an earlier fill by its layer: tween review {review}" in err
    temp = tmp_path / f".sh070.tween.v002.{owner_tag()}.tmp.usda"
    temp.write_text("")  # a live writer's (this process): its version is not finished
    r = _review(tmp_path, shot, "--out", tmp_path / "media")
    assert r.returncode == 0 and f"its latest fill, {review}" in r.stderr, r.stderr
    temp.unlink()
    layer.unlink()  # no fill left at all: not the shot rendered unfilled either
    assert "run tween fill again\n" in _refused(tmp_path, shot)


def test_an_earlier_review_is_replaced_only_with_force(tmp_path):
    """Nothing the user has is replaced without --force (the README): a second review of the
    same version and take re-rendered its MP4 over the first, exit 0. Refused naming it; with
    --all-takes no take renders; --force replaces the media."""
    shot, _, _ = _filled(tmp_path)
    media = tmp_path / "media"
    r = _review(tmp_path, shot, "--take", 1, "--out", media)
    assert r.returncode == 0, r.stderr
    mp4 = media / "sh070_v001_take1.mp4"
    first = mp4.stat().st_ino
    err = _refused(tmp_path, shot, "--take", 1)
    assert (
        err
        == f"tween: error: {mp4}: --out holds an earlier review of this take; give --force to replace its media, or another --out\n"
    )
    assert str(mp4) in _refused(tmp_path, shot, "--all-takes")  # take 0 not rendered either
    r = _review(tmp_path, shot, "--take", 1, "--out", media, "--force")
    assert r.returncode == 0, r.stderr
    assert mp4.stat().st_ino != first and sorted(p.name for p in media.iterdir() if p.suffix == ".mp4") == [
        mp4.name
    ]
