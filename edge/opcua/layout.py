"""Where a metric appears in the address space, and how its type and quality read in OPC UA terms.

Pure tables and functions (no asyncua), so they are tested and documented without the optional extra.

Every machine (and every further CNC path, which the collector publishes as its own device) is one object
under Objects/Machines, with the top-level components of the OPC UA for Machine Tools companion
specification (OPC 40501-1) by browse name — Identification, Monitoring, Production, Notification — and a
`Metrics` folder holding every published metric by its Sparkplug name (one folder per `/` segment), so
nothing the gateway publishes is missing. A metric that has a place in the 40501 structure appears there
too, as its own variable carrying the same DataValue (OPC 40501 names where the spec has one, e.g.
Identification/SoftwareRevision for Device/Version).
"""

from __future__ import annotations

from edge.samples import MetricType, Quality

MACHINES_FOLDER = "Machines"  # OPC 40001-1: machines live in Objects/Machines
METRICS_FOLDER = "Metrics"
COMPONENTS = ("Identification", "Monitoring", "Production", "Notification")
MESSAGES = "Notification/Messages"  # the machine's event notifier (OPC 40501-1 NotificationType.Messages)
MANUFACTURER = "FANUC"

# (Sparkplug name or prefix ending in "/", 40501 path or prefix). First match wins; a prefix maps the rest
# of the name below it (Axis/X/Absolute -> Monitoring/Axes/X/Absolute).
MIRRORS: tuple[tuple[str, str], ...] = (
    ("Device/Model", "Identification/Model"),
    ("Device/Series", "Identification/ProductCode"),
    ("Device/Version", "Identification/SoftwareRevision"),
    ("Device/MaxAxis", "Identification/MaxAxes"),
    ("Device/AxisNames", "Identification/AxisNames"),
    ("Device/SpindleNames", "Identification/SpindleNames"),
    ("Device/Paths", "Identification/Paths"),
    ("Status/", "Monitoring/Status/"),
    ("Axis/", "Monitoring/Axes/"),
    ("Spindle/", "Monitoring/Spindles/"),
    ("Feed/", "Monitoring/Feeds/"),
    ("Program/", "Production/ActiveProgram/"),
    ("Counters/", "Production/PartCounters/"),
    ("Times/", "Production/Times/"),
    ("Alarm/Count", "Notification/Alarms/ActiveCount"),
    ("Alarm/Active", "Notification/Alarms/Active"),
    ("Alarm/Status", "Notification/Alarms/Status"),
    ("Message/Operator", "Notification/OperatorMessages"),
)


def mirror_path(metric: str) -> str | None:
    """The 40501 path of a metric (below the machine object), or None when it has no place there."""
    for source, target in MIRRORS:
        if source.endswith("/"):
            if metric.startswith(source) and len(metric) > len(source):
                return target + metric[len(source):]
        elif metric == source:
            return target
    return None


def metric_path(metric: str) -> str:
    """The path of a metric's node in the plain folder (below the machine object)."""
    return f"{METRICS_FOLDER}/{metric}"


# MetricType -> the name of the OPC UA built-in type (ua.VariantType member and DataType node alike).
VARIANT_TYPES: dict[MetricType, str] = {
    MetricType.BOOLEAN: "Boolean",
    MetricType.INT8: "SByte",
    MetricType.INT16: "Int16",
    MetricType.INT32: "Int32",
    MetricType.INT64: "Int64",
    MetricType.UINT8: "Byte",
    MetricType.UINT16: "UInt16",
    MetricType.UINT32: "UInt32",
    MetricType.UINT64: "UInt64",
    MetricType.FLOAT: "Float",
    MetricType.DOUBLE: "Double",
    MetricType.STRING: "String",
    MetricType.DATETIME: "DateTime",
}

# Quality -> the StatusCode name a value carries. A quality this table does not know reads Bad.
STATUS_BY_QUALITY: dict[Quality, str] = {
    Quality.GOOD: "Good",
    Quality.STALE: "UncertainLastUsableValue",
    Quality.BAD: "Bad",
}
OFFLINE_STATUS = "BadNoCommunication"  # every value of a machine whose CNC session is down


def status_name(quality: object) -> str:
    return STATUS_BY_QUALITY.get(quality, "Bad")  # type: ignore[call-overload]


# Engineering units (the `unit` of a metric) as UNECE Recommendation 20 common codes: EUInformation's
# UnitId is the code packed as in OPC 10000-8 §5.6.3 (each character's byte, big-endian); namespace
# http://www.opcfoundation.org/UA/units/un/cefact. A unit not listed gets UnitId -1 and its text.
UNECE_CODES: dict[str, tuple[str, str]] = {  # unit -> (common code, description)
    "mm": ("MMT", "millimetre"),
    "deg": ("DD", "degree [unit of angle]"),
    "rpm": ("RPM", "revolutions per minute"),
    "mm/min": ("H81", "millimetre per minute"),
    "%": ("P1", "percent"),
    "s": ("SEC", "second [unit of time]"),
    "ms": ("C26", "millisecond"),
    "min": ("MIN", "minute [unit of time]"),
    "h": ("HUR", "hour"),
    "m/min": ("2X", "metre per minute"),
    "inch": ("INH", "inch"),
}


def unit_id(code: str) -> int:
    """The EUInformation UnitId of a UNECE common code."""
    value = 0
    for char in code:
        value = value << 8 | ord(char)
    return value


def describe_unit(unit: str) -> tuple[int, str]:
    """(UnitId, description) of a metric unit; UnitId -1 when the unit has no UNECE code here."""
    known = UNECE_CODES.get(unit)
    if known is None:
        return -1, unit
    code, description = known
    return unit_id(code), description
