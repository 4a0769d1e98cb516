"""The ablation set behind the model card: one small fixed budget, one switch at a time.

``python -m pipeline.train.ablations OUT_DIR [STEPS]`` trains each variant for STEPS steps
(same seed, same batches) and exports it; ``tween bench --methods interp,OUT/<variant>/model``
then gives the rows.
"""

from __future__ import annotations

import sys
from dataclasses import replace
from pathlib import Path

from pipeline.models.generator import GeneratorConfig
from pipeline.train.generator import TrainConfig, train

VARIANTS = {
    "full": {},
    "no_residual": {"model": {"residual": False}},
    "no_tta": {"model": {"tta": False}},
    "no_curriculum": {"gap_start": 90},
    "no_velocity_loss": {"w_vel": 0.0},
    "euler": {"model": {"rotation": "euler"}},  # range-constrained Euler delta instead of 6D
    # Levers for shots the model never saw (issue 19): relative pose inputs, and augmentation
    # with what other rigs and actors bring (posture offsets, mirror images), alone and together.
    "delta": {"model": {"delta": True}},
    "augment": {"posture": 30.0, "mirror": 0.5},
    "delta_augment": {"model": {"delta": True}, "posture": 30.0, "mirror": 0.5},
}


def variant_config(name: str, steps: int) -> TrainConfig:
    spec = dict(VARIANTS[name])
    model = replace(GeneratorConfig(), **spec.pop("model", {}))
    return replace(TrainConfig(steps=steps, batch=32, checkpoint_minutes=1000), model=model, **spec)


def main(out: Path, steps: int, names: list[str]) -> None:
    from pipeline.train.export import export

    for name in names:
        run = out / name
        train(variant_config(name, steps), run)
        export(run, run / "model", f"ablation-{name}")


if __name__ == "__main__":
    main(Path(sys.argv[1]), int(sys.argv[2]) if len(sys.argv) > 2 else 1500, sys.argv[3:] or list(VARIANTS))
