"""The panel, its operators and the add-on preferences (needs ``bpy``).

Fill exports and submits, then returns; a modal timer (:class:`TWEEN_OT_watch`) ticks the
job (``jobs.FillJob.tick``: one look at ``tween status``, never a wait) and, once it is done,
brings the takes back as actions. ``tween.tick`` is the same tick as an operator, for scripts
and for headless Blender, which runs no modal timers.
"""

from __future__ import annotations

import json
import os
import time
from pathlib import Path

import bpy
from bpy.props import BoolProperty, EnumProperty, FloatProperty, IntProperty, PointerProperty, StringProperty

from . import blend, commands, naming, usda
from .jobs import Command, FillJob
from .result import read_result

ADDON = __package__
#: Jobs and commands in flight, by armature object name (not saved with the file).
TRACK: dict[str, dict] = {}


def settings(context) -> commands.Settings:
    p = context.preferences.addons[ADDON].preferences
    return commands.Settings(
        tween=p.tween, farm=p.farm, broker_url=p.broker_url, out_dir=bpy.path.abspath(p.out_dir),
        model=p.model, takes=p.takes, trust=p.trust, render=p.render, mapping=bpy.path.abspath(p.mapping),
    )  # fmt: skip


class TweenPreferences(bpy.types.AddonPreferences):
    bl_idname = ADDON

    tween: StringProperty(name="tween executable", default="tween", subtype="FILE_PATH")
    farm: EnumProperty(
        name="Farm",
        items=[
            ("EMBEDDED", "Embedded", "`tween fill` runs its own worker on this machine"),
            ("FARM", "Broker", "`tween submit` to the farm's broker"),
        ],  # fmt: skip
        default="EMBEDDED",
    )
    broker_url: StringProperty(
        name="Broker URL", description="TWEEN_BROKER_URL (empty: the farm config file's)"
    )
    out_dir: StringProperty(
        name="Output folder", subtype="DIR_PATH", default="//tween",
        description="Blocking exports and fill layers go to <folder>/<shot>/ (on storage the farm sees)",
    )  # fmt: skip
    model: StringProperty(name="Model", default="default")
    takes: IntProperty(name="Takes", default=3, min=1, max=commands.MAX_TAKES)
    trust: EnumProperty(
        name="Trust",
        items=[
            ("auto", "Auto", "Model, spline or a blend, decided from your keys"),
            ("model", "Model", "Always the learned in-betweener"),
            ("spline", "Spline", "Always the spline"),
        ],  # fmt: skip
        default="auto",
    )
    render: BoolProperty(
        name="Render reviews", description="Render each take's MP4 and contact sheet on the farm"
    )
    mapping: StringProperty(
        name="Mapping file", subtype="FILE_PATH",
        description="Optional --mapping JSON ({model joint: bone}) for a rig whose bones do not map by themselves",
    )  # fmt: skip

    def draw(self, context):
        col = self.layout.column()
        for name in (
            "tween",
            "farm",
            "broker_url",
            "out_dir",
            "model",
            "takes",
            "trust",
            "render",
            "mapping",
        ):
            row = col.row()
            row.prop(self, name)
            row.enabled = name != "broker_url" or self.farm == "FARM"


class TweenState(bpy.types.PropertyGroup):
    note: StringProperty(name="Note", description="Your note for Approve")
    status: StringProperty()
    fraction: FloatProperty(min=0.0, max=1.0)
    shot: StringProperty()  # the shot name
    shot_file: StringProperty()
    out_dir: StringProperty()
    anim: StringProperty()  # the exported SkelAnimation's name
    result: StringProperty()  # the last fill's JSON


def _armature(context):
    ob = context.active_object
    return ob if ob is not None and ob.type == "ARMATURE" else None


def _source_action(arm):
    """The animator's action: the one on screen, or the one a take on screen came from."""
    act = arm.animation_data.action if arm.animation_data else None
    if act is not None and "tween_source" in act:
        return bpy.data.actions.get(act["tween_source"]) or act
    return act


def takes_of(arm) -> list:
    shot = arm.tween.shot
    out = [a for a in bpy.data.actions if (t := naming.parse_take_name(a.name)) and t.shot == shot]
    return sorted(
        out, key=lambda a: (naming.parse_take_name(a.name).version, naming.parse_take_name(a.name).take)
    )


#: Seconds of take building per timer tick (the rest of the tick is Blender's).
STEP_S = 0.1


