"""Per-rig training progress as structured records (issue 18): the trainer's ``on_progress``
callback, the CLI's bar, the JSON-lines channel to the farm, and the farm task's state
updates (a fake bound ``self``, no broker)."""

from __future__ import annotations

import ast
import dataclasses
import io
import json
import math
import random
from pathlib import Path
from types import SimpleNamespace

import pytest
from test_rig_core import walk

from pipeline.rig.progress import JsonLinesReader, JsonLinesWriter, Progress, ProgressBar

REPO = Path(__file__).resolve().parents[2]
ITERS = 4
FIELDS = [f.name for f in dataclasses.fields(Progress)]


def _cfg(out, **kw):
    from pipeline.rig.train import TrainConfig

    return TrainConfig(
        **{"source": "walk", "out": str(out), "schedule": "tiny", "iters": ITERS, "seed": 0, **kw}
    )


@pytest.fixture(scope="module")
def run(tmp_path_factory):
    """A tiny training's records, collected through the callback."""
    pytest.importorskip("torch")
    from pipeline.rig.train import train

    out = tmp_path_factory.mktemp("progress")
    records: list[Progress] = []
    tr = train(_cfg(out), walk(), on_progress=records.append)
    return SimpleNamespace(records=records, trainer=tr, out=out)


def check_records(records: list[Progress]) -> None:
    assert records
    steps = records[0].steps
    assert all(r.steps == steps for r in records) and steps > 0
    assert [r.step for r in records] == sorted(r.step for r in records), "steps go back"
    assert records[-1].step == steps and records[-1].done and records[-1].fraction == 1.0
    for r in records:
        assert 0 <= r.stage_step <= r.stage_steps and 0 <= r.step <= steps
        assert all(math.isfinite(v) for v in r.loss.values()), r
        assert r.elapsed_s >= 0 and (r.eta_s is None or r.eta_s >= 0)
        lv = r.group_levels
        assert lv and r.stage == f"levels {lv[0]}-{lv[-1]}/{r.n_levels}"
    elapsed = [r.elapsed_s for r in records]
    assert elapsed == sorted(elapsed)


def test_tiny_training_reports_records(run):
    recs, tr = run.records, run.trainer
    check_records(recs)
    assert recs[-1].steps == len(tr.groups) * ITERS
    after_steps = [r for r in recs if r.loss]
    # One record after every iteration, each with the four loss terms; one at each group's start.
    assert [r.step for r in after_steps] == list(range(1, recs[-1].steps + 1))
    assert all(set(r.loss) == {"d", "adv", "con", "rec"} for r in after_steps)
    starts = [r for r in recs if not r.loss]
    assert [r.stage_step for r in starts] == [0] * len(tr.groups)
    assert [r.group_levels for r in starts] == [tuple(i + 1 for i in g) for g in tr.groups]
    assert recs[-1].eta_s == 0.0 and recs[-1].elapsed_s == pytest.approx(sum(tr.wall), abs=1e-2)
    # The losses are the trainer's own: the log's last entry is the last record's.
    last = {k: v for k, v in tr.log[-1].items() if k not in ("group", "iteration")}
    assert recs[-1].loss == last


def test_resuming_a_finished_run_reports_where_it_stands(run):
    from pipeline.rig.train import train

    again: list[Progress] = []
    train(_cfg(run.out), walk(), on_progress=again.append)
    assert len(again) == 1
    (r,) = again
    assert r.done and r.step == run.records[-1].step and r.loss == run.records[-1].loss


def test_records_survive_json_lines_in_any_chunks(run):
    buf = io.StringIO()
    writer = JsonLinesWriter(buf)
    for r in run.records:
        writer(r)
    data = buf.getvalue().encode()
    assert data.count(b"\n") == len(run.records)
    rng = random.Random(0)
    reader, back, i = JsonLinesReader(), [], 0
    while i < len(data):
        n = rng.randint(1, 300)
        back += reader.feed(data[i : i + n])
        i += n
    assert back == run.records
    assert Progress.from_dict(json.loads(json.dumps(dataclasses.asdict(run.records[-1])))) == run.records[-1]


def test_bar_on_stderr_shows_each_group(run):
    err = io.StringIO()
    with ProgressBar(err) as bar:
        for r in run.records:
            bar(r)
    text = err.getvalue()
    for lv in {r.stage for r in run.records}:
        assert f"{lv}: 100%" in text
    assert f"{ITERS}/{ITERS}" in text and "run=100%" in text and "rec=" in text


