"""The Blender extension in a real, headless Blender (``bpy`` from PyPI), against the farm.

Run by a Python that has ``bpy`` (test_blender_real.py runs it; by hand:
``BPY_PYTHON tests/integrations/blender_check.py --tween .venv/bin/tween --out DIR``). For each
clip it installs the extension from a zip (Blender's own "Install from Disk"), imports the
BVH with Blender's BVH importer, deletes every key but each 10th frame's (the blocking),
presses Fill, polls until the takes are back, and checks: a take action per take, the keyed
frames the blocking's exactly, the in-betweens not Blender's Bezier. It prints one JSON line
per clip with the world-position error (cm, every joint, every in-between frame) of the fill's
takes and of Blender's Bezier against the clip.
"""

from __future__ import annotations

import argparse
import gzip
import json
import math
import os
import sys
import tempfile
import time
import zipfile
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]
DATA = REPO.parent / "shared" / "data"
EXT = REPO / "integrations" / "blender"
MODULE = "bl_ext.user_default.usd_tween"

# A Blender-named character (Rigify's names, .L/.R): the Bandai rig renamed, rooted at a
# pelvis whose thighs hang beside the spine chain (the rig the issue says was refused).
RIGIFY = {"joint_Root": "root", "Hips": "pelvis", "Spine": "spine", "Chest": "spine.001", "Neck": "neck",
          "Head": "head"} | {f"{a}_{s}": f"{b}.{s}" for s in "LR" for a, b in
          (("Shoulder", "shoulder"), ("UpperArm", "upper_arm"), ("LowerArm", "forearm"), ("Hand", "hand"),
           ("UpperLeg", "thigh"), ("LowerLeg", "shin"), ("Foot", "foot"), ("Toes", "toe"))}  # fmt: skip


def _to_quaternions(arm, act, frames) -> None:
    """The action's Euler rotations as quaternion curves (a key a frame) and the bones in
    QUATERNION mode, Blender's default for a rig built in Blender (Rigify's bones)."""
    from mathutils import Euler

    def bag_of(fc):
        for layer in act.layers:
            for strip in layer.strips:
                for bag in strip.channelbags:
                    if any(c == fc for c in bag.fcurves):
                        return bag
        return None

    curves = {(c.data_path, c.array_index): c for c in sys.modules[MODULE].blend.fcurves(act, arm)}
    for pb in arm.pose.bones:
        path = f'pose.bones["{pb.name}"]'
        eul = [curves.get((f"{path}.rotation_euler", i)) for i in range(3)]
        if not all(eul):
            continue
        quats, prev = [], None
        for f in frames:
            q = Euler([c.evaluate(f) for c in eul], pb.rotation_mode).to_quaternion()
            if prev is not None and q.dot(prev) < 0:
                q.negate()
            quats.append(q)
            prev = q
        for i in range(4):
            fc = act.fcurve_ensure_for_datablock(
                arm, f"{path}.rotation_quaternion", index=i, group_name=pb.name
            )
            fc.keyframe_points.add(len(quats))
            fc.keyframe_points.foreach_set(
                "co", [x for f, q in zip(frames, quats, strict=True) for x in (f, q[i])]
            )
            fc.update()
        for c in eul:
            bag_of(c).fcurves.remove(c)
        pb.rotation_mode = "QUATERNION"


CLIPS = {
    "bandai": (DATA / "bandai_namco" / "dataset-2" / "dataset-2_walk_normal_002.bvh.gz", None),
    "cmu_iclone": (DATA / "cmu_iclone" / "001_01.bvh.gz", None),
    # ... and animated in quaternions, as a rig built in Blender is
    "rigify_named": (DATA / "bandai_namco" / "dataset-2" / "dataset-2_walk_normal_002.bvh.gz", RIGIFY),
    # more of the eval split (takes 002), for the README's table; not run by default
    "bandai_run": (DATA / "bandai_namco" / "dataset-2" / "dataset-2_run_normal_002.bvh.gz", None),
    "bandai_wave": (
        DATA / "bandai_namco" / "dataset-2" / "dataset-2_wave-both-hands_normal_002.bvh.gz",
        None,
    ),
    "bandai_turn": (DATA / "bandai_namco" / "dataset-2" / "dataset-2_walk-turn-left_normal_002.bvh.gz", None),
}
DEFAULT = ("bandai", "cmu_iclone", "rigify_named")
# A partial key the animator adds between two keys: only the left arm, 15 frames in.
PARTIAL = {
    "rigify_named": ("upper_arm.L", "forearm.L"),
    "cmu_iclone": ("CC_Base_L_Upperarm", "CC_Base_L_Forearm"),
}
PARTIAL_AT = 15


