"""The compiled core's helpers (vdad._linalg), plain-Python mode and numba's cache."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from strategies import small_compiled_run

from vdad import _linalg as L
from vdad.spatial import pose_to_motion_transform, quat_log, quat_to_rot

EPS = np.finfo(float).eps
ROOT = Path(__file__).resolve().parent.parent


def test_products_match_numpy():
    rng = np.random.default_rng(0)
    A, B = rng.normal(size=(2, 6, 6))
    x = rng.normal(size=6)
    out, v = np.empty((6, 6)), np.empty(6)
    L.mm6(A, B, out)
    np.testing.assert_allclose(out, A @ B, rtol=0, atol=50 * EPS)
    out[:] = A
    L.mmt6_add(A, B, -2.0, out)
    np.testing.assert_allclose(out, A - 2.0 * A @ B.T, rtol=0, atol=50 * EPS)
    S = A + A.T
    out[:] = S
    L.mmt6_add_symmetric(A, A, 3.0, out)
    np.testing.assert_allclose(out, S + 3.0 * A @ A.T, rtol=0, atol=100 * EPS)
    np.testing.assert_array_equal(out, out.T)
    L.mv6(A, x, v)
    np.testing.assert_allclose(v, A @ x, rtol=0, atol=50 * EPS)
    v[:] = 1.0
    L.mtv6_add(A, x, -2.0, v)
    np.testing.assert_allclose(v, 1.0 - 2.0 * A.T @ x, rtol=0, atol=50 * EPS)
    L.symmetric_part(A, out)
    np.testing.assert_allclose(out, 0.5 * (A + A.T), rtol=0, atol=EPS)


def test_rotations_and_transforms_match_vdad_spatial():
    rng = np.random.default_rng(1)
    q = rng.normal(size=4)
    R = np.empty((3, 3))
    L.quaternion_rotation(q, 0, R)
    np.testing.assert_allclose(R, quat_to_rot(q / np.linalg.norm(q)), rtol=0, atol=10 * EPS)
    r = np.array(L.quaternion_log(*q))
    np.testing.assert_allclose(r, quat_log(q / np.linalg.norm(q)), rtol=0, atol=10 * EPS)
    p, m = rng.normal(size=3), rng.normal(size=6)
    out = np.empty(6)
    L.motion_to_child(R, p, m, out)
    np.testing.assert_allclose(out, pose_to_motion_transform(R, p) @ m, rtol=0, atol=20 * EPS)
    c, Iinv, mass = rng.normal(size=3), rng.normal(size=(3, 3)), 2.5
    X, Q, XQ = np.empty((3, 6, 6))
    L.port_transform(R, p, c, X)
    E, d = R.T, c - p
    E_dx = -np.cross(d, E)                              # rows e_i x d: E [d]x
    np.testing.assert_allclose(X, np.block([[E, np.zeros((3, 3))], [E_dx, E]]), rtol=0,
                               atol=20 * EPS)
    D = np.zeros((6, 6))
    D[:3, :3], D[3:, 3:] = Iinv, np.eye(3) / mass
    L.inverse_inertia_transpose(X, Iinv, mass, Q)
    np.testing.assert_allclose(Q, D @ X.T, rtol=0, atol=50 * EPS)
    L.port_product(X, Q, XQ)
    np.testing.assert_allclose(XQ, X @ D @ X.T, rtol=0, atol=200 * EPS)


@pytest.mark.parametrize("d", range(7))
def test_complement_spans_the_null_space_of_S_transposed(d):
    rng = np.random.default_rng(d)
    S = np.zeros((6, 6))
    S[:, :d] = rng.normal(size=(6, d))
    T, W = np.empty((6, 6)), np.empty((6, 6))
    L.complement(S, d, T, W, np.empty((3, 6, 6)))
    Tn, Wn = T[:, :6 - d], W[:, :d]
    cond = np.linalg.cond(S[:, :d]) if d else 1.0
    np.testing.assert_allclose(Tn.T @ Tn, np.eye(6 - d), rtol=0, atol=50 * EPS)
    np.testing.assert_allclose(S[:, :d].T @ Tn, 0, rtol=0, atol=50 * cond * EPS)
    np.testing.assert_allclose(S[:, :d].T @ Wn, np.eye(d), rtol=0, atol=50 * cond * EPS)
    assert not T[:, 6 - d:].any() and not W[:, d:].any()


@pytest.mark.parametrize("skew", [0.0, 1e-9])
def test_complement_of_a_free_joint_takes_W_as_S(skew):
    """A free joint's six orthonormal columns (its ball at the child's origin) have
    W = S and no T, taken as they are; columns a little off orthonormal go through
    the factorisation, and both satisfy (T5) as the numpy reference does."""
    from vdad.joints import complement

    R = quat_to_rot(np.array([0.8, 0.2, -0.4, 0.4]) / np.linalg.norm([0.8, 0.2, -0.4, 0.4]))
    S = np.zeros((6, 6))
    S[:3, 3:], S[3:, :3] = np.eye(3), R.T
    S[0, 0] += skew
    T, W = np.full((6, 6), np.nan), np.full((6, 6), np.nan)
    L.complement(S, 6, T, W, np.empty((3, 6, 6)))
    assert not T.any()
    if skew == 0.0:
        np.testing.assert_array_equal(W, S)
    else:
        assert not np.array_equal(W, S)
    np.testing.assert_allclose(S.T @ W, np.eye(6), rtol=0, atol=50 * EPS)
    np.testing.assert_allclose(W, complement(S[None])[1][0], rtol=0, atol=50 * EPS)


@pytest.mark.parametrize("gap", [1e-4, 1e-8, 0.0])
def test_complement_near_and_at_a_loss_of_rank(gap):
    """W = Q_1 R^-T keeps the accuracy of S (its error follows cond(S), where the
    normal equations' followed cond(S)^2) as two of three columns align; where
    they do (a gimbal lock), W is NaN and T still an orthonormal set."""
    rng = np.random.default_rng(1)
    S = np.zeros((6, 6))
    S[:, :2] = rng.normal(size=(6, 2))
    S[:, 2] = S[:, 0] + gap * rng.normal(size=6)
    T, W = np.empty((6, 6)), np.empty((6, 6))
    L.complement(S, 3, T, W, np.empty((3, 6, 6)))
    np.testing.assert_allclose(T[:, :3].T @ T[:, :3], np.eye(3), rtol=0, atol=50 * EPS)
    if gap == 0.0:
        assert np.isnan(W[:, :3]).all()
        return
    cond = np.linalg.cond(S[:, :3])
    np.testing.assert_allclose(S[:, :3].T @ W[:, :3], np.eye(3), rtol=0, atol=50 * cond * EPS)
    expected = np.linalg.pinv(S[:, :3]).T
    assert np.abs(W[:, :3] - expected).max() < 50 * cond * EPS * np.abs(expected).max()


def test_solve_general_and_cholesky():
    rng = np.random.default_rng(3)
    K = rng.normal(size=(6, 6))
    x = rng.normal(size=(6, 2))
    Kc, xc = K.copy(), x.copy()
    assert L.solve_general(Kc, xc, 4)
    np.testing.assert_allclose(xc[:4], np.linalg.solve(K[:4, :4], x[:4]), rtol=1e-12)
    np.testing.assert_array_equal(xc[4:], x[4:])
    assert not L.solve_general(np.zeros((6, 6)), x.copy(), 3)
    spd = K @ K.T + np.eye(6)
    C = spd.copy()
    assert L.cholesky(C, 6)
    np.testing.assert_allclose(np.tril(C), np.linalg.cholesky(spd), rtol=1e-12)
    assert not L.cholesky(-np.eye(6), 6)


SMALL = """
import json, sys
from numba.core.registry import CPUDispatcher
sys.path.insert(0, {tests!r})
from strategies import small_compiled_run
import vdad
out = small_compiled_run({upto!r})
kernels = [k for name, module in list(sys.modules.items()) if name.startswith("vdad")
           for k in vars(module).values() if isinstance(k, CPUDispatcher)]
print(json.dumps(dict(out, where=vdad.__file__,
                      compiled=sum(sum(k.stats.cache_misses.values()) for k in kernels),
                      loaded=sum(sum(k.stats.cache_hits.values()) for k in kernels))))
"""


def _run(code, env=None, cwd=None):
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                          env={**os.environ, **(env or {})}, cwd=cwd, timeout=900)
    assert done.returncode == 0, done.stderr
    return done


def test_plain_python_mode_gives_the_compiled_result():
    """NUMBA_DISABLE_JIT=1 runs the kernels as plain Python (a debugger can step
    through a pass): the same accelerations as the compiled core, the same
    compiled steps (RK4, built-in forces: drag, random torques, a spring), and the
    same compiled adaptive steps (forces, in-loop coverage, region changes)."""
    done = _run(SMALL.format(tests=str(ROOT / "tests"), upto="adaptive"),
                {"NUMBA_DISABLE_JIT": "1"})
    out, expected = json.loads(done.stdout), small_compiled_run("adaptive")
    assert sum(expected["changes"]) > 0                  # the region changed
    assert out["changes"] == expected["changes"]
    for name in ("p", "v", "qdd", "q", "qd", "adaptive_q", "adaptive_qd"):
        e = np.array(expected[name])
        np.testing.assert_allclose(np.array(out[name]), e, rtol=0,
                                   atol=1e-12 * max(1.0, np.abs(e).max()))
    assert L.NOTICE not in done.stderr


LONG_FIRST_RUN = """
import sys, time
from vdad import _linalg
from vdad.scenes import pendulum
pendulum(4).simulator().step(2)                  # the step loop compiled or loaded
_linalg._called.clear()                          # its next call counts as a first one
_linalg._noticed.clear()
print("long run", file=sys.stderr, flush=True)
sim = pendulum(2000).simulator()
t0 = time.perf_counter()
sim.step(2000)
print(time.perf_counter() - t0)
"""


def test_a_long_first_run_of_loaded_kernels_says_nothing():
    """The notice that kernels compile is for a compile: a first call of a loaded
    kernel that runs for seconds (2000 steps of a 2000-link chain) prints
    nothing."""
    done = _run(LONG_FIRST_RUN)
    assert float(done.stdout) > 1.2, "the run took under the notice's second"
    assert L.NOTICE not in done.stderr.split("long run", 1)[1], done.stderr


def test_read_only_install_compiles_once_then_loads_from_the_user_cache(tmp_path):
    """An installed copy of the package whose folder cannot take numba's cache (a
    file stands where __pycache__ would go; it is also made read-only) caches in
    the user's cache folder: the first process says once that it compiles, the
    second loads every kernel from there (numba counts no cache miss) and says
    nothing."""
    site = tmp_path / "site"
    shutil.copytree(ROOT / "vdad", site / "vdad",
                    ignore=shutil.ignore_patterns("__pycache__", "*.nbi", "*.nbc"))
    for folder in [site / "vdad", *[p for p in (site / "vdad").rglob("*") if p.is_dir()]]:
        (folder / "__pycache__").write_text("not a folder")
    for p in site.rglob("*"):
        p.chmod(0o555 if p.is_dir() else 0o444)
    cache = tmp_path / "cache"
    env = {"PYTHONPATH": str(site), "XDG_CACHE_HOME": str(cache), "NUMBA_CACHE_DIR": ""}
    code = SMALL.format(tests=str(ROOT / "tests"), upto="kinematics")
    try:
        first = _run(code, env, cwd=tmp_path)
        second = _run(code, env, cwd=tmp_path)
    finally:
        for p in site.rglob("*"):
            p.chmod(0o755 if p.is_dir() else 0o644)
    assert first.stderr.count(L.NOTICE) == 1, first.stderr
    assert L.NOTICE not in second.stderr
    assert any(cache.rglob("*.nbi")), "numba wrote no cache index in the user cache"
    expected = small_compiled_run("kinematics")
    out = [json.loads(done.stdout) for done in (first, second)]
    for o in out:
        for name in ("p", "v"):
            e = np.array(expected[name])
            np.testing.assert_allclose(np.array(o[name]), e, rtol=0,
                                       atol=1e-12 * np.abs(e).max())
    assert all(o["where"].startswith(str(site)) for o in out)
    assert out[0]["compiled"] > 0 and out[0]["loaded"] == 0, out[0]
    assert out[1]["compiled"] == 0 and out[1]["loaded"] > 0, out[1]


def test_kernel_caches_carry_the_stamp_of_the_sources():
    """numba keys a cache on its function's own file only; vdad stamps its cache
    folder with a hash of all the modules that define kernels (a kernel inlines
    others), and clears the folder when the stamp is missing, at import."""
    folder = ROOT / "vdad" / "__pycache__"
    if not os.access(folder, os.W_OK):
        pytest.skip("the package folder is read-only here")
    assert (folder / f"vdad-sources-{L.source_stamp()}.stamp").exists()
    assert len(list(folder.glob("vdad-sources-*.stamp"))) == 1
