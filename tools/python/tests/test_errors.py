"""Every library error is an lpm.Error subclass carrying the CLI's message, file and key."""

import numpy as np
import pytest

import lpm
from conftest import blob, run_cli, scene_dict


def cli_message(cli, *args):
    """The CLI's one-line message (`lpm: …` without the prefix) for a failing command."""
    done = run_cli(cli, *args, check=False)
    assert done.returncode != 0, "the CLI was expected to fail"
    line = [l for l in done.stderr.splitlines() if l.startswith("lpm: ")][-1]
    return line[len("lpm: "):]


def test_a_bad_value_in_a_scene_file_is_a_scene_error_with_the_cli_message(tmp_path, lpm_cli):
    scene = tmp_path / "bad.toml"
    scene.write_text('[volume]\nprocedural = "sphere"\ndims = [16, 16, 16]\n[medium]\nsigma_t = 1.0\nalbedo = 1.5\n')
    with pytest.raises(lpm.SceneError) as e:
        lpm.solve(scene, out=tmp_path / "o", backend="cpu")
    assert isinstance(e.value, lpm.Error)
    assert e.value.key == "medium.albedo"
    assert e.value.path == str(scene)
    assert str(e.value) == cli_message(lpm_cli, "solve", scene, "--out", tmp_path / "cli", "--backend", "cpu")
    assert "medium.albedo" in str(e.value) and "1.5" in str(e.value)


def test_an_unknown_key_in_a_dict_names_the_dict_and_the_key(tmp_path):
    table = scene_dict(blob())
    table["medium"]["albedoo"] = 0.5
    with pytest.raises(lpm.SceneError) as e:
        lpm.solve(table, out=tmp_path / "o", backend="cpu")
    assert str(e.value).startswith("<dict>: ")
    assert "albedoo" in str(e.value)


def test_a_toml_string_error_names_the_line(tmp_path):
    with pytest.raises(lpm.SceneError) as e:
        lpm.Scene.from_toml('[volume]\nprocedural = "sphere"\ndims = [16, 16]\n').validate()
    assert str(e.value).startswith("<string>: ")
    assert "volume.dims" in str(e.value)


def test_a_missing_raw_file_is_an_input_file_error_naming_it(tmp_path, lpm_cli):
    scene = tmp_path / "scene.toml"
    scene.write_text('[volume]\nraw = "nowhere.raw"\ndims = [16, 16, 16]\n[medium]\nsigma_t = 1.0\nalbedo = 0.8\n')
    with pytest.raises(lpm.InputFileError) as e:
        lpm.solve(scene, out=tmp_path / "o", backend="cpu")
    assert e.value.path == str(tmp_path / "nowhere.raw")
    assert e.value.key == "volume.raw"
    assert str(e.value) == cli_message(lpm_cli, "solve", scene, "--out", tmp_path / "cli", "--backend", "cpu")


def test_a_bad_density_in_an_array_is_an_input_file_error_naming_the_voxel(tmp_path):
    density = blob()
    density[3, 4, 5] = -1.0
    with pytest.raises(lpm.InputFileError) as e:
        lpm.solve(scene_dict(density), out=tmp_path / "o", backend="cpu")
    assert "voxel (3, 4, 5)" in str(e.value)
    assert e.value.path == str(tmp_path / "o/input/density.raw")
    # As the CLI: a failed solve that created its output directory (and left no checkpoint) removes it.
    assert not (tmp_path / "o").exists()


@pytest.mark.parametrize(
    "value, words",
    [
        (np.zeros((4, 4), np.float32), "3 axes"),
        (np.zeros((4, 4, 4), np.int32), "float32 or float64"),
        ("not-an-array-or-path".encode(), "a file path or a NumPy array"),
    ],
)
def test_a_bad_volume_array_is_a_scene_error_naming_the_key(tmp_path, value, words):
    with pytest.raises(lpm.SceneError) as e:
        lpm.solve(scene_dict({"raw": value}), out=tmp_path / "o", backend="cpu")
    assert e.value.key == "volume.raw"
    assert words in str(e.value)


def test_dims_that_contradict_the_array_name_the_key(tmp_path):
    with pytest.raises(lpm.SceneError) as e:
        lpm.solve(scene_dict({"raw": blob(), "dims": [8, 8, 8]}), out=tmp_path / "o", backend="cpu")
    assert e.value.key == "volume.dims"


def test_a_missing_device_is_a_device_error_with_the_cli_message(tmp_path, lpm_cli):
    scene = tmp_path / "scene.toml"
    scene.write_text('[volume]\nprocedural = "sphere"\ndims = [16, 16, 16]\n[medium]\nsigma_t = 1.0\nalbedo = 0.8\n')
    with pytest.raises(lpm.DeviceError) as e:
        lpm.solve(scene, out=tmp_path / "o", backend="gpu", device=99)
    assert str(e.value) == cli_message(lpm_cli, "solve", scene, "--out", tmp_path / "cli", "--device", 99)


def test_a_budget_too_small_is_a_device_error_naming_the_flag(tmp_path):
    with pytest.raises(lpm.DeviceError) as e:
        lpm.solve(scene_dict(blob()), out=tmp_path / "o", backend="gpu", device_memory_budget="1K")
    assert str(e.value).startswith("--device-memory-budget: ")
    assert "too small" in str(e.value)


def test_a_busy_output_directory_is_an_output_error_and_stays_untouched(tmp_path):
    import fcntl

    out = tmp_path / "o"
    out.mkdir()
    with open(out / ".lpm-lock", "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX | fcntl.LOCK_NB)
        with pytest.raises(lpm.OutputError) as e:
            lpm.solve(scene_dict(blob()), out=out, backend="cpu")
    assert "another lpm run is writing to this directory" in str(e.value)
    assert not (out / "input").exists()


def test_resume_on_the_cpu_backend_is_refused_as_the_cli_refuses_it(tmp_path, lpm_cli):
    scene = tmp_path / "scene.toml"
    scene.write_text('[volume]\nprocedural = "sphere"\ndims = [16, 16, 16]\n[medium]\nsigma_t = 1.0\nalbedo = 0.8\n')
    with pytest.raises(lpm.Error) as e:
        lpm.solve(scene, out=tmp_path / "o", backend="cpu", resume=True)
    assert str(e.value) == cli_message(
        lpm_cli, "solve", scene, "--out", tmp_path / "cli", "--backend", "cpu", "--resume"
    )


def test_a_progress_that_cannot_be_called_is_refused_before_solving(tmp_path):
    with pytest.raises(TypeError, match="progress must be callable"):
        lpm.solve(scene_dict(blob()), out=tmp_path / "o", backend="cpu", progress="not callable")
    assert not (tmp_path / "o").exists()


def test_an_absurd_thread_count_is_a_value_error_naming_the_limit(tmp_path):
    """threads=100000 kept starting threads for ever in the CLI (issue 57): refused at once."""
    with pytest.raises(ValueError) as e:
        lpm.solve(scene_dict(blob()), out=tmp_path / "o", backend="cpu", threads=100000)
    assert "threads=100000" in str(e.value) and "at most" in str(e.value)
    assert not (tmp_path / "o").exists()
