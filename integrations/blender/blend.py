"""Blender's side of a fill (needs ``bpy``): the keyed frames of the armature's action, the
export with Blender's own USD exporter, and the takes back as actions.

The animator's action is only read. Each take is a new action with a key on every frame of
the fill: on the animator's keyed frames the animator's own values (copied, bit for bit),
on the others the fill's, marked as generated keys so the blocking stays visible.
"""

from __future__ import annotations

import re
from pathlib import Path

import bpy
from mathutils import Euler, Matrix, Quaternion, Vector

from . import naming, usda

_BONE_PATH = re.compile(r'^pose\.bones\["((?:[^"\\]|\\.)*)"\]\.(\w+)$')
_ROT = {"QUATERNION": "rotation_quaternion", "AXIS_ANGLE": "rotation_axis_angle"}
SAME = 1e-5  # a channel the original does not key and the fill holds within this is left out


def fcurves(action, obj) -> list:
    """The F-curves that animate ``obj`` in ``action`` (slotted actions: its slot's; legacy
    actions of Blender 4.2/4.3: all)."""
    if not hasattr(action, "layers"):
        return list(action.fcurves)
    ad = obj.animation_data
    if ad is not None and ad.action == action:
        slot = ad.action_slot
    else:  # not on screen: the object's slot in it (Blender names it OB<name>), or its only one
        slot = next((s for s in action.slots if s.identifier == "OB" + obj.name), None)
        slot = slot or (action.slots[0] if len(action.slots) == 1 else None)
    out = []
    for layer in action.layers:
        for strip in layer.strips:
            for bag in strip.channelbags:
                if slot is None or bag.slot == slot:
                    out.extend(bag.fcurves)
    return out


def bone_channel(fc) -> tuple[str, str] | None:
    """(bone name, property) of a pose-bone F-curve, or None (an object channel)."""
    m = _BONE_PATH.match(fc.data_path)
    return (m.group(1).replace('\\"', '"'), m.group(2)) if m else None


def keyed(action, obj, lo: int, hi: int) -> dict:
    """The blocking within frames lo..hi: ``keys`` (sorted frames with any key), ``located``
    (frames with a location key), ``bones`` ({frame: bones keyed there}), ``animated`` (bones
    with any F-curve), ``values`` ({(data_path, index): {frame: value}}: every key's value)."""
    keys, located, bones, animated, values = set(), set(), {}, set(), {}
    for fc in fcurves(action, obj):
        bc = bone_channel(fc)
        vals = values.setdefault((fc.data_path, fc.array_index), {})
        for kp in fc.keyframe_points:
            f = round(kp.co[0])
            if abs(kp.co[0] - f) > 1e-3:
                continue  # subframe keys are not frames of the shot
            vals[f] = kp.co[1]
            if not lo <= f <= hi or bc is None:
                continue
            keys.add(f)
            bones.setdefault(f, set()).add(bc[0])
            if bc[1] == "location":
                located.add(f)
        if bc is not None:
            animated.add(bc[0])
    return {
        "keys": sorted(keys),
        "located": sorted(located),
        "bones": bones,
        "animated": animated,
        "values": values,
    }


def joint_tokens(arm) -> dict[str, str]:
    """{bone name: USD joint token} as Blender's USD exporter writes them (the path of names
    from the root, every character but letters, digits and ``_`` made ``_``)."""
    out: dict[str, str] = {}
    for b in arm.data.bones:  # parents come before their children
        leaf = re.sub(r"[^0-9A-Za-z_]", "_", b.name)
        out[b.name] = f"{out[b.parent.name]}/{leaf}" if b.parent else leaf
    return out


def partial_keys(info: dict, tokens: dict[str, str]) -> dict[int, list[str]]:
    """{frame: joint tokens keyed there} for the keys that do not key every animated bone;
    a bone the action never animates holds its pose, keyed on every key."""
    still = [b for b in tokens if b not in info["animated"]]
    out = {}
    for f in info["keys"]:
        got = info["bones"].get(f, set())
        if not info["animated"] <= got:
            out[f] = [tokens[b] for b in tokens if b in got or b in still]
    return out


