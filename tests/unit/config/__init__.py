"""Unit tests of edge.config, one file per module (test_<module>.py)."""
