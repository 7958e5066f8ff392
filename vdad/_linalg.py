"""Small fixed-size products for the compiled kernels (PyElastica's ``_linalg.py``).

Every helper writes into an ``out`` array it is given, loops over literal sizes
(``range(6)``, ``range(3)``: numba unrolls them, loops over ``A.shape`` cost 1.6x
the whole kernel, ``../shared/prototypes/numba-dca/MEASUREMENTS.md``) and
allocates nothing. ``@`` and ``np.linalg`` are not used inside kernels: numba would
need SciPy for them and would call BLAS and allocate per 6x6 product. Spatial
conventions are those of :mod:`vdad.spatial` (theory §1): motion ``(w; v)``,
force ``(n; f)``, angular part first.

With ``NUMBA_DISABLE_JIT=1`` these are plain Python functions. The module also
holds the two decorators of vdad's compiled code and :func:`compiling`, the
one-line notice of a first compilation.
"""

from __future__ import annotations

import contextlib
import hashlib
import sys
import threading
from pathlib import Path

import numba
import numpy as np
from numba import config, njit

#: decorator of the compiled functions that allocate (numba's on-disk cache; a
#: division by zero gives inf or NaN, which the callers' checks report, instead of
#: raising inside a kernel; numba's runtime set explicitly, since a compiled
#: function otherwise inherits it from the first caller that compiles it) ...
kernel = njit(cache=True, error_model="numpy", _nrt=True)
#: ... of the passes over nodes and joints and their drivers, which take every
#: array they need (no allocation) and run without numba's reference counting:
#: with it, every view (``Phi[k]``) and every array handed to an inlined kernel
#: costs an atomic increment and decrement, which LLVM cannot prune across a
#: kernel's branches and loops, more than the arithmetic of a joint (3.2x on the
#: kinematics pass), and a call from Python converts each array argument (2.7 µs
#: for the DCA's 70 instead of 5.5). The arrays are the caller's, alive for the
#: whole call (docs/design.md, "The compiled core") ...
pass_kernel = njit(cache=True, error_model="numpy", _nrt=False)
#: ... of passes over independent subtrees that numba runs on its threads ...
parallel_kernel = njit(cache=True, error_model="numpy", parallel=True, _nrt=True)
#: ... and of the per-node and per-joint kernels and the small products below,
#: which numba inlines into the passes that call them: a call between compiled
#: functions is not inlined by LLVM and costs ~10 ns per array argument, more
#: than the arithmetic of a joint (docs/design.md, "The compiled core")
inlined = njit(cache=True, inline="always", error_model="numpy")

NOTICE = ("vdad: compiling the numba kernels (once per installation, a few minutes; "
          "later runs load them from numba's cache)")
_noticed = threading.Event()


@contextlib.contextmanager
def _announce(dispatcher):
    timer = threading.Timer(1.0, _notice, (dispatcher,))
    timer.start()
    try:
        yield
    finally:
        timer.cancel()


def _notice(dispatcher):
    """:data:`NOTICE`, once, if ``dispatcher`` has no compiled version yet (a
    second into a first call that already runs one, the work is long, not the
    compile)."""
    if getattr(dispatcher, "overloads", None) or _noticed.is_set():
        return
    _noticed.set()
    print(NOTICE, file=sys.stderr, flush=True)


def compiling(dispatcher):
    """A context for a call of the compiled ``dispatcher``: on its first call in a
    process (when numba still has to load or compile it), :data:`NOTICE` is printed
    once on stderr if a second into the call numba has not yet loaded or compiled
    it (compiling takes minutes, loading from the cache a fraction of a second; a
    long first run of a loaded kernel says nothing). It also starts numba's
    threading layer, which a kernel loaded from the cache needs if it calls a
    parallel one (:func:`vdad.dca.forest_passes`) and which numba starts only for
    the parallel kernel itself (numba issues #8578, #9938): without it, the step
    loop loaded from the cache in a fresh process crashed."""
    if dispatcher in _called:
        return _NOTHING
    _called.add(dispatcher)
    numba.get_num_threads()
    return _announce(dispatcher)


