"""Model construction and validation (vdad.model)."""

import numpy as np
import pytest

import vdad
from vdad import Body, InputError, Joint, Model, ModelError, Pose


def two_links(**overrides):
    bodies = [Body("a", 1.0), Body("b", 1.0)]
    joints = [Joint("ja", None, "a"), Joint("jb", "a", "b", placement=Pose((0, 0, -1)))]
    return bodies, joints


@pytest.mark.parametrize("kwargs, match", [
    (dict(mass=0.0), "body 'bad': mass must be positive"),
    (dict(mass=-1.0), "body 'bad': mass must be positive"),
    (dict(mass=float("nan")), "body 'bad': mass must be finite"),
    (dict(mass="1.0"), "body 'bad': mass must be a real number.*a string"),
    (dict(mass=None), "body 'bad': mass must be a real number.*got None"),
    (dict(mass=[1, 2]), "body 'bad': mass must be a single number"),
    (dict(mass=1 + 1j), "body 'bad': mass must be a real number.*complex"),
    (dict(mass=True), "body 'bad': mass must be a real number.*boolean"),
    (dict(inertia=np.diag([1.0, 1.0, -1.0])), "body 'bad'.*not positive definite"),
    (dict(inertia=np.diag([1.0, 1.0, 3.0])), "body 'bad'.*triangle inequality"),
    (dict(inertia=[[1, 0.5, 0], [0, 1, 0], [0, 0, 1]]), "body 'bad'.*symmetric"),
    (dict(inertia="abc"), "body 'bad': inertia must be a real number.*string"),
    (dict(inertia=[[1, 0, 0], [0, 1], [0, 0, 1]]), "body 'bad': inertia .*ragged"),
    (dict(inertia=[1, 2]), "body 'bad': inertia must be a finite 3x3 matrix or 3 moments"),
    (dict(com=(0, np.inf, 0)), "body 'bad': com has non-finite"),
    (dict(com="abc"), "body 'bad': com must be a real number"),
    (dict(geoms=("sphere",)), "body 'bad': geoms must be vdad.Geom objects, got 'sphere'"),
    (dict(geoms=vdad.Geom("sphere", (1.0,))), "body 'bad': geoms must be a tuple"),
])
def test_invalid_bodies_name_the_body(kwargs, match):
    with pytest.raises(ModelError, match=match):
        Body("bad", **{"mass": 1.0, **kwargs})


@pytest.mark.parametrize("name", [None, "", 3])
def test_body_and_joint_names_are_strings(name):
    with pytest.raises(ModelError, match="body name must be a non-empty string"):
        Body(name, 1.0)
    with pytest.raises(ModelError, match="joint name must be a non-empty string"):
        Joint(name, None, "b")


def test_bodies_are_normalised_and_hashable():
    b = Body("b", np.float32(2), com=np.array([0, 0, 1]), inertia=[1, 2, 2.5])
    assert b.mass == 2.0 and type(b.mass) is float and b.com == (0.0, 0.0, 1.0)
    assert b.inertia == ((1.0, 0.0, 0.0), (0.0, 2.0, 0.0), (0.0, 0.0, 2.5))
    assert hash(b) == hash(Body("b", 2.0, (0, 0, 1), np.diag([1, 2, 2.5])))


