"""Friedman + Dunn-Bonferroni (fabric_guidance.experiments.stats) against independent computations.

The paper's table (its Table "Mean Value of Identified Target Objects per Subject") is written
out here so the tests stand alone; a test checks it against the shared copy when that exists.
"""
from __future__ import annotations

import io
import itertools
import math
from pathlib import Path

from hypothesis import given, settings, strategies as st
import numpy as np
import pandas as pd
import pytest
from scipy import stats as ss

from fabric_guidance.experiments.stats import (analyze_blocks, analyze_trials, condition_label, format_analysis,
                                               format_p, load_table, stars)

PAPER_CSV = """subject,surface_adjusted,surface_fixed,simple_adjusted,speech
A,7.7,8.7,7.8,6.5
B,11.8,11.8,8.3,7.8
C,10.8,9.3,10.0,8.7
D,11.3,12.0,11.2,8.8
E,15.3,11.5,14.7,9.5
F,10.7,10.0,10.0,8.7
G,7.2,6.2,5.2,8.0
H,10.7,10.0,4.3,6.5
I,10.5,8.0,8.5,8.3
J,8.0,7.7,5.8,7.5
K,10.3,6.7,8.7,8.2
L,13.5,9.0,13.3,10.5
M,14.5,16.2,13.2,10.7
N,8.7,7.8,9.2,8.7
O,9.7,7.7,8.2,7.3
"""
# The project's shared folder sits beside the checkout (as in CI); test/data keeps a copy.
SHARED_CSV = Path(__file__).resolve().parents[2] / 'shared' / 'paper' / 'table-identified-targets.csv'
C1, C2, C3, C4 = 'surface_adjusted', 'surface_fixed', 'simple_adjusted', 'speech'


def paper_table() -> pd.DataFrame:
    return pd.read_csv(io.StringIO(PAPER_CSV), index_col=0)


def write(tmp_path, text: str, name: str = 't.csv') -> Path:
    path = tmp_path / name
    path.write_text(text)
    return path


def reference(table: pd.DataFrame) -> dict:
    """Friedman and the block Dunn-Bonferroni written out from the textbook formulas."""
    x = table.to_numpy(float)
    n, k = x.shape
    ranks = np.vstack([ss.rankdata(row) for row in x])  # one subject at a time, ties averaged
    rank_sums = ranks.sum(axis=0)
    raw = 12.0 / (n * k * (k + 1)) * np.sum(rank_sums ** 2) - 3.0 * n * (k + 1)
    ties = sum(float(t ** 3 - t) for row in x for t in np.unique(row, return_counts=True)[1])
    chi2 = raw / (1.0 - ties / (n * k * (k * k - 1)))
    se = math.sqrt(k * (k + 1) / (6.0 * n))
    mean_ranks = dict(zip(table.columns, ranks.mean(axis=0)))
    pairs = list(itertools.combinations(table.columns, 2))
    out = {}
    for a, b in pairs:
        z = (mean_ranks[a] - mean_ranks[b]) / se
        p = 2.0 * ss.norm.sf(abs(z))
        out[(a, b)] = (z, p, min(1.0, p * len(pairs)))
    return {'chi2': chi2, 'p': ss.chi2.sf(chi2, k - 1), 'mean_ranks': mean_ranks, 'pairs': out}


# ------------------------------------------------------------------------ (a) the paper's table

def test_the_embedded_table_is_the_shared_one(tmp_path):
    copy = Path(__file__).resolve().parent / 'data' / 'table-identified-targets.csv'
    pd.testing.assert_frame_equal(load_table(copy), load_table(write(tmp_path, PAPER_CSV)))
    if SHARED_CSV.exists():
        pd.testing.assert_frame_equal(load_table(SHARED_CSV), load_table(copy))


