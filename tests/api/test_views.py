"""The per-study view cache: one build per version however many requests ask at once, and views
that may lag a version served from the previous one while the next is built."""

from __future__ import annotations

import threading
import time
from concurrent.futures import ThreadPoolExecutor

import pytest

from api.services.views import StudyViewCache


def test_concurrent_requests_for_a_new_version_build_it_once():
    views, builds = StudyViewCache(), []

    def build() -> bytes:
        builds.append(1)
        time.sleep(0.3)  # an expensive view (identifiability): long enough for every request to ask
        return b"v1"

    with ThreadPoolExecutor(8) as pool:
        bodies = list(pool.map(lambda _: views.get_or_build("identifiability", "s1", 1, build), range(8)))

    assert bodies == [b"v1"] * 8
    assert len(builds) == 1


def test_a_view_that_may_lag_is_served_stale_while_its_next_version_builds():
    views, release = StudyViewCache(), threading.Event()
    views.get_or_build("progress", "s1", 1, lambda: b"v1", stale_ok=True)

    def slow() -> bytes:
        release.wait(10)
        return b"v2"

    started = time.monotonic()
    during = [views.get_or_build("progress", "s1", 2, slow, stale_ok=True) for _ in range(3)]
    waited = time.monotonic() - started
    release.set()
    deadline = time.monotonic() + 10
    while views.get_or_build("progress", "s1", 2, slow, stale_ok=True) != b"v2":
        assert time.monotonic() < deadline, "the background build never landed"
        time.sleep(0.01)

    assert during == [b"v1"] * 3
    assert waited < 1.0


def test_a_view_that_must_be_current_waits_for_its_build():
    views = StudyViewCache()
    views.get_or_build("pareto", "s1", 1, lambda: b"v1")

    assert views.get_or_build("pareto", "s1", 2, lambda: b"v2") == b"v2"


def test_a_failed_build_is_raised_to_its_requests_and_tried_again_by_the_next():
    views, attempts = StudyViewCache(), []

    def flaky() -> bytes:
        attempts.append(1)
        if len(attempts) == 1:
            raise RuntimeError("database went away")
        return b"v1"

    try:
        views.get_or_build("pareto", "s1", 1, flaky)
    except RuntimeError as exc:
        assert "went away" in str(exc)
    else:
        raise AssertionError("the build's error was swallowed")

    assert views.get_or_build("pareto", "s1", 1, flaky) == b"v1"


def test_a_view_that_may_lag_builds_one_version_at_a_time_however_many_pass():
    views, release, builds = StudyViewCache(), threading.Event(), []
    views.get_or_build("progress", "s1", 1, lambda: b"v1", stale_ok=True)

    def slow(version: int):
        def build() -> bytes:
            builds.append(version)
            release.wait(10)
            return f"v{version}".encode()
        return build

    during = [views.get_or_build("progress", "s1", v, slow(v), stale_ok=True) for v in (2, 3, 4, 5)]
    release.set()
    deadline = time.monotonic() + 10
    while views.get_or_build("progress", "s1", 5, slow(5), stale_ok=True) != b"v5":
        assert time.monotonic() < deadline, "the latest version was never built"
        time.sleep(0.01)

    assert during == [b"v1"] * 4
    assert builds == [2, 5]  # versions 3 and 4 passed while 2 was building: never built


def test_a_resting_view_waits_rest_times_its_build_before_the_next_and_says_it_is_stale():
    # Identifiability rests 9 times its build: after every batch of quick trials it took two
    # thirds of a core (benchmarks/README.md, session 5).
    views, builds = StudyViewCache(), []
    views.serve("identifiability", "s1", 1, lambda: b"v1", stale_ok=True)

    def build(version: int):
        def slow() -> bytes:
            builds.append((version, time.monotonic()))
            time.sleep(0.2)
            return f"v{version}".encode()
        return slow

    def current(version: int, within_s: float = 10.0) -> float:
        """Ask until the view is of ``version``; when it was."""
        deadline = time.monotonic() + within_s
        while not views.serve("identifiability", "s1", version, build(version), True, rest=5.0).current:
            assert time.monotonic() < deadline, f"version {version} was never built"
            time.sleep(0.01)
        return time.monotonic()

    stale = views.serve("identifiability", "s1", 2, build(2), stale_ok=True, rest=5.0)
    built_2 = current(2)
    asked_3 = views.serve("identifiability", "s1", 3, build(3), stale_ok=True, rest=5.0)
    built_3 = current(3)

    assert (stale.body, stale.current) == (b"v1", False)
    assert (asked_3.body, asked_3.current) == (b"v2", False)
    assert [version for version, _ in builds] == [2, 3]
    # The second build started no sooner than 5 x 0.2 s after the first ended.
    assert builds[1][1] - built_2 >= 5 * 0.2 * 0.9
    assert built_3 - builds[1][1] >= 0.2


