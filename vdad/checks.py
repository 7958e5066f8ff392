"""Checks of user input, shared by every public entry point.

Each returns the value in the form the code uses (a float array, an int, ...) or
raises an :class:`~vdad.errors.InputError` (or the ``error`` class given, e.g.
:class:`~vdad.errors.ModelError` for model descriptions) whose message names the
argument and what is wrong with it. Numbers are real numbers: ints and floats of
any precision, alone or in (nested) sequences and arrays; strings, booleans,
complex numbers, ``None`` and ragged lists are errors, not silently converted.
The checks run in constructors and public functions, once per call, never inside
the hot path of a step.
"""

from __future__ import annotations

import numpy as np

from .errors import InputError


def show(value, width=60):
    """``repr(value)``, shortened to about ``width`` characters for a message."""
    text = repr(value)
    return text if len(text) <= width else text[:width - 3] + "..."


def _as_real(value):
    """``(float array, None)`` if ``value`` holds real numbers only, else ``(None,
    what it is)``."""
    if isinstance(value, (str, bytes)):
        return None, "a string"
    if value is None:
        return None, "None"
    try:
        a = np.asarray(value)
    except (TypeError, ValueError):
        return None, "a ragged sequence" if isinstance(value, (list, tuple)) else (
            f"a {type(value).__name__}")
    if a.dtype.kind in "iuf" and not (isinstance(value, (list, tuple)) and _has_bool(value)):
        return a.astype(float), None
    if a.dtype.kind in "iuf":
        return None, "a sequence with booleans"
    return None, {"b": "a boolean", "c": "a complex number", "U": "a string",
                  "S": "a string"}.get(a.dtype.kind, f"a {type(value).__name__}")


def _has_bool(items):
    """Whether the (nested) list or tuple ``items`` holds a boolean."""
    return any(isinstance(x, (bool, np.bool_))
               or (isinstance(x, (list, tuple)) and _has_bool(x)) for x in items)


def real_array(name, value, error=InputError):
    """``value`` as a float array, if it holds real numbers only (any shape)."""
    a, what = _as_real(value)
    if a is None:
        raise error(f"{name} must be a real number (or numbers), got {what}"
                    + ("" if value is None else f": {show(value)}"))
    return a


def check_finite(name, value, error=InputError):
    """``value`` as a float array of any shape whose entries are all finite."""
    a = real_array(name, value, error)
    if not np.all(np.isfinite(a)):
        raise error(f"{name} must be finite, got {show(value)}")
    return a


def all_finite(a):
    """Whether every entry of the float array ``a`` is finite: its sum is (one pass,
    no temporary), unless the sum overflowed, then entry by entry."""
    s = a.sum()
    return bool(s - s == 0.0) or bool(np.isfinite(a).all())


def check_vector(name, x, n, allow_none=False, error=InputError):
    """``x`` as a finite float vector of length ``n``, or a clear error (a float64
    array of that shape is returned as it is, without a copy)."""
    if x is None and allow_none:
        return None
    if type(x) is np.ndarray and x.dtype == np.float64 and x.shape == (n,) and all_finite(x):
        return x
    a = real_array(name, x, error)
    if a.shape != (n,):
        raise error(f"{name} must have shape ({n},), got {a.shape}")
    bad = np.flatnonzero(~np.isfinite(a))
    if len(bad):
        raise error(f"{name} has non-finite entries at indices {bad[:5].tolist()}")
    return a


def check_real(name, value, shape=None, positive=False, nonnegative=False, error=InputError):
    """``value`` as a finite float array broadcast to ``shape``, or with ``shape``
    None a single number (0-d array); optionally ``> 0`` or ``>= 0``; or an
    error naming ``name``."""
    a = real_array(name, value, error)
    if shape is None:
        if a.ndim:
            raise error(f"{name} must be a single number, got {show(value)}")
    else:
        try:
            a = np.broadcast_to(a, shape).copy()
        except ValueError:
            raise error(f"{name} must have shape {shape} (or broadcast to it), got "
                        f"{a.shape}") from None
    if not np.all(np.isfinite(a)):
        raise error(f"{name} must be finite, got {show(value)}")
    if positive and np.any(a <= 0):
        raise error(f"{name} must be positive, got {show(value)}")
    if nonnegative and np.any(a < 0):
        raise error(f"{name} must be >= 0, got {show(value)}")
    return a


def check_count(name, value, minimum=1, error=InputError):
    """``value`` as an int if it is a whole number ``>= minimum``, or an error
    naming ``name``."""
    if type(value) is int and value >= minimum:         # the common case, at once
        return value
    what = "a positive integer" if minimum == 1 else f"an integer >= {minimum}"
    a = _as_real(value)[0]
    if a is None or a.ndim or not np.isfinite(a) or a != int(a) or a < minimum:
        raise error(f"{name} must be {what}, got {show(value)}")
    return int(a)


def check_flag(name, value):
    """``value`` as a bool if it is one (Python's or numpy's), else an InputError
    naming ``name``: a string such as ``'no'`` is not taken for True."""
    if not isinstance(value, (bool, np.bool_)):
        raise InputError(f"{name} must be True or False, got {type(value).__name__}: "
                         f"{show(value)}")
    return bool(value)


def check_callable(name, f, signature):
    """``f`` if it is None or callable, else an InputError naming ``name`` and the
    expected ``signature``."""
    if f is not None and not callable(f):
        raise InputError(f"{name} must be a callable {signature} (or None), got "
                         f"{type(f).__name__}: {show(f)}")
    return f


def reject_unknown(where, unknown, accepted):
    """An InputError if the dict ``unknown`` of keyword arguments that ``where``
    does not take is not empty, naming them and the ``accepted`` ones."""
    if unknown:
        raise InputError(f"{where} got unknown option(s) {sorted(unknown)}; it takes "
                         f"{sorted(accepted)}")


def check_wrenches(model, f_ext, name="f_ext"):
    """``f_ext`` as a finite (nb, 6) array, or None; errors name ``name``."""
    if f_ext is None:
        return None
    a = real_array(name, f_ext)
    if a.shape != (model.nb, 6):
        raise InputError(f"{name} must have shape ({model.nb}, 6) (torque about the centre of "
                         f"mass; force, world axes), got {a.shape}")
    bad = np.flatnonzero(~np.all(np.isfinite(a), axis=1))
    if len(bad):
        raise InputError(f"{name} is not finite on body {model.body_names[bad[0]]!r}")
    return a


def names_text(names, most=3):
    """``names`` for a one-line message: at most ``most`` quoted, then "and N more"."""
    names = list(names)
    shown = ", ".join(repr(n) for n in names[:most])
    return shown + (f" and {len(names) - most} more" if len(names) > most else "")