def _start_bring_back(arm, fill: dict, track: dict) -> None:
    """Starts building the takes of a finished fill (its JSON) as actions (:func:`_step`)."""
    res = read_result(fill, os.path.dirname(track["shot_file"]))
    meta = {t.index: {"decision": t.decision, "mp4": t.mp4, "sheet": t.contact_sheet, "otio": t.timeline,
                      "layer": res.layer, "review": res.review, "shot_file": track["shot_file"],
                      "out_dir": track["out_dir"], "model": res.model} for t in res.takes}  # fmt: skip
    original = bpy.data.actions[track["original"]]
    track["fill"], track["res"] = fill, res
    track["steps"] = blend.take_steps(
        arm, original, Path(res.layer), track["shot"], res.version, track["anim"], track["info"], meta
    )


def _step(arm, track: dict, budget: float | None = STEP_S) -> str | None:
    """Builds the takes for ``budget`` seconds (None: to the end); the report line once they
    are all back, else None."""
    t0 = time.monotonic()
    while budget is None or time.monotonic() - t0 < budget:
        try:
            done, total = next(track["steps"])
        except StopIteration as stop:
            track.pop("steps")
            return _brought_back(arm, track, stop.value)
        except BaseException:
            track.pop("steps", None)  # a fault is said once, not again at every tick
            raise
        arm.tween.status = f"bringing the takes back ({done}/{total} bones)"
        arm.tween.fraction = done / total if total else 0.0
    return None


def _brought_back(arm, track: dict, acts: list) -> str:
    res = track["res"]
    arm.tween.result = json.dumps(track["fill"])
    arm.tween.status, arm.tween.fraction = "done", 1.0
    blend.assign(arm, acts[0])
    dec = ", ".join(sorted({t.decision for t in res.takes if t.decision})) or "?"
    return f"usd-tween: {len(acts)} take(s) of {track['shot']} v{res.version:03d} back ({dec})"


def _bring_back(arm, fill: dict, track: dict) -> str:
    """The takes of a finished fill, all at once (Fetch: the animator asked and waits)."""
    _start_bring_back(arm, fill, track)
    return _step(arm, track, None)


def tick_all(report) -> bool:
    """One look at every job and command; True while any still runs. Never raises: a fault
    of ours is one report line too, and the timer goes on with the other jobs."""
    try:
        return _tick_all(report)
    except Exception as e:  # the UI timer must not die with a traceback
        report({"ERROR"}, f"usd-tween: {type(e).__name__}: {' '.join(str(e).split())}")
        for track in TRACK.values():
            job = track.get("job")
            if job is not None and not job.finished:
                job.state, job.error = "failed", f"{type(e).__name__}: {e}"
            track["commands"] = []
        return False


def _tick_all(report) -> bool:
    busy = False
    for name, track in list(TRACK.items()):
        arm = bpy.data.objects.get(name)
        job = track.get("job")
        if job is not None and not job.finished:
            job.tick()
            if arm is not None:
                arm.tween.status, arm.tween.fraction = job.text(), job.fraction
            if job.state == "done" and arm is not None:
                try:
                    _start_bring_back(arm, job.result, track)
                except (ValueError, KeyError, OSError) as e:
                    arm.tween.status = f"failed: {e}"
                    report({"ERROR"}, f"usd-tween: cannot read the takes back: {e}")
            elif job.state == "failed":
                report({"ERROR"}, f"usd-tween: {job.error}")
            busy |= not job.finished
        if "steps" in track and arm is not None:
            try:
                line = _step(arm, track)
            except (ValueError, KeyError, OSError) as e:
                arm.tween.status = f"failed: {e}"
                report({"ERROR"}, f"usd-tween: cannot read the takes back: {e}")
            else:
                if line is None:
                    busy = True
                else:
                    report({"INFO"}, line)
        for cmd in list(track.get("commands", [])):
            done = cmd.tick()
            if done is None:
                busy = True
                continue
            track["commands"].remove(cmd)
            ok, out, err = done
            if not ok:
                report({"ERROR"}, f"usd-tween: {cmd.what}: {err}")
            elif cmd.on_done is not None:
                try:
                    report({"INFO"}, cmd.on_done(out))
                except (ValueError, KeyError, OSError) as e:
                    report({"ERROR"}, f"usd-tween: {cmd.what}: {e}")
    return busy


def _redraw(context) -> None:
    for window in context.window_manager.windows:
        for area in window.screen.areas:
            if area.type == "VIEW_3D":
                area.tag_redraw()


