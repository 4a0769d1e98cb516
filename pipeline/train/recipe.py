"""`tween train`'s flags, made from TrainConfig, and training recipes as files.

**Flags.** Every field of :class:`pipeline.train.generator_training.TrainConfig` is one `tween train`
flag (``gap_start`` -> ``--gap-start``) with the field's default and its ``help`` metadata;
the GeneratorConfig fields that `tween train` sets are listed in the ``model`` field's
``flags`` metadata. Only what is not a TrainConfig field is declared here: ``--out``,
``--path-steps`` (PathTrainConfig's steps, default from there) and the recipe options. The
command is built on first use (it imports torch), so `tween --help` and `tween fill` never
import torch.

**Recipes.** ``recipes/NAME.toml`` holds the ordered training stages of a shipped model:

.. code-block:: toml

    name = "tween-bandai-v5.3"
    model = "models/default"             # the folder the shipped export went to
    base = {recipe = "other", through = "s7"}   # optional: that recipe's stages first, up to s7

    [[stage]]
    name = "s2"                          # runs into OUT/s2/
    init = "s1"                          # --init: an earlier stage's generator.pt (or a path)
    args = "--path-steps 0 --steps 8000 --lr 3e-4 --pos-zscore --adv-start 7000 --seed 0"
    packed = false                       # true: --data-pack OUT/train.pack (made once)
    wall_s = 2058.0                      # measured wall time, seconds
    measured = "2-core CPU, one torch thread"   # where that was measured (and how)

    [export]                             # optional: `tween export OUT/<stage> --out OUT/model ARGS`
    stage = "s9"
    path_from = "s1"                     # path.pt copied from that stage's folder
    args = "--name tween-bandai-v5.3 --pad hold-key --pad-tail 16 --min-window 64 --feet-anchor"

``tween train --recipe NAME`` replays it on CPU (flags given beside ``--recipe``, such as
``--device cuda --workers 7`` or ``--limit-clips 2``, apply to every stage), skipping every
stage whose folder holds its finished checkpoint, so a replay resumes across sessions.
"""

from __future__ import annotations

import inspect
import json
import math
import shlex
import shutil
import sys
import time
import tomllib
import types
import typing
from dataclasses import MISSING, dataclass, field, fields
from functools import cache
from pathlib import Path
from typing import Any

import typer

from pipeline.atomic import holding
from pipeline.errors import TweenError
from pipeline.inputs import read_small_text
from pipeline.options import names_a_glob
from pipeline.outputs import given_path, missing_folders, refuse_read_only, remove_created
from pipeline.rig.options import check_device
from pipeline.staging import refuse_model
from pipeline.train.commands import export_command

RECIPES = Path(__file__).resolve().parents[2] / "recipes"
EXPLICIT = ("out", "path_steps", "recipe", "from_stage", "dry_run")  # flags that are not TrainConfig's
RESERVED = ("--out", "--init", "--recipe", "--from-stage", "--dry-run", "--data-pack")  # not in stage args


class RecipeError(ValueError):
    """A recipe file that cannot be replayed as written."""


# ---------------------------------------------------------------------------- flags


@dataclass(frozen=True)
class Flag:
    """One `tween train` flag made from a config field."""

    name: str  # the Python name; the flag is --name with _ as -
    field: str  # the TrainConfig field, or the GeneratorConfig one when ``model`` is set
    model: bool  # a GeneratorConfig field (TrainConfig.model)
    kind: Any  # the flag's type: int, float, str, bool, Path
    default: Any  # the config's default
    help: str
    meta: dict

    @property
    def option(self) -> str:
        return "--" + self.name.replace("_", "-")

    def cli_default(self):
        if isinstance(self.default, tuple):
            return ",".join(str(x) for x in self.default)
        if self.kind is Path and self.default is not None:
            return Path(self.default)
        return self.default

    def to_config(self, value):
        """The flag's value as the config field holds it."""
        if value is None:
            return None
        if isinstance(self.default, tuple):
            kind = type(self.default[0]) if self.default else int
            return tuple(kind(x) for x in str(value).split(",") if x.strip())
        if self.kind is Path:
            return str(value)
        if self.meta.get("none_if_negative") and value < 0:
            return None
        return value

    def to_args(self, value) -> list[str]:
        """Command-line arguments that give this flag ``value`` (a config or flag value)."""
        if isinstance(value, bool):
            return [self.option if value else "--no-" + self.option[2:]]
        if value is None:
            if self.meta.get("none_if_negative"):
                return [self.option, "-1"]
            raise ValueError(f"{self.option} cannot be given as None")
        if isinstance(value, tuple):
            value = ",".join(str(x) for x in value)
        return [self.option, str(value)]


