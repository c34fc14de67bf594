"""Tiny canonical scenes used by the tests."""
