"""Array heaps of the compiled passes (vdad.heaps): heapsort and the budget heap."""

from __future__ import annotations

import numpy as np
import pytest

from vdad.heaps import heap_pop, heap_push, sort_ascending, sort_marked


@pytest.mark.parametrize("seed", range(4))
def test_sort_ascending_sorts_a_prefix_only(seed):
    rng = np.random.default_rng(seed)
    a = rng.integers(-50, 50, size=40)
    n = int(rng.integers(0, 41))
    out = a.copy()
    sort_ascending(out, n)
    np.testing.assert_array_equal(out[:n], np.sort(a[:n]))
    np.testing.assert_array_equal(out[n:], a[n:])


@pytest.mark.parametrize("size", [3, 12, 30, 40])
def test_sort_marked_lists_the_marked_entries_in_ascending_order(size):
    """A few marked entries (heapsort) and many (a scan of the marks) alike."""
    rng = np.random.default_rng(size)
    mark = np.zeros(40, bool)
    chosen = rng.choice(40, size=size, replace=False)
    mark[chosen] = True
    a = np.full(40, -7)
    a[:size] = chosen
    sort_marked(a, size, mark)
    np.testing.assert_array_equal(a[:size], np.sort(chosen))
    np.testing.assert_array_equal(a[size:], -7)


@pytest.mark.parametrize("seed", range(4))
def test_heap_pops_keys_in_descending_order_with_their_values(seed):
    rng = np.random.default_rng(seed)
    keys_in = rng.normal(size=30)
    keys_in[rng.integers(0, 30, size=3)] = np.inf              # pinned nodes: first
    keys, values = np.empty(30), np.empty(30)
    n = 0
    for i, k in enumerate(keys_in):
        n = heap_push(keys, values, n, k, float(i))
    got = []
    while n > 0:
        got.append((keys[0], int(values[0])))
        n = heap_pop(keys, values, n)
    order = [k for k, _ in got]
    assert order == sorted(keys_in, reverse=True)
    assert all(keys_in[i] == k for k, i in got)                 # each value kept its key
    assert sorted(i for _, i in got) == list(range(30))