def _flag_type(hint) -> Any:
    """int | None -> int, tuple[int, ...] -> str (comma-separated)."""
    if isinstance(hint, types.UnionType) or typing.get_origin(hint) is typing.Union:
        hint = next(a for a in typing.get_args(hint) if a is not type(None))
    if typing.get_origin(hint) is tuple:
        return str
    return hint


@cache
def train_flags() -> tuple[Flag, ...]:
    """The flags `tween train` makes from TrainConfig (and the model fields it lists)."""
    from pipeline.networks.generator import GeneratorConfig
    from pipeline.train.generator_training import TrainConfig

    hints = typing.get_type_hints(TrainConfig)
    ghints = typing.get_type_hints(GeneratorConfig)
    gdefaults = {f.name: f.default for f in fields(GeneratorConfig)}
    out = []
    for f in fields(TrainConfig):
        if f.name == "model":
            for name, (gfield, help) in f.metadata["flags"].items():
                out.append(Flag(name, gfield, True, _flag_type(ghints[gfield]), gdefaults[gfield], help, {}))
            continue
        if "help" not in f.metadata:
            raise TypeError(f"TrainConfig.{f.name} has no help: declare it with _knob(default, help)")
        default = f.default if f.default is not MISSING else f.default_factory()
        kind = Path if f.metadata.get("path") else _flag_type(hints[f.name])
        out.append(Flag(f.name, f.name, False, kind, default, f.metadata["help"], dict(f.metadata)))
    clash = {fl.name for fl in out} & set(EXPLICIT)
    if clash:
        raise TypeError(f"TrainConfig fields clash with tween train's own flags: {sorted(clash)}")
    return tuple(out)


def path_steps_default() -> int:
    from pipeline.train.path_training import PathTrainConfig

    return next(f.default for f in fields(PathTrainConfig) if f.name == "steps")


def configs(values: dict):
    """Flag values (as click parsed them) -> (TrainConfig, PathTrainConfig)."""
    from pipeline.networks.generator import GeneratorConfig
    from pipeline.train.generator_training import TrainConfig
    from pipeline.train.path_training import PathTrainConfig

    kw, model = {}, {}
    for fl in train_flags():
        try:
            (model if fl.model else kw)[fl.field] = fl.to_config(values[fl.name])
        except ValueError:
            like = "comma-separated numbers" if isinstance(fl.default, tuple) else "a value"
            raise typer.BadParameter(
                f"{fl.option} {values[fl.name]!r}: expected {like} like {fl.cli_default()}"
            ) from None
        choices = fl.meta.get("choices")
        if choices and kw[fl.field] not in choices:
            raise typer.BadParameter(f"{fl.option} must be one of {', '.join(choices)}")
    if kw["adv_start"] is not None and kw["adv_start"] >= kw["steps"]:
        kw["adv_start"] = None  # no refinement within the run
    try:
        cfg = TrainConfig(**kw, model=GeneratorConfig(**model))
    except ValueError as e:
        raise typer.BadParameter(str(e)) from None
    common = {k: kw[k] for k in ("batch", "seed", "threads", "limit_clips", "data", "data_include", "corpus",
                                 "data_pack", "checkpoint_minutes")}  # fmt: skip
    if not 0 <= values["path_steps"] <= 1e9:  # as --steps; 0: no path predictor in this run
        raise typer.BadParameter(f"--path-steps {values['path_steps']}: must be from 0 to 1e+09")
    return cfg, PathTrainConfig(steps=values["path_steps"], **common)


def train_run(out: Path, cfg, path_cfg) -> Path:
    """The training entry point of `tween train` and of every recipe stage: the path predictor
    (when it has steps), then the generator. Returns the generator checkpoint."""
    from pipeline.train.generator_training import train as train_generator
    from pipeline.train.path_training import train_path

    made = missing_folders(out)  # removed again if left empty

    def busy() -> TweenError:
        return TweenError(
            f"{out}: another `tween train` is writing this run folder; wait for it, or give another --out"
        )

    try:  # one run a folder: two wrote the same checkpoints and logs
        # Made inside: an interrupt re-sent while torch imported (pipeline.command) landed
        # just after the mkdir, before the try, and left the run folder, empty.
        out.mkdir(parents=True, exist_ok=True)
        with holding(out, busy):
            if path_cfg.steps:
                train_path(path_cfg, out)
            return train_generator(cfg, out)
    finally:
        remove_created(made)  # refused before it wrote anything: its folders go


