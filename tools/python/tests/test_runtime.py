"""The solve as a running thing: Ctrl-C then resume, two solves in two threads, the GIL released
while solving, and a large field read without copying."""

import os
import signal
import subprocess
import sys
import threading
import time

import numpy as np
import pytest

import lpm
from conftest import blob, same_bits, scene_dict


def gpu_table():
    # The GPU backend (lavapipe here): the one that checkpoints and stops at a slice, as the CLI.
    # A checkpoint after every order, so a cancelled solve has one to resume from.
    return scene_dict(blob((24, 24, 24)), albedo=0.95, max_orders=24, tolerance=1e-12, checkpoint_every_seconds=0)


@pytest.fixture(scope="module")
def uninterrupted(tmp_path_factory):
    whole = lpm.solve(gpu_table(), out=tmp_path_factory.mktemp("gpu") / "whole", backend="gpu", no_image=True)
    assert whole.report["orders"] == 24
    return whole


def resume_and_compare(out, whole):
    assert (out / ".lpm-work/checkpoint.json").is_file()
    assert not (out / "fluence.raw").exists()
    # Without resume (or fresh) the checkpoint is in the way, as in the CLI.
    with pytest.raises(lpm.Error) as e:
        lpm.solve(gpu_table(), out=out, backend="gpu", no_image=True)
    assert "--resume" in str(e.value)
    resumed = lpm.solve(gpu_table(), out=out, backend="gpu", no_image=True, resume=True)
    assert resumed.report["orders"] == 24
    assert same_bits(resumed.fluence, whole.fluence)
    assert same_bits(resumed.source, whole.source)


def test_ctrl_c_cancels_at_a_slice_and_resume_gives_the_uninterrupted_result(tmp_path, uninterrupted):
    seen = []

    def ctrl_c_at_order_3(event):
        seen.append(event.get("order"))
        if event.get("order") == 3:
            # A real SIGINT to this process, as a terminal's Ctrl-C sends it (Python raises the
            # KeyboardInterrupt in this callback, which stops the solve like any exception here).
            os.kill(os.getpid(), signal.SIGINT)

    out = tmp_path / "cut"
    with pytest.raises(lpm.Cancelled) as e:
        lpm.solve(gpu_table(), out=out, backend="gpu", no_image=True, progress=ctrl_c_at_order_3)
    assert isinstance(e.value, KeyboardInterrupt) and isinstance(e.value, lpm.Error)
    assert e.value.resumable
    assert "cancelled" in str(e.value) and "--resume" in str(e.value)
    assert 3 in seen and max(o for o in seen if o is not None) < 24
    resume_and_compare(out, uninterrupted)


CTRL_C_CHILD = r"""
import sys
sys.path.insert(0, sys.argv[2])
import lpm
from test_runtime import gpu_table

def progress(event):
    print(event["phase"], event.get("order"), flush=True)

try:
    lpm.solve(gpu_table(), out=sys.argv[1], backend="gpu", no_image=True, progress=progress)
except lpm.Cancelled as e:
    print("cancelled", e.resumable, e, flush=True)
    sys.exit(3)
print("finished", flush=True)
"""


def test_ctrl_c_from_outside_while_waiting_cancels_and_resumes(tmp_path, uninterrupted):
    # SIGINT from another process while the solve's thread is waiting (not in a callback): the
    # 50 ms poll sees the pending KeyboardInterrupt and raises the cancel flag.
    out = tmp_path / "cut"
    tests = os.path.dirname(__file__)
    child = subprocess.Popen(
        [sys.executable, "-c", CTRL_C_CHILD, str(out), tests], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True
    )
    lines = []
    for line in child.stdout:
        lines.append(line.strip())
        if line.startswith("orders 2"):
            child.send_signal(signal.SIGINT)
            break
    rest, err = child.communicate(timeout=300)
    lines += rest.split("\n")
    assert child.returncode == 3, (lines, err)
    assert any(l.startswith("cancelled True the solve was cancelled") for l in lines), lines
    resume_and_compare(out, uninterrupted)


def test_an_exception_in_progress_stops_the_solve_and_propagates(tmp_path):
    class Stop(Exception):
        pass

    def stop(event):
        if event.get("order") == 1:
            raise Stop("enough")

    table = scene_dict(blob(), max_orders=12, tolerance=1e-9, checkpoint_every_seconds=0)
    with pytest.raises(Stop):
        lpm.solve(table, out=tmp_path / "o", backend="gpu", no_image=True, progress=stop)
    assert (tmp_path / "o/.lpm-work/checkpoint.json").is_file()


def test_ctrl_c_during_a_cpu_solve_cancels_it(tmp_path):
    # The CPU backend stops before its next direction's sweep, as the CLI's does at SIGINT: the
    # solve raises lpm.Cancelled (a KeyboardInterrupt), publishes nothing, and keeps no checkpoint
    # (it writes none), so OUT, which it created, is gone.
    def ctrl_c_at_order_1(event):
        if event.get("order") == 1:
            os.kill(os.getpid(), signal.SIGINT)

    out = tmp_path / "o"
    with pytest.raises(lpm.Cancelled):
        lpm.solve(scene_dict(blob()), out=out, backend="cpu", no_image=True, progress=ctrl_c_at_order_1)
    assert not (out / "report.json").exists()
    assert not (out / "fluence.raw").exists()


