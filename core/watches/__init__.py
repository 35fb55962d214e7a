"""Validity watches, one module each (``make(tracker) -> Watch | None``): see core/validity.py."""