def check_run(out: Path, cfg) -> None:
    """What `tween train` reads, checked before it writes anything: the run folder is not a
    model (a model is written by `tween export`), --init is a checkpoint that `tween train`
    wrote, --device is one torch has here, --partial has a key adapter to train, the
    takes folder holds takes, and every source of a corpus has takes as long as --lengths."""
    from pipeline.train.generator_training import check_partial, load_init

    refuse_model(out, "--out (a run folder)", force_hint=None)
    refuse_read_only(out)
    check_device(cfg.device, here=True)
    # --init first: whether --partial has a key adapter may be its network's to say.
    saved = (load_init(cfg.init).get("config") or {}).get("model") if cfg.init else None
    check_partial(cfg, saved)
    check_data(cfg)


def check_data(cfg, pack_made_later: bool = False) -> None:
    """The takes folder holds takes, every source of a corpus has takes as long as --lengths,
    and --data-pack is a whole pack (unless ``pack_made_later``: a recipe's runner packs
    OUT/train.pack before the first stage that reads it): for `tween train`, and for every
    stage of a recipe before its first trains."""
    from pipeline.train.corpus import check_takes

    if cfg.data_include is not None and not names_a_glob(cfg.data_include):  # as library build's
        raise TweenError(f"--data-include {cfg.data_include!r}: names no file-name glob (e.g. '001_*,002_*'); "
                         "leave it out for every take")  # fmt: skip
    if cfg.data and not cfg.data_pack:  # every take checked cheaply, none read yet
        check_takes(cfg.data, cfg.data_include)
    if cfg.corpus or (cfg.data_pack and not pack_made_later):
        from pipeline.train.generator_training import training_clips

        # Loaded (its description refused as load_corpus refuses it), prepared or read (memory
        # maps) here, not first by the path predictor's stage: a source with no take as long
        # as --lengths is named before anything trains. A pack is decoded whole (seconds), not
        # first by the generator's stage after the path predictor's minutes: one cut short,
        # damaged or no pack at all is named before anything trains.
        training_clips(cfg)


def _train(ctx: typer.Context, **values) -> None:
    out, recipe = values.pop("out"), values.pop("recipe")
    out = None if out is None else given_path(out, "--out")
    from_stage, dry_run = values.pop("from_stage"), values.pop("dry_run")
    if recipe is None:
        if from_stage is not None or dry_run:
            raise typer.BadParameter("--from-stage and --dry-run go with --recipe")
        cfg, path_cfg = configs(values)
        out = out or Path("runs/default")
        check_run(out, cfg)
        typer.echo(str(train_run(out, cfg, path_cfg)))
        return
    given = [n for n in values if ctx.get_parameter_source(n).name in ("COMMANDLINE", "ENVIRONMENT")]
    if "init" in given or "data_pack" in given:
        raise typer.BadParameter("--init and --data-pack are set by the recipe, per stage (init =, packed =)")
    flags = {fl.name: fl for fl in train_flags()}
    overrides = []
    for n in given:
        if n == "path_steps":
            overrides += ["--path-steps", str(values[n])]
        else:
            overrides += flags[n].to_args(values[n])
    try:
        rec = load_recipe(recipe)
        run_recipe(rec, out or Path("runs") / rec.name, from_stage, dry_run, overrides)
    except RecipeError as e:
        raise TweenError(str(e)) from None


TRAIN_HELP = (
    "Train the path predictor, then the generator, on CPU. Deterministic for a seed. "
    "`--recipe NAME` replays a shipped model's stages from recipes/NAME.toml instead."
)


