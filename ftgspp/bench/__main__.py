"""``python -m ftgspp.bench render ...``: ``ftgspp bench`` without the console script."""

from ftgspp.bench.cli import main

raise SystemExit(main())
