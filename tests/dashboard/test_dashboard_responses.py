"""The dashboard names whatever responses a study's experiments measure, with the units the
scenario registry declares: a heap study shows its angle of repose in degrees and no N_t; a heap
and feeder study gets one Fig. 5 panel per experiment; the feeder keeps its N_t in items."""

from __future__ import annotations

import json

import pytest

from tests.dashboard.conftest import save_screenshot
from tests.dashboard.seed import seed_heap_study
from tests.dashboard.test_dashboard_browser import js_fmt

pytestmark = pytest.mark.browser

DRAWN = "(id) => document.getElementById(id)?.data?.length > 0 && document.getElementById(id).layout"
# Everything plotly shows of a figure: axis titles, annotations, trace names and hover texts.
FIGURE = """(id) => {
  const div = document.getElementById(id);
  const axes = Object.entries(div.layout).filter(([k]) => /^[xy]axis\\d*$/.test(k))
    .map(([k, a]) => [k, a.title?.text ?? ""]);
  return {
    axes: Object.fromEntries(axes),
    yaxisOf: Object.fromEntries(Object.entries(div.layout).filter(([k]) => /^yaxis\\d*$/.test(k))
      .map(([k, a]) => [k, a.domain])),
    annotations: (div.layout.annotations || []).map((a) => a.text),
    traces: div.data.map((t) => ({name: t.name, y: t.y, yaxis: t.yaxis || "y", hover: t.hovertemplate,
      customdata: t.customdata})),
  };
}"""


def study_figures(page, dashboard, study_id: str) -> dict:
    page.goto(dashboard.url(f"/studies/{study_id}"))
    for plot in ("pareto-plot", "generation-plot", "parameter-plot", "progress-plot"):
        page.wait_for_function(DRAWN, arg=plot)
    page.wait_for_selector("#equivalent tbody tr")
    plots = ("pareto-plot", "generation-plot", "parameter-plot")
    return {plot: page.evaluate(FIGURE, plot) for plot in plots}


def mentions_n_t(*texts) -> bool:
    return any("N<sub>t</sub>" in text or "N_t" in text or "items" in text for text in texts)


@pytest.fixture(scope="module")
def heap(dashboard):
    return seed_heap_study(dashboard.store)


def test_heap_study_shows_the_angle_of_repose_in_degrees_and_no_n_t(page, dashboard, heap):
    figures = study_figures(page, dashboard, heap.study_id)
    facts = page.locator("#study-facts").inner_text()
    # The page's own text; the identifiability method is the optimiser's sentence, sent as is.
    body = page.locator("main").evaluate(
        "(main) => { const copy = main.cloneNode(true);"
        " copy.querySelector('#identifiability-basis').remove(); return copy.innerText; }"
    )

    fig5, pareto = figures["generation-plot"], figures["pareto-plot"]
    assert fig5["axes"]["yaxis"] == "(a) measured angle of repose (deg)"
    assert fig5["axes"]["yaxis2"] == "(b) computation time T of the whole protocol (s)"
    assert pareto["axes"]["yaxis"] == f"f1 = |median(angle of repose) − {heap.target:g}| (deg)"
    target = next(t for t in fig5["traces"] if t["name"].startswith("experimental target"))
    assert target["name"] == f"experimental target angle of repose = {heap.target:g}"
    assert set(target["y"]) == {heap.target} and target["yaxis"] == "y"
    # Every measured point's hover names the angle with its unit; failed runs say what they lack.
    measured = fig5["traces"][0]
    assert measured["customdata"] and all(
        c[5].startswith("angle of repose = ") and c[5].endswith(" deg") for c in measured["customdata"]
    )
    assert any("no angle of repose" in text for text in fig5["annotations"] + pareto["annotations"])
    assert "Target angle of repose\n31 deg (tolerance ±1.5)" in facts
    assert not mentions_n_t(json.dumps(figures, ensure_ascii=False), body)
    assert page.errors == []
    save_screenshot(page, "dashboard-heap")
    page.goto(dashboard.url("/"))
    listed = page.locator(f"tr[data-study-id='{heap.study_id}'] td").nth(4)
    listed.wait_for()
    # Sets within the tolerance exist, so the list shows the one the driver's rule recommends.
    recommended = dashboard.store.get_study(heap.study_id).recommendation
    assert min(heap.f1.values()) <= 1.5 and recommended["f1"] <= 1.5
    assert listed.inner_text() == f"E = {js_fmt(recommended['params']['E'])}, ν = 0.3, " \
        f"e = {js_fmt(recommended['params']['e'])}, μ = {js_fmt(recommended['params']['mu'])}"


