"""``blackbox learn --update``: refine an existing configuration with a new healthy run.

The file is split at its learned-block markers. Text outside the blocks (hand-written
observers, sections, comments) is kept byte for byte. Each learned block is replaced by the
block learned now, *merged* with what the block held before, so a second healthy run in
another operating mode widens the nominal model instead of replacing it: lower bounds and
``greater_than`` take the smaller value, upper bounds, ``less_than``, time-outs and windows
the larger, and quantities or states only one of the two knows are kept. A block the new
run did not produce (a topic that was silent this time) is kept as it was, with a note.
A learned entry whose observer type and resource a hand-written entry outside the blocks
already covers is left out, so a hand edit wins. The result is loaded and built before it is
written; if it would not load, nothing is written.
"""

from __future__ import annotations

import re
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from blackbox.config.node import ConfigError, ConfigNode
from blackbox.learn.model import Block, Learned
from blackbox.learn.render import (
    MODEL_ID,
    SUMMARY_ID,
    block_text,
    model_block_text,
    summary_text,
)
from blackbox.observe.build import build_observers, load_config_text

_START = re.compile(r"^(\s*)# >>> learned (.+?) >>>\s*$")
_END = re.compile(r"^\s*# <<< learned (.+?) <<<\s*$")
_LOWER_KEYS = frozenset({"lower_bound", "greater_than"})
_UPPER_KEYS = frozenset({"upper_bound", "less_than", "timeout", "window_size",
                         "block_noise", "h", "repeats", "std", "fresh", "delay",
                         "at_most", "cap"})
_LIST_KEYS = {"fields": "name", "states": "number", "relations": "name", "signals": "name"}
_SPAN_KEYS = frozenset({"span"})

Key = tuple[str, str, tuple[str, ...]]


@dataclass(frozen=True, slots=True)
class Segment:
    text: str
    block: str | None = None
    """The block id, ``None`` for text outside blocks."""
    first_line: int = 0
    last_line: int = 0


def split_blocks(text: str, file: str) -> list[Segment]:
    """The file as text and learned blocks; an unbalanced marker is a ConfigError."""
    segments: list[Segment] = []
    outside: list[str] = []
    inside: list[str] = []
    current: str | None = None
    start_line = 0
    for number, line in enumerate(text.splitlines(keepends=True), start=1):
        start, end = _START.match(line), _END.match(line)
        if current is None:
            if end:
                raise ConfigError(f"'# <<< learned {end.group(1)} <<<' closes "
                                  "no block", file, number)
            if start:
                if outside:
                    segments.append(Segment("".join(outside)))
                outside = []
                current, start_line, inside = start.group(2), number, [line]
            else:
                outside.append(line)
            continue
        inside.append(line)
        if start:
            raise ConfigError(f"block 'learned {start.group(2)}' starts inside block "
                              f"'learned {current}' (opened on line {start_line})", file, number)
        if end:
            if end.group(1) != current:
                raise ConfigError(f"'# <<< learned {end.group(1)} <<<' closes block "
                                  f"'learned {current}' (opened on line {start_line})",
                                  file, number)
            segments.append(Segment("".join(inside), current, start_line, number))
            current = None
    if current is not None:
        raise ConfigError(f"block 'learned {current}' is never closed", file, start_line)
    if outside:
        segments.append(Segment("".join(outside)))
    return segments


def entry_key(entry: Mapping[str, Any]) -> Key:
    resource = str(entry.get("topic") or entry.get("node") or entry.get("topic_a")
                   or entry.get("interface") or "")
    publishers = tuple(entry.get("publishers") or ())
    return (str(entry.get("type")), resource, publishers)


