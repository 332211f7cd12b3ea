"""The dashboard's HTTP side without a browser: page shells, static assets with their caching
headers (plotly from the installed wheel), and its two JSON routes behind the API keys."""

from __future__ import annotations

import re
from pathlib import Path

import httpx
import plotly
import pytest

from api.dashboard.pages import study_of_trial
from tests.dashboard.conftest import RETAINED_IN_REPLAY


@pytest.fixture
def http(dashboard):
    with httpx.Client(base_url=dashboard.base_url, timeout=30) as client:
        yield client


def auth(dashboard) -> dict[str, str]:
    return {"Authorization": f"Bearer {dashboard.study.api_key}"}


@pytest.mark.parametrize("path", ["/", "/new", "/studies/st-x", "/trials/st-x-i00001-r00"])
def test_page_shells_need_no_key_and_carry_no_study_data(http, path):
    response = http.get(path)

    assert response.status_code == 200
    assert response.headers["content-type"].startswith("text/html")
    assert response.headers["cache-control"] == "private, max-age=60"
    assert "feeder-calibration" not in response.text


def test_study_page_links_plotly_from_the_wheel_with_its_version(http):
    html = http.get("/studies/st-x").text

    link = re.search(r'src="(/static/vendor/plotly\.min\.js\?v=[^"]+)"', html).group(1)
    served = http.get(link)

    assert link.endswith(f"v=plotly-{plotly.__version__}")
    wheel_copy = Path(plotly.__file__).parent / "package_data" / "plotly.min.js"
    assert served.content == wheel_copy.read_bytes()
    assert served.headers["cache-control"] == "public, max-age=31536000, immutable"


def test_versioned_asset_is_immutable_and_revalidates_with_its_etag(http):
    link = re.search(r'href="(/static/dashboard\.css\?v=[^"]+)"', http.get("/").text).group(1)

    first = http.get(link)
    again = http.get(link, headers={"If-None-Match": first.headers["etag"]})
    unversioned = http.get("/static/dashboard.css")

    assert first.status_code == 200
    assert first.headers["cache-control"] == "public, max-age=31536000, immutable"
    assert again.status_code == 304
    assert again.content == b""
    assert unversioned.headers["cache-control"] == "no-cache"


def test_assets_are_gzipped_when_the_client_accepts_it(http):
    raw = http.get("/static/study.js", headers={"Accept-Encoding": "identity"})
    compressed = http.get("/static/study.js", headers={"Accept-Encoding": "gzip"})

    assert "content-encoding" not in raw.headers
    assert compressed.headers["content-encoding"] == "gzip"
    assert int(compressed.headers["content-length"]) < len(raw.content)
    assert compressed.content == raw.content  # httpx decompressed it


def test_unknown_asset_and_path_tricks_are_404(http):
    assert http.get("/static/nope.js").status_code == 404
    assert http.get("/static/../pages.py").status_code == 404
    assert http.get("/static/%2e%2e/pages.py").status_code == 404


def test_trial_id_names_its_study():
    assert study_of_trial("st-0123abcd4567-i00042-r01") == "st-0123abcd4567"
    assert study_of_trial("not-a-trial") is None


def test_replay_sends_hulls_once_and_frames_compactly(http, dashboard):
    study, trial = dashboard.study.study_id, dashboard.study.replay_trial_id

    response = http.get(f"/api/v1/studies/{study}/trials/{trial}/replay", params={"max_frames": 25},
                        headers=auth(dashboard))

    body = response.json()
    assert response.status_code == 200
    assert body["retained"] == RETAINED_IN_REPLAY
    assert len(body["items"]) == len(RETAINED_IN_REPLAY)
    assert body["frames_total"] == 60
    assert len(body["frames"]["t"]) <= 26
    assert body["frames"]["t"][-1] == 65.0  # the last frame is always sent
    assert len(body["frames"]["pos"][0]) == len(RETAINED_IN_REPLAY)


