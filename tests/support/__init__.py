"""Test support code that tests and benchmarks import as `tests.support.<module>` (the repository root on sys.path)."""
