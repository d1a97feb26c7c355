"""Errors a user can cause and fix: the CLI prints them as one line and exits non-zero."""


class HeightpipeError(Exception):
    """Base for every expected failure (bad input, bad config, missing model).

    The CLI catches these and prints ``heightpipe: error: <message>`` with no traceback;
    anything else escaping is a bug and keeps its traceback.
    """

    exit_code = 2


class ConfigError(HeightpipeError):
    """Unknown key, wrong type or bad value in config.toml or a command-line override."""


class SourceError(HeightpipeError):
    """A video, image folder or stream that cannot be opened or read."""


class ModelError(HeightpipeError):
    """A model file that is missing, unreadable or of the wrong shape."""


class MissingExtraError(HeightpipeError):
    """An optional dependency (an install extra: synth, train) that this command needs is missing."""
