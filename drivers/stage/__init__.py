"""graytrack drivers/stage."""
