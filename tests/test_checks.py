"""Checks of user input (vdad.checks): what counts as numbers, and the messages."""

import numpy as np
import pytest

import vdad
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
    (["1", "2"], "a string"), (object(), "a object"),
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
