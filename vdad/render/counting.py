"""Per-body visible pixel counts with occlusion, rendered (Kim 2008 §5.4; anchors §3).

The paper measures how much of each body the viewer sees by drawing the scene
and counting, per body, the pixels that survive the depth test. Here all bodies
live in one merged vertex buffer, uploaded once: each vertex carries its
position in its body's frame and an integer id (0 for the environment, whose
triangles are in world coordinates; ``i + 1`` for body ``i``). Each call
uploads one clip-from-local matrix per id into a texture buffer that the vertex
shader fetches by id, so the whole scene is one draw call whatever the number
of bodies. Two methods give the counts:

* ``"merged"``: one draw into an R32UI id buffer (the fragment writes its id,
  the clear value is 0), read back, each body's pixels counted by
  :func:`vdad.visibility.id_counts_pass`;
* ``"queries"``: the paper's occlusion queries: a depth pre-pass of everything,
  then with depth writes and colour writes off and ``GL_LEQUAL``, one
  ``GL_SAMPLES_PASSED`` query around each body's ranged draw of the same buffer
  by the same program (so that its depths are those of the pre-pass).

Both draw into the counter's own single-sample framebuffer at its counting
resolution, with the depth test on and no back-face culling (a camera inside a
body sees its back faces). They agree exactly except where fragments tie in
depth at a pixel: the id buffer keeps the first drawn, a query counts every
tying fragment. Besides coplanar surfaces, ties occur on a few pixels where a
body's front and back faces meet (silhouettes, the cut by the near plane), so
the queries may exceed the merged counts there by a few pixels.
"""

from __future__ import annotations

import ctypes
import weakref

import numpy as np

from ..environment import check_environment
from ..errors import InputError, RenderError
from ..model import check_model
from ..raster import merged_geometry
from ..visibility import id_counts_pass
from . import context

METHODS = ("merged", "queries")

_VERTEX_SHADER = """#version 330 core
layout(location = 0) in vec3 position;   // body frame (bodies), world frame (environment)
layout(location = 1) in uint id;         // 0: environment, i + 1: body i
uniform samplerBuffer transforms;        // 4 RGBA32F texels per id: clip-from-local columns
flat out uint fragment_id;
invariant gl_Position;
void main() {
    int t = 4 * int(id);
    mat4 clip_from_local = mat4(texelFetch(transforms, t), texelFetch(transforms, t + 1),
                                texelFetch(transforms, t + 2), texelFetch(transforms, t + 3));
    gl_Position = clip_from_local * vec4(position, 1.0);
    fragment_id = id;
}
"""

_FRAGMENT_SHADER = """#version 330 core
flat in uint fragment_id;
layout(location = 0) out uint pixel_id;
void main() {
    pixel_id = fragment_id;
}
"""


def _positive(name, value):
    if isinstance(value, bool) or int(value) != value or value < 1:
        raise InputError(f"{name} must be a positive whole number of pixels, got {value!r}")
    return int(value)


def _release(GL, names):
    """Delete a counter's GL objects (finalizer; the process-wide context stays).
    A garbage collection on another thread cannot make the context current there
    (EGL_BAD_ACCESS while it is current on its own thread): the objects are then
    left to the context, which frees them when the process ends, since a finalizer
    must not raise."""
    try:
        context.make_current()
    except RenderError:
        return
    GL.glDeleteQueries(len(names["queries"]), names["queries"])
    GL.glDeleteFramebuffers(1, [names["framebuffer"]])
    GL.glDeleteRenderbuffers(2, names["renderbuffers"])
    GL.glDeleteTextures(1, [names["texture"]])
    GL.glDeleteBuffers(4, names["buffers"])
    GL.glDeleteVertexArrays(1, [names["vertex_array"]])
    GL.glDeleteProgram(names["program"])


