"""Reading a config file: `load_config(path)` returns a Config or raises edge.ConfigError listing EVERY
problem, each with its path in the file and its line (`machines[2].poll.pmc[0].range: end 100 before
start 103 (line 14)`).

The YAML loader refuses a key given twice. `defaults:` and `templates:` are expanded (merge) before the
models validate. The rules between keys are re-checked on the raw data, because pydantic skips a model
validator when any field of its section is invalid and a bad file must show every problem at once. Soft
findings (a history depth clamped to 1..250, what a native-only machine cannot publish) do not fail the
load; they are listed in `Config.warnings` for the caller to log.
"""

from __future__ import annotations

import os
import pickle
import re
import types
import typing
from collections.abc import Iterator, Mapping
from pathlib import Path
from typing import Any

import yaml
from pydantic import BaseModel, ValidationError

from edge import ConfigError
from edge.config.gateways import GATEWAY_ENV, plain_file_problems, read_plan
from edge.config.lines import line_map, line_of, with_lines
from edge.config.machines import HISTORY_DEPTH_MAX, HISTORY_DEPTH_MIN, _endpoint_rules
from edge.config.merge import expand_machines
from edge.config.mqtt import FORMATS, _mqtt_rules, read_secret
from edge.config.opcua import opcua_secret_problems
from edge.config.root import Config, _duplicate_ids
from edge.config.service_access import current_account, unreadable_file


def load_config(path: str | os.PathLike[str], environ: Mapping[str, str] | None = None,
                secrets: bool = True, gateway: str | None = None) -> Config:
    """Read and validate a config file; ConfigError lists every problem with its path.

    `secrets=False` leaves the password unread (check-config --as-service asks the service's unit instead).
    `gateway` picks this process's gateway in a fleet file with `gateways:` (see parse_config).
    """
    source = str(path)
    try:
        text = Path(path).read_text(encoding="utf-8")
    except PermissionError as exc:
        denied = unreadable_file(current_account(), "config", Path(path).absolute())
        raise ConfigError([denied or f"cannot read the file: {exc.strerror}"], source) from exc
    except OSError as exc:
        raise ConfigError([f"cannot read the file: {exc.strerror or exc}"], source) from exc
    except UnicodeDecodeError as exc:
        raise ConfigError([f"not UTF-8 text: {exc.reason} at byte {exc.start}"], source) from exc
    return parse_config(text, source, environ, secrets, gateway)


def parse_config(text: str, source: str = "config", environ: Mapping[str, str] | None = None,
                 secrets: bool = True, gateway: str | None = None) -> Config:
    """Validate config text (YAML); see load_config.

    In a fleet file with `gateways:`, the whole fleet is validated as `gateway` sees it and the Config holds
    only its machines. Without a gateway, every gateway's view is validated (secrets unread: they live on
    each gateway's box) and the first gateway's Config is returned, for an overview (check-config).
    """
    environ = os.environ if environ is None else environ
    data, expansion_problems = expand_machines(_parse_yaml(text, source))
    plan = read_plan(data)
    if plan is None:
        problems = plain_file_problems(data, gateway)
        if problems:
            raise ConfigError(with_lines(problems, text), source)
        return _validated(data, text, source, environ, secrets, expansion_problems)
    if gateway is not None and gateway not in plan.bodies:
        where = line_of(("gateways",), line_map(text))
        raise ConfigError([f"gateway {gateway!r} (--gateway or {GATEWAY_ENV}) is not in gateways: "
                           f"{plan.defined()}" + (f" (line {where})" if where else "")], source)
    found = [*expansion_problems, *plan.problems]
    configs: dict[str, Config] = {}
    for name in [gateway] if gateway is not None else plan.names:
        try:
            configs[name] = _validated(plan.data_for(data, name), text, source, environ,
                                       secrets and gateway is not None, [])
        except ConfigError as exc:
            found += [p for p in (plan.rename(problem, name) for problem in _without_lines(exc.problems))
                      if p not in found]
    if found:
        raise ConfigError(with_lines(found, text), source)
    chosen = gateway if gateway is not None else plan.names[0]
    fleet = {name: plan.machines_of(name) for name in plan.names}
    return configs[chosen].only_gateway(chosen, fleet)


def _validated(data: dict[str, Any], text: str, source: str, environ: Mapping[str, str], secrets: bool,
               expansion_problems: list[str]) -> Config:
    """One gateway's data to a Config, or ConfigError with every problem (schema, cross-checks, secrets)."""
    try:
        config = Config.model_validate(data)
        if expansion_problems:
            raise ConfigError(with_lines(expansion_problems, text), source)
    except ValidationError as exc:
        found = expansion_problems + format_errors(exc)
        found += [p for p in (*_duplicate_ids(data), *_mqtt_cross_checks(data), *_machine_cross_checks(data),
                                   *_secret_problems(data, environ, secrets),
                                   *opcua_secret_problems(data.get("opcua"), environ, secrets))
                  if p not in found]
        raise ConfigError(with_lines(found, text), source) from None
    problems = [*_secret_problems(data, environ, secrets), *opcua_secret_problems(data.get("opcua"), environ, secrets)]
    if problems:
        raise ConfigError(with_lines(problems, text), source)
    config._warnings.extend(_clamp_warnings(data))
    config._warnings.extend(_native_only_warnings(config))
    config._warnings.extend(config.opcua.warnings())
    state_directory = environ.get("STATE_DIRECTORY", "").split(":")[0]
    if state_directory:
        config._state_dir = Path(state_directory)
    return config


