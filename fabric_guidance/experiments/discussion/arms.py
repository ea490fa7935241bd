"""What both Discussion studies (per_wearer_gain.py, moving_targets.py)
use: the paper's statistics on compared arms, per wearer."""
from __future__ import annotations

import math

import pandas as pd

from ..stats import BlockAnalysis, analyze_trials


def analyze_arms(frame: pd.DataFrame, measure: str, higher: bool,
                 conditions) -> BlockAnalysis | None:
    if frame.empty or frame['subject'].nunique() < 2:
        return None
    # The wearers' names (S01, ...) as the subject ids of the tables.
    return analyze_trials(frame.assign(subject=frame['wearer']), measure, higher_is_better=higher,
                          conditions=list(conditions))


def pair_p(a: BlockAnalysis | None, x: str, y: str) -> float:
    return math.nan if a is None else float(a.pair(x, y)['p_adjusted'])


def verdict(p: float) -> str:
    return 'n/a' if math.isnan(p) else ('significant' if p < 0.05 else 'not significant')
