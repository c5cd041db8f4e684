"""Built-in hand plugins."""
