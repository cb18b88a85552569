"""Prune's capability classes, packed into integers, are numpy's unique rows."""

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from robocloud.selection.exact import capability_classes


@settings(max_examples=200, deadline=None)
@given(
    st.integers(0, 40).flatmap(
        lambda n: st.sampled_from([0, 1, 3, 8, 62, 63, 70]).flatmap(
            lambda k: arrays(np.bool_, (n, k))
        )
    )
)
def test_capability_classes_are_numpys_unique_rows(uses: np.ndarray) -> None:
    classes, member = capability_classes(uses)
    expected_classes, expected_member = np.unique(uses, axis=0, return_inverse=True)
    assert classes.dtype == np.bool_ and classes.shape == expected_classes.shape
    assert np.array_equal(classes, expected_classes)
    assert np.array_equal(member, expected_member.reshape(-1))
