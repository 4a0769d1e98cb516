"""Farm commands of the ``tween`` CLI: fill, submit, submit-train-rig, status, worker, bench-farm."""

from __future__ import annotations

import json
import os
import sys
from pathlib import Path

import typer

_FILL_OPTS = dict(
    takes=typer.Option(1, "--takes", min=1, help="Takes (variations) per shot."),
    seed=typer.Option(0, "--seed", help="Seed of the first take."),
    keys=typer.Option(
        None, "--keys", help="Key frames to use, e.g. '1001,1012,1030' (default: the shot's keys)."
    ),
    range_=typer.Option(None, "--range", help="Frame range to fill, e.g. 1001-1048."),
    model=typer.Option(
        "default",
        "--model",
        help="default (a stored rig model when one fits the character, else the human model), interp, "
        "or a model name/folder (a rig model is then used for every character that fits it).",
    ),
    out_dir=typer.Option(None, "--out-dir", help="Folder for the layers (default: beside each shot)."),
    fmt=typer.Option("usda", "--format", help="Layer format: usda or usdc."),
    mapping=typer.Option(None, "--mapping", help="Joint mapping file (default: built in)."),
    dna=typer.Option(
        None, "--dna", help="Motion DNA: a reference take (USD or BVH) whose poses steer the fill."
    ),
    dna_poses=typer.Option(4, "--dna-poses", min=1, max=8, help="Representative poses taken from --dna."),
)


def _opts(takes, seed, keys, range_, model, out_dir, fmt, mapping, dna=None, dna_poses=4) -> dict:
    from workers.jobs import make_opts

    return make_opts(
        keys=keys,
        range=range_,
        takes=takes,
        seed=seed,
        model=model,
        out_dir=out_dir,
        fmt=fmt,
        mapping=mapping,
        dna=dna,
        dna_poses=dna_poses,
    )


def _err(msg: str) -> None:
    print(f"tween: error: {msg}", file=sys.stderr)


def _report(states) -> int:
    """Results to stdout, failures to stderr; returns the exit code."""
    failed = 0
    for s in states:
        if s.state == "SUCCESS":
            r = s.result or {}
            line = f"{s.shot}: layer {r.get('layer')}"
            if r.get("review"):
                line += f", review {r['review']}"
            for i, rend in enumerate(r.get("renders") or []):
                line += f", take {i} render {rend.get('mp4') or rend}"
            if r.get("render_note"):
                line += f" ({r['render_note']})"
            models = r.get("models") or {}
            if len(models) > 1:
                line += ", models " + "; ".join(f"{a}: {m}" for a, m in models.items())
            elif r.get("model"):
                line += f", model {r['model']}"
            typer.echo(line)
        else:
            failed += 1
            _err(s.error or f"{s.shot}: job {s.id} {s.state.lower()}")
    return 2 if failed else 0


