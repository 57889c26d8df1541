"""The field types every section shares, and the model base.

Durations accept seconds as a number or a string with a unit (`250ms`, `1s`, `5m`, `1h`, `7d`). Sparkplug
ids and metric names become topic levels and metric paths, and host names and IP addresses are checked for
form (not resolved), all where the file is read.
Every model refuses unknown keys (a typo must not silently fall back to a default) and is frozen; `_at`
lets a model validator name the key below it that is wrong (load.format_errors turns it into a path).
"""

from __future__ import annotations

import ipaddress
import re
from pathlib import Path
from typing import Annotated

from pydantic import BaseModel, BeforeValidator, ConfigDict, Field

_DURATION_RE = re.compile(r"\s*(\d+(?:\.\d+)?)\s*(ms|s|m|min|h|d)?\s*", re.ASCII)
_DURATION_UNITS = {"ms": 0.001, "s": 1.0, None: 1.0, "m": 60.0, "min": 60.0, "h": 3600.0,
                   "d": 86400.0}


def _parse_duration(value: object) -> object:
    """Seconds as a number, or a string with a unit; anything else is left for the float check."""
    if isinstance(value, str):
        match = _DURATION_RE.fullmatch(value)
        if match is None:
            raise ValueError(f"expected a duration like 250ms, 1s, 5m, 2h, 7d or a number of seconds, got {value!r}")
        return float(match[1]) * _DURATION_UNITS[match[2]]
    if isinstance(value, bool):
        raise ValueError(f"expected a duration, got {value!r}")
    return value


Duration = Annotated[float, BeforeValidator(_parse_duration), Field(gt=0)]


def check_sparkplug_id(value: str) -> str:
    """Sparkplug group/edge node/device ids: non-empty UTF-8 without + / # (they are topic levels)."""
    if not value:
        raise ValueError("must not be empty")
    bad = sorted({ch for ch in value if ch in "+/#"})
    if bad:
        raise ValueError(f"{value!r} contains {' '.join(bad)}; Sparkplug ids may not contain + / #")
    if any(ord(ch) < 0x20 or ord(ch) == 0x7F for ch in value):
        raise ValueError(f"{value!r} contains control characters")
    if value != value.strip():
        raise ValueError(f"{value!r} has leading or trailing spaces")
    return value


SparkplugId = Annotated[str, BeforeValidator(lambda v: check_sparkplug_id(v) if isinstance(v, str) else v)]


_LABEL_RE = re.compile(r"[A-Za-z0-9_](?:[A-Za-z0-9_-]{0,61}[A-Za-z0-9_])?", re.ASCII)


def check_host(value: str) -> str:
    """An IPv4/IPv6 address or a DNS name (never resolved here: a broker may not be up when the file is read).

    A name whose last label is all digits can only be meant as an IPv4 address, so `192.168.10.577` is
    refused as one instead of being looked up as a name for ever. Underscores pass: DNS allows them and
    container service names use them.
    """
    text = value.strip()
    if not text or text != value:
        raise ValueError(f"{value!r}: expected an IP address or a host name, without spaces")
    if ":" in text:
        try:
            ipaddress.IPv6Address(text.removeprefix("[").removesuffix("]"))
        except ValueError:
            raise ValueError(f"{value!r} is not a valid IPv6 address") from None
        return value
    labels = text.removesuffix(".").split(".")
    if labels[-1].isdigit():
        try:
            ipaddress.IPv4Address(text)
        except ValueError:
            over = [label for label in labels if label.isdigit() and int(label) > 255]
            why = f" ({over[0]} is more than 255)" if over else " (four numbers 0..255, e.g. 192.168.1.20)"
            raise ValueError(f"{value!r} is not a valid IPv4 address{why}") from None
        return value
    bad = next((label for label in labels if not _LABEL_RE.fullmatch(label)), None)
    if bad is not None or len(text) > 253:
        what = ("it is longer than 253 characters" if bad is None
                else "an empty label (two dots in a row)" if not bad else f"label {bad!r}")
        raise ValueError(f"{value!r} is not a valid host name: {what}; a host name is labels of letters, digits "
                         "and '-' (1..63 each, not starting or ending with '-') separated by dots")
    return value


HostName = Annotated[str, BeforeValidator(lambda v: check_host(v) if isinstance(v, str) else v)]


def check_file(value: Path | None) -> Path | None:
    """A file the config names (certificate, key) exists when the file is read, not at its first use."""
    if value is not None and not value.is_file():
        raise ValueError(f"no such file: {value}")
    return value


def check_metric_name(value: str) -> str:
    """A metric name: folders separated by '/', no empty folder, no MQTT wildcards."""
    if not value or any(not part.strip() for part in value.split("/")):
        raise ValueError(f"{value!r} is not a metric name: folders separated by '/', none empty")
    if "+" in value or "#" in value or any(ord(ch) < 0x20 for ch in value):
        raise ValueError(f"{value!r}: metric names may not contain + # or control characters")
    return value


MetricName = Annotated[str, BeforeValidator(lambda v: check_metric_name(v) if isinstance(v, str) else v)]


class _Model(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)


def _at(path: str, message: str) -> ValueError:
    """A cross-field error reported at `path` below the model that raises it."""
    return ValueError(f"@{path}@{message}")
