"""demo.cli."""
