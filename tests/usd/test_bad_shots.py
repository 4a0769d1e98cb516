"""Bad shot content and bad --keys/--range values (issue 17): each is ONE line naming the
shot (and the prim at fault), exit status 2 on the CLI, nothing on stdout, no USD
``Warning:`` lines, no output folder or file, the shot's bytes untouched.

Every case edits a valid shot (tests/usd_fixtures.bandai_shot) with pxr in its own
tmp_path; most go through the ``fill_shot`` API (stderr captured at the file-descriptor
level, where USD prints), a subset through the ``tween fill-local`` CLI.
"""

from __future__ import annotations

import hashlib
import shutil
import subprocess
import sys
import time
import tracemalloc
from pathlib import Path

import numpy as np
import pytest
from usd_fixtures import ANIM, bandai_shot

from pipeline.errors import ShotError, TweenError
from pipeline.fill.api import FillOptions, fill_shot

SKEL = ANIM.rsplit("/", 1)[0]
NAN, INF = float("nan"), float("inf")
ROOT = Path(__file__).parents[2]


@pytest.fixture(scope="module")
def base(tmp_path_factory) -> Path:
    """A valid 21-frame shot (1001-1021, keys at 1001, 1011, 1021)."""
    return bandai_shot(tmp_path_factory.mktemp("base") / "walk.usda", frames=21, keys_every=10)


# --- edits of the valid shot -----------------------------------------------------------


def _anim(stage):
    from pxr import UsdSkel

    return UsdSkel.Animation(stage.GetPrimAtPath(ANIM))


def _skel(stage):
    from pxr import UsdSkel

    return UsdSkel.Skeleton(stage.GetPrimAtPath(SKEL))


def _set_rot(t, joint, q):
    def edit(stage):
        from pxr import Vt

        attr = _anim(stage).GetRotationsAttr()
        a = np.array(attr.Get(t), np.float32)
        a[joint] = q
        attr.Set(Vt.QuatfArray.FromNumpy(a), t)

    return edit


def _set_rot_all(t, q):
    def edit(stage):
        from pxr import Vt

        attr = _anim(stage).GetRotationsAttr()
        a = np.array(attr.Get(t), np.float32)
        a[:] = q
        attr.Set(Vt.QuatfArray.FromNumpy(a), t)

    return edit


def _set_trans(t, joint, v):
    def edit(stage):
        from pxr import Vt

        attr = _anim(stage).GetTranslationsAttr()
        a = np.array(attr.Get(t), np.float32)
        a[joint] = v
        attr.Set(Vt.Vec3fArray.FromNumpy(a), t)

    return edit


def _short_trans(t, n):
    def edit(stage):
        from pxr import Vt

        attr = _anim(stage).GetTranslationsAttr()
        a = np.ascontiguousarray(np.array(attr.Get(t), np.float32)[:n])
        attr.Set(Vt.Vec3fArray.FromNumpy(a), t)

    return edit


def _scale_default(joint, v):
    def edit(stage):
        from pxr import Vt

        attr = _anim(stage).GetScalesAttr()
        a = np.array(attr.Get(), np.float16)
        a[joint] = v
        attr.Set(Vt.Vec3hArray.FromNumpy(a))

    return edit


def _scale_sample(t, joint, v):
    def edit(stage):
        from pxr import Vt

        attr = _anim(stage).GetScalesAttr()
        a = np.array(attr.Get(), np.float16)
        attr.Set(Vt.Vec3hArray.FromNumpy(a), 1001)
        a[joint] = v
        attr.Set(Vt.Vec3hArray.FromNumpy(a), t)

    return edit


def _rot_default_only(q):
    def edit(stage):
        from pxr import Vt

        attr = _anim(stage).GetRotationsAttr()
        a = np.array(attr.Get(1001), np.float32)
        for t in attr.GetTimeSamples():
            attr.ClearAtTime(t)
        a[:] = q
        attr.Set(Vt.QuatfArray.FromNumpy(a))

    return edit


def _tcps(v):
    return lambda stage: stage.SetTimeCodesPerSecond(v)


def _fps_only(v):
    def edit(stage):
        layer = stage.GetRootLayer()
        layer.ClearTimeCodesPerSecond()
        layer.framesPerSecond = v

    return edit


def _metadata(key, value):
    return lambda stage: stage.SetMetadata(key, value)


