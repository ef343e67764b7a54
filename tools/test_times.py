#!/usr/bin/env python3
"""The end of tools/test.sh's output: the time of each phase, the slowest tests, and the totals.

Usage: test_times.py PHASES_FILE JUNIT_XML [JUNIT_XML ...]

PHASES_FILE holds one line per phase, "NAME SECONDS STATUS" (written by test.sh). Each JUnit XML
is a test runner's own record of its tests (cargo-nextest's and pytest's `--junitxml`), read for
every test's time and outcome; a file that is missing (its phase never ran) is named and skipped.
The last line is the suite's closing line, "tests: N passed, M failed", so that the budget of the
next test added can be judged against the list above it.
"""

import sys
import xml.etree.ElementTree as ET

SLOWEST = 20


def phases(path):
    rows = []
    with open(path) as f:
        for line in f:
            parts = line.split()
            if len(parts) == 3:
                rows.append((parts[0], int(parts[1]), parts[2]))
    return rows


def cases(path):
    """(name, seconds, passed) for every test case of one JUnit file."""
    out = []
    for case in ET.parse(path).getroot().iter("testcase"):
        if case.find("skipped") is not None:
            continue
        failed = case.find("failure") is not None or case.find("error") is not None
        suite = case.get("classname", "")
        out.append((f"{suite} {case.get('name', '?')}".strip(), float(case.get("time", "0")), not failed))
    return out


def main(argv):
    if len(argv) < 2:
        sys.exit(__doc__)
    rows = phases(argv[1])
    total = sum(s for _, s, _ in rows)
    print("\nphase times (s):")
    for name, seconds, status in rows:
        mark = "" if status == "ok" else f"  ({status})"
        print(f"  {name:<16} {seconds:>6}{mark}")
    print(f"  {'all':<16} {total:>6}")
    tests = []
    for path in argv[2:]:
        try:
            tests += cases(path)
        except FileNotFoundError:
            print(f"(no test record at {path}: its phase did not run)")
        except ET.ParseError as e:
            print(f"(test record {path} is not valid XML: {e})")
    tests.sort(key=lambda t: -t[1])
    print(f"\nthe {min(SLOWEST, len(tests))} slowest tests (s):")
    for name, seconds, ok in tests[:SLOWEST]:
        print(f"  {seconds:8.1f}  {name}{'' if ok else '  FAILED'}")
    failed = [name for name, _, ok in tests if not ok]
    for name in failed:
        print(f"failed: {name}")
    passed = len(tests) - len(failed)
    print(f"tests: {passed} passed, {len(failed)} failed")


if __name__ == "__main__":
    main(sys.argv)
