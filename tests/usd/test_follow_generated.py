"""Kept root controls that follow a character joint (pipeline.usd.follow), generated
(Hypothesis) on the example walk with the pxr API, through ``tween fill-local --model interp``.

Each shot gets 1-3 root controls, each (a) rigidly on a random walk joint (0-30 cm off it,
turned at random, sometimes with noise under 0.5 cm), (b) moving on its own (a drifting random
walk) or (c) still; sometimes a scale on a joint (-1 on one axis among them); samples at every
frame or only at the keys; ``--keys`` every 5-15 frames, sometimes a ``--range`` between them.
An oracle written here (each control's position in each joint's frame over the keys the fill
fills between) says which controls follow; examples it cannot call clearly are skipped. Then:
one several-roots line naming what each control does; a following control, at every frame the
fill moved, where the named filled joint and the keys' interpolated relative transform put it
(translation lerped, rotation slerped); every control at the keys and outside the range bit for
bit, a control that follows nothing at every time; the shot untouched.
A mirrored joint's rotation is its orthogonal factor negated (follow._unit_rotations), with
two scales of one size ((-1, 1, 1)) too, where flipping one singular vector jumped a frame.

``TWEEN_HYPOTHESIS_EXAMPLES`` scales the example count (``make test-nightly``).
"""

from __future__ import annotations

import os
import re
import tempfile
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from hypothesis import HealthCheck, assume, event, example, given, settings
from hypothesis import strategies as st
from usd_fixtures import add_root_joints, digest, layer_samples, tween

SHOT = Path(__file__).resolve().parents[2] / "examples" / "sh010_walk.usda"
ROOT, SKEL = "/World/Walker", "/World/Walker/Skel"
ANIM = f"{SKEL}/Anim"
ATTRS = ("rotations", "translations", "scales")
FRAMES = [float(t) for t in range(1001, 1098)]
TOL = 2.0  # follow.TOLERANCE_M in the walk's units (metersPerUnit 0.01, an unscaled skeleton)
EXAMPLES = max(1, int(25 * int(os.environ.get("TWEEN_HYPOTHESIS_EXAMPLES", "200")) / 200))


@dataclass
class Control:
    """One root control the case adds (skeleton name ``Ctl<i>``, before the walk's joints)."""

    kind: str  # "on" a joint, "free" (its own random walk) or "still"
    joint: int = 0  # the walk joint it is on
    offset: tuple = (0.0, 0.0, 0.0)  # in the joint's frame
    turn: tuple = (0.0, 0.0, 0.0)  # its rotation relative to the joint's (rotation vector)
    noise: float = 0.0  # at most this far (cm) off the rigid place, at every sample
    seed: int = 0


@dataclass
class Case:
    """What one example makes of the walk and asks of the fill."""

    every: int  # keys every this many frames from 1001
    dense: bool  # samples at every frame, else at the keys only
    controls: list[Control] = field(default_factory=list)
    scale: tuple[int, tuple] | None = None  # (walk joint, its scale)
    span: tuple[float, float] | None = None  # --range

    @property
    def keys(self) -> list[float]:
        return FRAMES[:: self.every]