_called = set()
_NOTHING = contextlib.nullcontext()
EPS = float(np.finfo(float).eps)    # the rounding unit, a compile-time constant in kernels


def source_stamp():
    """A hash of the source of the ``vdad`` modules that define compiled code."""
    sources = [p.read_bytes() for p in sorted(Path(__file__).resolve().parent.glob("*.py"))]
    return hashlib.sha1(b"".join(s for s in sources if b"@kernel" in s or b"@inlined" in s
                                 or b"@pass_kernel" in s or b"@parallel_kernel" in s)
                        ).hexdigest()[:16]


def clear_stale_caches():
    """``docs/design.md``, start-up: numba keys a kernel's cache on its own file,
    but every pass inlines kernels of other modules, and would load stale machine
    code after they change. So vdad's caches carry one stamp, the hash of all its
    sources (``vdad-sources-<hash>.stamp`` beside them): in each of numba's cache
    folders for the package (``NUMBA_CACHE_DIR``, the package's ``__pycache__``,
    the user's cache), a missing stamp deletes the cached kernels there and writes
    it. Runs once, at import, before any kernel is loaded."""
    from numba.core import caching

    stamp_name = f"vdad-sources-{source_stamp()}.stamp"
    source = str(Path(__file__).resolve())
    locators = [caching.InTreeCacheLocator, caching.UserWideCacheLocator]
    if config.CACHE_DIR:
        locators.insert(0, caching.UserProvidedCacheLocator)
    stamped = False                 # the first writable folder is the one numba uses
    for locator in locators:
        try:
            folder = Path(locator(_notice, source).get_cache_path())
            if (folder / stamp_name).exists():
                stamped = True
                continue
            if folder.is_dir():
                for old in [*folder.glob("*.nbi"), *folder.glob("*.nbc"),
                            *folder.glob("vdad-sources-*.stamp")]:
                    old.unlink()
            if not stamped:
                folder.mkdir(parents=True, exist_ok=True)
                (folder / stamp_name).touch()
                stamped = True
        except (OSError, AttributeError, TypeError):
            continue                    # not writable, or a numba without that locator


def as_input(a):
    """``a`` as the one array type the kernels are compiled for: float64,
    C-contiguous and writable (a read-only or strided array would make numba
    compile another version of every kernel it reaches, a minute each)."""
    if (type(a) is np.ndarray and a.dtype == np.float64 and a.flags.c_contiguous
            and a.flags.writeable):
        return a
    return np.array(a, dtype=float, order="C")


@inlined
def finite(x):
    """Whether every entry of the C-contiguous array ``x`` is finite."""
    for v in x.flat:
        if not np.isfinite(v):
            return False
    return True


@inlined
def same(a, b):
    """Whether the vectors ``a`` and ``b`` (n,) are equal."""
    for i in range(a.shape[0]):
        if a[i] != b[i]:
            return False
    return True


@inlined
def copy_state(q, qd, out):
    """``out`` = (q, qd), entry by entry (a slice assignment would allocate)."""
    for i in range(q.shape[0]):
        out[0][i] = q[i]
    for i in range(qd.shape[0]):
        out[1][i] = qd[i]


# --- 6x6 and 6-vector products ---------------------------------------------------------

@inlined
def mm6(A, B, out):
    """``out = A B`` (6, 6)."""
    for i in range(6):
        for j in range(6):
            s = 0.0
            for k in range(6):
                s += A[i, k] * B[k, j]
            out[i, j] = s


@inlined
def is_zero6(A):
    """Whether every entry of ``A`` (6, 6) is zero."""
    for i in range(6):
        for j in range(6):
            if A[i, j] != 0.0:
                return False
    return True


@inlined
def zero6(out):
    """``out = 0`` (6, 6)."""
    for i in range(6):
        for j in range(6):
            out[i, j] = 0.0


@inlined
def mv6(A, x, out):
    """``out = A x`` (6,)."""
    for i in range(6):
        s = 0.0
        for k in range(6):
            s += A[i, k] * x[k]
        out[i] = s


