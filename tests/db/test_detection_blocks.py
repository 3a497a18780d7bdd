"""A batch's detections as one columnar block: every value back exactly, only the columns a
batch reports stored, rows picked by mask in order; and migration 0009, which turns the rows of
the `detection` table into blocks and back without changing a value."""

from __future__ import annotations

import struct
import uuid
from datetime import UTC, datetime

import numpy as np
import orjson
import pytest
from alembic import command
from sqlalchemy import Engine, Uuid, column, delete, insert, table, text

from roadlink.association.csvio import write_detections_csv
from roadlink.association.detections import COLUMNS, NO_LANE, Detections, concatenate
from roadlink.association.fast_csv import fast_detections
from roadlink.association.feature_columns import CodedTexts
from roadlink.db import repository
from roadlink.db.detection_blocks import TEXT_COLUMNS, Block, detections_of, encode
from roadlink.db.engine import make_engine, make_session_factory
from roadlink.db.json_columns import BatchSelection, WindowSelection
from roadlink.db.migrate import alembic_config
from roadlink.db.models import Batch
from roadlink.simulation import preset, simulate
from tests.databases import BACKENDS
from tests.helpers import store_batches, stored_detections, with_features


def _same(a: Detections, b: Detections) -> None:
    assert write_detections_csv(a) == write_detections_csv(b)
    assert a.position.tobytes() == b.position.tobytes()  # bit for bit, not just as printed
    assert a.velocity.tobytes() == b.velocity.tobytes()
    assert a.timestamp.tobytes() == b.timestamp.tobytes()
    assert a.lane.tolist() == b.lane.tolist()
    assert a.length.tobytes() == b.length.tobytes()
    assert a.vehicle_class.tolist() == b.vehicle_class.tolist()
    assert a.target.tolist() == b.target.tolist()


def _featured() -> Detections:
    d = simulate(preset("large", false_alarm_rate=0.1, miss_probability=0.1), seed=5).detections
    return with_features(d, lane_sensors=3)


def test_a_block_gives_back_every_value_exactly() -> None:
    d = _featured()
    block = Block.parse(encode(d))
    assert block.n == len(d)
    _same(detections_of([block]), d)
    assert block.sensors() == sorted(set(d.sensor_id.tolist()))


def test_a_batch_without_features_stores_only_its_columns() -> None:
    d = simulate(preset("small"), seed=1).detections
    block = Block.parse(encode(d))
    assert "lane" not in block.offsets and "length" not in block.offsets
    assert block.offsets["vehicle_class"][1] == 0
    assert len(encode(d)) < len(encode(with_features(d)))
    back = detections_of([block])
    assert back.features == () and len(back) == len(d)
    _same(back, d)


def test_classes_reported_only_after_the_first_detection_are_stored() -> None:
    d = simulate(preset("small"), seed=2).detections
    classes = [None] * (len(d) - 1) + ["truck"]
    with_class = Detections(*(getattr(d, name) for name in COLUMNS[:8]), np.array(classes))
    block = Block.parse(encode(with_class))
    assert block.texts("vehicle_class") == classes
    assert Block.parse(encode(d)).offsets["vehicle_class"][1] == 0


def test_a_block_is_the_same_bytes_whether_the_parser_coded_the_classes_or_not() -> None:
    """The CSV fast path and a JSON batch hand on their classes coded; detections built from
    arrays are coded at encoding: the same block, byte for byte."""
    d = _featured()
    text = write_detections_csv(d)
    fast = fast_detections(text.encode())
    assert fast is not None and fast.__dict__["_coded_classes"] is not None
    words = list(dict.fromkeys(d.vehicle_class.tolist()))
    coded = CodedTexts(words, np.array([words.index(c) for c in d.vehicle_class.tolist()]))
    columns = {name: getattr(d, name) for name in COLUMNS[:8]}
    from_codes = Detections.from_columns(**columns, vehicle_class=coded)
    assert from_codes.__dict__["_coded_classes"] is not None
    plain = Detections(*(getattr(d, name) for name in COLUMNS))
    assert plain.__dict__["_coded_classes"] is None
    assert encode(fast) == encode(plain) == encode(from_codes)


def test_masks_pick_rows_in_order_across_blocks_with_and_without_features() -> None:
    plain = simulate(preset("small"), seed=2).detections
    featured = _featured()
    blocks = [Block.parse(encode(plain)), Block.parse(encode(featured))]
    masks = [plain.timestamp > 10, None]
    back = detections_of(blocks, masks)
    _same(back, concatenate([plain.take(np.flatnonzero(plain.timestamp > 10)), featured]))
    assert len(detections_of([])) == 0