def _retyped(name: str, type_name: str):
    """The animation's ``name`` authored as ``type_name``, same values: a type UsdSkel does not
    pose from (its ComputeJointLocalTransforms gives nothing), or float4[] rotations (x y z w
    read where a quaternion holds w x y z)."""

    def edit(stage):
        from pxr import Gf, Sdf, Vt

        attr = stage.GetPrimAtPath(ANIM).GetAttribute(name)
        kind = Sdf.ValueTypeNames.Find(type_name)
        value = {
            "float4[]": lambda a: Vt.Vec4fArray([Gf.Vec4f(*q.GetImaginary(), q.GetReal()) for q in a]),
            "quatd[]": lambda a: Vt.QuatdArray(
                [Gf.Quatd(q.GetReal(), Gf.Vec3d(q.GetImaginary())) for q in a]
            ),
            "quath[]": lambda a: Vt.QuathArray(
                [Gf.Quath(q.GetReal(), Gf.Vec3h(q.GetImaginary())) for q in a]
            ),
            "double3[]": lambda a: Vt.Vec3dArray([Gf.Vec3d(v) for v in a]),
            "half3[]": lambda a: Vt.Vec3hArray([Gf.Vec3h(v) for v in a]),
            "float3[]": lambda a: Vt.Vec3fArray([Gf.Vec3f(v) for v in a]),
        }[type_name]
        samples = {t: value(attr.Get(t)) for t in attr.GetTimeSamples()}
        layer = stage.GetRootLayer()  # the stage refuses the type the schema does not give it
        prim_spec = layer.GetPrimAtPath(ANIM)
        prim_spec.RemoveProperty(prim_spec.properties[name])
        spec = Sdf.AttributeSpec(prim_spec, name, kind)
        for t, a in samples.items():
            layer.SetTimeSample(spec.path, t, a)

    return edit


def _keyed_joints_default(kind):
    def edit(stage):
        from pxr import Sdf

        prim = stage.GetPrimAtPath(ANIM)
        if kind == "int":
            prim.CreateAttribute("tween:keyedJoints", Sdf.ValueTypeNames.IntArray).Set([0, 1], 1011)
        else:  # a default names no key time
            prim.CreateAttribute("tween:keyedJoints", Sdf.ValueTypeNames.TokenArray).Set(["Hips"])

    return edit


def _time_range(start, end):
    def edit(stage):
        stage.SetStartTimeCode(start)
        stage.SetEndTimeCode(end)

    return edit


def _joints(fn):
    """Applies fn(list of tokens) to the joints of the skeleton AND of the animation."""

    def edit(stage):
        for prim in (_skel(stage), _anim(stage)):
            tokens = [str(t) for t in prim.GetJointsAttr().Get()]
            prim.GetJointsAttr().Set(fn(tokens))

    return edit


def _swap(i, j):
    def fn(t):
        t[i], t[j] = t[j], t[i]
        return t

    return _joints(fn)


def _rename(i, name):
    def fn(t):
        t[i] = name
        return t

    return _joints(fn)


def _prefix_all(prefix):
    return _joints(lambda t: ["/".join(prefix + p for p in x.split("/")) for x in t])


def _skel_matrix(attr_name, joint, fill):
    def edit(stage):
        from pxr import Gf, Vt

        attr = _skel(stage).GetPrim().GetAttribute(attr_name)
        mats = list(attr.Get())
        mats[joint] = Gf.Matrix4d(*([fill] * 16)) if isinstance(fill, float) else fill
        attr.Set(Vt.Matrix4dArray(mats))

    return edit


def _no_rest_singular_bind(stage):
    from pxr import Gf

    _skel(stage).GetRestTransformsAttr().Clear()
    _skel_matrix("bindTransforms", 3, Gf.Matrix4d(0.0))(stage)


def _skel_xform_nan(stage):
    from pxr import Gf, UsdGeom

    UsdGeom.Xformable(_skel(stage).GetPrim()).AddTranslateOp().Set(Gf.Vec3d(NAN, 0, 0))


def _key_times(values):
    def edit(stage):
        from pxr import Sdf

        attr = _anim(stage).GetPrim().CreateAttribute("tween:keyTimes", Sdf.ValueTypeNames.DoubleArray)
        attr.Set(values)

    return edit


def _anim_token(i, name):
    def edit(stage):
        tokens = [str(t) for t in _anim(stage).GetJointsAttr().Get()]
        tokens[i] = name
        _anim(stage).GetJointsAttr().Set(tokens)

    return edit


