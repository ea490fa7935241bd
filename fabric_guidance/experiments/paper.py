"""What the paper reports about its two subject experiments, as data.

Yokoe et al., IEEE Trans. Haptics 18(1), 2025, Sections V (accuracy) and VI (speed). Figures
are transcribed from the paper; everything else (means, standard errors, the statistics of the
table) is computed from them, never typed.

- SPEED_TABLE: the paper's table "Mean Value of Identified Target Objects per Subject"
  (15 subjects A-O x 4 conditions; 6 trials of 40 s per condition).
- SPEED_TRIAL_SD: the standard deviations the text states (3.0, 3.3, 4.0, 1.4). They are larger
  than the SD of the table's per-subject means (2.4, 2.6, 3.0, 1.2), so they are read here as
  the SD over all 90 trials of a condition.
- SPEED_BEST_COUNTS: "ten subjects had the largest mean" under condition 1, four under 2, one
  under 3, one under 4 (subject B ties 1 and 2, so they sum to 16).
- SPEED_CLAIMS / ACCURACY_CLAIMS: the paper's statements about significance (Friedman test with
  Dunn-Bonferroni correction), pair by pair; a pair the paper does not discuss is absent.
- ACCURACY_LIMIT_DEG: "In all four conditions, the mean and median of the horizontal and
  vertical errors were less than 30 deg"; the paper gives no other accuracy figure.
"""
from __future__ import annotations

from dataclasses import dataclass
import math

import pandas as pd

#: The paper's condition numbers (Table I) and the names fabric_guidance.experiments.stats uses.
CONDITIONS = {1: 'surface_adjusted', 2: 'surface_fixed', 3: 'simple_adjusted', 4: 'speech'}

#: Subject -> identified targets per 40 s trial, mean of 6 trials, conditions 1-4.
SPEED_TABLE_ROWS = (
    ('A', 7.7, 8.7, 7.8, 6.5), ('B', 11.8, 11.8, 8.3, 7.8), ('C', 10.8, 9.3, 10.0, 8.7),
    ('D', 11.3, 12.0, 11.2, 8.8), ('E', 15.3, 11.5, 14.7, 9.5), ('F', 10.7, 10.0, 10.0, 8.7),
    ('G', 7.2, 6.2, 5.2, 8.0), ('H', 10.7, 10.0, 4.3, 6.5), ('I', 10.5, 8.0, 8.5, 8.3),
    ('J', 8.0, 7.7, 5.8, 7.5), ('K', 10.3, 6.7, 8.7, 8.2), ('L', 13.5, 9.0, 13.3, 10.5),
    ('M', 14.5, 16.2, 13.2, 10.7), ('N', 8.7, 7.8, 9.2, 8.7), ('O', 9.7, 7.7, 8.2, 7.3),
)
SPEED_TRIAL_SD = {1: 3.0, 2: 3.3, 3: 4.0, 4: 1.4}
SPEED_BEST_COUNTS = {1: 10, 2: 4, 3: 1, 4: 1}
SPEED_SUBJECTS = 15
SPEED_REPETITIONS = 6
SPEED_TRIAL_S = 40.0        # the length of a speed trial (s)
ACCURACY_REPETITIONS = 10
ACCURACY_LIMIT_DEG = 30.0


@dataclass(frozen=True)
class Claim:
    """The paper says conditions a and b differ (`relation` '>' or '<': a's values are larger or
    smaller, at p < `p_below`) or do not ('ns')."""

    measure: str
    a: int
    b: int
    relation: str
    p_below: float | None = None
    where: str = ''

    def text(self) -> str:
        if self.relation == 'ns':
            return f'{self.a} vs {self.b}: no significant difference'
        return f'{self.a} {self.relation} {self.b} (p < {self.p_below:g})'


SPEED_CLAIMS = (
    # "Condition 1 ... had significantly higher identified target objects than Conditions 2, 3,
    # and 4 (... p < 0.05)."
    Claim('identified', 1, 2, '>', 0.05, 'Section VI-B'),
    Claim('identified', 1, 3, '>', 0.05, 'Section VI-B'),
    Claim('identified', 1, 4, '>', 0.05, 'Section VI-B'),
    # "there is no significant difference in the speed between surface haptic sensation without
    # air pressure adjustment and simple haptic sensation with the adjustment."
    Claim('identified', 2, 3, 'ns', None, 'Discussion'),
)
ACCURACY_CLAIMS = tuple(
    claim for measure in ('h_error_deg', 'v_error_deg') for claim in (
        # "Condition 4 ... had significantly smaller horizontal and vertical errors than
        # Conditions 1, 2, and 3 (... p < 0.001)."
        Claim(measure, 4, 1, '<', 0.001, 'Section V-B'),
        Claim(measure, 4, 2, '<', 0.001, 'Section V-B'),
        Claim(measure, 4, 3, '<', 0.001, 'Section V-B'),
        # "no significant differences were observed ... between Conditions 1, 2, and 3"
        Claim(measure, 1, 2, 'ns', None, 'Section V-B'),
        Claim(measure, 1, 3, 'ns', None, 'Section V-B'),
        Claim(measure, 2, 3, 'ns', None, 'Section V-B'),
    ))


def speed_table() -> pd.DataFrame:
    """The table as subjects x conditions (columns named as experiments.stats names them)."""
    frame = pd.DataFrame([row[1:] for row in SPEED_TABLE_ROWS], index=[row[0] for row in SPEED_TABLE_ROWS],
                         columns=[CONDITIONS[c] for c in sorted(CONDITIONS)])
    frame.index.name = 'subject'
    return frame


def speed_means() -> dict[int, float]:
    """Mean identified targets per condition: the mean of the table's per-subject means."""
    table = speed_table()
    return {c: float(table[name].mean()) for c, name in CONDITIONS.items()}


def speed_standard_errors() -> dict[int, float]:
    """Standard error of each condition's mean: SD of the per-subject means / sqrt(15). The
    stricter of the two readings (the text's SDs over trials would give about 1.3 times more)."""
    table = speed_table()
    n = len(table)
    return {c: float(table[name].std(ddof=1)) / math.sqrt(n) for c, name in CONDITIONS.items()}


__all__ = ['ACCURACY_CLAIMS', 'ACCURACY_LIMIT_DEG', 'ACCURACY_REPETITIONS', 'CONDITIONS', 'Claim', 'SPEED_BEST_COUNTS',
           'SPEED_CLAIMS', 'SPEED_REPETITIONS', 'SPEED_SUBJECTS', 'SPEED_TABLE_ROWS', 'SPEED_TRIAL_S',
           'SPEED_TRIAL_SD',
           'speed_means', 'speed_standard_errors', 'speed_table']
