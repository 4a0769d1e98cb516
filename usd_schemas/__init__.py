"""The TweenAPI codeless schema plugin (``tween/resources``).

:func:`register` must run before the first USD stage is opened in the process: the schema
registry is built once, and plugins registered after that are found but never become
schemas. ``pipeline.usd`` calls it on import. Other tools (DCCs, usdview) find the plugin
through ``PXR_PLUGINPATH_NAME=<this folder>/tween/resources``.
"""

from __future__ import annotations

from pathlib import Path

PLUGIN_DIR = Path(__file__).resolve().parent / "tween" / "resources"
SCHEMA_NAME = "TweenAPI"
_done = False


def register() -> None:
    """Registers the plugin with USD's plugin registry (idempotent)."""
    global _done
    if _done:
        return
    from pxr import Plug

    Plug.Registry().RegisterPlugins(str(PLUGIN_DIR))
    _done = True