# (id, edit, substring of the message, prim at fault or None)
CONTENT = [
    (
        "zero-quat",
        _set_rot(1011, 3, (0, 0, 0, 0)),
        "'Hips/Spine/Chest/Neck' at time 1011 is not a rotation",
        ANIM,
    ),
    ("zero-quats-first-key", _set_rot_all(1001, (0, 0, 0, 0)), "at time 1001 is not a rotation", ANIM),
    ("tiny-quat", _set_rot(1021, 0, (1e-9, 0, 0, 0)), "'Hips' at time 1021 is not a rotation", ANIM),
    ("nan-quat", _set_rot(1011, 5, (NAN, 0, 0, 1)), "rotations: NaN or infinite values at time 1011", ANIM),
    ("inf-quat", _set_rot(1001, 2, (0, INF, 0, 1)), "rotations: NaN or infinite values at time 1001", ANIM),
    (
        "nan-translation",
        _set_trans(1021, 0, (NAN, 0, 0)),
        "translations: NaN or infinite values at time 1021",
        ANIM,
    ),
    (
        "inf-translation",
        _set_trans(1011, 7, (0, 0, -INF)),
        "translations: NaN or infinite values at time 1011",
        ANIM,
    ),
    (
        "nan-scale-default",
        _scale_default(4, (1, NAN, 1)),
        "scales: NaN or infinite values in its default value",
        ANIM,
    ),
    (
        "inf-scale-sample",
        _scale_sample(1011, 9, (INF, 1, 1)),
        "scales: NaN or infinite values at time 1011",
        ANIM,
    ),
    (
        "short-translations",
        _short_trans(1011, 5),
        "translations holds 5 values for 21 joints at time 1011",
        ANIM,
    ),
    ("zero-quat-default", _rot_default_only((0, 0, 0, 0)), "in its default value is not a rotation", ANIM),
    # Finite but beyond any character (was an internal error: zero-norm quaternions downstream).
    (
        "far-translation",
        _set_trans(1011, 0, (1e20, 0, 0)),
        "translations: a value beyond ±1e+07 at time 1011",
        ANIM,
    ),
    ("float4-rotations", _retyped("rotations", "float4[]"), "rotations is float4[], not quatf[]", ANIM),
    # UsdSkel poses nothing from these (its joint transforms come back empty: the bind pose).
    ("quatd-rotations", _retyped("rotations", "quatd[]"), "rotations is quatd[], not quatf[]", ANIM),
    ("quath-rotations", _retyped("rotations", "quath[]"), "rotations is quath[], not quatf[]", ANIM),
    (
        "double3-translations",
        _retyped("translations", "double3[]"),
        "translations is double3[], not float3[]",
        ANIM,
    ),
    (
        "half3-translations",
        _retyped("translations", "half3[]"),
        "translations is half3[], not float3[]",
        ANIM,
    ),
    ("float3-scales", _retyped("scales", "float3[]"), "scales is float3[], not half3[]", ANIM),
    ("keyed-joints-default", _keyed_joints_default("token"), "tween:keyedJoints has no time samples", ANIM),
    ("keyed-joints-int", _keyed_joints_default("int"), "tween:keyedJoints is int[], not token[]", ANIM),
    ("up-axis-x", _metadata("upAxis", "X"), "upAxis 'X' is not an up axis USD knows (Y or Z)", None),
    ("mpu-huge", _metadata("metersPerUnit", 1e300), "metersPerUnit 1e+300 is not a unit", None),
    ("tcps-zero", _tcps(0), "timeCodesPerSecond 0 is not a positive number", None),
    ("tcps-negative", _tcps(-24), "timeCodesPerSecond -24 is not a positive number", None),
    ("tcps-nan", _tcps(NAN), "timeCodesPerSecond nan is not a positive number", None),
    ("tcps-inf", _tcps(INF), "timeCodesPerSecond inf is not a positive number", None),
    # USD's text parser itself refuses it; the line carries its reason (see the usdc test).
    (
        "fps-only-zero",
        _fps_only(0),
        'cannot open as USD: line 5:5: invalid value for field "framesPerSecond"',
        None,
    ),
    (
        "stage-range-reversed",
        _time_range(1021, 1001),
        "the stage range ends (1001) before it starts (1021)",
        None,
    ),
    ("stage-range-huge", _time_range(1001, 1e9), "spans more than 1,000,000 frames", None),
    ("stage-range-nan", _time_range(NAN, 1021), "the stage range nan-1021 is not finite", None),
    ("misordered-parent", _swap(0, 20), "skeleton topology is invalid: Joint 0 has mis-ordered parent", SKEL),
    ("ill-formed-joint", _rename(3, "Hips/Spine//Neck!"), "Ill-formed SdfPath <Hips/Spine//Neck!>", SKEL),
    ("duplicate-joint", _rename(20, "Hips/UpperLeg_R/LowerLeg_R/Foot_R"), "is joint 19 again", SKEL),
    ("absolute-joint", _rename(0, "/Hips"), "joint 0 '/Hips' is not a joint path", SKEL),
    ("namespaced-joints", _prefix_all("mixamorig:"), "joint 0 'mixamorig:Hips' is not a joint path", SKEL),
    ("nan-rest", _skel_matrix("restTransforms", 6, NAN), "restTransforms: NaN or infinite values", SKEL),
    ("inf-bind", _skel_matrix("bindTransforms", 2, INF), "bindTransforms: NaN or infinite values", SKEL),
    ("singular-bind-no-rest", _no_rest_singular_bind, "is singular", SKEL),
    ("nan-skel-xform", _skel_xform_nan, "world transform at time 1001 holds NaN", SKEL),
    ("nan-key-times", _key_times([1001.0, NAN, 1021.0]), "tween:keyTimes holds NaN or infinite", ANIM),
    ("inf-key-times", _key_times([1001.0, INF]), "tween:keyTimes holds NaN or infinite", ANIM),
    (
        "ill-formed-anim-joint",
        _anim_token(4, "Hips/Spine//Head"),
        "animation joint 'Hips/Spine//Head' is not",
        ANIM,
    ),
]

