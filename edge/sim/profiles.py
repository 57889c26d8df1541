"""Control profiles of the simulated CNC: what a 0i-F, a 16i or a 30i/31i says about itself.

A profile is the part of a machine that comes from the series, not from its current state: the sysinfo
strings, the record stride (max_axis), which parameter/diagnosis command forms answer, axis and
spindle names, PMC area sizes and the header version its responses carry. Values follow
shared/docs/focas-protocol.md (§3.3-§3.5); series/version strings are plausible, not captured.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

from edge.focas.model import SysInfo

# Native command codes of the two record forms (shared/docs/focas-protocol.md §2).
NARROW_RECORD_COMMANDS = frozenset({0x0E, 0x30})  # 4-byte slots: 16i/18i/21i/0i-D style
WIDE_RECORD_COMMANDS = frozenset({0x8D, 0x93})  # 8-byte scaled slots: 30i/31i/32i/0i-F style

# PMC area sizes in bytes (addresses 0..size-1) of a PMC-SB7-class ladder (16i) ...
PMC_SIZES_16I: dict[str, int] = {
    "G": 768, "F": 768, "Y": 128, "X": 128, "A": 125, "R": 8000,
    "T": 300, "K": 1000, "C": 200, "D": 10000, "E": 8000,
}
# ... and of a 30i-B / 0i-F PMC (first PMC path).
PMC_SIZES_30I: dict[str, int] = {
    "G": 1024, "F": 1024, "Y": 128, "X": 128, "A": 250, "R": 8000,
    "T": 500, "K": 1000, "C": 400, "D": 10000, "E": 10000,
}


@dataclass(frozen=True, slots=True)
class Profile:
    """Everything series-specific about a simulated control."""

    name: str
    sysinfo: SysInfo
    axis_names: tuple[str, ...]
    spindle_names: tuple[str, ...]
    response_version: int  # header "version" word of responses: 2, 3 or 4
    pmc_sizes: dict[str, int] = field(default_factory=lambda: dict(PMC_SIZES_30I))
    pmc_float_types: bool = True  # PMC data types 4/5 (float/double) exist on 30i-B/0i-F only
    timer_little_endian: bool = False  # a 31i-B sends cnc_rdtimer's payload little-endian (LMX 5f0a528)
    paths: int = 1  # CNC paths (a twin-turret lathe has 2); requests for a path beyond answer EW_PATH
    summary: str = ""  # one line for `focas-edge sim --help`: what real control this stands for

    @property
    def wide_records(self) -> bool:
        """True when parameters/diagnoses answer as 8-byte scaled slots (0x8d/0x93)."""
        return self.sysinfo.max_axis > 8

    @property
    def record_commands(self) -> frozenset[int]:
        """The parameter/diagnosis command codes this control answers."""
        return WIDE_RECORD_COMMANDS if self.wide_records else NARROW_RECORD_COMMANDS

    @property
    def refused_commands(self) -> frozenset[int]:
        """The command codes of the other record form: these answer EW_FUNC on this control."""
        return NARROW_RECORD_COMMANDS if self.wide_records else WIDE_RECORD_COMMANDS

    @property
    def axis_count(self) -> int:
        return len(self.axis_names)


def _sysinfo(addinfo: int, max_axis: int, cnc_type: str, mt_type: str, series: str, version: str,
             axes: int) -> SysInfo:
    return SysInfo(addinfo=addinfo, max_axis=max_axis, cnc_type=cnc_type, mt_type=mt_type,
                   series=series, version=version, axes=f"{axes:02d}")


# addinfo: high byte = model letter (1 A, 2 B, 3 C, 4 D, 6 F), low byte bit 1 = "i" series.
PROFILES: dict[str, Profile] = {
    "0i-F": Profile(
        name="0i-F",
        sysinfo=_sysinfo(0x0602, 32, " 0", " M", "D4F1", "30.0", 4),
        axis_names=("X", "Y", "Z", "A"),
        spindle_names=("S1",),
        response_version=4,
        summary="0i-F machining centre: 4 axes, 1 spindle, 32-axis series, version-4 responses",
    ),
    "16i": Profile(
        name="16i",
        sysinfo=_sysinfo(0x0202, 8, "16", " M", "B0H1", "0020", 4),
        axis_names=("X", "Y", "Z", "B"),
        spindle_names=("S1",),
        response_version=2,
        pmc_sizes=dict(PMC_SIZES_16I),
        pmc_float_types=False,
        summary="16i-B machining centre: 4 axes, 1 spindle, narrow (8-axis) records, no float PMC types",
    ),
    "30i": Profile(
        name="30i",
        sysinfo=_sysinfo(0x0202, 32, "30", " M", "G004", "21.0", 5),
        axis_names=("X", "Y", "Z", "A", "C"),
        spindle_names=("S1", "S2"),
        response_version=4,
        summary="30i-B machining centre: 5 axes, 2 spindles, version-4 responses",
    ),
    "31i": Profile(
        name="31i",
        sysinfo=_sysinfo(0x0202, 32, "31", " T", "G42A", "20.0", 3),
        axis_names=("X", "Z", "C"),
        spindle_names=("S1", "S2"),
        response_version=3,
        timer_little_endian=True,
        summary="31i-B lathe: 3 axes, 2 spindles, little-endian timers (as a real 31i-B answers)",
    ),
}
# A twin-turret lathe: a 31i whose second path runs its own program.
PROFILES["31i-2p"] = replace(PROFILES["31i"], name="31i-2p", paths=2,
                             summary="31i-B twin-turret lathe: the 31i with 2 paths, each its own program")
PROFILE_ALIASES = {"0i": "0i-F", "0if": "0i-F", "16": "16i", "30": "30i", "31": "31i", "31i-b": "31i"}


def profile_lines() -> list[str]:
    """One line per profile (name and what it stands for), for help texts."""
    width = max(len(name) for name in PROFILES)
    return [f"{name:<{width}}  {profile.summary}" for name, profile in PROFILES.items()]


def get_profile(name: str) -> Profile:
    """The profile called `name` (case-insensitive, a few aliases); ValueError lists the known ones."""
    key = name.strip()
    for candidate in (key, PROFILE_ALIASES.get(key.lower(), "")):
        for known, profile in PROFILES.items():
            if candidate.lower() == known.lower():
                return profile
    raise ValueError(f"unknown CNC profile {name!r}: expected one of {', '.join(PROFILES)}")