class TWEEN_OT_watch(bpy.types.Operator):
    """Polls the running fills and commands (a modal timer: Blender stays responsive)"""

    bl_idname = "tween.watch"
    bl_label = "Watch usd-tween jobs"
    _timer = None

    running = False  # one watcher polls every job

    def invoke(self, context, event):
        if TWEEN_OT_watch.running:
            return {"CANCELLED"}
        TWEEN_OT_watch.running = True
        self._timer = context.window_manager.event_timer_add(0.5, window=context.window)
        context.window_manager.modal_handler_add(self)
        return {"RUNNING_MODAL"}

    def modal(self, context, event):
        if event.type != "TIMER":
            return {"PASS_THROUGH"}
        busy = tick_all(self.report)
        lines = [f"{n}: {bpy.data.objects[n].tween.status}" for n in TRACK if n in bpy.data.objects]
        if context.workspace is not None:
            context.workspace.status_text_set("usd-tween  " + " | ".join(lines) if busy else None)
        _redraw(context)
        if not busy:
            context.window_manager.event_timer_remove(self._timer)
            TWEEN_OT_watch.running = False
            return {"FINISHED"}
        return {"PASS_THROUGH"}


def _watch(context) -> None:
    if context.window is not None and not bpy.app.background:
        bpy.ops.tween.watch("INVOKE_DEFAULT")


class TWEEN_OT_tick(bpy.types.Operator):
    """One look at the running usd-tween jobs (what the timer does)"""

    bl_idname = "tween.tick"
    bl_label = "Poll usd-tween"

    def execute(self, context):
        tick_all(self.report)
        return {"FINISHED"}


class TWEEN_OT_fill(bpy.types.Operator):
    """Export the keyed action over the scene range and fill its in-betweens on the farm"""

    bl_idname = "tween.fill"
    bl_label = "Fill"

    @classmethod
    def poll(cls, context):
        arm = _armature(context)
        return arm is not None and _source_action(arm) is not None

    def execute(self, context):
        arm = _armature(context)
        s = settings(context)
        bad = commands.check(s)
        track = TRACK.get(arm.name, {})
        if (
            bad is None
            and bpy.context.preferences.addons[ADDON].preferences.out_dir.startswith("//")
            and not bpy.data.filepath
        ):
            bad = "save the .blend first (the output folder is relative to it), or set an absolute one"
        if bad is None and (track.get("job") is not None and not track["job"].finished or "steps" in track):
            bad = "a fill of this armature is still running (Cancel it first)"
        original = _source_action(arm)
        scene = context.scene
        info = blend.keyed(original, arm, scene.frame_start, scene.frame_end)
        if bad is None and len(info["keys"]) < 2:
            bad = (f"action {original.name!r} has {len(info['keys'])} keyed frame(s) in the scene range "
                   f"{scene.frame_start}-{scene.frame_end}: the fill needs two or more")  # fmt: skip
        if bad is not None:
            self.report({"ERROR"}, f"usd-tween: {bad}")
            return {"CANCELLED"}
        shot = naming.shot_name(bpy.data.filepath, arm.name)
        folder = Path(s.out_dir) / shot
        shot_file = folder / f"{shot}.usda"
        was = arm.animation_data.action
        try:
            blend.assign(arm, original)  # the blocking is what is exported, not a take on screen
            exp = blend.export_blocking(context, arm, shot_file, info)
            job = FillJob(s, str(shot_file), str(folder), str(folder / ".tween-blender"))
        except (ValueError, OSError, RuntimeError) as e:
            blend.assign(arm, was)
            self.report({"ERROR"}, f"usd-tween: {' '.join(str(e).split())}")
            return {"CANCELLED"}
        st = arm.tween
        st.shot, st.shot_file, st.out_dir, st.anim = shot, str(shot_file), str(folder), exp["anim"]
        st.status, st.fraction = "submitting", 0.0
        TRACK[arm.name] = {"job": job, "shot": shot, "shot_file": str(shot_file), "out_dir": str(folder),
                           "anim": exp["anim"], "info": info, "original": original.name, "commands": []}  # fmt: skip
        partial = f", {exp['partial']} partial" if exp["partial"] else ""
        self.report(
            {"INFO"}, f"usd-tween: {shot}: {len(info['keys'])} keys{partial} submitted ({s.farm.lower()})"
        )
        _watch(context)
        return {"FINISHED"}


class TWEEN_OT_cancel(bpy.types.Operator):
    """Cancel the running fill of this armature (nothing of it is kept)"""

    bl_idname = "tween.cancel"
    bl_label = "Cancel"

    def execute(self, context):
        arm = _armature(context)
        job = TRACK.get(arm.name, {}).get("job") if arm else None
        if job is None or job.finished:
            self.report({"ERROR"}, "usd-tween: no fill of this armature is running")
            return {"CANCELLED"}
        job.cancel()
        arm.tween.status = "cancelled"
        return {"FINISHED"}


