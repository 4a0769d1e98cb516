"""A studio's motion library: building it from takes of any rig, and filling gaps from it.

The library is built from real takes (Bandai clips on the model skeleton, a CMU take on a
100-joint rig at 60 fps) through the product's own reading; the fill is checked against the
motion it came from."""

from __future__ import annotations

import json
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from library_fixtures import BANDAI, CMU_TAKE, HELD_OUT  # noqa: F401  (fixtures: conftest)

from pipeline.infer.plant import model_feet, plant_rotations
from pipeline.infer.spline import spline_keys
from pipeline.infer.trust import CURVE
from pipeline.library import match
from pipeline.library.build import build
from pipeline.library.infer import LibraryInbetweener, gap_weight, key_bend_cm
from pipeline.library.store import ARRAYS, MANIFEST, LibraryError, open_library
from pipeline.motion.bvh import read_bvh, write_bvh
from pipeline.motion.fk import fk
from pipeline.motion.rotations import slerp_pairs
from pipeline.usd.take import studio_take


def _err_cm(skel, rot, root, true_rot, true_root, frames):
    _, a = fk(rot[frames], root[frames], skel.parents, skel.offsets)
    _, b = fk(true_rot[frames], true_root[frames], skel.parents, skel.offsets)
    return float(np.linalg.norm(a - b, axis=-1).mean())


def test_a_library_holds_every_take_on_the_model_skeleton_with_a_manifest(library, takes):
    lib = open_library(library)
    m = lib.manifest
    assert {t["name"] for t in m["takes"]} == {*BANDAI, CMU_TAKE}
    assert m["licence"] == "studio-internal" and m["fps"] == 30.0
    assert lib.frames == sum(t["frames"] for t in m["takes"])
    assert m["hours"] == pytest.approx(lib.frames / 30 / 3600, abs=1e-6)
    # The Bandai takes are read exactly; the CMU take (60 fps, another rig) is resampled to 30.
    for t in m["takes"]:
        want = studio_take(takes / ("cmu/" if t["name"] == CMU_TAKE else "") / t["name"])
        got = lib.rotations[t["start"] : t["start"] + t["frames"]]
        assert np.array_equal(got, want.rotations)
        assert lib.take_end[t["start"]] == t["start"] + t["frames"] - 1
    cmu = next(t for t in m["takes"] if t["name"] == CMU_TAKE)
    assert cmu["frames"] == len(read_bvh(takes / "cmu" / CMU_TAKE).rotations[::2])
    assert cmu["rig"].startswith("BVH, 101 joints from RL_BoneRoot")
    # Memory-mapped, read-only: a worker shares one copy in the page cache.
    assert isinstance(lib.features, np.memmap) and not lib.features.flags.writeable
    assert lib.features.shape == (lib.frames, *ARRAYS["features"][1])


def test_add_appends_new_takes_only_and_versions_the_library(library, takes, tmp_path, data_dir):
    copy = tmp_path / "lib"
    shutil.copytree(library, copy)
    before = open_library(copy)
    h0, n0 = before.hash, before.frames
    again = build(takes, copy, add=True, progress=False)
    assert again["added"] == 0 and again["skipped"] == 4 and again["hash"] == h0
    more = tmp_path / "more"
    more.mkdir()
    shutil.copy(data_dir / "bandai_namco" / "dataset-2" / HELD_OUT, more / HELD_OUT)
    res = build(more, copy, add=True, progress=False)
    lib = open_library(copy)
    assert res["added"] == 1 and lib.frames > n0 and lib.hash != h0
    # The takes already there are untouched, byte for byte.
    assert np.array_equal(lib.rotations[:n0], before.rotations)
    # An add that died after writing frames but before its manifest is cut off by the next.
    with open(copy / "rotations.bin", "ab") as f:
        f.write(b"\0" * 4096)
    assert open_library(copy).frames == lib.frames
    build(more, copy, add=True, progress=False)
    assert (copy / "rotations.bin").stat().st_size == lib.frames * 21 * 4 * 4


def test_a_bad_take_is_one_line_and_the_others_go_on(takes, tmp_path, data_dir, capsys):
    folder = tmp_path / "takes"
    shutil.copytree(takes, folder)
    (folder / "broken.bvh").write_text("HIERARCHY\nROOT Hips\n{\n")
    res = build(folder, tmp_path / "lib", progress=False)
    err = capsys.readouterr().err
    assert res["added"] == 4 and len(res["failed"]) == 1
    lines = [ln for ln in err.splitlines() if "broken.bvh" in ln]
    assert len(lines) == 1 and lines[0].startswith("tween: skipped take:")


