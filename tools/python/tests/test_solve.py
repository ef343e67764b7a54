"""The module against the CLI: NumPy in equals a raw file in, the arrays equal the CLI's files,
render/write_vdb/reference/compare as the CLI's commands, progress events."""

import json

import numpy as np
import pytest

import lpm
from conftest import blob, run_cli, same_bits, scene_dict


def write_scene_file(path, raw_name, shape, albedo=0.9):
    """The scene of `scene_dict` as a TOML file naming a raw density file."""
    path.write_text(
        f"""
[volume]
raw = "{raw_name}"
dims = [{shape[0]}, {shape[1]}, {shape[2]}]
voxel_size = 1.0

[medium]
sigma_t = 0.8
albedo = {albedo}

[[lights]]
kind = "sky"
radiance = 0.5

[[lights]]
kind = "sun"
direction = [0.3, -0.4, 0.8]
irradiance = 2.0

[solver]
directions_per_face = 2
max_orders = 16
tolerance = 1e-3

[camera]
width = 40
height = 30
"""
    )
    return path


@pytest.mark.parametrize("order, dtype", [("C", np.float32), ("F", np.float64)])
def test_a_numpy_volume_is_the_raw_file_bitwise(tmp_path, order, dtype):
    density = np.asarray(blob(dtype=np.float64), order=order, dtype=dtype)
    # The raw file a user would write by hand: lpm's layout, x fastest (Fortran order of [x, y, z]).
    by_hand = density.astype("<f4").ravel(order="F").tobytes()
    staged = tmp_path / "staged"
    lpm.Scene.from_dict(scene_dict(density)).stage(staged)
    assert (staged / "density.raw").read_bytes() == by_hand
    (tmp_path / "density.raw").write_bytes(by_hand)
    scene_file = write_scene_file(tmp_path / "scene.toml", "density.raw", density.shape)

    from_array = lpm.solve(scene_dict(density), out=tmp_path / "a", backend="cpu", no_image=True)
    from_file = lpm.solve(scene_file, out=tmp_path / "b", backend="cpu", no_image=True)
    assert from_array.fluence.shape == (*density.shape, 1)
    assert same_bits(from_array.fluence, from_file.fluence)
    assert same_bits(from_array.source, from_file.source)
    assert (tmp_path / "a/fluence.raw").read_bytes() == (tmp_path / "b/fluence.raw").read_bytes()
    # The staged scene is one the CLI reads: OUT/input/scene.toml names the staged volume.
    assert "density.raw" in (tmp_path / "a/input/scene.toml").read_text()


def test_the_arrays_are_the_cli_files_bitwise(tmp_path, lpm_cli):
    # Medium in x < 24 only: the bricks of x ≥ 32 are empty, unsolved, NaN in the fluence.
    density = np.zeros((40, 20, 16), np.float32)
    density[:24] = blob()
    (tmp_path / "density.raw").write_bytes(density.astype("<f4").ravel(order="F").tobytes())
    scene_file = write_scene_file(tmp_path / "scene.toml", "density.raw", density.shape)
    run_cli(lpm_cli, "solve", scene_file, "--out", tmp_path / "cli", "--backend", "cpu")
    result = lpm.solve(scene_file, out=tmp_path / "py", backend="cpu")

    nx, ny, nz = density.shape
    for base in ("fluence", "source"):
        cli_bytes = (tmp_path / "cli" / f"{base}.raw").read_bytes()
        assert (tmp_path / "py" / f"{base}.raw").read_bytes() == cli_bytes
        cli = np.frombuffer(cli_bytes, "<f4").reshape(nz, ny, nx, -1).transpose(2, 1, 0, 3)
        assert same_bits(result.field(base), cli)
    for name in ("fluence.vdb", "source.vdb", "image.exr", "image.png"):
        assert (tmp_path / "py" / name).read_bytes() == (tmp_path / "cli" / name).read_bytes(), name
    assert np.isnan(result.fluence[32:]).all() and not np.isnan(result.fluence[:32]).any()
    assert (result.source[32:] == 0).all()
    assert isinstance(result.fluence.base, np.memmap) or isinstance(result.fluence, np.memmap)
    cli_report = json.loads((tmp_path / "cli/report.json").read_text())
    assert result.report["orders"] == cli_report["orders"]
    untimed = lambda history: [{k: v for k, v in h.items() if k != "seconds"} for h in history]  # noqa: E731
    assert untimed(result.report["history"]) == untimed(cli_report["history"])
    assert result.report["energy"] == cli_report["energy"]

    # render(): the CLI's `lpm render` with the same camera options, and the solve's own view.
    rgba = result.render(width=32, eye=[40, -30, 30], image=tmp_path / "py-view.exr")
    run_cli(lpm_cli, "render", tmp_path / "cli", "--width", 32, "--eye", "40,-30,30", "--image", tmp_path / "cli-view.exr")
    assert (tmp_path / "py-view.exr").read_bytes() == (tmp_path / "cli-view.exr").read_bytes()
    assert rgba.dtype == np.float32 and rgba.shape[1] == 32 and rgba.shape[2] == 4
    assert 0.0 <= rgba[..., 3].min() and rgba[..., 3].max() <= 1.0 and rgba[..., 3].max() > 0.1
    own = result.render(image=tmp_path / "own.exr")
    assert own.shape == (30, 40, 4)
    assert (tmp_path / "own.exr").read_bytes() == (tmp_path / "py/image.exr").read_bytes()


