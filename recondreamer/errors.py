"""Exceptions that the command line turns into a one-line message and a non-zero exit."""


class RecondreamerError(Exception):
    """Base class: an error caused by the user's input (file, argument, config), not a bug."""


class SceneFormatError(RecondreamerError):
    """A scene directory is missing a file or holds invalid data; the message names the file."""


class ConversionError(RecondreamerError):
    """A source file (Waymo TFRecord, ...) cannot be converted; the message names the file."""


class CheckpointError(RecondreamerError):
    """A checkpoint is missing, of the wrong kind or of an unknown format version."""


class ConfigValueError(RecondreamerError):
    """A config field holds a value outside its valid range; ``field`` names it (the command line
    turns it into its flag, ``cli_options.check_config``)."""

    def __init__(self, field: str, message: str):
        super().__init__(f"{field} {message}")
        self.field = field
        self.message = message
