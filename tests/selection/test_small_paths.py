"""The plain-Python paths for a few coalitions give numpy's answers, bit for bit.

``pareto_front`` and the final choice switch to plain Python below a few tens
of coalitions (numpy's per-call cost dominates there). Values are drawn on a
coarse grid and nudged by less and by more than MODEL.md's tolerance, so
ties, near-ties and the tolerance's edges all occur.
"""

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from robocloud.domain import Coalition
from robocloud.selection import pareto
from robocloud.selection.choice import CHOICE_WEIGHTS, SMALL_FRONT, choose
from robocloud.selection.promethee import usual_net_flows, usual_net_flows_small

NUDGES = (0.0, 0.0, 4e-7, -4e-7, 2e-6, -2e-6, 1e-10)


def value(base: float) -> st.SearchStrategy[float]:
    return st.tuples(st.integers(1, 6), st.sampled_from(NUDGES)).map(
        lambda p: base * p[0] + p[1] * (1.0 if p[1] < 1e-9 else base)
    )


coalition = st.builds(
    lambda ids, t, c: Coalition(robots=tuple(sorted(ids)), time=t, cost=c),
    st.sets(st.sampled_from([f"r-{i}" for i in range(6)]), min_size=1, max_size=3),
    value(50.0),
    value(3.0),
)


@settings(max_examples=400, deadline=None)
@given(st.lists(coalition, min_size=1, max_size=pareto.SMALL))
def test_the_small_front_is_the_arrays_front(coalitions: list[Coalition]) -> None:
    pool = sorted(set(coalitions), key=lambda s: (s.cost, s.time, s.size, s.robots))
    small = pareto._small_front(pool)
    assert pareto.pareto_front(coalitions) == small  # the public path takes it
    # The arrays' loop, taken past the threshold: padded with coalitions that
    # are far slower and dearer than any drawn one, so they change nothing.
    far = [Coalition(robots=(f"z-{i:02d}",), time=1e6 + i, cost=1e6 + i)
           for i in range(pareto.SMALL)]
    assert [c for c in pareto.pareto_front([*coalitions, *far]) if c not in far] == small


@settings(max_examples=400, deadline=None)
@given(
    st.lists(st.tuples(value(50.0), value(3.0), st.integers(1, 4).map(float)),
             min_size=1, max_size=SMALL_FRONT),
    st.sampled_from(sorted(CHOICE_WEIGHTS)),
)
def test_small_flows_are_numpys_bit_for_bit(rows: list[tuple[float, float, float]],
                                            priority: str) -> None:
    weights = CHOICE_WEIGHTS[priority]
    small = usual_net_flows_small(rows, weights, (True, True, True))
    arrays = usual_net_flows(np.array(rows), np.array(weights), np.ones(3, dtype=bool))
    assert small == arrays.tolist()


@settings(max_examples=200, deadline=None)
@given(st.lists(coalition, min_size=1, max_size=SMALL_FRONT),
       st.sampled_from(sorted(CHOICE_WEIGHTS)))
def test_the_choice_is_the_same_either_way(coalitions: list[Coalition], priority: str) -> None:
    front = pareto.pareto_front(coalitions)
    rows = np.array([[c.time, c.cost, float(c.size)] for c in front])
    phi = usual_net_flows(rows, np.array(CHOICE_WEIGHTS[priority]), np.ones(3, dtype=bool))
    best = round(float(phi.max()), 9)
    tied = [c for c, f in zip(front, phi, strict=True) if round(float(f), 9) == best]
    assert choose(front, priority) == min(tied, key=lambda c: (c.cost, c.time, c.size, c.robots))
