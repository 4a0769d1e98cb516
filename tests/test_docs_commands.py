"""The guides' commands do what they say (issue 31, item 8).

1. Every `tween` command line in the guides' code blocks names a command that exists and options
   it takes, and parses as written (placeholders filled in); every `tween …` in their text (the
   README's command table included) names a command and options that exist.
2. Every command in a shell code block of the README, docs/farm.md, docs/render.md and
   docs/usd.md is accounted for, in exactly one of three tables:
   - ``RUN``: run here, in process, in one workspace, in the order listed (the cheap ones: a
     shot converted and filled, reviews, approve, publish, a small library);
   - ``BY_TEST``: run by an existing test (a farm, TLS brokers, training), named by its id; the
     test must exist and its module (or the helper module named with it) must use the
     command and each of the line's options (values may differ: ports, hosts, take counts);
   - ``BY_MAKE``: run by a Makefile target;
   - ``NOT_RUN``: with the reason (hours of training).
   A command added to a guide fails here until it is put in one of them.
"""

from __future__ import annotations

import ast
import importlib
import inspect
import os
import re
import shlex
import shutil
from pathlib import Path

import pytest
from cli_contract import OPTION, commands, options_of

ROOT = Path(__file__).resolve().parents[1]
DOCS = ["README.md", "docs/farm.md", "docs/render.md", "docs/usd.md", "docs/library.md", "docs/rig.md",
        "docs/dailies.md", "docs/trust.md", "docs/models.md", "docs/benchmarks.md", "models/README.md",
        *sorted(str(p.relative_to(ROOT)) for p in ROOT.glob("models/*/MODEL_CARD.md"))]  # fmt: skip
RUN_DOCS = ["README.md", "docs/farm.md", "docs/render.md", "docs/usd.md"]


def _blocks(doc: str, langs=("", "bash")) -> list[str]:
    text = (ROOT / doc).read_text()
    return [
        re.sub(r"\\\n\s*", " ", b)
        for lang, b in re.findall(r"```([a-z]*)\n(.*?)```", text, re.S)
        if lang in langs
    ]


def _doc_lines():
    for doc in DOCS:
        for block in _blocks(doc):
            for line in block.splitlines():
                line = re.sub(r"^\$ ", "", line.strip())
                if line.startswith("tween "):
                    yield doc, line


LINES = list(_doc_lines())


def _inline_commands():
    """`tween …` in the prose and tables of the guides (the README's command table included)."""
    for doc in RUN_DOCS + ["docs/benchmarks.md", "docs/trust.md"]:
        text = re.sub(r"```.*?```", "", (ROOT / doc).read_text(), flags=re.S)
        for cmd in re.findall(r"`(tween [^`]*)`", text):
            yield doc, " ".join(cmd.replace("\\|", "|").split())


SYNOPSES = list(_inline_commands())


def _args(line: str) -> list[str]:
    line = re.split(r"\s#\s|\s+#", line, maxsplit=1)[0]  # the comment
    line = re.sub(r"\[[^\]]*\]", " ", line)  # optional parts (their options are checked apart)
    line = re.sub(r"<[^>]*>(\.\.\.)?", "JOB", line).replace("...", "").replace("…", "")
    return shlex.split(line)[1:]


def _name(args: list[str]) -> str:
    two = " ".join(args[:2])
    return two if len(args) > 1 and two in commands() else args[0]


def test_the_guides_hold_tween_command_lines():
    assert len(LINES) > 20 and len(SYNOPSES) > 15


@pytest.mark.parametrize("doc, line", LINES, ids=[f"{d}:{i}" for i, (d, _) in enumerate(LINES)])
def test_a_documented_command_line_parses(doc, line):
    args = _args(line)
    name = _name(args)
    assert name in commands(), f"{doc}: `{line}`: no command {name!r}"
    commands()[name].make_context(name, args[len(name.split()) :])  # raises on a bad option or value
    optional = " ".join(re.findall(r"\[([^\]]*)\]", re.split(r"\s#", line, maxsplit=1)[0]))
    unknown = [o for o in OPTION.findall(optional) if o not in options_of(name)]
    assert not unknown, f"{doc}: `{line}`: {name} takes no {unknown}"


@pytest.mark.parametrize("doc, line", SYNOPSES, ids=[f"{d}:inline{i}" for i, (d, _) in enumerate(SYNOPSES)])
def test_commands_in_the_text_name_real_commands_and_options(doc, line):
    name = _name(_args(line))
    assert name in commands(), f"{doc}: `{line}`: no command {name!r}"
    unknown = [o for o in OPTION.findall(line) if o not in options_of(name)]
    assert not unknown, f"{doc}: `{line}`: {name} takes no {unknown}"


