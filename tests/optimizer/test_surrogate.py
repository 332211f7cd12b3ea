"""The surrogate search: bounds, batch sizes, determinism, the feasibility model, and that it beats
random search on a cheap synthetic calibration problem with seed noise."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.stats import norm

from optimizer.ga import create_search, from_bytes, to_bytes
from optimizer.study import GASettings
from optimizer.surrogate import MatchRule, Observation, f1_of_distribution, fit_models, inverse_anscombe

RULE = MatchRule(measured=(4.0,) * 10, target=4.0, tolerance=0.5, n_items=30)


def clog_rate(genes: np.ndarray) -> float:
    """Mean N_t of a synthetic feeder: items stay with friction (gene 3), leave with restitution."""
    return 30.0 / (1.0 + np.exp(-10.0 * (genes[3] - 0.6) + 4.0 * (genes[2] - 0.5)))


def simulate(genes: np.ndarray, rng: np.random.Generator, invalid_below: float = 0.0) -> Observation:
    """One noisy run: Poisson N_t; sets with gene 0 (log E) below ``invalid_below`` fail."""
    if genes[0] < invalid_below:
        return Observation((), 1.0, False)
    return Observation((int(min(30, rng.poisson(clog_rate(genes)))),), 1e6 * (1.0 + genes[0]), True)


def objectives(observations):
    return np.array([[abs(o.n_remaining[0] - 4) if o.ok else 30, o.cost] for o in observations], float)


def surrogate(seed: int, population: int = 10, offspring: int = 5):
    settings = GASettings(algorithm="surrogate", population=population, offspring=offspring)
    return create_search(settings, n_genes=4, seed=seed, rule=RULE)


def run(search, batches: int, seed: int, invalid_below: float = 0.0):
    rng = np.random.default_rng(seed)
    proposed = []
    for _ in range(batches):
        genes = search.ask()
        proposed.append(genes)
        observations = [simulate(gene, rng, invalid_below) for gene in genes]
        search.tell(genes, objectives(observations), observations=observations)
    return proposed


def test_batches_have_the_study_sizes_and_stay_in_the_box():
    batches = run(surrogate(seed=1, population=8, offspring=3), batches=3, seed=0)

    assert [b.shape for b in batches] == [(8, 4), (3, 4), (3, 4)]
    for genes in batches:
        assert ((genes >= 0.0) & (genes <= 1.0)).all()
    # One batch never proposes the same set twice.
    assert len({tuple(row) for row in batches[1]}) == 3


def test_same_seed_same_proposals_and_restored_state_re_asks_the_same_batch():
    first, second = surrogate(seed=3), surrogate(seed=3)
    a, b = run(first, 2, seed=5), run(second, 2, seed=5)
    for x, y in zip(a, b, strict=True):
        np.testing.assert_array_equal(x, y)

    restored = from_bytes(to_bytes(first))
    np.testing.assert_array_equal(restored.ask(), first.ask())
    assert not np.array_equal(surrogate(seed=4).ask(), surrogate(seed=3).ask())


def test_tell_without_observations_is_refused():
    search = surrogate(seed=0)
    genes = search.ask()
    with pytest.raises(ValueError, match="observations"):
        search.tell(genes, np.zeros((len(genes), 2)))


def test_revise_replaces_the_observations_of_a_set_with_more_replicates():
    search = surrogate(seed=0, population=4)
    genes = search.ask()
    first = [Observation((0,), 1e6, True) for _ in genes]
    search.tell(genes, objectives(first), observations=first)

    search.revise(genes[1:2], np.zeros((1, 2)), observations=[Observation((0, 7, 9), 1e6, True)])

    assert search.observations[1].n_remaining == (0, 7, 9)
    assert [o.n_remaining for i, o in enumerate(search.observations) if i != 1] == [(0,)] * 3


def test_feasibility_model_learns_the_invalid_region_and_the_search_avoids_it():
    search = surrogate(seed=2, population=12, offspring=4)
    batches = run(search, batches=4, seed=1, invalid_below=0.3)

    model = search.models(random_state=0)
    probe = np.array([[0.05, 0.5, 0.5, 0.6], [0.8, 0.5, 0.5, 0.6]])
    p_invalid_side, p_valid_side = model.p_ok(probe)
    assert p_invalid_side < 0.3 < 0.7 < p_valid_side
    later = np.vstack(batches[1:])
    first_batch_failures = np.mean(batches[0][:, 0] < 0.3)
    assert np.mean(later[:, 0] < 0.3) < first_batch_failures


def test_median_of_the_clog_mixture_is_zero_unless_most_runs_clog():
    latent = np.array([2.0 * np.sqrt(4 + 0.375), 2.0 * np.sqrt(10 + 0.375)])
    assert inverse_anscombe(latent) == pytest.approx([4.0, 10.0])
    # Every run clogs: the median is the clog size's median (the transform is monotone).
    assert f1_of_distribution(RULE, 1.0, latent, noise_sd=1.0) == pytest.approx([0.0, 6.0])
    # Fewer than half clog: the median run emptied the tray, 4 items from the target.
    assert f1_of_distribution(RULE, 0.4, latent, noise_sd=1.0) == pytest.approx([4.0, 4.0])
    # Two thirds clog: the median is the clog size's 25 % quantile, below its median.
    lower = f1_of_distribution(RULE, 2.0 / 3.0, latent[1:], noise_sd=1.0)
    quartile = inverse_anscombe(latent[1] + norm.ppf(0.25))
    assert 4.0 < quartile < 10.0
    assert lower == pytest.approx([quartile - 4.0])


def test_wasserstein_rule_of_a_point_mass_is_the_mean_distance():
    rule = MatchRule(measured=(0, 0, 10, 10), target=5, tolerance=1, distance="wasserstein", n_items=30)
    latent = np.array([2.0 * np.sqrt(5 + 0.375)])
    # A simulated distribution concentrated at 5 is 5 items from every measured value.
    assert f1_of_distribution(rule, 1.0, latent, noise_sd=1e-9) == pytest.approx([5.0], abs=1e-6)
    # Half the runs empty, half keep 10: exactly the measured distribution.
    ten = np.array([2.0 * np.sqrt(10 + 0.375)])
    assert f1_of_distribution(rule, 0.5, ten, noise_sd=1e-9) == pytest.approx([0.0], abs=1e-6)


def test_models_need_no_failures_and_tolerate_only_failures():
    genes = np.random.default_rng(0).random((6, 4))
    all_ok = fit_models(genes, [Observation((3,), 1e6, True)] * 6, random_state=0)
    assert all_ok.feasibility is None and np.allclose(all_ok.p_ok(genes), 1.0)
    all_failed = fit_models(genes, [Observation((), 1.0, False)] * 6, random_state=0)
    assert all_failed.size is None and np.allclose(all_failed.p_match(genes, RULE), 0.5)


def first_true_match(search, seed: int, budget: int) -> int | None:
    """Simulations until one set both showed N_t = 4 and truly has a mean within 1 of 4."""
    rng = np.random.default_rng(seed)
    used = 0
    while used < budget:
        genes = search.ask()
        observations = []
        for gene in genes:
            used += 1
            observation = simulate(gene, rng)
            observations.append(observation)
            if observation.n_remaining == (4,) and abs(clog_rate(gene) - 4.0) < 1.0:
                return used
        search.tell(genes, objectives(observations), observations=observations)
    return None


def test_surrogate_finds_a_true_match_in_fewer_simulations_than_random():
    budget = 40
    found = {"surrogate": [], "random": []}
    for seed in range(3):
        found["surrogate"].append(first_true_match(surrogate(seed), seed, budget) or budget + 10)
        random = create_search(GASettings(algorithm="random", population=10, offspring=5), 4, seed)
        found["random"].append(first_true_match(random, seed, budget) or budget + 10)

    assert sum(found["surrogate"]) < sum(found["random"]), found


ANGLE = MatchRule(measured=(30.0, 32.0), target=31.0, tolerance=2.0, n_items=90.0, response="heap.angle_deg")
COUNT = MatchRule(measured=(1, 1, 2), target=1.0, tolerance=0.5, n_items=2, response="feeder.n_remaining")


def two_responses(genes: np.ndarray, rng: np.random.Generator) -> Observation:
    """A heap's angle that grows with friction (gene 3) and a two-item feeder that keeps one item
    where restitution (gene 2) is low: both experiments match only where mu ~ 0.55 and e < 0.5."""
    angle = 20.0 + 20.0 * genes[3] + rng.normal(0.0, 0.5)
    kept = int(genes[2] < 0.5) + int(rng.random() < 0.1)
    responses = {"heap.angle_deg": (angle,), "feeder.n_remaining": (kept,)}
    return Observation((angle,), 1e6 * (1.0 + genes[0]), True, responses)


def test_several_experiments_get_a_model_each_and_match_only_together():
    settings = GASettings(algorithm="surrogate", population=16, offspring=4)
    search = create_search(settings, n_genes=4, seed=0, rule=(ANGLE, COUNT))
    rng = np.random.default_rng(0)
    for _ in range(4):
        genes = search.ask()
        observations = [two_responses(gene, rng) for gene in genes]
        search.tell(genes, np.zeros((len(genes), 2)), observations=observations)

    model = search.models(random_state=0)
    # Both match / only the angle (the feeder empties) / only the count (the heap is too steep).
    probe = np.array([[0.5, 0.5, 0.2, 0.55], [0.5, 0.5, 0.8, 0.55], [0.5, 0.5, 0.2, 0.95]])
    both, angle_only, count_only = model.p_match(probe, search.rules)
    assert len(model.responses) == 2
    assert both > 0.5 > max(angle_only, count_only)
    for index in search.matched():
        observation = search.observations[index]
        assert abs(observation.values(ANGLE)[0] - 31.0) <= 2.0 and observation.values(COUNT) == (1,)
