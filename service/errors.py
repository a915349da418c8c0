"""The error a request can cause, answered as JSON with its HTTP status (never a server error)."""

from __future__ import annotations


class ServiceError(Exception):
    """An error a request caused: HTTP status, a kind for the metrics, a message saying what to change."""

    def __init__(self, status: int, kind: str, message: str):
        super().__init__(message)
        self.status, self.kind, self.message = status, kind, message