def _run_folder_params() -> list[inspect.Parameter]:
    """`tween train`'s parameters before TrainConfig's flags: the context, --out, --path-steps."""
    return [
        inspect.Parameter("ctx", inspect.Parameter.POSITIONAL_OR_KEYWORD, annotation=typer.Context),
        inspect.Parameter(
            "out",
            inspect.Parameter.KEYWORD_ONLY,
            annotation=str,
            default=typer.Option(
                None,
                help="Run folder: checkpoints, logs (resumes if present). Default runs/default; "
                "with --recipe NAME, runs/NAME (a folder per stage).",
                show_default=False,
            ),
        ),
        inspect.Parameter(
            "path_steps",
            inspect.Parameter.KEYWORD_ONLY,
            annotation=int,
            default=typer.Option(
                path_steps_default(), help="Path-predictor steps (trained first, then frozen; 0: none)."
            ),
        ),
    ]


def _recipe_params() -> list[inspect.Parameter]:
    """`tween train`'s parameters after TrainConfig's flags: --recipe, --from-stage, --dry-run."""
    return [
        inspect.Parameter(
            "recipe",
            inspect.Parameter.KEYWORD_ONLY,
            annotation=str,
            default=typer.Option(
                None,
                help="Replay a recipe: recipes/NAME.toml (or a .toml path), stage by stage into "
                "OUT/<stage>/; finished stages are skipped. Flags given beside it apply to every stage.",
            ),
        ),
        inspect.Parameter(
            "from_stage",
            inspect.Parameter.KEYWORD_ONLY,
            annotation=str,
            default=typer.Option(
                None, help="With --recipe: start at this stage (earlier ones must hold their checkpoints)."
            ),
        ),
        inspect.Parameter(
            "dry_run",
            inspect.Parameter.KEYWORD_ONLY,
            annotation=bool,
            default=typer.Option(False, help="With --recipe: print each stage's command; train nothing."),
        ),
    ]


@cache
def train_command():
    """The click command of `tween train`, its options made from TrainConfig's fields."""
    params = _run_folder_params()
    for fl in train_flags():
        params.append(
            inspect.Parameter(
                fl.name,
                inspect.Parameter.KEYWORD_ONLY,
                annotation=fl.kind,
                default=typer.Option(fl.cli_default(), help=fl.help),
            )
        )
    params += _recipe_params()

    def train(ctx, **values):
        return _train(ctx, **values)

    train.__signature__ = inspect.Signature(params)
    train.__annotations__ = {p.name: p.annotation for p in params}
    sub = typer.Typer(add_completion=False, pretty_exceptions_enable=False)
    sub.command("train", help=TRAIN_HELP)(train)
    return typer.main.get_command(sub)


def parse_train_args(args: list[str]) -> dict:
    """`tween train` arguments -> the flag values, by the command's own parser (a typo fails)."""
    cmd = train_command()
    ctx = cmd.make_context("train", list(args))
    return dict(ctx.params)


# ---------------------------------------------------------------------------- recipes


@dataclass
class Stage:
    name: str
    args: list[str]  # `tween train` arguments, without --out and --init
    init: str | None = None  # an earlier stage's name, or a checkpoint path
    packed: bool = False  # reads the train split packed by pipeline.data.pack
    wall_s: float | None = None  # measured wall time of the original run
    measured_device: str = "cpu"  # the device of that measurement (replays run on CPU by default)
    measured: str = ""  # where and how that was measured
    note: str = ""


@dataclass
class Export:
    stage: str
    args: list[str]  # `tween export` options, without the run folder and --out
    path_from: str | None = None  # the stage whose path.pt goes beside the exported generator


@dataclass
class Recipe:
    name: str
    source: Path
    stages: list[Stage]
    export: Export | None = None
    model: str | None = None
    notes: str = ""
    extra: dict = field(default_factory=dict)

    def stage(self, name: str) -> Stage:
        for s in self.stages:
            if s.name == name:
                return s
        raise RecipeError(f"{self.source}: no stage {name!r} (stages: {', '.join(self.names)})")

    @property
    def names(self) -> list[str]:
        return [s.name for s in self.stages]

    def wall_s(self) -> dict[str, float]:
        """The measured wall time summed over the stages, per device they were measured on."""
        out: dict[str, float] = {}
        for s in self.stages:
            out[s.measured_device] = out.get(s.measured_device, 0.0) + (s.wall_s or 0.0)
        return out

    def wall_line(self) -> str:
        per = self.wall_s()
        parts = [f"{_fmt_s(v)} ({v:,.1f} s) on {k}" for k, v in per.items()]
        return f"# measured wall time, summed over the stages: {' + '.join(parts)}"


