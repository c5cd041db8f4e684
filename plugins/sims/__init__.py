"""Built-in simulator plugins."""
