"""The camera and camera paths (vdad.camera): bad input is refused by name."""

import numpy as np
import pytest

from vdad.camera import Camera, Dolly, Keyframes, Orbit, camera_at, check_resolution
from vdad.errors import InputError


@pytest.mark.parametrize("options, match", [
    (dict(position="abc"), "camera position must be a real number"),
    (dict(position=(1, 2)), r"camera position must have shape \(3,\)"),
    (dict(target=(0, np.nan, 0)), "camera target has non-finite entries"),
    (dict(up=(0, 0, 0)), "camera up must be a nonzero vector"),
    (dict(yfov="1"), "camera yfov must be a real number"),
    (dict(yfov=None), "camera yfov must be a real number"),
    (dict(yfov=(1.0,)), "camera yfov must be a single number"),
    (dict(yfov=np.pi), r"camera yfov must be in \(0, pi\)"),
    (dict(yfov=np.nan), "camera yfov must be finite"),
    (dict(width=None), "camera width must be a positive whole number of pixels, got None"),
    (dict(height=(240,)), "camera height must be a positive whole number of pixels"),
    (dict(width=np.nan), "camera width must be a positive whole number of pixels, got nan"),
    (dict(width=np.inf), "camera width must be a positive whole number of pixels, got inf"),
    (dict(width=True), "camera width must be a positive whole number of pixels, got True"),
    (dict(width=320.5), "camera width must be a positive whole number of pixels"),
    (dict(height=0), "camera height must be a positive whole number of pixels"),
    (dict(znear="0.1"), "camera znear must be a real number"),
    (dict(zfar=None), "camera zfar must be a real number"),
    (dict(znear=2.0, zfar=1.0), "0 < znear < zfar"),
    (dict(zfar=np.inf), "camera zfar must be finite"),
])
def test_bad_camera_is_refused_by_name(options, match):
    with np.errstate(all="raise"), pytest.raises(InputError, match=match):
        Camera(**options)


def test_camera_geometry_errors_give_no_floating_point_warnings():
    with np.errstate(all="raise"):
        with pytest.raises(InputError, match="camera up must be a nonzero vector"):
            Camera(up=(0, 0, 0))
        with pytest.raises(InputError, match="camera up .* is parallel"):
            Camera(up=(1e-300, 0, 0))
        with pytest.raises(InputError, match="camera target must differ from its position"):
            Camera(position=(1, 2, 3), target=(1, 2, 3))
        with pytest.raises(InputError, match="camera target .* too far from its position"):
            Camera(position=(1e308, 0, 0), target=(-1e308, 0, 0))
        tiny = Camera(up=(0, 0, 1e-300))                    # a tiny up is still a direction
        np.testing.assert_allclose(tiny.rotation, Camera().rotation)


def test_camera_is_stored_as_plain_numbers():
    cam = Camera(position=np.array([1, 2, 3]), width=np.int64(64), height=48.0, yfov=1)
    assert cam.position == (1.0, 2.0, 3.0) and cam.target == (0.0, 0.0, 0.0)
    assert type(cam.width) is int and type(cam.height) is int and cam.height == 48
    assert type(cam.yfov) is float and cam == Camera(position=(1, 2, 3), width=64, height=48,
                                                     yfov=1.0)
    assert cam.with_resolution(32, 24).width == 32
    with pytest.raises(InputError, match="camera width must be a positive whole number"):
        cam.with_resolution("32", 24)


def test_project_checks_points():
    cam = Camera()
    with pytest.raises(InputError, match="points must be a real number"):
        cam.project("abc")
    with pytest.raises(InputError, match=r"points must have shape \(\.\.\., 3\)"):
        cam.project([1.0, 2.0])
    with pytest.raises(InputError, match="points must be a real number"):
        cam.to_camera([[0, 0, None]])
    xy, d = cam.project([[0, 0, 0], [0, 0, 0]])
    np.testing.assert_allclose(xy, [[160, 120]] * 2)
    np.testing.assert_allclose(d, [3.0, 3.0])


def test_dolly_checks_on_construction():
    cam = Camera()
    with pytest.raises(InputError, match="dolly speed must be a real number"):
        Dolly(cam, "fast")
    with pytest.raises(InputError, match="dolly speed must be finite"):
        Dolly(cam, np.nan)
    with pytest.raises(InputError, match="dolly start must be a real number"):
        Dolly(cam, 1, start="0")
    with pytest.raises(InputError, match="dolly camera must be a vdad.camera.Camera, got str"):
        Dolly("cam", 1)
    with pytest.raises(InputError, match="camera path time t must be a real number"):
        Dolly(cam, 1)("1")
    path = Dolly(cam, 1, start=1)
    assert path.speed == 1.0 and path(0.5) == cam
    assert camera_at(path, 2.0).position == pytest.approx((4.0, 0.0, 0.0))


