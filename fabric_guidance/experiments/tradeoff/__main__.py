"""python -m fabric_guidance.experiments.tradeoff: the subcommand without the entry point."""
import sys

from .command import main

sys.exit(main())
