"""The synthetic capture studio (``relight synth``): a capture video plus its ground truth."""
