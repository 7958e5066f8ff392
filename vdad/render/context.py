"""The process-wide OpenGL context for the rendered visibility (Kim 2008 §5.4; anchors §3).

vdad renders offscreen through pyrender's EGL platform, which needs no display
and no GPU (Mesa's llvmpipe is enough). One long-lived
``pyrender.OffscreenRenderer`` per process owns the context; it is never
deleted because ``OffscreenRenderer.delete()`` terminates the EGL display that
every renderer of the process shares. The context is current on one thread at
a time: use it from the thread that created it.

Importing this module sets ``PYOPENGL_PLATFORM=egl`` unless it is already set,
because PyOpenGL picks its platform once, when it is first imported.
"""

from __future__ import annotations

import logging
import os
import sys
import threading

from ..errors import InputError, RenderError

os.environ.setdefault("PYOPENGL_PLATFORM", "egl")

log = logging.getLogger(__name__)

INSTALL_HINT = (
    "rendered visibility needs OpenGL through EGL: install the EGL libraries (Debian: "
    "apt-get install libegl1 libegl-mesa0 libgl1-mesa-dri libopengl0) and the render extra "
    "(pip install 'vdad[render]', i.e. pyrender2 and PyOpenGL>=3.1.9), and set "
    "PYOPENGL_PLATFORM=egl before anything imports OpenGL")

_lock = threading.Lock()
_renderer = None          # the process-wide pyrender.OffscreenRenderer
_renderer_name = None     # its GL_RENDERER string


def _check_platform():
    """Raise :class:`RenderError` unless PyOpenGL is (or will be) on its EGL platform."""
    platform = os.environ.get("PYOPENGL_PLATFORM")
    if platform != "egl":
        raise RenderError(f"vdad renders on EGL but PYOPENGL_PLATFORM={platform!r}; set "
                          f"PYOPENGL_PLATFORM=egl (or leave it unset) before anything imports "
                          f"OpenGL; {INSTALL_HINT}")
    loaded = sys.modules.get("OpenGL.platform")
    chosen = type(getattr(loaded, "PLATFORM", None)).__name__
    if loaded is not None and chosen != "EGLPlatform":
        raise RenderError(f"OpenGL was imported on its {chosen} platform before "
                          f"PYOPENGL_PLATFORM=egl was set, and PyOpenGL cannot change platform "
                          f"afterwards; set PYOPENGL_PLATFORM=egl in the environment, or import "
                          f"vdad.render before OpenGL or pyrender; {INSTALL_HINT}")


def _create(width, height):
    """A new ``OffscreenRenderer`` with its context current, and its GL_RENDERER."""
    _check_platform()
    try:
        import pyrender
        from OpenGL import GL
    except Exception as exc:
        raise RenderError(f"cannot import pyrender and PyOpenGL ({type(exc).__name__}: {exc}); "
                          f"{INSTALL_HINT}") from exc
    try:
        renderer = pyrender.OffscreenRenderer(width, height)
        renderer._platform.make_current()
        name = GL.glGetString(GL.GL_RENDERER).decode(errors="replace")
    except Exception as exc:
        raise RenderError(f"cannot create an OpenGL context on EGL ({type(exc).__name__}: "
                          f"{exc}); {INSTALL_HINT}") from exc
    return renderer, name


def check_view(camera, R, p, nb):
    """``(R, p)`` as float arrays (nb, 3, 3), (nb, 3) for rendering ``nb`` bodies
    seen by ``camera``, or an :class:`InputError` naming what is wrong."""
    import numpy as np

    from ..camera import Camera

    if not isinstance(camera, Camera):
        raise InputError(f"camera must be a vdad.camera.Camera, got {type(camera).__name__}")
    R, p = np.asarray(R, dtype=float), np.asarray(p, dtype=float)
    if R.shape != (nb, 3, 3):
        raise InputError(f"R must have shape ({nb}, 3, 3), got {R.shape}")
    if p.shape != (nb, 3):
        raise InputError(f"p must have shape ({nb}, 3), got {p.shape}")
    if not (np.isfinite(R).all() and np.isfinite(p).all()):
        raise InputError("R and p must be finite")
    return R, p


def gl_context(width=None, height=None):
    """The process-wide ``pyrender.OffscreenRenderer`` (created on first use, at
    ``width`` x ``height``, default 320 x 240). Given ``width`` and ``height``,
    its viewport is set to them (pyrender resizes its framebuffer at its next
    render); vdad's own passes use their own framebuffers and ignore it.

    Raises :class:`~vdad.errors.RenderError` (with what to install or set) when
    pyrender, PyOpenGL or EGL is missing or the context cannot be created.
    """
    global _renderer, _renderer_name
    for name, value in (("width", width), ("height", height)):
        if value is not None and (int(value) != value or value < 1):
            raise InputError(f"{name} must be a positive whole number of pixels, got {value!r}")
    with _lock:
        if _renderer is None:
            _renderer, _renderer_name = _create(int(width or 320), int(height or 240))
            log.info("OpenGL context on EGL, GL_RENDERER %s", _renderer_name)
        if width is not None:
            _renderer.viewport_width = int(width)
        if height is not None:
            _renderer.viewport_height = int(height)
        return _renderer


def make_current():
    """Make the process-wide context current on this thread (creating it if needed)."""
    renderer = gl_context()
    try:
        renderer._platform.make_current()
    except Exception as exc:
        raise RenderError(f"cannot make the EGL context current ({type(exc).__name__}: {exc}); "
                          f"it is current on another thread, or {INSTALL_HINT}") from exc


def renderer_name() -> str:
    """GL_RENDERER of the process-wide context, e.g. ``'llvmpipe (LLVM 15.0.6, 256 bits)'``."""
    gl_context()
    return _renderer_name
