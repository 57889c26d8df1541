"""The checked-in sparkplug_b_pb2 module is generated from the checked-in sparkplug_b.proto."""

from __future__ import annotations

import re
from pathlib import Path

from google.protobuf.descriptor import Descriptor, EnumDescriptor, FieldDescriptor
from google.protobuf.internal import api_implementation

from edge.publish import sparkplug_b_pb2

PROTO = Path(sparkplug_b_pb2.__file__).with_name("sparkplug_b.proto")
SCALARS = {
    "string": FieldDescriptor.TYPE_STRING, "bytes": FieldDescriptor.TYPE_BYTES, "bool": FieldDescriptor.TYPE_BOOL,
    "uint32": FieldDescriptor.TYPE_UINT32, "uint64": FieldDescriptor.TYPE_UINT64,
    "float": FieldDescriptor.TYPE_FLOAT, "double": FieldDescriptor.TYPE_DOUBLE,
}


def parse_proto(text: str) -> tuple[dict[str, tuple[str, str, int]], dict[str, int], str]:
    """Fields as {'Payload.Metric.alias': (label, type, number)}, enum values, and the package."""
    text = re.sub(r"//[^\n]*", "", text)
    package = re.search(r"package\s+([\w.]+)\s*;", text).group(1)  # type: ignore[union-attr]
    fields: dict[str, tuple[str, str, int]] = {}
    enum_values: dict[str, int] = {}
    scope: list[str] = []
    kinds: list[str] = []
    for token in re.finditer(r"(message|enum|oneof)\s+(\w+)\s*\{|\}|([^;{}]+);", text):
        if token.group(1):
            kinds.append(token.group(1))
            scope.append(token.group(2) if token.group(1) != "oneof" else "")
        elif token.group(0) == "}":
            kinds.pop()
            scope.pop()
        else:
            stmt = token.group(3).split()
            owner = ".".join(s for s in scope if s)
            if kinds and kinds[-1] == "enum":
                name, _, number = stmt
                enum_values[name] = int(number)
            elif stmt[0] in ("extensions", "syntax", "package", "option"):
                continue
            elif stmt[0] in ("optional", "repeated", "required"):
                fields[f"{owner}.{stmt[2]}"] = (stmt[0], stmt[1], int(stmt[4]))
            else:  # a oneof member: no label
                fields[f"{owner}.{stmt[1]}"] = ("optional", stmt[0], int(stmt[3]))
    return fields, enum_values, package


def descriptor_fields(desc: Descriptor, prefix: str, out: dict[str, tuple[str, str, int]]) -> None:
    for f in desc.fields:
        repeated = f.is_repeated if hasattr(f, "is_repeated") else f.label == FieldDescriptor.LABEL_REPEATED
        label = "repeated" if repeated else "optional"
        if f.type in (FieldDescriptor.TYPE_MESSAGE, FieldDescriptor.TYPE_ENUM):
            kind = f.message_type.full_name if f.message_type else f.enum_type.full_name
        else:
            kind = next(k for k, v in SCALARS.items() if v == f.type)
        out[f"{prefix}{desc.name}.{f.name}"] = (label, kind, f.number)
    for nested in desc.nested_types:
        descriptor_fields(nested, f"{prefix}{desc.name}.", out)


def test_generated_module_matches_the_proto() -> None:
    fields, enum_values, package = parse_proto(PROTO.read_text())
    assert sparkplug_b_pb2.DESCRIPTOR.package == package == "org.eclipse.tahu.protobuf"
    generated: dict[str, tuple[str, str, int]] = {}
    descriptor_fields(sparkplug_b_pb2.Payload.DESCRIPTOR, "", generated)
    assert set(generated) == set(fields)
    for name, (label, kind, number) in fields.items():
        g_label, g_kind, g_number = generated[name]
        assert (g_label, g_number) == (label, number), name
        assert g_kind == kind or g_kind.endswith(f".{kind}"), f"{name}: {g_kind} vs {kind}"
    enum: EnumDescriptor = sparkplug_b_pb2.DESCRIPTOR.enum_types_by_name["DataType"]
    assert {v.name: v.number for v in enum.values} == enum_values


def test_key_wire_facts() -> None:
    """Spot checks against the spec's field table, independent of the parser above."""
    metric = sparkplug_b_pb2.Payload.Metric.DESCRIPTOR.fields_by_name
    assert {n: metric[n].number for n in ("name", "alias", "timestamp", "datatype", "is_null",
                                          "int_value", "long_value", "string_value")} == {
        "name": 1, "alias": 2, "timestamp": 3, "datatype": 4, "is_null": 7,
        "int_value": 10, "long_value": 11, "string_value": 15}
    payload = sparkplug_b_pb2.Payload.DESCRIPTOR.fields_by_name
    assert (payload["timestamp"].number, payload["metrics"].number, payload["seq"].number) == (1, 2, 3)
    assert sparkplug_b_pb2.DataType.Value("UInt32") == 7 and sparkplug_b_pb2.DataType.Value("DateTimeArray") == 34


def test_fast_backend_in_use() -> None:
    assert api_implementation.Type() == "upb"
