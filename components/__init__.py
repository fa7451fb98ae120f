"""Built-in components."""
BUILTIN_COMPONENTS = []
