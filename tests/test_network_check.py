"""The network check's decision (cuboidlib.network_check): analytic cases of the rule, its calibration and its words."""

from __future__ import annotations

import math

import numpy as np
import pytest

from cuboidlib.network_check import (CALIBRATION_MARGIN, LATENT_THRESHOLDS, NetworkVerdict, calibrated_threshold,
                                     network_verdict, verdict_advice, verdict_reasons)

THRESHOLDS = {"chair": 10.0, "table": 20.0, "animal": 40.0}


def test_a_shape_inside_the_given_networks_threshold_and_nearest_to_it_leaves_the_check_silent():
    v = network_verdict({"chair": 9.0, "table": 19.0, "animal": 39.0}, THRESHOLDS, "chair")
    assert not v.speaks and v.route is None
    assert verdict_reasons(v) == "" and verdict_advice(v) == ""


def test_a_shape_nearer_another_network_names_that_network_even_inside_the_given_threshold():
    # 9 / 10 = 0.9 under the chair network, 10 / 20 = 0.5 under the table network: a table
    v = network_verdict({"chair": 9.0, "table": 10.0, "animal": 100.0}, THRESHOLDS, "chair")
    assert v.speaks and v.route == "table"
    assert v.ratio("table") == pytest.approx(0.5)
    assert "nearer the table network's training shapes than the chair network's" in verdict_reasons(v)
    assert "model='table'" in verdict_advice(v) and "--model table" in verdict_advice(v, command_line=True)


def test_a_shape_beyond_every_threshold_names_the_per_shape_fit():
    v = network_verdict({"chair": 11.0, "table": 30.0, "animal": 90.0}, THRESHOLDS, "chair")
    assert v.speaks and v.route == "fit"  # the chair network is still the nearest, but above its threshold
    assert "unlike the training shapes of every network" in verdict_reasons(v)
    assert "the nearest other: 30.0 under the table network, threshold 20" in verdict_reasons(v)
    assert "model=None" in verdict_advice(v) and "cuboidlib fit" in verdict_advice(v, command_line=True)
    alone = network_verdict({"mine.pt": 13.0}, {"mine.pt": 12.0}, "mine.pt")  # no other network to compare
    assert alone.route == "fit" and "nearest other" not in verdict_reasons(alone)


def test_the_rule_is_relative_to_each_threshold_so_scaling_a_network_and_its_threshold_changes_nothing():
    distances = {"chair": 9.0, "table": 10.0, "animal": 100.0}
    v = network_verdict(distances, THRESHOLDS, "table")
    scaled = network_verdict({**distances, "table": 30.0}, {**THRESHOLDS, "table": 60.0}, "table")
    assert (v.speaks, v.route) == (scaled.speaks, scaled.route) == (False, None)
    tie = network_verdict({"chair": 5.0, "table": 10.0}, {"chair": 10.0, "table": 20.0}, "table")
    assert not tie.speaks, "a tie keeps the given network"


def test_the_record_goes_back_and_forth():
    v = network_verdict({"chair": 9.0, "table": 10.0}, THRESHOLDS, "chair")
    record = v.to_dict()
    assert record["speaks"] and record["route"] == "table" and record["latent_distance"]["chair"] == 9.0
    assert NetworkVerdict.from_dict(record) == v


@pytest.mark.parametrize("distances, thresholds, given, match", [
    ({"chair": 9.0}, THRESHOLDS, "table", "holding the given network 'table'"),
    ({"chair": float("nan")}, THRESHOLDS, "chair", "finite number >= 0"),
    ({"chair": -1.0}, THRESHOLDS, "chair", "finite number >= 0"),
    ({"chair": 1.0, "lamp": 2.0}, THRESHOLDS, "chair", "threshold of 'lamp'"),
    ({"chair": 1.0}, {"chair": 0.0}, "chair", "threshold of 'chair' must be a finite number > 0"),
    ([9.0], THRESHOLDS, "chair", "needs dicts"),
])
def test_bad_inputs_are_refused_with_the_problem_named(distances, thresholds, given, match):
    with pytest.raises(ValueError, match=match):
        network_verdict(distances, thresholds, given)


def test_the_calibrated_threshold_covers_the_validation_shapes_and_all_but_1_in_20_real_meshes():
    validation = np.arange(1.0, 101.0)  # 99th percentile 99.01
    assert calibrated_threshold(validation) == round(CALIBRATION_MARGIN * 99.01, 1)
    real = [5.0] * 19 + [500.0]  # the farthest 1 in 20 is left out
    assert calibrated_threshold([1.0], real) == round(CALIBRATION_MARGIN * 5.0, 1)
    real = [5.0] * 18 + [200.0, 500.0]  # 2 in 20: only one is left out
    assert calibrated_threshold([1.0], real) == round(CALIBRATION_MARGIN * 200.0, 1)
    assert calibrated_threshold([1.0], [300.0]) == round(CALIBRATION_MARGIN * 1.0, 1), "1 of 1 rounds up to 1"
    with pytest.raises(ValueError, match="at least one of validation shapes"):
        calibrated_threshold([])
    with pytest.raises(ValueError, match="finite distances"):
        calibrated_threshold([1.0], [math.inf])


def test_every_committed_network_has_a_calibrated_threshold():
    from cuboidlib.applications import committed_checkpoints

    assert set(committed_checkpoints()) <= set(LATENT_THRESHOLDS)
    assert all(t > 0 for t in LATENT_THRESHOLDS.values())
