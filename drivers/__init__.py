"""graytrack drivers."""