def recipe_path(name: str | Path) -> Path:
    """A bare NAME (no "/", no ".toml") is the project's recipes/NAME.toml, even where the
    current folder holds a file or folder called NAME; anything else is a path."""
    text = str(name)
    if "/" not in text and not text.endswith(".toml"):
        shipped = RECIPES / f"{text}.toml"
        if shipped.is_file() or not Path(text).is_file():
            return shipped
    return Path(name)


# The types of the keys a recipe may hold, as TOML writes them (float: any number).
TOP_KEYS = {"name": str, "model": str, "notes": str, "base": dict, "stage": list, "export": dict}
STAGE_KEYS = {"name": str, "args": "args", "init": str, "packed": bool, "wall_s": float,
              "measured_device": str, "measured": str, "note": str}  # fmt: skip
BASE_KEYS = {"recipe": str, "through": str}
EXPORT_KEYS = {"stage": str, "args": "args", "path_from": str}
KIND_NAMES = {str: "a string", bool: "true or false", float: "a number", int: "an integer",
              dict: "a table", list: "an array", "args": "a string of arguments (or an array of strings)"}  # fmt: skip
KEY_KINDS = {"stage": "[[stage]] tables", "export": "an [export] table (stage = STAGE, args = ...)",
             "base": "a table {recipe = NAME, through = STAGE}", "wall_s": "a number (seconds)"}  # fmt: skip
RUNNER_FOLDERS = ("model", "train.pack")  # what the runner itself writes into OUT/


def _kind_of(value) -> str:
    kind = next((k for k in (bool, str, int, float, dict, list) if isinstance(value, k)), None)
    return KIND_NAMES.get(kind, f"a {type(value).__name__}")


def _typed(raw: dict, known: dict, where: str) -> dict:
    """``raw`` (a TOML table) checked against ``known`` (key -> kind): every key known, every
    value of its kind. Returns the values, args split into a list."""
    unknown = set(raw) - set(known)
    if unknown:
        raise RecipeError(f"{where}: unknown keys {sorted(unknown)} (known: {', '.join(known)})")
    out = {}
    for key, value in raw.items():
        kind = known[key]
        if kind == "args":
            out[key] = _args(value, f"{where}: {key}")
            continue
        number = kind is float and isinstance(value, int | float) and not isinstance(value, bool)
        if not (number or (isinstance(value, kind) and (kind is bool or not isinstance(value, bool)))):
            want = KEY_KINDS.get(key, KIND_NAMES[kind])
            raise RecipeError(f"{where}: {key} must be {want}, not {_kind_of(value)}")
        if kind is float and (not math.isfinite(value) or value < 0):
            raise RecipeError(f"{where}: {key} = {value}: must be a number of seconds, 0 or more")
        out[key] = float(value) if kind is float else value
    return out


def _args(value, where: str) -> list[str]:
    if isinstance(value, str):
        try:
            return shlex.split(value)
        except ValueError as e:  # an unclosed quote
            raise RecipeError(f"{where}: {str(e).lower()} (quote as a shell does)") from None
    if isinstance(value, list) and all(isinstance(a, str) for a in value):
        return list(value)
    raise RecipeError(f"{where} must be {KIND_NAMES['args']}, not {_kind_of(value)}")


def _folder_name(name: str, where: str, what: str) -> None:
    """``name`` as one plain folder name: no path of its own, nothing the runner writes."""
    plain = name not in ("", ".", "..") and not any(c in name for c in "/\\") and name.isprintable()
    if not plain or name != name.strip() or name in RUNNER_FOLDERS:
        raise RecipeError(
            f"{where}: name = {name!r}: {what}, so it must be a plain folder name "
            f"(no '/', not '.' or '..', not {' or '.join(RUNNER_FOLDERS)})"
        )


#: The most bytes a recipe file may hold (a few KB each shipped): a pipe or a device in its
#: place blocked or ate memory (read_small_text).
TOML_LIMIT = 8 << 20


def _read_toml(path: Path) -> dict:
    try:
        text = read_small_text(path, TOML_LIMIT, "recipe")
    except UnicodeDecodeError as e:
        raise RecipeError(f"{path}: not UTF-8 text (byte {e.start}); a recipe is a TOML file") from None
    except OSError as e:
        raise RecipeError(f"{path}: cannot read it: {e.strerror or e}") from None
    try:
        return tomllib.loads(text)
    except tomllib.TOMLDecodeError as e:
        raise RecipeError(f"{path}: {e}") from None
    except RecursionError:
        raise RecipeError(f"{path}: not valid TOML: arrays or tables nested too deeply to read") from None