def test_orbit_checks_on_construction():
    cam = Camera()
    with pytest.raises(InputError, match="orbit period must be a real number"):
        Orbit(cam, "1")
    with pytest.raises(InputError, match="orbit period must be a non-zero number"):
        Orbit(cam, 0)
    with pytest.raises(InputError, match="orbit period must be finite"):
        Orbit(cam, np.inf)
    with pytest.raises(InputError, match="orbit camera must be a vdad.camera.Camera, got str"):
        Orbit("cam", 1)
    with pytest.raises(InputError, match="camera path time t must be finite"):
        Orbit(cam, 1)(np.nan)
    np.testing.assert_allclose(Orbit(cam, 4)(1).position, (0.0, 3.0, 0.0), atol=1e-12)


@pytest.mark.parametrize("seed", range(4))
def test_dolly_and_orbit_cameras_equal_checked_cameras_at_their_positions(seed):
    """The paths build their cameras unchecked, with axes carried over (dolly) or
    turned about ``up`` (orbit): equal to a Camera checked and built from
    scratch at the same position, and a dolly leaving the finite numbers fails."""
    rng = np.random.default_rng(seed)
    cam = Camera(position=tuple(rng.normal(size=3) * 5), target=tuple(rng.normal(size=3)),
                 up=tuple(rng.normal(size=3)), yfov=0.8, width=64, height=48)
    for path in (Dolly(cam, rng.normal() * 3), Orbit(cam, rng.uniform(0.5, 3.0))):
        for t in rng.uniform(0, 4, 3):
            moved = path(t)
            checked = Camera(position=moved.position, target=cam.target, up=cam.up,
                             yfov=cam.yfov, width=cam.width, height=cam.height)
            assert moved == checked and isinstance(moved.position[0], float)
            np.testing.assert_allclose(moved.rotation, checked.rotation, atol=1e-12)
            np.testing.assert_allclose(moved.view, checked.view, atol=1e-10)
            assert not moved.rotation.flags.writeable
    with pytest.raises(InputError, match="camera path left the finite numbers"):
        Dolly(cam, 1e308)(1e10)


def test_keyframes_check_times_and_cameras():
    a, b = Camera(), Camera(position=(5, 0, 0))
    with pytest.raises(InputError, match="keyframe times must be a sequence of numbers, got 5"):
        Keyframes(5, (a,))
    with pytest.raises(InputError, match="keyframe times must be a real number"):
        Keyframes(("a",), (a,))
    with pytest.raises(InputError, match="keyframe camera 0 must be a vdad.camera.Camera"):
        Keyframes((0, 1), ("a", "b"))
    with pytest.raises(InputError, match="keyframe cameras must be a tuple"):
        Keyframes((0,), a)
    with pytest.raises(InputError, match="as many times as cameras"):
        Keyframes((0, 1), (a,))
    with pytest.raises(InputError, match="as many times as cameras"):
        Keyframes((), ())
    with pytest.raises(InputError, match="keyframe times must be finite and increasing"):
        Keyframes((0, 0), (a, b))
    with pytest.raises(InputError, match="keyframe times must be finite and increasing"):
        Keyframes((0, np.nan), (a, b))
    path = Keyframes(np.array([0, 2]), [a, b])
    assert path.times == (0.0, 2.0) and path.cameras == (a, b)
    assert path(1).position == pytest.approx((4.0, 0.0, 0.0))
    with pytest.raises(InputError, match="camera path time t"):
        path(None)


@pytest.mark.parametrize("resolution, match", [
    ((320,), "resolution must be"), ("320x240", "resolution must be"),
    ((320, 240, 3), "resolution must be"), ({320: 240}, "resolution must be"),
    (np.array(320), "resolution must be"), (320, "resolution must be"),
    ((0, 240), "resolution width must be a positive whole number"),
    ((320.5, 240), "resolution width must be a positive whole number"),
    ((True, 240), "resolution width must be a positive whole number"),
    ((320, "240"), "resolution height must be a positive whole number"),
    ((320, np.nan), "resolution height must be a positive whole number"),
])
def test_bad_resolution_is_refused_by_name(resolution, match):
    with pytest.raises(InputError, match=match):
        check_resolution(resolution)


def test_resolution_none_and_good_values():
    assert check_resolution(None) is None
    with pytest.raises(InputError, match="resolution must be .*got None"):
        check_resolution(None, allow_none=False)
    assert check_resolution((320.0, np.int64(240))) == (320, 240)
    assert check_resolution(np.array([64, 48])) == (64, 48)
    assert all(type(n) is int for n in check_resolution([64.0, 48]))
