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


def load(text: str, *, max_chars: int = MAX_CHARS) -> Any:
    """The data of one YAML document, or :class:`YamlRefused` saying what is wrong and where."""
    if len(text) > max_chars:
        raise YamlRefused(f"{len(text):,} characters, more than the {max_chars:,} accepted")
    loader = _Loader(text)
    try:
        return loader.get_single_data()
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        at = f"line {mark.line + 1}, column {mark.column + 1}: " if mark is not None else ""
        problem = getattr(exc, "problem", None) or str(exc).splitlines()[0]
        raise YamlRefused(f"not valid YAML: {at}{problem}") from None
    except RecursionError:  # a structure the depth limit did not see (e.g. deep flow collections)
        raise YamlRefused(f"nested too deeply (the limit is {MAX_DEPTH} levels)") from None
    finally:
        loader.dispose()