def test_paper_table_friedman_matches_the_formula():
    a = analyze_blocks(paper_table())
    ref = reference(paper_table())
    # By hand: rank sums 53, 36, 36.5, 24.5 -> 12/(15*4*5) * 6037.5 - 3*15*5 = 241.5 - 225 = 16.5;
    # ties: B (1=2), F (2=3), N (1=4), three pairs, sum(t^3 - t) = 18 -> C = 1 - 18/(15*4*15) = 0.98;
    # chi2 = 16.5 / 0.98 = 16.8367..., df 3.
    assert ref['chi2'] == pytest.approx(16.5 / 0.98, rel=1e-12)
    assert a.chi2 == pytest.approx(ref['chi2'], rel=1e-12)
    assert a.p == pytest.approx(ref['p'], rel=1e-9)
    assert a.p == pytest.approx(7.6354e-4, rel=1e-3)
    assert (a.n, a.k, a.df) == (15, 4, 3)
    assert a.kendall_w == pytest.approx(16.5 / 0.98 / 45)
    assert a.mean_ranks.to_dict() == pytest.approx({C1: 53 / 15, C2: 36 / 15, C3: 36.5 / 15, C4: 24.5 / 15})


def test_paper_table_pairwise_matches_the_formula():
    a = analyze_blocks(paper_table())
    ref = reference(paper_table())['pairs']
    assert len(a.pairwise) == 6 == len(ref)
    for row in a.pairwise.itertuples():
        z, p, p_adj = ref[(row.a, row.b)]
        assert row.z == pytest.approx(z, rel=1e-12)
        assert row.p == pytest.approx(p, rel=1e-9)
        assert row.p_adjusted == pytest.approx(p_adj, rel=1e-9)
        assert row.significant == (p_adj < 0.05)
    # What the numbers say about the paper's claim "1 > 2, 3, 4 (p < 0.05)": only 1 vs 4 survives
    # Bonferroni; 1 vs 2 and 1 vs 3 are below 0.05 only unadjusted.
    assert a.pair(C1, C4).p_adjusted < 0.001
    assert 0.05 < a.pair(C1, C2).p_adjusted < 0.1 and a.pair(C1, C2).p < 0.05
    assert 0.05 < a.pair(C1, C3).p_adjusted < 0.2 and a.pair(C1, C3).p < 0.05
    assert [tuple(r) for r in a.pairwise[['a', 'b']].to_numpy() if a.pair(*r).significant] == [(C1, C4)]


def test_paper_table_summary():
    a = analyze_blocks(paper_table())
    assert a.means.round(3).to_dict() == {C1: 10.713, C2: 9.507, C3: 9.227, C4: 8.38}
    assert a.means.idxmax() == C1
    # SDs of the 15 subject means (ddof=1): not the paper's 3.0, 3.3, 4.0, 1.4, same order.
    assert a.sds.round(2).to_dict() == {C1: 2.37, C2: 2.57, C3: 2.98, C4: 1.23}
    assert a.sds.to_dict() == pytest.approx(paper_table().std(ddof=1).to_dict())
    assert a.medians.to_dict() == {C1: 10.7, C2: 9.0, C3: 8.7, C4: 8.3}


def test_pair_lookup_is_order_free():
    a = analyze_blocks(paper_table())
    fwd, back = a.pair(C1, C2), a.pair(C2, C1)
    assert back.z == -fwd.z and back.rank_diff == -fwd.rank_diff and back.p_adjusted == fwd.p_adjusted
    with pytest.raises(KeyError):
        a.pair(C1, 'nope')


# ------------------------------------------------------------------------ (c) best condition

def test_paper_best_condition_counts_include_one_tie():
    a = analyze_blocks(paper_table())
    # The paper: 10 / 4 / 1 / 1, which sums to 16 for 15 subjects. Subject B has 11.8 in both
    # surface conditions: counted for each, the counts are exactly the paper's.
    assert a.best_counts.to_dict() == {C1: 10, C2: 4, C3: 1, C4: 1}
    assert a.best_counts.sum() == 16
    assert a.tied_best == ('B',)
    assert a.best['B'] == (C1, C2)
    strict = {c: sum(b == (c,) for b in a.best.values()) for c in a.conditions}
    assert strict == {C1: 9, C2: 3, C3: 1, C4: 1}
    assert [s for s, b in a.best.items() if C1 not in b] == ['A', 'D', 'G', 'M', 'N']  # the Discussion's "five of 15"
    assert any('B: surface_adjusted = surface_fixed' in n and 'sum to 16' in n for n in a.notes)


