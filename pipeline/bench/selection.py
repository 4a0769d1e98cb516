"""Windows for choosing inference settings and models without looking at the eval split.

The research scripts (``experiments/pad_layouts.py``, ``experiments/foot_lock_variants.py``,
``experiments/partial_choice.py``) compare settings on the protocol's task (PROTOCOL.md) on
windows cut from the train clips, so that the eval split only ever measures the choice.
"""

from __future__ import annotations

import numpy as np

from pipeline.data.protocol import TEST_STRIDE, TEST_WINDOW, normalize_windows, windows_of

#: Every how many train clips a window set takes one (the experiments' default).
EVERY = 4


def train_windows(every: int = EVERY) -> tuple[np.ndarray, np.ndarray]:
    """Protocol windows (rotations, roots; centred, facing +X) cut as PROTOCOL.md cuts them
    from every ``every``-th train clip. The clips were seen in training: what is chosen on them
    is a question of input format or post-processing, not of what the model memorised."""
    from pipeline.data.cache import load_split

    if every < 1:
        raise ValueError(f"every={every}: must be 1 or more")
    clips = load_split("train")
    picked = (clips.clip(c) for c in range(0, len(clips), every))
    return normalize_windows(*windows_of(picked, TEST_WINDOW, TEST_STRIDE))
