"""A first config written from what the machines themselves answered (`focas-edge init`).

Each CNC is probed read-only (edge.focas.probe: one request per function, nothing written), and its poll plan
keeps only what that control answered with data: the position kinds, the part count (parameter 6711),
the probe's macro range, PMC F-area bytes and machine-position diagnosis. The status period is the
shortest of 0.5/1/2/5 s at which the status group, timed as the daemon sends it (one batched request,
edge.cli.init), takes at most a fifth of it, so a slow link or a busy control is not polled harder than
it can answer. The probe's own round trips are one request per function: summed, they would charge a
control on a 30 ms link nine round trips for what the daemon asks in one. Writes are off. The file is
commented so that an integration engineer can see what was found and where to go on from there.
"""

from __future__ import annotations

import json
import re
from dataclasses import dataclass

from edge.focas.connect import parse_address
from edge.focas.items import POSITION_KINDS
from edge.focas.probe import PROBE_DIAG, PROBE_MACROS, PROBE_PARAM, PROBE_PMC, ProbeReport

STATUS_PERIODS_S = (0.5, 1.0, 2.0, 5.0)
STATUS_SHARE = 0.2  # the status group's batch may take at most this share of its period
STATUS_FUNCTIONS = ("ReadStatus", "ReadAlarmStatus", "ReadProgramNumber", "ReadSequenceNumber", "ReadFeed",
                    "ReadSpindleSpeed", "ReadSpindleLoad")
WANTED_POSITIONS = ("absolute", "machine")  # more kinds are one line away; these two are what most plants chart


@dataclass(frozen=True)
class ProbedMachine:
    """One machine to write: its id, where it is, and what its probe found."""

    id: str
    host: str
    port: int
    transport: str
    report: ProbeReport
    status_batch_ms: float | None = None  # the status group sent as one batch, as the daemon sends it


def machine_id_for(address: str) -> str:
    """A Sparkplug-safe id from an address: 10.0.3.11 -> cnc-10-0-3-11 (the port is kept when given)."""
    return "cnc-" + re.sub(r"[^A-Za-z0-9]+", "-", address.removeprefix("tcp:")).strip("-")


def status_period_s(report: ProbeReport, batch_ms: float | None = None) -> float:
    """The shortest candidate period the status group's batch fits in (STATUS_SHARE of it); without a timed
    batch (it failed), the probe's round trips summed: an over-estimate, so never a period too short."""
    if batch_ms is not None:
        spent_s = batch_ms / 1000
    else:
        spent_s = sum((step.rtt_ms or 0.0) for step in report.steps
                      if step.function in STATUS_FUNCTIONS or step.function == "ReadPositions") / 1000
    for period in STATUS_PERIODS_S:
        if spent_s <= period * STATUS_SHARE:
            return period
    return STATUS_PERIODS_S[-1]


def _answered(report: ProbeReport, function: str, arguments: str | None = None) -> bool:
    return any(step.works for step in report.steps
               if step.function == function and (arguments is None or step.arguments == arguments))


def poll_lines(report: ProbeReport, batch_ms: float | None = None) -> list[str]:
    """The machine's `poll:` block (indented for a list entry), from what the probe saw work."""
    positions = [kind for kind in POSITION_KINDS
                 if kind in WANTED_POSITIONS and _answered(report, "ReadPositions", kind)]
    part_count = _answered(report, "ReadParams", f"{PROBE_PARAM} axis 0")
    measured = (f"one status batch took {batch_ms:.1f} ms" if batch_ms is not None
                else "the status reads' round trips, summed (the batch could not be timed)")
    lines = ["    poll:",
             f"      periods: {{status: {status_period_s(report, batch_ms):g}s}}   # measured: {measured}",
             f"      positions: [{', '.join(positions)}]"
             + ("" if len(positions) == len(WANTED_POSITIONS) else "   # only these answered"),
             f"      part_count: {'true' if part_count else 'false'}"
             + ("" if part_count else f"   # parameter {PROBE_PARAM} did not answer")]
    first, last = PROBE_MACROS
    if _answered(report, "ReadMacros"):
        lines.append(f"      macros: [\"{first}-{last}\"]   # these answered; list the ones your programs use")
    else:
        lines.append(f"      # macros: #{first}..#{last} did not answer (custom macro option?)")
    area, start, end = PROBE_PMC
    if _answered(report, "ReadPmc"):
        lines.append(f"      pmc: [{{range: {area}{start}-{area}{end}}}]   # CNC->PMC signals; add your ladder's "
                     "R/D addresses")
    else:
        lines.append(f"      # pmc: {area}{start}..{area}{end} did not answer")
    if _answered(report, "ReadDiag"):
        lines.append(f"      diags: [{{number: {PROBE_DIAG}, axis: 1}}]")
    return lines


