"""`defaults:` and `templates:` expanded into each machine before the config is validated.

A machine's effective settings are three layers merged in order, later winning:
  1. `defaults:` (every machine),
  2. the template the machine names with `template: NAME` (from `templates:`),
  3. the machine's own keys.
Mappings merge key by key at every depth (`poll.periods.status` in a machine keeps the template's
`poll.periods.pmc`); anything else, lists included, is replaced whole (a machine's `poll.pmc` list is
its whole PMC list, not an addition to the template's). docs/config.md states the same rules.
"""

from __future__ import annotations

from typing import Any

TEMPLATE_KEY = "template"


def deep_merge(base: dict[str, Any], override: dict[str, Any]) -> dict[str, Any]:
    """`override` on top of `base`: mappings merged recursively, every other value replaced."""
    merged = dict(base)
    for key, value in override.items():
        below = merged.get(key)
        merged[key] = deep_merge(below, value) if isinstance(below, dict) and isinstance(value, dict) else value
    return merged


def expand_machines(data: dict[str, Any]) -> tuple[dict[str, Any], list[str]]:
    """The config data with `defaults`/`templates` applied to every machine and removed, and the problems
    found in those sections ('path: message'); data without them is returned as it is."""
    machines = data.get("machines")
    names_a_template = isinstance(machines, list) and any(isinstance(m, dict) and TEMPLATE_KEY in m for m in machines)
    if "defaults" not in data and "templates" not in data and not names_a_template:
        return data, []
    problems: list[str] = []
    defaults = _layer(data.get("defaults", {}), "defaults", problems)
    raw_templates = data.get("templates", {})
    templates: dict[str, dict[str, Any]] = {}
    if isinstance(raw_templates, dict):
        for name, body in raw_templates.items():
            templates[str(name)] = _layer(body, f"templates.{name}", problems)
    else:
        problems.append("templates: expected a mapping of template names to machine keys")
    expanded = {key: value for key, value in data.items() if key not in ("defaults", "templates")}
    if isinstance(machines, list):
        expanded["machines"] = [_machine(m, i, defaults, templates, problems) for i, m in enumerate(machines)]
    return expanded, problems


def _layer(body: object, path: str, problems: list[str]) -> dict[str, Any]:
    """A defaults or template body, checked for the keys that cannot be shared."""
    if not isinstance(body, dict):
        problems.append(f"{path}: expected a mapping of machine keys, got {type(body).__name__}")
        return {}
    if "id" in body:
        problems.append(f"{path}.id: an id belongs to one machine; set it on each machine")
    if TEMPLATE_KEY in body:
        what = "a template cannot name another template" if path.startswith("templates.") else \
            "defaults cannot name a template; set template: on the machines"
        problems.append(f"{path}.{TEMPLATE_KEY}: {what}")
    return {key: value for key, value in body.items() if key not in ("id", TEMPLATE_KEY)}


def _machine(machine: object, index: int, defaults: dict[str, Any], templates: dict[str, dict[str, Any]],
             problems: list[str]) -> object:
    if not isinstance(machine, dict):
        return machine  # the schema reports it
    own = dict(machine)
    name = own.pop(TEMPLATE_KEY, None)
    layers = defaults
    if name is not None:
        template = templates.get(str(name))
        if template is None:
            defined = ", ".join(sorted(templates)) or "none: add a templates: section"
            problems.append(f"machines[{index}].{TEMPLATE_KEY}: unknown template {name!r} (defined: {defined})")
        else:
            layers = deep_merge(defaults, template)
    return deep_merge(layers, own)
