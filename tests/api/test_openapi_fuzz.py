"""Property-based fuzz of the OpenAPI schema (schemathesis): generated requests, valid and
invalid, never get a 500 and every response matches the documented schema and status codes.

Excluded: ``positive_data_acceptance`` (a schema-valid request must be accepted). The API's
semantic rules cannot be written as JSON Schema (bounds low < high, the feeder config's own keys,
service limits, the bytes of a mesh), so schema-valid requests are rightly refused with a 422.
Everything else runs: no 5xx, documented status codes, content types and response schemas, and
schema-invalid requests rejected.

Runs twice, each time with a seeded, finished study so that some generated ids exist: in process
on SQLite (ASGI), and over HTTP against a live server (uvicorn on a port) on PostgreSQL, where
``Infinity`` in a number column and NUL bytes in a path once answered 500. The number of examples
per operation is bounded to keep each run under a minute.
"""

from __future__ import annotations

import socket
import threading
import time
from pathlib import Path

import pytest
import schemathesis
from fastapi.testclient import TestClient
from hypothesis import HealthCheck, given, settings
from hypothesis.errors import Unsatisfiable
from schemathesis import GenerationMode
from schemathesis.checks import positive_data_acceptance

from api.app import create_app
from api.auth import create_key
from api.db import create_db_engine, upgrade_database
from api.settings import load_settings
from api.store import SqlStore
from optimizer.driver import Driver
from optimizer.memory import SyntheticExecutor
from optimizer.study import StudyDefinition
from tests.api.conftest import _empty_postgres, study_definition

EXAMPLES_PER_OPERATION = 8


def _seeded_app(url: str, data_dir: Path):
    """The app on a migrated database holding one finished study; returns (app, engine, token)."""
    upgrade_database(url)
    engine = create_db_engine(url)
    store = SqlStore(engine)
    definition = StudyDefinition.model_validate(
        study_definition(ga={"population": 4, "offspring": 2, "generations": 1})
    )
    study_id = store.create_study(definition.model_dump(mode="json"), owner="fuzzer")
    Driver(store, SyntheticExecutor()).run_to_completion(study_id, poll_timeout=0)
    with store.session() as session:
        _, token = create_key(session, "fuzzer")
    settings_ = load_settings(
        database_url=url, data_dir=data_dir, max_request_bytes=64_000, max_upload_bytes=100_000
    )
    return create_app(settings_, engine=engine), engine, token


@pytest.fixture(scope="module")
def fuzzed_app(tmp_path_factory):
    path = tmp_path_factory.mktemp("fuzz") / "fuzz.db"
    app, engine, token = _seeded_app(f"sqlite:///{path}", path.parent / "data")
    yield app, token
    engine.dispose()


@pytest.fixture(scope="module")
def live_postgres_server(tmp_path_factory, postgres_url):
    """The app on the session's PostgreSQL database, served by uvicorn on a free port; yields
    (base URL, token) while it listens."""
    import uvicorn

    _empty_postgres(postgres_url)
    app, engine, token = _seeded_app(postgres_url, tmp_path_factory.mktemp("fuzz-pg") / "data")
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        port = sock.getsockname()[1]
    server = uvicorn.Server(uvicorn.Config(app, host="127.0.0.1", port=port, log_level="warning"))
    thread = threading.Thread(target=server.run, daemon=True)
    thread.start()
    deadline = time.monotonic() + 30
    while not server.started:
        if time.monotonic() > deadline or not thread.is_alive():
            pytest.fail("uvicorn did not start within 30 s")
        time.sleep(0.05)
    yield f"http://127.0.0.1:{port}", token
    server.should_exit = True
    thread.join(timeout=10)
    engine.dispose()


# The dashboard's TOML upload has no JSON body to generate; its own tests cover it.
NOT_FUZZED = "^/dashboard/"


@pytest.fixture(scope="module")
def api_schema(fuzzed_app):
    app, _ = fuzzed_app
    return schemathesis.openapi.from_asgi("/openapi.json", app).exclude(path_regex=NOT_FUZZED)