def _encode_version_1(d: Detections) -> bytes:
    """A block as version 1 wrote it: lanes int16, lengths float64, the classes as text."""
    classes = d.vehicle_class.tolist()
    flags = (1 if bool(d.has_lane.any()) else 0) | (2 if bool(d.has_length.any()) else 0)
    flags |= 4 if any(c is not None for c in classes) else 0
    texts = [orjson.dumps(getattr(d, name).tolist()) for name in TEXT_COLUMNS[:3]]
    texts.append(orjson.dumps(classes) if flags & 4 else b"")
    parts = [struct.pack("<4sBBIIIII", b"RLDB", 1, flags, len(d), *map(len, texts))]
    parts += [d.position.tobytes(), d.velocity.tobytes(), d.timestamp.tobytes()]
    parts += [d.lane.astype("<i2").tobytes()] if flags & 1 else []
    parts += [d.length.tobytes()] if flags & 2 else []
    return b"".join(parts + texts)


def _with(d: Detections, **features: object) -> Detections:
    columns = {name: getattr(d, name) for name in COLUMNS} | features
    return Detections(**columns)


def test_a_version_1_block_still_reads() -> None:
    featured, plain = _featured(), simulate(preset("small"), seed=1).detections
    for d in (featured, plain):
        block = Block.parse(_encode_version_1(d))
        assert block.version == 1
        _same(detections_of([block]), d)
    blocks = [Block.parse(_encode_version_1(featured)), Block.parse(encode(plain))]
    _same(detections_of(blocks), concatenate([featured, plain]))


def test_features_that_need_it_are_stored_wide() -> None:
    """Lanes past 127, lengths that are no whole number of tenths, and more than 255 classes
    are stored in wider forms, and every value reads back exactly."""
    d = _featured()
    n = len(d)
    rng = np.random.default_rng(3)
    wide = _with(
        d,
        lane=np.where(d.has_lane, 255 - d.lane, NO_LANE),
        length=np.where(d.has_length, d.length + rng.random(n) / 1000, np.nan),
        vehicle_class=np.array([f"class {i % 300}" for i in range(n)], dtype=object),
    )
    assert len(encode(wide)) > len(encode(d)) + n * (1 + 6 + 1)  # lanes, lengths, codes
    _same(detections_of([Block.parse(encode(wide))]), wide)
    n = (1 << 16) + 10  # past the codes' 16 bits
    many = Detections(
        *(np.arange(n, dtype=float) for _ in range(3)),
        *(np.array([f"{i}" for i in range(n)], dtype=object) for _ in range(3)),
        vehicle_class=np.array([f"{i}" for i in range(n)], dtype=object),
    )
    _same(detections_of([Block.parse(encode(many))]), many)


def test_lengths_in_tenths_read_back_bit_for_bit() -> None:
    d = simulate(preset("small"), seed=6).detections
    tenths = np.arange(len(d)) % 1000 + 1
    lengths = np.where(tenths % 7 == 0, np.nan, tenths / 10)
    block = Block.parse(encode(_with(d, length=lengths)))
    assert block.offsets["length"][1] == 2 * len(d)
    assert block.floats("length").tobytes() == lengths.tobytes()


@pytest.mark.parametrize("data", [b"", b"RLDB\x03" + bytes(30), encode(_featured())[:-1]])
def test_anything_but_a_whole_block_is_refused(data: bytes) -> None:
    with pytest.raises(ValueError):
        Block.parse(data)


# The tables as revision 0008 has them (the models store detections as blocks now).
DETECTION_0008 = table(
    "detection",
    column("batch_id", Uuid()),
    column("deployment_id", Uuid()),
    *(column(name) for name in ("row", "position", "velocity", "timestamp", "sensor_id")),
    *(column(name) for name in ("detection_id", "target", "lane", "length", "vehicle_class")),
)
BATCH_0008 = table(
    "batch",
    column("id", Uuid()),
    column("deployment_id", Uuid()),
    *(column(name) for name in ("n_detections", "n_labelled", "first_timestamp")),
    *(column(name) for name in ("last_timestamp", "source", "created_at")),
)
FIELDS = ("position", "velocity", "timestamp", "sensor_id", "detection_id", "target")


def _rows_0008(engine: Engine) -> list[tuple[object, ...]]:
    with engine.connect() as connection:
        query = text(
            "SELECT batch_id, deployment_id, row, position, velocity, timestamp, sensor_id, "
            "detection_id, target, lane, length, vehicle_class FROM detection "
            "ORDER BY batch_id, row"
        )
        return [tuple(r) for r in connection.execute(query).all()]


