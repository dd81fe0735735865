"""The whole suite's defaults (tests/, plugins/, examples/)."""

import os

# Work runs in this process unless a test names an executor: monkeypatched functions and
# stand-in stages reach the work, a failing stage shows its own traceback, and no test
# pays for starting worker processes. The executors themselves are tested by name
# (tests/bench/test_execution.py), the processes and Ray ones against this one.
os.environ.setdefault("SSGA_EXECUTOR", "serial")
