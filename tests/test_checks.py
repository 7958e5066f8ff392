"""Checks of user input (vdad.checks): what counts as numbers, and the messages."""

import numpy as np
import pytest

import vdad
from vdad import quantities, reference
from vdad.checks import check_count, check_real, check_vector, real_array, reject_unknown
from vdad.errors import InputError, ModelError
from vdad.scenes import pendulum


@pytest.mark.parametrize("value", [1, 2.5, np.float32(1.5), np.int64(3), [1, 2.0],
                                   ((1, 0), (0, 1)), np.eye(3), np.arange(3, dtype=np.uint8)])
def test_real_numbers_are_accepted(value):
    a = real_array("x", value)
    assert a.dtype == float
    np.testing.assert_array_equal(a, np.asarray(value, dtype=float))


@pytest.mark.parametrize("value, what", [
    ("1.0", "a string"), (b"1", "a string"), (None, "None"), (True, "a boolean"),
    (np.bool_(False), "a boolean"), (1 + 2j, "a complex number"), ([1, 2j], "a complex number"),
    ([[1, 2], [3]], "a ragged sequence"), ([1, None], "a list"), ({"a": 1}, "a dict"),
    (["1", "2"], "a string"), (object(), "a object"), ((True, 0, 0), "a sequence with booleans"),
    ([[1, 0], [0, np.True_]], "a sequence with booleans"),
])
def test_other_values_are_refused_by_name(value, what):
    with pytest.raises(InputError, match=f"^x must be a real number \\(or numbers\\), got {what}"):
        real_array("x", value)
    with pytest.raises(ModelError):
        real_array("x", value, ModelError)


def test_shapes_signs_and_counts():
    assert check_real("dt", 0.1, positive=True) == 0.1
    with pytest.raises(InputError, match="dt must be a single number, got"):
        check_real("dt", [0.1])
    with pytest.raises(InputError, match="dt must be positive, got 0"):
        check_real("dt", 0, positive=True)
    with pytest.raises(InputError, match=r"p must have shape \(3,\) \(or broadcast to it\)"):
        check_real("p", [1, 2], (3,))
    np.testing.assert_array_equal(check_real("p", 1, (3,)), [1, 1, 1])
    with pytest.raises(InputError, match=r"q must have shape \(2,\), got \(3,\)"):
        check_vector("q", [1, 2, 3], 2)
    with pytest.raises(InputError, match=r"q has non-finite entries at indices \[1\]"):
        check_vector("q", [1, np.inf], 2)
    assert check_count("n", 3.0) == 3 and check_count("n", 0, minimum=0) == 0
    for bad in (0, 2.5, "3", np.nan, np.inf, [3], True, None):
        with pytest.raises(InputError, match="n must be a positive integer, got"):
            check_count("n", bad)
    with pytest.raises(InputError, match=r"f got unknown option\(s\) \['b'\]; it takes \['a'\]"):
        reject_unknown("f", {"b": 1}, ("a",))
    reject_unknown("f", {}, ("a",))


@pytest.mark.parametrize("kwargs, match", [
    (dict(f_ext="abc"), "f_ext must be a real number.*string"),
    (dict(f_ext=np.zeros((3, 5))), r"f_ext must have shape \(3, 6\)"),
    (dict(tau=[1, 2]), r"tau must have shape \(3,\)"),
    (dict(qd=None), "qd must be a real number.*None"),
    (dict(q="abc"), "q must be a real number.*string"),
])
def test_forward_dynamics_names_the_argument(kwargs, match):
    model = pendulum(3).model
    args = dict(q=model.q_neutral, qd=np.zeros(3))
    args.update(kwargs)
    with pytest.raises(InputError, match=match):
        vdad.forward_dynamics(model, **args)


@pytest.mark.parametrize("call, match", [
    (lambda m: vdad.passive_forces(m, np.zeros(2), np.zeros(3)), r"q must have shape \(3,\)"),
    (lambda m: vdad.passive_forces(m, "q", "qd"), "q must be a real number"),
    (lambda m: vdad.passive_forces("m", np.zeros(3), np.zeros(3)), "model must be a vdad.Model"),
    (lambda m: vdad.passive_forces(m, np.zeros(3), [np.nan, 0, 0]), "qd has non-finite"),
    (lambda m: reference.crba("m", [0.0]), "model must be a vdad.Model"),
    (lambda m: reference.aba(m, np.full(3, 0.3), np.full(3, 1e200)),
     r"overflowed .*\|qd\| up to 1e\+200"),
    (lambda m: quantities.kinetic_energy(m, np.zeros(4), np.zeros(3)), r"q must have shape"),
    (lambda m: quantities.kinetic_energy(m, [np.nan, 0, 0], np.zeros(3)), "q has non-finite"),
    (lambda m: quantities.spatial_momentum(m, np.zeros(3), None), "qd must be a real number"),
    (lambda m: quantities.potential_energy(m, "abc"), "q must be a real number"),
    (lambda m: quantities.total_energy("m", [0, 0, 0], [0, 0, 0]), "model must be a vdad.Model"),
])
def test_public_functions_check_their_arguments(call, match):
    model = pendulum(3, axes="alternate").model
    with np.errstate(all="ignore"), pytest.raises(InputError, match=match):
        call(model)


def test_lists_are_states_too():
    model = pendulum(3).model
    e = quantities.total_energy(model, [0.1, 0, 0], [1, 0, 0])
    assert e == pytest.approx(quantities.total_energy(model, np.array([0.1, 0, 0]),
                                                      np.array([1.0, 0, 0])), rel=1e-15)
    np.testing.assert_array_equal(vdad.passive_forces(model, [0, 0, 0], [1, 2, 3]), np.zeros(3))
