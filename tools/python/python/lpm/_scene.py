"""Scenes: a TOML file, a TOML string or a dict with the keys of a scene file, whose volume may be
a NumPy array or a ``pyopenvdb`` grid.

Why scenes are staged as files: the solve is the CLI's own job (``lpm::job``), which reads a scene
file and the files it names, so that a Python solve is the CLI's solve, bitwise, checkpoints and
``--resume`` included. A scene that is not already a file is therefore written, with its arrays,
into ``OUT/input/`` (``scene.toml``, ``density.raw``, …) before the solve: ``lpm solve
OUT/input/scene.toml --out OUT`` reruns it from the shell. A file scene is used where it is.

Volume arrays — axes, stated plainly: an array ``a`` of shape ``(nx, ny, nz)`` is indexed
``a[x, y, z]``: x is the first axis, z the last, the world axes of the scene (its camera's ``up``
says which one is up). ``volume.dims`` is taken from the shape. Any memory order (C or
Fortran) and float32 or float64 (rounded to float32, as lpm stores densities) is accepted; the
raw file written is lpm's layout (little-endian f32, x fastest, then y, then z), written one
z-plane at a time so that a large array is never copied whole.
"""

import json
import os
from pathlib import Path

import numpy as np

from . import _lpm
from .errors import SceneError

try:  # Python 3.11+
    import tomllib as _toml
except ImportError:  # pragma: no cover - older Pythons
    _toml = None

#: The ``[volume]`` keys that name a raw f32 file of the volume's dims: each may be an array.
ARRAY_KEYS = {
    "raw": "density.raw",
    "emission_raw": "emission.raw",
    "temperature_raw": "temperature.raw",
    "albedo_raw": "albedo.raw",
}
#: The ``[volume]`` keys that may be a ``pyopenvdb`` grid (written into one staged VDB file).
GRID_KEYS = ("vdb", "emission_grid", "temperature_grid", "albedo_grid")


def _is_vdb_grid(value):
    return type(value).__module__.split(".")[0] in ("pyopenvdb", "openvdb") and hasattr(value, "transform")


class Scene:
    """A scene for :func:`lpm.solve` and :func:`lpm.reference`.

    Make one with :meth:`load` (a TOML file), :meth:`from_toml` (TOML text) or :meth:`from_dict`
    (the same keys as a scene file: ``{"volume": {"raw": array, "voxel_size": 1.0}, "medium":
    {...}, "lights": [{...}], ...}``). In a dict, ``volume.raw``, ``volume.emission_raw``,
    ``volume.temperature_raw`` and ``volume.albedo_raw`` may be NumPy arrays (see the module docs
    for the axes), and ``volume.vdb`` (and ``*_grid``) ``pyopenvdb`` grids. A relative file path
    resolves against ``base_dir`` (default: the current directory; for a file scene, its
    directory, as the CLI resolves it).
    """

    def __init__(self, *, path=None, text=None, table=None, base_dir=None, name=None):
        self.path = Path(path) if path is not None else None
        self._text = text
        self._table = table
        self.base_dir = Path(base_dir) if base_dir is not None else None
        self.name = name

    @classmethod
    def load(cls, path):
        """A scene file, used where it is (nothing is staged for it)."""
        path = Path(path)
        return cls(path=path, base_dir=path.parent, name=str(path))

    @classmethod
    def from_toml(cls, text, base_dir=None):
        """Scene TOML text; messages name it ``<string>``."""
        if not isinstance(text, str):
            raise TypeError(f"scene text must be a str, not {type(text).__name__}")
        return cls(text=text, base_dir=base_dir, name="<string>")

    @classmethod
    def from_dict(cls, table, base_dir=None):
        """A dict with the keys of a scene file; messages name it ``<dict>``."""
        if not isinstance(table, dict):
            raise TypeError(f"a scene table must be a dict, not {type(table).__name__}")
        return cls(table=table, base_dir=base_dir, name="<dict>")

    def to_dict(self):
        """The scene's keys as a dict (a copy for a dict scene; parsed for a file or a string), to
        change and pass to :meth:`from_dict`."""
        if self._table is not None:
            return _copy_table(self._table)
        if _toml is None:  # pragma: no cover
            raise RuntimeError("reading TOML needs Python 3.11 (tomllib)")
        text = self._text if self._text is not None else self.path.read_text(encoding="utf-8")
        self.validate()
        return _toml.loads(text)

    def _nominal(self):
        base = self.base_dir
        return str(base / self.name) if base is not None else self.name

    def _base(self):
        return Path(os.path.abspath(self.base_dir if self.base_dir is not None else os.getcwd()))

    def validate(self):
        """Checks the scene as ``lpm solve`` does (a dict scene's arrays are written to a temporary
        directory for it). Raises :class:`lpm.SceneError` or :class:`lpm.InputFileError`."""
        if self.path is not None:
            _lpm.vdb_placement(str(self.path))
        elif self._text is not None:
            _lpm.prepare_scene(self._text, self._nominal(), str(self._base()))
        else:
            import tempfile

            with tempfile.TemporaryDirectory(prefix="lpm-scene-") as directory:
                self.stage(directory)

    def __repr__(self):
        return f"lpm.Scene({self.name})"

    def stage(self, directory):
        """The scene file a solve of this scene reads: a file scene's own path; otherwise
        ``directory/scene.toml``, written with its arrays beside it (and every relative path it
        names made absolute). Returns the path."""
        if self.path is not None:
            return self.path
        directory = Path(directory)
        directory.mkdir(parents=True, exist_ok=True)
        if self._text is not None:
            text = self._text
        else:
            table = _stage_arrays(self._table, directory, self.name)
            text = _lpm.dict_to_toml(json.dumps(table, default=_json_default), self.name)
        dest = directory / "scene.toml"
        _lpm.prepare_scene(text, self._nominal(), str(self._base()), str(dest))
        return dest


