"""YAML that a hostile file cannot blow up: no aliases, bounded depth, bounded size.

``yaml.safe_load`` builds no objects but still expands aliases: a 2 KB file of
nested ``&a [*b, *b, ...]`` anchors becomes gigabytes (the "billion laughs"),
and deep nesting ends in ``RecursionError``. Our files (calibrations, board
profiles, settings, ROS camera_info) never need anchors, so :func:`load`
refuses the first alias before anything is expanded, refuses nesting deeper
than :data:`MAX_DEPTH` before the recursive composer gets there, and text
longer than ``max_chars``. Every refusal is a :class:`YamlRefused` with one
line saying where and why. A leaf module: any layer may use it.
"""
from __future__ import annotations

from typing import Any

import yaml

__all__ = ["YamlRefused", "load", "MAX_DEPTH", "MAX_CHARS"]

MAX_DEPTH = 32  # our deepest file (a calibration's quality section) nests 5 levels
MAX_CHARS = 4 << 20  # a calibration with per-pair figures for 100 pairs is about 100 KB


class YamlRefused(ValueError):
    """Not YAML we accept; the message is one line, without the file's name (the caller adds it)."""


class _Loader(yaml.SafeLoader):
    """SafeLoader that refuses aliases and deep nesting while composing, i.e. before constructing."""

    def __init__(self, stream: str) -> None:
        super().__init__(stream)
        self._depth = 0

    def compose_node(self, parent: Any, index: Any) -> Any:  # noqa: ANN401 - PyYAML's own signature
        if self.check_event(yaml.AliasEvent):
            event = self.peek_event()
            raise YamlRefused(f"line {event.start_mark.line + 1}: YAML aliases (*{event.anchor}) are not "
                              "accepted; write the value out")
        if self._depth >= MAX_DEPTH:
            mark = self.peek_event().start_mark
            raise YamlRefused(f"line {mark.line + 1}: nested more than {MAX_DEPTH} levels deep")
        self._depth += 1
        try:
            return super().compose_node(parent, index)
        finally:
            self._depth -= 1


def _scan(text: str, loader: Any) -> None:
    """Refuse aliases and deep nesting from the parser's events alone, before anything is built."""
    depth = 0
    for event in yaml.parse(text, Loader=loader):
        line = event.start_mark.line + 1 if event.start_mark is not None else "?"
        if isinstance(event, yaml.AliasEvent):
            raise YamlRefused(f"line {line}: YAML aliases (*{event.anchor}) are not accepted; "
                              "write the value out")
        if isinstance(event, yaml.CollectionStartEvent):
            depth += 1
            if depth > MAX_DEPTH:
                raise YamlRefused(f"line {line}: nested more than {MAX_DEPTH} levels deep")
        elif isinstance(event, yaml.CollectionEndEvent):
            depth -= 1


def load(text: str, *, max_chars: int = MAX_CHARS) -> Any:
    """The data of one YAML document, or :class:`YamlRefused` saying what is wrong and where.

    With libyaml (PyYAML's C parser, as on the PYNQ image) the events are scanned and the
    document built in C, about four times faster than the pure-Python loader below, which
    serves where libyaml is missing.
    """
    if len(text) > max_chars:
        raise YamlRefused(f"{len(text):,} characters, more than the {max_chars:,} accepted")
    fast = getattr(yaml, "CSafeLoader", None)
    if fast is not None:
        try:
            _scan(text, fast)
            return yaml.load(text, Loader=fast)  # noqa: S506 - CSafeLoader: the safe loader, in C
        except yaml.YAMLError as exc:
            raise YamlRefused(_problem(exc)) from None
    loader = _Loader(text)
    try:
        return loader.get_single_data()
    except yaml.YAMLError as exc:
        raise YamlRefused(_problem(exc)) from None
    except RecursionError:  # a structure the depth limit did not see (e.g. deep flow collections)
        raise YamlRefused(f"nested too deeply (the limit is {MAX_DEPTH} levels)") from None
    finally:
        loader.dispose()


def _problem(exc: "yaml.YAMLError") -> str:
    mark = getattr(exc, "problem_mark", None)
    at = f"line {mark.line + 1}, column {mark.column + 1}: " if mark is not None else ""
    problem = getattr(exc, "problem", None) or str(exc).splitlines()[0]
    return f"not valid YAML: {at}{problem}"
