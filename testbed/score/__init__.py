"""Scoring of estimators on a standard scenario suite (``testbed score``)."""
