"""Pipeline stages used by the entry points (each runs and tests without the next)."""