PYTHON = [(doc, block) for doc in RUN_DOCS for block in _blocks(doc, langs=("python",))]


@pytest.mark.parametrize("doc, block", PYTHON, ids=[f"{d}:python{i}" for i, (d, _) in enumerate(PYTHON)])
def test_python_in_the_guides_calls_real_functions_with_real_keywords(doc, block):
    """The guides' Python: what it imports exists, and each call of it names real parameters."""
    tree = ast.parse(block)
    imported = {}
    for node in tree.body:
        if isinstance(node, ast.ImportFrom):
            mod = importlib.import_module(node.module)
            imported.update({a.asname or a.name: getattr(mod, a.name) for a in node.names})
    assert imported, f"{doc}: a Python block that imports nothing"
    for node in ast.walk(tree):
        if isinstance(node, ast.Call) and isinstance(node.func, ast.Name) and node.func.id in imported:
            params = inspect.signature(imported[node.func.id]).parameters
            unknown = [k.arg for k in node.keywords if k.arg not in params]
            assert not unknown, f"{doc}: {node.func.id}() takes no {unknown}"


# --- every shell command of the four guides, and how it is run ------------------------------


def _shell_commands() -> dict[str, list[str]]:
    """{command as written, comment dropped: [docs]} over the shell blocks of RUN_DOCS."""
    found: dict[str, list[str]] = {}
    for doc in RUN_DOCS:
        for block in _blocks(doc, langs=("bash",)):
            for line in block.splitlines():
                line = re.split(r"\s+#\s|\s+#$", line.strip(), maxsplit=1)[0].strip()
                line = re.sub(r" {2,}", " ", line)
                if line and not line.startswith("#"):
                    found.setdefault(line, []).append(doc)
    return found


SHELL = _shell_commands()

#: Run here, in this order, in one workspace (``workspace`` below). Reviews also get
#: ``CHEAP`` options (a small frame size, four frames) to keep them quick.
RUN = [
    "tween convert clip.bvh.gz sh010.usda --start 1001 --keys-every 10",
    "tween convert clip.bvh.gz sh010.usda --start 1001 --fps 24 --keys-every 8 [--up z] [--frames 0-120] [--force]",
    "tween fill-local sh010.usda [--keys 1001,1012,1030 | --keys 1001-1100x8] [--range 1010-1050] "
    "[--takes 2 --seed 0] [--model default|interp|DIR] [--out DIR] [--format usdc] "
    "[--mapping joints.json] [--review-layer dailies.usda] [--job-id ID]",
    "tween review sh010.review.v001.usda --take 1",
    "tween review sh010.usda --take 1 --force",
    "tween review sh010.review.v001.usda --all-takes --side-by-side -o dailies/sh010",
    "tween review sh010.usda --size 1920x1080 --camera front --ghosts --exr --frames 1001:1048",
    "tween review sh010.review.v001.usda --camera fixed --force",
    'tween approve sh010.usda --take 1 --note "good arc on the turn"',
    "tween publish sh010.usda",
    "tween library build /shows/takes --out /shows/library",
    "tween fill-local sh010.usda --library /shows/library",
]
#: The optional parts of a RUN line that are run (the others are left out).
KEEP_OPTIONAL = {"--frames 0-120", "--force", "--takes 2 --seed 0"}
CHEAP = ["--frames", "1001:1004"]