def _without_lines(problems: list[str]) -> list[str]:
    """Problems as found, before with_lines: a gateway's are renamed to its entry, then located again."""
    return [re.sub(r" \(line \d+\)$", "", problem) for problem in problems]


# libyaml's parser where PyYAML was built with it: the pure-Python one took 8 s for a 1,000-machine file, and
# a reload parses on the event loop (every CNC request waits meanwhile); libyaml takes a tenth of that.
_SafeLoader: type[yaml.SafeLoader] = getattr(yaml, "CSafeLoader", yaml.SafeLoader)


class _UniqueKeyLoader(_SafeLoader):  # type: ignore[valid-type,misc]
    """SafeLoader that refuses a key given twice in one mapping (PyYAML keeps the last silently)."""


def _construct_mapping(loader: yaml.SafeLoader, node: yaml.MappingNode, deep: bool = False) -> dict[Any, Any]:
    seen: dict[Any, yaml.Mark] = {}
    for key_node, _value in node.value:
        key = loader.construct_object(key_node, deep=deep)
        if isinstance(key, typing.Hashable) and key in seen:
            raise yaml.constructor.ConstructorError(
                "while reading a mapping", node.start_mark,
                f"key {key!r} given twice (first on line {seen[key].line + 1})", key_node.start_mark)
        if isinstance(key, typing.Hashable):
            seen[key] = key_node.start_mark
    return loader.construct_mapping(node, deep=deep)


_UniqueKeyLoader.add_constructor(yaml.resolver.BaseResolver.DEFAULT_MAPPING_TAG, _construct_mapping)


def _parse_yaml(text: str, source: str) -> dict[str, Any]:
    try:
        data = yaml.load(text, Loader=_UniqueKeyLoader)  # a SafeLoader subclass
    except yaml.MarkedYAMLError as exc:
        mark = exc.problem_mark or exc.context_mark
        where = f"line {mark.line + 1}, column {mark.column + 1}: " if mark else ""
        raise ConfigError([f"{where}YAML syntax: {exc.problem or exc.context}"], source) from None
    except yaml.YAMLError as exc:
        raise ConfigError([f"YAML syntax: {exc}"], source) from None
    if data is None:
        raise ConfigError(["the file is empty; expected a mapping with mqtt: and machines:"], source)
    if not isinstance(data, dict):
        raise ConfigError([f"expected a mapping at the top level, got {type(data).__name__}"], source)
    # The data again, rebuilt once everything the parse allocated is freed. The parser made a node per
    # scalar (~20 kB a machine) and the data reuses the nodes' strings, scattered over the allocator's
    # arenas, which stay mapped while one object in them lives: 1,000 machines kept ~15 MB of RSS for 3 MB
    # of data. Pickled to one buffer, freed (no reference left here) and unpickled (13 ms at 1,000
    # machines), it is laid out afresh. Only the safe loader's plain types are in it; the buffer is ours.
    packed = pickle.dumps(data, protocol=pickle.HIGHEST_PROTOCOL)
    del data
    return pickle.loads(packed)


def format_errors(exc: ValidationError) -> list[str]:
    """pydantic errors as 'path: message' lines, paths written as in the file (machines[2].poll)."""
    problems = []
    for error in exc.errors():
        loc = list(error["loc"])
        message = str(error["msg"]).removeprefix("Value error, ").removeprefix("Assertion failed, ")
        if message.startswith("@"):
            sub, _, message = message[1:].partition("@")
            loc.extend(part for part in re.split(r"\.|(?=\[)", sub) if part)
        if error["type"] == "extra_forbidden":
            allowed = _allowed_keys(loc[:-1])
            message = "unknown key" + (f" (expected one of: {', '.join(allowed)})" if allowed else "")
        elif error["type"] == "missing":
            message = "required"
        problems.append(f"{format_path(loc)}: {message}")
    return problems


def format_path(loc: list[Any]) -> str:
    text = ""
    for part in loc:
        if isinstance(part, int):
            text += f"[{part}]"
        elif isinstance(part, str) and part.startswith("["):
            text += part
        else:
            text += ("." if text else "") + str(part)
    return text or "(top level)"


