"""``python -m tests.fuzz``: run the fuzz targets one after the other (see ``_runner.cli``; ``make fuzz``)."""
import sys

from tests.fuzz._runner import cli

sys.exit(cli())
