"""graytrack drivers/camera."""
