"""An own minimal protobuf schema for Waymo Open Dataset v1 ``Frame`` records.

Only the fields the converter reads are declared; protobuf skips the others on parse. Field
numbers and wire types follow Waymo's public ``dataset.proto``, ``label.proto``, ``map.proto``
and ``vector.proto`` (see ``docs/waymo.md``). Nested messages are flattened to top-level names
(``Label.Box`` -> ``LabelBox``): names do not travel on the wire, field numbers do. Enums are
declared as int32 so that values this schema does not know are kept instead of dropped.

The message classes are built at import from a ``FileDescriptorProto`` in a private
descriptor pool, so nothing is compiled at install and no global pool name can clash.
"""

from __future__ import annotations

from google.protobuf import descriptor_pb2, descriptor_pool, message_factory

_PACKAGE = "recondreamer.waymo_v1"
_F = descriptor_pb2.FieldDescriptorProto

# Scalar type names of this table -> descriptor type codes.
_SCALARS = {
    "double": _F.TYPE_DOUBLE,
    "float": _F.TYPE_FLOAT,
    "int32": _F.TYPE_INT32,
    "int64": _F.TYPE_INT64,
    "bool": _F.TYPE_BOOL,
    "string": _F.TYPE_STRING,
    "bytes": _F.TYPE_BYTES,
}

# message name -> [(field name, number, type, repeated)]; a type that is not a scalar names a message.
_MESSAGES: dict[str, list[tuple[str, int, str, bool]]] = {
    "MatrixShape": [("dims", 1, "int32", True)],
    "MatrixFloat": [("data", 1, "float", True), ("shape", 2, "MatrixShape", False)],
    "Transform": [("transform", 1, "double", True)],  # 4x4 row major
    "Vector3d": [("x", 1, "double", False), ("y", 2, "double", False), ("z", 3, "double", False)],
    "CameraCalibration": [
        ("name", 1, "int32", False),  # CameraName.Name: FRONT = 1
        ("intrinsic", 2, "double", True),  # fu, fv, cu, cv, k1, k2, p1, p2, k3
        ("extrinsic", 3, "Transform", False),  # camera (x forward, y left, z up) to vehicle
        ("width", 4, "int32", False),
        ("height", 5, "int32", False),
        ("rolling_shutter_direction", 6, "int32", False),
    ],
    "LaserCalibration": [
        ("name", 1, "int32", False),  # LaserName.Name: TOP = 1
        ("beam_inclinations", 2, "double", True),  # radians, ascending; empty = uniform in [min, max]
        ("beam_inclination_min", 3, "double", False),
        ("beam_inclination_max", 4, "double", False),
        ("extrinsic", 5, "Transform", False),  # laser to vehicle
    ],
    "ContextStats": [
        ("time_of_day", 2, "string", False),
        ("location", 3, "string", False),
        ("weather", 4, "string", False),
    ],
    "Context": [
        ("name", 1, "string", False),
        ("camera_calibrations", 2, "CameraCalibration", True),
        ("laser_calibrations", 3, "LaserCalibration", True),
        ("stats", 4, "ContextStats", False),
    ],
    "RangeImage": [
        ("range_image_compressed", 2, "bytes", False),  # zlib of a serialized [H,W,4] MatrixFloat
        ("range_image_pose_compressed", 4, "bytes", False),  # zlib of [H,W,6] roll pitch yaw x y z
    ],
    "CameraImage": [
        ("name", 1, "int32", False),
        ("image", 2, "bytes", False),  # JPEG
        ("pose", 3, "Transform", False),
        ("pose_timestamp", 5, "double", False),
    ],
    "Laser": [
        ("name", 1, "int32", False),
        ("ri_return1", 2, "RangeImage", False),
        ("ri_return2", 3, "RangeImage", False),
    ],
    "LabelBox": [
        ("center_x", 1, "double", False),
        ("center_y", 2, "double", False),
        ("center_z", 3, "double", False),
        ("width", 4, "double", False),  # along y of the box
        ("length", 5, "double", False),  # along x of the box = along the heading
        ("height", 6, "double", False),
        ("heading", 7, "double", False),  # radians, rotation of +x about +z
    ],
    "LabelMetadata": [
        ("speed_x", 1, "double", False),
        ("speed_y", 2, "double", False),
        ("accel_x", 3, "double", False),
        ("accel_y", 4, "double", False),
        ("speed_z", 5, "double", False),
        ("accel_z", 6, "double", False),
    ],
    "Label": [
        ("box", 1, "LabelBox", False),
        ("metadata", 2, "LabelMetadata", False),
        ("type", 3, "int32", False),  # 1 vehicle, 2 pedestrian, 3 sign, 4 cyclist
        ("id", 4, "string", False),
        ("detection_difficulty_level", 5, "int32", False),
        ("tracking_difficulty_level", 6, "int32", False),
        ("num_lidar_points_in_box", 7, "int32", False),
        ("num_top_lidar_points_in_box", 13, "int32", False),
    ],
    "CameraLabels": [("name", 1, "int32", False), ("labels", 2, "Label", True)],
    "MapPoint": [("x", 1, "double", False), ("y", 2, "double", False), ("z", 3, "double", False)],
    "LaneCenter": [("type", 2, "int32", False), ("polyline", 8, "MapPoint", True)],
    "RoadLine": [("type", 1, "int32", False), ("polyline", 2, "MapPoint", True)],
    "RoadEdge": [("type", 1, "int32", False), ("polyline", 2, "MapPoint", True)],
    "Crosswalk": [("polygon", 1, "MapPoint", True)],
    "MapFeature": [
        ("id", 1, "int64", False),
        ("lane", 3, "LaneCenter", False),
        ("road_line", 4, "RoadLine", False),
        ("road_edge", 5, "RoadEdge", False),
        ("crosswalk", 8, "Crosswalk", False),
    ],
    "Frame": [
        ("context", 1, "Context", False),
        ("timestamp_micros", 2, "int64", False),
        ("pose", 3, "Transform", False),  # vehicle to global, 4x4 row major
        ("images", 4, "CameraImage", True),
        ("lasers", 5, "Laser", True),
        ("laser_labels", 6, "Label", True),
        ("projected_lidar_labels", 9, "CameraLabels", True),
        ("map_features", 10, "MapFeature", True),  # first frame of a segment only (v1.4.2+)
        ("map_pose_offset", 11, "Vector3d", False),
    ],
}

