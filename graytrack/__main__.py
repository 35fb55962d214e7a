"""``python -m graytrack`` is the same as the ``graytrack`` console script."""

from graytrack.service.cli import main

raise SystemExit(main())