def test_open_result_reads_a_cli_output_directory(tmp_path, lpm_cli):
    scene = tmp_path / "scene.toml"
    scene.write_text(
        '[volume]\nprocedural = "sphere"\ndims = [20, 20, 20]\n[medium]\nsigma_t = 1.0\nalbedo = 0.8\n'
        '[[lights]]\nkind = "sky"\nradiance = 1.0\n[solver]\ndirections_per_face = 2\nmax_orders = 8\n'
        "[camera]\nwidth = 16\n"
    )
    run_cli(lpm_cli, "solve", scene, "--out", tmp_path / "cli", "--backend", "cpu", "--no-image")
    opened = lpm.open_result(tmp_path / "cli")
    raw = np.fromfile(tmp_path / "cli/fluence.raw", "<f4").reshape(20, 20, 20).transpose(2, 1, 0)
    assert same_bits(opened.fluence[..., 0], raw)
    assert opened.report["backend"] == "cpu"


def test_progress_reports_the_store_then_every_order(tmp_path):
    events = []
    result = lpm.solve(scene_dict(blob()), out=tmp_path / "o", backend="cpu", no_image=True, progress=events.append)
    assert events[0]["phase"] == "store" and events[0]["message"] == "building the brick store"
    orders = [e for e in events if e["phase"] == "orders"]
    assert [e["order"] for e in orders] == [h["order"] for h in result.report["history"]]
    assert all(0.0 <= e["fraction"] <= 1.0 for e in orders)
    # The CLI's words, with Rust's exponent (3.111e-4, where Python writes 3.111e-04).
    mantissa, exponent = f"{orders[-1]['residual']:.3e}".split("e")
    assert orders[-1]["message"] == f"order {orders[-1]['order']} done, residual {mantissa}e{int(exponent)}"


def test_write_vdb_puts_the_fluence_beside_other_grids(tmp_path):
    import pyopenvdb
    density = blob()
    result = lpm.solve(scene_dict(density), out=tmp_path / "o", backend="cpu", no_image=True)
    path = result.write_vdb(tmp_path / "lit.vdb", grids={"density": density})
    grids = {g["name"] for g in pyopenvdb.readAllGridMetadata(str(path))}
    assert grids == {"fluence", "density"}
    fluence = pyopenvdb.read(str(path), "fluence")
    dense = np.zeros(density.shape, np.float32)
    fluence.copyToArray(dense, ijk=(0, 0, 0))
    solved = result.fluence[..., 0]
    assert np.array_equal(dense, np.nan_to_num(solved, nan=0.0))
    # The same grid as the solve's own fluence.vdb (the same writer, the same placement).
    own = np.zeros(density.shape, np.float32)
    pyopenvdb.read(str(tmp_path / "o/fluence.vdb"), "fluence").copyToArray(own, ijk=(0, 0, 0))
    assert np.array_equal(dense, own)
    back = np.zeros(density.shape, np.float32)
    pyopenvdb.read(str(path), "density").copyToArray(back, ijk=(0, 0, 0))
    active = np.isfinite(solved)
    assert np.array_equal(back[active], density[active])


