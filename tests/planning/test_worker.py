"""The planner's child process: a failure there is one sentence here, never a traceback."""

from __future__ import annotations

import dataclasses

import pytest

from robocloud.errors import RoboCloudError
from robocloud.planning.generate import generate
from robocloud.planning.mrta import read_instance
from robocloud.planning.solve import solve


def test_a_child_that_fails_is_a_sentence() -> None:
    problem = read_instance(generate(4, 2, 0))
    # Distances of the wrong shape: the child stops on an IndexError.
    broken = dataclasses.replace(problem, task_distance=((0.0,),))
    with pytest.raises(RoboCloudError) as caught:
        solve(broken, time_limit=5.0)
    message = caught.value.message
    assert message.startswith("the planner stopped with exit code 1: IndexError")
    assert "\n" not in message
