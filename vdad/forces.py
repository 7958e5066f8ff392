"""Forces that the paper's scenes need (Kim 2008 §6.1; derivations in ``docs/forces.md``).

Springs and virtual strings from body points to world points that may move (the
puppet's control stick, the hanging dogs' anchors), intermittent random torques
from a seeded generator (the hanging dogs), penalty contact with a floor and
Coulomb-style friction (the falling character), and joint limits. Each element
kind is one compiled kernel over its bodies (:func:`spring_wrenches`,
:func:`drag_wrenches`, :func:`floor_wrenches`, :func:`pulse_torques`,
:func:`limit_torques`); :class:`Forces` sums the elements into the
``external(t, q, qd) -> f_ext`` (nb, 6) and ``controller(t, q, qd) -> tau`` (nv,)
callables of :class:`~vdad.Simulator`, and :class:`ForceTables` hands the same
elements to the compiled step loop (:func:`apply_forces`), which calls the same
kernels: a simulator of vdad's own forces never returns to Python between steps.
External wrenches follow
``docs/conventions.md``: torque about each body's centre of mass, then force,
world axes. With the adaptive methods they enter through the force-update region
(:meth:`~vdad.hybrid.RigidGroups.update_forces`).

Only the bodies an element acts on (and their ancestors) are placed: a spring on
the torsos of 100 dogs costs the kinematics of 100 free joints, not 1600 joints.
"""

from __future__ import annotations

import numpy as np

from ._linalg import as_input, inlined, pass_kernel, quaternion_log
from .checks import check_real, real_array, show
from .errors import InputError, ModelError
from .kinematics import Kinematics, joint_set, kinematics, kinematics_pass
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
        w, v = np.empty((js.k, 3)), np.empty((js.k, 3))
        world_velocities(kin.R, kin.v, w, v)
        rows = self.rows
        return kin.R[rows], kin.p[rows], w[rows], v[rows]


# --- compiled kernels: one per element kind ----------------------------------------------

@inlined
def world_velocities(R, v, w, vo):
    """Angular velocities ``w`` and origin velocities ``vo`` (k, 3) in world axes of
    bodies with rotations ``R`` and body-axes velocities ``v`` (k, 6)."""
    for i in range(R.shape[0]):
        Ri, vi = R[i], v[i]
        for r in range(3):
            w[i, r] = Ri[r, 0] * vi[0] + Ri[r, 1] * vi[1] + Ri[r, 2] * vi[2]
            vo[i, r] = Ri[r, 0] * vi[3] + Ri[r, 1] * vi[4] + Ri[r, 2] * vi[5]


# Each reads body states (R (., 3, 3), p, w, v (., 3), world) at the rows ``rows`` and
# adds its wrenches (torque about the centre of mass, force; world axes) into
# ``f[target]`` (., 6): the elements' own methods call them with their bodies' states
# and ``target = 0..k-1``, the compiled step loop with every body's state.

@inlined
def _add_point_force(x0, x1, x2, F0, F1, F2, p, R, com, f):
    """``f += ((x - c) × F, F)`` with ``c = p + R com`` the centre of mass."""
    c0 = p[0] + R[0, 0] * com[0] + R[0, 1] * com[1] + R[0, 2] * com[2]
    c1 = p[1] + R[1, 0] * com[0] + R[1, 1] * com[1] + R[1, 2] * com[2]
    c2 = p[2] + R[2, 0] * com[0] + R[2, 1] * com[1] + R[2, 2] * com[2]
    d0, d1, d2 = x0 - c0, x1 - c1, x2 - c2
    f[0] += d1 * F2 - d2 * F1
    f[1] += d2 * F0 - d0 * F2
    f[2] += d0 * F1 - d1 * F0
    f[3] += F0
    f[4] += F1
    f[5] += F2


