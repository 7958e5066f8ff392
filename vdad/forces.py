"""Forces that the paper's scenes need (Kim 2008 §6.1; derivations in ``docs/forces.md``).

Springs and virtual strings from body points to world points that may move (the
puppet's control stick, the hanging dogs' anchors), intermittent random torques
from a seeded generator (the hanging dogs), penalty contact with a floor and
Coulomb-style friction (the falling character), and joint limits. Each element
is small and vectorised over its bodies; :class:`Forces` sums them into the
``external(t, q, qd) -> f_ext`` (nb, 6) and ``controller(t, q, qd) -> tau`` (nv,)
callables of :class:`~vdad.Simulator`. External wrenches follow
``docs/conventions.md``: torque about each body's centre of mass, then force,
world axes. With the adaptive methods they enter through the force-update region
(:meth:`~vdad.hybrid.RigidGroups.update_forces`).

Only the bodies an element acts on (and their ancestors) are placed: a spring on
the torsos of 100 dogs costs the kinematics of 100 free joints, not 1600 joints.
"""

from __future__ import annotations

import numpy as np

from .checks import check_real, real_array, show
from .errors import InputError, ModelError
from .kinematics import Kinematics, joint_set, kinematics
from .model import body_indices, check_model, whole_index
from .spatial import cross3, mv, quat_log

#: The most pulses per second that a :class:`RandomTorques` draws over all its
#: bodies (``rate * len(bodies)``): each 1 s window's pulses are drawn at once.
MAX_PULSE_RATE = 1e6


class BodyStates:
    """Theory §3 restricted to a few ``bodies`` of ``model``: their world poses and
    velocities from the full state, through the joint set of their ancestors only.

    Calling it with ``(q, qd)`` gives ``R`` (k, 3, 3), ``p`` (k, 3) (body frames),
    ``w`` (k, 3) angular velocity and ``v`` (k, 3) velocity of the body origin,
    world axes."""

    def __init__(self, model, bodies):
        self.model = model
        bodies = body_indices(check_model(model), bodies)
        keep = np.zeros(model.nb, bool)
        b = np.unique(bodies)
        while len(b):
            keep[b] = True
            b = model.parent[b]
            b = np.unique(b[(b >= 0) & ~keep[np.maximum(b, 0)]])
        closure = np.flatnonzero(keep)
        local = np.full(model.nb, -1)
        local[closure] = np.arange(len(closure))
        parent = np.where(model.parent[closure] >= 0, local[model.parent[closure]], -1)
        self.js = joint_set(model, closure, parent)
        self.rows = local[bodies]
        self._kin = Kinematics.empty(self.js)

    def __call__(self, q, qd):
        js = self.js
        kin = kinematics(self.model, q[js.q_index], qd[js.v_index], js, self._kin)
        R, p, v = kin.R[self.rows], kin.p[self.rows], kin.v[self.rows]
        return R, p, mv(R, v[:, :3]), mv(R, v[:, 3:])


def point_wrenches(model, bodies, R, p, x, F):
    """Wrenches (k, 6) of forces ``F`` (k, 3) applied at world points ``x`` (k, 3)
    of ``bodies`` with poses ``R, p``: torque about each centre of mass, force."""
    c = p + mv(R, model.com[bodies])
    return np.concatenate([cross3(x - c, F), F], axis=1)


