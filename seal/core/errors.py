"""The base class of expected failures: bad input, a missing, damaged or foreign file.

The CLI's error boundary (`seal.cli.main`) prints such an error's message on one line and exits with status 2;
the message names the file, field or option and says what to do. Library users catch the specific subclasses
(`seal.core.dataset.DatasetError`, the results store's ``StoreError``, ...) or this base.
"""

from __future__ import annotations


class SealError(Exception):
    """An expected failure whose message is meant for the user (see the module docstring)."""
