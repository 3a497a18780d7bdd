"""Detection ids kept as the CSV parser made them read, everywhere, as the object array of
str that the exact reader gives; a writer can have the parser's column instead."""

import dataclasses
import pickle
import threading

import numpy as np
import polars as pl
import pytest

from roadlink.association import associate
from roadlink.association.csvio import read_detections_csv, read_detections_csv_exactly
from roadlink.association.detections import Detections, concatenate
from roadlink.association.parsed_texts import ParsedTexts, generated_ids

CSV = b"position,velocity,timestamp,sensor_id,detection_id,target\n" + b"".join(
    b"%d,%d.5,%d,S%d,id-%d,A%d\n" % (100 * (i % 3), 20 + i, i, i % 3, i, i // 3) for i in range(30)
)


def exact(data: bytes) -> Detections:
    return read_detections_csv_exactly(data.decode())


def test_the_fast_reader_keeps_the_parsed_ids_and_reads_as_the_exact_reader():
    fast = read_detections_csv(CSV)
    parsed = fast.parsed_texts("detection_id")
    assert isinstance(parsed, pl.Series) and parsed.to_list() == [f"id-{i}" for i in range(30)]
    ids = fast.detection_id
    assert ids.dtype == object and ids.tolist() == exact(CSV).detection_id.tolist()
    assert all(type(i) is str for i in ids)
    assert fast.detection_id is ids  # made once
    sensors = fast.parsed_texts("sensor_id")
    assert sensors is not None and sensors.to_list() == fast.sensor_id.tolist()
    assert fast.sensor_id.tolist() == exact(CSV).sensor_id.tolist()
    assert fast.parsed_texts("detection_id") is parsed  # still there for a writer


def test_ids_made_for_a_file_without_them_are_the_exact_readers():
    data = b"position,velocity,timestamp\n" + b"".join(
        b"%d,%d,%d\n" % (100 * (i % 2), 20 + i, i) for i in range(12)
    )
    fast = read_detections_csv(data)
    assert fast.parsed_texts("detection_id") is not None
    assert (
        fast.detection_id.tolist()
        == exact(data).detection_id.tolist()
        == [f"d{i + 1}" for i in range(12)]
    )
    assert generated_ids(0).series.len() == 0


def test_parsed_ids_go_through_every_operation_on_detections():
    fast, plain = read_detections_csv(CSV), exact(CSV)
    index = np.array([5, 0, 29, 3])
    assert fast.take(index).detection_id.tolist() == plain.take(index).detection_id.tolist()
    assert fast.without_labels().detection_id.tolist() == plain.detection_id.tolist()
    # Copies that keep every row keep the parser's column: none of them makes the strs.
    fresh = read_detections_csv(CSV)
    for copy in (fresh.without_labels(), fresh.without_features(), fresh.only_features()):
        assert copy.parsed_texts("detection_id") is fresh.parsed_texts("detection_id")
    result = associate(fresh, "assignment", {})
    made = [texts.made for texts in vars(fresh).values() if isinstance(texts, ParsedTexts)]
    # `associate` made no str of an id nor of a label (the sensors' were made by the read).
    assert made == [True, False, False]
    assert result.metrics == associate(plain, "assignment", {}).metrics
    assert fresh.target.tolist() == plain.target.tolist()
    joined = concatenate([fast, read_detections_csv(CSV)])
    assert joined.detection_id.tolist() == plain.detection_id.tolist() * 2
    renamed = dataclasses.replace(fast, detection_id=np.array(["x"] * 30, dtype=object))
    assert renamed.parsed_texts("detection_id") is None and renamed.detection_id[0] == "x"
    assert "id-0" in repr(fast)


@pytest.mark.parametrize("read_first", [False, True])
def test_detections_with_parsed_ids_pickle(read_first):
    """Detections cross to a worker's associator process pickled."""
    fast = read_detections_csv(CSV)
    if read_first:
        _ = fast.detection_id
    back = pickle.loads(pickle.dumps(fast))
    assert back.detection_id.tolist() == exact(CSV).detection_id.tolist()
    parsed = back.parsed_texts("detection_id")
    assert parsed is not None and parsed.to_list() == back.detection_id.tolist()


def test_threads_reading_at_once_make_the_array_once():
    """Four threads ask at once; the array is made by one of them. The making waits (up to a
    tenth of a second, letting the others run) so that without the lock all four would be
    inside it together."""
    made = []
    inside = threading.Event()

    def make(series: pl.Series) -> np.ndarray:
        made.append(True)
        inside.wait(0.1)  # never set: holds the window open for the other threads
        return series.to_numpy().astype(object)

    texts = ParsedTexts(pl.Series([f"t{i}" for i in range(1000)]), make=make)
    barrier = threading.Barrier(4)
    seen = []

    def read() -> None:
        barrier.wait()
        seen.append(texts.objects())

    threads = [threading.Thread(target=read) for _ in range(4)]
    for thread in threads:
        thread.start()
    for thread in threads:
        thread.join()
    assert len(made) == 1
    assert len({id(array) for array in seen}) == 1


def test_the_ids_field_has_no_default():
    fields = {f.name: f for f in dataclasses.fields(Detections)}
    assert fields["detection_id"].default is dataclasses.MISSING
    with pytest.raises(TypeError, match="detection_id"):
        Detections(np.zeros(1), np.ones(1), np.zeros(1), np.array(["S1"], dtype=object))  # type: ignore[call-arg]