def test_the_paper_ties_are_ties_of_whole_counts():
    """Each cell is a mean over 6 trials of whole numbers of targets, so it is m/6 for an integer
    m; sixths lie 0.167 apart, so every one-decimal value comes from exactly one m and the tie of
    subject B (11.8 = 71/6 twice) is a real tie, not one made by rounding."""
    x = paper_table().to_numpy(float)
    totals = np.round(x * 6)
    assert np.array_equal(np.round(totals / 6, 1), x)
    assert totals[1, 0] == totals[1, 1] == 71


def test_lower_is_better_takes_the_minimum():
    a = analyze_blocks(paper_table(), higher_is_better=False)
    t = paper_table()
    for s in t.index:
        assert a.best[s] == tuple(c for c in t.columns if t.at[s, c] == t.loc[s].min())
    assert a.best['F'] == (C4,) and a.best['N'] == (C2,) and a.best['G'] == (C3,)
    # the tests are two-sided: direction changes nothing else
    b = analyze_blocks(t)
    assert a.chi2 == b.chi2 and a.pairwise.equals(b.pairwise)


# ------------------------------------------------------------------------ (b) small tables by hand

def test_three_by_three_perfect_agreement():
    # Every subject orders A < B < C: ranks (1, 2, 3) each time, rank sums 3, 6, 9.
    # chi2 = 12/(3*3*4) * (9 + 36 + 81) - 3*3*4 = 42 - 36 = 6; no ties; df 2 so p = exp(-6/2) = e^-3.
    # W = 6 / (3 * 2) = 1. se = sqrt(3*4/(6*3)) = sqrt(2/3); z(A,C) = -2/sqrt(2/3) = -2.4495,
    # p = 0.014306, x3 = 0.042918 (< 0.05); z(A,B) = z(B,C) = -1.2247, p = 0.22067, x3 = 0.66201.
    t = pd.DataFrame({'A': [1, 4, 7], 'B': [2, 5, 8], 'C': [3, 6, 9]}, index=['s1', 's2', 's3'])
    a = analyze_blocks(t)
    assert a.chi2 == pytest.approx(6.0)
    assert a.p == pytest.approx(math.exp(-3))
    assert a.kendall_w == pytest.approx(1.0)
    assert a.mean_ranks.to_dict() == {'A': 1.0, 'B': 2.0, 'C': 3.0}
    assert a.rank_se == pytest.approx(math.sqrt(2 / 3))
    ac, ab, bc = a.pair('A', 'C'), a.pair('A', 'B'), a.pair('B', 'C')
    assert ac.z == pytest.approx(-2.449490, abs=1e-6)
    assert ac.p == pytest.approx(0.014306, abs=1e-6) and ac.p_adjusted == pytest.approx(0.042918, abs=1e-6)
    assert ac.significant
    for r in (ab, bc):
        assert r.z == pytest.approx(-1.224745, abs=1e-6)
        assert r.p_adjusted == pytest.approx(0.662014, abs=1e-6) and not r.significant
    assert a.best_counts.to_dict() == {'A': 0, 'B': 0, 'C': 3}
    assert analyze_blocks(t, higher_is_better=False).best_counts.to_dict() == {'A': 3, 'B': 0, 'C': 0}


