"""Rendered visibility (Kim 2008 §5.4): per-body visible pixel counts on an EGL
OpenGL context.

Nothing here is imported by ``import vdad``: import :mod:`vdad.render.counting`
(which loads pyrender and PyOpenGL on first use) to count pixels.
"""
