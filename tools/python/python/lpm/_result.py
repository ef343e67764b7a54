"""Results: an output directory of ``lpm solve`` (or ``lpm reference``) opened from Python.

Why memory maps: the fields are dense f32 volumes that can be far larger than RAM (a 1024³ RGB
fluence is 12 GiB). ``fluence`` and ``source`` are read-only ``numpy.memmap`` views over the
files the solve wrote (``fluence.raw``, ``source.raw``): nothing is copied, pages are read when
touched and can be dropped again by the kernel, and the array equals the file bitwise because it
*is* the file.

Axes, stated plainly: ``result.fluence[x, y, z, c]`` — x, y, z as in the scene's volume (the
array a volume was given as is indexed ``[x, y, z]`` too), ``c`` the component (``grey``; or
``r, g, b``; the source of an anisotropic plan has one component per storage direction and
channel: ``result.field_info("source")["component_names"]``). The file's own layout is component
fastest, then x, y, z: the array is that file seen through strides, not a copy. NaN marks the
voxels of empty 16³ bricks in the fluence (no medium there: not solved), exactly as in the file.
"""

import json
from pathlib import Path

import numpy as np

from . import _lpm
from .errors import OutputError


def _read_json(path):
    try:
        with open(path, encoding="utf-8") as f:
            return json.load(f)
    except FileNotFoundError:
        raise OutputError(f"{path}: not found: is this an output directory of lpm solve?", path=str(path)) from None
    except (OSError, ValueError) as e:
        raise OutputError(f"{path}: cannot read it: {e}", path=str(path)) from None


def open_field(directory, base):
    """``directory/base.raw`` as a read-only array ``[x, y, z, component]`` (a memory map, no copy),
    described by ``directory/base.json``."""
    directory = Path(directory)
    info = _read_json(directory / f"{base}.json")
    nx, ny, nz = (int(d) for d in info["dims"])
    components = int(info["components"])
    raw = directory / info["file"]
    expected = nx * ny * nz * components * 4
    try:
        size = raw.stat().st_size
    except OSError as e:
        raise OutputError(f"{raw}: cannot read it: {e.strerror}", path=str(raw)) from None
    if size != expected:
        raise OutputError(
            f"{raw}: has {size} bytes, expected {expected} ({nx} × {ny} × {nz} voxels × {components} components × 4 bytes)",
            path=str(raw),
        )
    mapped = np.memmap(raw, dtype="<f4", mode="r", shape=(nz, ny, nx, components))
    return mapped.transpose(2, 1, 0, 3)


