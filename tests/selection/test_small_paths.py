"""The plain-Python path for a few coalitions gives numpy's answers, bit for bit.

``pareto_front`` switches to plain Python below a few tens of coalitions
(numpy's per-call cost dominates there). Values are drawn on a
coarse grid and nudged by less and by more than MODEL.md's tolerance, so
ties, near-ties and the tolerance's edges all occur.
"""

from hypothesis import given, settings
from hypothesis import strategies as st

from robocloud.domain import Coalition
from robocloud.selection import pareto

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
