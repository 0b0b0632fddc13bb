"""Errors of the bridge (:mod:`uwval.bridge`)."""

from __future__ import annotations

from uwval.errors import UwvalError


class BridgeError(UwvalError):
    """A bridge peer broke the protocol, or a connection failed."""
