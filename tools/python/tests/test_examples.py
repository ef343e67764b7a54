"""The two examples run as a user runs them (a subprocess each), on small volumes."""

import subprocess
import sys
from pathlib import Path

import numpy as np

import lpm

EXAMPLES = Path(__file__).resolve().parents[1] / "examples"


def run_example(name, *args):
    done = subprocess.run(
        [sys.executable, str(EXAMPLES / name), *map(str, args)], capture_output=True, text=True, check=False
    )
    assert done.returncode == 0, f"{name} failed:\n{done.stdout}\n{done.stderr}"
    return done.stdout


def test_the_numpy_cloud_example_plots_a_slice_and_the_image(tmp_path):
    out = tmp_path / "cloud"
    printed = run_example("cloud_numpy.py", "--size", 24, "--backend", "cpu", "--out", out)
    assert "order 1 done" in printed
    png = out / "cloud.png"
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    import matplotlib.image

    pixels = matplotlib.image.imread(png)
    assert pixels.shape[0] > 100 and pixels.shape[1] > 300
    assert pixels[..., :3].std() > 0.05, "the figure shows something"
    assert lpm.open_result(out).fluence.shape == (24, 24, 24, 3)


def test_the_vdb_example_writes_the_fluence_beside_the_density(tmp_path):
    import pyopenvdb

    smoke, lit, out = tmp_path / "smoke.vdb", tmp_path / "smoke_lit.vdb", tmp_path / "lpm-out"
    run_example("vdb_roundtrip.py", "--demo", smoke, lit, "--backend", "cpu", "--out", out)
    names = {g["name"] for g in pyopenvdb.readAllGridMetadata(str(lit))}
    assert names == {"density", "fluence"}
    density_in = pyopenvdb.read(str(smoke), "density")
    density_out = pyopenvdb.read(str(lit), "density")
    fluence = pyopenvdb.read(str(lit), "fluence")
    assert density_out.evalActiveVoxelBoundingBox() == density_in.evalActiveVoxelBoundingBox()
    assert fluence.transform.voxelSize() == density_in.transform.voxelSize()
    # The fluence grid lies on the density's index grid: lpm's voxel v is index lo + v.
    lo, hi = density_in.evalActiveVoxelBoundingBox()
    shape = tuple(h - l + 1 for l, h in zip(lo, hi))
    dense = np.zeros(shape, np.float32)
    fluence.copyToArray(dense, ijk=lo)
    solved = lpm.open_result(out).fluence[..., 0]
    assert solved.shape == shape
    assert np.array_equal(dense, np.nan_to_num(solved, nan=0.0))
    # lpm's own fluence.vdb agrees: the same index box.
    own = pyopenvdb.read(str(out / "fluence.vdb"), "fluence")
    own_dense = np.zeros(shape, np.float32)
    own.copyToArray(own_dense, ijk=lo)
    assert np.array_equal(own_dense, dense)
    # Result.write_vdb (lpm's own writer) puts the fluence on the same index box too.
    mine = lpm.open_result(out).write_vdb(tmp_path / "mine.vdb", grids={"density": solved})
    mine_dense = np.zeros(shape, np.float32)
    pyopenvdb.read(str(mine), "fluence").copyToArray(mine_dense, ijk=lo)
    assert np.array_equal(mine_dense, dense)
