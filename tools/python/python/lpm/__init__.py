"""lpm from Python: light transport in participating media, solved in process.

The ``lpm`` command line's work — solve a scene, render it again, a Monte-Carlo reference, a
comparison — as functions that take NumPy volumes and return NumPy fields::

    import numpy as np, lpm
    density = np.zeros((32, 32, 32), np.float32)      # indexed [x, y, z]
    density[8:24, 8:24, 8:24] = 1.0
    result = lpm.solve({"volume": {"raw": density, "voxel_size": 1.0},
                        "medium": {"sigma_t": 0.5, "albedo": 0.9},
                        "lights": [{"kind": "sky", "radiance": [0.3, 0.45, 0.75]}]},
                       out="out", backend="cpu")
    result.fluence[:, :, 16, 0]        # a z-slice of the fluence (memory-mapped, no copy)
    rgba = result.render(width=320)    # (height, width, 4) float32

Why in process and not a subprocess: the solve is the library's ``lpm::job::run``, the very
function the CLI runs, so the outputs are the CLI's bitwise (same files, same checkpoints, same
``--resume``), while the GIL is released for the whole solve (other Python threads run) and
Ctrl-C stops it the way SIGINT stops the CLI. Every library error is an :class:`lpm.Error`
subclass carrying the CLI's message (see :mod:`lpm.errors`).
"""

import json
import shutil
from pathlib import Path

from . import _lpm
from ._result import ReferenceResult, Result, open_field, open_result
from ._scene import Scene, as_scene, write_raw
from .errors import Cancelled, DeviceError, Error, InputFileError, OutputError, SceneError

__all__ = [
    "Scene",
    "Result",
    "ReferenceResult",
    "solve",
    "reference",
    "compare",
    "open_result",
    "open_field",
    "write_raw",
    "Error",
    "SceneError",
    "InputFileError",
    "DeviceError",
    "OutputError",
    "Cancelled",
]

#: Where a scene that is not a file is written inside an output directory (see :mod:`lpm._scene`).
INPUT_DIR = "input"


def _budget(value):
    if value is None:
        return None
    if isinstance(value, str):
        return _lpm.parse_byte_size(value)
    value = int(value)
    if value <= 0:
        raise ValueError("device_memory_budget must be more than 0 bytes")
    return value


def solve(
    scene,
    out,
    *,
    backend="gpu",
    device=None,
    device_memory_budget=None,
    threads=0,
    progress=None,
    resume=False,
    fresh=False,
    keep_store=False,
    no_image=False,
    no_fields=False,
    no_render_data=False,
    vdb_precision="float",
    background="sky",
    warm_start=None,
    validation=False,
):
    """Solves ``scene`` into the directory ``out``, as ``lpm solve SCENE --out OUT`` does, and
    returns the :class:`Result`.

    ``scene``: an :class:`lpm.Scene`, a dict of scene keys (volume arrays allowed), a scene file's
    path, or TOML text. A scene that is not a file is written to ``OUT/input/`` first (see
    :mod:`lpm._scene`). The other arguments are the CLI's flags: ``backend`` "gpu" (Vulkan) or
    "cpu" (the f64 twin); ``device`` (``--device``), ``device_memory_budget`` (bytes, or "2G");
    ``threads`` (CPU threads, 0: all); ``resume``, ``fresh``, ``keep_store``, ``no_image``,
    ``no_fields``, ``no_render_data``, ``vdb_precision``, ``background``, ``warm_start`` (an
    earlier output directory), ``validation`` (the Khronos layer).

    ``progress(event)`` is called in the calling thread with a dict: first ``{"phase": "store",
    "message": "building the brick store", ...}``, then after every order ``{"phase": "orders",
    "order", "residual", "max_orders", "tolerance", "seconds", "fraction", "seconds_left",
    "message"}`` — the CLI's line (``order 3 done, residual 1.234e-2``) and the job's estimate
    of the fraction done and the seconds left (``None`` while not known yet), the one the CLI's
    progress bar and ``lpm serve`` show.

    The GIL is released while the solve runs. Ctrl-C (or an exception raised by ``progress``)
    stops a GPU solve at its next slice with its last checkpoint kept and raises
    :class:`lpm.Cancelled` (a ``KeyboardInterrupt``) or that exception; ``resume=True`` then
    continues it to bitwise the uninterrupted result. A CPU solve stops before its next
    direction's sweep, as the CLI's does at SIGINT, and raises :class:`lpm.Cancelled` too; it keeps
    no checkpoint, so it is solved again from the start.
    """
    scene = as_scene(scene)
    out = Path(out)
    # As the CLI: a failed solve that created OUT and left no checkpoint to resume removes it.
    created = not out.exists()
    try:
        _lpm.check_unlocked(str(out))
        path = scene.stage(out / INPUT_DIR)
        _solve(path, out, backend, device, device_memory_budget, threads, progress, resume, fresh, keep_store,
               no_image, no_fields, no_render_data, vdb_precision, background, warm_start, validation)
    except BaseException:
        kept = (out / ".lpm-work" / "checkpoint.json").exists() or (out / "report.json").exists()
        if created and not kept:
            shutil.rmtree(out, ignore_errors=True)
        raise
    return Result(out)