def _allowed_keys(loc: list[Any]) -> list[str]:
    model: Any = Config
    for part in loc:
        if isinstance(part, int):
            continue
        field = model.model_fields.get(part) or next(
            (f for f in model.model_fields.values() if f.alias == part), None)
        if field is None:
            return []
        found = _model_in(field.annotation)
        if found is None:
            return []
        model = found
    return sorted(field.alias or name for name, field in model.model_fields.items() if name != "password")


def _model_in(annotation: Any) -> type[BaseModel] | None:
    if isinstance(annotation, type) and issubclass(annotation, BaseModel):
        return annotation
    if isinstance(annotation, types.UnionType) or typing.get_origin(annotation) is not None:
        for arg in typing.get_args(annotation):
            found = _model_in(arg)
            if found is not None:
                return found
    return None


def _clamp_warnings(data: dict[str, Any]) -> list[str]:
    sections: list[tuple[str, object]] = [("alarms", data.get("alarms"))]
    machines = data.get("machines")
    if isinstance(machines, list):
        sections += [(f"machines[{i}].alarms", m.get("alarms")) for i, m in enumerate(machines)
                     if isinstance(m, dict)]
    warnings = []
    for path, section in sections:
        depth = section.get("history_depth") if isinstance(section, dict) else None
        if isinstance(depth, int) and not HISTORY_DEPTH_MIN <= depth <= HISTORY_DEPTH_MAX:
            clamped = min(max(depth, HISTORY_DEPTH_MIN), HISTORY_DEPTH_MAX)
            warnings.append(f"{path}.history_depth: {depth} is outside {HISTORY_DEPTH_MIN}.."
                            f"{HISTORY_DEPTH_MAX} (the CNC ring holds at most {HISTORY_DEPTH_MAX}); "
                            f"using {clamped}")
    return warnings


def _native_only_warnings(config: Config) -> list[str]:
    """What a native-only machine (no fwlib_host) is set to publish but cannot: the wire has no public code for
    alarm history nor for the library-only poll flags (docs/protocol.md), so they would be dropped at once."""
    native_only = [(index, machine) for index, machine in enumerate(config.machines)
                   if machine.transport == "focas" and machine.fwlib_host is None]
    history = [
        f"machines[{index}] ({machine.id}): alarms mode ActivePlusHistory on the native transport alone: "
        f"the CNC's alarm history will NOT be published (no public wire code for cnc_rdalmhistry; "
        f"Plan/DroppedFunctions lists ReadAlarmHistory). Active alarms and the raise/clear events the "
        f"gateway derives from them at its poll rate (stamped with CNC time) WILL be published. "
        f"For the history, add fwlib_host: (a focas-edge fwlib-host, docs/install.md)"
        for index, machine in native_only if config.alarms_for(machine).mode == "ActivePlusHistory"]
    library = []
    for index, machine in native_only:
        poll = machine.poll
        flags = [name for name, on in (("work_offsets", bool(poll.work_offsets)), ("modal", poll.modal),
                                       ("tool_number", poll.tool_number)) if on]
        if flags:
            library.append(
                f"machines[{index}] ({machine.id}): poll {', '.join(flags)} on the native transport alone: "
                f"no public wire code exists for them, so they will NOT be published (Plan/DroppedFunctions "
                f"lists them). Add fwlib_host: (a focas-edge fwlib-host, docs/install.md)")
    return history + library


def _mqtt_cross_checks(data: dict[str, Any]) -> Iterator[str]:
    """The mqtt rules re-checked on the raw data: pydantic skips model validators when any field of the
    section is invalid, and a bad file must show every problem at once."""
    mqtt = data.get("mqtt")
    if not isinstance(mqtt, dict):
        return
    for key, message in _mqtt_rules(mqtt.get("formats", list(FORMATS)), mqtt.get("sparkplug"),
                                    mqtt.get("password_env"), mqtt.get("password_file"), mqtt.get("username")):
        yield f"mqtt.{key}: {message}"


def _machine_cross_checks(data: dict[str, Any]) -> Iterator[str]:
    """The endpoint rules re-checked on the raw data, for the same reason as _mqtt_cross_checks."""
    machines = data.get("machines")
    for index, machine in enumerate(machines if isinstance(machines, list) else []):
        if isinstance(machine, dict):
            for key, message in _endpoint_rules(machine.get("transport", "focas"), machine.get("host"),
                                                machine.get("address"), machine.get("max_subpackets"),
                                                machine.get("fwlib_host"), machine.get("paths", 1)):
                yield f"machines[{index}].{key}: {message}"


def _secret_problems(data: dict[str, Any], environ: Mapping[str, str], secrets: bool = True) -> list[str]:
    """The password cannot be had (read from the raw data, so it shows beside schema errors)."""
    mqtt = data.get("mqtt")
    if not secrets or not isinstance(mqtt, dict):
        return []
    try:
        read_secret(mqtt.get("password_env"), mqtt.get("password_file"), environ)
    except ConfigError as exc:
        return exc.problems
    return []