# (id, --keys, --range, substring of the message make_plan gives, the stage at hand)
OPTIONS = [
    ("keys-nan", "1001,nan", None, "--keys '1001,nan': 'nan' is not a finite time code"),
    ("keys-inf", "inf", None, "--keys 'inf': 'inf' is not a finite time code"),
    ("keys-minus-inf", "1001,-inf", None, "'-inf' is not a finite time code"),
    ("keys-overflow", "1001,1e400", None, "'1e400' is not a finite time code"),
    ("keys-huge-range", "1001-999999999", None, "key 1022 is outside the stage range 1001-1021"),
    ("keys-long-range", "1001-5000000", None, "key 1022 is outside the stage range 1001-1021"),
    ("keys-huge-dense", "1001-1021x1e-300", None, "more than 1,000,000 keys"),
    ("keys-step-zero", "1001-1100x0", None, "step 0 must be above 0"),
    ("keys-step-negative", "1001-1021x-2", None, "step -2 must be above 0"),
    ("keys-step-nan", "1001-1021xnan", None, "step 'nan' is not a finite number"),
    ("keys-step-missing", "1001-1021x", None, "step '' is not a finite number"),
    ("keys-reversed", "1021-1001", None, "the range ends (1001) before it starts (1021)"),
    ("keys-range-before-stage", "1001,900-1010", None, "'900-1010': key 900 is outside the stage range"),
    ("keys-nan-endpoint", "nan-1021", None, "'nan' is not a finite time code"),
    ("keys-garbage", "1001,eleven", None, "'eleven' is not a time code or a range like 1001-1100x8"),
    ("keys-empty-list", ",,", None, "--keys ',,': no key times"),
    ("range-nan", None, "nan-1021", "--range 'nan-1021': 'nan' is not a finite time code"),
    ("range-inf", None, "1001-inf", "'inf' is not a finite time code"),
    ("range-reversed", None, "1021-1001", "--range '1021-1001': end is before start"),
    ("range-huge", None, "1001-999999999", "spans 999998998 frames; at most 1,000,000"),
    ("range-past-stage", None, "1015-1035", "1015-1035 is not within the stage range 1001-1021"),
    ("range-step", None, "1001-1021x2", "expected START-END"),
    ("range-garbage", None, "soon", "--range 'soon': expected START-END"),
]

#: Cases also run through the CLI (a subprocess each, ~1.5 s).
CLI = {
    "zero-quat",
    "tcps-zero",
    "misordered-parent",
    "ill-formed-joint",
    "nan-skel-xform",
    "keys-huge-range",
    "keys-nan",
    "range-reversed",
}


def _prepare(tmp_path: Path, base: Path, edit) -> tuple[Path, str, dict]:
    from pxr import Usd

    shot = tmp_path / "shot.usda"
    shutil.copy(base, shot)
    if edit is not None:
        stage = Usd.Stage.Open(str(shot))
        edit(stage)
        stage.GetRootLayer().Save()
        del stage
    return shot, hashlib.sha256(shot.read_bytes()).hexdigest(), _listing(tmp_path)


