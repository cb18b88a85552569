import json

import pydantic
import pytest

from robocloud.domain import Capability, Robot
from robocloud.errors import InvalidInput
from robocloud.fleet import keys
from robocloud.fleet.behaviour import energy_needed, refuse_assign, refuse_cancel, task_to_report
from robocloud.fleet.messages import COMMAND, Ack, Assign, Cancel, State, TaskProgress

CAPS = {
    "light": Capability(kind="sensing", time=20.0, cost=1.0),
    "grabber": Capability(kind="actuating", time=90.0, cost=8.0),
}


def state_json(**changes: object) -> dict[str, object]:
    base: dict[str, object] = {
        "id": "a-0001",
        "cloud": "cloud-a",
        "kind": "tribot",
        "position": [120.0, 40.5],
        "speed": 1.5,
        "battery": 86.0,
        "status": "busy",
        "travel_cost_per_m": 0.05,
        "capabilities": {"grabber": {"kind": "actuating", "time": 90.0, "cost": 8.0}},
        "task": {
            "request_id": "r-17",
            "phase": "travel",
            "progress": 0.25,
            "capabilities": ["grabber"],
        },
        "seq": 1042,
        "sent_at": 1767225600.25,
    }
    base.update(changes)
    return base


def test_state_round_trips_and_becomes_a_model_robot() -> None:
    state = State.model_validate_json(json.dumps(state_json()))
    assert State.model_validate_json(state.model_dump_json()) == state
    robot = state.to_robot()
    assert robot == Robot.model_validate(
        {k: v for k, v in state_json().items() if k not in {"kind", "task", "seq", "sent_at"}}
    )
    assert state.to_robot("offline").status == "offline"


def test_state_ignores_unknown_fields_and_rejects_bad_values() -> None:
    assert State.model_validate(state_json(firmware="1.2")).id == "a-0001"
    with pytest.raises(pydantic.ValidationError):
        State.model_validate(state_json(battery=101.0))
    with pytest.raises(pydantic.ValidationError):
        State.model_validate(
            state_json(
                task={"request_id": "r", "phase": "nap", "progress": 0.0, "capabilities": []}
            )
        )


def test_commands_parse_by_type() -> None:
    assign = COMMAND.validate_json(
        b'{"type": "assign", "request_id": "r-1", "location": [1, 2],'
        b' "capabilities": ["light"], "execution": "sequential"}'
    )
    assert assign == Assign(
        request_id="r-1", location=[1.0, 2.0], capabilities=["light"], execution="sequential"
    )
    assert COMMAND.validate_json(b'{"type": "cancel", "request_id": "r-1"}') == Cancel(
        request_id="r-1"
    )
    with pytest.raises(pydantic.ValidationError):
        COMMAND.validate_json(b'{"type": "dance", "request_id": "r-1"}')
    with pytest.raises(pydantic.ValidationError):
        COMMAND.validate_json(
            b'{"type": "assign", "request_id": "r-1", "location": [1, 2], "capabilities": []}'
        )
    assert json.loads(Cancel(request_id="r").model_dump_json()) == {
        "type": "cancel",
        "request_id": "r",
    }
    assert json.loads(Ack(ok=True, robot="a-1", request_id="r").model_dump_json()) == {
        "ok": True,
        "robot": "a-1",
        "request_id": "r",
        "error": None,
    }


@pytest.mark.parametrize(("execution", "expected"), [("parallel", 90.0), ("sequential", 110.0)])
def test_work_time_follows_the_execution_mode(execution: str, expected: float) -> None:
    command = Assign.model_validate(
        {
            "request_id": "r",
            "location": [0, 0],
            "capabilities": ["light", "grabber"],
            "execution": execution,
        }
    )
    assert command.work_time(CAPS) == expected


def test_a_robot_refuses_what_it_cannot_do() -> None:
    def assign(**changes: object) -> Assign:
        fields: dict[str, object] = {
            "request_id": "r-2",
            "location": [100.0, 0.0],
            "capabilities": ["grabber"],
        }
        fields.update(changes)
        return Assign.model_validate(fields)

    def refusal(
        status: str = "idle",
        current: str | None = None,
        battery: float = 80.0,
        command: Assign | None = None,
    ) -> str | None:
        return refuse_assign("a-1", status, current, CAPS, battery, [0.0, 0.0], command or assign())

    assert refusal() is None
    assert refusal(current="r-2") is None  # the same assign again
    assert refusal(status="busy", current="r-1") == "robot a-1 is busy with request r-1."
    assert refusal(status="charging") == "robot a-1 is charging, not idle."
    assert refusal(command=assign(capabilities=["kicker", "sound"])) == (
        "robot a-1 lacks the capabilities kicker, sound."
    )
    need = energy_needed(100.0, 90.0)
    assert need == pytest.approx(2.8)
    assert refusal(battery=2.5) == (
        "robot a-1's battery (2.5%) is too low for this task, which needs 2.8%."
    )
    assert refuse_cancel("a-1", None, "r-9") is None
    assert refuse_cancel("a-1", "r-9", "r-9") is None
    assert refuse_cancel("a-1", "r-1", "r-9") == (
        "robot a-1 is not on request r-9 but on request r-1."
    )


def test_a_finished_task_is_reported_while_it_lingers_and_gives_way_to_a_new_one() -> None:
    done = TaskProgress(request_id="r-1", phase="done", progress=1.0, capabilities=["grabber"])
    new = TaskProgress(request_id="r-2", phase="travel", progress=0.0, capabilities=["grabber"])
    assert task_to_report(None, done, finished_until=13.0, now=12.9) == done
    assert task_to_report(None, done, finished_until=13.0, now=13.0) is None
    assert task_to_report(new, done, finished_until=13.0, now=12.0) == new
    assert task_to_report(None, None, finished_until=13.0, now=12.0) is None


def test_keys_are_per_robot_and_refuse_bad_chunks() -> None:
    assert keys.state_key("cloud-a", "a-0001") == "robocloud/cloud-a/robots/a-0001/state"
    assert keys.cmd_key("cloud-a", "a-0001") == "robocloud/cloud-a/robots/a-0001/cmd"
    assert keys.robot_of("robocloud/cloud-a/robots/a-0001/cmd") == "a-0001"
    assert keys.robot_of("robocloud/cloud-a/sim/control") is None
    for bad in ("", "a/b", "a*", " a"):
        with pytest.raises(InvalidInput):
            keys.state_key("cloud-a", bad)
