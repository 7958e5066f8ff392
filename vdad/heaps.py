"""Binary max-heaps in arrays, for compiled passes: the budget heap of adaptive
dynamics (Kim 2008 §4.2, budget mode: keys with node ids as values,
``vdad.region.run_heap``), a heapsort of index lists (``vdad.region.rebuild``)
and the ascending order of a marked set (``vdad.hybrid.carry_forces``). Nothing
allocates; the heap lives in ``keys[:n]``."""

from __future__ import annotations

from ._linalg import inlined


@inlined
def sift_down(keys, values, root, n):
    """Restore the max-heap property of ``keys[:n]`` below ``root``, moving
    ``values`` with their keys (``values`` as long as ``keys``, or empty: none)."""
    while 2 * root + 1 < n:
        child = 2 * root + 1
        if child + 1 < n and keys[child + 1] > keys[child]:
            child += 1
        if keys[root] >= keys[child]:
            return
        keys[root], keys[child] = keys[child], keys[root]
        if values.shape[0] > 0:
            values[root], values[child] = values[child], values[root]
        root = child


@inlined
def heap_push(keys, values, n, key, value):
    """Push ``(key, value)`` on the max-heap ``keys[:n]``; returns its new size."""
    i = n
    keys[i], values[i] = key, value
    while i > 0:
        up = (i - 1) // 2
        if keys[up] >= keys[i]:
            break
        keys[up], keys[i] = keys[i], keys[up]
        values[up], values[i] = values[i], values[up]
        i = up
    return n + 1


@inlined
def heap_pop(keys, values, n):
    """Remove the top of the max-heap ``keys[:n]`` (read ``keys[0]``, ``values[0]``
    first); returns its new size."""
    n -= 1
    keys[0], values[0] = keys[n], values[n]
    sift_down(keys, values, 0, n)
    return n


@inlined
def sort_ascending(a, n):
    """Heapsort of ``a[:n]`` in place (O(n log n))."""
    none = a[:0]
    for start in range(n // 2 - 1, -1, -1):
        sift_down(a, none, start, n)
    for end in range(n - 1, 0, -1):
        a[0], a[end] = a[end], a[0]
        sift_down(a, none, 0, end)


@inlined
def sort_marked(a, n, mark):
    """``a[:n]``, the entries whose ``mark`` is set (every set one, each once), in
    ascending order: a heapsort (O(n log n)) while they are few, else a scan of
    ``mark`` (O(len(mark))), which costs less once ``n`` is a quarter of it."""
    if 4 * n < mark.shape[0]:
        sort_ascending(a, n)
        return
    k = 0
    for i in range(mark.shape[0]):
        if mark[i]:
            a[k] = i
            k += 1