def test_two_solves_in_two_threads(tmp_path):
    tables = [scene_dict(blob(seed=1), albedo=0.8), scene_dict(blob(seed=2), albedo=0.95)]
    alone = [lpm.solve(t, out=tmp_path / f"alone{i}", backend="cpu", no_image=True) for i, t in enumerate(tables)]

    spans, results, errors = {}, {}, []

    def run(i):
        try:
            start = time.monotonic()
            results[i] = lpm.solve(tables[i], out=tmp_path / f"thread{i}", backend="cpu", threads=1, no_image=True)
            spans[i] = (start, time.monotonic())
        except BaseException as e:  # noqa: BLE001 - reported by the assertion below
            errors.append(e)

    threads = [threading.Thread(target=run, args=(i,)) for i in range(2)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert not errors, errors
    # They ran at the same time (each started before the other ended) ...
    assert spans[0][0] < spans[1][1] and spans[1][0] < spans[0][1]
    # ... and each gave what it gives alone.
    for i in range(2):
        assert same_bits(results[i].fluence, alone[i].fluence)
        assert same_bits(results[i].source, alone[i].source)


def test_the_gil_is_released_while_solving(tmp_path):
    done = threading.Event()
    counted = []

    def count():
        # Pure Python: it only advances while this thread holds the GIL.
        n = 0
        while not done.is_set():
            n += 1
        counted.append(n)

    table = scene_dict(blob((32, 32, 32)), max_orders=12, tolerance=1e-9)
    counter = threading.Thread(target=count)
    start = time.monotonic()
    counter.start()
    # sys.setswitchinterval's 5 ms would let the counter run between bytecodes even if the solve
    # held the GIL in Python code; the solve is one call, so only a released GIL lets it run.
    lpm.solve(table, out=tmp_path / "o", backend="cpu", no_image=True)
    seconds = time.monotonic() - start
    done.set()
    counter.join()
    assert seconds > 0.2, "the solve was too short to tell"
    # A held GIL would leave the counter at ~0 for the whole solve; released, it counts freely
    # (millions per second): demand at least 100 000 per second of solve.
    assert counted[0] > 100_000 * seconds, (counted[0], seconds)


RSS_PROBE = r"""
import sys, numpy as np, lpm

def status(key):
    for line in open("/proc/self/status"):
        if line.startswith(key + ":"):
            return int(line.split()[1]) * 1024
    raise SystemExit(f"no {key} in /proc/self/status")

result = lpm.open_result(sys.argv[1])
anon0, file0 = status("RssAnon"), status("RssFile")
fluence = result.fluence
assert fluence.shape == (256, 256, 256, 1), fluence.shape
total = 0.0
for z in range(256):          # every page of the 64 MiB field, a plane at a time
    total += float(np.nansum(fluence[:, :, z, 0]))
anon1, file1 = status("RssAnon"), status("RssFile")
copy = np.array(fluence)      # the control: a real copy
anon2 = status("RssAnon")
print(total, anon1 - anon0, file1 - file0, anon2 - anon1)
"""


def test_a_256_cubed_field_is_read_without_copying(tmp_path):
    # A 256³ field in the layout a solve writes (fluence.json from a real solve, its dims made
    # 256³): solving 256³ here would take minutes on a CPU; the reading is what is measured.
    small = lpm.solve(scene_dict(blob((16, 16, 16))), out=tmp_path / "small", backend="cpu", no_image=True)
    info = small.field_info("fluence")
    n = 256
    info["dims"] = [n, n, n]
    out = tmp_path / "big"
    out.mkdir()
    (out / "fluence.json").write_text(__import__("json").dumps(info))
    field = np.arange(n**3, dtype="<f4").reshape(n, n, n) % 1000.0  # indexed [z, y, x]: file order
    field.tofile(out / "fluence.raw")
    expected = float(np.sum(field, dtype=np.float64))
    del field
    done = subprocess.run(
        [sys.executable, "-c", RSS_PROBE, str(out)], capture_output=True, text=True, check=False
    )
    assert done.returncode == 0, done.stderr
    total, anon_read, file_read, anon_copy = (float(v) for v in done.stdout.split())
    mib = 1 << 20
    assert abs(total - expected) <= 1e-5 * expected
    # Reading all 64 MiB brought the file's pages in (file-backed memory) ...
    assert file_read > 48 * mib, file_read / mib
    # ... but no copy: the process's own (anonymous) memory grew by far less than the field ...
    assert anon_read < 8 * mib, anon_read / mib
    # ... while a real copy grows it by the field's size (the measure works).
    assert anon_copy > 60 * mib, anon_copy / mib
