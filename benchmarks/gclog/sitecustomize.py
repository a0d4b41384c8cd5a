"""Loaded by every Python process of a ``runs_per_hour.py --gc-log`` study (via PYTHONPATH).

When ``FTGSPP_GC_LOG`` names a file, every collection of generation 1 or 2 appends one line
to it: ``pid generation seconds collected``. Nothing else changes in the process.
"""

import gc
import os
import time

_LOG = os.environ.get("FTGSPP_GC_LOG")
if _LOG:
    _started = [0.0]

    def _log_collection(phase, info):
        if phase == "start":
            _started[0] = time.perf_counter()
        elif info["generation"] >= 1:
            seconds = time.perf_counter() - _started[0]
            with open(_LOG, "a") as f:
                f.write(f"{os.getpid()} {info['generation']} {seconds:.6f} {info['collected']}\n")

    gc.callbacks.append(_log_collection)
