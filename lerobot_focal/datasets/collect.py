"""Old path of :mod:`lerobot_focal.datasets.making.collect`, kept only for a run started before the move.

A `lerobot-focal-bench grid` that was already running when the datasets package was split into making/, repair/
and fast_loading/ holds ``python -m lerobot_focal.datasets.collect`` in memory and runs it to collect its demos.
Use ``lerobot-focal-collect`` or ``python -m lerobot_focal.datasets.making.collect``; delete this file once no run
started before the move is left.
"""

from lerobot_focal.datasets.making.collect import main

if __name__ == "__main__":
    raise SystemExit(main())