_EMBEDDED = "tests/workers/test_farm_embedded.py::test_identical_takes_are_said_once_and_rendered_once"
_SECURE = "tests/workers/test_farm_secure.py::test_signed_jobs_fill_over_tls"
_CANCEL = (
    "tests/workers/test_farm_cancel.py::test_cancelled_before_any_worker_runs_on_no_worker_started_later"
)
_LIBRARY = "tests/workers/test_farm_library.py::test_a_library_is_built_on_the_training_queue"
_RIG = "tests/workers/test_farm_rig.py::test_train_rig_on_its_queue_with_progress_then_fill_with_it"
_RABBIT = "tests/workers/test_farm_secure.py::test_amqps_farm_with_a_user"
#: Run by an existing test: command -> test id (and the helper module that holds the command
#: line, when the test's own module does not).
BY_TEST = {
    # the farm (embedded, Redis, TLS Redis, RabbitMQ): workers, submit, status, cancel
    "tween fill sh010.usda --takes 2 --render": _EMBEDDED,
    "tween fill /shows/seq010/sh010.usda --takes 3 --render": _EMBEDDED,
    "tween worker -c 2": (
        "tests/workers/test_farm_redis.py::test_twenty_shots_at_once",
        "tests/redis_server.py",
    ),
    "tween submit /shows/seq010/sh0*.usda --takes 3": _SECURE,
    "tween status JOB...": _CANCEL,
    "tween status <job-id>...": _CANCEL,
    "tween cancel JOB...": _CANCEL,
    "tween cancel <job-id>...": _CANCEL,
    "export TWEEN_BROKER_URL=redis://broker:6379/0 TWEEN_SHOT_ROOTS=/shows": (
        "tests/workers/test_farm_redis.py::test_paths_outside_roots_are_refused",
        "tests/redis_server.py",
    ),
    "redis-server --bind 0.0.0.0 --protected-mode no --appendonly yes": (
        "tests/workers/test_farm_secure.py::test_plain_broker_line_of_the_doc_answers_other_hosts"
    ),
    # "Securing the farm": test_farm_secure runs the doc's blocks as written, site values put in
    "BROKER=broker.example.com": _SECURE,
    'openssl req -x509 -newkey rsa:3072 -nodes -days 3650 -subj "/CN=tween farm CA" -keyout ca.key -out ca.pem': _SECURE,
    'openssl req -newkey rsa:3072 -nodes -subj "/CN=$BROKER" -addext "subjectAltName=DNS:$BROKER" -keyout broker.key -out broker.csr': _SECURE,  # noqa: E501
    "openssl x509 -req -in broker.csr -CA ca.pem -CAkey ca.key -CAcreateserial -days 825 -copy_extensions copy -out broker.pem": _SECURE,  # noqa: E501
    'openssl req -x509 -newkey rsa:3072 -nodes -days 825 -subj "/CN=tween farm signing" -keyout farm-signing.key -out farm-signing.pem': _SECURE,  # noqa: E501
    "openssl rand -hex 24 > broker.password": _SECURE,
    "chmod 600 ca.key broker.key farm-signing.key broker.password": _SECURE,
    "redis-server /etc/redis/tween.conf": _SECURE,
    "tween fill /shows/seq010/sh010.usda --takes 2": _SECURE,
    "tween submit /shows/seq010/sh020.usda --takes 2": _SECURE,
    "tween status <job-id>": _SECURE,
    'rabbitmqctl add_user tween "$(cat broker.password)"': _RABBIT,
    'rabbitmqctl set_permissions -p / tween ".*" ".*" ".*"': _RABBIT,
    "rabbitmqctl delete_user guest": _RABBIT,
    # training queues
    "tween worker --train -c 1": _LIBRARY,
    "tween submit-library /shows/takes --out /shows/library [--add] [--licence TEXT] [--include GLOBS] [--wait]": _LIBRARY,
    "tween status lib-9c…": _LIBRARY,
    "tween worker --train-rig -c 1": _RIG,
    "tween status rig-3f…": _RIG,
    "tween train --data /shows/takes --init models/default --out runs/studio": (
        "tests/train/test_studio_takes.py::test_fine_tune_continues_a_model_folder_with_its_shape"
    ),
    "tween export runs/studio --out runs/studio/model": (
        "tests/train/test_studio_takes.py::test_fine_tune_continues_a_model_folder_with_its_shape"
    ),
    "tween fill-local sh010.usda --library /shows/library --model runs/studio/model": (
        "tests/library/test_library_fill.py::test_a_library_fill_probes_the_network_model_names"
    ),
    # the README's quick start: the docs' RUN lines render take 1 into ./review/sh010/ before it
    "tween review sh010.usda --take 1": (
        "tests/render/test_review_latest.py::test_an_earlier_review_is_replaced_only_with_force"
    ),
    # dailies and the schema
    'tween approve sh010.usda --take 1 [--note "good arc on the turn"] [--out-dir DIR]': (
        "tests/usd/test_dailies.py::test_approve_writes_next_version_with_decision"
    ),
    "tween publish sh010.usda [--format usda|usdc] [--out PATH] [--out-dir DIR]": (
        "tests/usd/test_dailies.py::test_publish_usdc_and_out_path"
    ),
    "tween status JOB_ID": "tests/usd/test_dailies.py::test_status_line_shows_the_decision",
    "export PXR_PLUGINPATH_NAME=/path/to/usd-tween/usd_schemas/tween/resources${PXR_PLUGINPATH_NAME:+:$PXR_PLUGINPATH_NAME}": (
        "tests/usd/test_schema.py::test_plugin_found_through_pxr_pluginpath_name_by_other_tools"
    ),
}
#: Not run, and why.
NOT_RUN = {
    "tween submit-train-rig /shows/creatures/elephant_clip.usdc --out /shows/models/elephant "
    "--skeleton /Root/Elefant/_skel --schedule reduced [--frames 0:1511] [--seed 0] [--threads 2] [--wait]": (
        "the reduced schedule trains for most of an hour; the line parses (above), and "
        f"{_RIG} runs the job it submits (jobs.submit_train_rig, the tiny schedule) on a real farm"
    ),
}
#: Run by `make`: command -> the target that runs it (`make test` runs every test file).
BY_MAKE = {
    "make demo": "demo",
    "make test": "test",
    ".venv/bin/pytest -q tests/workers/test_farm_config.py tests/workers/test_farm_embedded.py "
    "tests/workers/test_farm_redis.py tests/workers/test_farm_rig.py": "test",
    ".venv/bin/pytest -q tests/workers/test_farm_limits.py tests/workers/test_farm_cancel.py "
    "tests/workers/test_farm_dead_worker.py": "test",
    ".venv/bin/pytest -q tests/render/test_render.py tests/render/test_render_blender.py "
    "tests/render/test_render_framing.py tests/render/test_timeline.py tests/render/test_render_speed.py": "test",
}


