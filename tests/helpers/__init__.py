"""Builders shared by several test files: scenes, captures, twins. Test files import from here,
never from each other (tests/test_layout.py checks it)."""
