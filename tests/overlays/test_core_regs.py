"""Register decoding shared by the rectify driver, fabric and emulated core: every writable field round-trips.

Writable means every register and field software sets (RW, or self-clearing
like CONTROL.APPLY): CONTROL, DEBUG_ROW and the shadow registers. The field
list comes from the spec's table, so a field or register added there without
a decoder in ``stereocam/overlays/model/core_regs.py`` fails here.
"""
from __future__ import annotations

import random
from typing import Dict, List

import pytest

from stereocam.overlays.model import core_regs
from stereocam.overlays.model.core_regs import CoreControl, config_words, read_config
from stereocam.overlays.model.result import CoreOptions
from stereocam.overlays.spec.rectify import (
    CAMERAS,
    N_NAMES,
    PARAM_NAMES,
    RECTIFY_MAP,
    CameraRegs,
    CoreConfig,
)
from stereocam.overlays.spec.regs import Access, Field, Register, RegisterMap

SEEDS = range(40)


def writable_mask(reg: Register) -> int:
    return reg.mask_of(Access.RW) | reg.mask_of(Access.SC)


def random_words(regmap: RegisterMap[Register], rng: random.Random) -> Dict[str, int]:
    """A random word for every writable register, each writable field drawn from its whole range."""
    words = {}
    for reg in regmap:
        mask = writable_mask(reg)
        if not mask:
            continue
        if not reg.fields:
            words[reg.name] = rng.getrandbits(reg.BITS)
            continue
        words[reg.name] = reg.encode(**{f.name: rng.randint(0, f.max) for f in reg.fields
                                        if f.mask & mask})
    return words


def decode_encode(words: Dict[str, int]) -> Dict[str, int]:
    """Words -> CoreConfig and CoreControl -> words, through the shared decoders."""
    read = words.__getitem__
    return {**config_words(read_config(read)), **CoreControl.read(read).words()}


def roundtrip_problems(regmap: RegisterMap[Register], seeds: range = SEEDS) -> List[str]:
    """Every writable register or field of ``regmap`` that does not survive decode then encode."""
    problems = set()
    for seed in seeds:
        words = random_words(regmap, random.Random(seed))
        back = decode_encode(words)
        for name, word in words.items():
            reg = regmap[name]
            if name not in back:
                problems.add(f"{name}: not decoded")
                continue
            for f in reg.fields or (Field("word", 0, reg.BITS),):
                if (word ^ back[name]) & f.mask:
                    problems.add(f"{name}.{f.name}: does not round-trip")
        problems.update(f"{name}: encoded but not a writable register of the spec" for name in back
                        if name not in words)
    return sorted(problems)


def test_every_writable_field_round_trips() -> None:
    assert roundtrip_problems(RECTIFY_MAP) == []


def test_the_round_trip_covers_control_debug_row_and_every_shadow_register() -> None:
    words = random_words(RECTIFY_MAP, random.Random(0))
    params = {f"{cam}_{n}_{half}" for cam in CAMERAS for n in PARAM_NAMES for half in ("LO", "HI")}
    assert {"CONTROL", "DEBUG_ROW", "WIDTH", "HEIGHT", "LB_DELAY"} | params <= set(words)
    assert words.keys().isdisjoint({"ID", "STATUS", "FLAGS", "FRAME_COUNT"})  # read-only or W1C: no setting


def _with(reg: Register, *extra: Field) -> Register:
    return Register(reg.name, reg.offset, reg.access, reg.reset, reg.fields + extra, reg.doc, reg.limits)


def test_a_field_or_register_added_to_the_spec_without_a_decoder_fails(
        monkeypatch: pytest.MonkeyPatch) -> None:
    grown = RegisterMap(
        RECTIFY_MAP.name,
        [*(_with(r, Field("MIRROR", 5)) if r.name == "CONTROL" else
           _with(r, Field("THICK", 16, 2)) if r.name == "DEBUG_ROW" else r for r in RECTIFY_MAP),
         Register("GAIN", 0x040, Access.RW, 0, fields=(Field("VALUE", 0, 8),))],
        size=RECTIFY_MAP.size,
    )
    monkeypatch.setattr(core_regs, "RECTIFY_MAP", grown)
    problems = roundtrip_problems(grown, range(8))
    assert problems == ["CONTROL.MIRROR: does not round-trip", "DEBUG_ROW.THICK: does not round-trip",
                        "GAIN: not decoded"]


def random_camera(rng: random.Random) -> CameraRegs:
    values = {n: rng.randint(-(1 << 63), (1 << 63) - 1) for n in PARAM_NAMES}
    return CameraRegs.from_values(values)


@pytest.mark.parametrize("seed", SEEDS)
def test_objects_survive_encode_then_decode(seed: int) -> None:
    rng = random.Random(seed)
    size = RECTIFY_MAP["WIDTH"].field("VALUE").max
    cfg = CoreConfig(random_camera(rng), random_camera(rng), rng.randint(0, size), rng.randint(0, size),
                     rng.randint(0, RECTIFY_MAP["LB_DELAY"].field("VALUE").max))
    assert read_config(config_words(cfg).__getitem__) == cfg
    control = CoreControl(enable=rng.random() < 0.5, bypass=rng.random() < 0.5, gray=rng.random() < 0.5,
                          debug_line=rng.random() < 0.5, apply=rng.random() < 0.5,
                          debug_row=rng.randint(0, RECTIFY_MAP["DEBUG_ROW"].field("VALUE").max))
    assert CoreControl.read(control.words().__getitem__) == control


def test_config_words_are_in_write_order_and_refuse_what_does_not_fit() -> None:
    cam = CameraRegs.from_values({n: i for i, n in enumerate(PARAM_NAMES)})
    names = list(config_words(CoreConfig(cam, cam, 8, 4, 1)))
    assert names[:5] == ["WIDTH", "HEIGHT", "LB_DELAY", f"L_{N_NAMES[0]}_LO", f"L_{N_NAMES[0]}_HI"]
    assert names[-1] == f"R_{PARAM_NAMES[-1]}_HI"
    with pytest.raises(ValueError, match=r"WIDTH.VALUE takes 0..65535, not 65536"):
        config_words(CoreConfig(cam, cam, 1 << 16, 4))
    with pytest.raises(ValueError, match="DEBUG_ROW.VALUE takes 0..65535, not -1"):
        CoreControl(debug_row=-1).words()


def test_options_carry_the_debug_row_only_while_the_debug_line_is_on() -> None:
    on = CoreControl(enable=True, bypass=True, gray=True, debug_line=True, debug_row=9)
    assert on.options(lb_rows=16, lb_delay=3, colour=False) == CoreOptions(
        lb_rows=16, lb_delay=3, gray=True, bypass=True, debug_row=9, colour=False)
    off = CoreControl(debug_row=9)
    assert off.options(lb_rows=80, lb_delay=0, colour=True) == CoreOptions(lb_rows=80)