def test_an_existing_library_is_not_overwritten_without_add(library, takes):
    before = (library / MANIFEST).read_bytes()
    with pytest.raises(LibraryError, match="use --add"):
        build(takes, library, progress=False)
    assert (library / MANIFEST).read_bytes() == before


def test_a_read_only_out_folder_is_refused_even_for_root(takes, tmp_path, capsys):
    """Before: root built a library into a folder of mode 555."""
    from cli_contract import refused

    ro = tmp_path / "ro"
    ro.mkdir()
    ro.chmod(0o555)
    try:
        line = refused(["library", "build", takes, "--out", ro / "lib"], capsys, tmp_path)
        assert (
            line
            == f"tween: error: {ro / 'lib'}: --out is in {ro}, which is read-only; give a folder you can write"
        )
        line = refused(["library", "build", takes, "--out", ro], capsys, tmp_path)
        assert line == f"tween: error: {ro}: --out is read-only; give a folder you can write"
    finally:
        ro.chmod(0o755)


def _edit(**change):
    def damage(folder):
        m = json.loads((folder / MANIFEST).read_text())
        m.update(change)
        (folder / MANIFEST).write_text(json.dumps(m))

    return damage


def _edit_take(**change):
    def damage(folder):
        m = json.loads((folder / MANIFEST).read_text())
        m["takes"][0].update(change)
        m["takes"][0] = {k: v for k, v in m["takes"][0].items() if v is not None}
        (folder / MANIFEST).write_text(json.dumps(m))

    return damage


@pytest.mark.parametrize(
    "damage, message",
    [
        (lambda d: (d / MANIFEST).unlink(), "not a library"),
        (lambda d: (d / MANIFEST).write_text("{not json"), "cannot read"),
        (lambda d: (d / MANIFEST).write_text(json.dumps({"kind": "something"})), "not a usd-tween library"),
        (lambda d: (d / "features.bin").write_bytes(b"\0" * 8), "features.bin"),
        (lambda d: (d / "roots.bin").unlink(), "roots.bin: missing"),
        # A damaged or hand-edited manifest: named before the search or the fill reads it.
        (_edit(fps="thirty"), "'fps' is 'thirty', not a frame rate"),
        (_edit(fps=0), "'fps' is 0, not a frame rate"),
        (_edit(fps=float("nan")), "'fps' is nan, not a frame rate"),
        (_edit(fps=1e-300), "'fps' is 1e-300, not a frame rate"),
        (_edit(hours=float("inf")), "'hours' is inf, not a number of hours"),
        (_edit(hash=5), "'hash' is 5, not a string"),
        (_edit(licence=7), "'licence' is 7, not a string"),
        (_edit(takes=[]), "its takes hold 0 frames, its 'frames' says"),
        (_edit_take(name=None), "take 0 has no 'name'"),
        (_edit_take(frames=10**9), "after 1000000000 frames of takes"),
        (_edit_take(frames="many"), "has no whole 'start' and 'frames'"),
        (_edit_take(start=3), "starts at frame 3, after 0 frames of takes"),
    ],
)
def test_a_broken_library_is_one_line_naming_it(library, tmp_path, damage, message):
    copy = tmp_path / "lib"
    shutil.copytree(library, copy)
    damage(copy)
    with pytest.raises(LibraryError, match=message) as e:
        LibraryInbetweener(copy)
    assert "\n" not in str(e.value) and str(copy) in str(e.value)


