"""Line numbers for config problems: `machines[1].poll.pmc[0].range: ... (line 14)`.

Problems are found on the parsed data and named by their path in it; this maps each path back to the
line of the key (or list entry) in the YAML text, so a 40-machine file needs no counting by hand. A path
that does not exist in the file (a missing key) gets the line of the nearest entry that does.
"""

from __future__ import annotations

import re

import yaml

Path = tuple[str | int, ...]
_PART_RE = re.compile(r"\[(\d+)\]|([^.\[\]]+)")


def line_map(text: str) -> dict[Path, int]:
    """Path -> 1-based line of every mapping key and sequence entry in the YAML text ({} if unparsable)."""
    try:
        root = yaml.compose(text, Loader=yaml.SafeLoader)
    except yaml.YAMLError:
        return {}
    lines: dict[Path, int] = {}

    def walk(node: yaml.Node, path: Path) -> None:
        if isinstance(node, yaml.MappingNode):
            for key, value in node.value:
                if isinstance(key, yaml.ScalarNode):
                    lines[(*path, key.value)] = key.start_mark.line + 1
                    walk(value, (*path, key.value))
        elif isinstance(node, yaml.SequenceNode):
            for index, item in enumerate(node.value):
                lines[(*path, index)] = item.start_mark.line + 1
                walk(item, (*path, index))

    if root is not None:
        walk(root, ())
    return lines


def parse_path(text: str) -> Path:
    """`machines[2].poll.pmc[0]` -> ('machines', 2, 'poll', 'pmc', 0)."""
    return tuple(int(index) if index else name for index, name in _PART_RE.findall(text))


def line_of(path: Path, lines: dict[Path, int]) -> int | None:
    """The line of `path`, or of its nearest ancestor found in the file."""
    for end in range(len(path), 0, -1):
        line = lines.get(path[:end])
        if line is not None:
            return line
    return None


def with_lines(problems: list[str], text: str) -> list[str]:
    """Each 'path: message' problem with ' (line N)' appended where the path is found in the text."""
    lines = line_map(text)
    out = []
    for problem in problems:
        path, sep, _ = problem.partition(": ")
        line = line_of(parse_path(path), lines) if sep and " " not in path else None
        out.append(problem if line is None else f"{problem} (line {line})")
    return out
