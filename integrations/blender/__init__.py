"""usd-tween for Blender: fill the in-betweens of the animator's blocking on the usd-tween
farm and bring the takes back as actions.

The Blender-facing modules (``ui``, ``blend``) are imported only by :func:`register`, so the
plain-Python logic (``commands``, ``status``, ``naming``, ``result``, ``usda``, ``jobs``)
imports without ``bpy`` and is tested in the project's CI.
"""


def register() -> None:
    from . import ui

    ui.register()


def unregister() -> None:
    from . import ui

    ui.unregister()
