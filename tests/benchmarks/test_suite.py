"""The benchmark machinery on tiny sizes: it runs, stops what is too slow, and writes its JSON.

Never asserts speed: timings depend on the machine; benchmarks/ reports them.
"""

import json

import numpy as np
import pytest

import benchmarks.__main__ as runner
from benchmarks import datasets
from benchmarks.isolated import RunSpec, run_isolated
from benchmarks.methods import stonesoup_available
from benchmarks.report import Column, Sample, Section, Table, format_cell
from benchmarks.sections import SECTIONS, peer
from benchmarks.sections.associators import ScalingPlan, measure_scaling
from roadlink.simulation import simulate

TINY = ScalingPlan(sizes=(100, 200), time_limit=60.0, repeats=3, budget_seconds=0.0)


@pytest.fixture(autouse=True)
def private_cache(tmp_path, monkeypatch):
    """Simulated data sets go to a temporary cache, not the real one."""
    monkeypatch.setattr(datasets, "CACHE", tmp_path / "cache")


def test_a_sample_reports_median_and_spread():
    sample = Sample.of([3.0, 1.0, 2.0, 10.0])
    assert (sample.median, sample.minimum, sample.maximum) == (2.5, 1.0, 10.0)
    assert sample.to_dict()["runs"] == [3.0, 1.0, 2.0, 10.0]
    assert format_cell(sample, Column("t", "seconds")) == "2.50 s [1.00 s, 10.00 s]"
    assert (
        format_cell(Sample.of([0.5, 0.7]), Column("a", "share", "mean")) == "60.0% [50.0%, 70.0%]"
    )
    assert format_cell(None, Column("x")) == "-"


def test_a_table_rejects_a_row_of_the_wrong_width():
    table = Table("t", [Column("a"), Column("b")])
    with pytest.raises(ValueError, match="1 cells for 2 columns"):
        table.add("only one")


def test_cached_data_sets_round_trip_and_are_reused():
    config = datasets.scaled_config(3)
    path = datasets.cached_dataset(config)
    again = datasets.cached_dataset(config)
    assert again == path and path.parent == datasets.CACHE
    loaded = datasets.load_detections(path)
    original = simulate(config, seed=datasets.SCALE_SEED).detections
    assert len(loaded) == 3 * datasets.SENSORS
    np.testing.assert_array_equal(loaded.timestamp, original.timestamp)
    assert list(loaded.target) == list(original.target)
    assert list(loaded.sensor_id) == list(original.sensor_id)


@pytest.mark.slow
def test_an_isolated_run_reports_repeats_accuracy_and_peak_memory():
    path = datasets.cached_dataset(datasets.scaled_config(4))
    spec = RunSpec("kmeans++", str(path), repeats=3, min_repeats=3, budget_seconds=0.0)
    run = run_isolated(spec, time_limit=60.0)
    assert run.outcome == "ok", run.error
    assert len(run.seconds) == 3 and all(s > 0 for s in run.seconds)
    assert run.n_detections == 4 * datasets.SENSORS
    assert run.accuracy is not None and 0.0 < run.accuracy <= 1.0
    assert run.peak_rss_mib is not None and run.baseline_rss_mib is not None
    assert run.peak_rss_mib >= run.baseline_rss_mib > 0


def test_a_failing_method_is_reported_with_its_error():
    path = datasets.cached_dataset(datasets.scaled_config(2))
    run = run_isolated(RunSpec("no-such-method", str(path), 3, 3, 0.0), time_limit=60.0)
    assert run.outcome == "error"
    assert run.error is not None and "no-such-method" in run.error


@pytest.mark.slow
def test_the_scaling_section_measures_every_size_of_every_method():
    section = measure_scaling(["kmeans++"], TINY)
    rows = section.to_dict()["tables"][0]["rows"]
    assert [(r["method"], r["detections"], r["targets"]) for r in rows] == [
        ("kmeans++", 100, 2),
        ("kmeans++", 200, 4),
    ]
    for row in rows:
        assert row["outcome"] == "ok"
        assert row["seconds"]["n"] == 3
        assert row["seconds"]["min"] <= row["seconds"]["median"] <= row["seconds"]["max"]
        assert 0.0 < row["accuracy"] <= 1.0
        assert row["peak memory"] > 0


def test_a_size_over_the_time_limit_stops_the_method_and_says_so():
    # No grouping finishes within a microsecond, so the first size is already over the limit.
    plan = ScalingPlan(sizes=(100, 200), time_limit=1e-6, repeats=3)
    table = measure_scaling(["kmeans++"], plan).tables[0]
    assert len(table.rows) == 1  # the larger size was skipped, not waited for
    assert table.rows[0][-1] == "over time limit"
    assert table.notes == [
        "- kmeans++: infeasible beyond any size detections (a repeat exceeded 1e-06 s at 100)."
    ]


def test_the_runner_prints_markdown_and_writes_the_json_document(tmp_path, monkeypatch, capsys):
    def tiny(quick: bool) -> Section:
        table = Table("Tiny", [Column("method"), Column("seconds", "seconds")])
        table.add("kmeans++" if quick else "full", Sample.of([0.3, 0.1, 0.2]))
        return Section("tiny", "A section of one table.", [table], {"quick": quick})

    monkeypatch.setattr(runner, "SECTIONS", {"tiny": tiny})
    out = tmp_path / "results.json"
    runner.main(["--quick", "--json", str(out)])
    printed = capsys.readouterr().out
    assert "## tiny" in printed and "| kmeans++ | 200.0 ms [100.0 ms, 300.0 ms] |" in printed
    document = json.loads(out.read_text())
    assert document["mode"] == "quick" and document["date"]
    assert set(document["machine"]) >= {
        "cpu",
        "cores",
        "memory_gib",
        "python",
        "numpy",
        "openblas_coretype",
    }
    (section,) = document["sections"]
    assert section["name"] == "tiny" and section["settings"] == {"quick": True}
    assert section["seconds"] >= 0
    (table,) = section["tables"]
    assert table["title"] == "Tiny"
    assert [c["name"] for c in table["columns"]] == list(table["rows"][0])
    assert table["rows"][0]["seconds"] == {
        "median": 0.2,
        "min": 0.1,
        "max": 0.3,
        "mean": pytest.approx(0.2),
        "n": 3,
        "runs": [0.3, 0.1, 0.2],
    }

    runner.main(["--render", str(out)])
    assert capsys.readouterr().out.strip() == printed.strip()


def test_every_section_is_registered_under_its_name():
    assert list(SECTIONS) == [
        "associators",
        "peer",
        "ingest",
        "latency",
        "throughput",
        "overhead",
        "files",
        "csv-read",
    ]


@pytest.mark.slow
@pytest.mark.skipif(not stonesoup_available(), reason="Stone Soup (the bench extra) is absent")
def test_the_peer_section_compares_stone_soup_with_the_registry(monkeypatch):
    monkeypatch.setattr(peer, "PRESETS", ("small",))
    monkeypatch.setattr(peer, "QUICK_SEEDS", 2)
    monkeypatch.setattr(peer, "QUICK_SCALING", ScalingPlan((100,), 60.0, 3, budget_seconds=0.0))
    section = peer.run(quick=True).to_dict()
    presets, scaling = section["tables"]
    (row,) = presets["rows"]
    assert row["preset"] == "small"
    for method in peer.compared_methods():
        assert row[f"{method} accuracy"]["n"] == 2
        assert 0.0 < row[f"{method} accuracy"]["mean"] <= 1.0
        assert row[f"{method} seconds"]["n"] == 2
    assert {r["method"] for r in scaling["rows"]} == set(peer.compared_methods())