class Springs:
    """Linear springs with dampers from body points to world anchors (Kim 2008
    §6.1: the hanging dogs' springs; with ``string=True`` the puppet's virtual
    strings, which pull and never push).

    bodies (k,): names or indices; points (k, 3): attachment in each body frame;
    anchors: world points (k, 3), or a callable ``t -> (k, 3)`` for anchors that
    move (their velocity is taken by central differences, step ``1e-4`` s);
    stiffness, damping, rest_length: scalars or (k,). The force on the body is
    ``-(k (L - L0) + c dL/dt) u`` along the unit vector ``u`` from anchor to
    point; strings exert it only while ``L > L0`` and clamp it to tension.
    """

    def __init__(self, model, bodies, points, anchors, stiffness, damping=0.0,
                 rest_length=0.0, string=False):
        self.model = check_model(model)
        self.bodies = body_indices(model, bodies)
        k = len(self.bodies)
        self.points = check_real("points", points, (k, 3))
        self.moving = callable(anchors)
        self.anchors = anchors if self.moving else check_real("anchors", anchors, (k, 3))
        self.stiffness = check_real("stiffness", stiffness, (k,), nonnegative=True)
        self.damping = check_real("damping", damping, (k,), nonnegative=True)
        self.rest_length = check_real("rest_length", rest_length, (k,), nonnegative=True)
        self.string = bool(string)

    def anchor_state(self, t):
        """Anchor positions (k, 3) and velocities (k, 3) at time ``t``."""
        if not self.moving:
            return self.anchors, np.zeros_like(self.anchors)
        k = len(self.bodies)
        a = check_real("anchors(t)", self.anchors(t), (k, 3))
        h = 1e-4
        va = (np.asarray(self.anchors(t + h), float) - np.asarray(self.anchors(t - h), float))
        return a, va / (2 * h)

    def lengths(self, t, states):
        """Spring lengths (k,) for body ``states`` (:class:`BodyStates` output)."""
        R, p = states[:2]
        return np.linalg.norm(p + mv(R, self.points) - self.anchor_state(t)[0], axis=1)

    def wrenches(self, t, states):
        """Wrenches (k, 6) on ``self.bodies``."""
        R, p, w, v = states
        a, va = self.anchor_state(t)
        r = mv(R, self.points)
        x = p + r
        d = x - a
        L = np.linalg.norm(d, axis=1)
        u = d / np.maximum(L, 1e-12)[:, None]
        Ldot = np.einsum("ki,ki->k", u, v + cross3(w, r) - va)
        T = self.stiffness * (L - self.rest_length) + self.damping * Ldot
        if self.string:
            T = np.where(L > self.rest_length, np.maximum(T, 0.0), 0.0)
        return point_wrenches(self.model, self.bodies, R, p, x, -T[:, None] * u)

    def energy(self, t, states):
        """Elastic energy ``k (L - L0)^2 / 2`` summed (strings: taut ones)."""
        e = np.maximum(self.lengths(t, states) - self.rest_length,
                       0.0 if self.string else -np.inf)
        return float(np.sum(self.stiffness * e**2) / 2)


class RandomTorques:
    """Intermittent random torques (Kim 2008 §6.1, the hanging dogs).

    Each of ``bodies`` receives pulses at the times of a Poisson process of
    ``rate`` pulses per second; a pulse lasts ``duration`` s and is a torque of
    ``magnitude`` N m about a uniformly random direction, world axes. The pulses
    are a function of time alone, drawn per 1 s window from
    ``numpy.random.default_rng([seed, window])``: a run repeats exactly, whatever
    the integrator's evaluation order or the method.
    """

    needs_states = False          # torques do not depend on the bodies' states

    def __init__(self, model, bodies, magnitude, rate=1.0, duration=0.1, seed=0):
        self.model = check_model(model)
        self.bodies = body_indices(model, bodies)
        self.magnitude = float(check_real("magnitude", magnitude, nonnegative=True))
        self.rate = float(check_real("rate", rate, nonnegative=True))
        if self.rate * len(self.bodies) > MAX_PULSE_RATE:
            k = len(self.bodies)
            raise InputError(f"rate = {self.rate:g} pulses per second on each of {k} "
                             f"bod{'y' if k == 1 else 'ies'} is too high: rate * len(bodies) "
                             f"must be at most {MAX_PULSE_RATE:g} (the pulses of each 1 s "
                             f"window are drawn at once)")
        self.duration = float(check_real("duration", duration, positive=True))
        if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0:
            raise InputError(f"seed must be an integer >= 0, got {seed!r}")
        self.seed = int(seed)
        self._windows = {}

    def pulses(self, window):
        """``(body rows, start times, torques (n, 3))`` of the pulses starting in
        ``[window, window + 1)`` s."""
        if window < 0:
            return np.zeros(0, int), np.zeros(0), np.zeros((0, 3))
        if window not in self._windows:
            rng = np.random.default_rng([self.seed, window])
            n = rng.poisson(self.rate * len(self.bodies))
            rows = rng.integers(len(self.bodies), size=n)
            start = window + rng.random(n)
            axis = rng.normal(size=(n, 3))
            axis /= np.maximum(np.linalg.norm(axis, axis=1), 1e-12)[:, None]
            self._windows[window] = (rows, start, self.magnitude * axis)
        return self._windows[window]

    def torques(self, t):
        """Torques (k, 3) on ``self.bodies`` at time ``t``."""
        out = np.zeros((len(self.bodies), 3))
        for w in range(max(int(np.floor(t - self.duration)), 0), int(np.floor(t)) + 1):
            rows, start, tau = self.pulses(w)
            on = (start <= t) & (t < start + self.duration)
            np.add.at(out, rows[on], tau[on])
        return out

    def wrenches(self, t, states=None):
        return np.concatenate([self.torques(t), np.zeros((len(self.bodies), 3))], axis=1)


