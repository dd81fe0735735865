"""Errors ssga reports to its users.

Every subclass of :class:`SsgaError` is a *user* error: bad input, a bad config, a
plugin that would not load. The CLI prints its message on one line and exits with
status 1, without a traceback. Anything else escaping the CLI is a bug in ssga.
"""

from __future__ import annotations


class SsgaError(Exception):
    """Base class of the errors the CLI reports as one line, without a traceback."""


class InputError(SsgaError, ValueError):
    """An array, image, file or value that is not what ssga expected; the message names both."""


class VariantSyntaxError(SsgaError, ValueError):
    """A variant string that does not follow the grammar in :mod:`ssga_core.variants`.

    Attributes:
        text: the string as given.
        column: 1-based column of the offending character (``len(text) + 1`` for
            "something is missing at the end").
        reason: what was expected there.
    """

    def __init__(self, text: str, column: int, reason: str) -> None:
        self.text = text
        self.column = column
        self.reason = reason
        # A variant is a few letters; echo at most the start of a long string.
        shown = repr(text) if len(text) <= 40 else f"{text[:20]!r}... ({len(text)} characters)"
        super().__init__(f"invalid variant {shown}: column {column}: {reason}")


class PluginError(SsgaError):
    """A plugin that failed to import, registered something invalid, or clashes with another."""


class UnknownStageError(SsgaError, LookupError):
    """A stage name no installed plugin provides; the message lists the known names."""


class ConfigError(SsgaError):
    """A config with one or more problems, each reported as ``path: message``.

    Attributes:
        source: the file (or other origin) of the config.
        problems: every problem found, in document order.
    """

    def __init__(self, source: str, problems: list[str]) -> None:
        self.source = source
        self.problems = list(problems)
        n = len(self.problems)
        lines = "\n".join(f"  {p}" for p in self.problems)
        super().__init__(f"{source}: {n} problem{'s' if n != 1 else ''}\n{lines}")


class CheckpointError(SsgaError):
    """Missing, corrupt or mismatched model weights; names the config field and the file expected."""


class MissingWeightsError(CheckpointError):
    """The checkpoint a stage's ``weights`` field names is not there (the other checkpoint errors: it is there but wrong).

    An experiment reports the variants that need it as not run, naming the field and the
    file, and runs the others; a damaged or mismatched file stops the run instead.
    """
