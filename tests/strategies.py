"""Seeded random models and states shared by the tests (one place, anchors §4)."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
from hypothesis import strategies as st

import vdad
from vdad.spatial import quat_normalize

JOINT_KINDS = ("revolute", "prismatic", "spherical", "free", "fixed")


def random_rotation(rng):
    return vdad.spatial.quat_to_rot(quat_normalize(rng.normal(size=4)))


def random_inertia(rng, scale=1.0):
    """A physically valid rotational inertia (triangle inequality holds)."""
    m = rng.uniform(0.5, 2.0, size=3) * scale
    moments = np.array([m[1] + m[2], m[0] + m[2], m[0] + m[1]])
    R = random_rotation(rng)
    return R @ np.diag(moments) @ R.T


def random_tree(seed, n=12, kinds=JOINT_KINDS, roots=1, springs=True, composite=False,
                gravity=(0.0, 0.0, -9.81)):
    """A random forest of ``n`` bodies with ``roots`` trees and every joint kind.

    Root joints are free or revolute; internal joints cycle through ``kinds``.
    With ``composite``, some joints are MuJoCo-style hinge chains with anchors.
    """
    rng = np.random.default_rng(seed)
    bodies, joints = [], []
    for i in range(n):
        name = f"b{i}"
        bodies.append(vdad.Body(name, mass=rng.uniform(0.5, 2.0),
                                com=tuple(rng.normal(size=3) * 0.2),
                                inertia=random_inertia(rng, 0.1)))
        if i < roots:
            parent, kind = None, ("free" if i % 2 == 0 else "revolute")
        else:
            parent = f"b{rng.integers(0, i)}"
            kind = kinds[i % len(kinds)]
        placement = vdad.Pose(tuple(rng.normal(size=3) * 0.5), random_rotation(rng))
        stiffness = rng.uniform(0, 3) if springs else 0.0
        damping = rng.uniform(0, 0.5) if springs else 0.0
        if composite and parent is not None and i % 3 == 0:
            stages = tuple(vdad.joints.Stage("hinge", tuple(rng.normal(size=3)),
                                             tuple(rng.normal(size=3) * 0.1), 0.0,
                                             stiffness, damping) for _ in range(1 + i % 3))
            joints.append(vdad.Joint(f"j{i}", parent, name, "composite", placement=placement,
                                     stages=stages))
            continue
        axis = tuple(rng.normal(size=3))
        if kind == "fixed":                     # no dofs, so no springs (the draws stay)
            stiffness = damping = 0.0
        joints.append(vdad.Joint(f"j{i}", parent, name, kind, axis=axis, placement=placement,
                                 stiffness=stiffness, damping=damping))
    q_model = vdad.Model(bodies, joints, gravity=gravity)
    q_spring = random_configuration(q_model, rng) if springs else None
    return vdad.Model(bodies, joints, gravity=gravity, q_spring=q_spring, name=f"random{seed}")


def with_armature(model, seed, low=0.05, high=1.0, free=True):
    """``model`` with a seeded rotor inertia in [low, high] on every joint (every
    stage of a composite joint; fixed joints have none, free joints only with
    ``free``)."""
    rng = np.random.default_rng(seed)
    joints = []
    for jt in model.joints:
        if jt.kind == "composite":
            stages = tuple(replace(s, armature=rng.uniform(low, high)) for s in jt.stages)
            joints.append(replace(jt, stages=stages))
        else:
            armature = rng.uniform(low, high)
            keep = jt.kind == "fixed" or (jt.kind == "free" and not free)
            joints.append(jt if keep else replace(jt, armature=armature))
    return vdad.Model(model.bodies, joints, gravity=model.gravity, q_spring=model.q_spring,
                      name=model.name)


def random_configuration(model, rng):
    q = rng.normal(size=model.nq)
    for s in range(model.ns):
        if model.stage_kind[s] == vdad.joints.BALL:
            i = model.stage_q[s]
            q[i:i + 4] = quat_normalize(q[i:i + 4])
    return q


def random_state(model, seed):
    """Seeded ``(q, qd, tau, f_ext)`` for ``model``."""
    rng = np.random.default_rng(seed)
    return (random_configuration(model, rng), rng.normal(size=model.nv),
            rng.normal(size=model.nv), rng.normal(size=(model.nb, 6)))


def random_chain(seed, n=8, kinds=("revolute", "spherical", "prismatic", "revolute"),
                 root="free", gravity=(0.0, 0.0, -9.81)):
    """A random serial chain: ``root`` joint, then ``kinds`` in turn."""
    rng = np.random.default_rng(seed)
    bodies, joints = [], []
    for i in range(n):
        bodies.append(vdad.Body(f"b{i}", mass=rng.uniform(0.5, 2.0),
                                com=tuple(rng.normal(size=3) * 0.2),
                                inertia=random_inertia(rng, 0.1)))
        kind = root if i == 0 else kinds[i % len(kinds)]
        joints.append(vdad.Joint(f"j{i}", None if i == 0 else f"b{i - 1}", f"b{i}", kind,
                                 axis=tuple(rng.normal(size=3)),
                                 placement=vdad.Pose(tuple(rng.normal(size=3) * 0.5),
                                                     random_rotation(rng))))
    return vdad.Model(bodies, joints, gravity=gravity, name=f"chain{seed}")


def coil_chain(n, skew=1.5, taper=0.95, branching=1):
    """Featherstone's ill-conditioned "coil" (spatial_v2 ``autoTree(n, 1, skew, taper)``):
    revolute joints about z, each frame turned by ``skew`` about x and moved one
    (tapering) link length along x; thin rods whose mass tapers as taper^3. With
    ``branching`` 2, ``autoTree(n, 2, skew, taper)``: the same links on a binary
    tree (body ``i``'s parent ``(i - 1) // 2``)."""
    bodies, joints = [], []
    for i in range(n):
        length, mass = taper**i, taper ** (3 * i)
        inertia = mass * length**2 * np.array([0.0025, 1.015 / 12, 1.015 / 12])
        bodies.append(vdad.Body(f"b{i}", mass, (length / 2, 0.0, 0.0), inertia))
        c, s = np.cos(skew), np.sin(skew)
        rot = np.array([[1, 0, 0], [0, c, -s], [0, s, c]]) if i else np.eye(3)
        parent = (i - 1) // branching if i else None
        joints.append(vdad.Joint(f"j{i}", None if i == 0 else f"b{parent}", f"b{i}", "revolute",
                                 axis=(0, 0, 1),
                                 placement=vdad.Pose((taper**parent if i else 0.0, 0, 0), rot)))
    return vdad.Model(bodies, joints, gravity=(0.0, 0.0, -9.81),
                      name=f"coil{n}" if branching == 1 else f"autotree{n}-{branching}")


def relative_error(a, b):
    return float(np.max(np.abs(a - b)) / max(np.max(np.abs(b)), 1e-300))


def tolerance(model, q, c=100.0):
    """``c · cond(M) · eps`` (theory §8, anchors §1)."""
    from vdad.reference import crba

    return c * np.linalg.cond(crba(model, q)) * np.finfo(float).eps


def plain_factor(model):
    """How much more than a model of ordinary bodies the DCA may lose where its
    evaluations are not refined ((R2) of docs/accuracy.md): ``(LEAF_RAISE / r)^2``
    for its thinnest body's ratio ``r`` of smallest moment to scale, at least 1
    (``r`` stays above ``LEAF_FLOOR`` there, so at most 100); 1 where they are
    refined (raised leaves), which makes them exact to the mechanics' own bound."""
    from vdad import dca

    if dca.body_arrays(model)[12] != 0:
        return 1.0
    moments, _, scale = dca.body_scales(model)
    return max(1.0, (dca.LEAF_RAISE / (moments[:, 0] / scale).min()) ** 2)


def small_compiled_run(upto="steps"):
    """The compiled kinematics (body positions and velocities), then (``upto``
    ``"dynamics"``, ``"steps"`` or ``"adaptive"``) forward dynamics, then three
    compiled RK4 steps with built-in forces (drag, random torques, a spring) of a
    small seeded tree with armature, then (``"adaptive"``) twelve compiled adaptive
    steps of two hanging dogs (their springs and drag, view-bvh coverage under the
    moved-pixels rule in the loop, region changes): what tests/test_linalg.py
    compares between processes and modes."""
    from vdad.forces import Drag, Forces, RandomTorques, Springs
    from vdad.kinematics import kinematics

    model = with_armature(random_tree(5, n=6, roots=2, composite=True), 5)
    rng = np.random.default_rng(5)
    q = random_configuration(model, rng)
    qd, tau = rng.normal(size=model.nv), rng.normal(size=model.nv)
    f = rng.normal(size=(model.nb, 6))
    kin = kinematics(model, q, qd)
    out = dict(p=kin.p.ravel().tolist(), v=kin.v.ravel().tolist())
    if upto == "kinematics":
        return out
    out["qdd"] = vdad.forward_dynamics(model, q, qd, tau, f).tolist()
    if upto == "dynamics":
        return out
    forces = Forces(model, [Drag(model, 0.5), RandomTorques(model, [1, 2], 0.3, rate=50.0),
                            Springs(model, [0], [[0.1, 0, 0]], [[0, 0, 1.0]], 20.0, 1.0)])
    sim = vdad.Simulator(model, q, qd, dt=1e-3, integrator="rk4", external=forces.external)
    sim.step(3)
    out = dict(out, q=sim.q.tolist(), qd=sim.qd.tolist())
    if upto != "adaptive":
        return out
    from vdad.scenes import hanging_dogs

    dogs = hanging_dogs(n_dogs=2).simulator(method="view-bvh", threshold=1e-2, pixels="moved",
                                            dwell=2, coverage_every=3)
    dogs.step(12)
    return dict(out, adaptive_q=dogs.q.tolist(), adaptive_qd=dogs.qd.tolist(),
                changes=[s.rigidified + s.released for s in dogs.history])


def node_bodies(tree, node):
    """The bodies of assembly-tree ``node`` (sorted; none for the ground, -1), by
    recursion over its children: an independent path to a node's bodies."""
    nb = tree.model.nb
    if node < 0:
        return []
    if node < nb:
        return [int(node)]
    i = node - nb
    return sorted(node_bodies(tree, tree.left[i]) + node_bodies(tree, tree.right[i]))


def moved_pixels(tree, per_body, floating=True):
    """``docs/visibility.md``, pixels a joint moves, by brute force from sets:
    every node's largest, over the joints of its subtree, of the pixels
    ``per_body`` (nb,) of the bodies the joint displaces (its successor's
    descendants; with ``floating``, in a tree whose root joint is free, the
    smaller side); a leaf its own pixels, the ground 0."""
    model, nb = tree.model, tree.model.nb
    below = [{b} for b in range(nb)]
    for b in range(nb - 1, -1, -1):
        if model.parent[b] >= 0:
            below[model.parent[b]] |= below[b]
    root = list(range(nb))
    for b in range(nb):
        if model.parent[b] >= 0:
            root[b] = root[model.parent[b]]

    def moved(j):
        side = per_body[sorted(below[j])].sum()
        r = root[j]
        if floating and j != r and model.joints[r].kind == "free":
            return min(side, per_body[sorted(below[r] - below[j])].sum())
        return side

    def joints(node):
        if node < nb:
            return []
        i = node - nb
        return [tree.joint[i]] + joints(tree.left[i]) + joints(tree.right[i])

    N = np.zeros(tree.n_nodes + 1)
    N[:nb] = per_body
    for m in range(len(tree.joint)):
        N[nb + m] = max(moved(j) for j in joints(nb + m))
    return N


def thin_rod(r, kind="revolute", seed=1, com=(0.0, 0.0, 0.0), axis=(0.3, 0.5, 0.8)):
    """One rod of unit mass on one joint to the world, no gravity: principal
    moments 0.1, 0.1 and ``0.1 r`` about seeded axes (issue: thin bodies)."""
    rng = np.random.default_rng(seed)
    R = random_rotation(rng)
    inertia = R @ np.diag([0.1, 0.1, 0.1 * r]) @ R.T
    body = vdad.Body("rod", 1.0, com, 0.5 * (inertia + inertia.T))
    if kind == "composite":
        stages = (vdad.joints.Stage("hinge", axis), vdad.joints.Stage("hinge", (1, -1, 0.2)))
        joint = vdad.Joint("j", None, "rod", kind, stages=stages)
    else:
        joint = vdad.Joint("j", None, "rod", kind, axis=axis)
    return vdad.Model([body], [joint], gravity=(0.0, 0.0, 0.0), name=f"rod{r:g}")


def thin_chain(n, moments, seed=2, com=(0.0, 0.0, -0.5), kinds=("revolute",)):
    """A chain of ``n`` unit-mass bodies with principal ``moments`` about seeded axes,
    one link length apart, joints of ``kinds`` in turn about seeded axes."""
    rng = np.random.default_rng(seed)
    bodies, joints = [], []
    for i in range(n):
        R = random_rotation(rng)
        inertia = R @ np.diag(moments) @ R.T
        bodies.append(vdad.Body(f"b{i}", 1.0, com, 0.5 * (inertia + inertia.T)))
        joints.append(vdad.Joint(f"j{i}", None if i == 0 else f"b{i - 1}", f"b{i}",
                                 kinds[i % len(kinds)], axis=tuple(rng.normal(size=3)),
                                 placement=vdad.Pose((0.0, 0.0, -1.0 if i else 0.0))))
    return vdad.Model(bodies, joints, name=f"thin{n}")


def welded_tip(r, tip_mass):
    """Three bodies on hinges about seeded axes and a rod of ``tip_mass`` with
    moments (0.1, 0.1, 0.1 r) times its mass, welded (a fixed joint) to the last."""
    rng = np.random.default_rng(5)
    bodies, joints = [], []
    for i in range(3):
        R = random_rotation(rng)
        inertia = R @ np.diag([0.1, 0.08, 0.05]) @ R.T
        bodies.append(vdad.Body(f"b{i}", 1.0, (0, 0, -0.5), 0.5 * (inertia + inertia.T)))
        joints.append(vdad.Joint(f"j{i}", None if i == 0 else f"b{i - 1}", f"b{i}", "revolute",
                                 axis=tuple(rng.normal(size=3)),
                                 placement=vdad.Pose((0, 0, -1.0 if i else 0.0))))
    R = random_rotation(rng)
    inertia = tip_mass * R @ np.diag([0.1, 0.1, 0.1 * r]) @ R.T
    bodies.append(vdad.Body("tip", tip_mass, (0, 0, -1.0), 0.5 * (inertia + inertia.T)))
    joints.append(vdad.Joint("weld", "b2", "tip", "fixed",
                             placement=vdad.Pose((0.1, 0.2, -1.0), (0.8, 0.3, -0.2, 0.5))))
    return vdad.Model(bodies, joints, name=f"welded{r:g}")


def light_chain(ratio, light, n=5, seed=3):
    """A chain of ``n`` unit-mass bodies on hinges about seeded axes, body
    ``light`` of mass ``ratio`` (its inertia scaled with it)."""
    rng = np.random.default_rng(seed)
    bodies, joints = [], []
    for i in range(n):
        m = ratio if i == light else 1.0
        R = random_rotation(rng)
        inertia = m * R @ np.diag([0.1, 0.08, 0.05]) @ R.T
        bodies.append(vdad.Body(f"b{i}", m, (0, 0, -0.5), 0.5 * (inertia + inertia.T)))
        joints.append(vdad.Joint(f"j{i}", None if i == 0 else f"b{i - 1}", f"b{i}", "revolute",
                                 axis=tuple(rng.normal(size=3)),
                                 placement=vdad.Pose((0, 0, -1.0 if i else 0.0))))
    return vdad.Model(bodies, joints, name=f"light{ratio:g}")


def thin_tree(seed, n, log_ratios):
    """:func:`random_tree` (every joint kind, composite joints, springs) whose
    bodies are made thin (:func:`thin_bodies`)."""
    return thin_bodies(random_tree(seed, n=n, composite=True), seed, log_ratios)


def thin_bodies(base, seed, log_ratios):
    """``base`` whose bodies are made thin rods (principal moments ``a, a, a
    10^x``) or point masses (every moment times ``10^x``) in turn, ``x`` from
    ``log_ratios``."""
    rng = np.random.default_rng(seed)
    bodies = []
    for i, body in enumerate(base.bodies):
        ratio = 10.0 ** log_ratios[i % len(log_ratios)]
        if i % 2 == 0:
            R = random_rotation(rng)
            a = rng.uniform(0.05, 0.2)
            inertia = R @ np.diag([a, a, a * ratio]) @ R.T
        else:
            inertia = np.asarray(body.inertia) * ratio
        bodies.append(replace(body, inertia=0.5 * (inertia + inertia.T)))
    return vdad.Model(bodies, base.joints, gravity=base.gravity, q_spring=base.q_spring,
                      name=f"thin{seed}")


def light_tree(seed, n, log_ratios):
    """:func:`random_tree` (every joint kind, composite joints, springs) whose
    bodies' masses and inertias are scaled by ``10^x`` in turn, ``x`` from
    ``log_ratios``: bodies light against their neighbours ((R5) of
    docs/accuracy.md)."""
    base = random_tree(seed, n=n, composite=True)
    bodies = [replace(body, mass=body.mass * 10.0 ** log_ratios[i % len(log_ratios)],
                      inertia=np.asarray(body.inertia) * 10.0 ** log_ratios[i % len(log_ratios)])
              for i, body in enumerate(base.bodies)]
    return vdad.Model(bodies, base.joints, gravity=base.gravity, q_spring=base.q_spring,
                      name=f"light{seed}")


#: hypothesis: random trees of thin rods and point masses, principal-moment
#: ratios down to 1e-10 (:func:`thin_tree`), with a state seed
thin_trees = st.builds(
    lambda seed, n, x: (thin_tree(seed, n, x), seed),
    st.integers(0, 2 ** 16), st.integers(2, 9),
    st.lists(st.floats(-10.0, 0.0), min_size=1, max_size=9))

#: hypothesis: random trees of bodies whose masses differ by up to 1e8
#: (:func:`light_tree`), with a state seed
light_trees = st.builds(
    lambda seed, n, x: (light_tree(seed, n, x), seed),
    st.integers(0, 2 ** 16), st.integers(2, 9),
    st.lists(st.floats(-8.0, 0.0), min_size=1, max_size=9))
