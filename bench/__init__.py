"""Benchmarks and evaluations of relight: the ``relight bench ...`` commands, the accuracy
bench against the synthetic truth and the real data, the numerical stability suite, the
real-face clips. They depend on the product (``pipeline``, ``kernels``, ``service``), never
the reverse (an import-linter contract, ``make lint``)."""
