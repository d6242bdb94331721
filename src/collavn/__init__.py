"""collavn: collaborative multi-agent visual navigation.

Scenes → simulator state → renderer → observations → policy → actions → simulator.
"""

__version__ = "0.1.0"
