"""The robot protocol, served by the IaaS: its version, this cloud's keys and timing, its schemas.

::

    GET /protocol                        the version, the keys of this cloud, its timing rules
    GET /protocol/state.schema.json      the JSON Schemas (draft 2020-12) of docs/protocol/,
    GET /protocol/command.schema.json    generated from robocloud.fleet.messages when the
    GET /protocol/ack.schema.json        IaaS starts, so they are those of the code it runs
    GET /protocol/error.schema.json
    GET /protocol/states.schema.json     (a fleet gateway's batch of states)

No API key: a robot team reads them before it has one, as it reads docs/protocol.md.
``create_app`` calls ``install_protocol(app)``.
"""

from __future__ import annotations

from fastapi import FastAPI, Request
from fastapi.responses import JSONResponse
from pydantic import BaseModel, Field

from robocloud.fleet import keys
from robocloud.fleet.messages import PROTOCOL_VERSION
from robocloud.fleet.schemas import MESSAGES, file_name, protocol_schemas
from robocloud.iaas.config import Settings

PREFIX = "/protocol"
STATE_EVERY = 1.0  # seconds: a robot publishes its state at least this often


class SchemaResponse(JSONResponse):
    """A JSON Schema document, with its own media type (also in the OpenAPI)."""

    media_type = "application/schema+json"


class ProtocolKeys(BaseModel):
    state: str = Field(description="where each robot publishes its state")
    cmd: str = Field(description="where each robot answers commands (a Zenoh queryable)")
    error: str = Field(description="where the IaaS answers a state it refused")
    states: str = Field(
        description="where a fleet gateway publishes its robots' states in batches "
        "(a JSON array of states); <gateway> is the gateway's name"
    )


class ProtocolTiming(BaseModel):
    state_every: float = Field(description="seconds: the longest a robot may go without a state")
    ack_timeout: float = Field(description="seconds a robot has to acknowledge a command")
    offline_after: float = Field(description="seconds of silence after which a robot is offline")
    forget_after: float = Field(description="seconds of silence after which it is forgotten")


class ProtocolInfo(BaseModel):
    version: str = Field(description="the robot protocol's version, MAJOR.MINOR")
    cloud: str
    keys: ProtocolKeys = Field(description="key expressions; <id> is the robot's id")
    timing: ProtocolTiming
    schemas: dict[str, str] = Field(description="message name -> the path of its JSON Schema")


def protocol_info(settings: Settings) -> ProtocolInfo:
    prefix = keys.robots_prefix(settings.cloud)
    return ProtocolInfo(
        version=PROTOCOL_VERSION,
        cloud=settings.cloud,
        keys=ProtocolKeys(
            state=f"{prefix}/<id>/state",
            cmd=f"{prefix}/<id>/cmd",
            error=f"{prefix}/<id>/error",
            states=f"{keys.fleets_prefix(settings.cloud)}/<gateway>/states",
        ),
        timing=ProtocolTiming(
            state_every=STATE_EVERY,
            ack_timeout=settings.ack_timeout,
            offline_after=settings.offline_after,
            forget_after=settings.forget_after,
        ),
        schemas={name: f"{PREFIX}/{file_name(name)}" for name in MESSAGES},
    )


def install_protocol(app: FastAPI) -> None:
    """Serve ``/protocol`` and the schemas on ``app`` (whose ``state.settings`` is set)."""
    documents = protocol_schemas()

    @app.get(PREFIX, response_model=ProtocolInfo, tags=["robots"], operation_id="protocol")
    async def protocol(request: Request) -> ProtocolInfo:
        """The robot protocol this IaaS speaks: version, keys, timing, schemas (no API key)."""
        return protocol_info(request.app.state.settings)

    for name, document in documents.items():
        _serve_schema(app, name, document)


def _serve_schema(app: FastAPI, name: str, document: dict[str, object]) -> None:
    async def schema() -> SchemaResponse:
        return SchemaResponse(document)

    app.add_api_route(
        f"{PREFIX}/{file_name(name)}",
        schema,
        methods=["GET"],
        tags=["robots"],
        operation_id=f"protocol_{name}_schema",
        summary=f"The JSON Schema of the robot protocol's {name} message",
        response_class=SchemaResponse,
        responses={200: {"description": "the JSON Schema (draft 2020-12)"}},
    )