@inlined
def spring_wrenches(rows, target, points, com, anchors, anchor_vel, stiffness, damping, rest,
                    string, R, p, w, v, f):
    """:class:`Springs` (``docs/forces.md``): the force ``-(k (L - L0) + c dL/dt) u``
    at each attachment point, ``u`` the unit vector from the anchor; a string
    pulls only while ``L > L0`` and never pushes."""
    for i in range(rows.shape[0]):
        b = rows[i]
        Rb, pt = R[b], points[i]
        x0 = Rb[0, 0] * pt[0] + Rb[0, 1] * pt[1] + Rb[0, 2] * pt[2]   # R point
        x1 = Rb[1, 0] * pt[0] + Rb[1, 1] * pt[1] + Rb[1, 2] * pt[2]
        x2 = Rb[2, 0] * pt[0] + Rb[2, 1] * pt[1] + Rb[2, 2] * pt[2]
        d0, d1, d2 = p[b, 0] + x0 - anchors[i, 0], p[b, 1] + x1 - anchors[i, 1], \
            p[b, 2] + x2 - anchors[i, 2]
        L = np.sqrt(d0 * d0 + d1 * d1 + d2 * d2)
        s = max(L, 1e-12)
        u0, u1, u2 = d0 / s, d1 / s, d2 / s
        wb, vb = w[b], v[b]
        r0 = vb[0] + wb[1] * x2 - wb[2] * x1 - anchor_vel[i, 0]
        r1 = vb[1] + wb[2] * x0 - wb[0] * x2 - anchor_vel[i, 1]
        r2 = vb[2] + wb[0] * x1 - wb[1] * x0 - anchor_vel[i, 2]
        T = stiffness[i] * (L - rest[i]) + damping[i] * (u0 * r0 + u1 * r1 + u2 * r2)
        if string[i]:
            T = max(T, 0.0) if L > rest[i] else 0.0
        _add_point_force(p[b, 0] + x0, p[b, 1] + x1, p[b, 2] + x2, -T * u0, -T * u1, -T * u2,
                         p[b], Rb, com[i], f[target[i]])


@inlined
def drag_wrenches(rows, target, rate, mass, com, inertia, R, p, w, v, f):
    """:class:`Drag`: ``-rate (I w; m v_c)``, ``I`` in world axes, ``v_c`` the
    velocity of the centre of mass (``rate`` per row)."""
    for i in range(rows.shape[0]):
        b, Rb, wb, I = rows[i], R[rows[i]], w[rows[i]], inertia[i]
        a0 = Rb[0, 0] * wb[0] + Rb[1, 0] * wb[1] + Rb[2, 0] * wb[2]    # R^T w
        a1 = Rb[0, 1] * wb[0] + Rb[1, 1] * wb[1] + Rb[2, 1] * wb[2]
        a2 = Rb[0, 2] * wb[0] + Rb[1, 2] * wb[1] + Rb[2, 2] * wb[2]
        Ia0 = I[0, 0] * a0 + I[0, 1] * a1 + I[0, 2] * a2
        Ia1 = I[1, 0] * a0 + I[1, 1] * a1 + I[1, 2] * a2
        Ia2 = I[2, 0] * a0 + I[2, 1] * a1 + I[2, 2] * a2
        c0 = Rb[0, 0] * com[i, 0] + Rb[0, 1] * com[i, 1] + Rb[0, 2] * com[i, 2]   # R com
        c1 = Rb[1, 0] * com[i, 0] + Rb[1, 1] * com[i, 1] + Rb[1, 2] * com[i, 2]
        c2 = Rb[2, 0] * com[i, 0] + Rb[2, 1] * com[i, 1] + Rb[2, 2] * com[i, 2]
        fi = f[target[i]]
        vc0 = v[b, 0] + wb[1] * c2 - wb[2] * c1
        vc1 = v[b, 1] + wb[2] * c0 - wb[0] * c2
        vc2 = v[b, 2] + wb[0] * c1 - wb[1] * c0
        for r in range(3):
            fi[r] -= rate[i] * (Rb[r, 0] * Ia0 + Rb[r, 1] * Ia1 + Rb[r, 2] * Ia2)
        fi[3] -= rate[i] * (mass[i] * vc0)
        fi[4] -= rate[i] * (mass[i] * vc1)
        fi[5] -= rate[i] * (mass[i] * vc2)


