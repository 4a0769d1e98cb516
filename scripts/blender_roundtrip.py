"""A real Blender round trip: BVH → Blender → USD → tween fill → USD back into Blender.

Two interpreters, because Blender's ``bpy`` (a 1 GB wheel) is not a project dependency:

    python3 -m venv /tmp/bpyenv && /tmp/bpyenv/bin/pip install bpy        # Blender as a module
    /tmp/bpyenv/bin/python scripts/blender_roundtrip.py export CLIP.bvh.gz OUT --keys-every 10
    .venv/bin/python scripts/blender_roundtrip.py measure OUT               # fills, scores
    /tmp/bpyenv/bin/python scripts/blender_roundtrip.py import-back OUT     # Blender reads the fill

``export`` imports the BVH with Blender's own importer and exports it with Blender's own USD
exporter twice: every frame (``truth.usda``) and blocked, with every keyframe deleted but
each ``--keys-every``-th so Blender's default Bezier curves fill between (``blocked.usda``:
Blender still writes a sample on every frame, so the keys are given to the fill with
``--keys``). ``measure`` fills ``blocked.usda`` with the default model, interpolation and the
spline and scores every joint's world position against ``truth.usda``, beside Blender's own
curves.
"""

from __future__ import annotations

import argparse
import gzip
import json
import shutil
import sys
import tempfile
from pathlib import Path


def _fcurves(action):
    """Every F-curve of an action (Blender 5's layered actions, or the legacy list)."""
    if hasattr(action, "fcurves") and len(getattr(action, "fcurves", [])):
        return list(action.fcurves)
    out = []
    for layer in action.layers:
        for strip in layer.strips:
            for bag in strip.channelbags:
                out.extend(bag.fcurves)
    return out


def export(bvh: Path, out: Path, keys_every: int, scale: float) -> None:
    import bpy

    out.mkdir(parents=True, exist_ok=True)
    src = bvh
    if bvh.suffix == ".gz":
        tmp = Path(tempfile.mkdtemp()) / bvh.stem
        tmp.write_bytes(gzip.decompress(bvh.read_bytes()))
        src = tmp
    bpy.ops.wm.read_factory_settings(use_empty=True)
    bpy.ops.import_anim.bvh(
        filepath=str(src), global_scale=scale, update_scene_fps=True, update_scene_duration=True
    )
    arm = next(o for o in bpy.context.scene.objects if o.type == "ARMATURE")
    scene = bpy.context.scene
    first, last = (round(f) for f in arm.animation_data.action.frame_range)
    scene.frame_start, scene.frame_end = first, last
    bpy.ops.wm.usd_export(filepath=str(out / "truth.usda"), export_animation=True, export_armatures=True)
    keys = set(range(first, last + 1, keys_every)) | {last}
    for fc in _fcurves(arm.animation_data.action):
        drop = [k for k in fc.keyframe_points if round(k.co[0]) not in keys]
        for k in reversed(drop):
            fc.keyframe_points.remove(k)
        for k in fc.keyframe_points:  # Blender's default: Bezier with auto-clamped handles
            k.interpolation = "BEZIER"
            k.handle_left_type = k.handle_right_type = "AUTO_CLAMPED"
        fc.update()
    bpy.ops.wm.usd_export(filepath=str(out / "blocked.usda"), export_animation=True, export_armatures=True)
    (out / "keys.json").write_text(json.dumps({"frames": sorted(keys), "fps": scene.render.fps}))
    print(f"exported {out / 'truth.usda'} and {out / 'blocked.usda'} ({len(keys)} keys)", file=sys.stderr)