class PixelCounter:
    """Kim 2008 §5.4: the visible pixels of every body of ``model``, occluded by the
    other bodies and by ``environment`` (a :class:`~vdad.environment.Environment`,
    drawn but not counted), at a counting resolution of ``width`` x ``height``
    pixels, by ``method`` ``"merged"`` (an id buffer) or ``"queries"`` (occlusion
    queries). Bodies without geoms count 0. Round geoms are tessellated with
    ``sections`` segments around (:meth:`~vdad.model.Geom.to_trimesh`; llvmpipe's
    cost grows with the triangle count, ``docs/visibility.md``).

    The GL objects live until :meth:`close` or until the counter is collected.
    Raises :class:`~vdad.errors.RenderError` when OpenGL/EGL is unavailable.
    """

    def __init__(self, model, environment=None, width=320, height=240, method="merged",
                 sections=8):
        check_model(model)
        if method not in METHODS:
            raise InputError(f"the counting method (counting= of view-oq) must be one of "
                             f"{METHODS}, got {method!r}")
        self.width, self.height = _positive("width", width), _positive("height", height)
        environment = check_environment(environment)
        self.model, self.environment, self.method = model, environment, method
        self.nb = model.nb
        if not (isinstance(sections, (int, np.integer)) and sections >= 3):
            raise InputError(f"sections must be a whole number >= 3, got {sections!r}")
        context.make_current()          # first: a missing extra is a RenderError with the hint
        positions, ids, indices, self._first, self._count, _ = merged_geometry(
            model, environment, int(sections))
        self._n_indices = indices.size
        self._transforms = np.zeros((self.nb + 1, 4, 4), np.float32)   # [id, column, row]
        self._image = np.zeros((self.height, self.width), np.uint32)
        self._samples = np.zeros(self.nb, np.uint32)                   # query results
        self._camera = self._clip_from_world = None                    # last camera seen

        from OpenGL import GL
        self._GL = GL
        try:
            self._names = self._create_objects(GL, positions, ids, indices)
        except GL.GLError as exc:
            raise RenderError(f"OpenGL failed while setting up the pixel counter: {exc}") from exc
        self._finalizer = weakref.finalize(self, _release, GL, self._names)
        self._finalizer.atexit = False
        # (query, index count, byte offset, result address) of each body with triangles
        self._ranges = [(self._names["queries"][i], int(self._count[i]), 4 * int(self._first[i]),
                         self._samples.ctypes.data + 4 * int(i))
                        for i in np.flatnonzero(self._count)]
        self._raw = _raw_functions() if method == "queries" else None

    def _create_objects(self, GL, positions, ids, indices):
        limit = int(GL.glGetIntegerv(GL.GL_MAX_RENDERBUFFER_SIZE))
        for name, value in (("width", self.width), ("height", self.height)):
            if value > limit:
                raise InputError(f"{name} {value} exceeds this OpenGL's largest renderbuffer, "
                                 f"{limit} pixels")
        texels = int(GL.glGetIntegerv(GL.GL_MAX_TEXTURE_BUFFER_SIZE))
        if 4 * (self.nb + 1) > texels:
            raise RenderError(f"{self.nb} bodies need {4 * (self.nb + 1)} texels of pose "
                              f"texture buffer; this OpenGL allows {texels}")
        names = dict(program=_program(GL), vertex_array=int(GL.glGenVertexArrays(1)),
                     buffers=[int(b) for b in GL.glGenBuffers(4)],
                     texture=int(GL.glGenTextures(1)),
                     framebuffer=int(GL.glGenFramebuffers(1)),
                     renderbuffers=[int(b) for b in GL.glGenRenderbuffers(2)],
                     queries=[int(q) for q in np.atleast_1d(GL.glGenQueries(self.nb))])
        position_buffer, id_buffer, index_buffer, transform_buffer = names["buffers"]
        GL.glBindVertexArray(names["vertex_array"])
        GL.glBindBuffer(GL.GL_ARRAY_BUFFER, position_buffer)
        GL.glBufferData(GL.GL_ARRAY_BUFFER, positions.nbytes, positions, GL.GL_STATIC_DRAW)
        GL.glEnableVertexAttribArray(0)
        GL.glVertexAttribPointer(0, 3, GL.GL_FLOAT, GL.GL_FALSE, 0, ctypes.c_void_p(0))
        GL.glBindBuffer(GL.GL_ARRAY_BUFFER, id_buffer)
        GL.glBufferData(GL.GL_ARRAY_BUFFER, ids.nbytes, ids, GL.GL_STATIC_DRAW)
        GL.glEnableVertexAttribArray(1)
        GL.glVertexAttribIPointer(1, 1, GL.GL_UNSIGNED_INT, 0, ctypes.c_void_p(0))
        GL.glBindBuffer(GL.GL_ELEMENT_ARRAY_BUFFER, index_buffer)
        GL.glBufferData(GL.GL_ELEMENT_ARRAY_BUFFER, indices.nbytes, indices, GL.GL_STATIC_DRAW)
        GL.glBindVertexArray(0)

        GL.glBindBuffer(GL.GL_TEXTURE_BUFFER, transform_buffer)
        GL.glBufferData(GL.GL_TEXTURE_BUFFER, self._transforms.nbytes, None, GL.GL_STREAM_DRAW)
        GL.glBindTexture(GL.GL_TEXTURE_BUFFER, names["texture"])
        GL.glTexBuffer(GL.GL_TEXTURE_BUFFER, GL.GL_RGBA32F, transform_buffer)
        GL.glUseProgram(names["program"])
        GL.glUniform1i(GL.glGetUniformLocation(names["program"], "transforms"), 0)

        colour, depth = names["renderbuffers"]
        GL.glBindRenderbuffer(GL.GL_RENDERBUFFER, colour)
        GL.glRenderbufferStorage(GL.GL_RENDERBUFFER, GL.GL_R32UI, self.width, self.height)
        GL.glBindRenderbuffer(GL.GL_RENDERBUFFER, depth)
        GL.glRenderbufferStorage(GL.GL_RENDERBUFFER, GL.GL_DEPTH_COMPONENT24, self.width,
                                 self.height)
        GL.glBindFramebuffer(GL.GL_FRAMEBUFFER, names["framebuffer"])
        GL.glFramebufferRenderbuffer(GL.GL_FRAMEBUFFER, GL.GL_COLOR_ATTACHMENT0,
                                     GL.GL_RENDERBUFFER, colour)
        GL.glFramebufferRenderbuffer(GL.GL_FRAMEBUFFER, GL.GL_DEPTH_ATTACHMENT,
                                     GL.GL_RENDERBUFFER, depth)
        status = GL.glCheckFramebufferStatus(GL.GL_FRAMEBUFFER)
        if status != GL.GL_FRAMEBUFFER_COMPLETE:
            raise RenderError(f"the pixel counter's framebuffer ({self.width} x {self.height}, "
                              f"R32UI + 24-bit depth) is incomplete: status 0x{int(status):04x}")
        return names

    def close(self):
        """Delete the counter's GL objects now (the process-wide context stays)."""
        self._finalizer()

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()

    def _upload(self, camera, R, p):
        """Check the inputs, bind the counter's GL state, upload the clip-from-local
        matrices (one texture-buffer upload) and clear the framebuffer."""
        R, p = context.check_view(camera, R, p, self.nb)
        if not self._finalizer.alive:
            raise RenderError("this PixelCounter is closed: its GL objects are deleted")
        if camera is not self._camera:
            at_resolution = camera.with_resolution(self.width, self.height)
            self._clip_from_world = at_resolution.projection @ at_resolution.view   # (4, 4)
            self._camera = camera
        clip_from_world = self._clip_from_world
        T = self._transforms                                        # (nb + 1, column, row)
        T[0] = clip_from_world.T
        T[1:, :3] = R.transpose(0, 2, 1) @ clip_from_world[:, :3].T
        T[1:, 3] = p @ clip_from_world[:, :3].T + clip_from_world[:, 3]

        GL, names = self._GL, self._names
        context.make_current()
        GL.glBindFramebuffer(GL.GL_FRAMEBUFFER, names["framebuffer"])
        GL.glViewport(0, 0, self.width, self.height)
        GL.glDisable(GL.GL_SCISSOR_TEST)
        GL.glDisable(GL.GL_CULL_FACE)
        GL.glPolygonMode(GL.GL_FRONT_AND_BACK, GL.GL_FILL)
        GL.glEnable(GL.GL_DEPTH_TEST)
        GL.glDepthFunc(GL.GL_LESS)
        GL.glDepthMask(GL.GL_TRUE)
        GL.glColorMask(GL.GL_TRUE, GL.GL_TRUE, GL.GL_TRUE, GL.GL_TRUE)
        GL.glUseProgram(names["program"])
        GL.glBindVertexArray(names["vertex_array"])
        GL.glActiveTexture(GL.GL_TEXTURE0)
        GL.glBindTexture(GL.GL_TEXTURE_BUFFER, names["texture"])
        GL.glBindBuffer(GL.GL_TEXTURE_BUFFER, names["buffers"][3])
        GL.glBufferSubData(GL.GL_TEXTURE_BUFFER, 0, T.nbytes, T)
        GL.glClearBufferfv(GL.GL_DEPTH, 0, _ONE)

    def _id_pass(self, camera, R, p):
        """Draw the id buffer and read it into ``self._image`` (height, width)."""
        GL = self._GL
        self._upload(camera, R, p)
        GL.glClearBufferuiv(GL.GL_COLOR, 0, _ZEROS)
        GL.glDrawElements(GL.GL_TRIANGLES, self._n_indices, GL.GL_UNSIGNED_INT,
                          ctypes.c_void_p(0))
        GL.glReadBuffer(GL.GL_COLOR_ATTACHMENT0)
        GL.glPixelStorei(GL.GL_PACK_ALIGNMENT, 4)
        GL.glReadPixels(0, 0, self.width, self.height, GL.GL_RED_INTEGER, GL.GL_UNSIGNED_INT,
                        self._image)
        return self._image

    def _query_pass(self, camera, R, p):
        """Depth pre-pass, then one GL_SAMPLES_PASSED query per body: counts (nb,)."""
        GL = self._GL
        self._upload(camera, R, p)
        GL.glColorMask(GL.GL_FALSE, GL.GL_FALSE, GL.GL_FALSE, GL.GL_FALSE)
        GL.glDrawElements(GL.GL_TRIANGLES, self._n_indices, GL.GL_UNSIGNED_INT,
                          ctypes.c_void_p(0))
        GL.glDepthMask(GL.GL_FALSE)
        GL.glDepthFunc(GL.GL_LEQUAL)
        begin, end, draw, result = self._raw
        samples, triangles, uint = _SAMPLES_PASSED, _TRIANGLES, _UNSIGNED_INT
        for query, count, offset, _ in self._ranges:
            begin(samples, query)
            draw(triangles, count, uint, offset)
            end(samples)
        GL.glColorMask(GL.GL_TRUE, GL.GL_TRUE, GL.GL_TRUE, GL.GL_TRUE)
        GL.glDepthMask(GL.GL_TRUE)
        for query, _, _, address in self._ranges:
            result(query, _QUERY_RESULT, address)
        return self._samples.astype(np.int64)

    def counts(self, camera, R, p) -> np.ndarray:
        """Visible pixels (nb,) int64 of each body posed at ``R`` (nb, 3, 3), ``p``
        (nb, 3) (world frame) seen by ``camera`` at the counter's resolution."""
        try:
            if self.method == "merged":
                counts = np.empty(self.nb, np.int64)
                id_counts_pass(self._id_pass(camera, R, p), counts)
                return counts
            return self._query_pass(camera, R, p)
        except self._GL.GLError as exc:
            raise RenderError(f"OpenGL failed while counting pixels: {exc}") from exc

    def id_image(self, camera, R, p) -> np.ndarray:
        """The merged pass's id image (height, width) uint32, rows from the bottom:
        0 where nothing or the environment is seen, ``i + 1`` where body ``i`` is."""
        try:
            return self._id_pass(camera, R, p).copy()
        except self._GL.GLError as exc:
            raise RenderError(f"OpenGL failed while drawing the id image: {exc}") from exc