def _listing(folder: Path) -> dict:
    return {str(p.relative_to(folder)): p.stat().st_size for p in sorted(folder.rglob("*"))}


def _untouched(tmp_path: Path, shot: Path, digest: str, listing: dict) -> None:
    assert hashlib.sha256(shot.read_bytes()).hexdigest() == digest, "the shot was modified"
    assert not (tmp_path / "o").exists(), "an output folder was created"
    assert _listing(tmp_path) == listing, "files appeared beside the shot"


def _api(shot: Path, tmp_path: Path, capfd, keys=None, range_=None) -> str:
    capfd.readouterr()
    with pytest.raises(TweenError) as ei:
        fill_shot(
            str(shot), FillOptions(model="interp", out_dir=str(tmp_path / "o"), keys=keys, range=range_)
        )
    out, err = capfd.readouterr()
    assert out == "" and err == "", f"stdout {out!r} stderr {err!r}"  # USD's Warning lines included
    return str(ei.value)


def _cli(shot: Path, tmp_path: Path, keys=None, range_=None) -> str:
    cmd = [sys.executable, "-m", "pipeline.cli", "fill-local", str(shot), "--model", "interp"]
    cmd += ["--out", str(tmp_path / "o")]
    cmd += ["--keys", keys] if keys is not None else []
    cmd += ["--range", range_] if range_ is not None else []
    r = subprocess.run(cmd, capture_output=True, text=True, cwd=ROOT, timeout=120)
    assert r.returncode == 2, (r.returncode, r.stderr[-2000:])
    assert r.stdout == ""
    lines = r.stderr.splitlines()
    assert len(lines) == 1, r.stderr
    assert lines[0].startswith("tween: error: "), lines[0]
    return lines[0][len("tween: error: ") :]


def _check_line(msg: str, shot: Path, match: str, prim: str | None) -> None:
    assert "\n" not in msg and "Warning" not in msg and "Traceback" not in msg, msg
    assert msg.startswith(str(shot)), msg
    if prim:
        assert msg.startswith(f"{shot} {prim}: "), msg
    assert match in msg, msg


@pytest.mark.parametrize("name,edit,match,prim", CONTENT, ids=[c[0] for c in CONTENT])
def test_bad_shot_content(name, edit, match, prim, base, tmp_path, capfd):
    shot, digest, listing = _prepare(tmp_path, base, edit)
    msg = _cli(shot, tmp_path) if name in CLI else _api(shot, tmp_path, capfd)
    _check_line(msg, shot, match, prim)
    _untouched(tmp_path, shot, digest, listing)


def _bounded(fn):
    """fn() must fail fast and small: a range is refused before it is expanded."""
    t0 = time.perf_counter()
    tracemalloc.start()
    try:
        msg = fn()
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert peak < 64 << 20, f"{peak / 2**20:.0f} MiB allocated before refusing"
    assert time.perf_counter() - t0 < 20
    return msg


@pytest.mark.parametrize("name,keys,range_,match", OPTIONS, ids=[c[0] for c in OPTIONS])
def test_bad_keys_and_range(name, keys, range_, match, base, tmp_path, capfd):
    """Through fill_shot / the CLI. Options that are bad whatever the shot are refused by
    FillOptions.check() before the shot is opened (pipeline/fill/api.py): that line names the
    option, not the shot; a check against the stage names both."""
    shot, digest, listing = _prepare(tmp_path, base, None)
    if name in CLI:
        msg = _cli(shot, tmp_path, keys, range_)
    else:
        msg = _bounded(lambda: _api(shot, tmp_path, capfd, keys, range_))
    opt = "--keys" if keys is not None else "--range"
    assert "\n" not in msg and "Warning" not in msg and "Traceback" not in msg, msg
    assert msg.startswith(f"{shot}: {opt} ") or msg.startswith(f"{opt} "), msg
    _untouched(tmp_path, shot, digest, listing)


@pytest.mark.parametrize("name,keys,range_,match", OPTIONS, ids=[c[0] for c in OPTIONS])
def test_bad_keys_and_range_against_the_stage(name, keys, range_, match, base, tmp_path, capfd):
    """make_plan parses the options with the stage at hand: every line names the shot and
    the option, ranges are checked against the stage range before they are expanded."""
    from pipeline.fill.plan import make_plan

    shot, digest, listing = _prepare(tmp_path, base, None)

    def plan():
        capfd.readouterr()
        with pytest.raises(ShotError) as ei:
            make_plan(str(shot), keys, range_, None, 30.0, own_rig=True)
        assert capfd.readouterr() == ("", "")
        return str(ei.value)

    msg = _bounded(plan)
    _check_line(msg, shot, match, None)
    assert msg.startswith(f"{shot}: {'--keys' if keys is not None else '--range'} "), msg
    _untouched(tmp_path, shot, digest, listing)


