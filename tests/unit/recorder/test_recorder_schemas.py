"""Key → channel kind → schema, with every key formation.keys builds."""

from __future__ import annotations

import json

import pytest
from foxglove.messages import FrameTransforms, Log, SceneUpdate
from jsonschema.validators import validator_for

from formation import keys
from formation.messages import ALL_MODELS
from recorder.reading.decoder import message_class
from recorder.recording import schemas

RUN = "run-7"

CASES = [
    (keys.agent_state(RUN, 3), "agent_state", "formation.CoordinationState"),
    (keys.link_state(RUN, 1, 2), "link_state", "formation.CoordinationState"),
    (keys.agent_report(RUN, 4), "agent_report", "formation.TokenReport"),
    (keys.link_report(RUN, 4), "leader_report", "formation.TokenReport"),
    (keys.leader_estimate_out(RUN), "leader_estimate", "formation.LeaderEstimate"),
    (keys.leader_estimate_for(RUN, 5), "agent_estimate", "formation.AgentEstimate"),
    (keys.link_estimate(RUN, 5), "link_estimate", "formation.AgentEstimate"),
    (keys.inbox(RUN, 0, "report"), "delivery", "formation.Delivery"),
    (keys.netem_decision(RUN), "decision", "formation.DecisionBatch"),
    (keys.netem_change(RUN), "link_change", "formation.LinkChange"),
    (keys.status(RUN, "agent", 2), "status", "formation.Status"),
    (keys.metrics(RUN), "metrics", "formation.EpochMetrics"),
    (keys.scene(RUN), "scene", "foxglove.SceneUpdate"),
    (keys.frames(RUN), "tf", "foxglove.FrameTransforms"),
    (keys.log(RUN), "log", "foxglove.Log"),
    (keys.alive(RUN, "leader", 0), "alive", "formation.LivelinessEvent"),
    (keys.netem_config(RUN), "unknown", "unknown"),
    ("somewhere/else", "unknown", "unknown"),
]


@pytest.mark.parametrize(("key", "kind", "schema"), CASES)
def test_every_key_maps_to_its_schema(key: str, kind: str, schema: str) -> None:
    assert schemas.classify(key) == kind
    assert schemas.schema_for_key(key).name == schema


def test_every_wire_model_has_a_channel_kind() -> None:
    assert set(ALL_MODELS) <= set(schemas.MESSAGE_MODELS.values())


@pytest.mark.parametrize("model", [*ALL_MODELS, schemas.LivelinessEvent])
def test_model_schemas_are_valid_json_schemas(model: type) -> None:
    spec = schemas.model_schema(model)
    doc = json.loads(spec.data)
    validator_for(doc).check_schema(doc)
    assert spec.encoding == "jsonschema"


def test_run_id_of() -> None:
    assert schemas.run_id_of(keys.agent_state(RUN, 1)) == RUN
    assert schemas.run_id_of("other/x/y") is None


@pytest.mark.parametrize(
    ("kind", "sdk"), [("scene", SceneUpdate), ("tf", FrameTransforms), ("log", Log)]
)
def test_foxglove_channels_carry_the_sdk_s_protobuf_schema(kind: str, sdk: type) -> None:
    spec = schemas.schema_for_kind(kind)
    theirs = sdk.get_schema()
    assert (spec.name, spec.encoding, spec.data) == (theirs.name, "protobuf", bytes(theirs.data))
    assert schemas.message_encoding(kind) == "protobuf"
    assert message_class(spec.name, spec.data).DESCRIPTOR.full_name == spec.name  # it parses


def test_wire_channels_are_json() -> None:
    assert schemas.message_encoding("agent_state") == "json"
    assert schemas.message_encoding("unknown") == "json"
