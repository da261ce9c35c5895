"""The one exception base a user can cause. The CLI turns it into one line and exit code 1."""


class FieldlocError(Exception):
    """An error caused by the user's input: missing file, wrong schema, invalid field, ..."""


class FieldSpecError(FieldlocError):
    """A field YAML is invalid; the message names the file and the key."""


class SchemaError(FieldlocError):
    """An artifact is not of the expected schema or version, or is corrupt."""


class DatasetError(FieldlocError):
    """A dataset folder is missing something or holds unreadable content."""
