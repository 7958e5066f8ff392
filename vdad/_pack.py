"""One argument for the constant arrays of a compiled pass (a numba StructRef).

A call of a compiled function from Python converts every array it is given:
numba's dispatcher types each one, then unboxes it (on the pusher arm of
gymnasium, the DCA's 77 arrays cost 2.3 µs and 3.5 µs per call, more than a
third of the DCA itself; ``docs/benchmarks.md``). A :class:`Pack` holds a tuple
of arrays, nested as a pass takes them, for compiled code: it is built once,
typed and unboxed as one pointer, and a kernel that takes it hands the tuple on
to the pass (``vdad.dca.dca_call``, ``vdad.integrators.dca_steps``,
``vdad.region.region_call``). The arrays are the same objects: what the pass
writes into them is seen from Python, and the pack keeps them alive. An array
replaced on the Python side is not seen: build a new pack (:func:`pack_once`
builds one when its key changes). numba cannot copy a pack: an object that
keeps one leaves it out of its copies (``__getstate__``).
"""

from __future__ import annotations

from types import SimpleNamespace

from numba import config, types
from numba.experimental import structref

from ._linalg import kernel


@structref.register
class PackType(types.StructRef):
    """numba's type of a :class:`Pack`: its one field ``data``, typed by its tuple."""

    def preprocess_fields(self, fields):
        return tuple((name, types.unliteral(t)) for name, t in fields)


class Pack(structref.StructRefProxy):
    """A tuple of arrays ``data`` held for compiled code; build it with :func:`pack`."""


structref.define_proxy(Pack, PackType, ["data"])


@kernel
def _compiled_pack(data):
    """``Pack(data)`` in a cached kernel (called from Python, the constructor would
    compile itself in every process)."""
    return Pack(data)


def pack(data):
    """A :class:`Pack` of the tuple ``data``; in plain-Python mode
    (``NUMBA_DISABLE_JIT=1``), where a StructRef cannot be built, an object with
    the same field."""
    return SimpleNamespace(data=data) if config.DISABLE_JIT else _compiled_pack(data)


def pack_once(held, key, build=None):
    """``held``, a pair ``(key, pack)`` (or None), if its key is ``key`` itself;
    else ``(key, pack(build()))`` (``build`` None: the pack of ``key``). A caller
    that keeps the pair builds a pack only when its arrays change: packing
    converts every array once, as a call does."""
    if held is not None and held[0] is key:
        return held
    return key, pack(key if build is None else build())