def _missing(name, path: Path) -> str:
    known = ", ".join(sorted(p.stem for p in RECIPES.glob("*.toml")))
    return f"no recipe {str(name)!r} ({path} does not exist; recipes: {known})"


def load_recipe(name: str | Path) -> Recipe:
    """recipes/NAME.toml (or a path to a .toml file) -> Recipe, its base's stages first. The
    whole file is checked here (every key's type, the stages' names and references, the
    bases' chain), so a recipe that cannot be replayed fails before anything runs."""
    path = recipe_path(name)
    if not path.exists():
        raise RecipeError(_missing(name, path))
    return _load(path, ())


def _load(path: Path, chain: tuple[Path, ...]) -> Recipe:
    raw = _typed(_read_toml(path), TOP_KEYS, str(path))
    rec_name = raw.get("name", path.stem)
    _folder_name(rec_name, str(path), "it names the default run folder runs/NAME/")
    stages = _base_stages(raw["base"], path, (*chain, path.resolve())) if "base" in raw else []
    for i, s in enumerate(raw.get("stage", []), start=1):
        stages.append(_stage(s, i, path))
    if not stages:
        raise RecipeError(f"{path}: no [[stage]] (nor a base with stages): nothing to run")
    export = None
    if "export" in raw:
        e = _typed(raw["export"], EXPORT_KEYS, f"{path}: [export]")
        if "stage" not in e:
            raise RecipeError(f"{path}: [export]: no stage = STAGE (the stage it exports)")
        if any(a.split("=")[0] == "--out" for a in e.get("args", [])):
            raise RecipeError(f"{path}: [export]: args: --out is set by the recipe runner (OUT/model)")
        export = Export(stage=e["stage"], args=e.get("args", []), path_from=e.get("path_from"))
    rec = Recipe(rec_name, path, stages, export, model=raw.get("model"), notes=raw.get("notes", ""))
    _check_structure(rec)
    return rec


def _stage(raw, i: int, path: Path) -> Stage:
    """The i-th [[stage]] table of ``path``, checked."""
    where = f"{path}: stage {i}"
    if not isinstance(raw, dict):
        raise RecipeError(f"{where}: must be a [[stage]] table, not {_kind_of(raw)}")
    if isinstance(raw.get("name"), str):
        where = f"{path}: stage {raw['name']!r}"
    s = _typed(raw, STAGE_KEYS, where)
    if "name" not in s:
        raise RecipeError(f"{where}: no name = NAME (the folder OUT/NAME/ it runs into)")
    _folder_name(s["name"], where, "the stage runs into OUT/NAME/")
    return Stage(**{"args": [], **s})


def _base_stages(raw: dict, path: Path, chain: tuple[Path, ...]) -> list[Stage]:
    """The stages ``base = {recipe = NAME, through = STAGE}`` puts first."""
    b = _typed(raw, BASE_KEYS, f"{path}: base")
    if "recipe" not in b:
        raise RecipeError(f"{path}: base: no recipe = NAME (the recipe whose stages come first)")
    bpath = recipe_path(b["recipe"])
    if not bpath.exists():
        raise RecipeError(f"{path}: base: {_missing(b['recipe'], bpath)}")
    if bpath.resolve() in chain:
        loop = " -> ".join(str(p) for p in (*chain, bpath.resolve()))
        raise RecipeError(f"{path}: base: recipe = {b['recipe']!r} leads back to itself ({loop})")
    try:
        base = _load(bpath, chain)
    except RecipeError as e:  # named from this file: the base it reads cannot be replayed
        raise RecipeError(f"{path}: base: {e}") from None
    through = b.get("through", base.names[-1])
    if through not in base.names:
        raise RecipeError(
            f"{path}: base: through = {through!r} is no stage of {bpath} (stages: {', '.join(base.names)})"
        )
    return base.stages[: base.names.index(through) + 1]


