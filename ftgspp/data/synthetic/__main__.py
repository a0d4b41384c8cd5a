"""``python -m ftgspp.data.synthetic``: the ``ftgspp synth`` command (``generate.main``)."""

from ftgspp.data.synthetic.generate import main

raise SystemExit(main())