def as_scene(scene):
    """A :class:`Scene` from what :func:`lpm.solve` accepts: a Scene, a dict, a path (``str`` or
    ``os.PathLike``) of a scene file, or TOML text (a ``str`` holding a line break)."""
    if isinstance(scene, Scene):
        return scene
    if isinstance(scene, dict):
        return Scene.from_dict(scene)
    if isinstance(scene, str) and "\n" in scene:
        return Scene.from_toml(scene)
    if isinstance(scene, (str, os.PathLike)):
        return Scene.load(scene)
    raise TypeError(
        f"a scene is an lpm.Scene, a dict, a scene file's path or TOML text, not {type(scene).__name__}"
    )


def _copy_table(value):
    if isinstance(value, dict):
        return {k: _copy_table(v) for k, v in value.items()}
    if isinstance(value, list):
        return [_copy_table(v) for v in value]
    return value


def _json_default(value):
    if isinstance(value, np.generic):
        return value.item()
    if isinstance(value, np.ndarray):
        return value.tolist()
    if isinstance(value, os.PathLike):
        return os.fspath(value)
    raise TypeError(f"{type(value).__name__} is not a scene value")


def _volume_arrays(table, name):
    """The volume table and its array values, checked: (volume, {key: array})."""
    volume = table.get("volume")
    if not isinstance(volume, dict):
        return None, {}
    arrays = {}
    for key in ARRAY_KEYS:
        value = volume.get(key)
        if value is None or isinstance(value, (str, os.PathLike)):
            continue
        if not isinstance(value, np.ndarray):
            if hasattr(value, "__array__"):
                value = np.asarray(value)
            else:
                raise SceneError(
                    f"{name}: volume.{key}: expected a file path or a NumPy array, got {type(value).__name__}",
                    key=f"volume.{key}",
                )
        if value.ndim != 3:
            raise SceneError(
                f"{name}: volume.{key}: a volume array has 3 axes (x, y, z), got shape {value.shape}",
                key=f"volume.{key}",
            )
        if value.dtype not in (np.float32, np.float64):
            raise SceneError(
                f"{name}: volume.{key}: a volume array must be float32 or float64, got {value.dtype}",
                key=f"volume.{key}",
            )
        if 0 in value.shape:
            raise SceneError(f"{name}: volume.{key}: the array is empty (shape {value.shape})", key=f"volume.{key}")
        arrays[key] = value
    shapes = {key: tuple(a.shape) for key, a in arrays.items()}
    if len(set(shapes.values())) > 1:
        listed = ", ".join(f"volume.{k} {s}" for k, s in shapes.items())
        raise SceneError(f"{name}: the volume arrays differ in shape: {listed}", key="volume")
    dims = volume.get("dims")
    if shapes and dims is not None and "raw" in arrays:
        if [int(d) for d in dims] != list(arrays["raw"].shape):
            raise SceneError(
                f"{name}: volume.dims: {list(dims)} but volume.raw is an array of shape {arrays['raw'].shape} "
                "(leave dims out: it is taken from the shape)",
                key="volume.dims",
            )
    return volume, arrays


def write_raw(array, path):
    """Writes a 3-D array indexed ``[x, y, z]`` as lpm's raw layout (little-endian f32, x fastest,
    then y, then z), one z-plane at a time (a plane's copy at most)."""
    with open(path, "wb") as f:
        for z in range(array.shape[2]):
            # (nx, ny) plane; its transpose in C order is y slow, x fast: lpm's order in a plane.
            plane = np.ascontiguousarray(array[:, :, z].T, dtype="<f4")
            f.write(plane.tobytes())


def _stage_arrays(table, directory, name):
    """A copy of `table` whose arrays and grids are written into `directory` and named by path."""
    table = _copy_table(table)
    volume, arrays = _volume_arrays(table, name)
    if volume is None:
        return table
    for key, array in arrays.items():
        path = directory / ARRAY_KEYS[key]
        write_raw(array, path)
        volume[key] = str(path)
    if "raw" in arrays:
        volume.setdefault("dims", [int(n) for n in arrays["raw"].shape])
    grids = [(key, volume[key]) for key in GRID_KEYS if _is_vdb_grid(volume.get(key))]
    if grids:
        import pyopenvdb

        if grids[0][0] != "vdb":
            key = grids[0][0]
            raise SceneError(
                f"{name}: volume.{key}: a pyopenvdb grid here needs volume.vdb to be a pyopenvdb grid too "
                "(they are written into one file)",
                key=f"volume.{key}",
            )

        path = directory / "volume.vdb"
        written = []
        for key, grid in grids:
            if not grid.name:
                grid = grid.deepCopy()
                grid.name = "density" if key == "vdb" else key.removesuffix("_grid")
            written.append(grid)
            if key == "vdb":
                volume["vdb"] = str(path)
                volume.setdefault("grid", grid.name)
            else:
                volume[key] = grid.name
        pyopenvdb.write(str(path), grids=written)
    return table
