"""`fabric-guidance tradeoff`: what accuracy costs in time, knob by knob (command.py says what it
sweeps and what it writes). One module per job, each importing only the ones above it:

  settings  the knobs, their grids and reference values, the scenes the sweep runs on
  runs      the simulation jobs (top level: they run in worker processes)
  rows      a knob value's accuracy and time with their spread, from the samples
  sweep     run_sweep: every knob value on the same wearers, as rows
  intervals the sweep over seeds or over variants of the scenes' values: t intervals, headlines
  reading   read_curve: the generated prose of tradeoff.md
  plot_marks what the plots draw at a point: its intervals (within range) and value labels
  plots     accuracy against time per knob, and the plane of all knobs and conditions
  report    tradeoff.csv, the markdown table, tradeoff.md
  command   the subcommand (configure, run, main)
"""
from __future__ import annotations

from .command import HELP, PROG, add_parser, configure, main, run, settings_from_args
from .intervals import (SeedRow, SeedSweep, headlines, parse_seeds, read_variants, run_seeds,
                        run_variants, t_interval)
from .plots import plot_knob, plot_plane
from .reading import (diff_se, gain_rate_reading, headline_lines, pareto_front, read_curve,
                      read_curve_interval)
from .report import markdown_table, write_outputs, write_variant_outputs
from .rows import Row
from .runs import calibrate_measured, calibration_key, speed_trial_detail
from .settings import (CSV_COLUMNS, DEFAULT_ACCURACY_SCENE, DEFAULT_GRIDS, DEFAULT_SPEED_SCENE,
                       KNOBS, PLANE_CONDITIONS, QUICK_GRIDS, Settings, as_protocol,
                       quick_settings)
from .sweep import SweepResult, run_sweep

__all__ = ['CSV_COLUMNS', 'DEFAULT_ACCURACY_SCENE', 'DEFAULT_GRIDS', 'DEFAULT_SPEED_SCENE',
           'HELP', 'KNOBS', 'PLANE_CONDITIONS', 'PROG', 'QUICK_GRIDS', 'Row', 'SeedRow', 'SeedSweep',
           'Settings', 'SweepResult', 'add_parser', 'as_protocol', 'calibrate_measured',
           'calibration_key', 'configure', 'diff_se', 'gain_rate_reading', 'headline_lines',
           'headlines', 'main', 'markdown_table', 'pareto_front', 'parse_seeds', 'plot_knob',
           'plot_plane', 'quick_settings', 'read_curve', 'read_curve_interval', 'read_variants',
           'run', 'run_seeds', 'run_sweep', 'run_variants', 'settings_from_args',
           'speed_trial_detail', 't_interval', 'write_outputs', 'write_variant_outputs']