class Drag:
    """Linear drag (``docs/forces.md``; still air, or a puppet's friction): on
    each of ``bodies`` (default all) the force ``-rate m v`` at its centre of mass and the torque
    ``-rate I w`` (``I`` in world axes), ``rate`` in 1/s: free motion decays as
    ``exp(-rate t)``. Stable while ``rate dt < 1``."""

    def __init__(self, model, rate, bodies=None):
        self.model = check_model(model)
        self.rate = float(check_real("rate", rate, nonnegative=True))
        self.bodies = np.arange(model.nb) if bodies is None else body_indices(model, bodies)

    def wrenches(self, t, states):
        R, p, w, v = states
        m = self.model
        c = mv(R, m.com[self.bodies])
        I_world = R @ m.inertia[self.bodies] @ np.swapaxes(R, 1, 2)
        return -self.rate * np.concatenate([mv(I_world, w),
                                            m.mass[self.bodies, None] * (v + cross3(w, c))],
                                           axis=1)


def contact_points(model, bodies=None):
    """Contact spheres from body geometry (``docs/forces.md``, floor contact):
    ``(body (m,), centre (m, 3) in the body frame, radius (m,))``. A sphere is
    itself; a capsule or cylinder gives its two end centres and its middle with
    its radius (a cylinder's rims are rounded); a box its 8 corners and a mesh
    the vertices of its convex hull (radius 0). ``bodies``: names or indices
    (default all)."""
    check_model(model)
    bodies = range(model.nb) if bodies is None else body_indices(model, bodies)
    rows = []
    for b in bodies:
        for g in model.bodies[b].geoms:
            R, p = g.pose.matrix()
            if g.kind == "sphere":
                local, r = np.zeros((1, 3)), g.size[0]
            elif g.kind in ("capsule", "cylinder"):
                local, r = np.outer([-1.0, 0.0, 1.0], [0.0, 0.0, g.size[1]]), g.size[0]
            elif g.kind == "box":
                signs = np.array(np.meshgrid(*[[-1.0, 1.0]] * 3)).reshape(3, -1).T
                local, r = signs * np.asarray(g.size, float), 0.0
            else:                                   # a mesh (Geom checks the kind)
                local, r = np.asarray(g.mesh.convex_hull.vertices, float), 0.0
            for x in local:
                rows.append((b, p + R @ x, r))
    if not rows:
        which = "" if len(bodies) == model.nb else (
            f" on bodies {show([model.body_names[b] for b in bodies])}")
        raise ModelError(f"model {model.name!r} has no geometry{which} to take contact points "
                         f"from")
    b, c, r = zip(*rows, strict=True)
    return np.array(b, int), np.array(c), np.array(r, float)