def _quoted(text: str) -> str:
    """A YAML double-quoted scalar (JSON strings are valid YAML)."""
    return json.dumps(text)


def render_config(machines: list[ProbedMachine], unreachable: list[tuple[str, str]], broker_host: str,
                  broker_port: int, group_id: str, edge_node_id: str,
                  not_focas: list[tuple[str, str]] | None = None) -> str:
    """The commented YAML for the probed machines; unreachable ones (address, reason) are listed as comments,
    and so are addresses where something else answered (address, what answered): a wrong port, say."""
    out = [
        "# focas-edge config written by `focas-edge init` from what each CNC answered to a read-only probe.",
        "# Check it with `focas-edge check-config FILE`; reference: docs/config.md.",
        f"# Status periods: the shortest of {', '.join(f'{p:g}s' for p in STATUS_PERIODS_S)} at which the status "
        f"group, sent as one batch as the daemon sends it, takes at most {STATUS_SHARE:.0%} of the period.",
        "",
        "mqtt:",
        f"  host: {_quoted(broker_host)}",
        f"  port: {broker_port}",
        "  formats: [sparkplug, json]",
        f"  sparkplug: {{group_id: {_quoted(group_id)}, edge_node_id: {_quoted(edge_node_id)}}}",
        "  # username: edge",
        "  # password_file: /run/credentials/focas-edge.service/mqtt-password",
        "",
        "writes:",
        "  enabled: false   # nothing is written to a CNC until this is on and targets are allowed (docs/writes.md)",
        "",
        "defaults:          # every machine below inherits these; a machine's own keys win (docs/config.md)",
        "  timezone: UTC    # the zone the CNC clocks are set in, e.g. Europe/Berlin",
        "  poll:",
        "    periods: {macros: 1s, pmc: 1s, params: 60s, diags: 60s}",
        "",
        "machines:",
    ]
    for machine in machines:
        info = machine.report.sysinfo
        works = sum(1 for step in machine.report.steps if step.works)
        out.append(f"  # {machine.host}:{machine.port}: {machine.report.model or 'unknown model'}"
                   + (f", series {info.series} version {info.version}, {info.axes} axes" if info else "")
                   + f"; {works} of {len(machine.report.steps)} read functions answered")
        out.append(f"  - id: {_quoted(machine.id)}")
        out.append(f"    host: {_quoted(machine.host)}")
        out.append(f"    port: {machine.port}")
        if machine.transport != "focas":
            out.append(f"    transport: {machine.transport}")
        if machine.report.model:
            out.append(f"    series: {_quoted(machine.report.model)}")
        if machine.report.paths > 1:
            out.append(f"    paths: {machine.report.paths}    # each path beyond the first is a device of its own")
        out.extend(poll_lines(machine.report, machine.status_batch_ms))
    for address, reason in unreachable:
        where = parse_address(address)
        out.append(f"  # NOT REACHED {address}: {reason}")
        out.append(f"  # - {{id: {machine_id_for(address)}, host: {where.host}, port: {where.port}}}")
    for address, what in not_focas or []:
        out.append(f"  # {address} answered but not FOCAS: {what}")
    return "\n".join(out) + "\n"