def _overwrite(name: str, value):
    def damage(folder):
        f = folder / f"{name}.bin"
        dtype = np.dtype(ARRAYS[name][0])
        f.write_bytes(np.full(f.stat().st_size // dtype.itemsize, value, dtype).tobytes())

    return damage


@pytest.mark.parametrize(
    "damage, message",
    [
        (_overwrite("rotations", np.nan), "rotations.bin or roots.bin, frames"),
        (_overwrite("roots", np.inf), "roots.bin"),
        (_overwrite("features", np.nan), "features.bin"),
    ],
)
def test_library_arrays_that_are_not_numbers_are_one_line_naming_the_file(
    library, takes, tmp_path, damage, message
):
    """Damage inside the arrays (their sizes right): named where the search reads them, never
    a fill of NaN (which the trusted fill's probes turned into an internal error)."""
    copy = tmp_path / "lib"
    shutil.copytree(library, copy)
    damage(copy)
    m = read_bvh(takes / BANDAI[0]).continuous().slice(0, 61)
    with pytest.raises(LibraryError, match=message) as e:
        LibraryInbetweener(copy).fill(m, np.r_[0:61:10])
    assert str(e.value).startswith(str(copy)) and str(e.value).endswith(
        "not finite numbers (the library is damaged; build it again)"
    )


def test_a_damaged_take_end_file_changes_nothing(library, takes, tmp_path):
    """Where each take ends comes from the manifest (checked to tile the frames), so windows
    never run across takes whatever take_end.bin holds."""
    copy = tmp_path / "lib"
    shutil.copytree(library, copy)
    _overwrite("take_end", 2**30)(copy)
    m = read_bvh(takes / BANDAI[0]).continuous().slice(0, 151)
    keys = np.r_[0:151:10]
    a, b = LibraryInbetweener(library).fill(m, keys), LibraryInbetweener(copy).fill(m, keys)
    assert np.array_equal(a.rotations, b.rotations) and np.array_equal(a.root_positions, b.root_positions)
    ends = open_library(copy).take_end
    assert ends.max() == open_library(copy).frames - 1 and np.all(np.diff(ends) >= 0)


def test_a_take_of_the_library_comes_back_from_its_keys(library, takes):
    """The library holds the very take: every gap finds its own stretch, fitted to the keys."""
    inb = LibraryInbetweener(library)
    m = read_bvh(takes / BANDAI[0]).continuous().slice(0, 151)
    keys = np.r_[0:151:10]
    out = inb.fill(m, keys)
    inside = np.setdiff1d(np.arange(len(m)), keys)
    lib_cm = _err_cm(inb.skeleton, out.rotations, out.root_positions, m.rotations, m.root_positions, inside)
    s_rot, s_root = spline_keys(m.rotations, m.root_positions, keys)
    spline_cm = _err_cm(inb.skeleton, s_rot, s_root, m.rotations, m.root_positions, inside)
    assert lib_cm < 0.35 * spline_cm
    # Keys are the input's, bit for bit; every gap is the library's, and says which take.
    assert np.array_equal(out.rotations[keys], m.rotations[keys])
    assert np.array_equal(out.root_positions[keys], m.root_positions[keys])
    assert all(g["weight"] == 1.0 and g["windows"][0][0] == BANDAI[0] for g in inb.last_gaps)


def test_a_held_out_take_of_the_same_motion_beats_the_spline(library, data_dir):
    inb = LibraryInbetweener(library)
    m = read_bvh(data_dir / "bandai_namco" / "dataset-2" / HELD_OUT).continuous()
    keys = np.unique(np.r_[0 : len(m) : 10, len(m) - 1])
    out = inb.fill(m, keys)
    inside = np.setdiff1d(np.arange(len(m)), keys)
    s_rot, s_root = spline_keys(m.rotations, m.root_positions, keys)
    lib_cm = _err_cm(inb.skeleton, out.rotations, out.root_positions, m.rotations, m.root_positions, inside)
    spline_cm = _err_cm(inb.skeleton, s_rot, s_root, m.rotations, m.root_positions, inside)
    assert lib_cm < 0.8 * spline_cm


def test_keys_unlike_every_take_are_the_splines(library, takes):
    inb = LibraryInbetweener(library)
    keys = np.array([0, 10, 20])
    still = read_bvh(takes / BANDAI[0]).continuous().slice(0, 21)
    # Keys in poses no take holds (every joint turned 90° about X): the spline.
    odd = still.rotations.copy()
    odd[:, 1:] = [0.7071068, 0.0, 0.0, 0.7071068]
    weird = type(still)(still.skeleton, odd, still.root_positions, still.fps)
    out = inb.fill(weird, keys)
    s_rot, s_root = spline_keys(weird.rotations, weird.root_positions, keys, CURVE)
    assert np.array_equal(out.rotations, s_rot.astype(np.float32))
    assert [g["weight"] for g in inb.last_gaps] == [0.0, 0.0]
    assert all("no motion like the keys" in g["why"] for g in inb.last_gaps)


def test_a_gap_longer_than_every_take_is_the_splines(library, takes):
    inb = LibraryInbetweener(library)
    longest = max(t["frames"] for t in inb.library.manifest["takes"])
    m = read_bvh(takes / BANDAI[0]).continuous()
    T = longest + 5
    idx = np.arange(T) % len(m)
    long = type(m)(m.skeleton, m.rotations[idx], m.root_positions[idx], m.fps)
    keys = np.array([0, 4, T - 1])
    out = inb.fill(long, keys)
    s_rot, _ = spline_keys(long.rotations, long.root_positions, keys)
    assert np.allclose(out.rotations[5 : T - 1], s_rot[5 : T - 1], atol=1e-6)
    assert inb.last_gaps[1]["weight"] == 0.0 and inb.last_gaps[1]["why"]


def test_partial_keys_keep_their_keyed_joints(library, takes):
    inb = LibraryInbetweener(library)
    m = read_bvh(takes / BANDAI[1]).continuous().slice(0, 41)
    keys = np.array([0, 10, 20, 30, 40])
    mask = np.ones((5, len(inb.skeleton) + 1), bool)
    mask[2, 13:] = False  # the key at 20 sets the upper body and root only: its legs are not keyed
    odd = m.rotations.copy()
    odd[20, 13:] = [0.7071068, 0.0, 0.0, 0.7071068]  # whatever is there is not a key
    m = type(m)(m.skeleton, odd, m.root_positions, m.fps)
    out = inb.fill(m, keys, joint_keys=mask)
    assert np.allclose(out.rotations[20, :13], m.rotations[20, :13], atol=1e-6)
    free = inb.fill(m, np.array([0, 10, 30, 40]))
    assert np.allclose(out.rotations[20, 13:], free.rotations[20, 13:], atol=1e-6)
    assert np.array_equal(out.rotations[[0, 10, 30, 40]], m.rotations[[0, 10, 30, 40]])


def test_the_match_gate_prefers_the_spline_where_the_keys_barely_move():
    assert gap_weight(2.0, 20.0) == 1.0
    assert gap_weight(20.0, 20.0) == 0.0  # a poor match
    assert gap_weight(3.0, 0.5) == 0.0  # a good match of keys that hardly move: the spline is right
    assert 0.0 < gap_weight(8.0, 30.0) < 1.0


def test_the_gate_sends_keys_on_a_smooth_curve_to_the_spline():
    t = np.arange(0.0, 70.0, 10.0)
    # One "joint" on a parabola and the root's height: the cubic through the neighbours is exact.
    feats = np.stack([-0.1 * t**2 + t, 3.0 * t, 0.05 * t**2, np.full_like(t, 90.0)], 1)
    assert np.allclose(key_bend_cm(feats, t), 0.0, atol=1e-9)
    bumped = feats.copy()
    bumped[3, :3] += 4.0
    bend = key_bend_cm(bumped, t)
    assert bend[3] > 2.0 and bend[0] == bend[1] and bend[-1] == bend[-2]
    assert gap_weight(2.0, 20.0, 0.3) == 0.0  # the spline follows such keys already
    assert gap_weight(2.0, 20.0, 5.0) == 1.0 and 0.0 < gap_weight(2.0, 20.0, 0.75) < 1.0


def test_a_slow_smooth_move_the_library_holds_is_the_splines(takes, tmp_path):
    """A studio's take of a slow, smooth move (a pose drifting into the next over four
    seconds), keyed every 10 frames: the library holds the very motion, so its match is
    perfect and the match gate alone would take it; but the keys lie on a curve the spline
    follows, so every gap is the spline's, and the fill is the trusted curve's bit for bit
    (its feet planted where the keys plant them, pipeline.infer.plant)."""
    m = read_bvh(takes / BANDAI[2]).continuous()
    a, b = m.rotations[0], m.rotations[3]
    t = np.linspace(0.0, 1.0, 121)[:, None] * np.ones(len(a))
    rot = slerp_pairs(np.broadcast_to(a, t.shape + (4,)), np.broadcast_to(b, t.shape + (4,)), t)
    root = m.root_positions[0] + t[:, :1] * (m.root_positions[3] - m.root_positions[0])
    slow = type(m)(m.skeleton, rot.astype(np.float32), root.astype(np.float32), m.fps)
    (tmp_path / "takes").mkdir()
    write_bvh(slow, tmp_path / "takes" / "slow.bvh")
    build(tmp_path / "takes", tmp_path / "lib", progress=False)
    inb = LibraryInbetweener(tmp_path / "lib")
    keys = np.r_[0:91:10]
    out = inb.fill(slow.slice(0, 91), keys)
    gaps = inb.last_gaps
    assert all(gap_weight(g["miss_cm"], g["change_cm"]) == 1.0 for g in gaps)  # matched in full
    assert all(g["weight"] == 0.0 and "smooth curve" in g["why"] for g in gaps)
    s_rot, s_root = spline_keys(slow.rotations[:91], slow.root_positions[:91], keys, CURVE)
    s_rot = plant_rotations(s_rot, s_root, inb.skeleton, keys, model_feet(inb.skeleton))
    assert np.array_equal(out.rotations, s_rot.astype(np.float32))
    assert np.array_equal(out.root_positions, s_root.astype(np.float32))


def test_search_finds_the_window_of_least_cost_by_brute_force(library):
    """The search's best window is the one a plain loop over every window of every take finds,
    and a window of the library itself is found at no cost."""
    lib = open_library(library)
    n = 12
    a = next(s for s in range(200, lib.frames) if lib.take_end[s] >= s + n)
    feats = np.asarray(lib.features[[a, a + n]])
    face = np.asarray(lib.facing[[a, a + n]], np.float64)
    travel = match.batch_quat_apply(face[0], np.asarray(lib.roots[a + n], np.float64) - lib.roots[a])[[0, 2]]
    turn = float(match.wrap_angle(match.yaw_of(face[0]) - match.yaw_of(face[1])))
    d = match.key_distances(lib, feats)
    got = match.search(lib, d[0], d[1], n, travel, turn, best=3)
    assert got.starts[0] == a and got.pose_cm[0] < 1e-2 and got.cost[0] < 0.05

    def cost(s):
        pose = sum(
            np.sqrt(((lib.features[f] - x) ** 2).sum() / 21) for f, x in ((s, feats[0]), (s + n, feats[1]))
        )
        f0 = np.asarray(lib.facing[s], np.float64)
        disp = match.batch_quat_apply(f0, np.asarray(lib.roots[s + n], np.float64) - lib.roots[s])[[0, 2]]
        t = match.wrap_angle(match.yaw_of(f0) - match.yaw_of(np.asarray(lib.facing[s + n], np.float64)))
        return (
            pose
            + match.DISP_WEIGHT * np.linalg.norm(disp - travel)
            + match.TURN_WEIGHT * abs(match.wrap_angle(t - turn))
        )

    brute = sorted((cost(s), s) for s in range(lib.frames - n) if lib.take_end[s] >= s + n)
    assert [s for _, s in brute[:3]] == list(got.starts)
    assert np.allclose([c for c, _ in brute[:3]], got.cost, atol=1e-3)


def test_tween_library_build_and_info_from_the_command_line(takes, tmp_path):
    out = tmp_path / "lib"
    r = subprocess.run([sys.executable, "-m", "pipeline.cli", "library", "build", str(takes), "--out", str(out),
                        "--licence", "CC BY 4.0", "--no-progress"], capture_output=True, text=True)  # fmt: skip
    assert r.returncode == 0, r.stderr
    assert json.loads(r.stdout)["takes"] == 4
    r = subprocess.run([sys.executable, "-m", "pipeline.cli", "library", "info", str(out)], capture_output=True,
                       text=True)  # fmt: skip
    assert r.returncode == 0 and "4 take(s)" in r.stdout and "CC BY 4.0" in r.stdout
    r = subprocess.run([sys.executable, "-m", "pipeline.cli", "library", "info", str(tmp_path)], capture_output=True,
                       text=True)  # fmt: skip
    assert r.returncode == 2 and r.stderr.count("\n") == 1 and r.stderr.startswith("tween: error:")


@settings(max_examples=30, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(
    content=st.one_of(
        st.binary(max_size=300),
        st.text(max_size=300).map(str.encode),
        st.sampled_from(
            [
                b"HIERARCHY\nROOT Hips\n{\n OFFSET 0 0 0\n CHANNELS 3 Xrotation\n}\nMOTION\nFrames: 1\n"
                b"Frame Time: 0.0333\n0 0 0\n",
                b"#usda 1.0\n",
                b"\x1f\x8b\x08\x00garbage",
            ]
        ),  # fmt: skip
    ),
    suffix=st.sampled_from([".bvh", ".bvh.gz", ".usda", ".usd"]),
)
def test_any_unreadable_take_is_one_line_and_the_good_take_goes_in(tmp_path_factory, takes, content, suffix):
    import contextlib
    import io

    folder = tmp_path_factory.mktemp("gen")
    shutil.copy(takes / BANDAI[0], folder / BANDAI[0])
    (folder / f"bad{suffix}").write_bytes(content)
    err = io.StringIO()
    with contextlib.redirect_stderr(err):
        res = build(folder, folder / "lib", progress=False)
    assert res["takes"] == 1 + (not res["failed"]) and res["added"] == res["takes"]
    lines = [ln for ln in err.getvalue().splitlines() if f"bad{suffix}" in ln]
    assert len(lines) == len(res["failed"]) <= 1
    assert all(ln.startswith("tween: skipped take:") for ln in lines)


@pytest.mark.parametrize(("lead", "chosen"), [(0.5, "library:studio"), (2.0, "network")])
def test_the_network_fills_a_library_character_only_when_its_probes_beat_the_librarys_by_a_margin(
    library, monkeypatch, lead, chosen
):
    """The probes' holes are twice the shot's gaps, which flatters the network: it takes over
    from the library only when its score beats the library's by the library's margin (``lead``:
    the network's lead in margins)."""
    from pipeline.infer import trust

    inb = LibraryInbetweener(library)
    net = type("Net", (), {"name": "network", "model_hash": "n", "skeleton": inb.skeleton, "fps": inb.fps,
                           "capabilities": inb.capabilities})()  # fmt: skip
    margin = inb.capabilities.probe_margin
    assert 0.0 < margin < 1.0
    scores = {inb.name: 0.1, "network": 0.1 + lead * margin}
    monkeypatch.setattr(trust, "decide", lambda m, s, *a, **k: trust.TrustDecision("model", 1.0, 1.0, 2.0,
                                                                                    score=scores[m.name]))  # fmt: skip
    t = trust.TrustedInbetweener(inb, alternatives=(net,))
    d = t.decide(None, np.array([0, 10, 20]))
    assert d.source == chosen and t.model.name == chosen


def test_a_damaged_manifest_is_one_line_from_every_command(library, takes, tmp_path, capsys):
    """`library info`, `library build --add` and `fill-local --library` on a manifest whose
    frame rate is NaN (before: internal errors, and the fill went on at NaN fps)."""
    from cli_contract import refused

    copy = tmp_path / "lib"
    shutil.copytree(library, copy)
    _edit(fps=float("nan"))(copy)
    shot = Path(__file__).resolve().parents[2] / "examples" / "sh010_walk.usda"
    for argv in (
        ["library", "info", copy],
        ["library", "build", takes, "--out", copy, "--add"],
        ["fill-local", shot, "--library", copy, "--out-dir", tmp_path / "out"],
    ):
        line = refused(argv, capsys, copy)
        assert (
            line
            == f"tween: error: {copy / MANIFEST}: 'fps' is nan, not a frame rate (the manifest is damaged; build the library again)"
        )
    assert not (tmp_path / "out").exists()


def test_a_first_build_stopped_by_sigterm_leaves_nothing_and_can_be_run_again(takes, tmp_path):
    """SIGTERM (a farm's kill) during a first build unwinds like Ctrl-C: exit 130, no folder.
    Before, it left array files without library.json, which refused every retry."""
    import signal
    import time

    out = tmp_path / "lib"
    cmd = [sys.executable, "-m", "pipeline.cli", "library", "build", str(takes), "--out", str(out)]
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    t0 = time.monotonic()
    while not (out / "rotations.bin").exists():
        assert proc.poll() is None and time.monotonic() - t0 < 120, "the build ended before it wrote"
        time.sleep(0.01)
    proc.send_signal(signal.SIGTERM)
    _, err = proc.communicate(timeout=60)
    assert proc.returncode == 130, err[-2000:]
    assert err.strip().splitlines()[-1] == "tween: interrupted"
    assert not out.exists()


def test_what_a_killed_first_build_left_is_removed_and_the_build_goes_on(takes, tmp_path):
    """SIGKILL or a lost host leave array files with no manifest: the next build removes
    them (and says so), and builds. A folder with anything else in it is still refused."""
    out = tmp_path / "lib"
    out.mkdir()
    for name in ("rotations.bin", "roots.bin", ".library.json.x1.tmp"):
        (out / name).write_bytes(b"\0" * 64)
    res = subprocess.run(
        [sys.executable, "-m", "pipeline.cli", "library", "build", str(takes), "--out", str(out)],
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert res.returncode == 0, res.stderr[-2000:]
    assert (
        f"tween: {out}: removing the 3 file(s) a build that was stopped left (no library.json)" in res.stderr
    )
    assert open_library(out).manifest["takes"] and not (out / ".library.json.x1.tmp").exists()

    other = tmp_path / "other"
    other.mkdir()
    (other / "rotations.bin").write_bytes(b"\0")
    (other / "notes.txt").write_text("mine")
    with pytest.raises(LibraryError, match="not empty"):
        build(takes, other, progress=False)
    assert sorted(p.name for p in other.iterdir()) == ["notes.txt", "rotations.bin"]


@pytest.mark.parametrize("where", ["mkdir", "lock"])
def test_an_interrupt_just_after_the_library_folder_is_made_leaves_none(tmp_path, monkeypatch, where):
    """Ctrl-C just after the build made --out (and the folders above it), before its clean-up
    noted them, or once it held the lock, before a file was written: ``out`` was left,
    empty (as `tween train` left its run folder)."""
    from interrupt_fixtures import interrupt_after_mkdir

    from pipeline.usd import files

    if where == "mkdir":
        interrupt_after_mkdir(monkeypatch)
    else:

        def interrupted(lock):
            raise KeyboardInterrupt

        monkeypatch.setattr(files, "mark_holder", interrupted)
    with pytest.raises(KeyboardInterrupt):
        build(None, tmp_path / "libs" / "lib", files=[], progress=False)
    assert list(tmp_path.iterdir()) == []


def test_a_file_given_as_a_library_folder_says_so(tmp_path):
    """`library info FILE` said "no such library folder", `library build --out FILE` "not
    empty": the file is there, so the line says what it is."""
    from pipeline.library.build import check_out

    f = tmp_path / "notes.txt"
    f.write_text("x")
    with pytest.raises(LibraryError, match=r"notes\.txt: a file, not a library folder"):
        open_library(f)
    with pytest.raises(LibraryError, match=r"notes\.txt: a file, not a folder; use --add"):
        check_out(f, add=False)
    assert f.read_text() == "x"


def test_info_shows_one_line_a_take_and_build_refuses_texts_that_are_not_one_line(takes, tmp_path, capsys):
    """Before: a take whose file name held a newline was two lines of `library info`, and
    ``--licence``/``--name`` took any text into library.json and every fill's record."""
    from cli_contract import refused, succeeded

    odd = tmp_path / "odd"
    odd.mkdir()
    shutil.copy(takes / BANDAI[0], odd / "walk\nrun.bvh")
    out = tmp_path / "lib"
    for flag, bad in (("--licence", "CC BY\n4.0"), ("--name", "   "), ("--licence", "x" * 201)):
        line = refused(["library", "build", odd, "--out", out, flag, bad, "--no-progress"], capsys, tmp_path)
        assert line.startswith(f"tween: error: {flag} ") and "one line of printable text" in line
    for bad in ("", " , "):  # an --include naming no glob read every take
        line = refused(["library", "build", odd, "--out", out, "--include", bad], capsys, tmp_path)
        assert line.startswith(f"tween: error: --include {bad!r}: names no file-name glob"), line
    assert not out.exists()
    succeeded(["library", "build", odd, "--out", out, "--licence", "CC BY 4.0", "--no-progress"], capsys)
    shown = succeeded(["library", "info", out], capsys).splitlines()
    assert len(shown) == 2 and "walk\\nrun" in shown[1], shown
    # A take that cannot be read, named with a newline: the error is one line, and says why.
    bad = tmp_path / "bad"
    bad.mkdir()
    (bad / "bad\nname.bvh").write_text("junk\n")
    line = refused(["library", "build", bad, "--out", tmp_path / "lib2", "--no-progress"], capsys, tmp_path)
    assert line.endswith("bad\\nname.bvh:1: expected HIERARCHY at the start of the file)"), line


def test_builds_of_one_library_at_once_take_turns_and_lose_no_take(takes, tmp_path):
    """Two `library build --add` on one library at once both exited 0, each wrote its own
    manifest over the other's, and the arrays held both's frames: one run's takes were lost
    and another take's motion filled under their names. Now a build waits for the one
    writing (saying so), then reads the library again. Two first builds into one new folder
    take turns the same way: the second is an add, or refused without --add."""
    import time

    from pipeline.atomic import locked
    from pipeline.library.build import LOCK

    parts = {}
    for i, name in enumerate(BANDAI[:2]):
        parts[i] = tmp_path / f"part{i}"
        parts[i].mkdir()
        shutil.copy(takes / name, parts[i] / name)
    out = tmp_path / "lib"
    out.mkdir()
    cmd = [sys.executable, "-m", "pipeline.cli", "library", "build"]
    waiting = f"tween: {out}: another build is writing this library; waiting for it"
    errs = [tmp_path / f"add{i}.err" for i in (0, 1)]
    with locked(out / LOCK):  # another build holds the library: both wait for it, and say so
        procs = [subprocess.Popen([*cmd, str(parts[i]), "--out", str(out), "--add"], stdout=subprocess.DEVNULL,
                                  stderr=errs[i].open("w"), text=True) for i in (0, 1)]  # fmt: skip
        t0 = time.monotonic()
        while not all(e.exists() and waiting in e.read_text() for e in errs):
            assert all(p.poll() is None for p in procs), "a build did not wait for the lock"
            assert time.monotonic() - t0 < 120, [e.read_text() for e in errs]
            time.sleep(0.1)
    for p, e in zip(procs, errs, strict=True):
        assert p.wait(timeout=300) == 0, e.read_text()[-2000:]
    lib = open_library(out)
    assert sorted(t["name"] for t in lib.manifest["takes"]) == sorted(BANDAI[:2])
    assert lib.frames == sum(t["frames"] for t in lib.manifest["takes"]) == len(lib.rotations)
    info = subprocess.run([*cmd[:-1], "info", str(out)], capture_output=True, text=True, timeout=300)
    assert info.returncode == 0, info.stderr  # every array checked against the manifest
    assert sorted(p.name for p in out.iterdir()) == sorted([MANIFEST, *(f"{a}.bin" for a in ARRAYS)])

    # Two first builds of one new folder: the one that waited finds a library, and says so.
    new = tmp_path / "new"
    new.mkdir()
    with locked(new / LOCK):
        procs = [subprocess.Popen([*cmd, str(parts[i]), "--out", str(new)], stdout=subprocess.PIPE,
                                  stderr=subprocess.PIPE, text=True) for i in (0, 1)]  # fmt: skip
        time.sleep(3)
    outs = [p.communicate(timeout=300) for p in procs]
    codes = sorted(p.returncode for p in procs)
    assert codes == [0, 2], outs
    refused = next(err for p, (_, err) in zip(procs, outs, strict=True) if p.returncode == 2)
    assert (
        refused.strip().splitlines()[-1]
        == f"tween: error: {new}: a library; use --add to append takes, or a new folder"
    )
    assert len(open_library(new).manifest["takes"]) == 1


def test_a_build_behind_a_hung_one_gives_up_naming_the_lock_and_its_holder(library, takes, tmp_path, capsys):
    """A `library build --add` behind a build that hung holding the library's lock waited for
    ever. It waits `--lock-wait` seconds, then exits 2 in one line naming the lock and the
    holder its lock file names; the library is as it was."""
    import fcntl
    import os
    import time

    from cli_contract import failed, refused, snapshot

    from pipeline.library.build import LOCK

    out = tmp_path / "lib"
    shutil.copytree(library, out)
    lock = out / LOCK
    fd = os.open(lock, os.O_RDWR | os.O_CREAT, 0o644)  # the hung build: its own open file, locked
    try:
        fcntl.flock(fd, fcntl.LOCK_EX)
        os.write(fd, b"4242@farm07")
        before = snapshot(out)
        t0 = time.monotonic()
        line = failed(["library", "build", takes, "--out", out, "--add", "--no-progress", "--lock-wait", "0.5"],
                      capsys)  # fmt: skip
        assert 0.5 <= time.monotonic() - t0 < 60
        assert snapshot(out) == before
    finally:
        os.close(fd)
    assert line.startswith(f"tween: error: {lock}: another build still holds this library's lock after 0.5 s "
                           "(process 4242@farm07, since "), line  # fmt: skip
    assert line.endswith("or wait longer with --lock-wait SECONDS"), line
    for bad in ("-1", "nan", "1e9"):
        assert "--lock-wait" in refused(["library", "build", takes, "--out", out, "--add", "--lock-wait", bad],
                                        capsys, out)  # fmt: skip
