"""The lean robot runtime: Johnson math, the fixed-memory fitter, features, segmentation, the sweep.

Imports numpy, msgpack and the standard library only.
"""