@inlined
def mv6_add(A, x, s, out):
    """``out += s A x`` (6,)."""
    for i in range(6):
        acc = 0.0
        for k in range(6):
            acc += A[i, k] * x[k]
        out[i] += s * acc


@inlined
def mtv6_add(A, x, s, out):
    """``out += s A^T x`` (6,)."""
    for i in range(6):
        acc = 0.0
        for k in range(6):
            acc += A[k, i] * x[k]
        out[i] += s * acc


@inlined
def symmetric_part(A, out):
    """``out = (A + A^T) / 2`` (6, 6); ``out`` may be ``A``."""
    for i in range(6):
        out[i, i] = A[i, i]
        for j in range(i + 1, 6):
            s = 0.5 * (A[i, j] + A[j, i])
            out[i, j] = s
            out[j, i] = s


@inlined
def mmt6_add(A, B, s, out):
    """``out += s A B^T`` (6, 6)."""
    for i in range(6):
        for j in range(6):
            acc = 0.0
            for k in range(6):
                acc += A[i, k] * B[j, k]
            out[i, j] += s * acc


@inlined
def mmt6_add_symmetric(A, B, s, out):
    """``out += s A B^T`` (6, 6) where both ``out`` and ``A B^T`` are symmetric:
    the upper triangle computed, the lower one copied from it."""
    for i in range(6):
        for j in range(i, 6):
            acc = 0.0
            for k in range(6):
                acc += A[i, k] * B[j, k]
            out[i, j] += s * acc
            out[j, i] = out[i, j]


# --- 3x3 and 3-vector products -----------------------------------------------------------

@inlined
def identity_pose(R, p):
    """``R = I`` (3, 3), ``p = 0`` (3,): the identity placement."""
    for r in range(3):
        p[r] = 0.0
        for s in range(3):
            R[r, s] = 1.0 if r == s else 0.0


@inlined
def copy_pose(R, p, oR, op):
    """``oR = R`` (3, 3), ``op = p`` (3,)."""
    for r in range(3):
        op[r] = p[r]
        for s in range(3):
            oR[r, s] = R[r, s]


@inlined
def compose_pose(Ra, pa, R, p, t):
    """``(R, p) = (Ra, pa) (R, p)`` in place: ``R = Ra R``, ``p = pa + Ra p`` (a pose
    given in frame ``a`` expressed where ``a`` has pose ``(Ra, pa)``); ``t`` (3, 3)
    scratch."""
    mm3(Ra, R, t)
    x0 = Ra[0, 0] * p[0] + Ra[0, 1] * p[1] + Ra[0, 2] * p[2]
    x1 = Ra[1, 0] * p[0] + Ra[1, 1] * p[1] + Ra[1, 2] * p[2]
    x2 = Ra[2, 0] * p[0] + Ra[2, 1] * p[1] + Ra[2, 2] * p[2]
    p[0], p[1], p[2] = pa[0] + x0, pa[1] + x1, pa[2] + x2
    for r in range(3):
        for s in range(3):
            R[r, s] = t[r, s]


@inlined
def relative_pose(Ra, pa, R, p, oR, op):
    """``(oR, op) = (Ra, pa)^-1 (R, p)``: a pose given in some frame, expressed in
    frame ``a`` at pose ``(Ra, pa)`` in it: ``oR = Ra^T R``, ``op = Ra^T (p -
    pa)``."""
    for r in range(3):
        op[r] = (Ra[0, r] * (p[0] - pa[0]) + Ra[1, r] * (p[1] - pa[1])
                 + Ra[2, r] * (p[2] - pa[2]))
        for s in range(3):
            oR[r, s] = Ra[0, r] * R[0, s] + Ra[1, r] * R[1, s] + Ra[2, r] * R[2, s]


@inlined
def mm3(A, B, out):
    """``out = A B`` (3, 3)."""
    for i in range(3):
        for j in range(3):
            out[i, j] = A[i, 0] * B[0, j] + A[i, 1] * B[1, j] + A[i, 2] * B[2, j]