_ONE = np.ones(1, np.float32)           # depth clear value
_ZEROS = np.zeros(4, np.uint32)         # id clear value
_TRIANGLES, _UNSIGNED_INT = 0x0004, 0x1405
_SAMPLES_PASSED, _QUERY_RESULT = 0x8914, 0x8866


def _raw_functions():
    """Bare ctypes bindings of glBeginQuery, glEndQuery, glDrawElements and
    glGetQueryObjectuiv for the per-body loop: PyOpenGL's wrappers cost about
    5 µs a call, which tripled the time of the queries at 1600 bodies. Errors
    they raise surface at the next PyOpenGL call, which checks glGetError."""
    import OpenGL.platform

    def bind(name, *argtypes):
        address = OpenGL.platform.PLATFORM.getExtensionProcedure(name.encode())
        if not address:
            raise RenderError(f"this OpenGL has no {name}")
        return ctypes.CFUNCTYPE(None, *argtypes)(address)

    uint, sizei, pointer = ctypes.c_uint, ctypes.c_int, ctypes.c_void_p
    return (bind("glBeginQuery", uint, uint), bind("glEndQuery", uint),
            bind("glDrawElements", uint, sizei, uint, pointer),
            bind("glGetQueryObjectuiv", uint, uint, pointer))


def _program(GL):
    """Compile and link the id program, or raise RenderError with the GL log."""
    shaders = []
    for kind, source in ((GL.GL_VERTEX_SHADER, _VERTEX_SHADER),
                         (GL.GL_FRAGMENT_SHADER, _FRAGMENT_SHADER)):
        shader = GL.glCreateShader(kind)
        GL.glShaderSource(shader, source)
        GL.glCompileShader(shader)
        if not GL.glGetShaderiv(shader, GL.GL_COMPILE_STATUS):
            log = GL.glGetShaderInfoLog(shader).decode(errors="replace")
            raise RenderError(f"the pixel counter's shader does not compile: {log}")
        shaders.append(shader)
    program = GL.glCreateProgram()
    for shader in shaders:
        GL.glAttachShader(program, shader)
    GL.glLinkProgram(program)
    for shader in shaders:
        GL.glDeleteShader(shader)
    if not GL.glGetProgramiv(program, GL.GL_LINK_STATUS):
        log = GL.glGetProgramInfoLog(program).decode(errors="replace")
        raise RenderError(f"the pixel counter's shaders do not link: {log}")
    return int(program)