class Result:
    """An output directory of a solve: ``report`` (``report.json`` as a dict), ``fluence`` and
    ``source`` (memory-mapped arrays ``[x, y, z, component]``, see the module docs), ``render()``
    and ``write_vdb()``. ``lpm.open_result(OUT)`` opens one the CLI wrote just the same."""

    def __init__(self, out):
        self.out = Path(out)
        self._report = None
        self._fields = {}

    def __repr__(self):
        return f"lpm.Result({str(self.out)!r})"

    @property
    def report(self):
        """``report.json`` as a dict (plan, orders, residual history, energy balance, timings)."""
        if self._report is None:
            self._report = _read_json(self.out / "report.json")
        return self._report

    def field_info(self, base):
        """``base.json`` as a dict: dims, components and their names, units, layout."""
        return _read_json(self.out / f"{base}.json")

    def field(self, base):
        """``base.raw`` (``fluence``, ``source``, ``fluence_stderr``) as a memory-mapped array."""
        if base not in self._fields:
            self._fields[base] = open_field(self.out, base)
        return self._fields[base]

    @property
    def fluence(self):
        """The fluence φ over all orders, ``[x, y, z, component]``, float32, memory-mapped; NaN
        in empty bricks."""
        return self.field("fluence")

    @property
    def source(self):
        """The in-scattered source J summed over orders, ``[x, y, z, component]``, float32,
        memory-mapped; 0 in empty bricks."""
        return self.field("source")

    def render(
        self,
        *,
        width=None,
        height=None,
        eye=None,
        target=None,
        up=None,
        fov=None,
        camera=None,
        background="sky",
        image=None,
        exposure=None,
        view=None,
    ):
        """Renders the solved result again (``lpm render OUT``) and returns the image as a float32
        array of shape (height, width, 4): linear RGB and alpha = 1 − transmittance, top row first.

        The options are the CLI's: ``camera`` a camera TOML file (a ``[camera]`` table), then
        ``width``/``height`` (one alone keeps the aspect ratio), ``eye``/``target``/``up`` (world
        X, Y, Z), ``fov`` (vertical, degrees), ``background`` ("sky" or "transparent"). With no
        option, the solve's own view (its ``image.exr``, bitwise). ``image``: also write it there
        (.exr or .png); a PNG is exposed and tone-mapped as the solve's was, or with ``exposure``
        (stops as a number or string, or "auto") and ``view`` ("agx", "filmic", "standard")."""
        return _lpm.render(
            str(self.out),
            camera=None if camera is None else str(camera),
            width=width,
            height=height,
            eye=_vec3(eye, "eye"),
            target=_vec3(target, "target"),
            up=_vec3(up, "up"),
            fov=fov,
            background=background,
            exposure=None if exposure is None else str(exposure),
            view=view,
            image=None if image is None else str(image),
        )

    def write_vdb(self, path, fields=("fluence",), grids=None, precision="float"):
        """Writes the solved ``fields`` (each component a float grid: ``fluence``, or
        ``fluence_r``, ``fluence_g``, ``fluence_b``) and any extra ``grids`` (a dict of name →
        array ``[x, y, z]`` of the volume's shape, e.g. the density) into one OpenVDB file at
        ``path``, with lpm's own writer, on the placement of the solve's ``fluence.vdb`` (a VDB
        input's own index grid and transform). Active voxels: the solved ones (finite fluence);
        only 8³ leaves that hold one are written. ``precision``: "float" or "half"."""
        scene = self.report.get("scene")
        if not scene:
            raise OutputError(f"{self.out / 'report.json'}: names no scene", path=str(self.out / "report.json"))
        index_min, voxel_size, translation = _lpm.vdb_placement(scene)
        active = np.asarray(self.fluence[..., 0])
        out_grids = []
        for base in fields:
            info = self.field_info(base)
            names = info["component_names"]
            if len(names) == 1 and names[0] == "grey":
                grid_names = [base]
            else:
                grid_names = [f"{base}_{c.replace('.', '_')}" for c in names]
            data = self.field(base)
            for c, (grid_name, component) in enumerate(zip(grid_names, names)):
                metadata = [
                    ("class", "fog volume"),
                    ("lpm_quantity", f"{info['quantity']} ({component})"),
                    ("lpm_units", info["units"]),
                ]
                out_grids.append((grid_name, metadata, data[..., c]))
        for name, array in (grids or {}).items():
            array = np.asarray(array, dtype=np.float32)
            out_grids.append((name, [("class", "fog volume")], array))
        _lpm.write_vdb(
            str(path),
            out_grids,
            active,
            index_min=tuple(index_min),
            voxel_size=voxel_size,
            translation=tuple(translation),
            precision=precision,
        )
        return Path(path)


class ReferenceResult(Result):
    """An output directory of ``lpm reference``: ``fluence``, ``fluence_stderr`` (its per-voxel
    standard error) and ``report``."""

    @property
    def fluence_stderr(self):
        return self.field("fluence_stderr")


def open_result(out):
    """Opens an output directory of ``lpm solve`` written by the CLI or by :func:`lpm.solve`."""
    return Result(out)


def _vec3(value, name):
    if value is None:
        return None
    values = [float(v) for v in value]
    if len(values) != 3:
        raise ValueError(f"{name} must be 3 numbers (X, Y, Z), got {len(values)}")
    return values
