"""The library as an in-betweener: per gap, the library's best windows fitted onto the keys,
or the spline where the library has nothing like them (the trusted fill's curve, feet the keys
plant held: :mod:`pipeline.infer.plant`).

Per gap (:mod:`pipeline.library.match`): the ``BEST`` windows of least cost, fitted onto the
two keys and averaged. How far the gap takes them over the spline through the same keys
(what the animator's DCC draws) follows from their pose miss at the keys (cm, the mean
joint-position distance between the keys and the windows' ends): in full up to
``TRUST_CM``, not at all from ``REFUSE_CM``, linearly between (the library's motion is
then not the keys' motion); from that miss against how much the keys move; and not at all
where the keys lie on a smooth curve, which the spline already follows (:func:`gap_weight`,
:func:`key_bend_cm`). Gaps no take of the library spans, and gaps longer than
``MAX_GAP`` frames, are the spline's. Feet in contact in the retrieved windows are held
in place by the fill's foot cleanup (:func:`pipeline.infer.post.lock_feet`). Keys are
bitwise the input's. ``last_gaps`` keeps, per gap of the latest fill, its frames, pose miss,
weight and the windows it took (take name and frame), for the fill's record.

The trusted fill (:mod:`pipeline.infer.trust`) wraps this in-betweener as it wraps the
network (and beside it: the one whose probes do better decides): probes from the shot's
own keys decide, per gap length, how far the whole is trusted over the spline; the network
decides instead only when its probes beat the library's by ``capabilities.probe_margin``. The constants
were chosen on held-out takes of a split other than the bench's (docs/library.md).
"""

from __future__ import annotations

from functools import cached_property

import numpy as np

from pipeline.data.skeletons import LEGS, bandai_skeleton
from pipeline.infer.api import Capabilities
from pipeline.infer.plant import model_feet, plant_rotations
from pipeline.infer.post import lock_feet, match_keys
from pipeline.infer.spline import spline_keys
from pipeline.infer.trust import CURVE
from pipeline.library import match
from pipeline.library.match_features import frame_features
from pipeline.library.store import FILL_FPS, Library, LibraryError, check_fillable, open_library
from pipeline.motion.clip import Motion
from pipeline.motion.rotations import slerp_pairs

#: Pose miss (cm) up to which a gap takes the library's windows in full.
TRUST_CM = 6.0
#: Pose miss (cm) from which a gap is the spline's.
REFUSE_CM = 12.0
#: Library frames in the pose bank the trusted fill measures the keys' familiarity on.
BANK_POSES = 4096
#: Pose miss over the keys' change of pose (+ CHANGE_FLOOR_CM) up to which a gap takes the
#: library in full (TRUST_RATIO), and from which it is the spline's (REFUSE_RATIO): where the
#: keys barely move, the spline is already right and a window that misses them adds motion
#: nobody keyed (on CMU takes, gaps whose keys move under 3.5 cm were 1.6x the spline).
TRUST_RATIO = 0.5
REFUSE_RATIO = 1.5
CHANGE_FLOOR_CM = 1.0
#: How far (cm) the keys of a gap bend off the cubic through their neighbours (key_bend_cm)
#: up to which the gap is the spline's (SMOOTH_CM), and from which it takes the library in
#: full (BENT_CM): keys on a smooth curve are keys the spline already follows between them (on
#: the tuning split, slow takes whose spline is 0.05 cm off, where the library's windows were
#: up to 1.2x the spline), and the most the library can win there is that 0.05 cm.
SMOOTH_CM = 0.5
BENT_CM = 1.0
#: The longest gap (frames) the library fills; longer ones are the spline's.
MAX_GAP = 300


def gap_weight(miss_cm: float, change_cm: float = np.inf, bend_cm: float = np.inf) -> float:
    """The library's share of a gap whose windows miss the keys by ``miss_cm`` while the pose
    changes by ``change_cm`` from one key to the other (both RMS over the joints), and whose
    keys bend ``bend_cm`` off the cubic through their neighbours (:func:`key_bend_cm`)."""
    absolute = (REFUSE_CM - miss_cm) / (REFUSE_CM - TRUST_CM)
    relative = (REFUSE_RATIO - miss_cm / (change_cm + CHANGE_FLOOR_CM)) / (REFUSE_RATIO - TRUST_RATIO)
    smooth = (bend_cm - SMOOTH_CM) / (BENT_CM - SMOOTH_CM)
    return float(np.clip(min(absolute, relative, smooth), 0.0, 1.0))