class TWEEN_OT_fetch(bpy.types.Operator):
    """Bring back the takes of this armature's latest fill from the output folder (a fill that
    finished while Blender was closed, or takes deleted by mistake)"""

    bl_idname = "tween.fetch"
    bl_label = "Fetch latest"

    @classmethod
    def poll(cls, context):
        arm = _armature(context)
        return arm is not None and _source_action(arm) is not None

    def execute(self, context):
        arm = _armature(context)
        shot = arm.tween.shot or naming.shot_name(bpy.data.filepath, arm.name)
        folder = Path(arm.tween.out_dir or Path(settings(context).out_dir) / shot)
        shot_file = Path(arm.tween.shot_file or folder / f"{shot}.usda")
        latest = usda.latest_layer(os.listdir(folder), shot) if folder.is_dir() else None
        if latest is None or not shot_file.is_file():
            self.report({"ERROR"}, f"usd-tween: no fill of {shot} in {folder}")
            return {"CANCELLED"}
        layer = folder / latest[1]
        try:
            fill = usda.layer_result(layer.read_text())
            fill["layer"] = str(layer)
            if fill["review"]:
                fill["review"] = str(folder / fill["review"])
            original = _source_action(arm)
            scene = context.scene
            track = {"shot": shot, "shot_file": str(shot_file), "out_dir": str(folder), "anim": None,
                     "info": blend.keyed(original, arm, scene.frame_start, scene.frame_end),
                     "original": original.name}  # fmt: skip
            arm.tween.shot, arm.tween.shot_file, arm.tween.out_dir = shot, str(shot_file), str(folder)
            self.report({"INFO"}, _bring_back(arm, fill, track))
        except (ValueError, KeyError, OSError) as e:
            self.report({"ERROR"}, f"usd-tween: {layer.name}: {' '.join(str(e).split())}")
            return {"CANCELLED"}
        return {"FINISHED"}


class TWEEN_OT_use(bpy.types.Operator):
    """Show this take (or, with no name, your own action) on the armature"""

    bl_idname = "tween.use"
    bl_label = "Use"
    action: StringProperty()

    def execute(self, context):
        arm = _armature(context)
        if arm is None:
            return {"CANCELLED"}
        act = bpy.data.actions.get(self.action) if self.action else _source_action(arm)
        if act is None:
            self.report({"ERROR"}, f"usd-tween: no action {self.action!r}")
            return {"CANCELLED"}
        blend.assign(arm, act)
        return {"FINISHED"}


def _on_screen_take(self, context):
    arm = _armature(context)
    act = arm.animation_data.action if arm and arm.animation_data else None
    if act is None or "tween_take" not in act:
        self.report({"ERROR"}, "usd-tween: show a take first (Takes: Use)")
        return None, None
    return arm, act


def _run(context, arm, cmd: list[str], what: str, on_done=None) -> None:
    folder = arm.tween.out_dir or str(Path(settings(context).out_dir) / arm.tween.shot)
    c = Command(cmd, settings(context), str(Path(folder) / ".tween-blender"), what)
    c.on_done = on_done
    TRACK.setdefault(arm.name, {"commands": []}).setdefault("commands", []).append(c)
    _watch(context)


def _latest_version(arm) -> int:
    takes = takes_of(arm)
    return max((naming.parse_take_name(a.name).version for a in takes), default=0)


class TWEEN_OT_approve(bpy.types.Operator):
    """Approve the take on screen with your note (tween approve)"""

    bl_idname = "tween.approve"
    bl_label = "Approve"

    def execute(self, context):
        arm, act = _on_screen_take(self, context)
        if act is None:
            return {"CANCELLED"}
        if act["tween_version"] != _latest_version(arm):
            self.report(
                {"ERROR"}, f"usd-tween: {act.name} is not of the latest fill (v{_latest_version(arm):03d})"
            )
            return {"CANCELLED"}
        s = settings(context)
        cmd = commands.approve_command(
            s, act["tween_shot_file"], act["tween_out_dir"], act["tween_take"], arm.tween.note
        )
        _run(context, arm, cmd, "approve", lambda out: f"usd-tween: approved {act.name}")
        return {"FINISHED"}