@inlined
def floor_wrenches(rows, target, centres, radii, com, k, c, friction, height, R, p, w, v, f):
    """:class:`FloorContact`: per contact sphere, at its lowest point ``x`` at
    depth ``height - x_z``, the normal force ``max(0, k d - c v_z)`` while it
    touches and the friction ``-min(mu F_n, c |v_t|) v_t / |v_t|`` (``friction``
    and ``height`` per point)."""
    for m in range(rows.shape[0]):
        b = rows[m]
        Rb, cm = R[b], centres[m]
        x0 = p[b, 0] + Rb[0, 0] * cm[0] + Rb[0, 1] * cm[1] + Rb[0, 2] * cm[2]
        x1 = p[b, 1] + Rb[1, 0] * cm[0] + Rb[1, 1] * cm[1] + Rb[1, 2] * cm[2]
        x2 = p[b, 2] + Rb[2, 0] * cm[0] + Rb[2, 1] * cm[1] + Rb[2, 2] * cm[2] - radii[m]
        depth = height[m] - x2
        wb, vb = w[b], v[b]
        e0, e1, e2 = x0 - p[b, 0], x1 - p[b, 1], x2 - p[b, 2]
        xd0 = vb[0] + wb[1] * e2 - wb[2] * e1
        xd1 = vb[1] + wb[2] * e0 - wb[0] * e2
        xd2 = vb[2] + wb[0] * e1 - wb[1] * e0
        Fn = max(k[m] * depth - c[m] * xd2, 0.0) if depth > 0 else 0.0
        speed = np.sqrt(xd0 * xd0 + xd1 * xd1)
        Ft = min(friction[m] * Fn, c[m] * speed)
        g = Ft / max(speed, 1e-12)
        _add_point_force(x0, x1, x2, -g * xd0, -g * xd1, Fn, p[b], Rb, com[m], f[target[m]])


@inlined
def pulse_torques(t, target, start, torque, duration, f):
    """:class:`RandomTorques`: the sum of the pulses ``start <= t < start +
    duration`` on each body (torques in ``f[target][:3]``; ``duration`` per pulse)."""
    for m in range(start.shape[0]):
        if start[m] <= t < start[m] + duration[m]:
            fi = f[target[m]]
            for r in range(3):
                fi[r] += torque[m, r]


@inlined
def limit_torques(h_dof, h_q, low, high, h_k, h_c, b_q, b_v, angle, b_k, b_c, q, qd, tau):
    """:class:`JointLimits`: ``-k e - c max(rate outwards, 0)`` on each hinge or
    slide beyond ``[low, high]`` by ``e``, and on each ball beyond its cone, along
    its rotation vector."""
    for i in range(h_dof.shape[0]):
        qh = q[h_q[i]]
        e = max(qh - high[i], 0.0) + min(qh - low[i], 0.0)
        rate = qd[h_dof[i]]
        outward = rate if e * rate > 0 else 0.0
        tau[h_dof[i]] -= h_k[i] * e + h_c[i] * outward
    for i in range(b_q.shape[0]):
        iq = b_q[i]
        r = quaternion_log(q[iq], q[iq + 1], q[iq + 2], q[iq + 3])
        n = np.sqrt(r[0] * r[0] + r[1] * r[1] + r[2] * r[2])
        e = max(n - angle[i], 0.0)
        if e > 0:
            s = max(n, 1e-12)
            iv = b_v[i]
            rate_out = max((qd[iv] * r[0] + qd[iv + 1] * r[1] + qd[iv + 2] * r[2]) / s, 0.0)
            T = b_k[i] * e + b_c[i] * rate_out
            for c in range(3):
                tau[iv + c] -= T * r[c] / s


def _rows(k):
    return np.arange(k, dtype=np.int64)


@inlined
def _point_wrenches(x, F, p, R, com, f):
    for i in range(x.shape[0]):
        _add_point_force(x[i, 0], x[i, 1], x[i, 2], F[i, 0], F[i, 1], F[i, 2], p[i], R[i], com[i],
                         f[i])