def export_blocking(context, arm, path: Path, info: dict) -> dict:
    """Blender's USD export of ``arm`` over the scene range, its samples kept on the keys
    only (usda.keep_keys). Returns {"anim": the SkelAnimation's name, "tokens"}."""
    path.parent.mkdir(parents=True, exist_ok=True)
    view = context.view_layer
    selected = [o for o in context.scene.objects if o.select_get()]
    active = view.objects.active
    frame = context.scene.frame_current
    props = {p.identifier for p in bpy.ops.wm.usd_export.get_rna_type().properties}
    want = dict(selected_objects_only=True, export_animation=True, export_armatures=True, export_meshes=False,
                export_materials=False, export_lights=False, export_cameras=False, export_curves=False,
                export_points=False, export_volumes=False, export_hair=False, export_shapekeys=False,
                only_deform_bones=False, export_custom_properties=False)  # fmt: skip
    try:
        for o in selected:
            o.select_set(False)
        arm.select_set(True)
        view.objects.active = arm
        bpy.ops.wm.usd_export(filepath=str(path), **{k: v for k, v in want.items() if k in props})
    finally:
        arm.select_set(False)
        for o in selected:
            o.select_set(True)
        view.objects.active = active
        context.scene.frame_set(frame)
    text = path.read_text()
    tokens = joint_tokens(arm)
    exported = set(usda.animation_joints(text))
    lost = [b for b, t in tokens.items() if t not in exported]
    if lost:
        raise ValueError(f"bone {lost[0]!r} is not in Blender's USD export (as {tokens[lost[0]]!r})")
    partial = partial_keys(info, tokens)
    path.write_text(usda.keep_keys(text, info["keys"], info["located"] or info["keys"], partial))
    anim = re.search(r'def SkelAnimation "([^"]+)"', text).group(1)
    return {"anim": anim, "tokens": tokens, "partial": len(partial)}


def _rotation(mode: str, basis: Matrix, prev):
    """The channel values of ``basis``'s rotation in the bone's mode, nearest ``prev`` (the
    same Euler solution, the same quaternion hemisphere)."""
    if mode == "QUATERNION":
        q = basis.to_quaternion()
        if prev is not None and q.dot(Quaternion(prev)) < 0:
            q.negate()
        return tuple(q)
    if mode == "AXIS_ANGLE":
        axis, angle = basis.to_quaternion().to_axis_angle()
        return (angle, *axis)
    e = basis.to_euler(mode, Euler(prev, mode)) if prev is not None else basis.to_euler(mode)
    return tuple(e)


def _set_keys(fc, frames: list[int], vals: list[float], mine: set[int]) -> None:
    """Keys on every frame, linear (each frame's value exactly); those not the animator's
    are marked generated."""
    kps = fc.keyframe_points
    kps.add(len(frames))
    kps.foreach_set("co", [c for f, v in zip(frames, vals, strict=True) for c in (f, v)])
    # all at once (a Python loop over the keys of a long shot keeps Blender's UI waiting)
    kps.foreach_set("interpolation", [_LINEAR] * len(frames))
    kps.foreach_set("type", [_KEY if f in mine else _GENERATED for f in frames])
    fc.update()


def _enum(prop: str, name: str, fallback: str) -> int:
    items = bpy.types.Keyframe.bl_rna.properties[prop].enum_items
    return (items.get(name) or items[fallback]).value


_LINEAR = _enum("interpolation", "LINEAR", "LINEAR")
_KEY = _enum("type", "KEYFRAME", "KEYFRAME")
_GENERATED = _enum("type", "GENERATED", "BREAKDOWN")  # Blender 4.2 has no GENERATED keys


class _Channels:
    """Creates an action's F-curves the way the running Blender does."""

    def __init__(self, action, arm):
        self.action = action
        if hasattr(action, "layers"):
            slot = action.slots.new(id_type="OBJECT", name=arm.name)
            strip = action.layers.new("Layer").strips.new(type="KEYFRAME")
            self.bag = strip.channelbag(slot, ensure=True)
        else:
            self.bag = None
        self.groups: dict[str, object] = {}

    def new(self, data_path: str, index: int, group: str):
        if self.bag is None:
            return self.action.fcurves.new(data_path, index=index, action_group=group)
        fc = self.bag.fcurves.new(data_path, index=index)
        if group not in self.groups:
            self.groups[group] = self.bag.groups.new(group)
        fc.group = self.groups[group]
        return fc


def take_actions(
    arm, original, layer: Path, shot: str, version: int, anim: str, info: dict, meta: dict
) -> list:
    """One action per take of the fill layer (:func:`take_steps`, all at once)."""
    steps = take_steps(arm, original, layer, shot, version, anim, info, meta)
    while True:
        try:
            next(steps)
        except StopIteration as done:
            return done.value


