"""The segment model's heavy tails (`assignment/model.py`, `Tails`): their cost, reach and fit."""

import numpy as np
import pytest

from roadlink.association.associators.assignment import Tails


def test_tails_cost_is_squared_in_the_core_and_flatter_beyond():
    r = np.linspace(0.0, 20.0, 81)
    assert np.allclose(Tails(0.0, 4.0).cost(r), r * r)
    heavy = Tails(0.1, 5.0)
    cost = heavy.cost(r)
    assert cost[0] == pytest.approx(0.0, abs=1e-12)
    assert np.all(np.diff(cost) > 0)
    assert np.allclose(cost[:3], r[:3] ** 2, rtol=0.1)  # the core is still r^2
    assert cost[-1] < 0.1 * 20.0**2  # 20 core spreads off is unlikely, not impossible
    # One large change is cheaper than two medium ones (a normal cost says the opposite).
    assert heavy.cost(np.array([10.0]))[0] < 2 * heavy.cost(np.array([5.0]))[0]


def test_tails_reach_is_where_the_cost_meets_the_budget():
    for tails in (Tails(0.0, 2.0), Tails(0.01, 3.0), Tails(0.2, 8.0)):
        reach = tails.reach(16.0)
        assert tails.cost(np.array([reach]))[0] <= 16.0 < tails.cost(np.array([reach * 1.02]))[0]


def test_tails_fit_recovers_a_known_mixture_and_finds_none_in_normal_data():
    rng = np.random.default_rng(0)
    core = rng.normal(size=9000)
    wide = 6.0 * rng.normal(size=1000)
    fitted = Tails.fit(np.concatenate([core, wide]), Tails(0.01, 3.0))
    assert fitted.weight == pytest.approx(0.1, abs=0.03)
    assert fitted.scale == pytest.approx(6.0, rel=0.15)
    assert Tails.fit(rng.normal(size=10000), Tails(0.05, 4.0)).weight < 0.02
    assert Tails.fit(np.zeros(5), Tails(0.05, 4.0)) == Tails(0.05, 4.0)  # too few: the prior
