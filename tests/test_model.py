"""Model construction and validation (vdad.model)."""

import numpy as np
import pytest

import vdad
from vdad import Body, Joint, Model, ModelError, Pose


def two_links(**overrides):
    bodies = [Body("a", 1.0), Body("b", 1.0)]
    joints = [Joint("ja", None, "a"), Joint("jb", "a", "b", placement=Pose((0, 0, -1)))]
    return bodies, joints


@pytest.mark.parametrize("body, match", [
    (Body("bad", 0.0), "body 'bad': mass must be positive"),
    (Body("bad", -1.0), "body 'bad': mass must be positive"),
    (Body("bad", float("nan")), "body 'bad': mass"),
    (Body("bad", 1.0, inertia=np.diag([1.0, 1.0, -1.0])), "body 'bad'.*not positive definite"),
    (Body("bad", 1.0, inertia=np.diag([1.0, 1.0, 3.0])), "body 'bad'.*triangle inequality"),
    (Body("bad", 1.0, inertia=[[1, 0.5, 0], [0, 1, 0], [0, 0, 1]]), "body 'bad'.*symmetric"),
    (Body("bad", 1.0, com=(0, np.inf, 0)), "body 'bad': com"),
])
def test_invalid_bodies_name_the_body(body, match):
    with pytest.raises(ModelError, match=match):
        Model([body], [Joint("j", None, "bad")])


@pytest.mark.parametrize("joint, match", [
    (Joint("jb", "a", "b", axis=(0, 0, 0)), "joint 'jb': zero axis"),
    (Joint("jb", "a", "b", axis=(0, np.nan, 1)), "joint 'jb': axis or anchor is not finite"),
    (Joint("jb", "zz", "b"), "joint 'jb': unknown parent body 'zz'"),
    (Joint("jb", "a", "zz"), "joint 'jb': unknown child body 'zz'"),
    (Joint("jb", "a", "b", kind="hinge3"), "joint 'jb': unknown kind 'hinge3'"),
    (Joint("jb", "a", "b", damping=-1.0), "joint 'jb': stiffness and damping"),
    (Joint("jb", "a", "b", placement=Pose(rotation=np.diag([1.0, 1.0, -1.0]))),
     "joint 'jb': placement rotation"),
    (Joint("jb", "a", "b", kind="composite"), "joint 'jb': a composite joint needs stages"),
])
def test_invalid_joints_name_the_joint(joint, match):
    bodies, joints = two_links()
    with pytest.raises(ModelError, match=match):
        Model(bodies, [joints[0], joint])


def test_duplicate_names():
    with pytest.raises(ModelError, match="duplicate body name 'a'"):
        Model([Body("a", 1.0), Body("a", 1.0)], [Joint("j", None, "a")])
    bodies, joints = two_links()
    with pytest.raises(ModelError, match="duplicate joint name 'ja'"):
        Model(bodies, [joints[0], Joint("ja", "a", "b")])


def test_cycle_and_missing_or_double_joints():
    bodies = [Body("a", 1.0), Body("b", 1.0), Body("c", 1.0)]
    with pytest.raises(ModelError, match="kinematic cycle through bodies 'a', 'b'"):
        Model(bodies, [Joint("ja", "b", "a"), Joint("jb", "a", "b"), Joint("jc", None, "c")])
    with pytest.raises(ModelError, match="body 'c' has no inbound joint"):
        Model(bodies, [Joint("ja", None, "a"), Joint("jb", "a", "b")])
    with pytest.raises(ModelError, match="body 'b' has two inbound joints"):
        Model(bodies, [Joint("ja", None, "a"), Joint("jb", "a", "b"), Joint("jb2", None, "b"),
                       Joint("jc", None, "c")])
    with pytest.raises(ModelError, match="body 'a' cannot be its own parent"):
        Model(bodies[:1], [Joint("ja", "a", "a")])


def test_topological_order_and_layout():
    bodies = [Body("tip", 1.0), Body("base", 2.0)]
    joints = [Joint("jt", "base", "tip", "spherical"), Joint("jb", None, "base", "free")]
    m = Model(bodies, joints)
    assert m.body_names == ("base", "tip")
    assert list(m.parent) == [-1, 0]
    assert (m.nq, m.nv) == (11, 9)
    assert list(m.q_start) == [0, 7] and list(m.v_start) == [0, 6]
    np.testing.assert_array_equal(m.q_neutral, [0, 0, 0, 1, 0, 0, 0, 1, 0, 0, 0])
    assert m.mass[0] == 2.0
    with pytest.raises(ValueError):
        m.mass[0] = 3.0                      # immutable arrays
    with pytest.raises(ModelError, match="no body called 'nope'"):
        m.body_index("nope")


def test_bad_gravity_and_q_spring():
    bodies, joints = two_links()
    with pytest.raises(ModelError, match="gravity"):
        Model(bodies, joints, gravity=(0, 0))
    with pytest.raises(ModelError, match="q_spring must be 2 finite numbers"):
        Model(bodies, joints, q_spring=[0.0])


def test_geometry_to_trimesh():
    g = vdad.Geom("capsule", (0.1, 0.4), Pose((0, 0, -0.5)))
    mesh = g.to_trimesh()
    assert mesh.is_watertight
    np.testing.assert_allclose(mesh.bounds, [[-0.1, -0.1, -1.0], [0.1, 0.1, 0.0]], atol=1e-6)
