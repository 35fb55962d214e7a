"""One module per ``graytrack`` subcommand; each exposes ``register(subparsers)``."""
