"""The exceptions every lpm call raises.

One base class, :class:`Error`, so ``except lpm.Error`` catches anything the library refuses; a
subclass per kind of failure a script reacts to differently. Each carries the message the ``lpm``
command line prints after ``lpm:`` (the error and its causes in one line, naming the file and the
scene key), and as attributes:

- ``path``: the file the error is about (the scene file, the raw or VDB volume, an output), or None;
  a scene given as a dict or as TOML text is named ``<dict>`` or ``<string>`` (prefixed by its
  ``base_dir`` when one was given), in the message and here;
- ``key``: the dotted scene key (``medium.albedo[1]``, ``volume.raw``), or None.
"""


class Error(Exception):
    """Anything lpm refuses or fails at."""

    def __init__(self, message, path=None, key=None):
        super().__init__(message)
        self.message = message
        self.path = path
        self.key = key


class SceneError(Error):
    """The scene's content is wrong: a key unknown, missing, mistyped or out of range (``key``
    names it), or a volume array of the wrong shape or type."""


class InputFileError(Error):
    """An input file cannot be read or holds bad data: the scene file itself, the raw, VDB,
    NanoVDB or NRRD volume, a per-voxel emission/temperature/albedo file, an environment map
    (``path`` names it)."""


class DeviceError(Error):
    """The Vulkan device: no loader or driver, no such device, a budget too small or larger than
    the device, a device limit, a validation error."""


class OutputError(Error):
    """The output directory: cannot be created or written, no disk space, another lpm run holds
    it, a result that is missing or unreadable."""


class Cancelled(Error, KeyboardInterrupt):
    """The solve was stopped by Ctrl-C (or SIGINT) at a slice, its last checkpoint kept, exactly
    as the CLI stops on SIGINT: ``solve(..., resume=True)`` continues it to bitwise the result of an
    uninterrupted solve. Also a ``KeyboardInterrupt``, so a script's ``except KeyboardInterrupt``
    still sees the Ctrl-C. ``resumable`` says whether a checkpoint was kept."""

    resumable = True
