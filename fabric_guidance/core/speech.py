"""Condition 4: the phrase spoken once per target, as in the paper's example
"36 to the right and 12 upward" (degrees, rounded to whole numbers)."""
from __future__ import annotations

import math


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