def _zip(dest: Path) -> Path:
    with zipfile.ZipFile(dest, "w") as z:
        for p in sorted(EXT.rglob("*")):
            if p.is_file() and "__pycache__" not in p.parts and p.name != "README.md":
                z.write(p, p.relative_to(EXT).as_posix())
    return dest


def install(tmp: Path):
    import bpy

    bpy.ops.wm.read_factory_settings(use_empty=True)
    bpy.ops.extensions.package_install_files(
        filepath=str(_zip(tmp / "usd_tween.zip")), repo="user_default", enable_on_install=True
    )
    assert MODULE in bpy.context.preferences.addons, "the extension did not install"
    return bpy.context.preferences.addons[MODULE].preferences


def _clear():
    import bpy

    for coll in (bpy.data.objects, bpy.data.armatures, bpy.data.actions):
        for x in list(coll):
            coll.remove(x)


def _world(arm, frames) -> list:
    """World positions (metres) of every bone's head at each frame."""
    import bpy

    out = []
    for f in frames:
        bpy.context.scene.frame_set(f)
        mw = arm.matrix_world
        out.append([tuple(mw @ pb.head) for pb in arm.pose.bones])
    return out


def _err_cm(a, b, frames, keys) -> float:
    import numpy as np

    a, b = np.array(a), np.array(b)
    inside = ~np.isin(np.array(frames), list(keys))
    return float(np.linalg.norm(a - b, axis=-1)[inside].mean() * 100)


def _jumps(curves, frames) -> int:
    """Frame-to-frame steps above 1 rad in rotation channels (an Euler flip, a sign flip)."""
    n = 0
    for fc in curves:
        if ".rotation_" in fc.data_path:
            v = [fc.evaluate(f) for f in frames]
            n += sum(abs(b - a) > 1.0 for a, b in zip(v, v[1:], strict=False))
    return n


