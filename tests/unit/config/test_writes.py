"""`writes:`: the global policy plus each machine's own, and bad rules."""

from __future__ import annotations

from tests.unit.config.minimal import MINIMAL, parse, problems_of


def test_writes_policy_global_plus_machine() -> None:
    config = parse("""
        mqtt: {host: b, formats: [json]}
        writes:
          enabled: true
          allow: [{target: "macro:500-599", min: 0, max: 10}]
          rate_limit: {max_writes: 5, per_s: 1m}
        machines:
          - {id: a, host: h, writes: {allow: [{target: "pmc:R100-R199"}], rate_limit: {max_writes: 1, per_s: 1}}}
          - {id: b, host: h, writes: {enabled: false}}
          - {id: c, host: h}
    """)
    a, b, c = (config.write_policy(m) for m in config.machines)
    assert a.enabled and [r.target for r in a.allow] == ["macro:500-599", "pmc:R100-R199"]
    assert a.rate_limit.max_writes == 1 and c.rate_limit.per_s == 60.0
    assert not b.enabled and c.enabled
    assert a.reconnect_deadline_s == 10.0 and a.max_payload_bytes == 4096
    off = parse(MINIMAL + "writes: {allow: [{target: 'macro:500'}]}\n")
    assert not off.write_policy(off.machines[0]).enabled


def test_writes_errors() -> None:
    problems = problems_of(MINIMAL + """writes:
  allow:
    - {target: "diag:980"}
    - {target: "macro:1", min: 5, max: 1}
    - {target: "pmc:Q1"}
  rate_limit: {max_writes: 0}
""")
    assert any(p.startswith("writes.allow[0].target: 'diag:980': diag:980 is read-only") for p in problems)
    assert "writes.allow[1].max: max 1.0 below min 5.0 (line 11)" in problems
    assert any(p.startswith("writes.allow[2].target: 'pmc:Q1': unknown PMC area") for p in problems)
    assert any(p.startswith("writes.rate_limit.max_writes: ") for p in problems)