@pytest.mark.parametrize("kwargs, match", [
    (dict(axis=(0, 0, 0)), "joint 'jb': zero axis"),
    (dict(axis=(0, np.nan, 1)), "joint 'jb': axis has non-finite entries"),
    (dict(axis="x"), "joint 'jb': axis must be a real number.*string"),
    (dict(kind="hinge3"), "joint 'jb': unknown kind 'hinge3'"),
    (dict(damping=-1.0), "joint 'jb': damping must be >= 0"),
    (dict(stiffness="a"), "joint 'jb': stiffness must be a real number"),
    (dict(placement=(0, 0, -1)), "joint 'jb': placement must be a vdad.Pose.*tuple"),
    (dict(kind="composite"), "joint 'jb': a composite joint needs stages"),
    (dict(kind="composite", stages=("hinge",)), "joint 'jb': stage 0 must be a vdad.joints"),
    (dict(kind="composite", stages="hinge"), "joint 'jb': stages must be a tuple"),
    (dict(stages=vdad.joints.revolute()), "joint 'jb': stages apply to kind='composite'"),
    (dict(parent=3), "joint 'jb': parent must be a body name or None"),
    (dict(child=None), "joint 'jb': child must be a body name"),
    (dict(limits=(1, 0)), r"joint 'jb': limits must be \(low, high\) with low < high"),
    (dict(limits=(0, np.nan)), "joint 'jb': limits must be .*low < high"),
    (dict(limits="abc"), r"joint 'jb': limits must be \(low, high\), got 'abc'"),
    (dict(limits=(0, 1, 2)), r"joint 'jb': limits must be \(low, high\)"),
    (dict(kind="free", limits=(0, 1)), "joint 'jb': limits: a free joint has no limits"),
    (dict(kind="fixed", stiffness=5.0), "joint 'jb': a fixed joint has no dofs"),
    (dict(kind="fixed", armature=0.1), "joint 'jb': a fixed joint has no dofs"),
    (dict(armature=-0.1), "joint 'jb': armature must be >= 0"),
    (dict(kind="composite", stages=vdad.joints.revolute(), armature=0.1),
     "joint 'jb': a composite joint takes stiffness, damping and armature per stage"),
    (dict(kind=["revolute"]), r"joint 'jb': unknown kind \['revolute'\]"),
    (dict(kind="composite", stages=vdad.joints.revolute() + vdad.joints.revolute(),
          limits=(0, 1)), "joint 'jb': limits: a joint of 2 stages takes one"),
    (dict(kind="composite", stages=vdad.joints.revolute() + vdad.joints.revolute(),
          limits=((0, 1), (2, 1))), r"joint 'jb': limits\[1\] must be \(low, high\)"),
])
def test_invalid_joints_name_the_joint(kwargs, match):
    with pytest.raises(ModelError, match=match):
        Joint("jb", **{"parent": "a", "child": "b", **kwargs})


@pytest.mark.parametrize("make, match", [
    (lambda: vdad.joints.revolute(axis=5), r"hinge stage axis must have shape \(3,\)"),
    (lambda: vdad.joints.revolute(anchor=None), "hinge stage anchor must be a real number"),
    (lambda: vdad.joints.prismatic(stiffness=-1), "slide stage stiffness must be >= 0"),
    (lambda: vdad.joints.spherical(damping="x"), "ball stage damping must be a real number"),
    (lambda: vdad.joints.Stage("wobble"), "unknown stage kind 'wobble'"),
    (lambda: vdad.joints.free(armature=-1), "translation stage armature must be >= 0"),
])
def test_stages_check_themselves(make, match):
    with pytest.raises(ModelError, match=match):
        make()


@pytest.mark.parametrize("name", [5, None, ""])
def test_model_names_are_strings(name):
    with pytest.raises(ModelError, match="the model's name must be a non-empty string"):
        Model(*two_links(), name=name)


def test_armature_per_dof():
    bodies = [Body("a", 1.0), Body("b", 1.0), Body("c", 1.0)]
    joints = [Joint("ja", None, "a", "free", armature=0.5),
              Joint("jb", "a", "b", "spherical", armature=0.2),
              Joint("jc", "b", "c", "composite",
                    stages=vdad.joints.revolute(armature=0.1) + vdad.joints.prismatic())]
    m = Model(bodies, joints)
    np.testing.assert_array_equal(m.armature, [0.5] * 6 + [0.2] * 3 + [0.1, 0.0])


def test_implicit_damping_adds_dt_times_the_damping_to_the_armature():
    """``with_implicit_damping(model, dt)``: every stage's armature grows by ``dt``
    times its damping (a joint's, a composite joint's stages'), nothing else
    changes; an undamped model is returned as it is."""
    from vdad.model import with_implicit_damping

    bodies = [Body("a", 1.0), Body("b", 1.0), Body("c", 1.0)]
    joints = [Joint("ja", None, "a", "free", damping=2.0, armature=0.5),
              Joint("jb", "a", "b", "spherical", damping=3.0),
              Joint("jc", "b", "c", "composite",
                    stages=vdad.joints.revolute(damping=4.0, armature=0.1)
                    + vdad.joints.prismatic())]
    m = Model(bodies, joints, gravity=(0.0, 1.0, -9.0), name="damped")
    d = with_implicit_damping(m, 0.01)
    np.testing.assert_allclose(d.armature, [0.52] * 6 + [0.03] * 3 + [0.14, 0.0],
                               rtol=1e-15)
    np.testing.assert_array_equal(d.stage_damping, m.stage_damping)
    for name in ("parent", "mass", "com", "inertia", "gravity", "q_spring", "q_neutral"):
        np.testing.assert_array_equal(getattr(d, name), getattr(m, name))
    assert d.name == m.name and d.joint_names == m.joint_names
    undamped = Model(*two_links())
    assert with_implicit_damping(undamped, 0.01) is undamped
    with pytest.raises(InputError, match="dt must be"):
        with_implicit_damping(m, 0.0)