def test_every_command_of_the_guides_is_run_somewhere():
    tables = [set(RUN), set(BY_TEST), set(BY_MAKE), set(NOT_RUN)]
    for cmd, docs in SHELL.items():
        homes = sum(cmd in t for t in tables)
        assert homes == 1, f"{docs}: `{cmd}` is in {homes} of RUN, BY_TEST, BY_MAKE, NOT_RUN (give it one)"
    stale = [c for t in tables for c in t if c not in SHELL]
    assert not stale, f"no longer in the guides: {stale}"


def _test_source(ref) -> tuple[str, str]:
    test_id, *helpers = (ref,) if isinstance(ref, str) else ref
    path, name = test_id.split("::")
    src = (ROOT / path).read_text()
    assert re.search(rf"^def {re.escape(name)}\(", src, re.M), f"{test_id}: no such test"
    return test_id, src + "".join((ROOT / h).read_text() for h in helpers)


@pytest.mark.parametrize("cmd", sorted(BY_TEST))
def test_a_command_run_by_a_test_is_in_that_test(cmd):
    test_id, src = _test_source(BY_TEST[cmd])
    if cmd.startswith("tween "):
        name = _name(_args(cmd))
        assert all(f'"{w}"' in src for w in name.split()), f"{test_id} does not run `tween {name}`"
        for opt in OPTION.findall(re.sub(r"\[[^\]]*\]", " ", cmd)):
            assert f'"{opt}"' in src, f"{test_id} does not give {opt} (`{cmd}`)"
    elif "test_farm_secure" in test_id:  # it reads its commands from docs/farm.md itself
        assert "docs" in src and "farm.md" in src and "_blocks()" in src
    else:
        assert cmd.split()[1].split("=")[0] in src, f"{test_id} does not use `{cmd}`"


def test_make_runs_what_is_said():
    make = (ROOT / "Makefile").read_text()
    for cmd, target in BY_MAKE.items():
        body = re.search(rf"^{target}:.*\n((?:\t.*\n)+)", make, re.M)
        assert body, f"Makefile: no target {target!r} (`{cmd}`)"
        for path in re.findall(r"tests/\S+\.py", cmd):
            assert (ROOT / path).is_file(), f"`{cmd}`: no {path}"
    demo = re.search(r"^demo:.*\n((?:\t.*\n)+)", make, re.M).group(1)
    assert "tween fill examples/sh010_walk.usda --render" in demo


# --- the RUN commands, in one workspace -------------------------------------------------------


def _instantiate(line: str, places: dict[str, str]) -> list[str]:
    """The command as run: KEEP_OPTIONAL parts kept, other optional parts dropped, paths put in."""
    line = re.sub(r"\[([^\]]*)\]", lambda m: m.group(1) if m.group(1) in KEEP_OPTIONAL else " ", line)
    args = shlex.split(line)[1:]
    args = [places.get(a, a) for a in args]
    if args[0] == "review":
        args += CHEAP + ([] if "--size" in args else ["--size", "160x90"])
        args += [] if "--exr" in args else ["--no-frames"]
    return args


