"""Pictures of a simulation (Kim 2008 Figures 1-2, 8-9): bodies coloured by rigid group,
active joints marked, rendered offscreen with pyrender on the process-wide EGL context.

* :func:`rigid_groups`, :func:`active_joints`: what a frame shows of the adaptive
  state (the rigid group of every body, the joints that still move);
* :func:`palette`: distinct colours, one per group or body;
* :class:`SceneRenderer`: a model and its environment as a pyrender scene, built
  and uploaded once, posed and coloured per frame;
* :func:`record`: step a simulator and render a frame every few steps;
* :func:`motion_strip`, :func:`write`: frames side by side, and to PNG, GIF or MP4.

Only :class:`SceneRenderer` and :func:`record` need pyrender and OpenGL (imported on
first use); the rest needs numpy, and Pillow (or imageio for MP4) to draw labels and
write files.
"""

from __future__ import annotations

import colorsys
import math
import weakref
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..camera import camera_at
from ..environment import check_environment
from ..errors import InputError, RenderError
from ..model import check_model
from . import context

COLORS = ("group", "body", "geom")
SUFFIXES = (".png", ".gif", ".mp4")
MARKER_RGB = (255, 0, 0)          # active-joint markers; palette() never gives it
BACKGROUND = (255, 255, 255)
VIDEO_HINT = "MP4 needs imageio and imageio-ffmpeg: pip install 'vdad[video]'"

_GOLDEN = (math.sqrt(5) - 1) / 2


# --- what a frame shows ------------------------------------------------------------


def _simulator(sim):
    from ..simulator import Simulator

    if not isinstance(sim, Simulator):
        raise InputError(f"sim must be a vdad.Simulator, got {type(sim).__name__}")
    return sim


def rigid_groups(sim) -> np.ndarray:
    """Kim 2008 §4 (hybrid bodies): the rigid group of every body, (nb,) int.

    Bodies welded together by rigid joints share a label (a group welded to the
    world is one group too); labels are 0 .. G-1 in order of each group's first
    body. Exact dynamics (``"dca"``) and an adaptive simulator before its first
    step give every body its own group.
    """
    sim = _simulator(sim)
    nb = sim.model.nb
    if sim.adaptive is None:
        return np.arange(nb)
    front = sim.adaptive.groups.pose_in_group(np.arange(nb), sim.adaptive.active)[0]
    _, first, inverse = np.unique(front, return_index=True, return_inverse=True)
    rank = np.empty(len(first), int)
    rank[np.argsort(first, kind="stable")] = np.arange(len(first))
    return rank[inverse.ravel()]


def active_joints(sim) -> np.ndarray:
    """Model ids (sorted) of the joints that move: all of them with ``"dca"`` or
    before the first adaptive step, otherwise the adaptive active region's."""
    sim = _simulator(sim)
    if sim.adaptive is None:
        return np.arange(sim.model.nb)
    return np.asarray(sim.adaptive.joints, int)