@inlined
def inverse3(A, out):
    """``out = A^-1`` (3, 3) by the adjugate (``A`` symmetric positive definite
    here: composite inertias)."""
    c00 = A[1, 1] * A[2, 2] - A[1, 2] * A[2, 1]
    c01 = A[1, 2] * A[2, 0] - A[1, 0] * A[2, 2]
    c02 = A[1, 0] * A[2, 1] - A[1, 1] * A[2, 0]
    det = A[0, 0] * c00 + A[0, 1] * c01 + A[0, 2] * c02
    out[0, 0] = c00 / det
    out[1, 0] = c01 / det
    out[2, 0] = c02 / det
    out[0, 1] = (A[0, 2] * A[2, 1] - A[0, 1] * A[2, 2]) / det
    out[1, 1] = (A[0, 0] * A[2, 2] - A[0, 2] * A[2, 0]) / det
    out[2, 1] = (A[0, 1] * A[2, 0] - A[0, 0] * A[2, 1]) / det
    out[0, 2] = (A[0, 1] * A[1, 2] - A[0, 2] * A[1, 1]) / det
    out[1, 2] = (A[0, 2] * A[1, 0] - A[0, 0] * A[1, 2]) / det
    out[2, 2] = (A[0, 0] * A[1, 1] - A[0, 1] * A[1, 0]) / det


@inlined
def mv3(A, x, out):
    """``out = A x`` (3,); ``out`` must not be ``x``."""
    for i in range(3):
        out[i] = A[i, 0] * x[0] + A[i, 1] * x[1] + A[i, 2] * x[2]


@inlined
def cross_motion_add(v, m, out):
    """``out += crm(v) m`` (6,): ``(w × m_w; w × m_v + v × m_w)``."""
    w0, w1, w2, v0, v1, v2 = v[0], v[1], v[2], v[3], v[4], v[5]
    a0, a1, a2, b0, b1, b2 = m[0], m[1], m[2], m[3], m[4], m[5]
    out[0] += w1 * a2 - w2 * a1
    out[1] += w2 * a0 - w0 * a2
    out[2] += w0 * a1 - w1 * a0
    out[3] += w1 * b2 - w2 * b1 + v1 * a2 - v2 * a1
    out[4] += w2 * b0 - w0 * b2 + v2 * a0 - v0 * a2
    out[5] += w0 * b1 - w1 * b0 + v0 * a1 - v1 * a0


# --- rotations ------------------------------------------------------------------------

@inlined
def axis_angle_rotation(a, t, R):
    """``R = exp(t [a]×)`` (Rodrigues), unit axis ``a``."""
    c, s = np.cos(t), np.sin(t)
    C = 1.0 - c
    x, y, z = a[0], a[1], a[2]
    R[0, 0] = c + x * x * C
    R[0, 1] = x * y * C - z * s
    R[0, 2] = x * z * C + y * s
    R[1, 0] = y * x * C + z * s
    R[1, 1] = c + y * y * C
    R[1, 2] = y * z * C - x * s
    R[2, 0] = z * x * C - y * s
    R[2, 1] = z * y * C + x * s
    R[2, 2] = c + z * z * C


@inlined
def quaternion_rotation(q, i, R):
    """``R`` of the quaternion ``q[i:i + 4] = (w, x, y, z)``, normalised first (as
    :func:`vdad.spatial.quat_to_rot` of ``q / |q|``)."""
    w, x, y, z = q[i], q[i + 1], q[i + 2], q[i + 3]
    n = np.sqrt(w * w + x * x + y * y + z * z)
    w, x, y, z = w / n, x / n, y / n, z / n
    R[0, 0] = 1 - 2 * (y * y + z * z)
    R[0, 1] = 2 * (x * y - w * z)
    R[0, 2] = 2 * (x * z + w * y)
    R[1, 0] = 2 * (x * y + w * z)
    R[1, 1] = 1 - 2 * (x * x + z * z)
    R[1, 2] = 2 * (y * z - w * x)
    R[2, 0] = 2 * (x * z - w * y)
    R[2, 1] = 2 * (y * z + w * x)
    R[2, 2] = 1 - 2 * (x * x + y * y)