def key_bend_cm(feats: np.ndarray, keys: np.ndarray) -> np.ndarray:
    """(K,) how far each key's pose (features, RMS over the joints, cm) is from the cubic
    through the two keys on either side of it (fewer at the ends of the shot): the spline's
    miss at that key were it left out, a probe per key without filling anything. The first
    and last keys take their neighbour's."""
    K = len(keys)
    out = np.full(K, np.inf)
    t = np.asarray(keys, np.float64)
    f = np.asarray(feats, np.float64)
    joints = (f.shape[1] - 1) / 3.0
    for k in range(1, K - 1):
        nb = [i for i in (k - 2, k - 1, k + 1, k + 2) if 0 <= i < K]
        guess = np.zeros(f.shape[1])
        for i in nb:  # Lagrange's polynomial through the neighbours, at key k
            guess += np.prod([(t[k] - t[j]) / (t[i] - t[j]) for j in nb if j != i]) * f[i]
        out[k] = np.sqrt(((guess - f[k]) ** 2).sum() / joints)
    if K > 2:
        out[0], out[-1] = out[1], out[-2]
    return out


class LibraryInbetweener:
    """Fills the frames between keys from a studio's library (:mod:`pipeline.library`)."""

    fps = FILL_FPS  # the frame rate a library must be at (store.check_fillable)
    #: ``probe_margin``: the score (mean log error ratio at the probes) by which the network
    #: probed beside the library must beat it to fill the character instead
    #: (pipeline.infer.trust): the probes' holes are twice the shot's gaps, and on the tuning
    #: split they picked the network where the library was better (keys every 10: 0.212
    #: pooled, against the library's 0.198).
    capabilities = Capabilities(partial_keys=True, novelty=True, per_gap=True, probe_margin=0.25)

    def __init__(self, library: str | Library, feet: bool = True, best: int = match.BEST):
        self.library = library if isinstance(library, Library) else open_library(library)
        self.skeleton = bandai_skeleton()
        check_fillable(self.library)  # `tween library info` runs the same check
        if self.library.frames < 2:
            raise LibraryError(f"{self.library.folder}: the library holds no motion")
        self.name = f"library:{self.library.name}"
        self.model_hash = f"library-{self.library.hash}"
        self.feet, self.best = feet, best
        self.legs = [tuple(self.skeleton.index(n) for n in leg) for leg in LEGS]
        self.planted = model_feet(self.skeleton)
        self.last_gaps: list[dict] = []

    @cached_property
    def pose_bank(self) -> np.ndarray:
        """(P, J, 3) float32: ``BANK_POSES`` library frames (fixed seed) as the trusted fill's
        novelty reads them, so keys unlike the library's motion earn it no credit beyond
        what the probes show (:mod:`pipeline.infer.novelty`)."""
        lib = self.library
        pick = np.sort(
            np.random.default_rng(0).choice(lib.frames, min(BANK_POSES, lib.frames), replace=False)
        )
        J = len(self.skeleton)
        return np.asarray(lib.features[pick, : J * 3], np.float32).reshape(len(pick), J, 3)

    def fill(self, motion: Motion, keys, seed: int = 0, joint_keys=None, dna=None) -> Motion:
        if dna is not None:
            raise ValueError(f"{self.name}: a library takes no motion DNA")
        keys = np.asarray(keys, np.int64)
        if joint_keys is None or np.asarray(joint_keys, bool).all():
            rot, root = self._fill(motion.rotations, motion.root_positions, np.unique(keys))
        else:  # partial keys: filled from the full keys, the partial ones matched after (as the spline)
            mask = np.asarray(joint_keys, bool)
            rot, root = self._fill(motion.rotations, motion.root_positions, keys[mask.all(axis=1)])
            q, r = match_keys(rot[None], root[None], motion.rotations[keys][None],
                              motion.root_positions[keys][None], keys, mask)  # fmt: skip
            rot, root = np.asarray(q[0], np.float32), np.asarray(r[0], np.float32)
        return Motion(motion.skeleton, rot, root, motion.fps, motion.name)

    def _fill(self, rotations: np.ndarray, roots: np.ndarray, keys: np.ndarray):
        """(T, J, 4) / (T, 3) filled from the full ``keys``: the spline, then each gap the
        library spans blended over it at its weight; the keys bitwise the input's."""
        skel = self.skeleton
        rot, root = spline_keys(rotations, roots, keys, CURVE, fps=self.fps)
        if self.feet and self.planted is not None:  # the trusted curve's, as the gaps left to it
            rot = plant_rotations(rot, root, skel, keys, self.planted)
        rot, root = rot.astype(np.float64), root.astype(np.float64)
        contacts = np.zeros((len(rot), 2))
        k_rot = np.asarray(rotations[keys], np.float64)
        k_root = np.asarray(roots[keys], np.float64)
        feats, faces = frame_features(k_rot, k_root, skel)
        bend = key_bend_cm(feats, keys)
        gaps: list[dict] = []
        todo = [g for g in range(len(keys) - 1) if 1 < keys[g + 1] - keys[g] <= MAX_GAP]
        for g in range(len(keys) - 1):
            if keys[g + 1] - keys[g] > MAX_GAP:
                gaps.append(self._row(keys, g, None, 0.0, "longer than the library fills"))
        # The distances of a block of keys to every library frame at once (memory follows the block).
        for b0 in range(0, len(todo), match.KEY_BLOCK - 1):
            block = todo[b0 : b0 + match.KEY_BLOCK - 1]
            idx = sorted({i for g in block for i in (g - 1, g, g + 1, g + 2) if 0 <= i < len(keys)})
            at = {i: c for c, i in enumerate(idx)}
            d = match.key_distances(self.library, feats[idx])
            for g in block:
                m = self._search(keys, g, d, at, k_root, faces)
                if m is None:
                    gaps.append(self._row(keys, g, None, 0.0, "no take of the library is that long"))
                    continue
                change = float(np.sqrt(((feats[g + 1] - feats[g]) ** 2).sum() / len(skel)))
                bent = float(max(bend[g], bend[g + 1]))
                w = gap_weight(m.miss_cm, change, bent)
                why = "" if w > 0 else "the library has no motion like the keys"
                if w <= 0 and gap_weight(m.miss_cm, change) > 0:
                    why = "the keys lie on a smooth curve: the spline's"
                row = self._row(keys, g, m, w, why)
                gaps.append(row | {"change_cm": round(change, 4), "bend_cm": round(min(bent, 1e6), 4)})
                if w <= 0.0:
                    continue
                self._blend(rot, root, contacts, keys, g, m, w, k_rot, k_root, faces)
        self.last_gaps = sorted(gaps, key=lambda r: r["frames"][0])
        out_rot = rot.astype(np.float32)
        if self.feet and contacts.any():
            out_rot = lock_feet(out_rot, root, skel, (contacts > 0.5).astype(np.float32), keys, self.legs,
                                anchor=True, orient=True)  # fmt: skip
        out_root = root.astype(np.float32)
        out_rot[keys], out_root[keys] = rotations[keys], roots[keys]
        return out_rot, out_root

    def _search(self, keys, g: int, d, at: dict, k_root, faces):
        """The library's best match for gap ``g`` (its keys' distances ``d[at[g]]`` and
        ``d[at[g + 1]]``, the travel and turn between them, the keys around it), or None."""
        n = int(keys[g + 1] - keys[g])
        step = k_root[g + 1] - k_root[g]
        travel = match.batch_quat_apply(faces[g], step)[[0, 2]]
        turn = float(match.wrap_angle(match.yaw_of(faces[g]) - match.yaw_of(faces[g + 1])))
        context = [
            (d[at[i]], int(keys[i] - keys[g]))
            for i in (g - 1, g + 2)
            if i in at and abs(int(keys[i]) - int(keys[g if i < g else g + 1])) <= match.CONTEXT_FRAMES
        ]
        return match.search(self.library, d[at[g]], d[at[g + 1]], n, travel, turn, self.best, context)

    def _blend(self, rot, root, contacts, keys, g: int, m, w: float, k_rot, k_root, faces) -> None:
        """Gap ``g``: the match ``m``'s windows fitted to its keys, averaged and blended over
        the spline at weight ``w``, and their foot contacts, in place."""
        n = int(keys[g + 1] - keys[g])
        fits = [match.fit_window(self.library, int(s), n, k_rot[g : g + 2], k_root[g : g + 2], faces[g])
                for s in m.starts]  # fmt: skip
        q, p = match.average([f[0] for f in fits], [f[1] for f in fits], m.weights)
        lo, hi = int(keys[g]), int(keys[g + 1])
        inner = slice(lo + 1, hi)
        if w >= 1.0:
            rot[inner], root[inner] = q[1:-1], p[1:-1]
        else:
            rot[inner] = slerp_pairs(rot[inner], q[1:-1], np.full(q[1:-1].shape[:-1], w))
            root[inner] += w * (p[1:-1] - root[inner])
        c = sum(wt * match.window_contacts(self.library, int(s), n)
                for s, wt in zip(m.starts, m.weights, strict=True))  # fmt: skip
        contacts[lo : hi + 1] = np.maximum(contacts[lo : hi + 1], w * c)

    def _row(self, keys, g: int, m, weight: float, why: str) -> dict:
        row = {"frames": [int(keys[g]), int(keys[g + 1])], "weight": round(weight, 4)}
        if m is None:
            return row | {"miss_cm": None, "windows": [], "why": why}
        takes = self.library.manifest["takes"]
        starts = np.array([t["start"] for t in takes])
        where = []
        for s in m.starts:
            t = takes[int(np.searchsorted(starts, s, side="right")) - 1]
            where.append([t["name"], int(s) - int(t["start"])])
        return row | {"miss_cm": round(m.miss_cm, 3), "windows": where, **({"why": why} if why else {})}
