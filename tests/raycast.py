"""Pixel coverage by ray casting (an independent path for projected areas): a pixel
counts when the ray through its centre leaves the volume at depth >= znear, which is
what a rasteriser covers drawing the volume's surface without back-face culling."""

import numpy as np


def pixel_rays(camera):
    """Ray directions (H*W, 3) in camera coordinates through pixel centres, depth 1."""
    x, y = np.meshgrid(np.arange(camera.width) + 0.5, np.arange(camera.height) + 0.5)
    f = camera.focal
    return np.stack([(x - camera.width / 2) / f, (y - camera.height / 2) / f,
                     -np.ones_like(x)], axis=-1).reshape(-1, 3)


def sphere_pixels(camera, C, r):
    """Pixels covered by the sphere of centre ``C`` (camera frame) and radius ``r``."""
    u = pixel_rays(camera)
    a, b, c = np.sum(u * u, axis=1), u @ C, C @ C - r * r
    disc = b * b - a * c
    t_out = (b + np.sqrt(np.maximum(disc, 0))) / a        # depth of the exit point
    return int(np.sum((disc > 0) & (t_out >= camera.znear)))


def box_pixels(camera, c, R, h):
    """Pixels covered by the box of centre ``c``, axes ``R``, half-extents ``h``
    (camera frame), by the slab method."""
    u = pixel_rays(camera) @ R
    o = -c @ R
    with np.errstate(divide="ignore", invalid="ignore"):
        t1, t2 = (-h - o) / u, (h - o) / u
    t_in = np.nanmax(np.minimum(t1, t2), axis=1)
    t_out = np.nanmin(np.maximum(t1, t2), axis=1)
    return int(np.sum((t_in <= t_out) & (t_out >= camera.znear)))
