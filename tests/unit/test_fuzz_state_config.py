"""Fuzz the other inputs from outside: primary host STATE messages and config files."""

from __future__ import annotations

import json

import yaml
from hypothesis import given
from hypothesis import strategies as st

from edge import ConfigError
from edge.config import parse_config
from edge.publish.primary_host import PrimaryHost, StateVerdict

json_values = st.recursive(
    st.one_of(st.none(), st.booleans(), st.integers(), st.floats(allow_nan=False), st.text(max_size=12)),
    lambda children: st.one_of(st.lists(children, max_size=4),
                               st.dictionaries(st.text(max_size=8), children, max_size=4)),
    max_leaves=16)
state_docs = st.one_of(
    json_values,
    st.fixed_dictionaries({"online": st.one_of(st.booleans(), json_values),
                           "timestamp": st.one_of(st.integers(-(2**70), 2**70), json_values)}),
)


@given(st.lists(st.tuples(st.sampled_from(["spBv1.0/STATE/scada", "spBv1.0/STATE/other", "x"]),
                          st.one_of(state_docs.map(lambda d: json.dumps(d).encode()), st.binary(max_size=80))),
                max_size=8))
def test_fuzz_state_messages_never_raise_and_timestamps_never_go_back(
        messages: list[tuple[str, bytes]]) -> None:
    host = PrimaryHost("scada")
    accepted: list[int] = []
    for topic, payload in messages:
        verdict = host.on_state(topic, payload)
        assert isinstance(verdict, StateVerdict)
        if verdict is not StateVerdict.IGNORED:
            assert topic == "spBv1.0/STATE/scada"
            doc = json.loads(payload)
            assert isinstance(doc["online"], bool) and host.online is doc["online"]
            accepted.append(doc["timestamp"])
    assert accepted == sorted(accepted)


VALID = {
    "mqtt": {"host": "127.0.0.1", "formats": ["sparkplug", "json"],
             "sparkplug": {"group_id": "plant", "edge_node_id": "gw"}},
    "state_dir": "/tmp/focas-edge-fuzz",
    "machines": [{"id": "m1", "host": "10.0.0.1", "poll": {"macros": ["500-505"], "pmc": [{"range": "R100-R103"}]}}],
    "spool": {"max_bytes": "64MiB", "max_age_s": "1d"},
}


def _paths(doc: object, prefix: tuple[object, ...] = ()) -> list[tuple[object, ...]]:
    out = [prefix]
    if isinstance(doc, dict):
        for k, v in doc.items():
            out += _paths(v, (*prefix, k))
    elif isinstance(doc, list):
        for i, v in enumerate(doc):
            out += _paths(v, (*prefix, i))
    return out


def _replace(doc: object, path: tuple[object, ...], value: object) -> object:
    if not path:
        return value
    copy = json.loads(json.dumps(doc))
    node = copy
    for key in path[:-1]:
        node = node[key]
    node[path[-1]] = value
    return copy


@given(st.sampled_from(_paths(VALID)), json_values)
def test_fuzz_mutated_configs_load_or_list_problems(path: tuple[object, ...], value: object) -> None:
    text = yaml.safe_dump(_replace(VALID, path, value))
    try:
        parse_config(text, environ={})
    except ConfigError as exc:
        assert exc.problems and all(isinstance(p, str) and p for p in exc.problems)


@given(st.text(max_size=300))
def test_fuzz_arbitrary_text_as_config_raises_only_config_error(text: str) -> None:
    try:
        parse_config(text, environ={})
    except ConfigError as exc:
        assert exc.problems


def test_the_valid_config_is_valid() -> None:
    """Guards the mutation fuzz: mutations start from a config that loads."""
    assert parse_config(yaml.safe_dump(VALID), environ={}).machines[0].id == "m1"
