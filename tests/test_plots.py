"""Plots of association results: real PNG and SVG, one drawn element per target, and exactly the
wrongly grouped detections highlighted."""

import struct
import xml.etree.ElementTree as ET

import matplotlib as mpl
import numpy as np
import pytest

from roadlink.association import associate
from roadlink.association.result import build_result
from roadlink.association.scores import wrongly_grouped
from roadlink.plots import DPI, FIGURE_SIZE, LEGEND_LIMIT, PLOT_KINDS, plot_figure, render_plot
from roadlink.simulation import preset, simulate

SVG = "{http://www.w3.org/2000/svg}"


@pytest.fixture(scope="module")
def ten():
    """kmeans++ on the paper's small preset with false alarms: some detections grouped wrongly."""
    d = simulate(preset("small", false_alarm_rate=0.1), seed=2).detections
    return associate(d, "kmeans++")


@pytest.fixture(scope="module")
def hundred_twenty():
    d = simulate(preset("congested", miss_probability=0.05), seed=1).detections
    return associate(d, "kmeans++")


def groups_by_id(svg_bytes):
    root = ET.fromstring(svg_bytes)
    return {g.get("id"): g for g in root.iter(f"{SVG}g") if g.get("id")}


@pytest.mark.parametrize("kind", PLOT_KINDS)
def test_png_is_a_png_of_the_figure_size(ten, kind):
    png = render_plot(ten, kind, "png")
    assert png[:8] == b"\x89PNG\r\n\x1a\n"
    width, height = struct.unpack(">II", png[16:24])  # the IHDR chunk
    assert (width, height) == (round(FIGURE_SIZE[0] * DPI), round(FIGURE_SIZE[1] * DPI))


@pytest.mark.parametrize("kind", PLOT_KINDS)
def test_svg_has_one_element_per_target_and_each_highlight(ten, kind):
    groups = groups_by_id(render_plot(ten, kind, "svg"))
    targets = sorted(i for i in groups if i.startswith("target-"))
    assert targets == sorted(f"target-T{k + 1}" for k in range(ten.n_targets))
    assert all(groups[i].find(f".//{SVG}path") is not None for i in targets)
    wrong = int(wrongly_grouped(ten.groups, ten.detections.target).sum())
    assert wrong > 0
    assert len(groups["wrongly-grouped"].findall(f".//{SVG}use")) == wrong
    labelled = int(ten.detections.labelled.sum())
    assert wrong == round((1 - ten.metrics.accuracy) * labelled)


def test_time_space_lines_are_single_paths_and_unassigned_are_marked():
    d = simulate(preset("large"), seed=3).detections
    groups = np.unique(d.target.astype(str), return_inverse=True)[1]
    groups[[3, 17, 40]] = -1
    result = build_result(d, groups, "truth", {})
    svg = groups_by_id(render_plot(result, "time-space", "svg"))
    for k in range(result.n_targets):
        assert len(svg[f"target-T{k + 1}"].findall(f"{SVG}path")) == 1
    assert len(svg["unassigned"].findall(f".//{SVG}use")) == 3
    # Unassigned detections of real targets are wrong too, and ringed.
    assert len(svg["wrongly-grouped"].findall(f".//{SVG}use")) == 3


def test_unlabelled_results_have_no_highlight(ten):
    result = build_result(ten.detections.without_labels(), ten.groups, "kmeans++", {})
    assert "wrongly-grouped" not in groups_by_id(render_plot(result, "time-space", "svg"))


@pytest.mark.parametrize("kind", PLOT_KINDS)
def test_legends_stay_short(ten, hundred_twenty, kind):
    def entries(result):
        legend = plot_figure(result, kind).axes[0].get_legend()
        return [t.get_text() for t in legend.get_texts()]

    assert hundred_twenty.n_targets > LEGEND_LIMIT
    many = entries(hundred_twenty)
    assert len(many) <= 3
    assert f"{hundred_twenty.n_targets} targets, one colour each" in many
    few = entries(ten)
    assert few[: ten.n_targets] == [f"T{k + 1}" for k in range(ten.n_targets)]


def test_rendering_is_reproducible_and_leaves_matplotlib_settings_alone(ten):
    before = dict(mpl.rcParams)
    first = render_plot(ten, "backprojected", "svg")
    assert render_plot(ten, "backprojected", "svg") == first
    assert dict(mpl.rcParams) == before


def test_unknown_kind_or_format_names_the_choices(ten):
    with pytest.raises(ValueError, match="time-space, backprojected"):
        render_plot(ten, "histogram")
    with pytest.raises(ValueError, match="png, svg"):
        render_plot(ten, "time-space", "pdf")


def test_wrongly_grouped_marks_what_the_accuracy_counts_wrong():
    labels = np.array(["A", "A", "A", "B", "B", "clutter", "clutter", None], dtype=object)
    groups = np.array([0, 0, 1, 1, -1, -1, 1, 0])
    # Group 0 is matched to A (two agree), group 1 to B: the A in group 1, the B left
    # unassigned and the clutter put in a group are wrong; the unlabelled one is not scored.
    assert wrongly_grouped(groups, labels).tolist() == [
        False,
        False,
        True,
        False,
        True,
        False,
        True,
        False,
    ]
