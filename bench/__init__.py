"""demo.bench."""
