"""``tween train`` and ``tween export`` (need the ``[train]`` extra: torch)."""

from pathlib import Path

import typer


def register(app: typer.Typer) -> None:
    @app.command()
    def train(
        out: Path = typer.Option(
            Path("runs/default"), help="Run folder: checkpoints, logs (resumes if present)."
        ),
        steps: int = typer.Option(8000, help="Generator steps."),
        path_steps: int = typer.Option(2000, help="Path-predictor steps (trained first, then frozen)."),
        adv_start: int = typer.Option(
            6800, help="Generator step where the LSGAN refinement starts (none: -1)."
        ),
        batch: int = typer.Option(32),
        seed: int = typer.Option(0),
        threads: int = typer.Option(1, help="torch threads; 1 is fastest on 2 shared cores."),
        data: Path = typer.Option(
            None, help="A folder of your own BVH clips (model skeleton) instead of Bandai train."
        ),
        limit_clips: int = typer.Option(None, help="Use only the first N train clips (smoke tests)."),
        init: Path = typer.Option(None, help="Continue from this generator checkpoint's weights."),
        lr: float = typer.Option(1e-3, help="Peak learning rate of the one-cycle schedule."),
        pos_zscore: bool = typer.Option(False, help="Weigh position errors by 1/std per coordinate."),
        device: str = typer.Option("cpu", help="cpu, or cuda where a GPU is available."),
        gap_weighting: float = typer.Option(
            0.0, help="Weigh frames by gap length ** -this (1: every gap alike)."
        ),
        lengths: str = typer.Option("64,96,128", help="Training window lengths, comma-separated."),
        workers: int = typer.Option(0, help="Processes making batches ahead (useful with --device cuda)."),
        data_pack: Path = typer.Option(
            None, help="Train split packed by `python -m pipeline.data.pack` (hosts without ../shared)."
        ),
        mirror: float = typer.Option(0.0, help="Share of windows mirrored left/right (augmentation)."),
        posture: float = typer.Option(
            0.0, help="Largest per-joint posture offset, degrees, on half the windows (augmentation)."
        ),
        target_noise: bool = typer.Option(
            False, help="Scheduled target noise: the take latent fades to 0 within 5 frames of a key."
        ),
        partial: float = typer.Option(0.0, help="Share of batches with partial keys (some joints only)."),
        key_mask: bool = typer.Option(
            False, help="Per-joint key-mask input (partial keys), its own zero-start convolution."
        ),
        full_timing: bool = typer.Option(
            False,
            help="Key distance, key flag and time-to-arrival inputs count full keys only (partial "
            "keys reach the network through their joints and the key mask).",
        ),
        key_adapter: bool = typer.Option(
            False,
            help="Partial keys as a side input through a zero-start adapter; the main input is that "
            "of the full keys alone (with --freeze, fills from full keys stay bit for bit).",
        ),
        partial_layout: str = typer.Option(
            "convert", help="Partial keys in training: 'convert' some keys, or 'insert' them in gaps."
        ),
        match_partial: bool = typer.Option(
            True, help="Losses on the output with partial keys matched, as the farm matches them."
        ),
        dna: int = typer.Option(
            0, help="Motion-DNA encoder width (0: none); new to an --init checkpoint, it starts at zero."
        ),
        dna_prob: float = typer.Option(0.5, help="Share of windows given a motion DNA."),
        w_dna: float = typer.Option(0.5, help="Weight of the DNA loss (eq. 11)."),
        dna_from: float = typer.Option(
            0.0, help="Share of DNAs from the rest of the window's clip (else from its gap)."
        ),
        new_lr: float = typer.Option(
            10.0, help="Learning-rate factor of the weights the --init checkpoint lacks."
        ),
        freeze: bool = typer.Option(
            False, help="Train only the add-on modules (DNA, key mask, adapter); the trunk stays as it was."
        ),
    ):
        """Train the path predictor, then the generator, on CPU. Deterministic for a seed."""
        from pipeline.models.generator import GeneratorConfig
        from pipeline.train.batches import PARTIAL_LAYOUTS
        from pipeline.train.generator import TrainConfig
        from pipeline.train.generator import train as train_generator
        from pipeline.train.path import PathTrainConfig, train_path

        if partial_layout not in PARTIAL_LAYOUTS:
            raise typer.BadParameter(f"--partial-layout must be one of {', '.join(PARTIAL_LAYOUTS)}")
        adv_start = None if adv_start < 0 or adv_start >= steps else adv_start
        common = dict(
            batch=batch, seed=seed, threads=threads, limit_clips=limit_clips, data=str(data) if data else None
        )
        if path_steps:
            train_path(PathTrainConfig(steps=path_steps, **common), out)
        ckpt = train_generator(
            TrainConfig(
                steps=steps,
                adv_start=adv_start,
                lr=lr,
                pos_zscore=pos_zscore,
                init=str(init) if init else None,
                device=device,
                gap_weighting=gap_weighting,
                lengths=tuple(int(x) for x in lengths.split(",")),
                workers=workers,
                data_pack=str(data_pack) if data_pack else None,
                mirror=mirror,
                posture=posture,
                partial=partial,
                partial_layout=partial_layout,
                match_partial=match_partial,
                dna_prob=dna_prob,
                dna_from=dna_from,
                w_dna=w_dna,
                new_lr=new_lr,
                freeze=freeze,
                model=GeneratorConfig(
                    noise_schedule=target_noise,
                    key_mask=key_mask,
                    full_timing=full_timing,
                    key_adapter=key_adapter,
                    dna=dna,
                ),
                **common,
            ),
            out,
        )
        typer.echo(str(ckpt))

    @app.command()
    def export(
        run: Path = typer.Argument(..., help="Run folder written by `tween train`."),
        out: Path = typer.Option(..., help="Model folder to write (ONNX files + model.json)."),
        name: str = typer.Option(None, help="Model name (default: the folder name)."),
        root: str = typer.Option("generator", help="Root path source at inference: generator or path."),
        pad: str = typer.Option(
            "hold-key", help="Pad layout at inference: hold-key (the last padded frame a key), end, front."
        ),
        pad_tail: int = typer.Option(16, help="Frames held after the last key at least, when padding."),
        min_window: int = typer.Option(64, help="Shortest padded window, frames."),
        feet_anchor: bool = typer.Option(
            True, help="Lock contacts that hold a key at the key's foot position."
        ),
        feet_orient: bool = typer.Option(
            True, help="Locked feet hold their orientation too (toes stay put)."
        ),
    ):
        """Export both networks to ONNX and check onnxruntime against torch."""
        from pipeline.train.export import export as do_export
        from pipeline.train.export import verify

        settings = {
            "root": root,
            "pad": pad,
            "pad_tail": pad_tail,
            "min_window": min_window,
            "feet_anchor": feet_anchor,
            "feet_orient": feet_orient,
        }
        meta = do_export(run, out, name or out.name, settings)
        err = verify(run, out)
        typer.echo(f"{out}: model {meta['name']} hash {meta['hash']}; max |onnx - torch| = {err:.2e}")
