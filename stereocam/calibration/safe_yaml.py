"""YAML that a hostile file cannot blow up: no aliases, bounded depth, bounded size.

``yaml.safe_load`` builds no objects but still expands aliases: a 2 KB file of
nested ``&a [*b, *b, ...]`` anchors becomes gigabytes (the "billion laughs"),
and deep nesting ends in ``RecursionError``. Our files (calibrations, board
profiles, settings, ROS camera_info) never need anchors, so :func:`load`
refuses the first alias before anything is expanded, refuses nesting deeper
than :data:`MAX_DEPTH` before the recursive composer gets there, text
longer than ``max_chars``, integers wider than :data:`MAX_INT_BITS` bits (a
few hundred bytes of hex digits make a number no float holds) and scalars the
safe constructor cannot read (``!!bool maybe``, ``2001-13-45``). Every refusal is
a :class:`YamlRefused` with one line saying where and why. A leaf module: any layer may use it.
"""
from __future__ import annotations

from typing import Any, Dict

import yaml

__all__ = ["YamlRefused", "load", "MAX_DEPTH", "MAX_CHARS", "MAX_INT_BITS"]

MAX_DEPTH = 32  # our deepest file (a calibration's quality section) nests 5 levels
MAX_CHARS = 4 << 20  # a calibration with per-pair figures for 100 pairs is about 100 KB
MAX_INT_BITS = 64  # our files' integers are sizes, counts, register values and ids
_INT_TAG = "tag:yaml.org,2002:int"


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


def _construct_int(loader: Any, node: Any) -> int:
    """PyYAML's integer, refused when wider than :data:`MAX_INT_BITS` bits."""
    value: int = yaml.constructor.SafeConstructor.construct_yaml_int(loader, node)
    if abs(value).bit_length() > MAX_INT_BITS:
        raise YamlRefused(f"line {node.start_mark.line + 1}: an integer wider than {MAX_INT_BITS} bits")
    return value


_Loader.add_constructor(_INT_TAG, _construct_int)
_FAST_LOADERS: Dict[Any, Any] = {}


def _fast_loader() -> Any:
    """libyaml's safe loader (None without libyaml) with the integer check of :func:`_construct_int`."""
    base = getattr(yaml, "CSafeLoader", None)
    if base is None:
        return None
    loader: Any = _FAST_LOADERS.get(base)
    if loader is None:
        loader = type("_FastLoader", (base,), {})
        loader.add_constructor(_INT_TAG, _construct_int)
        _FAST_LOADERS[base] = loader
    return loader


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
    fast = _fast_loader()
    if fast is not None:
        try:
            _scan(text, fast)
            return yaml.load(text, Loader=fast)  # noqa: S506 - CSafeLoader: the safe loader, in C
        except yaml.YAMLError as exc:
            raise YamlRefused(_problem(exc)) from None
        except YamlRefused:
            raise
        except _VALUE_ERRORS as exc:
            raise YamlRefused(_value_problem(exc)) from None
    try:
        loader = _Loader(text)  # reads the text: refuses characters YAML does not allow
    except yaml.YAMLError as exc:
        raise YamlRefused(_problem(exc)) from None
    try:
        return loader.get_single_data()
    except yaml.YAMLError as exc:
        raise YamlRefused(_problem(exc)) from None
    except YamlRefused:
        raise
    except RecursionError:  # a structure the depth limit did not see (e.g. deep flow collections)
        raise YamlRefused(f"nested too deeply (the limit is {MAX_DEPTH} levels)") from None
    except _VALUE_ERRORS as exc:
        raise YamlRefused(_value_problem(exc)) from None
    finally:
        loader.dispose()


# What PyYAML's safe constructor lets escape on a hostile scalar: ``!!bool maybe`` (KeyError),
# ``!!int xyz`` or an integer of more than 4300 digits (ValueError), ``2001-13-45`` (a timestamp
# that is no date: ValueError), a year past 9999 (OverflowError), ...
_VALUE_ERRORS = (ValueError, KeyError, TypeError, ArithmeticError)


def _value_problem(exc: BaseException) -> str:
    """One line for a scalar the safe constructor cannot turn into a value."""
    if isinstance(exc, KeyError):
        detail = f"{exc.args[0]!r} is not a value of its type" if exc.args else "an unknown value"
    elif "integer string conversion" in str(exc):
        detail = "an integer with too many digits"
    else:
        detail = " ".join(str(exc).split()) or type(exc).__name__
    return f"not valid YAML: a value cannot be read ({detail[:120]})"


def _problem(exc: "yaml.YAMLError") -> str:
    mark = getattr(exc, "problem_mark", None)
    at = f"line {mark.line + 1}, column {mark.column + 1}: " if mark is not None else ""
    problem = getattr(exc, "problem", None) or str(exc).splitlines()[0]
    return f"not valid YAML: {at}{problem}"
