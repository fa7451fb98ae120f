"""Tooling that measures the product, apart from the core it measures: ``sweep`` (``lokigraph
bench``: parameter sweeps against references, Pareto tables, scaling), ``references`` (the
independent truths a bench scene names), ``stress`` (``lokigraph stress``: the stress suite), and
micro-benchmarks of kernels run with ``python -m``: ``kernels`` (constraint sweeps),
``broadphase`` and ``narrowphase`` (collision)."""
