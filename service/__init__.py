"""The daemon and the command line: the only part of graytrack that owns processes and files."""