def test_heap_trial_page_shows_the_declared_responses_with_units(page, dashboard, heap):
    trial = next(tid for tid in heap.trial_ids if tid not in heap.failed)
    failed = next(iter(heap.failed))
    page.goto(dashboard.url(f"/trials/{trial}"))
    page.wait_for_selector("#trial[data-loaded='1']")
    facts = page.locator("#trial-facts").inner_text()
    curve_hidden = page.locator("#discharge-plot").evaluate("(box) => box.closest('.card').hidden")
    page.goto(dashboard.url(f"/trials/{failed}"))
    page.wait_for_selector("#trial[data-loaded='1']")
    failed_facts = page.locator("#trial-facts").inner_text()

    assert "angle of repose\n" in facts and " deg\n" in facts
    assert "heap height\n0.04 m" in facts
    assert f"f1 = |angle of repose − target|\n{heap.f1[trial]:.3g} deg" in facts
    assert "angle of repose\nnone: the run ended unstable, it measured nothing" in failed_facts
    assert curve_hidden  # a heap records no discharge curve
    assert not mentions_n_t(facts, failed_facts)
    assert page.errors == []


def test_heap_and_feeder_study_has_one_panel_per_experiment(page, dashboard):
    study = seed_heap_study(dashboard.store, with_feeder=True)
    figures = study_figures(page, dashboard, study.study_id)
    fig5 = figures["generation-plot"]

    assert fig5["axes"]["yaxis"] == "(a) heap angle of repose (deg)"
    assert fig5["axes"]["yaxis4"] == "(b) feeder N<sub>t</sub> (items)"
    assert fig5["axes"]["yaxis2"] == "(c) computation time T of the whole protocol (s)"
    top, bottom = fig5["yaxisOf"]["yaxis"], fig5["yaxisOf"]["yaxis4"]
    assert bottom[1] < top[0]  # stacked, not overlapping
    targets = {t["yaxis"]: set(t["y"]) for t in fig5["traces"] if t["name"].startswith("experimental target")}
    assert targets == {"y": {20.5}, "y4": {2}}
    medians = [t for t in fig5["traces"] if t["name"] == "median per generation"]
    assert sorted(t["yaxis"] for t in medians) == ["y", "y2", "y4"]
    assert figures["pareto-plot"]["axes"]["yaxis"]== "f1 = max |simulated − target| / tolerance (–)"
    hover = fig5["traces"][0]["customdata"][0][5]
    assert "heap angle of repose = " in hover and " deg<br>feeder N<sub>t</sub> = " in hover
    assert hover.endswith(" items")
    # Sets within the tolerance were found: the page recommends one, as the driver stored it.
    page.wait_for_selector("#recommendation dl")
    recommendation = page.locator("#recommendation").inner_text()
    stored = dashboard.store.get_study(study.study_id).recommendation
    assert "No parameter set matched" not in recommendation
    assert f"open trial {stored['trial_ids'][0]}" in recommendation
    # identifiability: the verdict of both experiments together, and each one's own beside it
    page.wait_for_selector("#identifiability-alone tbody tr[data-parameter='mu']")
    header = page.locator("#identifiability-alone thead").inner_text()
    assert "heap angle of repose" in header and "feeder N_t" in header
    assert page.locator("#identifiability-alone tbody tr[data-parameter='mu'] .status").count() == 2
    assert page.errors == []
    save_screenshot(page, "dashboard-heap-feeder")


def test_feeder_study_keeps_its_n_t_in_items(page, dashboard):
    figures = study_figures(page, dashboard, dashboard.study.study_id)

    assert figures["generation-plot"]["axes"]["yaxis"] == "(a) measured N<sub>t</sub> (items)"
    assert figures["pareto-plot"]["axes"]["yaxis"] == "f1 = |median(N<sub>t</sub>) − 4| (items)"
    header = page.locator("#equivalent thead").inner_html()
    assert "N<sub>t</sub> per search run" in header
    assert page.errors == []
