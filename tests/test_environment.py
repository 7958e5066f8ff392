"""Environment geometry (vdad.environment): bad input is refused by name."""

import numpy as np
import pytest

from vdad.environment import Environment, box, check_environment, floor, wall
from vdad.errors import InputError, VdadError
from vdad.model import Geom


@pytest.mark.parametrize("options, match", [
    (dict(size=-1), "floor size must be positive"),
    (dict(size="a"), "floor size must be a real number"),
    (dict(thickness=0), "floor thickness must be positive"),
    (dict(height=np.nan), "floor height must be finite"),
    (dict(height="a"), "floor height must be a real number"),
    (dict(height=(0, 1)), "floor height must be a single number"),
])
def test_bad_floor_is_refused_by_name(options, match):
    with pytest.raises(InputError, match=match):
        floor(**options)


@pytest.mark.parametrize("args, options, match", [
    (((0, 0), (1, 0)), dict(height=-1), "wall height must be positive"),
    (((0, 0), (np.nan, 0)), {}, "wall end has non-finite entries"),
    (((0, 0), (1, 0)), dict(base=np.nan), "wall base must be finite"),
    ((("a", "b"), (1, 1)), {}, "wall start must be a real number"),
    (((0, 0, 0), (1, 1)), {}, r"wall start must have shape \(2,\)"),
    (((0, 0), (1, 0)), dict(thickness="x"), "wall thickness must be a real number"),
    (((0, 0), (1, 0)), dict(thickness=0), "wall thickness must be positive"),
    (((1, 1), (1, 1)), {}, "a wall needs two distinct .* zero length"),
    (((-1e308, 0), (1e308, 0)), {}, "too far apart"),
])
def test_bad_wall_is_refused_by_name(args, options, match):
    with np.errstate(all="raise"), pytest.raises(InputError, match=match):
        wall(*args, **options)


def test_bad_box_is_refused_by_name():
    with pytest.raises(InputError, match="box half_extents must be a real number"):
        box((0, 0, 0), "abc")
    with pytest.raises(InputError, match="box half_extents must be 3 positive numbers"):
        box((0, 0, 0), (1, 1, 0))
    with pytest.raises(InputError, match=r"box half_extents must have shape \(3,\)"):
        box((0, 0, 0), 1)
    with pytest.raises(InputError, match="box center has non-finite entries"):
        box((0, np.inf, 0), (1, 1, 1))
    with pytest.raises(VdadError, match="rotation"):
        box((0, 0, 0), (1, 1, 1), rotation=(0, 0, 0, 0))


def test_geometry_of_floor_and_wall():
    (g,) = floor(height=1.0, size=4.0, thickness=0.1).geoms
    assert g.size == (2.0, 2.0, 0.1) and g.pose.translation == pytest.approx((0, 0, 0.9))
    (w,) = wall((0, 0), (0, 2), height=1.0, thickness=0.2, base=0.5).geoms
    assert w.size == pytest.approx((1.0, 0.1, 0.5))
    assert w.pose.translation == pytest.approx((0.0, 1.0, 1.0))


def test_environment_geoms_and_addition():
    sphere = Geom("sphere", (1.0,))
    with pytest.raises(InputError, match="environment geoms must be a tuple of vdad.Geom, got int"):
        Environment(geoms=5)
    with pytest.raises(InputError, match="environment geoms must be a tuple of .* got Geom"):
        Environment(geoms=sphere)
    with pytest.raises(InputError, match="environment geom 1 must be a vdad.Geom, got str"):
        Environment((sphere, "wall"))
    with pytest.raises(InputError, match="only a vdad.environment.Environment can be added to an "
                                         "Environment, got int: 5"):
        Environment() + 5
    with pytest.raises(InputError, match="can be added to an Environment, got int"):
        5 + Environment()
    both = Environment([sphere]) + floor()
    assert isinstance(both.geoms, tuple) and len(both.geoms) == 2 and both.geoms[0] is sphere
    assert check_environment(None) == Environment()
    with pytest.raises(InputError, match="environment must be"):
        check_environment((sphere,))
