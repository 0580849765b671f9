"""demo.curate."""
