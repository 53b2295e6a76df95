"""Writing learned blocks as native configuration text a person can read and edit.

Each learned part of the file sits between two marker comments::

    # >>> learned topic /signal >>>
    ...
    # <<< learned topic /signal <<<

``blackbox learn --update`` rewrites what is between the markers and nothing else. Entries
are written one key per line with small nested values in flow style, so a state or a filter
reads as one line.
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from typing import Any

import yaml

from blackbox.learn.model import Block, Learned

START = "# >>> learned {id} >>>"
END = "# <<< learned {id} <<<"
SUMMARY_ID = "summary"
LINE = 120
"""A state longer than this is written one check per line."""
MODEL_ID = "diagnosis model"


def _plain(value: Any) -> Any:
    """Large whole floats (memory bounds in bytes) as integers, for the reader."""
    if isinstance(value, float) and abs(value) >= 1e4 and value.is_integer():
        return int(value)
    if isinstance(value, dict):
        return {k: _plain(v) for k, v in value.items()}
    if isinstance(value, list):
        return [_plain(v) for v in value]
    return value


def flow(value: Any) -> str:
    """``value`` as one line of YAML flow style."""
    value = _plain(value)
    text = str(yaml.safe_dump(value, default_flow_style=True, width=1 << 30,
                              sort_keys=False)).strip()
    if text.endswith("\n..."):
        text = text[:-4].strip()
    return text.removesuffix("...").strip()


def entry_lines(entry: dict[str, Any], indent: str = "  ") -> list[str]:
    """One observer entry as a YAML list item."""
    lines: list[str] = []
    first = True
    for key, value in entry.items():
        if key == "publishers" and not value:
            continue
        lead = f"{indent}- " if first else f"{indent}  "
        first = False
        if isinstance(value, list) and value and all(isinstance(v, dict) for v in value):
            lines.append(f"{lead}{key}:")
            for item in value:
                one = f"{indent}    - {flow(item)}"
                if len(one) <= LINE or key != "states":
                    lines.append(one)
                    continue
                for n, (k, v) in enumerate(item.items()):  # a long state: one check a line
                    lines.append(f"{indent}    {'- ' if n == 0 else '  '}{k}: {flow(v)}")
        else:
            lines.append(f"{lead}{key}: {flow(value)}")
    return lines


def comment_lines(texts: Iterable[str], indent: str, width: int = 96) -> list[str]:
    out: list[str] = []
    for text in texts:
        words = text.split()
        line = ""
        for w in words:
            if line and len(indent) + 2 + len(line) + 1 + len(w) > width:
                out.append(f"{indent}# {line}")
                line = "  " + w
            else:
                line = f"{line} {w}" if line else w
        if line:
            out.append(f"{indent}# {line}")
    return out


def block_text(block: Block, indent: str = "  ", extra: Sequence[str] = ()) -> str:
    lines = [f"{indent}{START.format(id=block.id)}"]
    lines += comment_lines(block.comments, indent)
    lines += comment_lines((f"could not learn: {n}" for n in block.notes), indent)
    lines += comment_lines(extra, indent)
    for entry in block.entries:
        lines += entry_lines(entry, indent)
    lines.append(f"{indent}{END.format(id=block.id)}")
    return "\n".join(lines) + "\n"


def summary_text(learned: Learned, when: str, extra: Sequence[str] = ()) -> str:
    observers = sum(len(b.entries) for b in learned.blocks)
    lines = [START.format(id=SUMMARY_ID),
             "# Learned by `blackbox learn` from a healthy run (rules: docs/learn.md)",
             f"#   source {learned.source}, {learned.duration:.0f} s, {when}; "
             f"{len(learned.nodes)} nodes, {len(learned.topics)} topics, "
             f"{observers} observers",
             "# `blackbox learn --update` rewrites the blocks between '# >>> learned' and",
             "# '# <<< learned' markers and keeps everything else; to keep an edit of a",
             "# learned entry, move the entry out of its block."]
    notes = [*learned.notes, *extra]
    if notes:
        lines.append("# Could not learn:")
        lines += comment_lines((f"- {n}" for n in notes), "#  ")
    lines.append(END.format(id=SUMMARY_ID))
    return "\n".join(lines).replace("#  # ", "#   ") + "\n"


def model_block_text(model_file: str, learned: Learned, indent: str = "  ") -> str:
    topics = {t for pub, sub in learned.graph.values() for t in (*pub, *sub)}
    return "\n".join([
        f"{indent}{START.format(id=MODEL_ID)}",
        f"{indent}# the graph seen while learning ({len(learned.graph)} nodes, {len(topics)} "
        f"topics): who publishes and subscribes what",
        f"{indent}model: {flow(model_file)}",
        f"{indent}{END.format(id=MODEL_ID)}"]) + "\n"


def render_config(learned: Learned, robot_id: str, model_file: str, when: str) -> str:
    """A complete native configuration file for ``learned``."""
    parts = [summary_text(learned, when), "version: 1\n",
             f"robot:\n  id: {flow(robot_id)}\n"]
    if learned.graph:
        parts.append("diagnosis:\n" + model_block_text(model_file, learned))
    parts.append("observers:\n")
    for block in learned.blocks:
        parts.append(block_text(block))
    return "".join(parts)


def render_model(learned: Learned, when: str) -> str:
    """The graph as a tug_diagnosis model file (``nodes`` with ``pub_topic``/``sub_topic``)."""
    lines = ["# Diagnosis model learned by `blackbox learn`: the robot's graph as seen while",
             f"# learning ({learned.source}, {learned.duration:.0f} s, {when}).",
             "# `blackbox learn --update` rewrites this file; point diagnosis.model at a copy",
             "# to keep hand edits. Format: docs/diagnosis.md (tug_diagnosis layout).",
             "nodes:"]
    for name, (pub, sub) in learned.graph.items():
        item = {"name": name}
        if pub:
            item["pub_topic"] = list(pub)  # type: ignore[assignment]
        if sub:
            item["sub_topic"] = list(sub)  # type: ignore[assignment]
        lines.append(f"  - {flow(item)}")
    if not learned.graph:
        lines[-1] = "nodes: []"
    lines.append("observations: []")
    return "\n".join(lines) + "\n"