def test_joint_limits_are_normalised():
    assert Joint("j", None, "b", limits=[np.int64(-1), 2]).limits == (-1.0, 2.0)
    two = vdad.joints.revolute() + vdad.joints.prismatic()
    j = Joint("j", None, "b", "composite", stages=two, limits=[None, [0, 0.5]])
    assert j.limits == (None, (0.0, 0.5))


@pytest.mark.parametrize("joint, match", [
    (Joint("jb", "zz", "b"), "joint 'jb': unknown parent body 'zz'"),
    (Joint("jb", "a", "zz"), "joint 'jb': unknown child body 'zz'"),
])
def test_joints_that_name_unknown_bodies(joint, match):
    bodies, joints = two_links()
    with pytest.raises(ModelError, match=match):
        Model(bodies, [joints[0], joint])


@pytest.mark.parametrize("kwargs, match", [
    (dict(rotation=np.diag([1.0, 1.0, -1.0])), "Pose rotation is not a proper rotation"),
    (dict(rotation=(0, 0, 0, 0)), "Pose rotation: the quaternion .* cannot be normalised"),
    (dict(rotation=np.eye(2)), "Pose rotation must be a 3x3 matrix or a quaternion"),
    (dict(rotation="identity"), "Pose rotation must be a real number.*string"),
    (dict(translation=(0, 0)), r"Pose translation must have shape \(3,\)"),
    (dict(translation=(0, np.inf, 0)), "Pose translation has non-finite"),
    (dict(translation=(True, 0, 0)), "Pose translation must be a real number.*booleans"),
])
def test_invalid_poses(kwargs, match):
    with pytest.raises(ModelError, match=match):
        Pose(**kwargs)


@pytest.mark.parametrize("args, kwargs, match", [
    (("sphere",), {}, r"a sphere geom takes size = \(radius,\), got \(\)"),
    (("capsule", (-1, 1)), {}, "a capsule geom's size .* must be positive"),
    (("box", (1, 1)), {}, "a box geom takes size"),
    (("box", "abc"), {}, "box geom size must be a real number"),
    (("cone", (1,)), {}, "unknown geometry kind 'cone'"),
    ((["sphere"], (1,)), {}, r"unknown geometry kind \['sphere'\]"),
    (("mesh",), {}, "a mesh geom needs mesh="),
    (("sphere", (1,)), dict(pose=(0, 0, 0)), "geom pose must be a vdad.Pose"),
    (("sphere", (1,)), dict(rgba=(1, 0, 0, 2)), r"geom rgba must be 4 numbers in \[0, 1\]"),
])
def test_invalid_geoms(args, kwargs, match):
    with pytest.raises(ModelError, match=match):
        vdad.Geom(*args, **kwargs)


@pytest.mark.parametrize("bodies, joints, match", [
    ([{"name": "b", "mass": 1}], [Joint("j", None, "b")], r"bodies\[0\] must be a vdad.Body, "
     "got dict"),
    ([Body("b", 1.0)], None, "joints must be a sequence of vdad.Joint, got None"),
    ([Body("b", 1.0)], [("j", None, "b")], r"joints\[0\] must be a vdad.Joint, got tuple"),
    ("b", [Joint("j", None, "b")], "bodies must be a sequence of vdad.Body"),
])
def test_models_take_bodies_and_joints(bodies, joints, match):
    with pytest.raises(ModelError, match=match):
        Model(bodies, joints)


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
    with pytest.raises(ModelError, match="gravity must be a real number.*string"):
        Model(bodies, joints, gravity="down")
    with pytest.raises(ModelError, match=r"q_spring must have shape \(2,\)"):
        Model(bodies, joints, q_spring=[0.0])


def test_zero_quaternions_are_refused():
    ball = [Joint("j", None, "b", "spherical", stiffness=1.0)]
    with pytest.raises(ModelError, match=r"q_spring\[0:4\], the quaternion of joint 'j', is "
                       "zero"):
        Model([Body("b", 1.0)], ball, q_spring=[0, 0, 0, 0])
    model = Model([Body("b", 1.0)], ball)
    with pytest.raises(vdad.InputError, match=r"q0\[0:4\], the quaternion of joint 'j'"):
        vdad.Simulator(model, q0=[0, 0, 0, 0])
    with pytest.raises(vdad.InputError, match="the quaternion of joint 'j', is zero"):
        vdad.forward_dynamics(model, [0, 0, 0, 0], np.zeros(3))


def test_geometry_to_trimesh():
    g = vdad.Geom("capsule", (0.1, 0.4), Pose((0, 0, -0.5)))
    mesh = g.to_trimesh()
    assert mesh.is_watertight
    np.testing.assert_allclose(mesh.bounds, [[-0.1, -0.1, -1.0], [0.1, 0.1, 0.0]], atol=1e-6)
