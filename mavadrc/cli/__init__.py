"""Command-line entry points: argument parsing and each command's main."""
