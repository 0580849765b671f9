"""demo.collect."""
