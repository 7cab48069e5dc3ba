"""Event and frame fusion: consumers of sequence folders (mapping, filling, scoring)."""