def check_clip(name: str, bvh: Path, rename, frames: int, every: int, tmp: Path, timeout: float) -> dict:
    import bpy

    ext = sys.modules[MODULE]
    _clear()
    src = tmp / bvh.name.removesuffix(".gz")
    src.write_bytes(gzip.decompress(bvh.read_bytes()))
    bpy.ops.import_anim.bvh(
        filepath=str(src), global_scale=0.01, update_scene_fps=True, update_scene_duration=True
    )
    arm = next(o for o in bpy.context.scene.objects if o.type == "ARMATURE")
    arm.name = name
    for old, new in (rename or {}).items():
        arm.data.bones[old].name = new  # Blender renames the action's F-curve paths too
    scene = bpy.context.scene
    act = arm.animation_data.action
    first, last = (round(f) for f in act.frame_range)
    scene.frame_start, scene.frame_end = first, min(first + frames - 1, last)  # a short clip: all of it
    span = list(range(scene.frame_start, scene.frame_end + 1))
    if rename:
        _to_quaternions(arm, act, span)
    truth = _world(arm, span)
    truth_jumps = _jumps(ext.blend.fcurves(act, arm), span)
    keys = set(span[::every]) | {span[-1]}
    part_bones, part_at = PARTIAL.get(name, ("UpperArm_L", "LowerArm_L")), span[0] + PARTIAL_AT
    for fc in ext.blend.fcurves(act, arm):
        bc = ext.blend.bone_channel(fc)
        keep = keys | ({part_at} if bc and bc[0] in part_bones else set())
        drop = [k for k in fc.keyframe_points if round(k.co[0]) not in keep]
        for k in reversed(drop):
            fc.keyframe_points.remove(k)
        for k in fc.keyframe_points:  # Blender's default keys: Bezier, auto-clamped handles
            k.interpolation = "BEZIER"
            k.handle_left_type = k.handle_right_type = "AUTO_CLAMPED"
        fc.update()
    blocking = {(fc.data_path, fc.array_index): [tuple(k.co) for k in fc.keyframe_points]
                for fc in ext.blend.fcurves(act, arm)}  # fmt: skip
    bezier = _world(arm, span)

    for o in scene.objects:
        o.select_set(o == arm)
    bpy.context.view_layer.objects.active = arm
    t0 = time.monotonic()
    assert bpy.ops.tween.fill() == {"FINISHED"}, "Fill refused"
    submitted = time.monotonic() - t0
    track = ext.ui.TRACK[arm.name]
    job = track["job"]
    longest = 0.0  # the longest tick: how long Blender's UI waited at once
    while not job.finished or "steps" in track:  # the fill, then its takes built a bit a tick
        if time.monotonic() - t0 > timeout:
            raise SystemExit(f"{name}: no result after {timeout:.0f} s ({arm.tween.status})")
        time.sleep(0.5 if not job.finished else 0.02)
        t_tick = time.monotonic()
        try:
            bpy.ops.tween.tick()
        except RuntimeError as e:  # bpy raises what the operator reported as an error
            raise SystemExit(f"{name}: {' '.join(str(e).split())}") from None
        longest = max(longest, time.monotonic() - t_tick)
    if job.state != "done":
        raise SystemExit(f"{name}: fill failed: {job.error}")
    waited = time.monotonic() - t0
    takes = ext.ui.takes_of(arm)
    assert takes, "no take actions"
    assert arm.animation_data.action == takes[0]
    assert act.name in bpy.data.actions and [
        tuple(k.co) for fc in ext.blend.fcurves(act, arm) for k in fc.keyframe_points
    ] == [c for v in blocking.values() for c in v], "the animator's action changed"

    out = {"clip": name, "bvh": bvh.name, "joints": len(arm.pose.bones), "frames": len(span), "keys": len(keys),
           "fps": scene.render.fps, "submit_s": round(submitted, 2), "fill_s": round(waited, 1),
           "longest_tick_s": round(longest, 3),
           "takes": [], "bezier_cm": round(_err_cm(bezier, truth, span, keys), 3),
           "clip_rotation_jumps": truth_jumps}  # fmt: skip
    for take in takes:
        ext.blend.assign(arm, take)
        curves = {(fc.data_path, fc.array_index): fc for fc in ext.blend.fcurves(take, arm)}
        exact, moved = 0, 0.0
        for ch, pts in blocking.items():
            fc = curves[ch]
            got = {round(k.co[0]): k.co[1] for k in fc.keyframe_points}
            for f, v in pts:
                assert got[round(f)] == v, (
                    f"{take.name} {ch} at frame {f}: {got[round(f)]!r} != blocking {v!r}"
                )
                exact += 1
            orig = next(c for c in ext.blend.fcurves(act, arm) if (c.data_path, c.array_index) == ch)
            for f in span:
                if f not in keys:
                    moved = max(moved, abs(fc.evaluate(f) - orig.evaluate(f)))
        assert moved > 1e-3, f"{take.name}: the in-betweens are Blender's Bezier"
        pos = _world(arm, span)
        out["takes"].append({"action": take.name, "decision": take.get("tween_decision"),
                             "error_cm": round(_err_cm(pos, truth, span, keys), 3), "keys_exact": exact,
                             "max_channel_change_vs_bezier": round(moved, 4),
                             "rotation_jumps": _jumps(curves.values(), span)})  # fmt: skip
    # the partial key went out as tween:keyedJoints, and the fill went through it
    track = ext.ui.TRACK[arm.name]
    export = Path(track["shot_file"]).read_text()
    tokens = ext.blend.joint_tokens(arm)
    want = ", ".join(
        f'"{tokens[b]}"' for b in tokens if b in part_bones or b not in track["info"]["animated"]
    )
    assert f"{part_at}: [{want}]," in export, "no tween:keyedJoints for the partial key"
    layer = json.loads(arm.tween.result)["layer"]
    joints, takes_back = ext.usda.read_takes(Path(layer).read_text(), track["anim"])
    _, kept = ext.usda.read_samples(export)
    worst = 0.0
    for b in part_bones:
        j = joints.index(tokens[b])
        a, k = takes_back[0]["rotations"][float(part_at)][j], kept["rotations"][float(part_at)][j]
        worst = max(
            worst, 2 * math.degrees(math.acos(min(1.0, abs(sum(x * y for x, y in zip(a, k, strict=True))))))
        )
    out["partial_key"] = {"frame": part_at, "bones": list(part_bones), "fill_off_by_deg": round(worst, 3)}
    ext.blend.assign(arm, act)
    return out


def _wait(ext, what: str, timeout: float) -> list:
    """Ticks (what the panel's timer does) until no command runs; the reports it made."""
    msgs: list = []
    t0 = time.monotonic()
    while ext.ui.tick_all(lambda kind, m: msgs.append((sorted(kind)[0], m))):
        if time.monotonic() - t0 > timeout:
            raise SystemExit(f"{what}: not done after {timeout:.0f} s")
        time.sleep(0.3)
    return msgs


