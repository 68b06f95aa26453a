"""Command-line programs: replay, simulate, convert and bench."""
