"""`associate` (`association/pipeline.py`): the named associator over the detections, its
parameters checked, the grouping scored."""

import json

import pytest

from roadlink.association import Detections, associate
from roadlink.association.associators import AssociationError
from roadlink.association.pipeline import parse_params
from roadlink.simulation import preset, simulate


def paper_data(name="large", seed=0, **overrides):
    return simulate(preset(name, **overrides), seed=seed).detections


def test_unknown_associator_lists_the_known_ones():
    with pytest.raises(AssociationError, match=r"known: .*kmeans"):
        associate(paper_data(), "nope")


@pytest.mark.parametrize("name", ["kmeans", "kmeans++", "assignment", "svm-linear"])
def test_empty_input_is_refused_saying_so(name):
    with pytest.raises(AssociationError, match="there are no detections to associate"):
        associate(Detections.from_columns([], [], []), name)


def test_parameters_are_converted_from_text_and_refused_naming_the_parameter():
    assert parse_params("kmeans", {"backproject": "false"}).model_dump()["backproject"] is False
    with pytest.raises(
        AssociationError, match=r"invalid parameters for 'kmeans': parameter 'nope'"
    ):
        parse_params("kmeans", {"nope": 1})
    with pytest.raises(AssociationError, match="invalid parameters for 'assignment'"):
        associate(paper_data(), "assignment", {"gate_cost": -1})


def test_one_sensor_position_is_refused_saying_so():
    one = Detections.from_columns([0.0, 0.0], [20.0, 21.0], [1.0, 2.0])
    with pytest.raises(AssociationError, match="at least two"):
        associate(one, "kmeans")


def test_unsupervised_associators_never_see_the_labels():
    d = paper_data()
    labelled = associate(d, "kmeans++")
    unlabelled = associate(d.without_labels(), "kmeans++")
    assert labelled.groups.tolist() == unlabelled.groups.tolist()
    assert labelled.metrics is not None and unlabelled.metrics is None
    assert labelled.params == unlabelled.params


def test_an_unscored_result_is_scored_later_to_the_same_metrics():
    d = paper_data()
    unscored = associate(d, "assignment", scored=False)
    assert unscored.metrics is None
    scored = unscored.scored()
    assert scored.metrics == associate(d, "assignment").metrics is not None
    assert scored.groups is unscored.groups and scored.detections is unscored.detections


def printed_by(script: str) -> str:
    """What a fresh Python process running `script` prints (it must succeed)."""
    import subprocess
    import sys

    out = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True)
    assert out.returncode == 0, out.stderr
    return out.stdout.strip()


def test_the_deferred_imports_are_what_the_core_imports_on_first_use():
    """A process that imports them up front (the worker's fork server) runs every associator
    and scores without importing anything more of scikit-learn or scipy."""
    script = (
        "import sys\n"
        "from roadlink.association.pipeline import import_deferred\n"
        "import_deferred()\n"
        "before = {m for m in sys.modules if m.startswith(('sklearn', 'scipy'))}\n"
        "from roadlink.association import associate\n"
        "from roadlink.association.associators import ASSOCIATORS\n"
        "from roadlink.simulation import preset, simulate\n"
        "d = simulate(preset('large'), seed=1).detections\n"
        "for name in ASSOCIATORS:\n"
        "    associate(d, name, {})\n"
        "after = {m for m in sys.modules if m.startswith(('sklearn', 'scipy'))}\n"
        "print(sorted({m.split('.')[1] for m in after - before if m.count('.') >= 1}))\n"
    )
    assert printed_by(script) == "[]"


@pytest.mark.parametrize(
    ("name", "traffic"),
    [
        ("assignment", "preset('congested', n_targets=500)"),  # its sparse solver's size
        ("kmeans", "preset('large')"),
        ("svm-linear", "preset('large')"),
    ],
)
def test_what_an_associator_imports_on_first_use_is_what_it_imports(name, traffic):
    """The modules an associator names (which the CLI imports beside its read, and the
    deferred imports gather) are imported by its first association, in a process that had not
    imported them: the list does not go stale."""
    script = (
        "import json, sys\n"
        "from roadlink.association import associate\n"
        "from roadlink.association.associators import ASSOCIATORS\n"
        "from roadlink.simulation import preset, simulate\n"
        f"names = ASSOCIATORS[{name!r}].imports_on_first_use\n"
        "before = [n for n in names if n in sys.modules]\n"
        f"associate(simulate({traffic}, seed=1).detections, {name!r}, {{}})\n"
        "print(json.dumps([names, before, [n for n in names if n in sys.modules]]))\n"
    )
    names, before, after = json.loads(printed_by(script))
    assert names and before == [] and after == names


def test_the_cli_imports_only_what_every_command_needs():
    """Every `roadlink` command imports the CLI; what only some commands need is deferred:
    scikit-learn and scipy, polars, httpx (the remote commands), pydantic-settings (the
    server's and the configuration's commands)."""
    deferred = {"sklearn", "scipy", "polars", "httpx", "pydantic_settings"}
    script = (
        "import sys\n"
        "import roadlink.cli\n"
        f"print(sorted({{m.split('.')[0] for m in sys.modules}} & {deferred!r}))\n"
    )
    assert printed_by(script) == "[]"
