"""Run the ``study`` CLI in a subprocess with the fake trainer (for kill/resume tests).

    python drive_study.py run toy --profile quick ...
"""

from __future__ import annotations

import sys
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).resolve().parent))

from conftest import use_fakes  # noqa: E402

if __name__ == "__main__":
    mp = pytest.MonkeyPatch()
    use_fakes(mp)
    from harness.cli.study import main

    raise SystemExit(main(sys.argv[1:]))
