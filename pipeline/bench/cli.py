"""``tween bench``: the in-betweening benchmark of PROTOCOL.md."""

import os
from pathlib import Path

import typer

from pipeline.bench.outputs import OUTPUTS, check_out_folder, refuse_earlier
from pipeline.bench.speed import check_speed_model, run_speed
from pipeline.errors import TweenError

#: The options each kind of bench takes besides --methods and --out (the protocol's: "").
MODES = {
    "": ("--limit", "--mirrored", "--posture", "--source"),
    "--partial-keys": ("--limit", "--mirrored", "--posture", "--source"),
    "--long-gaps": ("--limit",),
    "--rig-variants": ("--limit", "--keys-every"),
    "--speed": (),
}


def _rig_variants_bench(names: list[str], limit: int | None, keys_every: int, out: Path) -> None:
    """``--rig-variants``: the eval motion on rigs of other conventions, filled through USD."""
    from pipeline.bench.rig_variants import bench_clips, run_rig_bench

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


def _env_count(name: str, default: int, lo: int, hi: int) -> int:
    """The whole number in the environment variable ``name`` (``default`` where unset)."""
    text = os.environ.get(name, "").strip() or str(default)
    try:
        v = int(text)
    except ValueError:
        v = None
    if v is None or not lo <= v <= hi:
        raise TweenError(f"{name}={text!r}: must be a whole number from {lo} to {hi}")
    return v


def _speed_model(names: list[str] | None) -> str:
    """The one model ``--speed`` times: ``--methods``' (``model``: the default), else the default."""
    from pipeline.bench.methods import BASELINES
    from pipeline.infer.api import builtin_names

    if not names:
        return "default"
    if len(names) > 1:
        raise TweenError(f"--methods {','.join(names)}: --speed times one model; name one")
    name = "default" if names[0] == "model" else names[0]
    if name in BASELINES or name in builtin_names():
        raise TweenError(
            f"--methods {name}: --speed times a human network model's fill and {name} has no network "
            "to time; give a model folder (model.json), or leave --methods out for the default model"
        )
    return name


def _check_mode(given: dict[str, bool], modes: dict[str, bool]) -> str:
    """The one kind of bench asked for (MODES' key); refuses two, or an option it does not take."""
    asked = [m for m, on in modes.items() if on]
    if len(asked) > 1:
        raise TweenError(f"{' and '.join(asked)}: one kind of bench a run; give one of them")
    mode = asked[0] if asked else ""
    unused = [o for o, on in given.items() if on and o not in MODES[mode]]
    if unused:
        what = f"the {mode} bench" if mode else "the protocol bench"
        takes = f"it takes {', '.join(MODES[mode])}" if MODES[mode] else "it takes none of these options"
        raise TweenError(
            f"{', '.join(unused)}: not used by {what} ({takes}); leave {'it' if len(unused) == 1 else 'them'} out"
        )
    return mode


def bench(
    methods: str = typer.Option(
        None,
        help="Comma-separated: zero, interp, spline, model, or a human model folder "
        "(default zero,interp; --speed: the default model).",
    ),
    limit: int = typer.Option(
        None,
        help="Use only the first N eval clips (CMU takes with --source cmu or --long-gaps; quick check).",
    ),
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
    force: bool = typer.Option(False, "--force", help="Replace an earlier run's results in --out."),
):
    """Run the benchmark; prints the Markdown table, writes JSON + Markdown under --out."""
    # Long because of its option declarations; each kind of bench runs in a function of its own.
    from pipeline.bench.heldout import cmu_files, parse_source
    from pipeline.bench.methods import check_methods

    # Everything is checked before any data is read (a cold cache reads the train split for minutes).
    names = [m.strip() for m in methods.split(",") if m.strip()] if methods is not None else None
    if names is not None:
        check_methods(names)
    if limit is not None and limit < 1:
        raise TweenError(f"--limit {limit}: must be 1 or more")
    if not 0.0 <= posture <= 180.0:  # NaN fails too
        raise TweenError(f"--posture {posture}: must be from 0 to 180 degrees")
    name, subjects = parse_source(source)
    if name == "cmu" and subjects:  # cmu:99: said now, not once the train statistics are read
        cmu_files(subjects)
    given = {"--limit": limit is not None, "--mirrored": mirrored, "--posture": posture > 0}
    given |= {"--source": source != "eval", "--keys-every": keys_every != 10}
    modes = {"--partial-keys": partial_keys, "--long-gaps": long_gaps, "--rig-variants": rig_variants}
    mode = _check_mode(given, modes | {"--speed": speed})
    names = names if names is not None or mode == "--speed" else ["zero", "interp"]
    _check_methods_of(mode, names, keys_every)
    check_out_folder(out)
    refuse_earlier(out, OUTPUTS[mode], force)  # before the data is read, as every check
    if mode == "--speed":
        name = _speed_model(names)
        check_speed_model(name)
        frames = _env_count("TWEEN_SPEED_FRAMES", 4096, 20, 10**6)
        repeats = _env_count("TWEEN_SPEED_REPEATS", 5, 1, 1000)
        typer.echo(run_speed(name, frames, repeats, out))
    elif mode == "--rig-variants":
        _rig_variants_bench(names, limit, keys_every, out)
    elif mode == "--long-gaps":
        from pipeline.bench.long_gaps import run_long_gap_bench

        typer.echo(run_long_gap_bench(names, limit, out))
    elif mode == "--partial-keys":
        _partial_keys_bench(names, limit, mirrored, posture, source, out)
    else:
        from pipeline.bench.run import run_bench

        res = run_bench(names, limit, out, mirrored, posture, source)
        typer.echo(res["markdown"])
        typer.echo(f"written: {res['json']}", err=True)


def _check_methods_of(mode: str, names: list[str] | None, keys_every: int) -> None:
    """What --rig-variants takes (its rigs are filled through USD by these methods only)."""
    if mode != "--rig-variants":
        return
    if keys_every < 2:
        raise TweenError(f"--keys-every {keys_every}: must be at least 2")
    known = ("model", "interp", "spline")
    bad = [m for m in names if m not in known]
    if bad:
        raise TweenError(f"--methods {bad[0]!r}: the rig bench runs {', '.join(known)}")


def register(app: typer.Typer) -> None:
    """Adds this package's commands to ``app``."""
    app.command()(bench)
