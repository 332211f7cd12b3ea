"""TOML study definitions for the dashboard's "New study" form: ``POST /dashboard/definition``
turns the TOML text a user pasted or uploaded into the JSON document that
``POST /api/v1/studies`` accepts. Browsers have no TOML parser and we ship no JavaScript build,
so the server parses it with the standard library's ``tomllib``.

It only translates: it does not validate the study (the API does that when the browser POSTs the
result, with the messages every client gets) and it stores nothing. It refuses ``scenario_path``
because a request must never make the server read a file it names; the scenario goes inline as a
``[scenario]`` table instead.
"""

from __future__ import annotations

import tomllib
from typing import Any

from fastapi import APIRouter, Request

from api.deps import ApiKeyDep, SettingsDep
from api.errors import InvalidInputError, PayloadTooLargeError

router = APIRouter(prefix="/dashboard", tags=["dashboard"])


@router.post(
    "/definition",
    openapi_extra={"requestBody": {"content": {"application/toml": {"schema": {"type": "string"}}}}},
)
async def toml_definition(request: Request, principal: ApiKeyDep, settings: SettingsDep) -> dict[str, Any]:
    """A TOML study definition (request body) as the JSON object to POST to /api/v1/studies."""
    body = await request.body()
    if len(body) > settings.max_request_bytes:
        raise PayloadTooLargeError(
            f"the definition is {len(body)} bytes; this service accepts at most "
            f"{settings.max_request_bytes} (DEMCAL_MAX_REQUEST_BYTES)"
        )
    try:
        data = tomllib.loads(body.decode("utf-8"))
    except UnicodeDecodeError:
        raise InvalidInputError("the definition is not UTF-8 text") from None
    except tomllib.TOMLDecodeError as exc:
        raise InvalidInputError(f"not valid TOML: {exc}") from None
    except RecursionError:  # tomllib recurses per nesting level: "a = [[[[...]]]]" can exhaust it
        raise InvalidInputError("the TOML is nested too deeply; a study definition is a few tables") from None
    if "scenario_path" in data:
        raise InvalidInputError(
            "scenario_path names a file on your machine, which the server cannot read: paste the "
            "feeder configuration inline as a [scenario] table (its keys are those of the feeder "
            "TOML, e.g. [scenario.items], [scenario.stages])"
        )
    return data
