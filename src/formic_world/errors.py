"""The one exception type for input a user gave that cannot be used (a scenario or model file,
a setting): the ``formic`` command reports it as one line instead of a traceback, wherever in
the code it is found."""


class InputError(ValueError):
    """A file, option or setting from the user that cannot be used; the message says why."""