@pytest.fixture(scope="module")
def workspace(tmp_path_factory, data_dir, bandai_clip):
    """Each RUN command once, in order, in process; {command: (exit status, stdout, stderr)}."""
    from pipeline.cli import main

    ws = tmp_path_factory.mktemp("docs")
    takes = ws / "takes"
    takes.mkdir()
    for name in ("dataset-2_walk_active_001.bvh.gz", "dataset-2_run_active_001.bvh.gz"):
        shutil.copy(data_dir / "bandai_namco" / "dataset-2" / name, takes / name)
    places = {
        "clip.bvh.gz": str(bandai_clip),
        "/shows/takes": str(takes),
        "/shows/library": str(ws / "library"),
    }
    env = {"TWEEN_FARM_CONFIG": os.devnull}
    saved, cwd = {k: os.environ.get(k) for k in env}, os.getcwd()
    os.environ.update(env)
    runs = {}
    try:
        os.chdir(ws)
        for line in RUN:
            args = _instantiate(line, places)
            try:
                main(args)
                code = 0
            except SystemExit as e:
                code = e.code
            runs[line] = (code, args)
            if code != 0:
                break  # the rest depend on it
    finally:
        os.chdir(cwd)
        for k, v in saved.items():
            os.environ.pop(k, None) if v is None else os.environ.__setitem__(k, v)
    return ws, runs


#: What each RUN command leaves in the workspace (beside the exit status 0).
LEAVES = {
    RUN[0]: ["sh010.usda"],
    RUN[1]: ["sh010.usda"],
    RUN[2]: ["sh010.tween.v001.usda", "sh010.review.v001.usda"],
    RUN[3]: [
        "review/sh010/sh010_v001_take1.mp4",
        "review/sh010/sh010_v001_take1_contact.png",
        "review/sh010/sh010_v001.otio",
    ],  # fmt: skip
    RUN[4]: ["review/sh010/sh010_v001_take1.mp4"],
    RUN[5]: [
        "dailies/sh010/sh010_v001_take0.mp4",
        "dailies/sh010/sh010_v001_take1.mp4",
        "dailies/sh010/sh010_v001.otio",
    ],
    # take 0 (the default); its EXR frames went with RUN[7]'s --force (checked below)
    RUN[6]: ["review/sh010/sh010_v001_take0.mp4"],
    RUN[7]: ["review/sh010/sh010_v001_take0.mp4"],
    RUN[8]: ["sh010.tween.v002.usda", "sh010.review.v002.usda"],
    RUN[9]: ["sh010.publish.v002.usda"],
    RUN[10]: ["library"],
    RUN[11]: ["sh010.tween.v003.usda"],
}


@pytest.mark.parametrize("line", RUN, ids=[f"run{i}" for i in range(len(RUN))])
def test_a_documented_command_runs(workspace, line):
    ws, runs = workspace
    assert line in runs, "an earlier command failed (see its test)"
    code, args = runs[line]
    assert code == 0, f"`tween {shlex.join(args)}` exited {code}"
    for rel in LEAVES[line]:
        assert (ws / rel).exists(), f"`{line}` left no {rel}: {sorted(p.name for p in ws.rglob('*'))}"


def test_what_the_run_commands_wrote_is_what_the_docs_say(workspace):
    """The README: the fill is one tweenTake variant per take; approve records the decision in a
    new version; publish writes a variant-free layer; the library fill names its library."""
    from pxr import Sdf

    ws, runs = workspace
    assert all(code == 0 for code, _ in runs.values()) and len(runs) == len(RUN)
    fill = Sdf.Layer.FindOrOpen(str(ws / "sh010.tween.v001.usda"))
    sets = [p.variantSets["tweenTake"] for p in fill.rootPrims if "tweenTake" in p.variantSets]
    assert sets and sorted(sets[0].variants.keys()) == ["take0", "take1"]
    approval = Sdf.Layer.FindOrOpen(str(ws / "sh010.tween.v002.usda")).customLayerData["tween"]["approval"]
    assert approval["take"] == 1 and approval["note"] == "good arc on the turn"
    # RUN[7] (--force, --no-frames here) replaced take 0's review whole: none of RUN[6]'s EXR frames left
    assert not list((ws / "review" / "sh010").glob("sh010_v001_take0.*.exr"))
    published = Sdf.Layer.FindOrOpen(str(ws / "sh010.publish.v002.usda"))
    assert not published.subLayerPaths and all(not p.variantSets for p in published.rootPrims)
    layer = Sdf.Layer.FindOrOpen(str(ws / "sh010.tween.v003.usda")).ExportToString()
    assert "library:library" in layer  # the library it was given (named after its folder) took part