def test_replay_sends_the_tilted_tray_its_vibration_and_every_item_as_a_closed_hull(http, dashboard):
    from collections import Counter

    import numpy as np

    from dem.scenarios.tray import TrayConfig, build_tray
    from tests.dashboard.seed import REPLAY_TILT_DEG, REPLAY_VIBRATION

    study, trial = dashboard.study.study_id, dashboard.study.replay_trial_id

    body = http.get(f"/api/v1/studies/{study}/trials/{trial}/replay", headers=auth(dashboard)).json()

    tray = build_tray(TrayConfig(tilt_deg=REPLAY_TILT_DEG))
    assert np.allclose(body["tray"]["vertices"], tray.vertices, atol=1e-4)
    assert body["tray"]["faces"] == tray.faces.tolist()
    assert body["tray"]["tilt_deg"] == REPLAY_TILT_DEG
    vibration = body["tray"]["vibration"]
    assert vibration["direction"] == pytest.approx(REPLAY_VIBRATION[:3])
    assert vibration["angle_deg"] == pytest.approx(25.0)
    assert (vibration["amplitude"], vibration["frequency"], vibration["start"]) == REPLAY_VIBRATION[3:]
    offsets = np.array(body["frames"]["tray_offset"])
    assert offsets.shape == (len(body["frames"]["t"]), 3)
    assert 0 < np.abs(offsets).max() <= REPLAY_VIBRATION[3] + 1e-5
    for item in body["items"]:
        # Each item's shape is a closed surface over its hull points: every edge has two faces.
        faces = np.array(item["faces"])
        edges = Counter(tuple(sorted(e)) for f in faces for e in ((f[0], f[1]), (f[1], f[2]), (f[2], f[0])))
        assert set(faces.ravel()) == set(range(len(item["hull"])))
        assert set(edges.values()) == {2}


def test_replay_needs_a_key_of_the_owner(http, dashboard):
    study, trial = dashboard.study.study_id, dashboard.study.replay_trial_id

    no_key = http.get(f"/api/v1/studies/{study}/trials/{trial}/replay")
    unknown = f"/api/v1/studies/{study}/trials/{study}-i99999-r00/replay"
    unknown_trial = http.get(unknown, headers=auth(dashboard))

    assert no_key.status_code == 401
    assert unknown_trial.status_code == 404


def test_replay_of_a_trial_without_snapshots_is_404_saying_where_they_live(http, dashboard):
    study, trial = dashboard.study.study_id, dashboard.study.trial_ids[0]

    response = http.get(f"/api/v1/studies/{study}/trials/{trial}/replay", headers=auth(dashboard))

    assert response.status_code == 404
    assert "snapshots" in response.json()["detail"]


def test_toml_definition_becomes_the_json_the_api_takes(http, dashboard):
    toml = 'name = "x"\n[experiment]\nmeasured = [3, 4]\n[ga]\npopulation = 4\n'

    response = http.post("/dashboard/definition", content=toml, headers=auth(dashboard))

    assert response.status_code == 200
    assert response.json() == {"name": "x", "experiment": {"measured": [3, 4]}, "ga": {"population": 4}}


@pytest.mark.parametrize(
    ("toml", "expected"),
    [
        ("name = ", "not valid TOML"),
        ('scenario_path = "/etc/feeder.toml"', "inline as a [scenario] table"),
        ("a = " + "[" * 5000 + "]" * 5000, "nested too deeply"),
    ],
)
def test_bad_toml_definition_is_422_saying_what_to_fix(http, dashboard, toml, expected):
    response = http.post("/dashboard/definition", content=toml, headers=auth(dashboard))

    assert response.status_code == 422
    assert expected in response.json()["detail"]


def test_the_new_study_starter_is_the_readme_quick_study():
    """The form's starter is examples/study-quick.toml, a calibration that matches and validates
    (the former starter put 9 of 20 runs in the invalid region and matched nothing)."""
    import tomllib

    from optimizer.study import load_study_file, parse_study

    root = Path(__file__).resolve().parents[2]
    source = (root / "api/dashboard/static/new.js").read_text()
    starter = re.search(r"const STARTER = `(.*?)`;", source, re.S).group(1)

    assert parse_study(tomllib.loads(starter)) == load_study_file(root / "examples/study-quick.toml")
