"""The ``tdtp`` command line: every subcommand, its parser, the live display and the summaries.

The entry point is :func:`tdtp.cli.main.main` (``tdtp`` and ``python -m tdtp``). The command line sits
on top of everything else and nothing in the library imports it (``tests/test_layering.py``).
"""