def merge_values(old: Any, new: Any, key: str = "") -> Any:
    """``new`` widened by ``old`` (module docstring). For learned relations and liveness:
    residual noise, thresholds and spans widen, and an operating mode only one run saw
    (``still``: standing, judged with its own noise) is kept, so ``--update`` with a run in
    another mode adds that mode."""
    if new is None and old is not None:
        return old
    if isinstance(old, bool) or isinstance(new, bool):
        return new
    if key in _SPAN_KEYS and isinstance(old, list) and isinstance(new, list) \
            and len(old) == len(new) == 2:
        return [min(old[0], new[0]), max(old[1], new[1])]
    if isinstance(old, (int, float)) and isinstance(new, (int, float)):
        if key in _LOWER_KEYS:
            return min(old, new)
        if key in _UPPER_KEYS:
            return max(old, new)
        return new
    if isinstance(old, dict) and isinstance(new, dict):
        if old.get("type") != new.get("type") and "type" in old and "type" in new:
            return new
        out = dict(new)
        for k, v in old.items():
            out[k] = merge_values(v, new[k], k) if k in new else v
        return out
    if isinstance(old, list) and isinstance(new, list) and key == "deviation" \
            and len(old) == len(new):
        return [merge_values(o, n) for o, n in zip(old, new, strict=True)]
    if isinstance(old, list) and isinstance(new, list) and key in _LIST_KEYS:
        ident = _LIST_KEYS[key]
        old_by = {item.get(ident): item for item in old if isinstance(item, dict)}
        merged = [merge_values(old_by[item.get(ident)], item, key + "[]")
                  if isinstance(item, dict) and item.get(ident) in old_by else item
                  for item in new]
        seen = {item.get(ident) for item in new if isinstance(item, dict)}
        merged += [item for item in old if isinstance(item, dict) and item.get(ident) not in seen]
        return merged
    return new


def _entries_by_block(root: ConfigNode, segments: Sequence[Segment]
                      ) -> tuple[dict[str, list[dict[str, Any]]], set[Key], list[str]]:
    spans = [(s.first_line, s.last_line, s.block) for s in segments if s.block is not None]
    learned: dict[str, list[dict[str, Any]]] = {}
    hand: set[Key] = set()
    top = list(root.keys())
    observers = root.get("observers")
    for entry in observers.list() if observers is not None and observers.is_list else []:
        python = entry.to_python()
        block = next((b for a, z, b in spans if a <= entry.line <= z), None)
        if block is None:
            hand.add(entry_key(python))
        else:
            learned.setdefault(block, []).append(python)
    return learned, hand, top


def _without_hand(block: Block, hand: set[Key], old: Sequence[dict[str, Any]]) -> tuple[
        Block, list[str]]:
    old_by = {entry_key(e): e for e in old}
    kept: list[dict[str, Any]] = []
    said: list[str] = []
    for entry in block.entries:
        key = entry_key(entry)
        if key in hand:
            said.append(f"a hand-written {key[0]} observer of {key[1]} outside this block is "
                        "kept instead of the learned one")
            continue
        kept.append(merge_values(old_by[key], entry) if key in old_by else entry)
    new_keys = {entry_key(e) for e in block.entries}
    for key, entry in old_by.items():
        if key not in new_keys and key not in hand:
            kept.append(entry)
            said.append(f"{key[0]} observer of {key[1]} kept from the earlier run")
    if old_by:
        said.append("bounds merged with the earlier learned ones (widened, never narrowed)")
    return Block(block.id, block.comments, kept, block.notes), said


def _unseen_block_text(seg: Segment, indent: str, entries: Sequence[dict[str, Any]],
                       hand: set[Key], when: str) -> str:
    """A block the update run did not produce, kept as it was with a note; its entries a
    hand-written one now covers are left out (two would share one identity)."""
    note = f"not seen in the update run ({when}); kept as it was"
    assert seg.block is not None
    if any(entry_key(e) in hand for e in entries):
        _, said = _without_hand(Block(seg.block, entries=list(entries)), hand, [])
        return block_text(Block(seg.block, entries=[e for e in entries
                                                     if entry_key(e) not in hand]),
                          indent, [note, *said])
    lines = seg.text.splitlines(keepends=True)
    return "".join([lines[0], f"{indent}# {note}\n",
                    *[ln for ln in lines[1:] if "not seen in the update run" not in ln]])