def test_two_by_three_with_ties():
    # s1 = (5, 5, 9) -> ranks (1.5, 1.5, 3); s2 = (2, 7, 7) -> ranks (1, 2.5, 2.5).
    # Rank sums 2.5, 4, 5.5; 12/(2*3*4) * (6.25 + 16 + 30.25) - 3*2*4 = 26.25 - 24 = 2.25.
    # One tie of two per subject: sum(t^3 - t) = 12, C = 1 - 12/(2*3*8) = 0.75; chi2 = 3.0,
    # p = exp(-1.5) = 0.22313; W = 3 / (2*2) = 0.75.
    # Best (largest): s1 -> C; s2 -> B and C tied. Counts A 0, B 1, C 2 (sum 3 over 2 subjects).
    t = pd.DataFrame([[5, 5, 9], [2, 7, 7]], index=['s1', 's2'], columns=['A', 'B', 'C'])
    a = analyze_blocks(t)
    assert a.chi2 == pytest.approx(3.0)
    assert a.p == pytest.approx(math.exp(-1.5))
    assert a.kendall_w == pytest.approx(0.75)
    assert a.mean_ranks.to_dict() == {'A': 1.25, 'B': 2.0, 'C': 2.75}
    assert a.best == {'s1': ('C',), 's2': ('B', 'C')}
    assert a.best_counts.to_dict() == {'A': 0, 'B': 1, 'C': 2}
    assert a.tied_best == ('s2',)
    # se = sqrt(3*4/12) = 1; z(A,C) = 1.25 - 2.75 = -1.5; p = 0.133614; x3 = 0.400843
    assert a.pair('A', 'C').z == pytest.approx(-1.5)
    assert a.pair('A', 'C').p_adjusted == pytest.approx(0.400843, abs=1e-6)


def test_two_conditions_where_scipy_refuses():
    # Ranks (1,2), (1,2), (2,1), (1,2): rank sums 5, 7; 12/(4*2*3) * (25 + 49) - 3*4*3 = 37 - 36 = 1.
    # df 1: p = P(chi2_1 > 1) = 2*Phi(-1) = 0.317311. The one pair: se = sqrt(2*3/24) = 0.5,
    # dR = 1.25 - 1.75 = -0.5, z = -1 (z^2 = chi2, as it must be for k = 2); Bonferroni x1.
    t = pd.DataFrame({'x': [1, 3, 6, 7], 'y': [2, 4, 5, 8]})
    a = analyze_blocks(t)
    assert a.chi2 == pytest.approx(1.0) and a.df == 1
    assert a.p == pytest.approx(0.317311, abs=1e-6)
    row = a.pair('x', 'y')
    assert row.z == pytest.approx(-1.0) and row.p_adjusted == pytest.approx(a.p)


def test_all_tied_gives_an_undefined_statistic_not_a_crash():
    t = pd.DataFrame({'a': [1.0, 2.0], 'b': [1.0, 2.0], 'c': [1.0, 2.0]})
    a = analyze_blocks(t)
    assert math.isnan(a.chi2) and math.isnan(a.p)
    assert (a.pairwise['z'] == 0).all() and (a.pairwise['p_adjusted'] == 1).all()
    assert a.best_counts.to_dict() == {'a': 2, 'b': 2, 'c': 2}
    assert 'n/a' in format_analysis(a)


@settings(max_examples=60, deadline=None)
@given(st.integers(2, 8).flatmap(lambda n: st.integers(3, 5).flatmap(
    lambda k: st.lists(st.lists(st.integers(0, 4), min_size=k, max_size=k), min_size=n, max_size=n))))
def test_any_small_integer_table_matches_the_reference(rows):
    t = pd.DataFrame(rows, columns=[f'c{i}' for i in range(len(rows[0]))], index=[f's{i}' for i in range(len(rows))])
    if all(len(set(r)) == 1 for r in rows):
        return  # undefined statistic, covered above
    a = analyze_blocks(t)
    ref = reference(t)
    assert a.chi2 == pytest.approx(ref['chi2'], rel=1e-9, abs=1e-12)
    assert a.p == pytest.approx(ref['p'], rel=1e-9, abs=1e-15)
    assert sum(a.mean_ranks) == pytest.approx(a.k * (a.k + 1) / 2)
    for row in a.pairwise.itertuples():
        z, p, p_adj = ref['pairs'][(row.a, row.b)]
        assert row.z == pytest.approx(z) and row.p_adjusted == pytest.approx(p_adj)
    assert a.best_counts.sum() >= a.n


