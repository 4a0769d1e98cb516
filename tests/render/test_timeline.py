"""The OpenTimelineIO timeline a review writes beside its media (issue 20, item 3)."""

from __future__ import annotations

from pathlib import Path

import opentimelineio as otio
import pytest
from render_fixtures import converted_review

from render.review import render_review

SIZE = (160, 90)


@pytest.fixture(scope="module")
def takes(tmp_path_factory, bandai_clip):
    """Both takes of a converted, filled 30-frame shot rendered one after the other into one
    folder, as the farm's render stage does (render_review once per take)."""
    work = tmp_path_factory.mktemp("otio")
    stage, keys = converted_review(bandai_clip, work, frames=30, key_step=10, takes=2)
    out = work / "review"
    results = [render_review(stage, str(out), take=t, size=SIZE, write_frames=False) for t in (1, 0)]
    return {"stage": stage, "keys": keys, "out": out, "results": results}


def test_one_track_per_take_with_the_mp4(takes):
    res = takes["results"]
    assert res[0]["timeline"] == res[1]["timeline"] == str(takes["out"] / "sh010_v001.otio")
    tl = otio.adapters.read_from_file(res[1]["timeline"])
    assert isinstance(tl, otio.schema.Timeline) and tl.name == "sh010 v001"
    assert [t.name for t in tl.tracks] == ["take0", "take1"]  # sorted by take, whatever the order
    for track, take in zip(tl.tracks, (0, 1), strict=True):
        assert track.kind == otio.schema.TrackKind.Video
        (clip,) = list(track.find_clips())
        ref = clip.media_reference
        assert isinstance(ref, otio.schema.ExternalReference)
        assert ref.target_url == f"sh010_v001_take{take}.mp4"
        media = Path(res[1]["timeline"]).parent / ref.target_url
        assert media.is_file()
        assert clip.source_range.start_time.to_frames() == 1001
        assert clip.source_range.duration.to_frames() == 30
        assert ref.available_range == clip.source_range
        assert track.duration().to_frames() == 30


def test_rate_is_the_movies(takes):
    import av

    tl = otio.adapters.read_from_file(takes["results"][0]["timeline"])
    for track in tl.tracks:
        (clip,) = list(track.find_clips())
        with av.open(str(takes["out"] / clip.media_reference.target_url)) as box:
            rate = box.streams.video[0].average_rate
        assert clip.source_range.start_time.rate == float(rate) == 30
        assert tl.global_start_time.rate == 30 and tl.global_start_time.to_frames() == 1001


def test_markers_on_the_keys(takes):
    tl = otio.adapters.read_from_file(takes["results"][0]["timeline"])
    for track, res in zip(tl.tracks, takes["results"][::-1], strict=True):
        (clip,) = list(track.find_clips())
        times = [m.marked_range.start_time.to_frames() for m in clip.markers]
        assert times == takes["keys"] == res["key_frames"] == [1001, 1011, 1021, 1030]
        assert all(m.metadata["tween"]["frame"] == t for m, t in zip(clip.markers, times, strict=True))
        assert {m.color for m in clip.markers} == {otio.schema.MarkerColor.ORANGE}


def test_metadata_model_and_take(takes):
    tl = otio.adapters.read_from_file(takes["results"][0]["timeline"])
    assert tl.metadata["tween"]["model"] == "interpolation"
    assert list(tl.metadata["tween"]["takes"]) == ["take0", "take1"]
    for n, track in enumerate(tl.tracks):
        (clip,) = list(track.find_clips())
        for meta in (track.metadata["tween"], clip.metadata["tween"]):
            assert meta["take"] == f"take{n}" and meta["take_number"] == n
            assert meta["model"] == "interpolation"
            assert meta["model_hash"] == "none"  # the interpolation model has no weights
            assert list(meta["frame_range"]) == [1001, 1030]
            assert meta["contact_sheet"] == f"sh010_v001_take{n}_contact.png"


def test_rerender_replaces_its_track(takes, tmp_path):
    """Rendering a take again replaces its track and keeps the other; a shot without takes
    gets a 'main' track; frames written are named in the metadata."""
    out = takes["out"]
    again = render_review(
        takes["stage"], str(out), take=1, size=SIZE, write_frames=True, frame_range=(1005, 1012)
    )
    tl = otio.adapters.read_from_file(again["timeline"])
    assert [t.name for t in tl.tracks] == ["take0", "take1"]
    clip = list(tl.tracks[1].find_clips())[0]
    assert clip.source_range.start_time.to_frames() == 1005
    assert [m.marked_range.start_time.to_frames() for m in clip.markers] == [1011]
    assert clip.metadata["tween"]["frames"] == "sh010_v001_take1.####.png"
    assert list(tl.tracks[0].find_clips())[0].source_range.duration.to_frames() == 30


def test_cli_all_takes_writes_the_timeline(takes, tmp_path):
    import json
    import subprocess
    import sys

    r = subprocess.run(
        [sys.executable, "-m", "pipeline.cli", "review", takes["stage"], "--all-takes", "--size", "160x90",
         "--no-frames", "--frames", "1001:1003", "--camera", "fixed", "-o", str(tmp_path)],
        capture_output=True, text=True,
    )  # fmt: skip
    assert r.returncode == 0, r.stderr
    summaries = json.loads(r.stdout)
    assert [s["framing"] for s in summaries] == ["fixed", "fixed"]
    tl = otio.adapters.read_from_file(str(tmp_path / "sh010_v001.otio"))
    assert [t.name for t in tl.tracks] == ["take0", "take1"]


def test_takes_over_different_frames_line_up_on_the_shots_frame_numbers(tmp_path):
    """Takes rendered over different --frames: each track starts with a gap up to its first
    frame, so one timeline frame is one shot frame on every track (before, both clips started
    at track time 0 and the global start was the last take's first frame)."""
    from render.timeline import take_track, update_timeline

    tl_path = tmp_path / "sh.otio"
    for take, frames in (
        ("take0", range(1001, 1098)),
        ("take2", range(1020, 1031)),
        ("take1", range(1050, 1061)),
    ):
        track = take_track(f"{take}.mp4", 24, list(frames), [frames[0]], take, {})
        update_timeline(tl_path, tl_path, "sh", track, {})
    tl = otio.adapters.read_from_file(str(tl_path))
    assert tl.global_start_time.to_frames() == 1001
    for track in tl.tracks:
        (clip,) = list(track.find_clips())
        at = track.range_of_child(clip).start_time.to_frames()
        assert tl.global_start_time.to_frames() + at == clip.source_range.start_time.to_frames(), track.name
    # Re-rendering take0 over later frames moves the start; the others keep their frames.
    track = take_track("take0.mp4", 24, list(range(1030, 1040)), [], "take0", {})
    update_timeline(tl_path, tl_path, "sh", track, {})
    tl = otio.adapters.read_from_file(str(tl_path))
    assert tl.global_start_time.to_frames() == 1020
    starts = {t.name: tl.global_start_time.to_frames() + t.range_of_child(t.find_clips()[0]).start_time.to_frames()
              for t in tl.tracks}  # fmt: skip
    assert starts == {"take0": 1030, "take1": 1050, "take2": 1020}
