"""MuJoCo offscreen OpenGL on machines without a display: backend choice (EGL, then OSMesa)
and a current offscreen context, shared by the synthetic renderer and twin pictures."""

from __future__ import annotations

import logging
import os
import subprocess
import sys

from funrec.errors import FunrecError

LOGGER = logging.getLogger(__name__)

_GL_BACKENDS = ("egl", "osmesa")
_PROBE = "import mujoco; m = mujoco.MjModel.from_xml_string('<mujoco/>'); mujoco.Renderer(m, 8, 8).close()"


def ensure_gl_backend() -> str:
    """Pick MuJoCo's offscreen OpenGL backend before MuJoCo is imported.

    Keeps ``MUJOCO_GL`` when the user set it. Otherwise tries EGL, then OSMesa, each in a
    short subprocess, and sets ``MUJOCO_GL`` (and ``PYOPENGL_PLATFORM``) to the first that
    renders. MuJoCo reads the variable once, at import, so this must run first.

    Returns:
        The backend in use ("egl", "osmesa", or the user's value).

    Raises:
        FunrecError: no backend can render.
    """
    chosen = os.environ.get("MUJOCO_GL")
    if chosen or "mujoco" in sys.modules:
        return chosen or "default"
    for backend in _GL_BACKENDS:
        env = {**os.environ, "MUJOCO_GL": backend, "PYOPENGL_PLATFORM": backend}
        probe = subprocess.run([sys.executable, "-c", _PROBE], env=env, capture_output=True, timeout=120, check=False)
        if probe.returncode == 0:
            os.environ["MUJOCO_GL"] = backend
            os.environ.setdefault("PYOPENGL_PLATFORM", backend)
            LOGGER.info("MuJoCo offscreen rendering with %s", backend)
            return backend
        LOGGER.info("MuJoCo %s rendering unavailable: %s", backend, probe.stderr.decode(errors="replace")[-300:])
    raise FunrecError("MuJoCo cannot render offscreen with EGL or OSMesa; install libegl1 or libosmesa6 (see Makefile)")


def offscreen_context(width: int, height: int) -> object:
    """A current offscreen GL context: MuJoCo's own when it was imported with EGL or OSMesa,
    else (MuJoCo imported first by other code, with a windowing backend) one made directly."""
    import importlib

    import mujoco

    candidates = []
    if any(name in getattr(mujoco, "GLContext", type).__module__ for name in _GL_BACKENDS):
        candidates.append(mujoco.GLContext)
    errors = []
    for backend in _GL_BACKENDS:
        try:
            candidates.append(importlib.import_module(f"mujoco.{backend}").GLContext)
        except Exception as exc:  # the GL bindings raise assorted types
            errors.append(f"{backend}: {exc}")
    for context_class in candidates:
        try:
            context = context_class(width, height)
            context.make_current()
            return context
        except Exception as exc:  # context creation fails with assorted types too
            errors.append(f"{context_class.__module__}: {exc}")
    raise FunrecError(
        f"cannot create an offscreen OpenGL context (MUJOCO_GL={os.environ.get('MUJOCO_GL')}): {'; '.join(errors)}"
    )


__all__ = ["ensure_gl_backend", "offscreen_context"]
