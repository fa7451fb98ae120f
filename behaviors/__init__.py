"""Built-in behaviors."""
BUILTIN_BEHAVIORS = []
