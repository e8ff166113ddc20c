"""Errors that reach the user as one clear line (see cli.py)."""


class PhotonmcError(Exception):
    """Base class for errors caused by user input rather than by a bug."""


class SceneError(PhotonmcError):
    """A scene file is malformed, unsupported or describes invalid geometry."""


class SettingsError(PhotonmcError):
    """A render option is out of range or inconsistent."""