def register(app: typer.Typer) -> None:
    @app.command()
    def fill(
        shots: list[Path] = typer.Argument(..., help="USD shot files (.usda/.usdc/.usd)."),
        takes: int = _FILL_OPTS["takes"],
        seed: int = _FILL_OPTS["seed"],
        keys: str = _FILL_OPTS["keys"],
        range_: str = _FILL_OPTS["range_"],
        model: str = _FILL_OPTS["model"],
        out_dir: Path = _FILL_OPTS["out_dir"],
        fmt: str = _FILL_OPTS["fmt"],
        mapping: Path = _FILL_OPTS["mapping"],
        dna: Path = _FILL_OPTS["dna"],
        dna_poses: int = _FILL_OPTS["dna_poses"],
        render: bool = typer.Option(False, "--render", help="Also render the review of each take."),
        concurrency: int = typer.Option(2, "-c", "--concurrency", help="Embedded worker processes."),
        progress: bool = typer.Option(True, "--progress/--no-progress", help="Progress bars on stderr."),
    ):
        """Fill shots through the farm and wait; prints where the layers (and renders) are.

        With no broker configured (TWEEN_BROKER_URL or the farm config file) this runs an
        embedded farm: a local worker on a SQLite broker, started and stopped here.
        """
        from workers import jobs
        from workers.app import app as celery_app

        s = celery_app.conf.tween
        opts = _opts(takes, seed, keys, range_, model, out_dir, fmt, mapping, dna, dna_poses)
        paths = [str(p) for p in shots]
        for p in paths:
            if not os.path.isfile(p):
                _err(f"{p}: no such shot file")
                raise typer.Exit(2)
        if not s.embedded:
            ids = jobs.submit(paths, opts, render=render)
            raise typer.Exit(_report(jobs.wait(ids, progress=progress)))
        from workers.embedded import EmbeddedWorker

        roots = [os.path.dirname(os.path.abspath(p)) for p in paths]
        roots += [opts[k] for k in ("out_dir",) if opts.get(k)]
        for key in ("mapping", "dna"):
            if opts.get(key):
                roots.append(os.path.dirname(opts[key]))
        with EmbeddedWorker(roots, concurrency=min(concurrency, max(1, takes * len(paths)))) as w:
            ids = jobs.submit(paths, opts, render=render, roots=w.roots, queue=w.queue)
            code = _report(jobs.wait(ids, progress=progress, alive=w.alive))
        raise typer.Exit(code)

    @app.command()
    def submit(
        shots: list[Path] = typer.Argument(..., help="USD shot files, on storage every worker sees."),
        takes: int = _FILL_OPTS["takes"],
        seed: int = _FILL_OPTS["seed"],
        keys: str = _FILL_OPTS["keys"],
        range_: str = _FILL_OPTS["range_"],
        model: str = _FILL_OPTS["model"],
        out_dir: Path = _FILL_OPTS["out_dir"],
        fmt: str = _FILL_OPTS["fmt"],
        mapping: Path = _FILL_OPTS["mapping"],
        dna: Path = _FILL_OPTS["dna"],
        dna_poses: int = _FILL_OPTS["dna_poses"],
        render: bool = typer.Option(False, "--render", help="Also render the review of each take."),
    ):
        """Submit shots to the farm; prints one job id per shot (stdout) and returns at once."""
        from workers import jobs
        from workers.app import app as celery_app

        if celery_app.conf.tween.embedded:
            _err("no broker configured (set TWEEN_BROKER_URL); `tween fill` runs an embedded farm")
            raise typer.Exit(2)
        opts = _opts(takes, seed, keys, range_, model, out_dir, fmt, mapping, dna, dna_poses)
        for job_id in jobs.submit([str(p) for p in shots], opts, render=render):
            typer.echo(job_id)

    @app.command()
    def status(
        job_ids: list[str] = typer.Argument(..., help="Job ids from `tween submit`."),
        wait: bool = typer.Option(False, "--wait", help="Wait (with progress bars) until the jobs finish."),
        as_json: bool = typer.Option(False, "--json", help="One JSON object per job."),
    ):
        """State of farm jobs: queued, running (stage), success (layer paths) or failure (reason)."""
        from workers import jobs

        fills = [j for j in job_ids if not j.startswith("rig-")]
        by_id = dict(
            zip(fills, jobs.wait(fills) if wait and fills else [jobs.state(j) for j in fills], strict=True)
        )
        for j in job_ids:
            if j.startswith("rig-"):
                by_id[j] = jobs.wait_train_rig(j) if wait else jobs.train_rig_state(j)
        states = [by_id[j] for j in job_ids]
        code = 0
        for s in states:
            if as_json:
                typer.echo(json.dumps(s.as_dict()))
            elif s.id.startswith("rig-") and s.state == "SUCCESS":
                r = s.result or {}
                typer.echo(
                    f"{s.id} {s.shot}: success, model {r.get('out')} ({r.get('model')}, hash {r.get('model_hash')})"
                )
            elif s.id.startswith("rig-") and s.state == "RUNNING" and (s.result or {}).get("levels"):
                r = s.result
                typer.echo(f"{s.id} {s.shot}: running train-rig, levels {r['levels']}, iteration "
                           f"{r['iteration']}/{r['iterations']} ({100 * r['fraction']:.0f} %)")  # fmt: skip
            elif s.state == "SUCCESS":
                typer.echo(f"{s.id} {s.shot}: success, layer {(s.result or {}).get('layer')}")
            elif s.state == "UNKNOWN":
                typer.echo(f"{s.id}: unknown: {s.error}")
            elif s.state == "FAILURE":
                typer.echo(f"{s.id} {s.shot}: failure: {s.error}")
            else:
                typer.echo(f"{s.id} {s.shot}: {s.state.lower()} {s.stage} ({s.done}/{s.total} stages)")
            code = code or (2 if s.state in ("FAILURE", "UNKNOWN") else 0)
        raise typer.Exit(code)

    @app.command()
    def worker(
        concurrency: int = typer.Option(
            None, "-c", "--concurrency", help="Pool processes (default: CPU count)."
        ),
        queue: str = typer.Option(None, "--queue", "-Q", help="Queue to consume (default: the fill queue)."),
        train: bool = typer.Option(False, "--train", help="Run training jobs (their own queue and limits)."),
        train_rig: bool = typer.Option(
            False, "--train-rig", help="Run per-rig model training jobs (their own queue and limits)."
        ),
        hostname: str = typer.Option(None, "--hostname", "-n", help="Worker name, e.g. node1@%h."),
        loglevel: str = typer.Option("info", "--loglevel", "-l"),
        logfile: Path = typer.Option(None, "--logfile"),
        include: list[str] = typer.Option([], "--include", "-I", help="Extra modules to import."),
    ):
        """Run a Celery worker for the farm (several may run per host and across hosts)."""
        from workers.runtime import thread_env

        n = concurrency or os.cpu_count() or 1
        # Before any ORT/GL import: each pool process gets its share of the cores.
        for k, v in thread_env(n).items():
            os.environ.setdefault(k, v)
        if train and train_rig:
            raise typer.BadParameter("--train and --train-rig are two different workers; start one of each")
        if train_rig:
            from workers.app import rig_app as celery_app
        elif train:
            from workers.app import train_app as celery_app
        else:
            from workers.app import app as celery_app
        s = celery_app.conf.tween
        q = queue or (s.train_rig_queue if train_rig else s.train_queue if train else s.queue)
        argv = ["worker", "-c", str(n), "-Q", q, "-l", loglevel, "--without-gossip", "--without-mingle"]
        argv += ["--pool", "prefork"]
        if hostname:
            argv += ["-n", hostname]
        if logfile:
            argv += ["--logfile", str(logfile)]
        for mod in include:
            argv += ["-I", mod]
        print(f"tween worker: {s.broker_url.split('@')[-1]} queue {q}, {n} processes", file=sys.stderr)
        celery_app.worker_main(argv)

    @app.command("submit-train-rig")
    def submit_train_rig(
        source: Path = typer.Argument(
            ..., help="The reference clip: a USD shot or a BVH, on shared storage."
        ),
        out: Path = typer.Option(
            ..., "--out", help="Model folder (e.g. models/<rig>); resubmitting resumes."
        ),
        skeleton: str = typer.Option(None, "--skeleton", help="USD: the Skeleton prim path."),
        frames: str = typer.Option(None, "--frames", help="START:STOP frame indices of the clip."),
        schedule: str = typer.Option("reduced", "--schedule", help="tiny, reduced or paper."),
        iters: int = typer.Option(
            None, "--iters", help="Iterations per group of levels (overrides the schedule)."
        ),
        seed: int = typer.Option(0, "--seed"),
        threads: int = typer.Option(1, "--threads", help="torch threads on the worker."),
        device: str = typer.Option("cpu", "--device", help="cpu or cuda (on the worker)."),
        name: str = typer.Option(None, "--name", help="Model name (default: the --out folder's name)."),
        wait: bool = typer.Option(False, "--wait", help="Wait with a progress bar; print the model folder."),
    ):
        """Train a per-rig model on the farm's rig training queue (`tween worker --train-rig`);
        prints the job id (`tween status ID` shows its progress)."""
        from workers import jobs
        from workers.app import rig_app

        if rig_app.conf.tween.embedded:
            _err("no broker configured (set TWEEN_BROKER_URL); run `tween train-rig` on this host instead")
            raise typer.Exit(2)
        if not source.is_file():
            _err(f"{source}: no such file")
            raise typer.Exit(2)
        opts = dict(skeleton=skeleton, frames=frames, schedule=schedule, iters=iters, seed=seed, threads=threads,
                    device=device, name=name)  # fmt: skip
        job_id = jobs.submit_train_rig(str(source), str(out), opts)
        if not wait:
            typer.echo(job_id)
            return
        print(job_id, file=sys.stderr)
        s = jobs.wait_train_rig(job_id)
        if s.state != "SUCCESS":
            _err(s.error or f"{source}: training {job_id} {s.state.lower()}")
            raise typer.Exit(2)
        r = s.result or {}
        typer.echo(f"{r.get('out')}  ({r.get('model')}, hash {r.get('model_hash')})")

    @app.command("bench-farm")
    def bench_farm(
        shots: int = typer.Option(50, "--shots", help="Copies of the example shot to fill."),
        workers: str = typer.Option("1,2", "--workers", help="Worker counts to measure (each -c 1)."),
        shot: Path = typer.Option(None, "--shot", help="Shot to copy (default: the example shot)."),
        out: Path = typer.Option(Path("bench_results") / "farm.json", "--out"),
    ):
        """Shots per minute with 1 and 2 workers, and Celery's overhead against a direct fill."""
        from workers.bench import run_bench_farm

        res = run_bench_farm(shots, [int(w) for w in workers.split(",")], shot, out)
        typer.echo(res["markdown"])
        typer.echo(f"written: {out}", err=True)
