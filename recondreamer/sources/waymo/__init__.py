"""Waymo Open Dataset v1 source: streaming TFRecord reader, own minimal Frame schema, converter.

The public names are imported on first use (PEP 562) so that ``recondreamer --help``, which
imports this package's ``commands`` module, does not load numpy, protobuf and Pillow.
"""

from __future__ import annotations

import importlib

_PUBLIC = {
    "convert_waymo": "recondreamer.sources.waymo.convert",
    "TFRecordError": "recondreamer.sources.waymo.tfrecord",
    "iter_records": "recondreamer.sources.waymo.tfrecord",
    "masked_crc32c": "recondreamer.sources.waymo.tfrecord",
    "write_records": "recondreamer.sources.waymo.tfrecord",
}

__all__ = sorted(_PUBLIC)


def __getattr__(name: str):
    if name not in _PUBLIC:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    return getattr(importlib.import_module(_PUBLIC[name]), name)
