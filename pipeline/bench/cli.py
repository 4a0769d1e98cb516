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
    ):
        """Run the benchmark; prints the Markdown table, writes JSON + Markdown under --out."""
        from pipeline.bench.run import run_bench

        res = run_bench([m.strip() for m in methods.split(",") if m.strip()], limit, out)
        typer.echo(res["markdown"])
        typer.echo(f"written: {res['json']}", err=True)