# Waymo declares these packed; the others use proto2's default (parsers accept both encodings).
_PACKED = {("MatrixFloat", "data")}


def _file_descriptor() -> descriptor_pb2.FileDescriptorProto:
    file_proto = descriptor_pb2.FileDescriptorProto(
        name="recondreamer/waymo_v1.proto", package=_PACKAGE, syntax="proto2"
    )
    for message_name, fields in _MESSAGES.items():
        message = file_proto.message_type.add(name=message_name)
        for field_name, number, type_name, repeated in fields:
            field = message.field.add(
                name=field_name,
                number=number,
                label=_F.LABEL_REPEATED if repeated else _F.LABEL_OPTIONAL,
            )
            if type_name in _SCALARS:
                field.type = _SCALARS[type_name]
            else:
                field.type = _F.TYPE_MESSAGE
                field.type_name = f".{_PACKAGE}.{type_name}"
            if (message_name, field_name) in _PACKED:
                field.options.packed = True
    return file_proto


def _build_classes() -> dict[str, type]:
    pool = descriptor_pool.DescriptorPool()
    pool.Add(_file_descriptor())
    return {
        name: message_factory.GetMessageClass(pool.FindMessageTypeByName(f"{_PACKAGE}.{name}")) for name in _MESSAGES
    }


_CLASSES = _build_classes()

Frame = _CLASSES["Frame"]
MatrixFloat = _CLASSES["MatrixFloat"]
Label = _CLASSES["Label"]
CameraCalibration = _CLASSES["CameraCalibration"]
LaserCalibration = _CLASSES["LaserCalibration"]
MapFeature = _CLASSES["MapFeature"]

CAMERA_NAMES = {"FRONT": 1, "FRONT_LEFT": 2, "FRONT_RIGHT": 3, "SIDE_LEFT": 4, "SIDE_RIGHT": 5}
LASER_TOP = 1
LABEL_TYPES = {1: "vehicle", 2: "pedestrian", 3: "sign", 4: "cyclist"}
