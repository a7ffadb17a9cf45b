"""Thin command-line layer: argument parsing, calls into the libraries, exit codes."""
