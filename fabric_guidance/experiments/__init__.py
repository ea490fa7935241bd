"""Statistics of the paper's experiments (no ROS): Friedman test with the Dunn-Bonferroni
post-hoc on subjects x conditions tables, violin plots and reports.

  stats    load_table, analyze_blocks, analyze_trials, format_analysis, BlockAnalysis
  plots    violin_plot (imports matplotlib; import it from .plots when needed)
  report   markdown_report
  analyze  the `fabric-guidance analyze` subcommand (add_parser, run, main)
"""
from .report import markdown_report
from .stats import (CONDITION_LABELS, BlockAnalysis, analyze_blocks, analyze_trials, condition_label,
                    format_analysis, format_p, load_table, paper_order, stars)

__all__ = ['BlockAnalysis', 'CONDITION_LABELS', 'analyze_blocks', 'analyze_trials', 'condition_label',
           'format_analysis', 'format_p', 'load_table', 'markdown_report', 'paper_order', 'stars']