def point_wrenches(model, bodies, R, p, x, F):
    """Wrenches (k, 6) of forces ``F`` (k, 3) applied at world points ``x`` (k, 3)
    of ``bodies`` with poses ``R, p``: torque about each centre of mass, force
    (:func:`_add_point_force`, as the elements' kernels)."""
    f = np.zeros((len(x), 6))
    _point_wrenches(as_input(x), as_input(F), as_input(p), as_input(R),
                    as_input(model.com[bodies]), f)
    return f


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

    def anchor_states(self, times):
        """Anchor positions and velocities (E, k, 3) at each of ``times`` (E,), as
        :meth:`anchor_state`; in one call each when the anchors callable has a
        ``many(times) -> (E, k, 3)`` method (e.g. the puppet's stick path)."""
        times = np.asarray(times, float)
        many = getattr(self.anchors, "many", None) if self.moving else None
        if many is None:
            states = [self.anchor_state(t) for t in times]
            return np.array([a for a, _ in states]), np.array([v for _, v in states])
        k, h = len(self.bodies), 1e-4
        a = check_real("anchors(t)", many(times), (len(times), k, 3))
        va = (np.asarray(many(times + h), float) - np.asarray(many(times - h), float)) / (2 * h)
        return a, va

    def lengths(self, t, states):
        """Spring lengths (k,) for body ``states`` (:class:`BodyStates` output)."""
        R, p = states[:2]
        return np.linalg.norm(p + mv(R, self.points) - self.anchor_state(t)[0], axis=1)

    def wrenches(self, t, states):
        """Wrenches (k, 6) on ``self.bodies`` (:func:`spring_wrenches`)."""
        R, p, w, v = (as_input(s) for s in states)
        a, va = self.anchor_state(t)
        k = len(self.bodies)
        f = np.zeros((k, 6))
        spring_wrenches(_rows(k), _rows(k), self.points, self.model.com[self.bodies],
                        as_input(a), as_input(va), self.stiffness, self.damping,
                        self.rest_length, np.full(k, self.string), R, p, w, v, f)
        return f

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

    def table(self, t0, t1):
        """Every pulse that acts in ``[t0, t1]``: ``(body rows, start times, torques
        (n, 3))``, window by window (the order :func:`pulse_torques` sums them)."""
        windows = [self.pulses(w) for w in range(max(int(np.floor(t0 - self.duration)), 0),
                                                 int(np.floor(t1)) + 1)]
        rows, start, tau = zip(*windows, strict=True) if windows else ((), (), ())
        return (np.concatenate([np.zeros(0, np.int64), *rows]).astype(np.int64),
                np.concatenate([np.zeros(0), *start]),
                np.concatenate([np.zeros((0, 3)), *tau]))

    def torques(self, t):
        """Torques (k, 3) on ``self.bodies`` at time ``t``."""
        rows, start, tau = self.table(t, t)
        f = np.zeros((len(self.bodies), 6))
        pulse_torques(float(t), rows, start, tau, np.full(len(start), self.duration), f)
        return f[:, :3]

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
        R, p, w, v = (as_input(s) for s in states)
        m, k = self.model, len(self.bodies)
        f = np.zeros((k, 6))
        drag_wrenches(_rows(k), _rows(k), np.full(k, self.rate), m.mass[self.bodies],
                      m.com[self.bodies], m.inertia[self.bodies], R, p, w, v, f)
        return f


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
        self.bodies, point_body = np.unique(body, return_inverse=True)
        self.point_body = point_body.astype(np.int64)
        self.point_com = model.com[self.bodies[self.point_body]]
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
        R, p, w, v = (as_input(s) for s in states)
        f = np.zeros((len(self.bodies), 6))
        n = len(self.point_body)
        floor_wrenches(self.point_body, self.point_body, self.centres, self.radii,
                       self.point_com, self.k, self.c, np.full(n, self.friction),
                       np.full(n, self.height), R, p, w, v, f)
        return f

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
    angle}`` for ball joints, ``{joint name: ((low, high) or None, ...)}`` (one
    entry per stage) for composite joints of hinges and slides (the ranges of
    MuJoCo's multi-joint bodies). Beyond a limit by ``e``, the joint feels
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
            if len(kinds) > 1 and set(kinds) <= {"hinge", "slide"}:
                if not isinstance(limit, (tuple, list)) or len(limit) != len(kinds):
                    raise InputError(f"limits[{name!r}]: a composite joint of {len(kinds)} "
                                     f"stages takes one (low, high) or None per stage, got "
                                     f"{show(limit)}")
                ranges = list(limit)
            elif kinds in (["hinge"], ["slide"]):
                if real_array(f"limits[{name!r}]", limit).shape != (2,):
                    raise InputError(f"limits[{name!r}]: a one-dof joint takes (low, high), "
                                     f"got {show(limit)}")
                ranges = [limit]
            elif kinds == ["ball"]:
                if real_array(f"limits[{name!r}]", limit).ndim != 0:
                    raise InputError(f"limits[{name!r}]: a ball joint takes one cone angle, "
                                     f"got {show(limit)}")
                angle = float(check_real(f"limits[{name!r}]", limit, positive=True))
                ball.append((model.q_start[j], model.v_start[j], angle, I_joint))
                continue
            else:
                raise ModelError(f"joint {name!r}: limits need a one-dof, ball or composite "
                                 f"hinge and slide joint, not stages {kinds}")
            first = int(np.flatnonzero(model.stage_joint == j)[0])
            for k, (kind, pair) in enumerate(zip(kinds, ranges, strict=True)):
                if pair is None:
                    continue
                low, high = check_real(f"limits[{name!r}]", pair, (2,))
                if low > high:
                    raise InputError(f"joint {name!r}: limit low {low} > high {high}")
                inertia = joint_inertia(model, j, "mass") if kind == "slide" else I_joint
                hinge.append((model.stage_v[first + k], model.stage_q[first + k], low, high,
                              inertia))
        h = np.array(hinge, float).reshape(-1, 5)
        h = np.ascontiguousarray(h.T)
        self.h_dof, self.h_q = h[0].astype(np.int64), h[1].astype(np.int64)
        self.low, self.high = h[2], h[3]
        self.h_k, self.h_c = h[4] * frequency**2, 2 * zeta * h[4] * frequency
        b = np.array(ball, float).reshape(-1, 4)
        b = np.ascontiguousarray(b.T)
        self.b_q, self.b_v, self.angle = b[0].astype(np.int64), b[1].astype(np.int64), b[2]
        self.b_k, self.b_c = b[3] * frequency**2, 2 * zeta * b[3] * frequency

    def excess(self, q):
        """How far each limit is exceeded: hinges (h,) signed (+: above high,
        -: below low, 0 inside), balls (b,) angle beyond the cone (>= 0), and the
        balls' rotation vectors (b, 3)."""
        qh = q[self.h_q]
        e_h = np.maximum(qh - self.high, 0.0) + np.minimum(qh - self.low, 0.0)
        r = quat_log(q[self.b_q[:, None] + np.arange(4)]) if len(self.b_q) else np.zeros((0, 3))
        return e_h, np.maximum(np.linalg.norm(r, axis=1) - self.angle, 0.0), r

    @property
    def arrays(self) -> tuple:
        """The tables :func:`limit_torques` reads."""
        return (self.h_dof, self.h_q, self.low, self.high, self.h_k, self.h_c, self.b_q,
                self.b_v, self.angle, self.b_k, self.b_c)

    def tau(self, t, q, qd, out):
        """Add the limit torques to ``out`` (nv,) (:func:`limit_torques`)."""
        tau = as_input(out)
        limit_torques(*self.arrays, as_input(q), as_input(qd), tau)
        if tau is not out:
            out[:] = tau

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


class ForceTables:
    """The elements of a :class:`Forces` as the arrays the compiled step loop reads
    (:func:`vdad.integrators.dca_steps`), or ``None`` from :meth:`of` where an
    element is not one of vdad's own (its Python methods must run then).

    Springs, drag and contact act on model bodies; random torques, moving anchors
    and the pulses' windows depend on time and are tabulated per chunk of steps
    by :meth:`arrays`."""

    BUILT_IN = ()                # set below the element classes' definitions

    @classmethod
    def of(cls, forces):
        if not all(type(e) in cls.BUILT_IN for e in forces.elements):
            return None
        return cls(forces)

    def __init__(self, forces):
        m = forces.model
        kinds = {k: [e for e in forces.elements if type(e) is k] for k in self.BUILT_IN}
        sp = kinds[Springs]
        cat, i64, vec = self._cat, np.int64, (3,)
        self.springs = sp
        self.spring = (cat([e.bodies for e in sp], i64), cat([e.points for e in sp], tail=vec),
                       cat([m.com[e.bodies] for e in sp], tail=vec),
                       cat([e.stiffness for e in sp]), cat([e.damping for e in sp]),
                       cat([e.rest_length for e in sp]),
                       cat([np.full(len(e.bodies), e.string) for e in sp], bool))
        dr = kinds[Drag]
        self.drag = (cat([e.bodies for e in dr], i64),
                     cat([np.full(len(e.bodies), e.rate) for e in dr]),
                     cat([m.mass[e.bodies] for e in dr]),
                     cat([m.com[e.bodies] for e in dr], tail=vec),
                     cat([m.inertia[e.bodies] for e in dr], tail=(3, 3)))
        fc = kinds[FloorContact]
        self.floor = (cat([e.bodies[e.point_body] for e in fc], i64),
                      cat([e.centres for e in fc], tail=vec), cat([e.radii for e in fc]),
                      cat([e.point_com for e in fc], tail=vec), cat([e.k for e in fc]),
                      cat([e.c for e in fc]),
                      cat([np.full(len(e.point_body), e.friction) for e in fc]),
                      cat([np.full(len(e.point_body), e.height) for e in fc]))
        self.pulses = kinds[RandomTorques]
        #: what :meth:`arrays` gives at every call where nothing depends on time
        #: (None until its first call, or where something does)
        self.fixed = None
        lim = [e.arrays for e in kinds[JointLimits]]
        self.limits = tuple(cat([a[i] for a in lim], i64 if i in (0, 1, 6, 7) else float)
                            for i in range(11))

    @staticmethod
    def _cat(arrays, dtype=float, tail=()):
        """Concatenation of ``arrays`` as one contiguous ``dtype`` array; with none,
        an empty one of trailing shape ``tail``."""
        if not arrays:
            return np.zeros((0, *tail), dtype)
        return np.ascontiguousarray(np.concatenate(arrays), dtype)

    def arrays(self, step0, n, dt, use_rk4):
        """The tuple :func:`apply_forces` reads, for the evaluations of ``n`` steps
        of ``dt`` from step ``step0`` (:func:`evaluation_times`): anchors and their
        velocities per evaluation (one row if none moves) and every random-torque
        pulse acting between the first and the last time. Without moving anchors
        and pulses, the same tuple at every call."""
        if self.fixed is not None:
            return self.fixed
        times = evaluation_times(step0, n, dt, use_rk4)
        cat = self._cat
        moving = [e for e in self.springs if e.moving]
        rows = 1 if not moving else len(times)
        anchors = np.zeros((rows, len(self.spring[0]), 3))
        velocity = np.zeros_like(anchors)
        at = 0
        for e in self.springs:
            k = len(e.bodies)
            if e.moving:
                anchors[:, at:at + k], velocity[:, at:at + k] = e.anchor_states(times)
            else:
                anchors[:, at:at + k] = e.anchors
            at += k
        tables = [e.table(float(times[0]), float(times[-1])) for e in self.pulses]
        pulses = (cat([e.bodies[t[0]] for e, t in zip(self.pulses, tables, strict=True)],
                      np.int64), cat([t[1] for t in tables]),
                  cat([t[2] for t in tables], tail=(3,)),
                  cat([np.full(len(t[1]), e.duration)
                       for e, t in zip(self.pulses, tables, strict=True)]))
        out = (*self.spring[:3], anchors, velocity, *self.spring[3:], *self.drag, *self.floor,
               *pulses, *self.limits)
        if not moving and not self.pulses:
            self.fixed = out
        return out


def evaluation_times(step0, n, dt, use_rk4):
    """The times (n E,) at which the compiled steps (:func:`vdad.integrators.dca_steps`)
    evaluate forces on ``n`` steps from ``step0``: the step's start, and for RK4
    also its middle (twice) and end."""
    t = (step0 + np.arange(n)) * dt
    if not use_rk4:
        return t
    return (t[:, None] + np.array([0.0, dt / 2, dt / 2, dt])).ravel()


def state_bodies(F):
    """The bodies (k,) whose states the elements of the tables ``F``
    (:meth:`ForceTables.arrays`) read: those springs, drag and contact act on
    (pulses and joint limits read none), as :func:`apply_forces` unpacks them."""
    s_rows, d_rows, c_rows = F[0], F[9], F[14]
    return np.concatenate([s_rows, d_rows, c_rows])


@pass_kernel
def apply_forces(F, e, t, R, p, w, v, q, qd, f, tau):
    """Every built-in element of the tables ``F`` (:meth:`ForceTables.arrays`) at
    evaluation ``e`` and time ``t``: wrenches into ``f`` (nb, 6), joint forces into
    ``tau`` (nv,), from the body states ``R, p, w, v`` of every body."""
    (s_rows, s_points, s_com, anchors, anchor_vel, s_k, s_c, s_rest, s_string,
     d_rows, d_rate, d_mass, d_com, d_inertia,
     c_rows, c_centres, c_radii, c_com, c_k, c_c, c_mu, c_height,
     p_target, p_start, p_torque, p_duration,
     h_dof, h_q, low, high, h_k, h_c, b_q, b_v, angle, b_k, b_c) = F
    a = 0 if anchors.shape[0] == 1 else e
    spring_wrenches(s_rows, s_rows, s_points, s_com, anchors[a], anchor_vel[a], s_k, s_c,
                    s_rest, s_string, R, p, w, v, f)
    drag_wrenches(d_rows, d_rows, d_rate, d_mass, d_com, d_inertia, R, p, w, v, f)
    floor_wrenches(c_rows, c_rows, c_centres, c_radii, c_com, c_k, c_c, c_mu, c_height, R, p,
                   w, v, f)
    pulse_torques(t, p_target, p_start, p_torque, p_duration, f)
    limit_torques(h_dof, h_q, low, high, h_k, h_c, b_q, b_v, angle, b_k, b_c, q, qd, tau)


@pass_kernel
def body_forces(js, F, e, t, q, qd, kin, states, f, tau, fresh=None):
    """Every built-in element of the tables ``F`` at evaluation ``e`` and time ``t``
    at ``(q, qd)``, into ``f`` (nb, 6) and ``tau`` (nv,), both zeroed first: every
    body's state (kinematics with velocities into ``kin``, world-axes angular
    and origin velocities into ``states`` (2, nb, 3)), then :func:`apply_forces`.
    ``fresh``: the joints whose placement ``kin`` holds already
    (:func:`~vdad.kinematics.kinematics_pass`)."""
    kinematics_pass(js, q, qd, True, *kin, fresh)
    R, p, v, w, vo = kin[5], kin[6], kin[7], states[0], states[1]
    world_velocities(R, v, w, vo)
    for i in range(f.shape[0]):
        for r in range(6):
            f[i, r] = 0.0
    for i in range(tau.shape[0]):
        tau[i] = 0.0
    apply_forces(F, e, t, R, p, w, vo, q, qd, f, tau)


ForceTables.BUILT_IN = (Springs, RandomTorques, Drag, FloorContact, JointLimits)


__all__ = ["BodyStates", "Drag", "FloorContact", "ForceTables", "Forces", "JointLimits",
           "RandomTorques", "Springs", "contact_points", "joint_inertia", "point_wrenches",
           "state_bodies"]
