"""``tween bench``: the in-betweening benchmark of PROTOCOL.md."""

from pathlib import Path

import typer


def register(app: typer.Typer) -> None:
    @app.command()
    def bench(
        methods: str = typer.Option(
            "zero,interp", help="Comma-separated: zero, interp, model, or a model folder."
        ),
        limit: int = typer.Option(None, help="Use only the first N eval clips (quick check)."),
        out: Path = typer.Option(Path("bench_results"), help="Folder for bench.json and bench.md."),
        long_gaps: bool = typer.Option(
            False, "--long-gaps", help="Keys 2/5/10 s apart on long takes instead."
        ),
        mirrored: bool = typer.Option(
            False, "--mirrored", help="Left/right mirror images of the eval windows (robustness check)."
        ),
        posture: float = typer.Option(
            0.0, help="Per-joint posture offsets up to this many degrees (robustness check)."
        ),
        source: str = typer.Option(
            "eval", help="eval (the protocol), or cmu: the CMU takes retargeted (held-out source)."
        ),
        partial_keys: bool = typer.Option(
            False, "--partial-keys", help="One partial key (root / legs / upper body) inside each gap."
        ),
    ):
        """Run the benchmark; prints the Markdown table, writes JSON + Markdown under --out."""
        from pipeline.bench.run import run_bench

        if long_gaps:
            import json

            from pipeline.bench import long_gaps as lg
            from pipeline.infer.api import load_inbetweener

            takes = lg.long_takes(limit)
            res = {}
            for m in [m.strip() for m in methods.split(",") if m.strip()]:
                name = {"model": "default", "zero": None}.get(m, m)
                if name is None:
                    continue
                typer.echo(f"long gaps: {m} on {len(takes)} takes…", err=True)
                res[m] = lg.evaluate_long_gaps(load_inbetweener(name), takes)
            out.mkdir(parents=True, exist_ok=True)
            (out / "long_gaps.json").write_text(json.dumps(res, indent=1))
            md = lg.markdown(res)
            (out / "long_gaps.md").write_text(md)
            typer.echo(md)
            return

        if partial_keys:
            import json

            from pipeline.bench import partial
            from pipeline.bench.protocol import position_stats
            from pipeline.bench.run import test_windows
            from pipeline.data.cache import load_split
            from pipeline.infer.api import load_inbetweener

            mean, std = position_stats(load_split("train"))
            rots, roots = test_windows(limit, mirrored, posture, source)
            res = {}
            for m in [m.strip() for m in methods.split(",") if m.strip()]:
                if m == "zero":
                    continue
                typer.echo(f"partial keys: {m} on {len(rots)} windows…", err=True)
                if m == "interp":
                    fill = partial.fill_interp
                else:
                    inb = load_inbetweener("default" if m == "model" else m)
                    fill = lambda r, p, k, jk, inb=inb: inb.fill_batch(r, p, k, None, jk)  # noqa: E731
                res[m] = partial.evaluate_partial(fill, rots, roots, mean, std)
            out.mkdir(parents=True, exist_ok=True)
            payload = {
                m: {k: {str(t): v for t, v in r.items()} for k, r in d.items()} for m, d in res.items()
            }
            (out / "partial_keys.json").write_text(
                json.dumps({"windows": len(rots), "results": payload}, indent=1)
            )
            md = partial.markdown(res)
            (out / "partial_keys.md").write_text(md)
            typer.echo(md)
            return

        res = run_bench(
            [m.strip() for m in methods.split(",") if m.strip()], limit, out, mirrored, posture, source
        )
        typer.echo(res["markdown"])
        typer.echo(f"written: {res['json']}", err=True)