def test_train_without_callback_shows_a_bar_unless_quiet(tmp_path, capsys):
    pytest.importorskip("torch")
    from pipeline.rig.train import train

    train(_cfg(tmp_path / "a", iters=1), walk())
    assert "levels 1-2/" in capsys.readouterr().err
    train(_cfg(tmp_path / "b", iters=1), walk(), quiet=True)
    assert capsys.readouterr().err == ""


# --- the farm task ---------------------------------------------------------------------


@pytest.fixture
def farm_roots(tmp_path):
    """The rig app's settings with ``tmp_path`` as the only shot root (restored after)."""
    from workers.app import rig_app

    old = rig_app.conf.tween
    rig_app.conf.tween = dataclasses.replace(old, shot_roots=(str(tmp_path),))
    try:
        yield tmp_path
    finally:
        rig_app.conf.tween = old


class FakeTask:
    """What the task body uses of its bound ``self``."""

    def __init__(self):
        self.states: list[dict] = []

    def update_state(self, state=None, meta=None):
        self.states.append({"state": state, "meta": meta})


def test_farm_task_state_updates_carry_the_records(run, farm_roots):
    pytest.importorskip("onnx")
    from pipeline.rig.source import save_npz
    from workers.rig_tasks import train_rig

    src, out = farm_roots / "walk.npz", farm_roots / "model"
    save_npz(walk(), src)
    fake = FakeTask()
    result = train_rig.run.__func__(fake, str(src), str(out), {"schedule": "tiny", "iters": ITERS, "seed": 0})
    assert fake.states and {s["state"] for s in fake.states} == {"PROGRESS"}
    metas = [s["meta"] for s in fake.states]
    assert result["progress_updates"] == len(metas)
    recs = []
    for m in metas:
        assert set(FIELDS) <= set(m) and m["source"] == str(src) and m["out"] == str(out)
        r = Progress.from_dict(m)
        # What `tween status` and `submit-train-rig --wait` show, from the record's own fields.
        assert m["levels"] == f"{r.group_levels[0]}-{r.group_levels[-1]}/{r.n_levels}"
        assert (m["iteration"], m["iterations"], m["fraction"]) == (
            r.stage_step,
            r.stage_steps,
            round(r.fraction, 4),
        )
        json.dumps(m)  # the meta goes through the JSON serializer as it is
        recs.append(r)
    check_records(recs)  # the last update is the final record, whatever the throttle held back
    # The same training as the in-process one: the same stages and steps, the same losses.
    by_step = {(r.step, r.stage_step, r.stage): r for r in run.records}
    for r in recs:
        twin = by_step[(r.step, r.stage_step, r.stage)]
        assert r.loss.keys() == twin.loss.keys()
        assert all(r.loss[k] == pytest.approx(twin.loss[k], rel=1e-4, abs=1e-6) for k in r.loss)
    assert result["progress"]["fraction"] == 1.0 and result["progress"]["step"] == recs[-1].steps
    assert result["model"] == "model" and (out / "rig.json").is_file()


def test_farm_task_failure_is_the_trainers_one_line(farm_roots):
    from workers.errors import JobError
    from workers.rig_tasks import train_rig

    (farm_roots / "short.npz").write_bytes(b"not an npz")
    fake = FakeTask()
    with pytest.raises(JobError) as e:
        train_rig.run.__func__(
            fake, str(farm_roots / "short.npz"), str(farm_roots / "m"), {"schedule": "tiny"}
        )
    msg = str(e.value)
    assert "short.npz" in msg and "\n" not in msg and not msg.startswith("tween: error:")
    assert fake.states == []


def test_farm_task_reads_no_progress_text():
    """workers/rig_tasks.py gets records, not a bar's text: no regular expressions, no tqdm
    fragments, and the records come through pipeline.rig.progress."""
    tree = ast.parse((REPO / "workers" / "rig_tasks.py").read_text())
    imported = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            imported |= {a.name for a in node.names}
        elif isinstance(node, ast.ImportFrom):
            imported.add(node.module or "")
        elif isinstance(node, ast.Attribute) and isinstance(node.value, ast.Name):
            assert node.value.id != "re", f"line {node.lineno}: re.{node.attr}"
        elif isinstance(node, ast.Constant) and isinstance(node.value, str):
            for bit in ("it/s", "%|", "s/it"):
                assert bit not in node.value, f"line {node.lineno}: {node.value!r}"
    assert not {m for m in imported if m == "re" or m.startswith(("re.", "regex"))}
    assert "pipeline.rig.progress" in imported
