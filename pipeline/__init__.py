"""Offline side: a capture (phone video or RTI image set) -> reflectance bundle.

``relight.pipeline.synth`` is the synthetic capture studio: it simulates the paper's
acquisition on a procedural head whose truth is known, for tests and benchmarks.
"""