def _solve(path, out, backend, device, device_memory_budget, threads, progress, resume, fresh, keep_store,
           no_image, no_fields, no_render_data, vdb_precision, background, warm_start, validation):
    _lpm.solve(
        str(path),
        str(out),
        backend=backend,
        device=device,
        device_memory_budget=_budget(device_memory_budget),
        threads=int(threads),
        resume=resume,
        fresh=fresh,
        keep_store=keep_store,
        no_image=no_image,
        no_fields=no_fields,
        no_render_data=no_render_data,
        vdb_precision=vdb_precision,
        background=background,
        warm_start=None if warm_start is None else str(warm_start),
        validation=validation,
        progress=progress,
    )


def reference(scene, out, *, samples, seed=0, image_spp=0, threads=0, orders=None):
    """The Monte-Carlo reference of ``scene`` into ``out`` (``lpm reference``): ``samples``
    photons per channel, ``seed`` (the same seed gives bitwise the same result), ``image_spp``
    camera paths per pixel (0: no image), ``threads`` (0: all), ``orders`` the scattering orders
    the image counts (``"1"``, ``"2..4"``, ``"2.."``; None: all). Returns a
    :class:`ReferenceResult` (``fluence``, ``fluence_stderr``, ``report``). The GIL is released;
    the reference cannot be stopped mid-way (neither can the CLI's): Ctrl-C is raised when it ends."""
    scene = as_scene(scene)
    out = Path(out)
    path = scene.stage(out / INPUT_DIR)
    _lpm.reference(
        str(path),
        str(out),
        int(samples),
        seed=int(seed),
        image_spp=int(image_spp),
        threads=int(threads),
        orders=None if orders is None else str(orders),
    )
    return ReferenceResult(out)


def compare(a, b, *, max_rel_stderr=0.05, scene=None, core_quantile=0.9, json_path=None):
    """``lpm compare A B``: the accuracy of output directory ``a`` (e.g. a solve) against ``b``
    (e.g. a reference) as a dict (what ``--json`` writes: relative L2, RMSE, max relative error,
    mean bias of the fluence, the images'), plus ``"text"``: the table the CLI prints. ``scene``
    (any scene :func:`solve` takes) adds the dense core's row. ``json_path``: also write the JSON."""
    a, b = Path(getattr(a, "out", a)), Path(getattr(b, "out", b))
    scene_path = None
    scratch = None
    if scene is not None:
        scene = as_scene(scene)
        if scene.path is None:
            import tempfile

            scratch = tempfile.TemporaryDirectory(prefix="lpm-compare-scene-")
        scene_path = str(scene.stage(scratch.name if scratch else a))
    try:
        text, table = _lpm.compare(
            str(a),
            str(b),
            max_rel_stderr=float(max_rel_stderr),
            scene=scene_path,
            core_quantile=float(core_quantile),
            json=None if json_path is None else str(json_path),
        )
    finally:
        if scratch is not None:
            scratch.cleanup()
    result = json.loads(text)
    result["text"] = table
    return result
