"""The Discussion studies' wing: the paper's two open points tried in simulation
(`fabric-guidance beyond`). Each study keeps its trials, analysis, plots and report section in one
module.

per_wearer_gain  the first open point: a per-wearer adjustment gain G, tuned on trials of its own
moving_targets   the second open point: moving targets under three versions of Eq. 5
trials           what seeds a trial of either study: TrialKey, the condition they run in
arms             the paper's statistics (Friedman, Dunn-Bonferroni) on compared arms, per wearer
studies          both studies on the same simulated wearers, in parallel over wearers
beyond           the `fabric-guidance beyond` command: runs the studies, writes CSVs, plots, report
"""
