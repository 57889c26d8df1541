"""The library host's YAML file: where the library is, which CNCs, where each one is served.

    library: /opt/fanuc/libfwlib32.so        # your copy from FANUC's FOCAS2 kit (never shipped with us)
    call_timeout_s: 10
    machines:
      - name: mill-1
        cnc: 192.168.1.10:8193               # the control's FOCAS/Ethernet address
        listen: unix:/run/focas-edge-fwlib/mill-1.sock
        params: {6711: two_word, 1815: bit}  # data type per parameter number the daemon reads or writes
        diag: {300: two_word}
        input_decimals: 3                    # decimals of the least input increment (IS-B mm: 3)

`listen` is a Unix socket (mode `socket_mode`, default 0660) or loopback TCP. A non-loopback TCP address
(the host on a Windows or x86 PC next to the gateway) needs `allow_remote: true`: the surface has no
authentication, so that link must be a network only the gateway reaches.
"""

from __future__ import annotations

import ipaddress
from pathlib import Path
from typing import Literal

import yaml
from pydantic import BaseModel, ConfigDict, Field, ValidationError, field_validator

from edge import ConfigError
from edge.focas.connect import Address, parse_address
from edge.focas.model import ParamType
from edge.focas.packed.client import PackedAddress, parse_packed_address
from edge.fwlib.worker import CncTarget, WorkerTimeouts

ParamTypeName = Literal["bit", "byte", "word", "two_word", "real"]
PARAM_TYPES: dict[str, ParamType] = {
    "bit": ParamType.BIT, "byte": ParamType.BYTE, "word": ParamType.WORD, "two_word": ParamType.TWO_WORD,
    "real": ParamType.REAL,
}
_LOOPBACK_NAMES = {"localhost"}


class HostMachine(BaseModel):
    model_config = ConfigDict(extra="forbid")

    name: str = Field(min_length=1)
    cnc: str = Field(min_length=1, description="HOST[:PORT] of the control; port 8193 by default")
    listen: str
    params: dict[int, ParamTypeName] = Field(default_factory=dict)
    diag: dict[int, ParamTypeName] = Field(default_factory=dict)
    input_decimals: int = Field(default=3, ge=0, le=9, description=(
        "decimal places of the control's least input increment: cnc_rdzofs answers integers in it "
        "(IS-B metric 0.001 mm: 3; IS-C or inch: 4)"))

    @field_validator("cnc")
    @classmethod
    def _cnc_is_host_port(cls, value: str) -> str:
        _cnc_address(value)
        return value

    def target(self) -> CncTarget:
        cnc = _cnc_address(self.cnc)
        return CncTarget(self.name, cnc.host, cnc.port, {n: PARAM_TYPES[t] for n, t in self.params.items()},
                         {n: PARAM_TYPES[t] for n, t in self.diag.items()}, self.input_decimals)

    def address(self) -> PackedAddress:
        return parse_packed_address(self.listen)


class HostSettings(BaseModel):
    model_config = ConfigDict(extra="forbid")

    library: str = Field(min_length=1)
    log_file: str = Field(default="focas.log", description="cnc_startupprocess's log file (Linux)")
    # Below the daemon's view of this host (0.75 x its request_s, 5 s by default), so a hung call answers
    # EW_SOCKET before the daemon gives up on the request.
    call_timeout_s: float = Field(default=3.0, gt=0)
    connect_timeout_s: float = Field(default=10.0, gt=0)
    # A request whose call overran answers EW_SOCKET without calling the library for this long (doubling
    # while it keeps overrunning, 10 min at most), so one hanging function does not stall the others.
    hung_rest_s: float = Field(default=60.0, gt=0)
    backoff_initial_s: float = Field(default=0.5, gt=0)
    backoff_max_s: float = Field(default=30.0, gt=0)
    socket_mode: int = Field(default=0o660, ge=0, le=0o777)
    allow_remote: bool = False
    machines: list[HostMachine] = Field(min_length=1)

    @field_validator("socket_mode", mode="before")
    @classmethod
    def _octal_text(cls, value: object) -> object:
        """`0o600` or `"600"` in YAML: a file mode is octal however it is written."""
        if isinstance(value, str):
            try:
                return int(value.removeprefix("0o"), 8)
            except ValueError:
                raise ValueError(f"expected an octal file mode such as 0o600, got {value!r}") from None
        return value

    def timeouts(self) -> WorkerTimeouts:
        return WorkerTimeouts(self.call_timeout_s, self.connect_timeout_s, self.backoff_initial_s,
                              self.backoff_max_s, self.hung_rest_s)


def _cnc_address(text: str) -> Address:
    """The control's FOCAS/Ethernet address, as the daemon parses one: HOST[:PORT], [v6]:PORT; 8193 by default."""
    try:
        address = parse_address(text)
    except ConfigError as exc:
        raise ValueError("; ".join(exc.problems)) from None
    if address.is_unix:
        raise ValueError(f"{text!r}: expected HOST[:PORT]; a CNC is reached over TCP, not a Unix socket")
    return address


def _is_loopback(host: str) -> bool:
    if host in _LOOPBACK_NAMES:
        return True
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        return False


def check_settings(settings: HostSettings) -> list[str]:
    """Problems no field validator sees alone: listen addresses, duplicates, remote exposure."""
    problems: list[str] = []
    seen: dict[str, str] = {}
    for index, machine in enumerate(settings.machines):
        where = f"machines[{index}] ({machine.name})"
        try:
            address = machine.address()
        except ConfigError as exc:
            problems.extend(f"{where}.listen: {p}" for p in exc.problems)
            continue
        if not address.is_unix and not settings.allow_remote and not _is_loopback(address.host):
            problems.append(f"{where}.listen: {machine.listen!r} is not loopback; the packed surface has no "
                            f"authentication (set allow_remote: true only on a link only the gateway reaches)")
        key = str(address)
        if key in seen:
            problems.append(f"{where}.listen: {key} is also {seen[key]}'s")
        seen[key] = machine.name
    names = [m.name for m in settings.machines]
    problems.extend(f"machines: name {n!r} appears more than once" for n in sorted(set(names))
                    if names.count(n) > 1)
    return problems


def load_settings(path: str | Path) -> HostSettings:
    """Read and check the host's YAML file; ConfigError listing every problem otherwise."""
    source = str(path)
    try:
        raw = yaml.safe_load(Path(path).read_text())
    except OSError as exc:
        raise ConfigError([f"cannot read it: {exc}"], source) from None
    except yaml.YAMLError as exc:
        raise ConfigError([f"not valid YAML: {exc}"], source) from None
    try:
        settings = HostSettings.model_validate(raw)
    except ValidationError as exc:
        raise ConfigError([f"{'.'.join(str(p) for p in e['loc'])}: {e['msg']}" for e in exc.errors()],
                          source) from None
    problems = check_settings(settings)
    if problems:
        raise ConfigError(problems, source)
    return settings