def check_actions(name: str, prefs, timeout: float) -> dict:
    """Fetch (the takes deleted, brought back from the files), Approve (with a note), Publish
    and Review of the take on screen; then a Fill refused
    in one report line (no tween), and a CLI error (a rig with no humanoid reading) as one."""
    import bpy

    ext = sys.modules[MODULE]
    arm = bpy.data.objects[name]
    bpy.context.view_layer.objects.active = arm
    # the takes deleted (or Blender closed during the fill): Fetch brings them back from the files
    assert bpy.ops.tween.use(action="") == {"FINISHED"}  # the animator's action on screen
    before = [(a.name, a.get("tween_decision")) for a in ext.ui.takes_of(arm)]
    for a in ext.ui.takes_of(arm):
        bpy.data.actions.remove(a)
    assert bpy.ops.tween.fetch() == {"FINISHED"}
    takes = ext.ui.takes_of(arm)
    assert [(a.name, a.get("tween_decision")) for a in takes] == before, (before, takes)
    assert bpy.ops.tween.use(action=takes[-1].name) == {"FINISHED"}
    out: dict = {"fetched": len(takes)}
    arm.tween.note = "arms swing later, keep take " + str(takes[-1]["tween_take"])
    bpy.ops.tween.approve()
    msgs = _wait(ext, "approve", timeout)
    assert msgs and msgs[-1][0] == "INFO" and "approved" in msgs[-1][1], msgs
    out["approve"] = msgs[-1][1]
    bpy.ops.tween.publish()
    msgs = _wait(ext, "publish", timeout)
    assert msgs and msgs[-1][0] == "INFO", msgs
    out["publish"] = msgs[-1][1].rsplit(" ", 1)[-1]
    assert Path(out["publish"]).is_file(), out
    bpy.ops.tween.review(sheet=False)
    msgs = _wait(ext, "review", timeout)
    assert msgs and msgs[-1][0] == "INFO", msgs
    out["review"] = arm.animation_data.action["tween_mp4"]
    out["timeline"] = arm.animation_data.action.get("tween_otio")
    assert Path(out["review"]).is_file(), out

    good = prefs.tween
    prefs.tween = "/no/such/tween"
    try:
        bpy.ops.tween.fill()
        raise SystemExit("Fill ran without a tween executable")
    except RuntimeError as e:  # bpy raises what the operator reported as an error
        out["refused"] = str(e).strip()
    prefs.tween = good
    # a keyed rig no humanoid reading fits: a chain of three bones
    bpy.ops.object.armature_add()
    chain = bpy.context.active_object
    chain.name = "chain"
    bpy.ops.object.mode_set(mode="EDIT")
    b0 = chain.data.edit_bones[0]
    for i in range(2):
        e = chain.data.edit_bones.new(f"link{i}")
        e.head, e.tail, e.parent = (
            (0, 0, 1 + i),
            (0, 0, 2 + i),
            b0 if i == 0 else chain.data.edit_bones["link0"],
        )
    bpy.ops.object.mode_set(mode="POSE")
    for f, ang in ((1, 0.0), (20, 0.7)):
        for pb in chain.pose.bones:
            pb.rotation_quaternion = (1.0, ang, 0.0, 0.0)
            pb.keyframe_insert("rotation_quaternion", frame=f)
    bpy.ops.object.mode_set(mode="OBJECT")
    bpy.context.scene.frame_start, bpy.context.scene.frame_end = 1, 20
    bpy.ops.tween.fill()
    job = ext.ui.TRACK["chain"]["job"]
    msgs = _wait(ext, "fill of a chain", timeout)
    assert job.state == "failed" and msgs[-1][0] == "ERROR", (job.state, msgs)
    out["cli_error"] = msgs[-1][1]
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--tween", required=True, help="The tween executable the extension runs.")
    ap.add_argument("--out", type=Path, default=None, help="Output folder (default: a temporary one).")
    ap.add_argument("--clips", default=",".join(DEFAULT), help=f"Which of {', '.join(CLIPS)}.")
    ap.add_argument("--frames", type=int, default=241, help="Frames of each clip (from its first).")
    ap.add_argument("--every", type=int, default=10, help="Keep the keys of every N-th frame.")
    ap.add_argument("--takes", type=int, default=2)
    ap.add_argument("--model", default="default")
    ap.add_argument("--timeout", type=float, default=900.0)
    ap.add_argument("--actions", action="store_true", help="Also Approve, Publish, Review, and two refusals.")
    a = ap.parse_args()
    tmp = Path(tempfile.mkdtemp(prefix="tween-blender-"))
    prefs = install(tmp)
    prefs.tween, prefs.farm, prefs.takes, prefs.model = a.tween, "EMBEDDED", a.takes, a.model
    prefs.out_dir = str(a.out or tmp / "out")
    names = a.clips.split(",")
    for name in names:
        bvh, rename = CLIPS[name]
        print(json.dumps(check_clip(name, bvh, rename, a.frames, a.every, tmp, a.timeout)), flush=True)
    if a.actions:
        print(json.dumps(check_actions(names[-1], prefs, a.timeout)), flush=True)


if __name__ == "__main__":
    os.environ.setdefault("TWEEN_BLENDER_CHECK", "1")
    main()
