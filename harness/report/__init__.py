"""What a reader sees: the study's results (read side), sections that each return their
Markdown/LaTeX and files, the report writer, ``reports/index.md``, tables, plots and number
formatting. Imports ``analysis``, ``spec`` and ``tracking``; never the run side."""
