"""Domain exceptions. Each names what is wrong in words a client can act on; the API maps the class
to an HTTP status in one place (backend.api.errors)."""

from __future__ import annotations


class DomainError(Exception):
    """Base class; `message` is shown to the client."""

    def __init__(self, message: str) -> None:
        super().__init__(message)
        self.message = message


class NotFoundError(DomainError):
    pass


class AuthError(DomainError):
    """Missing, invalid or expired credentials."""


class PermissionDeniedError(DomainError):
    pass


class InvalidInputError(DomainError):
    """Well-formed but wrong: a keypoint outside the image, an unknown view, a mask of the wrong size."""


class ConflictError(DomainError):
    """The request is valid but the current state forbids it: wrong sample state, lease held by another."""


class LeaseExpiredError(ConflictError):
    pass


class TooLargeError(DomainError):
    pass


class ServiceUnavailableError(DomainError):
    """A service the request needs (the job broker) is unreachable; nothing was written, retry later."""


class RateLimitedError(DomainError):
    """Too many attempts (logins): refused before any work is done; `retry_after_s` says when to try again."""

    def __init__(self, message: str, retry_after_s: int) -> None:
        super().__init__(message)
        self.retry_after_s = retry_after_s
