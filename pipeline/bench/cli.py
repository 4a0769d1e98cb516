"""``tween bench``: the in-betweening benchmark of PROTOCOL.md."""

import os
from pathlib import Path

import typer

from pipeline.bench.speed import run_speed
from pipeline.errors import TweenError


def _rig_variants_bench(names: list[str], limit: int | None, keys_every: int, out: Path) -> None:
    """``--rig-variants``: the eval motion on rigs of other conventions, filled through USD."""
    from pipeline.bench.rig_variants import bench_clips, run_rig_bench

    if keys_every < 2:
        raise TweenError(f"--keys-every {keys_every}: must be at least 2")
    known = ("model", "interp", "spline")
    bad = [m for m in names if m not in known]
    if bad:
        raise TweenError(f"--methods {bad[0]!r}: the rig bench runs {', '.join(known)}")
    res = run_rig_bench(bench_clips(limit or 8), methods=tuple(names), keys_every=keys_every, out=out)
    typer.echo(res["markdown"])
    typer.echo(f"written: {out / 'rig_bench.json'}", err=True)


def _partial_keys_bench(
    names: list[str], limit: int | None, mirrored: bool, posture: float, source: str, out: Path
) -> None:
    """``--partial-keys``: one partial key (root / legs / upper body) inside each gap."""
    from pipeline.bench.partial import run_partial_bench
    from pipeline.bench.run import test_windows
    from pipeline.data.cache import load_split
    from pipeline.data.protocol import position_stats

    mean, std = position_stats(load_split("train"))
    rots, roots = test_windows(limit, mirrored, posture, source)
    typer.echo(run_partial_bench(names, rots, roots, mean, std, out))


def bench(
    methods: str = typer.Option(
        "zero,interp", help="Comma-separated: zero, interp, spline, model, or a model folder."
    ),
    limit: int = typer.Option(None, help="Use only the first N eval clips (quick check)."),
    out: Path = typer.Option(Path("bench_results"), help="Folder for bench.json and bench.md."),
    long_gaps: bool = typer.Option(False, "--long-gaps", help="Keys 2/5/10 s apart on long takes instead."),
    mirrored: bool = typer.Option(
        False, "--mirrored", help="Left/right mirror images of the eval windows (robustness check)."
    ),
    posture: float = typer.Option(
        0.0, help="Per-joint posture offsets up to this many degrees (robustness check)."
    ),
    source: str = typer.Option(
        "eval",
        help="eval (the protocol), or cmu: the CMU takes retargeted (held-out source); "
        "cmu:5,6,7: those CMU subjects only.",
    ),
    partial_keys: bool = typer.Option(
        False, "--partial-keys", help="One partial key (root / legs / upper body) inside each gap."
    ),
    rig_variants: bool = typer.Option(
        False,
        "--rig-variants",
        help="The same eval motion on rigs of other conventions (names, joint frames, rest pose, "
        "up axis, units, extra joints), filled through USD; --limit clips (default 8).",
    ),
    keys_every: int = typer.Option(10, "--keys-every", help="Key spacing of the --rig-variants shots."),
    speed: bool = typer.Option(
        False,
        "--speed",
        help="Fill speed: a 4096-frame fill of the model (--methods, default 'default') against "
        "the core's sgemm peak (pipeline/bench/speed.py; TWEEN_SPEED_FRAMES, TWEEN_SPEED_REPEATS).",
    ),
):
    """Run the benchmark; prints the Markdown table, writes JSON + Markdown under --out."""
    # Long because of its option declarations; each kind of bench runs in a function of its own.
    from pipeline.bench.methods import check_methods

    # Checked before any data is read (a cold cache reads the train split for minutes).
    check_methods([m.strip() for m in methods.split(",") if m.strip()])
    if limit is not None and limit < 1:
        raise TweenError(f"--limit {limit}: must be 1 or more")
    if not 0.0 <= posture <= 180.0:  # NaN fails too
        raise TweenError(f"--posture {posture}: must be from 0 to 180 degrees")
    if speed:
        picked = [m.strip() for m in methods.split(",")]
        picked = [m for m in picked if m and m not in ("zero", "interp", "model")]
        frames = int(os.environ.get("TWEEN_SPEED_FRAMES", "4096"))
        repeats = int(os.environ.get("TWEEN_SPEED_REPEATS", "5"))
        typer.echo(run_speed(picked[0] if picked else "default", frames, repeats, out))
        return
    from pipeline.bench.heldout import parse_source
    from pipeline.bench.run import run_bench

    parse_source(source)  # a bad --source is one line before anything runs

    names = [m.strip() for m in methods.split(",") if m.strip()]
    if rig_variants:
        _rig_variants_bench(names, limit, keys_every, out)
        return
    if long_gaps:
        from pipeline.bench.long_gaps import run_long_gap_bench

        typer.echo(run_long_gap_bench(names, limit, out))
        return

    if partial_keys:
        _partial_keys_bench(names, limit, mirrored, posture, source, out)
        return

    res = run_bench(names, limit, out, mirrored, posture, source)
    typer.echo(res["markdown"])
    typer.echo(f"written: {res['json']}", err=True)


def register(app: typer.Typer) -> None:
    """Adds this package's commands to ``app``."""
    app.command()(bench)