@st.composite
def cases(draw) -> Case:
    """1-3 controls, mostly on a joint; a scale on a joint a third of the time (half of those
    mirrored on one axis); a --range between the first and the last key half the time."""
    c = Case(every=draw(st.integers(5, 15)), dense=draw(st.booleans()))
    unit = st.floats(-1, 1, allow_nan=False)
    for _ in range(draw(st.integers(1, 3))):
        kind = draw(st.sampled_from(["on", "on", "free", "still"]))
        length = draw(st.floats(0, 30))
        v = np.array([draw(unit) for _ in range(3)]) + (1e-3, 0, 0)
        c.controls.append(
            Control(
                kind,
                joint=draw(st.integers(0, 20)),
                offset=tuple(v / np.linalg.norm(v) * length),
                turn=tuple(draw(unit) * 3.1 for _ in range(3)),
                noise=draw(st.sampled_from([0.0, 0.0, draw(st.floats(0, 0.49))])),
                seed=draw(st.integers(0, 2**32 - 1)),
            )
        )
    if draw(st.integers(0, 2)) == 0:  # on a joint a control is on, or any
        joint = draw(st.sampled_from([k.joint for k in c.controls if k.kind == "on"] or list(range(21))))
        axes = st.sampled_from([0.75, 1.0, 1.25, 1.5])
        s = [draw(axes) for _ in range(3)]
        if draw(st.booleans()):
            s[draw(st.integers(0, 2))] = -1.0  # a mirrored joint
        c.scale = (joint, tuple(s))
    if draw(st.booleans()):
        lo, hi = sorted(draw(st.lists(st.sampled_from(FRAMES[: FRAMES.index(c.keys[-1]) + 1]),
                                      min_size=2, max_size=2, unique=True)))  # fmt: skip
        c.span = (lo, hi)
    return c


def _polar(lin: np.ndarray) -> np.ndarray:
    """The orthogonal factor of (..., 3, 3) column-convention matrices (improper where mirrored)."""
    u, _, vt = np.linalg.svd(lin)
    return u @ vt


def _build(shot: Path, c: Case) -> None:
    """Writes the case into the copy ``shot`` of the walk (pxr API): the scale, the walk
    resampled at the case's times (USD's interpolation of its keys), the controls."""
    from pxr import Gf, Usd, UsdSkel, Vt
    from scipy.spatial.transform import Rotation

    stage = Usd.Stage.Open(str(shot))
    anim = stage.GetPrimAtPath(ANIM)
    if c.scale:
        sc = anim.GetAttribute("scales")
        v = np.array(sc.Get(), np.float16)
        v[c.scale[0]] = c.scale[1]
        sc.Set(Vt.Vec3hArray.FromNumpy(v))
    times = FRAMES if c.dense else c.keys
    cache = UsdSkel.Cache()
    cache.Populate(UsdSkel.Root(stage.GetPrimAtPath(ROOT)), Usd.PrimDefaultPredicate)
    query = cache.GetSkelQuery(UsdSkel.Skeleton(stage.GetPrimAtPath(SKEL)))
    mats = np.array([np.array(query.ComputeJointSkelTransforms(Usd.TimeCode(t))) for t in times])
    mats = np.swapaxes(mats, -1, -2)  # column convention
    names = [f"Ctl{i}" for i in range(len(c.controls))]
    rots, trs = [], []
    for k in c.controls:
        rng = np.random.default_rng(k.seed)
        if k.kind == "on":
            lin = mats[:, k.joint, :3, :3]
            g = _polar(lin)
            sign = np.sign(np.linalg.det(g))[:, None, None]  # a mirrored joint: g improper
            rot = g @ (sign * Rotation.from_rotvec(k.turn).as_matrix())
            pos = lin @ np.array(k.offset) + mats[:, k.joint, :3, 3]
            jitter = rng.normal(size=(len(times), 3))
            jitter *= (k.noise * rng.uniform(0, 1, (len(times), 1))) / np.linalg.norm(jitter, axis=1)[:, None]
            pos = pos + jitter
        elif k.kind == "free":  # drifts 3-6 cm a frame, wandering
            drift = rng.normal(size=3)
            drift *= rng.uniform(3, 6) / np.linalg.norm(drift)
            steps = drift + rng.normal(0, 1.5, (len(FRAMES), 3))
            walk = rng.uniform(-100, 100, 3) + np.cumsum(steps, 0)
            pos = walk[[FRAMES.index(t) for t in times]]
            rot = Rotation.from_rotvec(np.outer(np.array(times) - 1001, rng.normal(0, 0.05, 3))).as_matrix()
        else:
            pos = np.tile(rng.uniform(-100, 100, 3), (len(times), 1))
            rot = np.tile(Rotation.random(random_state=k.seed % 2**31).as_matrix(), (len(times), 1, 1))
        rots.append(Rotation.from_matrix(rot).as_quat())
        trs.append(pos)
    add_root_joints(stage.GetPrimAtPath(SKEL), anim, names)
    rot_a, tr_a = anim.GetAttribute("rotations"), anim.GetAttribute("translations")
    walk_r = {t: np.array(rot_a.Get(t), np.float32) for t in times}
    walk_t = {t: np.array(tr_a.Get(t), np.float32) for t in times}
    rot_a.Clear()
    tr_a.Clear()
    for i, t in enumerate(times):
        q = np.array([r[i] for r in rots], np.float32).reshape(-1, 4)
        rot_a.Set(Vt.QuatfArray.FromNumpy(np.concatenate([walk_r[t], q])), t)
        p = np.array([x[i] for x in trs], np.float32).reshape(-1, 3)
        tr_a.Set(Vt.Vec3fArray.FromNumpy(np.concatenate([walk_t[t], p])), t)
    sc = anim.GetAttribute("scales")
    sc.Set(Vt.Vec3hArray(list(sc.Get()) + [Gf.Vec3h(1, 1, 1)] * len(names)))
    stage.Save()


