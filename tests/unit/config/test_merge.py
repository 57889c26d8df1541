"""`defaults:` and `templates:`: forty machines without forty copied poll blocks."""

from __future__ import annotations

import textwrap

import pytest

from edge import ConfigError
from edge.config import Config, parse_config
from edge.config.merge import expand_machines

FLEET = """
mqtt: {host: broker, sparkplug: {group_id: g, edge_node_id: n}}
defaults:
  timezone: Europe/Berlin
  timeouts: {request_s: 2s}
  poll:
    periods: {status: 500ms, macros: 2s}
    macros: ["500-505"]
templates:
  robodrill:
    transport: focas
    poll:
      periods: {pmc: 250ms}
      pmc: [{range: R100-R103}]
machines:
  - {id: m1, host: 10.0.0.1}
  - {id: m2, host: 10.0.0.2, template: robodrill}
  - id: m3
    host: 10.0.0.3
    template: robodrill
    timezone: UTC
    poll:
      periods: {status: 1s}
      macros: [600]
"""


def parse(text: str) -> Config:
    return parse_config(textwrap.dedent(text), "fleet.yaml", {})


def problems_of(text: str) -> list[str]:
    with pytest.raises(ConfigError) as info:
        parse(text)
    return info.value.problems


def test_machines_inherit_defaults_then_their_template_then_their_own_keys() -> None:
    m1, m2, m3 = parse(FLEET).machines
    assert m1.timezone == "Europe/Berlin" and m1.timeouts.request_s == 2.0
    assert m1.poll.periods.status == 0.5 and m1.poll.periods.pmc == 1.0  # unset keys keep the built-in default
    assert [list(r.numbers) for r in m1.poll.macros] == [[500, 501, 502, 503, 504, 505]]
    assert m1.poll.pmc == []
    # the template adds to the defaults key by key inside mappings
    assert m2.poll.periods.status == 0.5 and m2.poll.periods.macros == 2.0 and m2.poll.periods.pmc == 0.25
    assert [p.range for p in m2.poll.pmc] == ["R100-R103"] and len(m2.poll.macros) == 1
    # the machine's own keys win; a list replaces the inherited list whole
    assert m3.timezone == "UTC" and m3.poll.periods.status == 1.0 and m3.poll.periods.pmc == 0.25
    assert [list(r.numbers) for r in m3.poll.macros] == [[600]]
    assert m3.timeouts.request_s == 2.0


def test_a_file_without_defaults_or_templates_is_unchanged() -> None:
    data = {"mqtt": {"host": "b"}, "machines": [{"id": "m", "host": "h"}]}
    assert expand_machines(data) == (data, [])


def test_an_unknown_template_names_the_ones_there_are() -> None:
    text = FLEET.replace("template: robodrill}", "template: robodril}")
    assert any(p.startswith("machines[1].template: unknown template 'robodril' (defined: robodrill)")
               for p in problems_of(text))


def test_a_bad_value_in_defaults_is_reported_beside_other_problems() -> None:
    text = FLEET.replace("timezone: Europe/Berlin", "timezone: Mars/Olympus").replace("id: m3", "id: m3\n    port: 0")
    problems = problems_of(text)
    assert any(p.startswith("machines[0].timezone: unknown IANA time zone 'Mars/Olympus'") for p in problems)
    assert any(p.startswith("machines[2].port:") for p in problems)


@pytest.mark.parametrize(("section", "message"), [
    ("defaults: [a]", "defaults: expected a mapping of machine keys"),
    ("defaults: {id: x}", "defaults.id: an id belongs to one machine"),
    ("templates: {t: 3}", "templates.t: expected a mapping of machine keys"),
    ("templates: {t: {template: u}}", "templates.t.template: a template cannot name another template"),
])
def test_malformed_sections_are_refused_with_the_reason(section: str, message: str) -> None:
    text = f"mqtt: {{host: b, formats: [json]}}\n{section}\nmachines: [{{id: m, host: h}}]\n"
    assert any(p.startswith(message) for p in problems_of(text)), problems_of(text)


def test_a_machine_without_a_template_key_where_templates_exist_only_gets_defaults() -> None:
    text = FLEET.replace("defaults:\n", "defaults:\n  port: 8194\n")
    assert [m.port for m in parse(text).machines] == [8194, 8194, 8194]


def test_a_template_named_without_a_templates_section_says_so() -> None:
    text = "mqtt: {host: b, formats: [json]}\nmachines:\n  - {id: m, host: h, template: mill}\n"
    assert problems_of(text) == [
        "machines[0].template: unknown template 'mill' (defined: none: add a templates: section) (line 3)"]