def test_reference_and_compare_are_the_cli_commands(tmp_path, lpm_cli):
    density = blob((16, 16, 16))
    (tmp_path / "density.raw").write_bytes(density.astype("<f4").ravel(order="F").tobytes())
    scene_file = write_scene_file(tmp_path / "scene.toml", "density.raw", density.shape)
    solved = lpm.solve(scene_file, out=tmp_path / "solve", backend="cpu", no_image=True)
    ref = lpm.reference(scene_file, out=tmp_path / "ref", samples=20000, seed=7, threads=2)
    run_cli(lpm_cli, "reference", scene_file, "--out", tmp_path / "cli-ref", "--samples", 20000, "--seed", 7)
    assert (tmp_path / "ref/fluence.raw").read_bytes() == (tmp_path / "cli-ref/fluence.raw").read_bytes()
    assert ref.fluence_stderr.shape == ref.fluence.shape
    # The image's scattering orders (--orders): the same image bits as the CLI's, named in the report;
    # orders that are not N, N..M or N.. are a ValueError naming what was written.
    counted = lpm.reference(scene_file, out=tmp_path / "ref1", samples=16, seed=7, image_spp=1, orders="1")
    run_cli(
        lpm_cli, "reference", scene_file, "--out", tmp_path / "cli-ref1", "--samples", 16, "--seed", 7,
        "--image-spp", 1, "--orders", 1,
    )
    assert (tmp_path / "ref1/image.exr").read_bytes() == (tmp_path / "cli-ref1/image.exr").read_bytes()
    assert counted.report["image_orders"] == {"first": 1, "last": 1}
    with pytest.raises(ValueError, match="below the first"):
        lpm.reference(scene_file, out=tmp_path / "ref2", samples=16, image_spp=1, orders="3..1")

    table = lpm.compare(solved, ref, max_rel_stderr=0.5, scene=scene_file, json_path=tmp_path / "py.json")
    run_cli(
        lpm_cli, "compare", tmp_path / "solve", tmp_path / "ref",
        "--max-rel-stderr", 0.5, "--scene", scene_file, "--json", tmp_path / "cli.json",
    )
    cli = json.loads((tmp_path / "cli.json").read_text())
    assert json.loads((tmp_path / "py.json").read_text()) == cli
    assert {k: v for k, v in table.items() if k != "text"} == cli
    assert table["fluence"]["voxels_used"] > 0
    assert "rel" in table["text"].lower()


def test_per_voxel_emission_and_albedo_arrays_are_their_raw_files(tmp_path):
    density = blob((20, 18, 16))
    x = np.arange(20, dtype=np.float64)[:, None, None]
    emission = np.broadcast_to(np.exp(-((x - 6) ** 2) / 8.0), density.shape).astype(np.float64)  # F or C: any
    albedo = np.asfortranarray(np.clip(0.5 + density / 2, 0, 1)).astype(np.float32)
    for name, array in (("d.raw", density), ("e.raw", emission), ("a.raw", albedo)):
        (tmp_path / name).write_bytes(np.asarray(array, "<f4").ravel(order="F").tobytes())
    scene_file = write_scene_file(tmp_path / "scene.toml", "d.raw", density.shape)
    # The file's keys as a dict (Scene.to_dict), the files named by path, then by arrays.
    by_path = lpm.Scene.load(scene_file).to_dict()
    by_path["volume"].update(emission_raw="e.raw", albedo_raw="a.raw")
    by_path["medium"]["emission"] = 0.7
    by_array = lpm.Scene.load(scene_file).to_dict()
    by_array["volume"].update(raw=density, emission_raw=emission, albedo_raw=albedo)
    del by_array["volume"]["dims"]
    by_array["medium"]["emission"] = 0.7
    a = lpm.solve(lpm.Scene.from_dict(by_path, base_dir=tmp_path), out=tmp_path / "a", backend="cpu", no_image=True)
    b = lpm.solve(by_array, out=tmp_path / "b", backend="cpu", no_image=True)
    assert same_bits(a.fluence, b.fluence) and same_bits(a.source, b.source)
    assert a.report["plan"] == b.report["plan"]
    # The per-voxel fields were used: the emission makes the fluence differ from the plain scene's.
    plain = lpm.solve(scene_file, out=tmp_path / "plain", backend="cpu", no_image=True)
    assert not same_bits(plain.fluence, a.fluence)