def _skel_transforms(path: Path, times) -> tuple[list[str], np.ndarray]:
    """(joint names, (T, J, 4, 4) column-convention skeleton-space transforms): UsdSkel's
    reading of the composed stage at ``path``."""
    from pxr import Usd, UsdSkel

    stage = Usd.Stage.Open(str(path))
    cache = UsdSkel.Cache()
    cache.Populate(UsdSkel.Root(stage.GetPrimAtPath(ROOT)), Usd.PrimDefaultPredicate)
    query = cache.GetSkelQuery(UsdSkel.Skeleton(stage.GetPrimAtPath(SKEL)))
    names = [str(t).rsplit("/", 1)[-1] for t in query.GetJointOrder()]
    mats = np.array([np.array(query.ComputeJointSkelTransforms(Usd.TimeCode(t))) for t in times])
    return names, np.swapaxes(mats, -1, -2)


def _judged(c: Case) -> list[float]:
    """The keys the fill fills between: those in the range and the key on either side."""
    if not c.span:
        return c.keys
    lo = max(k for k in c.keys if k <= c.span[0])
    hi = min(k for k in c.keys if k >= c.span[1])
    return [k for k in c.keys if lo <= k <= hi]


def _deviation(mats: np.ndarray, ctl: int, chars: list[int]) -> np.ndarray:
    """Per character joint, how far the control strays over ``mats``' times from the mean of
    its positions in the joint's frame (the definition of following)."""
    sub = mats[:, chars]
    lin, at = sub[..., :3, :3], sub[..., :3, 3]
    p = np.linalg.solve(lin, (mats[:, ctl, :3, 3][:, None] - at)[..., None])[..., 0]
    return np.linalg.norm((lin @ (p - p.mean(0))[..., None])[..., 0], axis=-1).max(0)


def _expected(c: Case, names: list[str], src: np.ndarray, chars: list[int]) -> dict[str, np.ndarray | None]:
    """Per control, its deviations from the joints (it follows the least) or None where it
    follows nothing; an example too close to the tolerance to call is skipped."""
    at = [FRAMES.index(t) for t in _judged(c)]
    out: dict = {}
    for i, k in enumerate(c.controls):
        ctl = names.index(f"Ctl{i}")
        pos = src[at, ctl, :3, 3]
        moves = np.linalg.norm(pos - pos.mean(0), axis=1).max()
        assume(not 0.5 * TOL < moves < 2 * TOL)
        dev = np.full(len(names), np.inf)  # by skeleton index: the controls follow no control
        dev[chars] = _deviation(src[at], ctl, chars)
        if moves <= 0.5 * TOL:
            out[k.kind + str(i)] = None  # a control still over the keys follows nothing
            continue
        if k.kind == "on":
            assume(dev.min() < 0.75 * TOL)
            out[k.kind + str(i)] = dev
        else:
            assume(dev.min() > 2 * TOL)  # clearly on no joint
            out[k.kind + str(i)] = None
    return out


