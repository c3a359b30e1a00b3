"""Decoding Foxglove scene messages as a Foxglove client does: protobuf from the schema a
channel advertises (a serialized FileDescriptorSet), no climbd code; transforms as a tree."""

from __future__ import annotations

import numpy as np
from google.protobuf import descriptor_pb2, descriptor_pool, json_format, message_factory

from climbd.daemon.contract.geometry import rotation

_classes: dict[tuple[str, bytes], type] = {}


def proto_class(name: str, descriptor_set: bytes) -> type:
    """The protobuf message class ``name`` from a serialized FileDescriptorSet."""
    k = (name, descriptor_set)
    if k not in _classes:
        pool = descriptor_pool.DescriptorPool()
        for f in descriptor_pb2.FileDescriptorSet.FromString(descriptor_set).file:
            pool.Add(f)
        _classes[k] = message_factory.GetMessageClass(pool.FindMessageTypeByName(name))
    return _classes[k]


def proto_dict(name: str, descriptor_set: bytes, payload: bytes) -> dict:
    """``payload`` decoded strictly as ``name``, every field present (zeros included)."""
    msg = proto_class(name, descriptor_set)()
    msg.ParseFromString(payload)
    assert msg.SerializeToString() == payload or msg.ByteSize() == len(payload)
    return json_format.MessageToDict(
        msg, preserving_proto_field_name=True, always_print_fields_with_no_presence=True
    )


def decoded(message) -> dict:
    """A foxglove-sdk message object, encoded and decoded against its own schema."""
    schema = type(message).get_schema()
    assert schema.encoding == "protobuf"
    return proto_dict(schema.name, schema.data, message.encode())


def tree(transforms: list[dict]) -> dict[str, tuple[str, np.ndarray, np.ndarray]]:
    """child → (parent, translation, rotation matrix) of decoded FrameTransform dicts."""
    out = {}
    for t in transforms:
        r = t["rotation"]
        q = [r["w"], r["x"], r["y"], r["z"]]
        v = t["translation"]
        out[t["child_frame_id"]] = (
            t["parent_frame_id"],
            np.array([v["x"], v["y"], v["z"]]),
            rotation(q),
        )
    return out


def in_frame(frames: dict, child: str, root: str) -> tuple[np.ndarray, np.ndarray]:
    """Position and rotation of ``child`` in ``root`` by chaining the tree's transforms."""
    p, r = np.zeros(3), np.eye(3)
    while child != root:
        parent, t, rot = frames[child]
        p, r = rot @ p + t, rot @ r
        child = parent
    return p, r