@inlined
def quaternion_log(q0, q1, q2, q3):
    """Rotation vector ``(r0, r1, r2)`` of ``q / |q|``, ``q = (q0, q1, q2, q3)``,
    angle in [0, pi] (:func:`vdad.spatial.quat_log`)."""
    n = np.sqrt(q0 * q0 + q1 * q1 + q2 * q2 + q3 * q3)
    sign = -1.0 if q0 < 0 else 1.0
    w = sign * q0 / n
    x, y, z = sign * q1 / n, sign * q2 / n, sign * q3 / n
    s = np.sqrt(x * x + y * y + z * z)
    k = 2.0 / max(w, 1e-300) if s <= 1e-12 else 2.0 * np.arctan2(s, w) / s
    return k * x, k * y, k * z


@inlined
def quaternion_step(q, w, dt, out):
    """``out = q ⊗ exp(w dt)``, normalised: a ball stage turned by its body-frame
    angular velocity ``w`` (3,) over ``dt`` (:func:`vdad.spatial.quat_exp`)."""
    wx, wy, wz = w[0] * dt, w[1] * dt, w[2] * dt
    angle = np.sqrt(wx * wx + wy * wy + wz * wz)
    half = 0.5 * angle
    k = np.sin(half) / angle if angle > 1e-8 else 0.5 - angle * angle / 48.0
    ew, ex, ey, ez = np.cos(half), k * wx, k * wy, k * wz
    aw, ax, ay, az = q[0], q[1], q[2], q[3]
    rw = aw * ew - ax * ex - ay * ey - az * ez
    rx = aw * ex + ax * ew + ay * ez - az * ey
    ry = aw * ey - ax * ez + ay * ew + az * ex
    rz = aw * ez + ax * ey - ay * ex + az * ew
    n = np.sqrt(rw * rw + rx * rx + ry * ry + rz * rz)
    out[0] = rw / n
    out[1] = rx / n
    out[2] = ry / n
    out[3] = rz / n


# --- spatial transforms ---------------------------------------------------------------

@inlined
def motion_to_child(R, p, m, out):
    """``out = X m`` (6,): the motion ``m`` of a parent frame seen in a child frame
    at pose ``(R, p)`` in it (:func:`vdad.spatial.pose_to_motion_transform`):
    ``(R^T w; R^T (v + w × p))``."""
    w0, w1, w2 = m[0], m[1], m[2]
    t0 = m[3] + w1 * p[2] - w2 * p[1]
    t1 = m[4] + w2 * p[0] - w0 * p[2]
    t2 = m[5] + w0 * p[1] - w1 * p[0]
    for i in range(3):
        out[i] = R[0, i] * w0 + R[1, i] * w1 + R[2, i] * w2
        out[3 + i] = R[0, i] * t0 + R[1, i] * t1 + R[2, i] * t2


@inlined
def port_transform(R, r, c, X):
    """``X_{h<-c}`` (6, 6), theory (T2): motion at the centre of mass ``c`` (body
    axes) to a port frame at ``r`` whose axes are the columns of ``R`` (body axes):
    ``[[E, 0], [E [c - r]×, E]]`` with ``E = R^T``."""
    d0, d1, d2 = c[0] - r[0], c[1] - r[1], c[2] - r[2]
    for i in range(3):
        e0, e1, e2 = R[0, i], R[1, i], R[2, i]          # row i of E
        X[i, 0] = e0
        X[i, 1] = e1
        X[i, 2] = e2
        X[i, 3] = 0.0
        X[i, 4] = 0.0
        X[i, 5] = 0.0
        X[3 + i, 0] = e1 * d2 - e2 * d1                 # row i of E [d]×
        X[3 + i, 1] = e2 * d0 - e0 * d2
        X[3 + i, 2] = e0 * d1 - e1 * d0
        X[3 + i, 3] = e0
        X[3 + i, 4] = e1
        X[3 + i, 5] = e2


@inlined
def inverse_inertia_transpose(X, Iinv, m, out):
    """``out = diag(I^-1, 1/m) X^T`` (6, 6) of a port transform ``X``
    (:func:`port_transform`; ``Iinv`` = ``I^-1`` (3, 3)): ``[[I^-1 E^T, I^-1
    B^T], [0, E^T / m]]``."""
    for s in range(6):
        for r in range(3):
            out[r, s] = Iinv[r, 0] * X[s, 0] + Iinv[r, 1] * X[s, 1] + Iinv[r, 2] * X[s, 2]
            out[3 + r, s] = X[s, 3 + r] / m


