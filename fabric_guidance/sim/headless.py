"""Old name of sim/worked_example.py, kept for cli.py until the merge of issue 15 (the lead
removes it then)."""
from .worked_example import TurnResult, calibrate, guide, within  # noqa: F401
