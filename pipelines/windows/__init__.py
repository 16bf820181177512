"""Long clips as overlapping windows (docs: join.py until the split)."""