def test_frame_rate_zero_in_a_usdc_shot(base, tmp_path, capfd):
    """A binary layer takes framesPerSecond = 0 (the text parser does not); with no
    timeCodesPerSecond USD falls back to it."""
    from pxr import Sdf, Usd

    shot = tmp_path / "shot.usdc"
    stage = Usd.Stage.Open(str(base))  # held: the layer is a weak pointer into it
    stage.GetRootLayer().Export(str(shot))
    del stage
    layer = Sdf.Layer.FindOrOpen(str(shot))
    layer.ClearTimeCodesPerSecond()
    layer.framesPerSecond = 0
    layer.Save()
    del layer
    digest, listing = hashlib.sha256(shot.read_bytes()).hexdigest(), _listing(tmp_path)
    _check_line(_api(shot, tmp_path, capfd), shot, "framesPerSecond 0 is not a positive number", None)
    _untouched(tmp_path, shot, digest, listing)


def test_usd_warnings_are_folded_into_the_error(tmp_path, capfd):
    """USD's own message about a failure is part of the one line, never printed itself."""
    shot = tmp_path / "layered.usda"
    shot.write_text(
        '#usda 1.0\n(\n    subLayers = [@./missing_animation.usda@]\n)\n\ndef Xform "World"\n{\n}\n'
    )
    digest, listing = hashlib.sha256(shot.read_bytes()).hexdigest(), _listing(tmp_path)
    msg = _api(shot, tmp_path, capfd)
    _check_line(msg, shot, "no SkelRoot holds a skeleton with a bound SkelAnimation; USD: ", None)
    assert "missing_animation.usda" in msg, msg
    _untouched(tmp_path, shot, digest, listing)


def test_diagnostics_capture_keeps_usd_off_stderr_and_restores_it(capfd):
    from pxr import Sdf, Tf

    from pipeline.usd.diagnostics import usd_diagnostics

    capfd.readouterr()
    with usd_diagnostics() as diags:
        Tf.Warn("Joint 0 has mis-ordered parent 20. Joints are expected to be ordered.")
        Sdf.Path("Hips//Neck!")  # USD warns: Ill-formed SdfPath
    assert capfd.readouterr().err == ""
    assert len(diags) == 2 and "mis-ordered parent 20" in diags.texts()[0]
    assert "Ill-formed SdfPath" in diags.relevant("Hips//Neck!")
    err = diags.fold(ShotError("s.usda", "cannot read", "/World/Skel"))
    assert str(err) == "s.usda /World/Skel: cannot read; USD: Joint 0 has mis-ordered parent 20"
    with pytest.raises(ShotError, match=r"^s.usda: broken; USD: late warning$"):
        with usd_diagnostics("s.usda"):
            Tf.Warn("late warning")
            raise ShotError("s.usda", "broken")
    Tf.Warn("after the block")  # the delegate is gone: USD prints again
    assert "after the block" in capfd.readouterr().err


def test_valid_shot_still_fills_with_sub_frame_and_ranged_keys(base, tmp_path, capfd):
    """The checks refuse nothing good: a ranged --keys inside the stage and --range."""
    shot, digest, _ = _prepare(tmp_path, base, None)
    res = fill_shot(str(shot), FillOptions(model="interp", out_dir=str(tmp_path / "o"), keys="1001-1024x10",
                                           range="1003-1019"))  # fmt: skip
    assert Path(res["layer"]).is_file() and hashlib.sha256(shot.read_bytes()).hexdigest() == digest
    assert "Warning" not in capfd.readouterr().err
    assert Path(res["layer"]).parent == tmp_path / "o"


def test_keys_too_dense_for_the_model_rate(base, tmp_path, capfd):
    """20,001 sub-frame keys: within the bounds, refused by the plan (two on one frame)."""
    shot, digest, listing = _prepare(tmp_path, base, None)
    msg = _bounded(lambda: _api(shot, tmp_path, capfd, "1001-1021x0.001"))
    _check_line(msg, shot, "keys 1001 and 1001.001 fall on one model frame", ANIM)
    _untouched(tmp_path, shot, digest, listing)
