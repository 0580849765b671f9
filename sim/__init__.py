"""demo.sim."""