@inlined
def port_product(X, Q, out):
    """``out = X Q`` (6, 6) of a port transform ``X = [[E, 0], [B, E]]``
    (:func:`port_transform`) and ``Q = [[Q11, Q12], [0, Q22]]``
    (:func:`inverse_inertia_transpose`), skipping the zero blocks: five 3x3 products
    instead of one 6x6."""
    for i in range(3):
        for j in range(3):
            out[i, j] = X[i, 0] * Q[0, j] + X[i, 1] * Q[1, j] + X[i, 2] * Q[2, j]
            out[i, 3 + j] = X[i, 0] * Q[0, 3 + j] + X[i, 1] * Q[1, 3 + j] + X[i, 2] * Q[2, 3 + j]
            out[3 + i, j] = X[3 + i, 0] * Q[0, j] + X[3 + i, 1] * Q[1, j] + X[3 + i, 2] * Q[2, j]
            out[3 + i, 3 + j] = (X[3 + i, 0] * Q[0, 3 + j] + X[3 + i, 1] * Q[1, 3 + j]
                                 + X[3 + i, 2] * Q[2, 3 + j] + X[3 + i, 3] * Q[3, 3 + j]
                                 + X[3 + i, 4] * Q[4, 3 + j] + X[3 + i, 5] * Q[5, 3 + j])


# --- small dense solves ----------------------------------------------------------------

@inlined
def cholesky(K, n):
    """Lower Cholesky factor of the leading ``n x n`` block of ``K``, in place
    (the upper triangle is left as it was). Returns False if the block is not
    positive definite."""
    for r in range(n):
        for s in range(r + 1):
            acc = K[r, s]
            for k in range(s):
                acc -= K[r, k] * K[s, k]
            if r == s:
                if not acc > 0.0:
                    return False
                K[r, r] = np.sqrt(acc)
            else:
                K[r, s] = acc / K[s, s]
    return True


@inlined
def cholesky_solve(L, x, n):
    """``x = (L L^T)^-1 x`` for the first ``n`` entries of ``x``, ``L`` the factor
    :func:`cholesky` left in the lower triangle of its block."""
    for r in range(n):                                 # L y = x
        acc = x[r]
        for k in range(r):
            acc -= L[r, k] * x[k]
        x[r] = acc / L[r, r]
    for r in range(n - 1, -1, -1):                     # L^T x = y
        acc = x[r]
        for k in range(r + 1, n):
            acc -= L[k, r] * x[k]
        x[r] = acc / L[r, r]


@inlined
def solve_general(K, x, n):
    """``x = K^-1 x`` for the leading ``n x n`` block of ``K`` and the first ``n``
    rows of ``x`` (n, m), by Gaussian elimination with partial pivoting; ``K`` and
    ``x`` are overwritten. Returns False if ``K`` is singular."""
    m = x.shape[1]
    for c in range(n):
        piv, big = c, abs(K[c, c])
        for r in range(c + 1, n):
            if abs(K[r, c]) > big:
                piv, big = r, abs(K[r, c])
        if big == 0.0:
            return False
        if piv != c:
            for k in range(n):
                K[c, k], K[piv, k] = K[piv, k], K[c, k]
            for k in range(m):
                x[c, k], x[piv, k] = x[piv, k], x[c, k]
        for r in range(c + 1, n):
            f = K[r, c] / K[c, c]
            if f != 0.0:
                for k in range(c, n):
                    K[r, k] -= f * K[c, k]
                for k in range(m):
                    x[r, k] -= f * x[c, k]
    for c in range(n - 1, -1, -1):
        for k in range(m):
            acc = x[c, k]
            for j in range(c + 1, n):
                acc -= K[c, j] * x[j, k]
            x[c, k] = acc / K[c, c]
    return True