class FloorContact:
    """Penalty contact of the bodies' contact spheres (:func:`contact_points`)
    with the horizontal floor ``z = height`` (Kim 2008 §6.1, the falling
    character), with Coulomb-style friction.

    Each body of mass ``m`` with ``n`` contact points, all touching, rests on
    them as a mass on a spring of natural ``frequency`` w (rad/s) and
    ``damping_ratio`` (fewer touching: a softer spring): a point at
    depth ``d`` pushes up with ``F_n = max(0, m w^2 d / n - 2 zeta m w v_z / n)``
    (no suction) at the sphere's lowest point. Friction opposes the sliding
    velocity ``v_t`` of that point with ``min(mu F_n, c |v_t|)``, ``c = 2 zeta m w
    / n`` the normal damper: Coulomb's law while sliding fast, viscous below
    ``mu F_n / c`` (regularised, and as stable as the normal damper: a stiffer
    viscous part makes light bodies chatter). Stable for ``w dt`` up to about 0.5
    with the semi-implicit integrator (``docs/forces.md``).
    """

    def __init__(self, model, height=0.0, frequency=150.0, damping_ratio=0.7, friction=0.8,
                 bodies=None):
        self.model = check_model(model)
        self.height = float(check_real("height", height))
        self.frequency = float(check_real("frequency", frequency, positive=True))
        self.damping_ratio = float(check_real("damping_ratio", damping_ratio, nonnegative=True))
        self.friction = float(check_real("friction", friction, nonnegative=True))
        chosen = None if bodies is None else body_indices(model, bodies)
        body, self.centres, self.radii = contact_points(model, chosen)
        self.bodies, self.point_body = np.unique(body, return_inverse=True)
        n = np.bincount(self.point_body)
        m = model.mass[self.bodies]
        self.k = (m * self.frequency**2 / n)[self.point_body]
        self.c = (2 * self.damping_ratio * m * self.frequency / n)[self.point_body]

    def points(self, states):
        """Lowest points of the contact spheres (m, 3), their depths below the
        floor (m,) and velocities (m, 3), world frame."""
        R, p, w, v = (s[self.point_body] for s in states)
        x = p + mv(R, self.centres)
        x[:, 2] -= self.radii
        return x, self.height - x[:, 2], v + cross3(w, x - p)

    def wrenches(self, t, states):
        R, p = states[0][self.point_body], states[1][self.point_body]
        x, depth, xd = self.points(states)
        touch = depth > 0
        Fn = np.where(touch, np.maximum(self.k * depth - self.c * xd[:, 2], 0.0), 0.0)
        vt = xd.copy()
        vt[:, 2] = 0.0
        speed = np.linalg.norm(vt, axis=1)
        Ft = np.minimum(self.friction * Fn, self.c * speed)
        F = -(Ft / np.maximum(speed, 1e-12))[:, None] * vt
        F[:, 2] = Fn
        W = point_wrenches(self.model, self.bodies[self.point_body], R, p, x, F)
        out = np.zeros((len(self.bodies), 6))
        np.add.at(out, self.point_body, W)
        return out

    def energy(self, t, states):
        """Elastic energy of the penetrating points, ``k d^2 / 2`` summed."""
        d = np.maximum(self.points(states)[1], 0.0)
        return float(np.sum(self.k * d**2) / 2)


def joint_inertia(model, j, kind="inertia"):
    """The lighter side of joint ``j`` (a joint name or index): the smaller of its
    child's and its parent body's largest moment of inertia about the joint
    (``kind="mass"``: the smaller mass). A spring or damper on the joint
    accelerates both sides, so its stable stiffness and damping at a time step
    scale with this value (``docs/forces.md``)."""
    check_model(model)
    if isinstance(j, str):
        j = model.joint_index(j)
    elif (i := whole_index(model, j)) is None:
        raise InputError(f"j: {j!r} is neither a joint name nor a joint index of "
                         f"{model.name!r} (0..{model.nb - 1})")
    else:
        j = i
    if kind not in ("inertia", "mass"):
        raise InputError(f"kind must be 'inertia' or 'mass', got {show(kind)}")

    def about(b, point):
        d = model.com[b] - point
        return np.max(np.linalg.eigvalsh(model.inertia[b]
                                         + model.mass[b] * (d @ d * np.eye(3) - np.outer(d, d))))

    stages = model.joints[j].build_stages()
    parent = model.parent[j]
    if kind == "mass":
        return float(min(model.mass[j], model.mass[parent] if parent >= 0 else np.inf))
    anchor = np.asarray(stages[0].anchor if stages else (0.0, 0.0, 0.0), float)
    child = about(j, anchor)
    return float(min(child, about(parent, model.placement_p[j]) if parent >= 0 else np.inf))


