"""Finding SUMO, running a scenario with it, and applying the detectors' faults to what it saw."""

from __future__ import annotations

import importlib.util
import os
import shutil
import subprocess
import tempfile
from pathlib import Path

import numpy as np

from roadlink.association.detections import CLUTTER, Detections, FloatArray
from roadlink.simulation.faults import DetectorFaults, Passages, apply_detector_faults
from roadlink.simulation.sumo.files import (
    MIN_REPORTED_SPEED,
    connections_xml,
    detectors_xml,
    network_xml,
    parse_detector_output,
    routes_xml,
    signals_xml,
)
from roadlink.simulation.sumo.scenarios import SumoScenario, sensor_ids

INSTALL_HINT = "pip install 'roadlink[sumo]'"


class SumoNotInstalledError(RuntimeError):
    """The SUMO binaries are not found."""


class SumoRunError(RuntimeError):
    """A SUMO tool failed; the message carries its error output."""


def sumo_home_candidates() -> list[Path]:
    """Where SUMO may live, in order: the `eclipse-sumo` package, $SUMO_HOME, `sumo` on the PATH."""
    candidates: list[Path] = []
    # find_spec, not import: importing the package would set SUMO_HOME in our environment.
    spec = importlib.util.find_spec("sumo")
    if spec is not None and spec.submodule_search_locations:
        candidates.extend(Path(p) for p in spec.submodule_search_locations)
    if os.environ.get("SUMO_HOME"):
        candidates.append(Path(os.environ["SUMO_HOME"]))
    on_path = shutil.which("sumo")
    if on_path:
        candidates.append(Path(on_path).resolve().parent.parent)
    return candidates


def find_sumo_home() -> Path:
    """The first SUMO installation with the binaries `run_sumo` needs.

    Raises SumoNotInstalledError, saying how to install it, when there is none.
    """
    for home in sumo_home_candidates():
        if (home / "bin" / "sumo").is_file() and (home / "bin" / "netconvert").is_file():
            return home
    raise SumoNotInstalledError(
        f"Eclipse SUMO is not installed: {INSTALL_HINT} (or set SUMO_HOME to a SUMO installation)"
    )


def sumo_available() -> bool:
    """True when `run_sumo` can find SUMO."""
    try:
        find_sumo_home()
    except SumoNotInstalledError:
        return False
    return True


def run_sumo(scenario: SumoScenario, seed: int = 0, workdir: Path | None = None) -> Detections:
    """Simulate the scenario with SUMO and return what its sensors detected, faults applied.

    The same scenario and seed give the same detections. SUMO's files (network, routes,
    detectors, output) are written to `workdir` when given (to inspect them), else to a
    temporary directory that is removed afterwards.
    """
    home = find_sumo_home()
    if workdir is not None:
        workdir.mkdir(parents=True, exist_ok=True)
        return _run_in(home, scenario, seed, workdir)
    with tempfile.TemporaryDirectory(prefix="roadlink-sumo-") as tmp:
        return _run_in(home, scenario, seed, Path(tmp))


def _run_in(home: Path, scenario: SumoScenario, seed: int, work: Path) -> Detections:
    nodes, edges = network_xml(scenario)
    (work / "road.nod.xml").write_text(nodes)
    (work / "road.edg.xml").write_text(edges)
    (work / "road.rou.xml").write_text(routes_xml(scenario))
    inputs = ["-n", "road.nod.xml", "-e", "road.edg.xml"]
    if scenario.ramps:
        (work / "road.con.xml").write_text(connections_xml(scenario))
        inputs += ["-x", "road.con.xml"]
    _call(home, "netconvert", work, *inputs, "-o", "road.net.xml")
    net = (work / "road.net.xml").read_text()
    (work / "detectors.add.xml").write_text(detectors_xml(scenario, net, "detections.xml"))
    additional = "detectors.add.xml"
    if scenario.signals:
        (work / "signals.add.xml").write_text(signals_xml(scenario, net))
        additional += ",signals.add.xml"
    _call(
        home,
        "sumo",
        work,
        *("-n", "road.net.xml", "-r", "road.rou.xml", "-a", additional),
        *("--begin", "0", "--end", f"{scenario.warmup + scenario.duration}"),
        *("--step-length", f"{scenario.step_length}", "--seed", str(seed)),
        *("--no-step-log", "--duration-log.disable", "--no-warnings"),
    )
    detections = parse_detector_output(
        (work / "detections.xml").read_bytes(),
        sensor_ids(scenario),
        (scenario.warmup, scenario.warmup + scenario.duration),
        features=scenario.features,
    )
    if scenario.faults != DetectorFaults():
        # Its own stream, so faults never change what SUMO simulated.
        rng = np.random.default_rng([seed, 0x5E45])
        detections = with_detector_faults(detections, scenario.faults, rng)
    return detections


def _call(home: Path, tool: str, work: Path, *args: str) -> None:
    env = {**os.environ, "SUMO_HOME": str(home)}
    done = subprocess.run(
        [str(home / "bin" / tool), *args], cwd=work, env=env, capture_output=True, text=True
    )
    if done.returncode != 0:
        raise SumoRunError(f"{tool} failed ({done.returncode}): {done.stderr.strip()[-2000:]}")


# A false alarm's speed is one its sensor reported, read again with this relative error: it
# looks like any other vehicle there.
FALSE_ALARM_SPEED_ERROR = 0.05


def with_detector_faults(
    detections: Detections, faults: DetectorFaults, rng: np.random.Generator
) -> Detections:
    """The detections as faulty loops would have reported them (the shared fault model), ordered
    by sensor position, then time, as sensors log them."""
    positions, sensor = np.unique(detections.position, return_inverse=True)
    sensor_id = {int(k): detections.sensor_id[sensor == k][0] for k in range(positions.size)}

    def speeds(_k: int, count: int, seen: FloatArray, rng: np.random.Generator) -> FloatArray:
        return rng.choice(seen, count) * np.exp(
            FALSE_ALARM_SPEED_ERROR * rng.standard_normal(count)
        )

    passages = apply_detector_faults(
        Passages(
            sensor,
            detections.timestamp,
            detections.velocity,
            detections.target,
            lane=detections.lane,
            length=detections.length,
            vehicle_class=detections.vehicle_class,
        ),
        faults,
        rng,
        false_alarm_speeds=speeds,
        clutter=CLUTTER,
    )
    order = np.lexsort((passages.time, positions[passages.sensor]))
    passages = passages.take(order)
    return Detections.from_columns(
        positions[passages.sensor],
        np.maximum(passages.speed, MIN_REPORTED_SPEED),
        passages.time,
        sensor_id=[sensor_id[int(k)] for k in passages.sensor],
        target=passages.target.tolist(),
        lane=passages.lane,
        length=passages.length,
        vehicle_class=passages.vehicle_class.tolist(),
    )
