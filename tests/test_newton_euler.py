"""Newton-Euler in compiled form (vdad.newton_euler; docs/accuracy.md (R1))."""

import numpy as np
import pytest
from strategies import random_state, random_tree, relative_error, tolerance, with_armature

import vdad
from vdad import dca, reference
from vdad.kinematics import kinematics, plan
from vdad.newton_euler import MASS, inverse_dynamics_pass


@pytest.mark.parametrize("seed", range(4))
def test_inverse_dynamics_equals_the_reference_rnea_and_inverts_the_dca(seed):
    """On random forests with every joint kind, composite joints, springs,
    armature and external wrenches: vdad.newton_euler equals the reference
    RNEA (both leave out the springs and dampers, which forward_dynamics adds
    itself) and gives back the tau that forward_dynamics took."""
    model = with_armature(random_tree(seed, n=9, roots=2, composite=True), seed)
    q, qd, tau, f_ext = random_state(model, seed)
    qdd = vdad.forward_dynamics(model, q, qd, tau, f_ext)
    tau_back = vdad.inverse_dynamics(model, q, qd, qdd, f_ext)
    tol = tolerance(model, q)
    assert relative_error(tau_back, tau) < tol
    assert relative_error(tau_back, reference.rnea(model, q, qd, qdd, f_ext)) < 1e-12


def momenta(model, q, qd):
    """The kinematics of ``(q, qd)`` and inverse_dynamics_pass in mode MASS with
    ``x = qd``: body velocities ``a``, subtree momenta ``f``, ``M qd``."""
    kin = kinematics(model, q, qd)
    a, f, out = np.empty((model.nb, 6)), np.empty((model.nb, 6)), np.empty(model.nv)
    inverse_dynamics_pass(plan(model).arrays, dca.body_arrays(model), kin.arrays,
                          np.zeros((0, 6)), qd, MASS, a, f, np.empty((2, 6)), out)
    return kin, a, f, out


def test_without_velocity_terms_the_pass_is_the_mass_matrix_product():
    """inverse_dynamics_pass in mode MASS is M x (the CRBA's, armature
    included) and leaves the body motions of x in ``a`` and the transmitted
    wrenches in ``f``: with x = qd, the body velocities and subtree momenta, whose
    kinetic energy is qd^T M qd / 2 (S1 of docs/accuracy.md)."""
    from vdad.quantities import kinetic_energy

    model = with_armature(random_tree(2, n=8, composite=True), 2)
    q, qd, _, _ = random_state(model, 2)
    kin, a, f, out = momenta(model, q, qd)
    M = reference.crba(model, q)
    np.testing.assert_allclose(out, M @ qd, rtol=0, atol=1e-13 * np.abs(M @ qd).max())
    np.testing.assert_allclose(a, kin.v, rtol=0, atol=1e-13 * np.abs(kin.v).max())
    assert 0.5 * qd @ out == pytest.approx(kinetic_energy(model, q, qd), rel=1e-12)


def test_bad_inputs_name_the_argument():
    model = random_tree(0, n=3)
    q, qd, _, _ = random_state(model, 0)
    with pytest.raises(vdad.InputError, match=rf"qdd must have shape \({model.nv},\)"):
        vdad.inverse_dynamics(model, q, qd, qd[:-1])
    with pytest.raises(vdad.InputError, match="f_ext must have shape"):
        vdad.inverse_dynamics(model, q, qd, qd, np.zeros((model.nb, 3)))


def test_kinetic_gradient_is_the_derivative_of_the_kinetic_energy():
    """(S2) of docs/accuracy.md: -s^T crf(v_before) H, stage by stage, equals the
    central differences of the kinetic energy in q, on a chain of hinges and slides
    with armature and on composite joints of hinges."""
    from strategies import random_chain, thin_rod

    from vdad.newton_euler import kinetic_gradient_pass
    from vdad.quantities import kinetic_energy

    for model in (with_armature(random_chain(3, n=6, kinds=("revolute", "prismatic"),
                                             root="revolute"), 3),
                  thin_rod(0.5, "composite", com=(0.1, 0.2, 0.3))):
        q, qd, _, _ = random_state(model, 3)
        kin, a, f, _ = momenta(model, q, qd)
        dT = np.empty(model.nv)
        kinetic_gradient_pass(plan(model).arrays, kin.S, a, f, qd, dT)
        h = 1e-6
        fd = np.array([(kinetic_energy(model, q + h * e, qd) - kinetic_energy(model, q - h * e, qd))
                       / (2 * h) for e in np.eye(model.nq)])
        np.testing.assert_allclose(dT, fd, rtol=0, atol=1e-7 * np.abs(fd).max())
