"""Storage-level failures that the REST layer turns into 404 and 409."""


class NotFound(LookupError):
    pass


class Conflict(RuntimeError):
    pass
