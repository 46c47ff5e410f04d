"""Gymnasium environments of the testbed (registered when :mod:`testbed` is imported)."""
