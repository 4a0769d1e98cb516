"""A render-only job (the dailies page's "render") that fails or is cancelled removes the media
it made and its scratch, never the fill version it rendered nor media that were there before."""

from workers import cleanup


def test_undo_of_a_render_only_job_keeps_the_version(tmp_path):
    fill = tmp_path / "sh010.tween.v002.usda"
    review = tmp_path / "sh010.review.v002.usda"
    fill.write_text("#usda 1.0\n")
    review.write_text("#usda 1.0\n")
    media = tmp_path / "review"
    media.mkdir()
    before = media / "sh010_v002_take0.mp4"
    before.write_bytes(b"x")
    other = media / "sh010_v001_take1.mp4"  # another version's
    other.write_bytes(b"x")
    made = [media / "sh010_v002_take1.mp4", media / "sh010_v002.otio", media / "sh010_v002_take1_contact.png"]
    for p in made:
        p.write_bytes(b"x")
    scratch = media / ".tween-review-abc.123@host.0.tmp"
    scratch.mkdir()
    (scratch / "f.png").write_bytes(b"x")
    job = {"id": "abc", "kind": "review", "review": str(review), "existing": [before.name]}
    removed = cleanup.undo(str(review), {}, job)
    assert sorted(removed) == sorted([str(scratch), *map(str, made)])
    assert fill.is_file() and review.is_file() and before.is_file() and other.is_file()
    assert cleanup.undo(str(review), {}, job) == []  # idempotent
