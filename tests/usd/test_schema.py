"""The TweenAPI codeless schema: registered on import, attributes and fallbacks, plugin path."""

import os
import subprocess
import sys

import pipeline.usd  # noqa: F401  (registers the plugin before any stage exists)
import usd_schemas


def test_registry_knows_tween_api_with_fallbacks():
    from pxr import Usd

    reg = Usd.SchemaRegistry()
    assert reg.IsAppliedAPISchema("TweenAPI")
    d = reg.FindAppliedAPIPrimDefinition("TweenAPI")
    names = set(d.GetPropertyNames())
    want = {"tween:keyTimes", "tween:model", "tween:modelHash", "tween:seed", "tween:take", "tween:jobId",
            "tween:createdAt", "tween:reviewStatus", "tween:approvedTake"}  # fmt: skip
    assert want <= names
    stage = Usd.Stage.CreateInMemory()
    prim = stage.DefinePrim("/Shot")
    assert prim.ApplyAPI("TweenAPI") and prim.HasAPI("TweenAPI")
    status = prim.GetAttribute("tween:reviewStatus")
    assert status.Get() == "pending" and not status.HasAuthoredValue()
    assert list(status.GetMetadata("allowedTokens")) == ["pending", "approved", "rejected"]
    assert prim.GetAttribute("tween:approvedTake").Get() == -1
    assert prim.GetAttribute("tween:seed").Get() == 0
    assert prim.GetAttribute("tween:model").Get() == ""
    assert str(prim.GetAttribute("tween:keyTimes").GetTypeName()) == "double[]"


def test_plugin_found_through_pxr_pluginpath_name_by_other_tools():
    # A process that never imports this package (a DCC, usdview) finds the schema
    # through the documented environment variable.
    code = "from pxr import Usd; print(Usd.SchemaRegistry().IsAppliedAPISchema('TweenAPI'))"
    env = dict(os.environ, PXR_PLUGINPATH_NAME=str(usd_schemas.PLUGIN_DIR))
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "True"
    env.pop("PXR_PLUGINPATH_NAME")
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "False"


def test_generated_files_match_schema_source(tmp_path):
    from pathlib import Path

    subprocess.run(
        [
            sys.executable,
            "-m",
            "pxr.Usd.usdGenSchema",
            str(usd_schemas.PLUGIN_DIR.parent / "schema.usda"),
            str(tmp_path),
        ],
        check=True,
        capture_output=True,
    )
    gen = (tmp_path / "generatedSchema.usda").read_text()
    assert gen == Path(usd_schemas.PLUGIN_DIR / "generatedSchema.usda").read_text()


def test_tokens_module_is_generated_from_the_schema():
    """usd_schemas/tokens.py holds one constant per TweenAPI attribute, current with the
    schema (regenerate with python -m usd_schemas.generate)."""
    from pathlib import Path

    from usd_schemas import generate, tokens

    assert Path(tokens.__file__).read_text() == generate.tokens_source()
    assert tokens.KEY_TIMES == "tween:keyTimes" and tokens.TAKE_VARIANT_SET == "tweenTake"


def test_no_tween_name_is_spelled_outside_the_tokens_module():
    """Every tween:* USD name (and the take variant set) comes from usd_schemas.tokens;
    render/output.py's image metadata keys are OpenImageIO attributes, not USD."""
    import ast
    import re
    from pathlib import Path

    root = Path(__file__).resolve().parents[2]
    pattern = re.compile(r"^(tween:[A-Za-z]+|tweenTake|TweenAPI)$")
    hits = []
    for top in ("pipeline", "render", "workers"):
        for path in root.joinpath(top).rglob("*.py"):
            if path.name == "output.py" and path.parent.name == "render":
                continue
            for node in ast.walk(ast.parse(path.read_text())):
                if (
                    isinstance(node, ast.Constant)
                    and isinstance(node.value, str)
                    and pattern.match(node.value)
                ):
                    hits.append(f"{path.relative_to(root)}:{node.lineno} {node.value!r}")
    assert not hits, hits
