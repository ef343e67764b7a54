"""The Python module's costs against the CLI (benches/RESULTS.md, "The Python module"): the time
to import `lpm`, and a Python solve's wall time against `lpm solve` of the same scene, alternating
runs so that both meet the same machine load. A benchmark, not a test.

    tools/python/.venv/bin/python tools/python/bench_overhead.py --cli target/release/lpm \
        --scene tools/scenes/demo_cloud.toml --backend cpu --runs 2
"""

import argparse
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path


def import_seconds(runs):
    code = "import time; t = time.perf_counter(); import lpm; print(time.perf_counter() - t)"
    times = [float(subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout)
             for _ in range(runs)]
    return statistics.median(times), min(times)


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--cli", type=Path, required=True)
    parser.add_argument("--scene", type=Path, required=True)
    parser.add_argument("--backend", default="cpu", choices=["cpu", "gpu"])
    parser.add_argument("--runs", type=int, default=2)
    args = parser.parse_args()

    median, best = import_seconds(7)
    print(f"import lpm: median {median * 1e3:.1f} ms, best {best * 1e3:.1f} ms (7 fresh interpreters)")

    import lpm

    cli_times, py_times = [], []
    with tempfile.TemporaryDirectory(prefix="lpm-bench-") as tmp:
        for run in range(args.runs):
            out = Path(tmp) / f"cli{run}"
            t = time.perf_counter()
            subprocess.run([str(args.cli), "--log", "warn", "solve", str(args.scene), "--out", str(out),
                            "--backend", args.backend], check=True, capture_output=True)
            cli_times.append(time.perf_counter() - t)
            out_py = Path(tmp) / f"py{run}"
            t = time.perf_counter()
            result = lpm.solve(args.scene, out=out_py, backend=args.backend)
            py_times.append(time.perf_counter() - t)
            same = (out / "fluence.raw").read_bytes() == (out_py / "fluence.raw").read_bytes()
            print(f"run {run}: CLI {cli_times[-1]:.2f} s, Python {py_times[-1]:.2f} s, "
                  f"{result.report['orders']} orders, fluence bitwise equal: {same}", flush=True)
    c, p = min(cli_times), min(py_times)
    print(f"best of {args.runs}: CLI {c:.2f} s, Python {p:.2f} s, overhead {p - c:+.2f} s ({(p / c - 1) * 100:+.1f} %)")


if __name__ == "__main__":
    main()
