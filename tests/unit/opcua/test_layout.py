"""The OPC UA server's pure tables: where a metric appears, its type, its status, a write's status."""

from __future__ import annotations

import pytest

from edge.opcua import layout
from edge.opcua.writes import STATUS_BY_CODE, WriteOutcome, status_for
from edge.samples import MetricType, Quality


@pytest.mark.parametrize(("metric", "path"), [
    ("Device/Version", "Identification/SoftwareRevision"),
    ("Device/MaxAxis", "Identification/MaxAxes"),
    ("Status/Run", "Monitoring/Status/Run"),
    ("Status/Execution", "Monitoring/Status/Execution"),  # a metric added later lands by its prefix
    ("Axis/X/Absolute", "Monitoring/Axes/X/Absolute"),
    ("Spindle/2/Load", "Monitoring/Spindles/2/Load"),
    ("Program/Name", "Production/ActiveProgram/Name"),
    ("Counters/Parts", "Production/PartCounters/Parts"),
    ("Alarm/Count", "Notification/Alarms/ActiveCount"),
    ("Macro/500", None),
    ("Status/", None),
    ("Device/Paths2", None),
])
def test_mirror_paths(metric: str, path: str | None) -> None:
    assert layout.mirror_path(metric) == path


def test_every_metric_type_has_a_variant_type() -> None:
    assert set(layout.VARIANT_TYPES) == set(MetricType)


def test_status_of_quality_unknown_reads_bad() -> None:
    assert [layout.status_name(q) for q in (Quality.GOOD, Quality.STALE, Quality.BAD)] == \
        ["Good", "UncertainLastUsableValue", "Bad"]
    assert layout.status_name(12345) == "Bad"


def test_units_pack_the_unece_code() -> None:
    assert layout.describe_unit("mm") == (0x4D4D54, "millimetre")
    assert layout.describe_unit("furlong") == (-1, "furlong")


def test_every_reply_code_has_a_status() -> None:
    errors = pytest.importorskip("edge.command.errors")
    assert {code.value for code in errors.ErrorCode} <= set(STATUS_BY_CODE)
    assert status_for(WriteOutcome(True)) == "Good"
    assert status_for(WriteOutcome(False, "not_allowed")) == "BadUserAccessDenied"
    assert status_for(WriteOutcome(False, "something new")) == "BadInternalError"


def test_status_names_exist_in_asyncua() -> None:
    ua = pytest.importorskip("asyncua").ua
    names = {*STATUS_BY_CODE.values(), *layout.STATUS_BY_QUALITY.values(), layout.OFFLINE_STATUS}
    assert all(hasattr(ua.StatusCodes, name) for name in names)
