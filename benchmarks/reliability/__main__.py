import sys

from agiprobot_measurement.common.cli import run_main
from benchmarks.reliability.run import main

sys.exit(run_main(main, "benchmarks.reliability"))
