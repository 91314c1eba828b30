"""The compiled simulation engine."""