def _check_structure(rec: Recipe) -> None:
    seen: set[str] = set()
    for s in rec.stages:
        if s.name in seen:
            raise RecipeError(f"{rec.source}: stage {s.name!r} twice (each runs into OUT/{s.name}/)")
        for a in s.args:
            if a.split("=")[0] in RESERVED:
                raise RecipeError(
                    f"{rec.source}: stage {s.name!r}: {a} is set by the recipe runner "
                    "(use init = STAGE, packed = true)"
                )
        if s.init is not None and s.init not in seen and not _is_path(s.init):
            raise RecipeError(f"{rec.source}: stage {s.name!r}: init {s.init!r} is no earlier stage")
        seen.add(s.name)
    if rec.export is not None:
        for key, ref in (("stage", rec.export.stage), ("path_from", rec.export.path_from)):
            if ref is not None and ref not in seen:
                raise RecipeError(f"{rec.source}: [export]: {key} = {ref!r} is no stage")


def _is_path(ref: str) -> bool:
    return "/" in ref or ref.endswith(".pt")


def stage_args(rec: Recipe, stage: Stage, out: Path, overrides: list[str] = ()) -> list[str]:
    """The full `tween train` arguments of a stage run into ``out``/<stage>/."""
    args = ["--out", str(out / stage.name), *stage.args]
    if stage.packed:
        args += ["--data-pack", str(out / "train.pack")]
    if stage.init is not None:
        args += ["--init", stage.init if _is_path(stage.init) else str(out / stage.init / "generator.pt")]
    return args + list(overrides)


def export_args(rec: Recipe, out: Path) -> list[str]:
    return [str(out / rec.export.stage), "--out", str(out / "model"), *rec.export.args]


def check_recipe(rec: Recipe, overrides: list[str] = (), out: Path | None = None) -> list:
    """Every stage's arguments parsed by `tween train`'s parser (and the export's by
    `tween export`'s): a typo is an error here, before any training. Returns the configs
    of the stages run into ``out`` (default runs/NAME)."""
    out = Path("runs") / rec.name if out is None else out
    parsed = []
    for s in rec.stages:
        try:
            parsed.append(configs(parse_train_args(stage_args(rec, s, out, overrides)[2:])))
        except Exception as e:  # click's usage errors, BadParameter
            msg = e.format_message() if hasattr(e, "format_message") else str(e)
            raise RecipeError(f"{rec.source}: stage {s.name!r}: {msg}") from None
    if rec.export is not None:
        try:
            export_command().make_context("export", export_args(rec, out))
        except Exception as e:
            msg = e.format_message() if hasattr(e, "format_message") else str(e)
            raise RecipeError(f"{rec.source}: export: {msg}") from None
    return parsed


def finished(run: Path, steps: int) -> bool:
    """The stage folder holds its generator checkpoint at its last step. A file there that is
    no checkpoint of `tween train` (or whose step is not a number) is refused in one line."""
    ckpt = run / "generator.pt"
    if not ckpt.exists():
        return False
    from pipeline.train.generator_training import read_checkpoint

    hint = "; it is no finished stage to skip: remove it, or give another --out"
    state = read_checkpoint(ckpt, f"recipe stage {run.name}", hint=hint)
    step = state.get("step", 0)
    if isinstance(step, bool) or not isinstance(step, int):
        raise TweenError(f"{ckpt}: recipe stage {run.name}: its step is {step!r}, not a number{hint}")
    return step >= steps


def _finished_stages(rec: Recipe, configs_: list, out: Path, start: int) -> set[str]:
    """The stages from ``start`` on whose folders hold their finished checkpoints; every other
    stage's folder and --init checked first, so a replay that cannot go on stops before it
    writes anything."""
    if out.exists() and not out.is_dir():
        raise RecipeError(f"{out}: --out of recipe {rec.source} is a file, not a folder")
    done, runs = set(), set()
    for s, (cfg, _) in list(zip(rec.stages, configs_, strict=True))[start:]:
        run = out / s.name
        if run.exists() and not run.is_dir():
            raise RecipeError(f"{run}: stage {s.name} of {rec.source} runs into it, but it is a file; "
                              "remove it, or give another --out")  # fmt: skip
        if finished(run, cfg.steps):
            done.add(s.name)
            continue
        runs.add(s.name)
        if cfg.init is not None and s.init not in runs and not Path(cfg.init).exists():
            raise RecipeError(f"{rec.source}: stage {s.name!r}: its --init {cfg.init} does not exist")
        try:  # a later stage's takes, corpus or pack refused now, not after the stages before it trained
            check_data(cfg, pack_made_later=s.packed and not Path(cfg.data_pack).exists())
        except TweenError as e:
            raise RecipeError(f"{rec.source}: stage {s.name!r}: {e}") from None
    return done


