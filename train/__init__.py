"""demo.train."""
