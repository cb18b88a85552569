"""MOPSO's repository REP and its adaptive grid (thesis Algorithm 4, step 6 and the loop).

REP holds the non-dominated feasible coalitions found so far. Step 6 fills it
from the first evaluation; each pass of the while loop (steps 9-17) merges the
particles' new positions into it.

Where the thesis leaves the repository's size and the leader's choice open,
this follows Coello Coello, Pulido and Lechuga, "Handling multiple objectives
with particle swarm optimization" (IEEE TEVC 8(3), 2004):

- the objective space (T, C, N) spanned by REP is cut into hypercubes, the
  grid adapting to REP's bounds each time it is used;
- a leader is drawn by roulette over the occupied hypercubes, each with
  fitness 10 / (number of members), then a member of the chosen hypercube at
  random; the thesis's own rule, any member at random, is the other option;
- when REP holds more than its size, members are removed from the most
  crowded hypercubes first.

Dominance is docs/model.md's, under the tolerance of :mod:`robocloud.domain.numeric`.
"""

from __future__ import annotations

from typing import Literal

import numpy as np
import numpy.typing as npt

from robocloud.domain.numeric import isclose_array

FloatArray = npt.NDArray[np.float64]
BoolArray = npt.NDArray[np.bool_]
IntArray = npt.NDArray[np.int64]

LeaderRule = Literal["random", "grid"]


def dominance_matrix(a: FloatArray, b: FloatArray) -> BoolArray:
    """``out[i, j]``: objective row ``a[i]`` weakly dominates ``b[j]`` (all minimised)."""
    left = a[:, None, :]
    right = b[None, :, :]
    close = isclose_array(left, right)
    smaller = left < right
    no_worse = (smaller | close).all(axis=2)
    better = (smaller & ~close).any(axis=2)
    return np.asarray(no_worse & better)


def dominates_rows(a: FloatArray, b: FloatArray) -> BoolArray:
    """``out[i]``: ``a[i]`` weakly dominates ``b[i]``."""
    close = isclose_array(a, b)
    smaller = a < b
    return np.asarray((smaller | close).all(axis=1) & (smaller & ~close).any(axis=1))


def grid_cells(objectives: FloatArray, divisions: int) -> IntArray:
    """The hypercube of each row: the grid spans the rows' own bounds (adaptive).

    A dimension on which every row agrees is one division wide.
    """
    if len(objectives) == 0:
        return np.zeros(0, dtype=np.int64)
    low = objectives.min(axis=0)
    span = objectives.max(axis=0) - low
    scaled = np.divide(objectives - low, span, out=np.zeros_like(objectives), where=span > 0)
    index = np.minimum((scaled * divisions).astype(np.int64), divisions - 1)
    weights = divisions ** np.arange(objectives.shape[1], dtype=np.int64)
    return np.asarray(index @ weights, dtype=np.int64)


def crowding_keep(cells: IntArray, capacity: int, rng: np.random.Generator) -> BoolArray:
    """Which rows stay when members are removed from the most crowded hypercubes.

    Removing one member at a time from the fullest hypercube (ties at random)
    until ``capacity`` remain is a water-filling: every hypercube above some
    level is cut to it, and a few at the level lose one more.
    """
    total = len(cells)
    keep = np.ones(total, dtype=bool)
    excess = total - capacity
    if excess <= 0:
        return keep
    _, inverse, counts = np.unique(cells, return_inverse=True, return_counts=True)
    levels = np.arange(1, int(counts.max()) + 1)
    removed = np.maximum(counts[None, :] - levels[:, None], 0).sum(axis=1)
    level = int(levels[removed <= excess].min())
    quota = np.minimum(counts, level)
    extra = excess - int(removed[level - 1])
    if extra:
        at_level = np.flatnonzero(counts >= level)
        quota[rng.choice(at_level, size=extra, replace=False)] -= 1
    # A random order inside each hypercube decides which of its members go.
    order = np.lexsort((rng.random(total), inverse))
    start = np.concatenate(([0], np.cumsum(counts)[:-1]))
    rank = np.empty(total, dtype=np.int64)
    rank[order] = np.arange(total) - start[inverse[order]]
    return np.asarray(rank < quota[inverse])


def first_occurrences(rows: BoolArray) -> IntArray:
    """Indices of the rows not equal to an earlier row, ascending."""
    if len(rows) == 0:
        return np.zeros(0, dtype=np.int64)
    packed = np.packbits(rows, axis=1)
    padded = np.zeros((len(rows), -(-packed.shape[1] // 8) * 8), dtype=np.uint8)
    padded[:, : packed.shape[1]] = packed
    words = padded.view(np.uint64)
    # lexsort is stable: the first of each group of equal rows is the earliest.
    order = np.lexsort(words.T[::-1])
    ordered = words[order]
    starts = np.ones(len(rows), dtype=bool)
    starts[1:] = (ordered[1:] != ordered[:-1]).any(axis=1)
    return np.sort(order[starts]).astype(np.int64)


class Repository:
    """REP: non-dominated feasible positions (rows over the pool) and their (T, C, N)."""

    def __init__(self, width: int, capacity: int, divisions: int) -> None:
        self.capacity = capacity
        self.divisions = divisions
        self.members: BoolArray = np.zeros((0, width), dtype=bool)
        self.objectives: FloatArray = np.zeros((0, 3))
        self._leader_weight: FloatArray | None = None  # the grid roulette's, until REP changes

    def __len__(self) -> int:
        return len(self.members)

    def update(
        self, positions: BoolArray, objectives: FloatArray, rng: np.random.Generator
    ) -> None:
        """Algorithm 4, step 6 and each iteration: merge feasible positions, keep the best.

        The caller passes feasible rows only. A position already in REP, or
        twice among the new ones, is kept once; members keep their order.
        """
        old = len(self)
        members = np.concatenate((self.members, positions))
        values = np.concatenate((self.objectives, objectives))
        first = first_occurrences(members)
        fresh = first[first >= old]
        if len(fresh) == 0:
            return
        # REP is already mutually non-dominated: only comparisons with the
        # new positions can remove anything.
        fresh_values = values[fresh]
        kept_values = np.concatenate((self.objectives, fresh_values))
        fresh_ok = ~dominance_matrix(kept_values, fresh_values).any(axis=0)
        old_ok = ~dominance_matrix(fresh_values[fresh_ok], self.objectives).any(axis=0)
        members = np.concatenate((self.members[old_ok], members[fresh[fresh_ok]]))
        values = np.concatenate((self.objectives[old_ok], fresh_values[fresh_ok]))
        if len(members) > self.capacity:
            keep = crowding_keep(grid_cells(values, self.divisions), self.capacity, rng)
            members, values = members[keep], values[keep]
        self.members, self.objectives = members, values
        self._leader_weight = None

    def leaders(self, count: int, rule: LeaderRule, rng: np.random.Generator) -> IntArray:
        """Indices of ``count`` leaders (REP[h] of Algorithm 4's velocity update)."""
        size = len(self)
        if rule == "random":
            return np.asarray(rng.integers(0, size, size=count), dtype=np.int64)
        if self._leader_weight is None:
            # Roulette over hypercubes with fitness 10 / members, then a member
            # at random: a member's chance is proportional to 1 / members².
            _, inverse, counts = np.unique(
                grid_cells(self.objectives, self.divisions),
                return_inverse=True,
                return_counts=True,
            )
            weight = 1.0 / counts[inverse].astype(np.float64) ** 2
            self._leader_weight = weight / weight.sum()
        return np.asarray(rng.choice(size, size=count, p=self._leader_weight), dtype=np.int64)
