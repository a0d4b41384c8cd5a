"""``python -m ftgspp.diagnostics RUN_DIR``: the ``ftgspp diagnose`` command (``diagnose.main``)."""

from ftgspp.diagnostics.diagnose import main

raise SystemExit(main())