def _fmt_s(s: float) -> str:
    return f"{s / 3600:.2f} h" if s >= 3600 else f"{s / 60:.1f} min"


def run_recipe(
    rec: Recipe,
    out: Path,
    from_stage: str | None = None,
    dry_run: bool = False,
    overrides: list[str] = (),
    echo=typer.echo,
) -> Path | None:
    """Replay a recipe into ``out``/<stage>/ (and ``out``/model/ for its export). Returns the
    last stage's generator checkpoint (the export's folder when it has one)."""
    configs_ = check_recipe(rec, overrides, out)
    if not dry_run:
        refuse_read_only(out)
    start = rec.names.index(rec.stage(from_stage).name) if from_stage else 0
    say = echo if dry_run else (lambda m: print(m, file=sys.stderr))
    done = set() if dry_run else _finished_stages(rec, configs_, out, start)
    say(f"# recipe {rec.name} ({rec.source}): {len(rec.stages)} stages into {out}/")
    last = _run_stages(rec, configs_, out, (start, from_stage, done), dry_run, overrides, echo, say)
    if rec.export is None:
        if dry_run:
            echo(rec.wall_line())
        return last
    return _run_export(rec, out, dry_run, echo, say)


def _run_stages(rec, configs_, out, where, dry_run, overrides, echo, say) -> Path | None:
    """The recipe's stages from ``start`` on (each printed, with ``dry_run``, not run; skipped
    when in ``done``, the finished ones); returns the last stage's generator checkpoint."""
    (start, from_stage, done), last, packed_said = where, None, False
    for i, (s, (cfg, path_cfg)) in enumerate(zip(rec.stages, configs_, strict=True)):
        run = out / s.name
        cmd = "tween train " + shlex.join(stage_args(rec, s, out, overrides))
        wall = f"measured {_fmt_s(s.wall_s)} on {s.measured_device}" if s.wall_s else "no measured time"
        if i < start:
            say(f"# {s.name}: before --from-stage {from_stage}, not run")
            last = run / "generator.pt"
            continue
        if dry_run:
            if s.packed and not packed_said:
                echo(f"python -m pipeline.data.pack {out / 'train.pack'}   # once, where ../shared is")
                packed_said = True
            echo(f"{cmd}   # {s.name}: {wall}")
            continue
        if s.name in done:
            say(f"# {s.name}: {run / 'generator.pt'} finished ({cfg.steps} steps), skipped")
            last = run / "generator.pt"
            continue
        if cfg.init is not None and not Path(cfg.init).exists():
            raise RecipeError(f"{rec.source}: stage {s.name!r}: its --init {cfg.init} does not exist")
        if s.packed and not (out / "train.pack").exists():
            from pipeline.data.cache import load_split
            from pipeline.data.pack import pack

            say(f"# packing the train split into {out / 'train.pack'}")
            pack(load_split("train"), out / "train.pack")
        say(f"{cmd}   # {s.name}: {wall}")
        t0 = time.time()
        last = train_run(run, cfg, path_cfg)
        (run / "recipe_stage.json").write_text(
            json.dumps(
                {
                    "recipe": rec.name,
                    "stage": s.name,
                    "args": stage_args(rec, s, out, overrides),
                    "wall_s": round(time.time() - t0, 1),
                    "measured_wall_s": s.wall_s,
                },
                indent=1,
            )  # fmt: skip
        )
    return last


def _run_export(rec: Recipe, out: Path, dry_run: bool, echo, say) -> Path | None:
    """The recipe's export into ``out``/model/ (printed, with ``dry_run``, not run; skipped
    when its model.json exists); returns the model folder."""
    args = export_args(rec, out)
    steps = []
    if rec.export.path_from and rec.export.path_from != rec.export.stage:
        src, dst = out / rec.export.path_from / "path.pt", out / rec.export.stage / "path.pt"
        steps.append(f"cp {src} {dst}")
    steps.append("tween export " + shlex.join(args))
    if dry_run:
        for line in steps:
            echo(line)
        echo(rec.wall_line())
        return None
    model = out / "model"
    if (model / "model.json").exists():
        say(f"# export: {model / 'model.json'} exists, skipped")
        return model
    if len(steps) == 2:
        shutil.copyfile(src, dst)
    say(steps[-1])

    export_command().main(args, prog_name="tween export", standalone_mode=False)
    return model