def _warning(err: str, c: Case, expect: dict) -> dict[int, str]:
    """Checks the one several-roots line; the joint each control follows, by control."""
    lines = [ln for ln in err.splitlines() if "root joints" in ln]
    assert len(lines) == 1 and "Traceback" not in err and "error" not in err, (c, err)
    line = lines[0]
    said = dict(re.findall(r"'(Ctl\d)' follows the filled '(\w+)'", line))
    want = [f"Ctl{i}" for i, d in enumerate(expect.values()) if d is not None]
    assert sorted(said) == want, (c, line)
    if not want:
        assert line.endswith("the animation's values as authored"), (c, line)
        return {}
    stays = [f"'Ctl{i}'" for i, d in enumerate(expect.values()) if d is None]
    if stays:
        assert line.endswith(f"; {', '.join(stays)} {'stays' if len(stays) == 1 else 'stay'} as authored"), (
            c,
            line,
        )
    return {int(k[3:]): v for k, v in said.items()}


def _slerp(a: np.ndarray, b: np.ndarray, w: np.ndarray) -> np.ndarray:
    """(T, 3, 3) rotations from ``a`` to ``b`` (each (T, 3, 3)) by ``w``."""
    from scipy.spatial.transform import Rotation

    step = Rotation.from_matrix(np.swapaxes(a, -1, -2) @ b).as_rotvec()
    return a @ Rotation.from_rotvec(step * w[:, None]).as_matrix()


def _check_follow(c: Case, names, src, out, ctl: int, joint: int, dev, moved: list[int]) -> None:
    """The control ``ctl`` at the ``moved`` frames: the filled ``joint``'s transform times the
    keys' relative transform, translation lerped and rotation slerped (in the joint's frame
    less its scale; a mirrored joint's relative rotation taken with its reflection)."""
    judged = _judged(c)
    at = [FRAMES.index(t) for t in judged]
    assert dev[joint] <= TOL + 1e-6 and dev[joint] <= dev.min() + 1e-3 * TOL + 1e-6, (c, names[joint], dev)
    lin, pos = src[at, joint, :3, :3], src[at, joint, :3, 3]
    rel_t = np.linalg.solve(lin, (src[at, ctl, :3, 3] - pos)[..., None])[..., 0]
    g = _polar(lin)
    sign = np.sign(np.linalg.det(g))[0]
    rel_r = sign * np.swapaxes(g, -1, -2) @ src[at, ctl, :3, :3]  # proper: times the reflection -1
    t = np.array(FRAMES)[moved]
    b = np.clip(np.searchsorted(judged, t), 1, len(judged) - 1)
    w = (t - np.array(judged)[b - 1]) / (np.array(judged)[b] - np.array(judged)[b - 1])
    lin_t, pos_t = out[moved, joint, :3, :3], out[moved, joint, :3, 3]
    want = (lin_t @ (rel_t[b - 1] + (rel_t[b] - rel_t[b - 1]) * w[:, None])[..., None])[..., 0] + pos_t
    got = out[moved, ctl, :3, 3]
    assert np.abs(got - want).max() < 1e-3, (c, names[joint], np.abs(got - want).max())  # float32, 1 m off
    rot = _polar(lin_t) @ (sign * _slerp(rel_r[b - 1], rel_r[b], w))
    turn = np.swapaxes(rot, -1, -2) @ out[moved, ctl, :3, :3]
    # The angle from |R - I| (2√2·sin(θ/2)), exact near 0 where arccos of the trace is not.
    angle = np.degrees(2 * np.arcsin(np.minimum(np.linalg.norm(turn - np.eye(3), axis=(1, 2)) / 8**0.5, 1)))
    assert angle.max() < 0.01, (c, names[joint], angle.max())


