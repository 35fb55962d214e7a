"""graytrack drivers/sim."""