@inlined
def orthonormal(S, tol):
    """Whether the columns of ``S`` (6, 6) are orthonormal: every entry of ``S^T
    S - 1`` within ``tol``."""
    for a in range(6):
        for b in range(a, 6):
            g = 0.0
            for i in range(6):
                g += S[i, a] * S[i, b]
            if abs(g - (1.0 if a == b else 0.0)) > tol:
                return False
    return True


@inlined
def complement(S, d, T, W, work):
    """``T`` and ``W`` of theory (T5) for the first ``d`` columns of ``S`` (6, 6).
    Six orthonormal columns (a free joint whose ball turns about its child's
    origin: ``docs/joints.md``) have ``W = S`` and no ``T``, taken as they are (to
    ``16 eps`` in ``S^T S``, the rounding of a rotation matrix). Otherwise
    from a Householder QR ``S = Q R``: ``T``'s first ``6 - d`` columns the last
    columns of ``Q``, an orthonormal basis of ``null(S^T)``, and ``W = S (S^T
    S)^-1 = Q_1 R^-T`` in ``W``'s first ``d`` columns (``Q_1`` the first ``d``
    columns of ``Q``: no normal equations, so ``W`` keeps the accuracy of ``S``
    near a singular configuration, ``docs/joints.md``); the other columns zero.
    Where ``S`` loses rank (a diagonal entry of ``R`` below ``64 eps`` of the
    largest: a composite joint in gimbal lock) ``W`` is NaN, which the callers
    report. ``work`` (3, 6, 6) is scratch. Any basis of ``null(S^T)`` gives the
    same (T7)."""
    if d == 6 and orthonormal(S, 16.0 * EPS):
        for i in range(6):
            for j in range(6):
                T[i, j] = 0.0
                W[i, j] = S[i, j]
        return
    Q, Rf, Z = work[0], work[1], work[2]
    h = Z[0]                                  # Z is needed only after the reflections
    for i in range(6):
        for j in range(6):
            Q[i, j] = S[i, j] if j < d else 0.0
            T[i, j] = 0.0
            W[i, j] = 0.0
    # Householder reflectors H_k = 1 - 2 h h^T; h_k kept in column k of Q, R in Rf
    for k in range(d):
        norm = 0.0
        for i in range(k, 6):
            norm += Q[i, k] * Q[i, k]
        norm = np.sqrt(norm)
        alpha = -norm if Q[k, k] >= 0 else norm
        Rf[k, k] = alpha
        for i in range(6):
            h[i] = Q[i, k] if i >= k else 0.0
        h[k] -= alpha
        hn = 0.0
        for i in range(k, 6):
            hn += h[i] * h[i]
        hn = np.sqrt(hn)
        for i in range(6):
            h[i] = h[i] / hn if hn > 0 else 0.0
        for j in range(k + 1, d):                  # apply H_k to the remaining columns
            s = 0.0
            for i in range(k, 6):
                s += h[i] * Q[i, j]
            for i in range(k, 6):
                Q[i, j] -= 2.0 * s * h[i]
            Rf[k, j] = Q[k, j]
        for i in range(6):
            Q[i, k] = h[i]
    # columns of Q = H_0 ... H_{d-1} e_c: Q_1 into W (c < d), T (c >= d)
    for c in range(6):
        col = W[:, c] if c < d else T[:, c - d]
        for i in range(6):
            col[i] = 1.0 if i == c else 0.0
        for k in range(d - 1, -1, -1):
            s = 0.0
            for i in range(6):
                s += Q[i, k] * col[i]
            for i in range(6):
                col[i] -= 2.0 * s * Q[i, k]
    # W = Q_1 R^-T: each row w of W solves R w^T = (row of Q_1)^T
    big = 0.0
    for k in range(d):
        big = max(big, abs(Rf[k, k]))
    singular = False
    for k in range(d):
        singular = singular or not abs(Rf[k, k]) > 64.0 * EPS * big
    for i in range(6):
        for c in range(d - 1, -1, -1):
            acc = W[i, c]
            for k in range(c + 1, d):
                acc -= Rf[c, k] * W[i, k]
            W[i, c] = np.nan if singular else acc / Rf[c, c]


clear_stale_caches()
