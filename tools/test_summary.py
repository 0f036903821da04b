"""Count test cases over JUnit XML files and print `N passed, M failed` (the line CI reads)."""

import sys
import xml.etree.ElementTree as ET
from pathlib import Path


def count_file(path: Path) -> tuple[int, int, list[str]]:
    passed, failed, names = 0, 0, []
    try:
        root = ET.parse(path).getroot()
    except ET.ParseError as exc:
        return 0, 1, [f"{path.name}: unreadable result file ({exc})"]
    for case in root.iter("testcase"):
        if case.find("skipped") is not None:
            continue
        if case.find("failure") is not None or case.find("error") is not None:
            failed += 1
            names.append(f"{path.name}: {case.get('classname', '')}.{case.get('name', '')}")
        else:
            passed += 1
    return passed, failed, names


def main() -> int:
    results_dir, ros_results_dir, test_dir = Path(sys.argv[1]), Path(sys.argv[2]), Path(sys.argv[3])
    passed = failed = 0
    failures: list[str] = []
    lint = results_dir / "lint"
    if lint.exists():
        ok = lint.read_text().strip() == "ok"
        passed, failed = int(ok), int(not ok)
        if not ok:
            failures.append("lint (ruff check / ruff format --check)")
    for xml in sorted(results_dir.glob("*.xml")):
        p, f, n = count_file(xml)
        passed, failed, failures = passed + p, failed + f, failures + n
    # rostest writes rosunit-*.xml (one test case per unittest method) and rostest-*.xml (one per .test
    # file, failing when a node under test died or a test never reported); count the first, and the
    # second only where it failed.
    for xml in sorted(ros_results_dir.rglob("*.xml")):
        p, f, n = count_file(xml)
        if xml.name.startswith("rostest-"):
            failed, failures = failed + f, failures + n
            if p + f == 0:
                # a test node that died before reporting leaves a rostest file without test cases
                failed += 1
                failures.append(f"{xml.name}: no test results (the test node crashed or never ran)")
        else:
            passed, failed, failures = passed + p, failed + f, failures + n
    # a .test whose launch file does not even load leaves no result file at all
    for test_file in sorted(test_dir.glob("*.test")):
        if not any(ros_results_dir.rglob(f"rostest-*{test_file.stem}.xml")):
            failed += 1
            failures.append(f"{test_file.name}: no result file (rostest did not run it)")
    for name in failures:
        print(f"FAILED: {name}")
    print(f"{passed} passed, {failed} failed")
    return 1 if failed or passed == 0 else 0


if __name__ == "__main__":
    sys.exit(main())