class JointLimits:
    """Penalty joint limits (``docs/forces.md``): a hinge or slide leaves
    ``[low, high]``, a ball joint turns more than ``angle`` from its zero (a cone
    on the rotation vector).

    limits: ``{joint name: (low, high)}`` for one-dof joints, ``{joint name:
    angle}`` for ball joints. Beyond a limit by ``e``, the joint feels
    ``-k e - c max(rate outwards, 0)`` with ``k = I w^2`` and ``c = 2 zeta I w``,
    ``I`` = :func:`joint_inertia` (for slides the lighter mass): each limit is a
    spring of natural ``frequency`` w on the lighter side of the joint alone,
    whose damping never holds a joint at its limit.
    """

    def __init__(self, model, limits, frequency=60.0, damping_ratio=1.0):
        self.model = check_model(model)
        if not isinstance(limits, dict):
            raise InputError(f"limits must be a dict {{joint name: (low, high) or cone angle}}, "
                             f"got {type(limits).__name__}: {show(limits)}")
        frequency = float(check_real("frequency", frequency, positive=True))
        zeta = float(check_real("damping_ratio", damping_ratio, nonnegative=True))
        hinge, ball = [], []
        for name, limit in limits.items():
            if not isinstance(name, str):
                raise InputError(f"limits: keys must be joint names, got {show(name)}")
            j = model.joint_index(name)
            stages = model.joints[j].build_stages()
            kinds = [s.kind for s in stages]
            I_joint = joint_inertia(model, j)
            if kinds in (["hinge"], ["slide"]):
                if real_array(f"limits[{name!r}]", limit).shape != (2,):
                    raise InputError(f"limits[{name!r}]: a one-dof joint takes (low, high), "
                                     f"got {show(limit)}")
                low, high = check_real(f"limits[{name!r}]", limit, (2,))
                if low > high:
                    raise InputError(f"joint {name!r}: limit low {low} > high {high}")
                inertia = joint_inertia(model, j, "mass") if kinds == ["slide"] else I_joint
                hinge.append((model.v_start[j], low, high, inertia))
            elif kinds == ["ball"]:
                if real_array(f"limits[{name!r}]", limit).ndim != 0:
                    raise InputError(f"limits[{name!r}]: a ball joint takes one cone angle, "
                                     f"got {show(limit)}")
                angle = float(check_real(f"limits[{name!r}]", limit, positive=True))
                ball.append((model.q_start[j], model.v_start[j], angle, I_joint))
            else:
                raise ModelError(f"joint {name!r}: limits need a one-dof or ball joint, not "
                                 f"stages {kinds}")
        h = np.array(hinge, float).reshape(-1, 4)
        self.h_dof, self.low, self.high = h[:, 0].astype(int), h[:, 1], h[:, 2]
        self.h_q = model.q_start[model.dof_joint[self.h_dof]]
        self.h_k, self.h_c = h[:, 3] * frequency**2, 2 * zeta * h[:, 3] * frequency
        b = np.array(ball, float).reshape(-1, 4)
        self.b_q, self.b_v, self.angle = b[:, 0].astype(int), b[:, 1].astype(int), b[:, 2]
        self.b_k, self.b_c = b[:, 3] * frequency**2, 2 * zeta * b[:, 3] * frequency

    def excess(self, q):
        """How far each limit is exceeded: hinges (h,) signed (+: above high,
        -: below low, 0 inside), balls (b,) angle beyond the cone (>= 0), and the
        balls' rotation vectors (b, 3)."""
        qh = q[self.h_q]
        e_h = np.maximum(qh - self.high, 0.0) + np.minimum(qh - self.low, 0.0)
        r = quat_log(q[self.b_q[:, None] + np.arange(4)]) if len(self.b_q) else np.zeros((0, 3))
        return e_h, np.maximum(np.linalg.norm(r, axis=1) - self.angle, 0.0), r

    def tau(self, t, q, qd, out):
        """Add the limit torques to ``out`` (nv,)."""
        e_h, e_b, r = self.excess(q)
        rate = qd[self.h_dof]
        outward = np.where(e_h * rate > 0, rate, 0.0)
        out[self.h_dof] -= self.h_k * e_h + self.h_c * outward
        if len(self.b_q):
            u = r / np.maximum(np.linalg.norm(r, axis=1), 1e-12)[:, None]
            w = qd[self.b_v[:, None] + np.arange(3)]
            rate_out = np.maximum(np.einsum("ki,ki->k", w, u), 0.0)
            T = np.where(e_b > 0, self.b_k * e_b + self.b_c * rate_out, 0.0)
            np.add.at(out, self.b_v[:, None] + np.arange(3), -T[:, None] * u)

    def energy(self, q):
        e_h, e_b, _ = self.excess(q)
        return float(np.sum(self.h_k * e_h**2) + np.sum(self.b_k * e_b**2)) / 2


def _has(element, method):
    """Whether ``element`` has a callable ``method``."""
    return callable(getattr(element, method, None))


