"""``python -m graytrack`` is the same as the ``graytrack`` console script."""

from graytrack.service.cli import main

if __name__ == "__main__":  # Dask's worker processes import the main module again: run nothing then
    raise SystemExit(main())