def palette(n) -> np.ndarray:
    """``n`` distinct colours (n, 3) uint8, one per group or body (deterministic;
    ``palette(m)`` starts with ``palette(n)`` for ``m > n``).

    Hues step by the golden ratio (so that neighbours differ most), skipping the
    reds kept for the active-joint markers; saturation and value cycle through
    three and four levels. Rows are pairwise distinct for any ``n`` (a clash after
    rounding to 8 bits is moved by one unit of its brightest channel), never
    white, grey or pure red.
    """
    n = _whole("the number of colours", n, 0)
    i = np.arange(n)
    hue = 0.07 + 0.86 * ((0.11 + i * _GOLDEN) % 1.0)
    sat = np.array([0.85, 0.6, 0.72])[i % 3]
    val = np.array([0.92, 0.72, 0.82, 0.62])[(i // 3) % 4]
    rgb = np.array([colorsys.hsv_to_rgb(h, s, v) for h, s, v in zip(hue, sat, val, strict=True)])
    out = np.rint(255 * rgb.reshape(n, 3)).astype(np.int64)
    seen = set()
    for k in range(n):
        key = tuple(out[k])
        top = int(np.argmax(out[k]))
        while key in seen:
            out[k, top] -= 1
            key = tuple(out[k])
        seen.add(key)
    return out.astype(np.uint8)


# --- the renderer ------------------------------------------------------------------


def _whole(name, value, minimum=1):
    """``value`` as an int, or InputError unless it is a whole number >= ``minimum``."""
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < minimum:
        raise InputError(f"{name} must be a whole number >= {minimum}, got {value!r}")
    return int(value)


def _release(renderer):
    """Free a SceneRenderer's GL objects (finalizer; the process-wide context stays)."""
    try:
        context.make_current()
    except RenderError:
        return
    renderer.delete()


def _primitive(pyrender, mesh, smooth, material):
    """A pyrender primitive of trimesh ``mesh`` without its visual colours (so that
    the material alone gives the colour): smooth or per-face normals."""
    if smooth:
        positions, normals, faces = mesh.vertices, mesh.vertex_normals, mesh.faces
    else:
        positions = mesh.vertices[mesh.faces.ravel()]
        normals = np.repeat(mesh.face_normals, 3, axis=0)
        faces = np.arange(len(positions)).reshape(-1, 3)
    return pyrender.Primitive(positions=np.asarray(positions, np.float32),
                              normals=np.asarray(normals, np.float32),
                              indices=np.asarray(faces, np.uint32), material=material)


def _material(pyrender, rgba):
    return pyrender.MetallicRoughnessMaterial(baseColorFactor=np.array(rgba, float),
                                              metallicFactor=0.0, roughnessFactor=0.7)


class SceneRenderer:
    """Kim 2008 Figures 1-2, 8-9: ``model`` and its ``environment`` drawn at ``width``
    x ``height`` pixels with pyrender, on the process-wide EGL context
    (:func:`vdad.render.context.gl_context`) through a pyrender renderer of its own.

    The scene is built and its geometry uploaded once: one mesh node per body and
    geom colour (round geoms tessellated with ``sections`` segments), the
    environment as static nodes, a head light and ambient light, white background.
    :meth:`render` only moves nodes and changes material colours.
    Active-joint markers are red spheres of ``marker_radius`` (default 2 % of the
    model's extent in its neutral configuration, at most a quarter of the median
    body's size). The GL objects live until :meth:`close` or until the renderer is
    collected.
    """

    def __init__(self, model, environment=None, width=640, height=480, sections=16,
                 marker_radius=None):
        check_model(model)
        environment = check_environment(environment)
        self.width, self.height = _whole("width", width), _whole("height", height)
        sections = _whole("sections", sections, 3)
        self.model, self.environment, self.nb = model, environment, model.nb
        context.gl_context()            # first: a missing extra is a RenderError with the hint
        meshes = [[(g, g.to_trimesh(sections)) for g in body.geoms]
                  for body in model.bodies]
        if marker_radius is None:
            marker_radius = _marker_radius(model, meshes)
        if not (isinstance(marker_radius, (int, float, np.integer, np.floating))
                and np.isfinite(marker_radius) and marker_radius > 0):
            raise InputError(f"marker_radius must be a positive length, got {marker_radius!r}")
        self.marker_radius = float(marker_radius)

        import pyrender
        import trimesh

        self._pyrender = pyrender
        scene = pyrender.Scene(bg_color=np.array([*np.array(BACKGROUND) / 255, 1.0]),
                               ambient_light=np.full(3, 0.35))
        # per body: (node, material, geom rgba) of each group of geoms of one colour
        self._parts = []
        for geoms in meshes:
            groups = {}
            for g, mesh in geoms:
                groups.setdefault(tuple(float(c) for c in g.rgba), []).append((g.kind, mesh))
            parts = []
            for rgba, items in groups.items():
                material = _material(pyrender, rgba)
                primitives = []
                for smooth in (True, False):
                    chosen = [m for kind, m in items if (kind in ("sphere", "capsule")) == smooth]
                    if chosen:
                        primitives.append(_primitive(pyrender, trimesh.util.concatenate(chosen),
                                                     smooth, material))
                node = scene.add(pyrender.Mesh(primitives))
                parts.append((node, material, np.array(rgba)))
            self._parts.append(parts)
        self._static = {}                         # environment node -> rgb uint8
        for g in environment.geoms:
            node = scene.add(pyrender.Mesh([_primitive(pyrender, g.to_trimesh(sections),
                                                       g.kind in ("sphere", "capsule"),
                                                       _material(pyrender, g.rgba))]))
            self._static[node] = _rgb(g.rgba)
        self._camera = pyrender.PerspectiveCamera(yfov=np.pi / 3,
                                                  aspectRatio=self.width / self.height)
        self._camera_node = scene.add(self._camera)
        light = pyrender.DirectionalLight(color=np.ones(3), intensity=2.5)
        # a head light, from above left of the viewer
        tilt = trimesh.transformations.euler_matrix(0.35, -0.35, 0.0)
        scene.add(light, pose=tilt, parent_node=self._camera_node)
        self._marker_mesh = trimesh.creation.icosphere(subdivisions=2, radius=self.marker_radius)
        self._marker_material = _material(pyrender, (*np.array(MARKER_RGB) / 255, 1.0))
        self._marker_node = None                  # rebuilt at every render with markers
        self._scene = scene

        context.make_current()
        self._renderer = pyrender.Renderer(self.width, self.height)
        self._finalizer = weakref.finalize(self, _release, self._renderer)
        self._finalizer.atexit = False

    def close(self):
        """Free this renderer's scene buffers, shaders and framebuffers now (the
        process-wide context and its ``OffscreenRenderer`` stay)."""
        self._finalizer()

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()

    def _markers(self, points):
        """A node of one sphere instanced at every point (one draw, a small upload)."""
        poses = np.broadcast_to(np.eye(4), (len(points), 4, 4)).copy()
        poses[:, :3, 3] = points
        mesh = self._marker_mesh
        primitive = self._pyrender.Primitive(
            positions=np.asarray(mesh.vertices, np.float32),
            normals=np.asarray(mesh.vertex_normals, np.float32),
            indices=np.asarray(mesh.faces, np.uint32), material=self._marker_material,
            poses=poses)
        return self._scene.add(self._pyrender.Mesh([primitive]))

    def render(self, camera, R, p, colors=None, markers=None, flat=False) -> np.ndarray:
        """The bodies posed at ``R`` (nb, 3, 3), ``p`` (nb, 3) (world frame) seen by
        ``camera`` (its pose, ``yfov`` and planes; the aspect is the renderer's):
        an image (height, width, 3) uint8, row 0 at the top.

        colors: (nb, 3) uint8 colour of every body, or None for the geoms' own.
        markers: world points (k, 3) drawn as red spheres (the active joints).
        flat: no lighting and no antialiasing: every pixel is exactly the colour of
        the body, environment geom or marker it shows, or white (pyrender's
        segmentation pass; its ``RenderFlags.FLAT`` keeps the 4x multisampling,
        whose edge blends outnumber the exact pixels of thin links).
        """
        R, p = context.check_view(camera, R, p, self.nb)
        if colors is not None:
            colors = np.asarray(colors)
            if colors.shape != (self.nb, 3) or not np.issubdtype(colors.dtype, np.integer) or (
                    colors.size and (colors.min() < 0 or colors.max() > 255)):
                raise InputError(f"colors must be ({self.nb}, 3) whole numbers in 0..255 "
                                 f"(uint8), got shape {colors.shape}, dtype {colors.dtype}")
        markers = np.zeros((0, 3)) if markers is None else np.asarray(markers, dtype=float)
        if markers.ndim != 2 or markers.shape[1] != 3 or not np.isfinite(markers).all():
            raise InputError(f"markers must be finite world points (k, 3), got shape "
                             f"{markers.shape}")
        if not self._finalizer.alive:
            raise RenderError("this SceneRenderer is closed: its GL objects are deleted")

        scene, seg = self._scene, {}
        T = np.zeros((self.nb, 4, 4))
        T[:, :3, :3], T[:, :3, 3], T[:, 3, 3] = R, p, 1.0
        for i, parts in enumerate(self._parts):
            for node, material, rgba in parts:
                scene.set_pose(node, T[i])
                rgb = _rgb(rgba) if colors is None else colors[i].astype(np.uint8)
                material.baseColorFactor = np.array([*(rgb / 255.0), rgba[3]])
                seg[node] = rgb
        if self._marker_node is not None:           # its buffers go at the next draw
            scene.remove_node(self._marker_node)
            self._marker_node = None
        if len(markers):
            self._marker_node = self._markers(markers)
            seg[self._marker_node] = np.array(MARKER_RGB, np.uint8)
        seg.update(self._static)
        cam = self._camera
        cam.yfov, cam.znear, cam.zfar = float(camera.yfov), float(camera.znear), float(
            camera.zfar)
        scene.set_pose(self._camera_node, camera.pose)

        flags = self._pyrender.RenderFlags
        try:
            context.make_current()
            if flat:
                color, depth = self._renderer.render(scene, flags.OFFSCREEN | flags.SEG, seg)
            else:
                color, _ = self._renderer.render(scene, flags.OFFSCREEN)
        except Exception as exc:
            raise RenderError(f"pyrender failed to draw the scene ({type(exc).__name__}: "
                              f"{exc})") from exc
        image = np.array(color)
        if flat:
            image[depth == 0] = BACKGROUND        # segmentation clears to black
        return image


def _rgb(rgba):
    return np.rint(255 * np.clip(np.asarray(rgba, float)[:3], 0, 1)).astype(np.uint8)


def _marker_radius(model, meshes):
    """2 % of the diagonal of the bounding box of the model's geoms (and body origins)
    in its neutral configuration, at most a quarter of the median body's diagonal,
    0.02 for a model with no extent."""
    from ..kinematics import body_poses, joint_kinematics, plan

    js = plan(model)
    R, p = body_poses(js, *joint_kinematics(js, np.asarray(model.q_neutral, float))[:2])
    points = [p]
    for i, geoms in enumerate(meshes):
        for _, mesh in geoms:
            points.append(mesh.bounds @ R[i].T + p[i])
    points = np.concatenate(points)
    radius = 0.02 * float(np.linalg.norm(points.max(axis=0) - points.min(axis=0)))
    bodies = [np.linalg.norm(np.ptp(np.concatenate([m.bounds for _, m in geoms]), axis=0))
              for geoms in meshes if geoms]
    if bodies and np.median(bodies) > 0:
        radius = min(radius, 0.25 * float(np.median(bodies)))
    return radius if radius > 0 else 0.02


# --- recording ---------------------------------------------------------------------


@dataclass(frozen=True, eq=False)
class Frame:
    """One rendered frame: the ``image`` (height, width, 3) uint8 at time ``t`` after
    ``step`` steps, the rigid group of every body ``groups`` (nb,) and their number
    ``n_groups``, and the model ids of the ``active`` joints."""

    image: np.ndarray
    t: float
    step: int
    n_groups: int
    groups: np.ndarray
    active: np.ndarray


def record(sim, steps, every=1, renderer=None, camera=None, color="group", show_active=False,
           flat=False, progress=False) -> list:
    """Kim 2008 Figures 1-2: step ``sim`` ``steps`` times and render a frame before
    the first step and after every ``every`` steps (a last partial stretch is
    stepped but not rendered); returns the :class:`Frame` list.

    renderer: a :class:`SceneRenderer` of ``sim.model`` (default: a new one at the
    camera's resolution with ``sim.environment``, closed at the end).
    camera: a :class:`~vdad.camera.Camera` or a path ``t -> Camera`` (default
    ``sim.camera``), evaluated at each frame's time at the renderer's resolution.
    color: ``"group"`` (one colour per rigid group, :func:`rigid_groups`),
    ``"body"`` (one per body) or ``"geom"`` (the geoms' own colours).
    show_active: mark the active joints (:func:`active_joints`) with red spheres at
    their child bodies' origins. flat: unlit, unantialiased colours
    (:meth:`SceneRenderer.render`). progress: a progress bar on stderr.
    """
    sim = _simulator(sim)
    steps, every = _whole("steps", steps, 0), _whole("every", every)
    if color not in COLORS:
        raise InputError(f"color must be one of {COLORS}, got {color!r}")
    path = sim.camera if camera is None else camera
    if path is None:
        raise InputError("record needs a camera: pass camera= or give the simulator one")
    if renderer is not None and not isinstance(renderer, SceneRenderer):
        raise InputError(f"renderer must be a SceneRenderer, got {type(renderer).__name__}")
    if renderer is not None and renderer.model is not sim.model:
        raise InputError("the renderer was built for another model than the simulator's")
    own = renderer is None
    if own:
        first = camera_at(path, sim.t)
        renderer = SceneRenderer(sim.model, sim.environment, first.width, first.height)
    from tqdm import tqdm

    frames = []
    body_colors = palette(sim.model.nb)

    def snapshot():
        R, p = sim.body_poses()
        groups = rigid_groups(sim)
        n_groups = int(groups.max()) + 1 if len(groups) else 0
        active = active_joints(sim)
        colors = {"group": palette(n_groups)[groups], "body": body_colors, "geom": None}[color]
        view = camera_at(path, sim.t).with_resolution(renderer.width, renderer.height)
        image = renderer.render(view, R, p, colors, p[active] if show_active else None, flat)
        frames.append(Frame(image, sim.t, sim.step_count, n_groups, groups, active))

    try:
        snapshot()
        with tqdm(total=steps, unit="step", disable=not progress) as bar:
            done = 0
            while done < steps:
                n = min(every, steps - done)
                sim.step(n)
                done += n
                bar.update(n)
                if n == every:
                    snapshot()
    finally:
        if own:
            renderer.close()
    return frames


# --- images and files --------------------------------------------------------------


def _image(item, name="image"):
    """An (h, w, 3) uint8 array from an image (h, w), (h, w, 3|4) uint8 or a Frame."""
    image = np.asarray(item.image if isinstance(item, Frame) else item)
    if image.dtype != np.uint8 or image.ndim not in (2, 3) or (
            image.ndim == 3 and image.shape[2] not in (3, 4)) or 0 in image.shape[:2]:
        raise InputError(f"{name} must be a Frame or a uint8 array (h, w), (h, w, 3) or "
                         f"(h, w, 4), got {image.dtype} {image.shape}")
    if image.ndim == 2:
        return np.repeat(image[:, :, None], 3, axis=2)
    return image[:, :, :3]


def _images(items):
    if isinstance(items, (np.ndarray, Frame)):
        items = [items]
    items = list(items)
    if not items:
        raise InputError("no images given")
    return [_image(item, f"image {k}") for k, item in enumerate(items)]


def _pillow():
    try:
        from PIL import Image, ImageDraw, ImageFont
    except ImportError as exc:
        raise InputError("pictures need Pillow: pip install pillow") from exc
    return Image, ImageDraw, ImageFont


def motion_strip(images, columns=None, gap=4, labels=None) -> np.ndarray:
    """Kim 2008 Figures 1-2: ``images`` (arrays or :class:`Frame`) side by side,
    ``columns`` to a row (default: all in one row), ``gap`` white pixels apart, each
    with its label (e.g. ``"t = 0.50 s"``) under it in Pillow's default font.
    Columns are as wide as their widest image and rows as tall as their tallest."""
    images = _images(images)
    n = len(images)
    columns = n if columns is None else _whole("columns", columns)
    gap = _whole("gap", gap, 0)
    if labels is not None:
        labels = [str(s) for s in labels]
        if len(labels) != n:
            raise InputError(f"{n} images but {len(labels)} labels")
    rows = -(-n // columns)
    cell = [(k // columns, k % columns) for k in range(n)]
    width = np.zeros(min(columns, n), int)
    height = np.zeros(rows, int)
    for (r, c), image in zip(cell, images, strict=True):
        width[c] = max(width[c], image.shape[1])
        height[r] = max(height[r], image.shape[0])
    band, font = 0, None
    if labels is not None:
        Image, ImageDraw, ImageFont = _pillow()
        font = ImageFont.load_default()
        probe = ImageDraw.Draw(Image.new("RGB", (1, 1)))
        band = max(probe.textbbox((0, 0), s or " ", font=font)[3] for s in labels) + 6
    x0 = np.concatenate([[0], np.cumsum(width + gap)])
    y0 = np.concatenate([[0], np.cumsum(height + band + gap)])
    out = np.full((y0[-1] - gap, x0[-1] - gap, 3), 255, np.uint8)
    for (r, c), image in zip(cell, images, strict=True):
        h, w = image.shape[:2]
        out[y0[r]:y0[r] + h, x0[c]:x0[c] + w] = image
    if labels is not None:
        picture = Image.fromarray(out)
        draw = ImageDraw.Draw(picture)
        for (r, c), image, text in zip(cell, images, labels, strict=True):
            left, _, right, _ = draw.textbbox((0, 0), text, font=font)
            x = x0[c] + (image.shape[1] - (right - left)) / 2 - left
            draw.text((x, y0[r] + image.shape[0] + 3), text, fill=(0, 0, 0), font=font)
        out = np.asarray(picture).copy()
    return out


def check_output(path) -> Path:
    """``path`` as a Path that :func:`write` can write: one of :data:`SUFFIXES`,
    in an existing folder; else an InputError (checked before a run, too)."""
    path = Path(path)
    if path.suffix.lower() not in SUFFIXES:
        raise InputError(f"cannot write {str(path)!r}: the suffix must be one of "
                         f"{', '.join(SUFFIXES)}")
    if not path.parent.is_dir():
        raise InputError(f"cannot write {str(path)!r}: folder {str(path.parent)!r} does not "
                         f"exist")
    return path


def write(frames_or_images, path, fps=30) -> list:
    """Write frames (:class:`Frame` or images) by the suffix of ``path``: ``.png``
    one image to ``path``, several to ``STEM_0000.png``, ``STEM_0001.png``, ...;
    ``.gif`` an animation looping forever at ``fps`` frames per second (Pillow,
    which merges identical consecutive frames into one of their total duration);
    ``.mp4`` an H.264 video (imageio with imageio-ffmpeg; odd sizes padded with a
    white row or column). Returns the paths written."""
    images = _images(frames_or_images)
    path = check_output(path)
    suffix = path.suffix.lower()
    if not (isinstance(fps, (int, float, np.integer, np.floating)) and not isinstance(
            fps, bool) and np.isfinite(fps) and fps > 0):
        raise InputError(f"fps must be a positive number, got {fps!r}")
    if suffix != ".png" and len({image.shape for image in images}) > 1:
        raise InputError(f"the frames of a {suffix} must all have the same size, got "
                         f"{sorted({image.shape[:2] for image in images})}")
    if suffix == ".mp4":
        return [_write_mp4(images, path, fps)]
    Image = _pillow()[0]
    pictures = [Image.fromarray(image) for image in images]
    if suffix == ".gif":
        pictures[0].save(path, save_all=True, append_images=pictures[1:],
                         duration=1000.0 / fps, loop=0)
        return [path]
    if len(pictures) == 1:
        pictures[0].save(path)
        return [path]
    paths = [path.with_name(f"{path.stem}_{k:04d}{path.suffix}") for k in range(len(pictures))]
    for picture, name in zip(pictures, paths, strict=True):
        picture.save(name)
    return paths


def _write_mp4(images, path, fps):
    try:
        import imageio.v2 as imageio
        import imageio_ffmpeg  # noqa: F401
    except ImportError as exc:
        raise InputError(VIDEO_HINT) from exc
    h, w = images[0].shape[:2]
    pad = ((0, h % 2), (0, w % 2), (0, 0))
    try:
        with imageio.get_writer(path, format="FFMPEG", mode="I", fps=float(fps),
                                codec="libx264", pixelformat="yuv420p",
                                macro_block_size=1) as writer:
            for image in images:
                writer.append_data(np.pad(image, pad, constant_values=255))
    except (OSError, RuntimeError) as exc:
        raise InputError(f"cannot write {str(path)!r} with ffmpeg: {exc}") from exc
    return path
