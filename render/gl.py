"""One headless OpenGL 3.3 core context per process (EGL through moderngl), made on first use.

Created lazily, never at import, so Celery prefork children each make their own after fork.
"""

from __future__ import annotations

import os

from pipeline.errors import TweenError

_CTX = None


class RenderError(TweenError):
    """Review media cannot be rendered (no GL, bad size, encoder missing)."""


def context():
    """The process's moderngl context (EGL; Mesa llvmpipe on CPU hosts, the GPU driver on nodes)."""
    global _CTX
    if _CTX is None:
        # llvmpipe sizes its thread pool from the CPU count; keep an explicit setting if given.
        os.environ.setdefault("LP_NUM_THREADS", str(os.cpu_count() or 2))
        try:
            import moderngl

            _CTX = moderngl.create_standalone_context(backend="egl", require=330)
        except Exception as e:  # glcontext raises plain Exceptions whose text names the missing library
            msg = str(e).strip().splitlines()[0] if str(e).strip() else type(e).__name__
            raise RenderError(
                f"no headless OpenGL 3.3 (EGL) on this host: {msg}; "
                "install it with: apt-get install -y libegl1 libegl-mesa0 libgl1-mesa-dri"
            ) from None
    return _CTX


def renderer_name() -> str:
    return context().info.get("GL_RENDERER", "?")