def take_steps(arm, original, layer: Path, shot: str, version: int, anim: str, info: dict, meta: dict):
    """One action per take of the fill layer: named ``<shot>.v<NNN>.take<N>``, the keyed
    frames the animator's, the in-betweens the fill's, marked with where they came from.

    A generator: it yields (bones done, bones in all) after each bone, so that the panel's
    timer can build a long shot's takes a little at a time and Blender stays responsive;
    it returns the actions."""
    takes = usda.Takes(layer.read_text(), anim)
    joints = takes.joints
    tokens = joint_tokens(arm)
    by_token = {t: b for b, t in tokens.items()}
    index = {t: i for i, t in enumerate(joints)}
    values = info["values"]
    # the animator's curves: each in-between's rotation is written on the branch (Euler
    # solution, quaternion sign) of the blocking's own curve on that frame, so a take's curves
    # meet the keys without a flip (near gimbal lock an Euler in-between may still step to an
    # equivalent solution: the pose on every frame is the fill's either way)
    curves = {(fc.data_path, fc.array_index): fc for fc in fcurves(original, arm)}
    out = []
    total, done = len(takes.spans) * sum(t in by_token for t in index), 0
    for n in sorted(takes.spans):
        samples = takes.samples(n)
        yield done, total  # a take read: the timer's turn
        name = naming.take_action_name(shot, version, n)
        old = bpy.data.actions.get(name)
        if old is not None and old != original:
            bpy.data.actions.remove(old)  # a take fetched again
        act = bpy.data.actions.new(name)
        act.use_fake_user = True  # kept while the armature shows another take
        ch = _Channels(act, arm)
        frames = sorted(round(t) for t in samples["rotations"])
        times = {round(t): t for t in samples["rotations"]}
        for tok, j in index.items():
            bone = by_token.get(tok)
            if bone is None:
                continue
            _bone_channels(arm, bone, j, samples, frames, times, values, curves, ch)
            done += 1
            yield done, total
        for fc in fcurves(original, arm):  # the object's own channels, as they are
            if bone_channel(fc) is None:
                new = ch.new(fc.data_path, fc.array_index, "Object Transforms")
                for kp in fc.keyframe_points:
                    k = new.keyframe_points.insert(kp.co[0], kp.co[1], options={"FAST"})
                    k.interpolation = kp.interpolation
                new.update()
        act["tween_shot"], act["tween_version"], act["tween_take"] = shot, int(version), int(n)
        act["tween_source"] = original.name
        for k, v in meta.get(n, {}).items():
            act[f"tween_{k}"] = v if v is not None else ""
        out.append(act)
    return out


def _bone_channels(arm, bone: str, j: int, samples: dict, frames, times, values, curves, ch) -> None:
    pb = arm.pose.bones[bone]
    b = arm.data.bones[bone]
    rest = b.matrix_local if b.parent is None else b.parent.matrix_local.inverted() @ b.matrix_local
    rest_inv = rest.inverted()
    mode = pb.rotation_mode
    rot_path = _ROT.get(mode, "rotation_euler")
    base = f'pose.bones["{bpy.utils.escape_identifier(bone)}"]'
    n_rot = 4 if mode in _ROT else 3
    chans = {("location", i): [] for i in range(3)}
    chans.update({(rot_path, i): [] for i in range(n_rot)})
    chans.update({("scale", i): [] for i in range(3)})
    prev = None
    blocking = [curves.get((f"{base}.{rot_path}", i)) for i in range(n_rot)]
    blocking = blocking if all(c is not None for c in blocking) else None
    rot, tr, sc = samples["rotations"], samples.get("translations", {}), samples.get("scales", {})
    for f in frames:
        t = times[f]
        q = Quaternion(rot[t][j])
        loc = Vector(tr[t][j]) if t in tr else Vector(rest.to_translation())
        s = Vector(sc[t][j]) if t in sc else Vector((1.0, 1.0, 1.0))
        basis = rest_inv @ Matrix.LocRotScale(loc, q, s)
        bl, _, bs = basis.decompose()
        ref = tuple(c.evaluate(f) for c in blocking) if blocking else prev
        r = list(_rotation(mode, basis, ref))
        for i in range(n_rot):  # the animator's key where there is one (anchors continuity)
            key = values.get((f"{base}.{rot_path}", i), {})
            if f in key:
                r[i] = key[f]
        prev = tuple(r)
        for i in range(3):
            chans[("location", i)].append(bl[i])
            chans[("scale", i)].append(bs[i])
        for i in range(n_rot):
            chans[(rot_path, i)].append(r[i])
    for (prop, i), vals in chans.items():
        path = f"{base}.{prop}"
        key = values.get((path, i))
        if key is None:
            still = getattr(pb, prop)[i]
            if max(abs(v - still) for v in vals) < SAME:
                continue  # not animated before, not moved by the fill
            mine = set()
        else:
            vals = [key.get(f, v) for f, v in zip(frames, vals, strict=True)]
            mine = {f for f in frames if f in key}
        fr = list(frames)
        if key:  # the animator's keys outside the fill's frames, as they are
            extra = sorted(f for f in key if f < frames[0] or f > frames[-1])
            pairs = sorted([*zip(fr, vals, strict=True), *((f, key[f]) for f in extra)])
            fr, vals = [p[0] for p in pairs], [p[1] for p in pairs]
            mine |= set(extra)
        _set_keys(ch.new(path, i, bone), fr, vals, mine)


def assign(arm, action) -> None:
    """Shows ``action`` on the armature (its slot, on Blender 4.4+)."""
    if arm.animation_data is None:
        arm.animation_data_create()
    arm.animation_data.action = action
    if hasattr(action, "slots") and len(action.slots) and arm.animation_data.action_slot is None:
        arm.animation_data.action_slot = action.slots[0]