def _walk_joints() -> list[str]:
    from pxr import Sdf

    layer = Sdf.Layer.FindOrOpen(str(SHOT))  # held: its specs expire with it
    return [str(t) for t in layer.GetAttributeAtPath(f"{SKEL}.joints").default]


def _check(shot: Path, c: Case, err: str) -> None:
    """The fill of ``shot`` against the oracle: the warning, the review stage, the fill layer."""
    from pxr import Usd

    names, src = _skel_transforms(shot, FRAMES)
    _, out = _skel_transforms(shot.parent / "sh010.review.v001.usda", FRAMES)
    chars = [i for i, n in enumerate(names) if not n.startswith("Ctl")]
    expect = _expected(c, names, src, chars)
    follows = _warning(err, c, expect)
    event(f"{len(follows)} of {len(expect)} controls follow" + (", a --range" if c.span else ""))
    lo, hi = c.span or (c.keys[0], c.keys[-1])
    moved = [i for i, t in enumerate(FRAMES) if lo <= t <= hi and t not in c.keys]
    kept = [i for i in range(len(FRAMES)) if i not in moved]
    for i, dev in enumerate(expect.values()):
        ctl = names.index(f"Ctl{i}")
        # At the keys and outside the range (every time for one that follows nothing): as authored.
        same = kept if i in follows else list(range(len(FRAMES)))
        assert np.array_equal(out[same, ctl], src[same, ctl]), (c, i)
        if i in follows:
            joint = names.index(follows[i]) - len(c.controls)  # in the walk's order
            event("follows the joint it is on" if joint == c.controls[i].joint else "follows another joint")
            if c.scale and c.scale[0] == joint and min(c.scale[1]) < 0:
                event("follows a mirrored joint")
            _check_follow(c, names, src, out, ctl, names.index(follows[i]), dev, moved)
    # The fill layer: every control and every joint at the keys as the animator's animation gives.
    stage = Usd.Stage.Open(str(shot))  # held: its prims expire with it
    anim = stage.GetPrimAtPath(ANIM)
    joints, filled = layer_samples(shot.parent / "sh010.tween.v001.usda", f"{ANIM}_tween", ATTRS)
    still = [joints.index(f"Ctl{i}") for i, d in enumerate(expect.values()) if i not in follows]
    for name in ATTRS:
        for t, v in filled[name].items():
            authored = np.array(anim.GetAttribute(name).Get(t))
            assert np.array_equal(v[still], authored[still]), (c, name, t)
            if t in c.keys or not lo <= t <= hi:
                assert np.array_equal(v, authored), (c, name, t)


@settings(max_examples=EXAMPLES, deadline=None, database=None,
          suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow,
                                 HealthCheck.filter_too_much])  # fmt: skip
@given(c=cases())
# Found by the generator: a control on the Spine under Hips scaled (-1, 0.75, 1.25), a sheared
# mirrored frame, and a prop on Hand_R scaled (-1, 1, 1), two scales of one size, which turned
# up to 180 degrees a frame before mirrored rotations were the negated orthogonal factor.
@example(c=Case(5, False, [Control("on", joint=1)], scale=(0, (-1.0, 0.75, 1.25))))
@example(
    c=Case(
        8,
        True,
        [Control("on", joint=12, offset=(0.0, -8.0, 3.0), turn=(0.2, 0.4, 0.6))],
        scale=(12, (-1.0, 1.0, 1.0)),
    )
)
def test_generated_controls_follow_their_joint_or_stay_as_authored(monkeypatch, capsys, c):
    with tempfile.TemporaryDirectory() as d:
        shot = Path(d) / "sh010.usda"
        shot.write_bytes(SHOT.read_bytes())
        _build(shot, c)
        before = digest(shot)
        args = ["--keys", f"1001-1097x{c.every}", "--model", "interp"]
        if c.span:
            args += ["--range", f"{c.span[0]:g}-{c.span[1]:g}"]
        rc, err = tween(monkeypatch, capsys, "fill-local", shot, *args)
        assert rc == 0, (c, err)
        assert digest(shot) == before, c
        _check(shot, c, err)