@pytest.mark.parametrize("empty_database_url", BACKENDS, indirect=True)
def test_migration_0009_turns_rows_into_blocks_and_back(empty_database_url: str) -> None:
    config = alembic_config(empty_database_url)
    command.upgrade(config, "0008")
    engine = make_engine(empty_database_url)
    featured, plain = _featured(), simulate(preset("small"), seed=4).detections
    deployment, batches = uuid.uuid4(), [uuid.uuid4(), uuid.uuid4()]
    with engine.begin() as connection:
        connection.execute(
            text("INSERT INTO deployment (id, name, created_at) VALUES (:id, 'r', :t)"),
            {
                "id": deployment.hex if engine.dialect.name == "sqlite" else deployment,
                "t": "2026-01-01 00:00:00+00:00",
            },
        )
        for k, (batch, d) in enumerate(zip(batches, (featured, plain), strict=True)):
            connection.execute(
                insert(BATCH_0008).values(
                    id=batch,
                    deployment_id=deployment,
                    n_detections=len(d),
                    n_labelled=0,
                    first_timestamp=float(d.timestamp.min()),
                    last_timestamp=float(d.timestamp.max()),
                    source="csv",
                    created_at=datetime(2026, 1, 1 + k, tzinfo=UTC),
                )
            )
            values = {name: getattr(d, name).tolist() for name in FIELDS}
            values |= {name: d.feature_values(name) for name in ("lane", "length")}
            values["vehicle_class"] = d.feature_values("vehicle_class")
            rows = [
                {"batch_id": batch, "deployment_id": deployment, "row": i + 1}
                | {name: column_values[i] for name, column_values in values.items()}
                for i in range(len(d))
            ]
            connection.execute(insert(DETECTION_0008), rows)
    before = _rows_0008(engine)

    command.upgrade(config, "0009")
    with make_session_factory(engine)() as session:
        for batch, d in zip(batches, (featured, plain), strict=True):
            loaded = repository.load_detections(
                session, deployment_id=deployment, selection=BatchSelection((batch,))
            )
            _same(loaded, d)
        window = repository.load_detections(
            session, deployment_id=deployment, selection=WindowSelection(None, None)
        )
    assert len(window) == len(featured) + len(plain)
    with engine.connect() as connection:
        stored = connection.execute(text("SELECT count(*) FROM detection_block")).scalar_one()
    assert stored == 2

    command.downgrade(config, "0008")
    assert _rows_0008(engine) == before
    engine.dispose()


def test_a_deleted_batch_takes_its_block_with_it(engine: Engine) -> None:
    """ON DELETE CASCADE: no block outlives its batch."""
    _, (batch_id, _) = store_batches(engine, _featured(), simulate(preset("small")).detections)
    with engine.begin() as connection:
        connection.execute(delete(Batch).where(Batch.id == batch_id))
    assert stored_detections(engine) == len(simulate(preset("small")).detections)


def _compressions(engine: Engine) -> list[str | None]:
    with engine.connect() as connection:
        query = "SELECT pg_column_compression(data) FROM detection_block ORDER BY batch_id"
        return list(connection.execute(text(query)).scalars())


@pytest.mark.parametrize("empty_database_url", BACKENDS, indirect=True)
def test_migration_0011_stores_blocks_with_lz4_on_postgresql(empty_database_url: str) -> None:
    """Blocks stored before 0011 are rewritten with lz4 on PostgreSQL, and back with the
    default on downgrading; every value reads back the same, on SQLite too."""
    config = alembic_config(empty_database_url)
    command.upgrade(config, "0010")
    engine = make_engine(empty_database_url)
    featured, plain = _featured(), simulate(preset("large"), seed=4).detections
    deployment, batches = store_batches(engine, featured, plain)
    postgres = engine.dialect.name == "postgresql"
    if postgres:
        assert _compressions(engine) == ["pglz", "pglz"]

    def same_as_stored() -> None:
        with make_session_factory(engine)() as session:
            for batch, d in zip(batches, (featured, plain), strict=True):
                selection = BatchSelection((batch,))
                _same(
                    repository.load_detections(
                        session, deployment_id=deployment, selection=selection
                    ),
                    d,
                )

    command.upgrade(config, "0011")
    same_as_stored()
    if postgres:
        assert _compressions(engine) == ["lz4", "lz4"]
        store_batches(engine, plain)  # a block stored after the upgrade: lz4 too
        assert set(_compressions(engine)) == {"lz4"}
    command.downgrade(config, "0010")
    same_as_stored()
    if postgres:
        assert set(_compressions(engine)) == {"pglz"}
    engine.dispose()