def test_a_stale_answer_of_a_resting_view_says_when_a_newer_one_can_be_ready():
    # Dashboards asked every poll for identifiability while it rested: a third of their requests.
    views, built = StudyViewCache(), []
    views.serve("identifiability", "s1", 1, lambda: b"v1", stale_ok=True)

    def slow() -> bytes:
        started = time.monotonic()
        time.sleep(0.2)
        built.append((started, time.monotonic()))
        return b"v2"

    building = views.serve("identifiability", "s1", 2, slow, stale_ok=True, rest=5.0)
    deadline = time.monotonic() + 10
    while not views.serve("identifiability", "s1", 2, slow, stale_ok=True, rest=5.0).current:
        assert time.monotonic() < deadline, "version 2 was never built"
        time.sleep(0.01)
    asked = time.monotonic()
    resting = views.serve("identifiability", "s1", 3, lambda: b"v3", stale_ok=True, rest=5.0)

    started, ended = built[0]
    took = ended - started
    assert building.current is False
    assert building.retry_after_s == pytest.approx(0.0, abs=0.05)  # as long as version 1's (instant) build
    assert (resting.body, resting.current) == (b"v2", False)
    # The rest left (5 builds' time after the build ended), then one more build.
    assert resting.retry_after_s == pytest.approx(ended + 5 * took - asked + took, abs=0.05)


def test_a_stale_answer_of_a_resting_view_while_it_builds_says_when_the_build_should_end():
    # Pages asked every poll while identifiability built, 84-915 times a benchmark run
    # (benchmarks/README.md, API session 8): a build is expected to take as long as the previous.
    views, release = StudyViewCache(), threading.Event()

    def first() -> bytes:
        time.sleep(0.5)
        return b"v1"

    views.serve("identifiability", "s1", 1, first, stale_ok=True, rest=5.0)
    started = time.monotonic()
    building = views.serve("identifiability", "s1", 2, lambda: release.wait(10) and b"v2", True, rest=5.0)
    time.sleep(0.2)
    asked_again = views.serve("identifiability", "s1", 2, lambda: b"v2", True, rest=5.0)
    waited = time.monotonic() - started
    release.set()

    assert (building.body, building.current) == (b"v1", False)
    assert building.retry_after_s == pytest.approx(0.5, abs=0.05)
    assert (asked_again.body, asked_again.current) == (b"v1", False)
    assert asked_again.retry_after_s == pytest.approx(0.5 - waited, abs=0.05)


def test_forty_polled_studies_keep_their_objects_between_builds():
    # One limit of 32 (view, study) pairs: with progress and the study read each keeping one, 16
    # studies polled in turn made theirs afresh at every build, and a fresh progress reads the
    # whole study (benchmarks/README.md, API session 8, part 2).
    views, made = StudyViewCache(), []

    for _ in range(2):
        for study in range(40):
            for view in ("progress", "trial-tally"):
                views.kept(view, f"s{study}", lambda: made.append(1) or object())

    assert len(made) == 80  # once per view and study


def test_past_its_limit_the_least_recently_polled_study_loses_its_kept_objects(settings, engine):
    from api.app import create_app

    views = create_app(settings.model_copy(update={"view_kept_studies": 2}), engine=engine).state.study_views
    kept = {(view, study): views.kept(view, study, object) for study in ("s1", "s2") for view in ("a", "b")}

    views.kept("a", "s1", object)  # s1 polled last: s2 is the least recent
    views.kept("a", "s3", object)

    assert views.kept("b", "s1", object) is kept[("b", "s1")]
    assert views.kept("a", "s2", object) is not kept[("a", "s2")]
