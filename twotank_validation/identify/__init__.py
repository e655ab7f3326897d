"""Identification: from a periodic experiment to a nominal model and its weights.

Nonparametric frequency responses with their noise and distortion levels
(:mod:`.nonparametric`, :mod:`.lpm`); layers: it imports ``core`` and below only.
"""