# ------------------------------------------------------------------------ (d) load_table

def test_load_table_reads_the_paper_table(tmp_path):
    t = load_table(write(tmp_path, PAPER_CSV))
    assert t.shape == (15, 4) and list(t.columns) == [C1, C2, C3, C4]
    assert t.index.name == 'subject' and t.index[0] == 'A' and t.at['M', C2] == 16.2
    assert t.dtypes.eq(float).all()


def test_load_table_tolerates_bom_blank_lines_and_spaces(tmp_path):
    text = '\ufeffsubject, a , b\n\n s1 , 1 , 2 \ns2,3,4\n\n'
    t = load_table(write(tmp_path, text))
    assert list(t.columns) == ['a', 'b'] and list(t.index) == ['s1', 's2'] and t.at['s1', 'b'] == 2.0


@pytest.mark.parametrize('text, message', [
    ('', 'empty file'),
    ('subject,a,b\ns1,1,\ns2,3,4\n', 'missing value at subject s1, condition b'),
    ('subject,a,b\ns1,1,NA\ns2,3,4\n', 'missing value at subject s1, condition b'),
    ('subject,a,b\ns1,1,2\ns2,three,4\n', "non-numeric value at subject s2, condition a ('three')"),
    ('subject,a,b\ns1,1,inf\ns2,3,4\n', "non-numeric value at subject s1, condition b ('inf')"),
    ('subject,a\ns1,1\ns2,2\n', 'at least 2 condition columns, got 2 column(s)'),
    ('subject;a;b\ns1;1;2\ns2;3;4\n', 'is it comma-separated?'),
    ('subject,a,b\ns1,1,2\n', 'at least 2 subjects, got 1'),
    ('subject,a,b\ns1,1,2\ns2,3\n', 'line 3 has 2 cells, the header has 3'),
    ('subject,a,b\ns1,1,2\ns1,3,4\n', 'duplicate subject s1'),
    ('subject,a,a\ns1,1,2\ns2,3,4\n', 'duplicate condition a'),
    ('subject,a,\ns1,1,2\ns2,3,4\n', 'empty condition name'),
    ('subject,a,b\n,1,2\ns2,3,4\n', 'line 2 has no subject id'),
])
def test_load_table_errors_name_the_problem(tmp_path, text, message):
    with pytest.raises(ValueError) as err:
        load_table(write(tmp_path, text))
    assert message in str(err.value)
    assert str(tmp_path / 't.csv') in str(err.value)


def test_analyze_blocks_checks_a_dataframe_too():
    with pytest.raises(ValueError, match='missing value at subject s2, condition b'):
        analyze_blocks(pd.DataFrame({'a': [1.0, 2.0], 'b': [1.0, None]}, index=['s1', 's2']))
    with pytest.raises(ValueError, match='non-numeric'):
        analyze_blocks(pd.DataFrame({'a': [1.0, 2.0], 'b': ['x', 1.0]}, index=['s1', 's2']))
    with pytest.raises(ValueError, match='at least 2 conditions'):
        analyze_blocks(pd.DataFrame({'a': [1.0, 2.0]}))
    with pytest.raises(ValueError, match='at least 2 subjects'):
        analyze_blocks(pd.DataFrame({'a': [1.0], 'b': [2.0]}))


# ------------------------------------------------------------------------ (e) analyze_trials

def trials_from(table: pd.DataFrame, offsets=(-1.0, 0.0, 1.0)) -> pd.DataFrame:
    """Trials whose mean per subject and condition is the table's value."""
    rows = [{'subject': s, 'condition': c, 'repetition': r, 'targets': table.at[s, c] + d}
            for s in table.index for c in table.columns for r, d in enumerate(offsets)]
    return pd.DataFrame(rows).sample(frac=1.0, random_state=1)  # order must not matter


