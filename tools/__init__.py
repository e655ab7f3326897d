"""Test and benchmark harnesses (stream, node and long-run fuzzers); not part of the package."""
