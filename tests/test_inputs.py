"""Every reader names a path that is not a regular file in the same words (pipeline.inputs)."""

import os

import pytest

from pipeline.inputs import not_a_file


def test_each_kind_of_path_is_named(tmp_path):
    (tmp_path / "shot.usda").write_text("#usda 1.0\n")
    (tmp_path / "link.usda").symlink_to(tmp_path / "shot.usda")
    (tmp_path / "gone.usda").symlink_to(tmp_path / "nowhere.usda")
    (tmp_path / "loop.usda").symlink_to(tmp_path / "loop.usda")
    os.mkfifo(tmp_path / "pipe.usda")
    assert not_a_file(tmp_path / "shot.usda", "shot file") is None
    assert not_a_file(tmp_path / "link.usda", "shot file") is None
    assert not_a_file(tmp_path, "shot file") == "a folder, not a shot file"
    assert not_a_file(tmp_path / "pipe.usda", "shot file") == (
        "not a regular file (a pipe, socket or device), not a shot file"
    )
    assert not_a_file("/dev/null", "BVH file").startswith("not a regular file")
    assert not_a_file(tmp_path / "gone.usda", "shot file") == "a link to nothing"
    assert not_a_file(tmp_path / "loop.usda", "shot file") == "a link to nothing"
    assert not_a_file(tmp_path / "none.usda", "shot file") == "file not found"
    assert not_a_file("a\0b.usda", "shot file") == "file not found"


@pytest.mark.parametrize(
    "argv, kind",
    [
        (["fill-local", "{p}"], "shot file"),
        (["review", "{p}", "-o", "{d}/review"], "shot file"),
        (["approve", "{p}", "--take", "0"], "shot file"),
        (["submit", "{p}"], "shot file"),
        (["convert", "{p}", "{d}/o.usda"], "BVH file"),
        (["rig-extract", "{p}", "{d}/clip.npz"], "clip file"),
    ],
    ids=lambda a: a[0] if isinstance(a, list) else "",
)
def test_every_reader_says_a_pipe_the_same_way(tmp_path, argv, kind):
    """A shot, take or clip that is a pipe: one line naming it, the same words from each command
    (they said "not a file", "is not a regular file", "not a regular file (a shot is a USD file)")."""
    import subprocess
    import sys

    pipe = tmp_path / ("take.bvh" if argv[0] in ("convert", "rig-extract") else "shot.usda")
    os.mkfifo(pipe)
    args = [a.format(p=pipe, d=tmp_path) for a in argv]
    env = {k: v for k, v in os.environ.items() if not k.startswith("TWEEN_")}
    env.update(TWEEN_FARM_CONFIG=os.devnull, TWEEN_BROKER_URL="redis://127.0.0.1:1/0")  # nothing is sent
    r = subprocess.run([sys.executable, "-m", "pipeline.cli", *args], capture_output=True, text=True,
                       timeout=120, env=env, cwd=tmp_path)  # fmt: skip
    assert r.returncode == 2, r.stderr
    assert r.stderr.splitlines() == [
        f"tween: error: {pipe}: not a regular file (a pipe, socket or device), not a {kind}"
    ]
    assert sorted(p.name for p in tmp_path.iterdir()) == [pipe.name]