def test_analyze_trials_is_analyze_blocks_on_the_subject_means():
    t = paper_table().astype(float)
    a = analyze_trials(trials_from(t), 'targets')
    b = analyze_blocks(t)
    assert list(a.conditions) == [C1, C2, C3, C4]  # the paper's order, whatever the trial order
    pd.testing.assert_frame_equal(a.table.sort_index(), b.table.rename_axis(index=None).sort_index(),
                                  check_names=False, atol=1e-12)
    assert a.chi2 == pytest.approx(b.chi2) and a.best_counts.to_dict() == b.best_counts.to_dict()
    for x, y in zip(a.pairwise.itertuples(), b.pairwise.itertuples()):
        assert x.z == pytest.approx(y.z) and x.p_adjusted == pytest.approx(y.p_adjusted)
    # The SD over all trials is larger than the SD of the subject means: it adds the spread
    # within subjects (here +-1 around each mean).
    trials = trials_from(t)
    for c in t.columns:
        assert a.trial_sd[c] == pytest.approx(trials.loc[trials.condition == c, 'targets'].std(ddof=1))
        assert a.trial_sd[c] > a.sds[c]
    assert (a.repetitions == 3).all(axis=None)
    assert 'SD trials' in format_analysis(a)


def test_analyze_trials_means_tie_whatever_the_summation_order():
    # 0.1 + 0.2 + 0.3 != 0.3 + 0.2 + 0.1 in floating point; the two means must still tie.
    trials = pd.DataFrame({'subject': ['s1'] * 6 + ['s2'] * 2,
                           'condition': ['a'] * 3 + ['b'] * 3 + ['a', 'b'],
                           'repetition': [0, 1, 2] * 2 + [0, 0],
                           'err': [0.1, 0.2, 0.3, 0.3, 0.2, 0.1, 1.0, 2.0]})
    a = analyze_trials(trials, 'err')
    assert a.best['s1'] == ('a', 'b')
    assert a.mean_ranks['a'] == pytest.approx(1.25)  # s1 tie (1.5 each), s2 a < b
    assert any('Unequal repetitions: 1 to 3' in n for n in a.notes)


def test_analyze_trials_errors():
    good = trials_from(pd.DataFrame({'a': [1.0, 2.0], 'b': [3.0, 4.0]}, index=['s1', 's2']))
    with pytest.raises(ValueError, match='missing column'):
        analyze_trials(good, 'time')
    with pytest.raises(ValueError, match='no trial for subject s2, condition b'):
        analyze_trials(good[~((good.subject == 's2') & (good.condition == 'b'))], 'targets')
    with pytest.raises(ValueError, match='repeated trial'):
        analyze_trials(pd.concat([good, good.iloc[:1]]), 'targets')
    bad = good.copy()
    bad['targets'] = bad['targets'].astype(object)
    bad.iloc[0, bad.columns.get_loc('targets')] = 'lots'
    with pytest.raises(ValueError, match='non-numeric targets'):
        analyze_trials(bad, 'targets')
    with pytest.raises(ValueError, match='not in'):
        analyze_trials(good, 'targets', conditions=['a'])


# ------------------------------------------------------------------------ text

def test_format_analysis_is_an_aligned_report():
    text = format_analysis(analyze_blocks(paper_table()))
    assert 'Friedman chi-square = 16.837, df = 3, p = 7.64e-04' in text
    lines = text.splitlines()
    for label in (condition_label(c) for c in (C1, C2, C3, C4)):
        assert any(line.startswith(label) for line in lines)
    summary = [line for line in lines if line.startswith(('1 surface', '2 surface', '3 simple', '4 speech'))][:4]
    assert len({len(line) for line in summary}) == 1  # the last column right-aligned
    assert '+4.031' in text and '3.34e-04' in text and '***' in text
    assert 'B(tie)' in text and 'sum to 16' in text


def test_small_helpers():
    assert [stars(p) for p in (0.2, 0.05, 0.049, 0.0099, 0.00099, float('nan'))] == ['', '', '*', '**', '***', '']
    assert format_p(0.01234) == '0.0123' and format_p(0.0001234) == '1.23e-04' and format_p(float('nan')) == 'n/a'
    assert condition_label('speech') == '4 speech' and condition_label('other') == 'other'