@pytest.fixture(scope="module")
def token(fuzzed_app):
    return fuzzed_app[1]


def _fuzz(operation, mode: GenerationMode, headers: dict[str, str]) -> None:
    @settings(
        max_examples=EXAMPLES_PER_OPERATION, deadline=None, suppress_health_check=list(HealthCheck),
        derandomize=True, database=None,
    )
    @given(case=operation.as_strategy(mode))
    def run(case) -> None:
        case.call_and_validate(headers=headers, excluded_checks=[positive_data_acceptance])

    try:
        run()
    except Unsatisfiable:
        # Only an operation with no parameter, header or body at all (GET /healthz) has nothing
        # to make invalid; for any other, no invalid request generated is a failure.
        if mode is GenerationMode.POSITIVE or _has_inputs(operation):
            raise


def _has_inputs(operation) -> bool:
    parts = (operation.path_parameters, operation.query, operation.headers, operation.cookies, operation.body)
    return any(len(list(part)) for part in parts)


@pytest.mark.parametrize("mode", [GenerationMode.POSITIVE, GenerationMode.NEGATIVE], ids=["valid", "invalid"])
def test_no_request_gets_a_500_or_breaks_the_schema(api_schema, token, mode):
    operations = [result.ok() for result in api_schema.get_all_operations()]

    for operation in operations:
        _fuzz(operation, mode, {"Authorization": f"Bearer {token}"})

    assert len(operations) >= 20


@pytest.mark.postgres
@pytest.mark.parametrize("mode", [GenerationMode.POSITIVE, GenerationMode.NEGATIVE], ids=["valid", "invalid"])
def test_a_live_server_on_postgresql_answers_no_request_with_a_500(live_postgres_server, mode):
    base_url, token = live_postgres_server
    schema = schemathesis.openapi.from_url(f"{base_url}/openapi.json").exclude(path_regex=NOT_FUZZED)
    operations = [result.ok() for result in schema.get_all_operations()]

    for operation in operations:
        _fuzz(operation, mode, {"Authorization": f"Bearer {token}"})

    assert len(operations) >= 20


def test_openapi_document_is_served(fuzzed_app):
    app, _ = fuzzed_app
    with TestClient(app) as client:
        document = client.get("/openapi.json").json()

    assert "/api/v1/studies/{study_id}/pareto" in document["paths"]
    assert document["components"]["securitySchemes"]["HTTPBearer"]["scheme"] == "bearer"


def test_scenario_and_params_publish_their_real_schema(fuzzed_app):
    app, _ = fuzzed_app
    with TestClient(app) as client:
        schemas = client.get("/openapi.json").json()["components"]["schemas"]

    def resolve(node):
        return schemas[node["$ref"].rsplit("/", 1)[-1]]

    for model in ("SimulationCreate", "StudyDefinition"):
        scenario = schemas[model]["properties"]["scenario"]
        # a discriminated union on kind: one alternative per registered kind
        assert scenario["discriminator"]["propertyName"] == "kind"
        assert set(scenario["discriminator"]["mapping"]) == {"feeder", "angle_of_repose", "combined"}
        mapping = scenario["discriminator"]["mapping"]
        by_kind = {kind: resolve({"$ref": ref}) for kind, ref in mapping.items()}
        assert [resolve(alt)["title"] for alt in scenario["oneOf"]] == [
            "FeederConfig", "HeapConfig", "CombinedConfig"
        ]
        feeder = by_kind["feeder"]
        assert feeder["additionalProperties"] is False
        assert {"tray", "items", "stages", "vibration", "run"} <= set(feeder["properties"])
        assert {"particles", "cylinder", "plate", "fit"} <= set(by_kind["angle_of_repose"]["properties"])
    params = schemas["SimulationCreate"]["properties"]["params"]
    assert (params["required"], params["additionalProperties"]) == (["E", "nu", "e", "mu"], False)
