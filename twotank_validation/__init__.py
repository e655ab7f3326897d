"""twotank_validation: frequency-domain model validation of LFT robust-control models.

The numerical core (this package minus the ``ros`` adapters) imports numpy, scipy and
cvxpy only. The method is R. S. Smith, "Model validation for robust control: an
experimental process control application", Automatica 31(11), 1995.
"""

__version__ = "0.1.0"