class TWEEN_OT_publish(bpy.types.Operator):
    """Publish the approved take as a plain animation layer over the shot (tween publish)"""

    bl_idname = "tween.publish"
    bl_label = "Publish"

    def execute(self, context):
        arm, act = _on_screen_take(self, context)
        if act is None:
            return {"CANCELLED"}
        cmd = commands.publish_command(settings(context), act["tween_shot_file"], act["tween_out_dir"])
        _run(
            context, arm, cmd, "publish", lambda out: f"usd-tween: published {commands.published_layer(out)}"
        )
        return {"FINISHED"}


def _open(path: str) -> None:
    if path and not bpy.app.background:
        bpy.ops.wm.path_open(filepath=path)


class TWEEN_OT_review(bpy.types.Operator):
    """Open the take's review MP4 (rendered now if the farm did not)"""

    bl_idname = "tween.review"
    bl_label = "Review"
    sheet: BoolProperty(name="Contact sheet", default=False)

    def execute(self, context):
        arm, act = _on_screen_take(self, context)
        if act is None:
            return {"CANCELLED"}
        have = act.get("tween_sheet" if self.sheet else "tween_mp4")
        if have and os.path.isfile(have):
            _open(have)
            return {"FINISHED"}
        version = naming.parse_take_name(act.name).version
        siblings = [a for a in takes_of(arm) if naming.parse_take_name(a.name).version == version]
        take = act["tween_take"] if len(siblings) > 1 else None  # one take: no variant to select
        out = str(Path(act["tween_out_dir"]) / "review" / act.name)
        sheet = self.sheet
        cmd = commands.review_command(settings(context), act["tween_review"] or act["tween_layer"], take, out)

        def done(stdout: str) -> str:
            r = json.loads(stdout[stdout.index("{") :])
            act["tween_mp4"], act["tween_sheet"] = r.get("mp4") or "", r.get("contact_sheet") or ""
            act["tween_otio"] = r.get("timeline") or act.get("tween_otio") or ""
            _open(act["tween_sheet"] if sheet else act["tween_mp4"])
            return f"usd-tween: review of {act.name}: {act['tween_mp4']}"

        _run(context, arm, cmd, "review", done)
        return {"FINISHED"}


class VIEW3D_PT_tween(bpy.types.Panel):
    bl_space_type = "VIEW_3D"
    bl_region_type = "UI"
    bl_category = "Tween"
    bl_label = "usd-tween"

    def draw(self, context):
        layout = self.layout
        arm = _armature(context)
        if arm is None:
            layout.label(text="Select an armature")
            return
        st = arm.tween
        job = TRACK.get(arm.name, {}).get("job")
        running = job is not None and not job.finished
        row = layout.row(align=True)
        row.operator("tween.fill", icon="PLAY")
        if running:
            row.operator("tween.cancel", text="", icon="X")
        if st.status:
            if running and hasattr(layout, "progress"):
                layout.progress(factor=st.fraction, type="BAR", text=st.status)
            else:
                layout.label(text=st.status, icon="ERROR" if st.status.startswith("failed") else "INFO")
        box = layout.box()
        head = box.row()
        head.label(text="Takes")
        head.operator("tween.fetch", text="", icon="FILE_REFRESH")
        current = arm.animation_data.action if arm.animation_data else None
        src = _source_action(arm)
        if src is not None:
            r = box.row()
            r.operator("tween.use", text=f"Original: {src.name}", depress=current == src).action = src.name
        for act in reversed(takes_of(arm)):
            r = box.row()
            r.operator("tween.use", text=act.name, depress=current == act).action = act.name
            r.label(text=act.get("tween_decision", "") or "-")
        layout.prop(st, "note")
        row = layout.row(align=True)
        row.operator("tween.approve", icon="CHECKMARK")
        row.operator("tween.publish", icon="EXPORT")
        row = layout.row(align=True)
        row.operator("tween.review", text="Review MP4", icon="FILE_MOVIE").sheet = False
        row.operator("tween.review", text="Contact sheet", icon="IMAGE_DATA").sheet = True
        if current is not None and current.get("tween_otio"):
            layout.label(text=f"Timeline: {current['tween_otio']}")


CLASSES = (TweenPreferences, TweenState, TWEEN_OT_watch, TWEEN_OT_tick, TWEEN_OT_fill, TWEEN_OT_cancel, TWEEN_OT_fetch, TWEEN_OT_use,
           TWEEN_OT_approve, TWEEN_OT_publish, TWEEN_OT_review, VIEW3D_PT_tween)  # fmt: skip


def register() -> None:
    for c in CLASSES:
        bpy.utils.register_class(c)
    bpy.types.Object.tween = PointerProperty(type=TweenState)


def unregister() -> None:
    del bpy.types.Object.tween
    for c in reversed(CLASSES):
        bpy.utils.unregister_class(c)
