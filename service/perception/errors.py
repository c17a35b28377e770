"""Errors the perception core raises for input it cannot use."""


class InvalidInputError(ValueError):
    """The image, the mask or the parameters cannot be used; the message says why."""
