"""Condition 4: the phrase spoken once per target, as in the paper's example
"36 to the right and 12 upward" (degrees, rounded to whole numbers), and what a listener
takes from it (parse_phrase, its inverse up to the rounding)."""
from __future__ import annotations

import math
import re


def phrase(horizontal_deg: float, vertical_deg: float) -> str:
    """The spoken guidance for signed angles (horizontal positive left, vertical positive up)."""
    if not (math.isfinite(horizontal_deg) and math.isfinite(vertical_deg)):
        raise ValueError(f'angles must be finite, got {horizontal_deg}, {vertical_deg}')
    h, v = round(horizontal_deg), round(vertical_deg)
    parts = []
    if h:
        parts.append(f'{abs(h)} to the {"left" if h > 0 else "right"}')
    if v:
        parts.append(f'{abs(v)} {"upward" if v > 0 else "downward"}')
    return ' and '.join(parts) if parts else 'straight ahead'


_PHRASE_H = re.compile(r'(\d+) to the (left|right)')
_PHRASE_V = re.compile(r'(\d+) (upward|downward)')


def parse_phrase(text: str) -> tuple[float, float]:
    """What a listener takes from phrase: (horizontal, vertical) degrees, positive left / up."""
    h = v = 0.0
    m = _PHRASE_H.search(text)
    if m:
        h = float(m.group(1)) * (1.0 if m.group(2) == 'left' else -1.0)
    m = _PHRASE_V.search(text)
    if m:
        v = float(m.group(1)) * (1.0 if m.group(2) == 'upward' else -1.0)
    return h, v