def _positions(path: str):
    """World positions (T, J, 3) in metres of the first skeleton's joints at every time code."""
    import numpy as np
    from pxr import Usd, UsdGeom, UsdSkel

    stage = Usd.Stage.Open(path)
    cache = UsdSkel.Cache()
    for prim in stage.Traverse():
        if prim.IsA(UsdSkel.Root):
            cache.Populate(UsdSkel.Root(prim), Usd.PrimDefaultPredicate)
    skel = next(p for p in stage.Traverse() if p.IsA(UsdSkel.Skeleton))
    q = cache.GetSkelQuery(UsdSkel.Skeleton(skel))
    xf = UsdGeom.Xformable(skel)
    times = np.arange(stage.GetStartTimeCode(), stage.GetEndTimeCode() + 0.5)
    out = []
    for t in times:
        m = np.array(q.ComputeJointSkelTransforms(Usd.TimeCode(t)))
        w = np.array(xf.ComputeLocalToWorldTransform(Usd.TimeCode(t)))
        out.append(m[:, 3, :3] @ w[:3, :3] + w[3, :3])
    return np.array(out) * UsdGeom.GetStageMetersPerUnit(stage), times, [str(j) for j in q.GetJointOrder()]


def measure(out: Path) -> dict:
    import numpy as np

    from pipeline.fill.api import FillOptions, fill_shot
    from pipeline.usd.read import read_shot

    truth, times, joints = _positions(str(out / "truth.usda"))
    blocked, _, _ = _positions(str(out / "blocked.usda"))
    k = json.loads((out / "keys.json").read_text())["frames"]
    shot = read_shot(out / "blocked.usda")
    t0 = shot.start
    key_times = [float(t0 + f - k[0]) for f in k]
    spec = ",".join(f"{t:g}" for t in key_times)
    inside = ~np.isin(times, key_times)
    res = {"keys": len(k), "frames": len(times), "joints": len(joints), "error_cm": {}, "reference": None}
    res["error_cm"]["blender bezier"] = float(np.linalg.norm(blocked - truth, axis=-1)[inside].mean() * 100)
    for m in ("default", "interp", "spline"):
        d = out / f"fill_{m}"
        shutil.rmtree(d, ignore_errors=True)
        r = fill_shot(str(out / "blocked.usda"), FillOptions(model=m, keys=spec, out_dir=str(d)))
        pos, _, _ = _positions(r["review"])
        res["error_cm"]["model" if m == "default" else m] = float(
            np.linalg.norm(pos - truth, axis=-1)[inside].mean() * 100
        )
        if m == "default":
            res["reference"] = next(iter(r["retarget"].values()))
            res["review"] = r["review"]
    b = res["error_cm"]["blender bezier"]
    res["ratio_to_blender"] = {m: e / b for m, e in res["error_cm"].items()}
    (out / "measure.json").write_text(json.dumps(res, indent=1))
    return res


def import_back(out: Path) -> None:
    import bpy

    review = json.loads((out / "measure.json").read_text())["review"]
    bpy.ops.wm.read_factory_settings(use_empty=True)
    bpy.ops.wm.usd_import(filepath=review)
    arm = [o for o in bpy.context.scene.objects if o.type == "ARMATURE"]
    keyed = sorted(
        {round(k.co[0]) for fc in _fcurves(arm[0].animation_data.action) for k in fc.keyframe_points}
    )
    print(f"Blender imported {review}: {len(arm)} armature(s), keyframes on {len(keyed)} frames "
          f"({keyed[0]}-{keyed[-1]})")  # fmt: skip


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    sub = ap.add_subparsers(dest="cmd", required=True)
    e = sub.add_parser("export")
    e.add_argument("bvh", type=Path)
    e.add_argument("out", type=Path)
    e.add_argument("--keys-every", type=int, default=10)
    e.add_argument("--scale", type=float, default=0.01, help="BVH units to metres (0.01: centimetres)")
    sub.add_parser("measure").add_argument("out", type=Path)
    sub.add_parser("import-back").add_argument("out", type=Path)
    a = ap.parse_args()
    if a.cmd == "export":
        export(a.bvh, a.out, a.keys_every, a.scale)
    elif a.cmd == "measure":
        print(json.dumps(measure(a.out), indent=1))
    else:
        import_back(a.out)


if __name__ == "__main__":
    main()
