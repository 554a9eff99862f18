"""Key → channel kind → schema, with every key formation.keys builds."""

from __future__ import annotations

import json
from importlib import resources

import pytest
from jsonschema.validators import validator_for

from formation import keys
from formation.errors import RecordingError
from formation.messages import ALL_MODELS
from recorder import schemas

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
    (keys.control(RUN), "control", "formation.Control"),
    (keys.metrics(RUN), "metrics", "formation.EpochMetrics"),
    (keys.scene(RUN), "scene", "foxglove.SceneUpdate"),
    (keys.alive(RUN, "leader", 0), "alive", "formation.LivelinessEvent"),
    (keys.netem_config(RUN), "unknown", "unknown"),
    ("somewhere/else", "unknown", "unknown"),
]


@pytest.mark.parametrize(("key", "kind", "schema"), CASES)
def test_every_key_maps_to_its_schema(key: str, kind: str, schema: str) -> None:
    assert schemas.classify(key) == kind
    assert schemas.schema_for_key(key).name == schema


def test_every_wire_model_has_a_channel_kind() -> None:
    assert set(ALL_MODELS) <= set(schemas.MODELS.values())


@pytest.mark.parametrize("model", [*ALL_MODELS, schemas.LivelinessEvent])
def test_model_schemas_are_valid_json_schemas(model: type) -> None:
    spec = schemas.model_schema(model)
    doc = json.loads(spec.data)
    validator_for(doc).check_schema(doc)
    assert spec.encoding == "jsonschema"


def test_run_id_of() -> None:
    assert schemas.run_id_of(keys.agent_state(RUN, 1)) == RUN
    assert schemas.run_id_of("other/x/y") is None


def test_foxglove_scene_schema_is_foxglove_s_own_file() -> None:
    spec = schemas.schema_for_kind("scene")
    doc = json.loads(spec.data)
    assert (spec.name, spec.encoding) == ("foxglove.SceneUpdate", "jsonschema")
    assert doc["title"] == "foxglove.SceneUpdate"
    assert "entities" in doc["required"] and "deletions" in doc["required"]
    validator_for(doc).check_schema(doc)
    assert len(spec.data) > 10_000  # the real schema, not a stand-in


def test_foxglove_schema_ships_with_its_licence() -> None:
    folder = resources.files("recorder") / schemas.FOXGLOVE_DIR
    assert "MIT License" in (folder / "LICENSE").read_text()
    assert "Foxglove" in (folder / "README.md").read_text()


def test_missing_foxglove_file_is_an_error() -> None:
    with pytest.raises(
        RecordingError,
        match=r"NoSuchSchema\.json: Foxglove's schema of foxglove\.NoSuchSchema is not in the installed package",
    ):
        schemas.foxglove_schema("NoSuchSchema")
