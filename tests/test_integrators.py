"""The integrators' compiled pieces (vdad.integrators); whole runs are in
test_simulator.py."""

from __future__ import annotations

import numpy as np

from vdad.integrators import ANDERSON_MEMORY, anderson_scratch, anderson_update


def fixed_point(A, b, x, iterations):
    """The residuals ``|G(x) - x|`` (max norm) of Anderson-accelerated iteration of
    ``G(x) = A x + b`` from ``x``."""
    rows, R = anderson_scratch(len(b))
    out = []
    for k in range(iterations):
        gx = A @ x + b
        out.append(np.abs(gx - x).max())
        anderson_update(k, x, gx, rows, R)
    return np.array(out)


def test_anderson_solves_a_fixed_point_where_plain_iteration_diverges():
    """(S4) of docs/accuracy.md: on a linear map with three eigenvalues outside the
    unit circle (plain iteration grows as 1.8^k), Anderson's method with its six
    differences is GMRES: it reaches the fixed point to rounding in a few more
    iterations than the unstable directions."""
    rng = np.random.default_rng(0)
    n = 20
    V = np.linalg.qr(rng.normal(size=(n, n)))[0] @ np.diag(rng.uniform(0.5, 2.0, n))
    eig = np.concatenate([[1.8, -1.5, 1.2], rng.uniform(-0.4, 0.4, n - 3)])
    A = V @ np.diag(eig) @ np.linalg.inv(V)
    b = rng.normal(size=n)
    exact = np.linalg.solve(np.eye(n) - A, b)
    x = np.zeros(n)
    residual = fixed_point(A, b, x, 40)
    assert residual[-1] < 1e-12 * np.abs(exact).max()
    np.testing.assert_allclose(x, exact, rtol=0, atol=1e-11 * np.abs(exact).max())
    plain = np.zeros(n)
    for _ in range(40):
        plain = A @ plain + b
    assert np.abs(plain - exact).max() > 1e6 * np.abs(exact).max()


def test_anderson_leaves_out_dependent_differences():
    """Iterating on past convergence gives residual differences of the rounding's
    size, dependent on the others (or zero): the least squares leave them out, and
    the iterate stays at the fixed point (a dependent column would make the
    triangular factor singular)."""
    n = 8
    A = np.diag([2.5, 0.3, -0.2, 0.1, 0.0, 0.4, -0.3, 0.2])    # one unstable direction
    b = np.arange(1.0, n + 1)
    x = np.zeros(n)
    residual = fixed_point(A, b, x, 6 * ANDERSON_MEMORY)
    assert np.all(np.isfinite(residual)) and residual[-6:].max() < 1e-13 * n
    np.testing.assert_allclose(x, np.linalg.solve(np.eye(n) - A, b), rtol=0, atol=1e-13 * n)
