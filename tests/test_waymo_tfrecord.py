"""TFRecord reader/writer: CRC32C values, round trip, streaming and every kind of bad file."""

from __future__ import annotations

import struct
from pathlib import Path

import numpy as np
import pytest

from recondreamer.errors import ConversionError
from recondreamer.sources.waymo.tfrecord import TFRecordError, iter_records, masked_crc32c, write_records

FIXTURE = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "waymo" / "pvps_data_one_frame.tfrecord"


def _bitwise_crc32c(data: bytes) -> int:
    """CRC32C by its definition (reflected Castagnoli polynomial 0x82F63B78), bit by bit."""
    crc = 0xFFFFFFFF
    for byte in data:
        crc ^= byte
        for _ in range(8):
            crc = (crc >> 1) ^ (0x82F63B78 if crc & 1 else 0)
    return crc ^ 0xFFFFFFFF


def _mask(crc: int) -> int:
    return ((((crc >> 15) | (crc << 17)) & 0xFFFFFFFF) + 0xA282EAD8) & 0xFFFFFFFF


def test_crc32c_check_value():
    # 0xE3069283 is the published CRC-32C check value of the ASCII digits "123456789".
    assert _bitwise_crc32c(b"123456789") == 0xE3069283
    assert masked_crc32c(b"123456789") == _mask(0xE3069283)
    for data in (b"", b"\x00" * 8, bytes(range(256)), struct.pack("<Q", 2168758)):
        assert masked_crc32c(data) == _mask(_bitwise_crc32c(data))


def test_crc_matches_a_file_written_by_tensorflow():
    if not FIXTURE.is_file():
        pytest.skip(f"Waymo fixture not found at {FIXTURE} (../shared/data is not part of this checkout)")
    with FIXTURE.open("rb") as stream:
        header = stream.read(12)
    length, length_crc = struct.unpack("<QI", header)
    assert masked_crc32c(header[:8]) == length_crc
    records = list(iter_records(FIXTURE))  # checks the data CRC TensorFlow wrote too
    assert [len(r) for r in records] == [length]


def _records(count: int = 4) -> list[bytes]:
    rng = np.random.default_rng(0)
    return [b""] + [rng.integers(0, 256, size=int(n), dtype=np.uint8).tobytes() for n in (1, 100, 5000)][: count - 1]


def test_round_trip(tmp_path):
    records = _records()
    path = tmp_path / "a.tfrecord"
    write_records(path, records)
    assert path.stat().st_size == sum(len(r) + 16 for r in records)
    assert list(iter_records(path)) == records
    assert list(tmp_path.iterdir()) == [path]  # no temporary files left


def test_empty_file_has_no_records(tmp_path):
    path = tmp_path / "empty.tfrecord"
    path.write_bytes(b"")
    assert list(iter_records(path)) == []


@pytest.mark.parametrize("cut", [3, 12, 12 + 50, 12 + 100 + 2])
def test_truncated_file(tmp_path, cut):
    records = [b"x" * 7, b"y" * 100]
    path = tmp_path / "t.tfrecord"
    write_records(path, records)
    first_size = 7 + 16
    path.write_bytes(path.read_bytes()[: first_size + cut])
    stream = iter_records(path)
    assert next(stream) == records[0]  # records before the damage are still delivered: the file is streamed
    with pytest.raises(TFRecordError, match=r"truncated.*record 1"):
        next(stream)


@pytest.mark.parametrize(
    ("offset", "message"), [(2, "length checksum"), (12 + 5, "data checksum"), (12 + 100 + 1, "data checksum")]
)
def test_flipped_byte_in_second_record(tmp_path, offset, message):
    path = tmp_path / "c.tfrecord"
    write_records(path, [b"a" * 10, b"b" * 100])
    data = bytearray(path.read_bytes())
    data[26 + offset] ^= 0x01
    path.write_bytes(bytes(data))
    with pytest.raises(TFRecordError, match=rf"{message} mismatch in record 1 at byte 26"):
        list(iter_records(path))


def test_random_bytes_are_not_a_tfrecord(tmp_path):
    path = tmp_path / "random.bin"
    path.write_bytes(np.random.default_rng(1).integers(0, 256, size=4096, dtype=np.uint8).tobytes())
    with pytest.raises(TFRecordError, match="not a TFRecord file") as error:
        list(iter_records(path))
    assert str(path) in str(error.value)
    assert isinstance(error.value, ConversionError)  # the CLI turns it into one line and exit code 1


def test_missing_file(tmp_path):
    with pytest.raises(TFRecordError, match="no such file"):
        list(iter_records(tmp_path / "missing.tfrecord"))
