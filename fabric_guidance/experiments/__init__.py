"""The paper's experiments on simulated wearers, their statistics and what is built on them
(no ROS). Each command module is imported only when its subcommand runs.

  stats             load_table, analyze_blocks, analyze_trials, format_analysis, BlockAnalysis:
                    Friedman test with the Dunn-Bonferroni post-hoc on subjects x conditions tables
  analysis_report   markdown_report, md_table, image_path: a report of one or more analyses
  violin_plots      violin_plot like the paper's figures (imports matplotlib: import it when needed)
  analyze           `fabric-guidance analyze`: the statistics of a CSV table
  paper             the paper's figures as data (means, SDs, per-subject tables, significance)
  experiment        `fabric-guidance experiment`: one protocol on simulated wearers, with report
  fit_wearer        `fabric-guidance fit-wearer`: the population fitted to the paper's table
  population_fit    the fit itself: a design population reweighted (importance weights), bootstrap
  paper_comparison  `fabric-guidance compare-paper`: every figure of the paper beside the model's
  tradeoff/         `fabric-guidance tradeoff`: what accuracy costs in time, one module per job
  sensitivity       `fabric-guidance sensitivity`: the headline figures against each assumed parameter
                    (the command; its runs in sensitivity_runs, its outputs in sensitivity_report)
  discussion/       `fabric-guidance beyond`: the Discussion's two open points, one module per study
"""
from .analysis_report import markdown_report
from .stats import (CONDITION_LABELS, BlockAnalysis, analyze_blocks, analyze_trials, condition_label,
                    format_analysis, format_p, load_table, paper_order, stars)

__all__ = ['BlockAnalysis', 'CONDITION_LABELS', 'analyze_blocks', 'analyze_trials', 'condition_label',
           'format_analysis', 'format_p', 'load_table', 'markdown_report', 'paper_order', 'stars']
