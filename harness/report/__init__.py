"""What a reader sees: the study's results (read side), sections that each return their
Markdown/LaTeX and files, the report writer, ``reports/index.md``, tables, plots and number
formatting. Imports ``analysis``, ``spec`` and ``tracking``; never the run side."""

from pathlib import Path

USER_REPORTS = Path("outputs/reports")  # where `study report` writes unless told (a user's own results)
COMMITTED_REPORTS = Path("reports")  # the committed answers: written only by `make reports` (--out reports)
