"""The documentation stays a map: the README is short and starts with the two commands, its links into docs/ resolve,
and neither the documentation nor the files around the nodes cite issue or brief numbers a reader cannot look up."""

import re
from pathlib import Path

from agiprobot_measurement._paths import PACKAGE_ROOT

README = PACKAGE_ROOT / "README.md"
DOCS = PACKAGE_ROOT / "docs"
README_MAX_LINES = 150
COMMANDS = ("make demo", "make test")

# "issue 12", "issues 12", "issue #12", "#12", "brief 004", "brief section 4.2", "seed 004"
PLANNING_NUMBER = re.compile(
    r"\bissues?\s+#?\d+|(?<![\w&#/])#\d{1,4}\b(?![\w-])|\bbrief\s+(?:section\s+)?\d|\bseed\s+0\d{2}\b", re.IGNORECASE
)
LINK = re.compile(r"\]\(([^)\s]+)\)")
TEXT_SUFFIXES = {".py", ".md", ".launch", ".test", ".yaml", ".yml", ".xacro", ".urdf", ".txt", ".cfg", ".rviz", ""}


def _slug(heading: str) -> str:
    """GitHub's anchor of a Markdown heading."""
    text = heading.strip().lower().replace("`", "")
    text = re.sub(r"[^\w\- ]", "", text)
    return text.replace(" ", "-")


def _anchors(path: Path) -> set[str]:
    return {_slug(line.lstrip("#")) for line in path.read_text().splitlines() if re.match(r"#{1,6} ", line)}


def _broken_links(page: Path) -> list[str]:
    broken = []
    for target in LINK.findall(page.read_text()):
        if re.match(r"[a-z]+://|mailto:", target):
            continue
        path_part, _, anchor = target.partition("#")
        resolved = (page.parent / path_part).resolve() if path_part else page
        if not resolved.exists():
            broken.append(f"{page.name}: {target} (no such file)")
        elif anchor and resolved.suffix == ".md" and anchor not in _anchors(resolved):
            broken.append(f"{page.name}: {target} (no such heading)")
    return broken


def _numbers_in(paths) -> list[str]:
    hits = []
    for path in paths:
        for number, line in enumerate(path.read_text(errors="replace").splitlines(), 1):
            match = PLANNING_NUMBER.search(line)
            if match:
                hits.append(f"{path.relative_to(PACKAGE_ROOT)}:{number}: {match.group(0)!r}")
    return hits


def _text_files(*folders: str, exclude: tuple[str, ...] = ()) -> list[Path]:
    files = []
    for folder in folders:
        root = PACKAGE_ROOT / folder
        candidates = [root] if root.is_file() else sorted(p for p in root.rglob("*") if p.is_file())
        files += [
            p
            for p in candidates
            if p.suffix in TEXT_SUFFIXES and "__pycache__" not in p.parts and p.name not in exclude
        ]
    return files


def test_readme_is_a_short_map():
    lines = README.read_text().splitlines()
    assert len(lines) <= README_MAX_LINES, (
        f"README.md has {len(lines)} lines (at most {README_MAX_LINES}): move detail to docs/"
    )


def test_readme_starts_with_the_two_commands():
    lines = [line for line in README.read_text().splitlines() if line.strip()]
    assert lines[0].startswith("# "), "README.md: the title first"
    assert lines[1].startswith("```"), "README.md: the commands right after the title"
    assert [line.split("#")[0].strip() for line in lines[2:4]] == list(COMMANDS), lines[1:5]


def test_readme_links_into_docs_resolve():
    text = README.read_text()
    targets = [t for t in LINK.findall(text) if t.startswith("docs/")]
    assert targets, "README.md links to no page in docs/"
    assert _broken_links(README) == []


def test_links_between_docs_pages_resolve():
    broken = [b for page in sorted(DOCS.rglob("*.md")) for b in _broken_links(page)]
    assert broken == []


def test_every_docs_page_is_reachable_from_the_readme():
    text = README.read_text()
    pages = {p.relative_to(PACKAGE_ROOT).as_posix() for p in DOCS.glob("*.md")}
    assert sorted(p for p in pages if p not in text) == []


def test_no_issue_or_brief_numbers_in_the_docs():
    assert _numbers_in([README, *sorted(DOCS.rglob("*.md")), *_text_files("docs", exclude=())]) == []


def test_no_issue_or_brief_numbers_around_the_nodes():
    files = _text_files("launch", "nodes", "test/ros", "packages") + _text_files("config", exclude=("nbv.yaml",))
    assert _numbers_in(files) == []


def test_the_ros_interface_reference_covers_every_node():
    """Every node type of nodes/ and packages/*/nodes/ has a section, and every section is checked by a rostest."""
    text = (DOCS / "ros-interface.md").read_text()
    type_lines = re.findall(r"^Types? (.+?), started by", text, re.M)
    documented = {name for line in type_lines for name in re.findall(r"`([^`]+)`", line)}
    node_types = {p.name for p in (PACKAGE_ROOT / "nodes").iterdir() if p.is_file()}
    node_types |= {p.name for p in PACKAGE_ROOT.glob("packages/*/nodes/*") if p.is_file()}
    assert sorted(node_types - documented) == [], "node types without a section in docs/ros-interface.md"
    sections = set(re.findall(r"^### Node `(/[^`]+)`(?: \((\w+)\))?", text, re.M))
    keys = {name + (f":{variant}" if variant else "") for name, variant in sections}
    checked = set()
    for test in (PACKAGE_ROOT / "test" / "ros").glob("test_ros_interface_reference*.test"):
        for value in re.findall(r'<param name="nodes" value="([^"]+)"', test.read_text()):
            checked |= set(value.split())
    assert sorted(keys - checked) == [], "sections no rostest checks"


def test_no_issue_or_brief_numbers_in_the_code():
    assert _numbers_in(_text_files("src", "scripts", "config/nbv.yaml")) == []
