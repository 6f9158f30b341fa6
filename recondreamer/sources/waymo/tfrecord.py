"""Streaming TFRecord reader and writer (no TensorFlow).

A TFRecord file is a sequence of records, each laid out as::

    uint64 length (little endian)
    uint32 masked CRC32C of the 8 length bytes
    length bytes of data
    uint32 masked CRC32C of the data

CRC32C is the Castagnoli polynomial (``google-crc32c``), not zlib's CRC32. The mask rotates the
CRC right by 15 bits and adds 0xa282ead8 (mod 2**32), so that a CRC of data that itself holds
CRCs does not degenerate. Waymo segments are about 1 GB, so records are read one at a time and
the file is never loaded whole.
"""

from __future__ import annotations

import os
import struct
from collections.abc import Iterable, Iterator
from pathlib import Path

import google_crc32c

from recondreamer.errors import ConversionError
from recondreamer.io import atomic_path

_MASK_DELTA = 0xA282EAD8
_HEADER = struct.Struct("<QI")  # length, masked CRC of the length
_FOOTER = struct.Struct("<I")  # masked CRC of the data


class TFRecordError(ConversionError):
    """A file is not a TFRecord file, is truncated, or fails a checksum."""


def masked_crc32c(data: bytes) -> int:
    """The masked CRC32C that TFRecord stores next to the length and the data."""
    crc = google_crc32c.value(data)
    rotated = ((crc >> 15) | (crc << 17)) & 0xFFFFFFFF
    return (rotated + _MASK_DELTA) & 0xFFFFFFFF


def iter_records(path: str | os.PathLike) -> Iterator[bytes]:
    """Yield the data of each record of a TFRecord file in order, checking both CRCs.

    Raises TFRecordError naming the file, the record index and the byte offset when the file
    is missing, is not a TFRecord file, is truncated or fails a checksum.
    """
    path = Path(path)
    if path.is_dir():
        raise TFRecordError(f"{path}: is a folder; give one segment's .tfrecord file")
    if not path.is_file():
        raise TFRecordError(f"{path}: no such file")
    file_size = path.stat().st_size
    with path.open("rb") as stream:
        index = 0
        while True:
            offset = stream.tell()
            header = stream.read(_HEADER.size)
            if not header:
                return
            if len(header) < _HEADER.size:
                raise TFRecordError(
                    f"{path}: truncated: record {index} at byte {offset} has a {len(header)}-byte header "
                    f"(expected {_HEADER.size})"
                )
            length, length_crc = _HEADER.unpack(header)
            if masked_crc32c(header[:8]) != length_crc:
                if index == 0:
                    raise TFRecordError(
                        f"{path}: not a TFRecord file (the length checksum of the first record does not match)"
                    )
                raise TFRecordError(f"{path}: corrupted: length checksum mismatch in record {index} at byte {offset}")
            remaining = file_size - stream.tell()
            if length + _FOOTER.size > remaining:
                raise TFRecordError(
                    f"{path}: truncated: record {index} at byte {offset} declares {length} bytes of data "
                    f"but only {max(remaining - _FOOTER.size, 0)} follow"
                )
            data = stream.read(length)
            (data_crc,) = _FOOTER.unpack(stream.read(_FOOTER.size))
            if masked_crc32c(data) != data_crc:
                raise TFRecordError(f"{path}: corrupted: data checksum mismatch in record {index} at byte {offset}")
            yield data
            index += 1


def write_records(path: str | os.PathLike, records: Iterable[bytes]) -> None:
    """Write records as a TFRecord file (atomically)."""
    with atomic_path(path) as tmp, tmp.open("wb") as stream:
        for data in records:
            length = struct.pack("<Q", len(data))
            stream.write(length + struct.pack("<I", masked_crc32c(length)))
            stream.write(data)
            stream.write(_FOOTER.pack(masked_crc32c(data)))
