"""Binary assembly trees over a model (theory §4-5).

Leaves are the bodies plus one *ground leaf* per root joint (``Phi = 0``,
``b = 0``). Every internal node joins two sub-assemblies ``A`` (holding the
predecessor side of its joint) and ``B`` (the successor side) across exactly one
joint, so a tree is fixed by the order in which joints are merged: any
permutation of the joints is a valid assembly order, and results do not depend on
it. :meth:`AssemblyTree.balanced` picks the order by rounds of greedy matchings
that prefer merges with few resulting ports, giving depth O(log n) on chains and
small port sets on trees.

A port is ``(joint, side)``: side ``+1`` if the sub-assembly holds the joint's
child body, ``-1`` if it holds the parent. Each node's ports are ordered
``alpha`` (from ``A``) then ``beta`` (from ``B``), as in (T11).

The tree precomputes the flat arrays the compiled passes read
(:attr:`AssemblyTree.arrays`: per node where its blocks ``Phi`` (n_pairs, 6, 6)
and its ports' vectors ``b`` start, and its first port slot; per slot its port and
where it comes from; :attr:`AssemblyTree.stack_arrays`: the same with the
blocks of the nodes live in the bottom-up pass only).
"""

from __future__ import annotations

from functools import cached_property

import numpy as np

from .checks import check_count, show
from .errors import InputError
from .model import Immutable, check_model

GROUND = -1


def _find(parent, i):
    """Root of ``i`` in the union-find forest ``parent`` (path halving)."""
    while parent[i] != i:
        parent[i] = parent[parent[i]]
        i = parent[i]
    return i


def _merge(model, order):
    """The binary tree that merging the joints of ``model`` in ``order`` builds:
    ``left``, ``right``, ``joint`` and ``height`` per internal node (numbered in
    merge order after the bodies), ``ports`` per node."""
    nb = model.nb
    # cluster bookkeeping: union-find over bodies; ground leaves are separate
    find_parent = list(range(nb))
    node_of = list(range(nb))          # cluster root body -> node id
    ports = [[(i, +1)] + [(int(c), -1) for c in model.children[i]] for i in range(nb)]
    height = [0] * nb
    left, right, joint = [], [], []
    for j in order:
        p = model.parent[j]
        if p < 0:
            a_node, a_ports, a_h = GROUND, [(j, -1)], 0
        else:
            ra = _find(find_parent, p)
            a_node, a_ports, a_h = node_of[ra], ports[node_of[ra]], height[node_of[ra]]
        rb = _find(find_parent, j)
        b_node = node_of[rb]
        node = nb + len(joint)
        left.append(a_node)
        right.append(b_node)
        joint.append(j)
        ports.append([pt for pt in a_ports if pt != (j, -1)]
                     + [pt for pt in ports[b_node] if pt != (j, +1)])
        height.append(1 + max(a_h, height[b_node]))
        if p < 0:
            node_of[rb] = node
        else:
            find_parent[rb] = ra
            node_of[ra] = node
    return left, right, joint, height, ports


def depth_first(nb, left, right):
    """Every node id (bodies and internal nodes ``nb + i``) in depth-first
    post-order: ``A``'s subtree, ``B``'s, then the node; roots in merge order."""
    referenced = set(left) | set(right)
    out = []
    for root in range(nb, nb + len(left)):
        if root in referenced:
            continue
        stack = [(root, False)]
        while stack:
            node, done = stack.pop()
            if node == GROUND:
                continue
            if node < nb or done:
                out.append(node)
                continue
            stack += [(node, True), (right[node - nb], False), (left[node - nb], False)]
    return out


