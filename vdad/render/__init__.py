"""Rendering on an EGL OpenGL context: rendered visibility (Kim 2008 §5.4) and
pictures of a simulation (Kim 2008 Figures 1-2, 8-9).

* :mod:`vdad.render.counting`: per-body visible pixel counts, with occlusion;
* :mod:`vdad.render.pictures`: frames of a simulation rendered with pyrender, bodies
  coloured by rigid group, active joints marked; motion strips, PNG, GIF and MP4;
* :mod:`vdad.render.context`: the process-wide OpenGL context both share.

Nothing here is imported by ``import vdad``, and importing these modules loads
neither pyrender nor PyOpenGL: they are imported on first use (a pixel counter,
a scene renderer).
"""