def _wrench(e):
    """Whether ``e`` is a wrench element: ``wrenches(t, states)`` and ``bodies``."""
    return _has(e, "wrenches") and hasattr(e, "bodies")


def _is_element(e):
    """Whether ``e`` has the interface of a force element: a wrench element, or
    ``tau(t, q, qd, out)`` and ``energy(q)`` (a joint-space element), or both."""
    return (_wrench(e) or _has(e, "tau")) and (_has(e, "energy") or not _has(e, "tau"))


class Forces:
    """The sum of force ``elements`` on ``model``, as the simulator's callables.

    Elements with ``wrenches(t, states)`` (springs, random torques, contact) give
    :meth:`external`; elements with ``tau(t, q, qd, out)`` (joint limits) give
    :meth:`controller`. The body states every wrench element needs are computed
    once per call, for those bodies only (an element whose ``needs_states`` is
    False gets ``None``). ``elements``: a list or tuple of such objects (an
    element need not come from this module)."""

    def __init__(self, model, elements):
        self.model = check_model(model)
        if not isinstance(elements, (list, tuple)):
            raise InputError(f"elements must be a list or tuple of force elements, got "
                             f"{type(elements).__name__}: {show(elements)}")
        self.elements = tuple(elements)
        for i, e in enumerate(self.elements):
            if not _is_element(e):
                raise InputError(f"elements[{i}] is not a force element (an object with "
                                 f"wrenches(t, states) and bodies, or tau(t, q, qd, out) and "
                                 f"energy(q)), got {type(e).__name__}: {show(e)}")
            if getattr(e, "model", model) is not model:
                raise InputError(f"force element {type(e).__name__} was built for another "
                                 f"model than {model.name!r}")
            if _wrench(e):
                body_indices(model, e.bodies, f"elements[{i}].bodies")
        self.wrench_elements = [e for e in self.elements if _wrench(e)]
        self.tau_elements = [e for e in self.elements if _has(e, "tau")]
        self._needs = [getattr(e, "needs_states", True) for e in self.wrench_elements]
        bodies = [e.bodies for e, need in zip(self.wrench_elements, self._needs, strict=True)
                  if need]
        self.state_bodies = np.unique(np.concatenate(bodies)) if bodies else np.zeros(0, int)
        self.states = BodyStates(model, self.state_bodies) if len(self.state_bodies) else None
        row = np.full(model.nb, -1)
        row[self.state_bodies] = np.arange(len(self.state_bodies))
        self._rows = [row[e.bodies] for e in self.wrench_elements]

    def states_of(self, element, q, qd, states=None):
        """The body states (:class:`BodyStates` output) of ``element``'s bodies;
        ``states``: those of all :attr:`state_bodies`, if already computed."""
        rows = self._rows[self.wrench_elements.index(element)]
        return tuple(s[rows] for s in (self.states(q, qd) if states is None else states))

    @property
    def external(self):
        """``external(t, q, qd) -> f_ext`` (nb, 6), or None without wrench elements."""
        return self._external if self.wrench_elements else None

    @property
    def controller(self):
        """``controller(t, q, qd) -> tau`` (nv,), or None without joint-space elements."""
        return self._controller if self.tau_elements else None

    def _external(self, t, q, qd):
        f = np.zeros((self.model.nb, 6))
        all_states = self.states(q, qd) if self.states is not None else None
        for e, rows, need in zip(self.wrench_elements, self._rows, self._needs, strict=True):
            states = tuple(s[rows] for s in all_states) if need else None
            np.add.at(f, e.bodies, e.wrenches(t, states))
        return f

    def _controller(self, t, q, qd):
        tau = np.zeros(self.model.nv)
        for e in self.tau_elements:
            e.tau(t, q, qd, tau)
        return tau

    def potential_energy(self, t, q):
        """Elastic energy stored in the springs, contacts and limits at ``(t, q)``."""
        e = 0.0
        qd = np.zeros(self.model.nv)
        states = self.states(q, qd) if self.states is not None else None
        for el in self.wrench_elements:
            if hasattr(el, "energy"):
                e += el.energy(t, self.states_of(el, q, qd, states))
        for el in self.tau_elements:
            e += el.energy(q)
        return e


__all__ = ["BodyStates", "Drag", "FloorContact", "Forces", "JointLimits", "RandomTorques",
           "Springs", "contact_points", "joint_inertia", "point_wrenches"]
