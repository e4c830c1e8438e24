"""Race tests that leave nothing to the scheduler's luck: run something between every two bytecodes.

Under the GIL another thread can only run between two bytecodes of this one. A tracer from
:func:`at_every_bytecode`, installed with ``sys.settrace`` (this thread) or ``threading.settrace``
(threads started afterwards), calls ``action`` before each bytecode of one function's code:
a check of what other threads could see at that point, or ``time.sleep(0)`` to hand the GIL over.
"""
from __future__ import annotations

from types import CodeType, FrameType
from typing import Any, Callable, Optional

Tracer = Callable[[FrameType, str, Any], Optional[Callable[..., Any]]]


def at_every_bytecode(code: CodeType, action: Callable[[], None]) -> Tracer:
    """A ``settrace`` function calling ``action()`` before every bytecode run in frames of ``code``."""

    def step(frame: FrameType, event: str, arg: Any) -> Tracer:
        if event == "opcode":
            action()
        return step

    def enter(frame: FrameType, event: str, arg: Any) -> Optional[Tracer]:
        if frame.f_code is not code:
            return None  # other functions run untraced
        frame.f_trace_opcodes = True
        return step

    return enter
