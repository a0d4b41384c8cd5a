"""``python -m ftgspp.data.synthetic``: the ``ftgspp synth`` command (``build.main``)."""

from ftgspp.data.synthetic.build import main

raise SystemExit(main())