class AssemblyTree(Immutable):
    """An immutable binary assembly tree of ``model``.

    Build with :meth:`balanced`, :meth:`sequential` or from any joint order
    ``AssemblyTree(model, order)`` (joint names or indices, each once).
    Attributes: ``left``, ``right``, ``joint`` (internal nodes; children are
    body ids ``0..nb-1``, ``GROUND`` or ``nb + internal index``), ``height``,
    ``ports`` (per node), ``n_slots``, ``n_nodes`` (bodies and
    internal nodes), ``up`` (parent node of every node, -1 at the roots),
    ``top`` (top body of every node: the body whose parent is outside it; -1 when
    the node holds a ground leaf), ``first`` (per internal node: the first internal
    index of its subtree, whose internal nodes are ``first[i]`` to ``i``),
    ``n_ports`` (per node; ``max_ports``),
    ``pair_base``, ``slot_base`` (per node: its first block and slot; the
    internal nodes' ``n_inner_slots`` slots first), ``n_pairs``
    (the store of the blocks ``a <= c`` only, ``docs/design.md``), ``slot_joint``,
    ``slot_side`` (per slot: its port), ``port_A``, ``port_B`` (per internal
    node: where its joint's port is in A's and B's ports), ``slot_child``,
    ``slot_index``, ``slot_sign`` (per slot of an internal node: the child the
    port comes from, its index there and ``s_a`` of (T11)), :attr:`arrays`
    (all of these for the compiled passes), ``post`` (every node, bodies too, in
    depth-first post-order), ``segments`` (where each root's subtree starts in
    ``post``, then its length: independent subtrees, one per root). Internal
    nodes are numbered in depth-first post-order, whatever the merge order given
    (it only fixes the tree), and the blocks of every node are stored in ``post``
    order: a subtree's data lie together, so the passes work in cache
    (``docs/design.md``).
    """

    def __init__(self, model, order):
        check_model(model)
        nb = model.nb
        if isinstance(order, (str, bytes)) or not hasattr(order, "__iter__"):
            raise InputError(f"an assembly order is a sequence of joint names or indices, got "
                             f"{show(order)}")
        order = [self._joint_id(model, j) for j in order]
        if sorted(order) != list(range(nb)):
            missing = sorted(set(range(nb)) - set(order))
            raise InputError("an assembly order must name every joint exactly once; "
                             f"missing or repeated: {[model.joint_names[j] for j in missing][:5]}")
        self.model = model
        left, right, joint, height, ports = _merge(model, order)
        post = [joint[n - nb] for n in depth_first(nb, left, right) if n >= nb]
        if post != joint:                   # number the nodes depth first (docstring)
            left, right, joint, height, ports = _merge(model, post)
        self.left = np.array(left, int)
        self.right = np.array(right, int)
        self.joint = np.array(joint, int)
        self.height = np.array(height, int)
        self.ports = tuple(tuple(p) for p in ports)
        self.depth = int(max(height))
        self.n_nodes = nb + len(joint)
        up = np.full(self.n_nodes, -1)
        top = np.arange(self.n_nodes)
        first = np.arange(len(joint), dtype=np.int64)
        for i, (a, b) in enumerate(zip(left, right, strict=True)):
            up[b] = nb + i
            if a != GROUND:
                up[a] = nb + i
            top[nb + i] = -1 if a == GROUND else top[a]
            first[i] = min([i] + [first[c - nb] for c in (a, b) if c >= nb])
        self.up, self.top, self.first = up, top, first
        self._plan()

    @staticmethod
    def _joint_id(model, j):
        if isinstance(j, str):
            return model.joint_index(j)
        index = check_count("an assembly order's joint index", j, minimum=0)
        if index >= model.nb:
            raise InputError(f"joint index {index} out of range 0..{model.nb - 1}")
        return index

    # --- constructors --------------------------------------------------------------

    @classmethod
    def balanced(cls, model):
        """Rounds of greedy matchings, cheapest merges (fewest ports) first."""
        nb = check_model(model).nb
        parent = model.parent
        uf = list(range(nb))
        nports = np.array([1 + len(model.children[i]) for i in range(nb)])
        size = np.ones(nb, int)
        grounded = np.zeros(nb, bool)      # cluster root -> already holds its ground leaf
        remaining = list(range(nb))
        order = []
        while remaining:
            cand = []
            for j in remaining:
                b = _find(uf, j)
                if parent[j] < 0:
                    cand.append((nports[b] - 1, size[b] + 1, j, -1 - j, b))
                else:
                    a = _find(uf, parent[j])
                    cand.append((nports[a] + nports[b] - 2, size[a] + size[b], j, a, b))
            cand.sort()
            used = set()
            merged = []
            for merged_ports, merged_size, j, a, b in cand:
                if a in used or b in used:
                    continue
                used.update((a, b))
                merged.append(j)
                order.append(j)
                if a < 0:
                    grounded[b] = True
                    nports[b] -= 1
                    size[b] += 1
                else:
                    uf[b] = a
                    nports[a] = merged_ports
                    size[a] = merged_size
                    grounded[a] |= grounded[b]
            done = set(merged)
            remaining = [j for j in remaining if j not in done]
        return cls(model, order)

    @classmethod
    def sequential(cls, model):
        """Tip-to-base order (each body joined to its subtree, ABA-like): depth O(n)."""
        return cls(model, list(range(check_model(model).nb))[::-1])

    # --- plans ------------------------------------------------------------------------

    def _plan(self):
        model = self.model
        nb, nj = model.nb, model.nb
        n_nodes = nb + len(self.joint)
        # storage: blocks a <= c and slots P for every body leaf and internal node
        pair_base = np.zeros(n_nodes, int)
        slot_base = np.zeros(n_nodes, int)
        npair, nslt = 0, 0
        self.post = np.array(depth_first(nb, self.left, self.right), np.int64)
        ends = np.flatnonzero(self.up[self.post] < 0) + 1       # after each root
        self.segments = np.concatenate([[0], ends]).astype(np.int64)
        n_inner = sum(len(self.ports[n]) for n in range(nb, n_nodes))
        for n in self.post:                 # stored in the order the passes visit them,
            P = len(self.ports[n])          # the internal nodes' slots first
            pair_base[n] = npair
            npair += P * (P + 1) // 2
            if n >= nb:
                slot_base[n] = nslt
                nslt += P
        for n in self.post:
            if n < nb:
                slot_base[n] = nslt
                nslt += len(self.ports[n])
        self.n_pairs, self.n_slots, self.n_inner_slots = npair, nslt, n_inner
        self.pair_base, self.slot_base = pair_base, slot_base
        self.n_ports = np.array([len(p) for p in self.ports], int)
        self.max_ports = int(self.n_ports.max())
        self.slot_joint = np.full(nslt, nj)      # (joint, side) of every port slot
        self.slot_side = np.zeros(nslt, int)
        for n in range(n_nodes):
            for a, (j, side) in enumerate(self.ports[n]):
                self.slot_joint[slot_base[n] + a], self.slot_side[slot_base[n] + a] = j, side
        # per internal node: the index of its joint's port in A's and B's ports; per
        # slot of an internal node: the child it comes from, its index there, its sign
        self.port_A = np.zeros(len(self.joint), int)
        self.port_B = np.zeros(len(self.joint), int)
        self.slot_child = np.full(nslt, -1)
        self.slot_index = np.zeros(nslt, int)
        self.slot_sign = np.zeros(nslt, int)
        for i, (j, A, B) in enumerate(zip(self.joint, self.left, self.right, strict=True)):
            if A != GROUND:
                self.port_A[i] = self.ports[A].index((j, -1))
            self.port_B[i] = self.ports[B].index((j, +1))
            for a, pt in enumerate(self.ports[nb + i]):
                child, sign = (A, -1) if A != GROUND and pt in self.ports[A] else (B, +1)
                s = slot_base[nb + i] + a
                self.slot_child[s], self.slot_index[s], self.slot_sign[s] = (
                    child, self.ports[child].index(pt), sign)

    @cached_property
    def arrays(self) -> tuple:
        """The arrays the compiled DCA passes (:mod:`vdad.dca`) read, as one tuple:
        ``left, right, joint, port_A, port_B`` per internal node, ``n_ports,
        pair_base, slot_base`` per node, ``slot_joint, slot_side, slot_child,
        slot_index, slot_sign`` per slot, ``post``, ``segments`` (int64)."""
        return tuple(np.ascontiguousarray(a, np.int64) for a in (
            self.left, self.right, self.joint, self.port_A, self.port_B, self.n_ports,
            self.pair_base, self.slot_base, self.slot_joint, self.slot_side, self.slot_child,
            self.slot_index, self.slot_sign, self.post, self.segments))

    @cached_property
    def stack_arrays(self) -> tuple:
        """:attr:`arrays` with ``pair_base`` for a store that keeps only the blocks
        live in the bottom-up pass (``docs/design.md``, "Block storage"), then the
        number of blocks that store holds: ``(arrays, n_blocks)``. A node's blocks
        live from its evaluation to its parent's. In post-order the live nodes of one
        depth parity form a stack, and a node (one parity) is written while its
        children (the other) are read: each node is placed on its parity's stack
        above the live nodes of that parity. Each root's subtree has stacks of its
        own (subtrees run in parallel)."""
        depth = np.zeros(self.n_nodes, np.int64)
        for n in self.post[::-1]:                          # parents before children
            if self.up[n] >= 0:
                depth[n] = depth[self.up[n]] + 1
        pairs = self.n_ports * (self.n_ports + 1) // 2
        base = np.zeros(self.n_nodes, np.int64)
        parity = depth % 2
        total = 0
        for lo, hi in zip(self.segments[:-1], self.segments[1:], strict=True):
            tops, extent = [0, 0], [0, 0]                  # per parity: stack top, extent
            for n in self.post[lo:hi]:
                if n >= self.model.nb:                     # its children leave the stack
                    for c in (self.right[n - self.model.nb], self.left[n - self.model.nb]):
                        if c != GROUND:
                            tops[parity[c]] = base[c]
                p = parity[n]
                base[n] = tops[p]
                tops[p] += pairs[n]
                extent[p] = max(extent[p], tops[p])
            odd = parity[self.post[lo:hi]] == 1            # parity 1 after parity 0
            base[self.post[lo:hi][odd]] += extent[0]
            base[self.post[lo:hi]] += total
            total += extent[0] + extent[1]
        arrays = list(self.arrays)
        arrays[6] = base
        return tuple(arrays), total

    def __repr__(self):
        return (f"AssemblyTree(bodies={self.model.nb}, depth={self.depth}, "
                f"max_ports={max(len(p) for p in self.ports)})")


def check_tree(model, tree):
    """``tree`` checked to be an :class:`AssemblyTree` of ``model`` (built for it,
    or for a model of the same topology and joint dofs), or an InputError."""
    if not isinstance(tree, AssemblyTree):
        raise InputError(f"tree must be a vdad.AssemblyTree, got {type(tree).__name__}")
    other = tree.model
    if other is model:
        return tree
    if other.nb != model.nb or not np.array_equal(other.parent, model.parent):
        raise InputError(f"tree was built for model {other.name!r} ({other.nb} bodies), whose "
                         f"topology differs from model {model.name!r} ({model.nb} bodies); "
                         f"build it with AssemblyTree.balanced(model)")
    differ = np.flatnonzero((other.nv_joint != model.nv_joint)
                            | (other.nq_joint != model.nq_joint))
    if len(differ):
        j = differ[0]
        raise InputError(f"tree was built for model {other.name!r}, whose joint "
                         f"{other.joint_names[j]!r} has {other.nv_joint[j]} dofs where joint "
                         f"{model.joint_names[j]!r} of model {model.name!r} has "
                         f"{model.nv_joint[j]}; build it with AssemblyTree.balanced(model)")
    return tree