def update_config(old_text: str, file: str, learned: Learned, model_file: str,
                  when: str) -> str:
    """The text of ``file`` (``old_text``) refined by ``learned``; raises ConfigError when
    the file does not load now or the result would not."""
    segments = split_blocks(old_text, file)
    config = load_config_text(old_text, file)  # the file must load before we touch it
    if config.format != "native":
        raise ConfigError("--update works on native configuration files; this one is in "
                          "the tug_observers format (convert it, or learn into a new file)", file)
    root = ConfigNode.parse(old_text, file)
    old_entries, hand, top = _entries_by_block(root, segments)
    new_blocks = {b.id: b for b in learned.blocks}
    pieces: list[str] = []
    done: set[str] = set()
    extra_notes: list[str] = []
    last_observer_piece = -1
    for seg in segments:
        if seg.block is None:
            pieces.append(seg.text)
            continue
        indent = _START.match(seg.text.splitlines()[0]).group(1)  # type: ignore[union-attr]
        if seg.block == SUMMARY_ID:
            pieces.append("\0summary\0")
        elif seg.block == MODEL_ID:
            pieces.append(model_block_text(model_file, learned, indent) if learned.graph
                          else seg.text)
        elif seg.block in new_blocks:
            merged, said = _without_hand(new_blocks[seg.block], hand,
                                         old_entries.get(seg.block, []))
            pieces.append(block_text(merged, indent, said))
            last_observer_piece = len(pieces) - 1
        else:
            pieces.append(_unseen_block_text(seg, indent, old_entries.get(seg.block, []),
                                             hand, when))
            last_observer_piece = len(pieces) - 1
        done.add(seg.block)
    added = []
    for block in learned.blocks:
        if block.id in done:
            continue
        merged, said = _without_hand(block, hand, [])
        added.append(block_text(merged, "  ", said))
    if added:
        if last_observer_piece >= 0:
            pieces.insert(last_observer_piece + 1, "".join(added))
        elif "observers" not in top:
            pieces.append(("" if "".join(pieces).endswith("\n") else "\n") + "observers:\n"
                          + "".join(added))
        elif top[-1] == "observers" and not root["observers"].is_null \
                and root["observers"].is_list and _block_style_list(old_text, root):
            pieces.append(("" if "".join(pieces).endswith("\n") else "\n") + "".join(added))
        else:
            raise ConfigError("cannot add learned observers: put 'observers:' last in the file "
                              "as a block list ('- type: ...' lines)", file,
                              root["observers"].line)
    if MODEL_ID not in done and learned.graph:
        if "diagnosis" in top:
            extra_notes.append(f"the hand-written diagnosis section is kept; the learned "
                               f"model {model_file} is not referenced from it")
        else:
            section = "diagnosis:\n" + model_block_text(model_file, learned)
            at = _line_index_of_top_key(pieces, "observers")
            pieces.insert(at, section) if at is not None else pieces.append(section)
    summary = summary_text(learned, when, extra_notes)
    text = "".join(pieces)
    text = text.replace("\0summary\0", summary) if "\0summary\0" in text else summary + text
    check = load_config_text(text, file)
    build_observers(check)
    return text


def _block_style_list(text: str, root: ConfigNode) -> bool:
    line = text.splitlines()[root["observers"].line - 1] if root["observers"].line else ""
    return "[" not in line


def _line_index_of_top_key(pieces: list[str], key: str) -> int | None:
    """Split the text piece holding the top-level ``key:`` line so a section can go before
    it; the index to insert at, ``None`` when the key is not there."""
    for i, piece in enumerate(pieces):
        if "\0" in piece:
            continue
        lines = piece.splitlines(keepends=True)
        for j, line in enumerate(lines):
            if line.startswith(f"{key}:"):
                pieces[i:i + 1] = ["".join(lines[:j]), "".join(lines[j:])]
                return i + 1
    return None


def write_files(path: Path, text: str, model_path: Path, model_text: str) -> None:
    """Write the configuration and its model next to each other (model first)."""
    path.parent.mkdir(parents=True, exist_ok=True)
    model_path.write_text(model_text, encoding="utf-8")
    path.write_text(text, encoding="utf-8")
