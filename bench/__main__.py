import signal
import sys

from dbc.lifeline import tie_from_environment

# started by the pytest plugin or a campaign worker (BENCH_PARENT_PID): SIGTERM when that process dies, the way a
# stop is asked for (the target stopped, no partial output left), before anything is imported or started
if tie_from_environment() is False:
    sys.exit(128 + signal.SIGTERM)   # the parent is gone already: nothing was started

from bench.cli import main  # noqa: E402 - after the tie: a parent dying during the imports stops this process

sys.exit(main())
