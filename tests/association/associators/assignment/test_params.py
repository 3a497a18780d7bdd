"""The parameters in time units (`assignment/params.py`, `within_time_scale`): held to the
detections' own time scale, and the defaults where that is seconds."""

import pytest
from pydantic import ValidationError

from roadlink.association.associators import AssociationError
from roadlink.association.associators.assignment import AssignmentParams, within_time_scale
from roadlink.association.associators.assignment.params import MAX_COST
from roadlink.association.associators.assignment.sensors import arrange
from roadlink.association.pipeline import parse_params
from roadlink.simulation import preset, simulate
from tests.helpers import in_hours


def test_parameters_in_time_units_follow_the_callers_time_unit():
    d = simulate(preset("medium"), seed=0).detections
    params = AssignmentParams()
    # Seconds: the defaults stand.
    assert within_time_scale(params, arrange(d, params).typical_travel_time()) == params
    # Hours: a 0.5 h duplicate window would take every report within half an hour of another
    # for a copy; both are held to shares of a travel time between sensors (about 3 s here).
    hours = within_time_scale(params, arrange(in_hours(d), params).typical_travel_time())
    assert 0.1 / 3600 < hours.duplicate_window < 1.0 / 3600
    assert hours.timestamp_noise < 0.1 / 3600


def test_the_contracts_velocity_names_are_the_parameters_and_their_bounds_are_checked():
    contract = {
        "velocity_change_weight",
        "velocity_change_spread",
        "velocity_change_ambiguity",
        "velocity_floor",
        "duplicate_velocity_tolerance",
    }
    assert contract <= set(AssignmentParams.model_fields)
    for name in contract:
        with pytest.raises(ValidationError, match=name):
            AssignmentParams(**{name: -1.0})


@pytest.mark.parametrize("value", ["inf", "-inf", "nan"])
def test_no_parameter_of_any_associator_may_be_infinite_or_nan(value):
    """The result's JSON holds the parameters it ran with, and JSON has no infinity."""
    for name in ("miss_cost", "timestamp_noise", "duplicate_window", "min_track_evidence"):
        with pytest.raises(AssociationError, match=name):
            parse_params("assignment", {name: value})
    with pytest.raises(AssociationError, match="length_weight"):
        parse_params("kmeans", {"length_weight": value})


def test_costs_are_bounded_where_every_pair_would_become_a_candidate():
    """gate_cost 1e14 ran for minutes on 5,000 detections (every pair within the time gate a
    candidate link), and inf failed inside the matching."""
    assert AssignmentParams(gate_cost=MAX_COST).gate_cost == MAX_COST
    for name in ("gate_cost", "miss_cost", "min_track_evidence"):
        with pytest.raises(ValidationError, match=name):
            AssignmentParams(**{name: 1e14})
