"""The repository stands alone: every document a tracked file names is a tracked file of it, and no
file cites documents that live outside it (design notes, planning files, a shared folder)."""

from __future__ import annotations

import re
import subprocess
from pathlib import Path, PurePosixPath

import pytest

REPO = Path(__file__).resolve().parents[1]
THIS = PurePosixPath("tests") / Path(__file__).name
# Markdown files the code writes into its outputs (`dotsim eval` writes OUT/eval.md): not documents.
OUTPUT_FILES = {"eval.md"}
# A name like docs/FORMAT.md or GEOMETRY.md, not part of a longer path or URL.
MD_REFERENCE = re.compile(r"(?<![\w./-])((?:[\w.-]+/)*[\w-]+\.md)\b")
OUTSIDE = re.compile(r"ARCHITECTURE\.md|\bplan\.md|\.\./shared|/work/|\bthe seed's\b", re.IGNORECASE)


def tracked_text_files() -> dict[PurePosixPath, str]:
    try:
        listing = subprocess.run(["git", "ls-files", "-z"], cwd=REPO, capture_output=True, check=True).stdout
    except (OSError, subprocess.CalledProcessError):
        pytest.skip("not a git checkout: the tracked files are unknown")
    files = {}
    for name in listing.decode().split("\0"):
        path = REPO / name
        if not name or not path.is_file():
            continue
        try:
            files[PurePosixPath(name)] = path.read_text(encoding="utf-8")
        except UnicodeDecodeError:
            continue  # binary
    return files


def resolves(reference: str, source: PurePosixPath, tracked: set[PurePosixPath]) -> bool:
    """A reference names a tracked file relative to its own folder, the repository root or docs/."""
    candidates = (source.parent / reference, PurePosixPath(reference), PurePosixPath("docs") / reference)
    return any(PurePosixPath(*_normal(c.parts)) in tracked for c in candidates)


def _normal(parts: tuple[str, ...]) -> list[str]:
    out: list[str] = []
    for part in parts:
        if part == "..":
            if out:
                out.pop()
        elif part != ".":
            out.append(part)
    return out


def test_named_documents_exist():
    files = tracked_text_files()
    tracked = set(files)
    missing = [f"{name}:{text.count(chr(10), 0, m.start()) + 1}: {m.group(1)}"
               for name, text in files.items() if name != THIS
               for m in MD_REFERENCE.finditer(text)
               if PurePosixPath(m.group(1)).name not in OUTPUT_FILES
               and not resolves(m.group(1), name, tracked)]
    assert not missing, "documents named but not in the repository:\n" + "\n".join(missing)


def test_no_documents_from_outside():
    files = tracked_text_files()
    cited = [f"{name}:{text.count(chr(10), 0, m.start()) + 1}: {m.group(0)}"
             for name, text in files.items() if name != THIS for m in OUTSIDE.finditer(text)]
    assert not cited, "files cite documents outside the repository:\n" + "\n".join(cited)


def test_the_checks_catch_what_they_should():
    # The patterns themselves, on lines that must and must not be flagged.
    tracked = {PurePosixPath("docs/FORMAT.md"), PurePosixPath("docs/GEOMETRY.md"), PurePosixPath("README.md")}
    found = lambda line: [m.group(1) for m in MD_REFERENCE.finditer(line)]  # noqa: E731
    assert found("see docs/FORMAT.md and [GEOMETRY.md](GEOMETRY.md).") == ["docs/FORMAT.md", "GEOMETRY.md",
                                                                          "GEOMETRY.md"]
    assert found("https://example.org/x/README.md") == []
    assert resolves("GEOMETRY.md", PurePosixPath("docs/FORMAT.md"), tracked)
    assert resolves("../README.md", PurePosixPath("docs/FORMAT.md"), tracked)
    assert resolves("docs/FORMAT.md", PurePosixPath("generator/config.py"), tracked)
    assert not resolves("docs/SCENE.md", PurePosixPath("generator/config.py"), tracked)
    # built from parts, so that this file does not itself name the documents it bans
    md, shared = ".md", "shared/"
    for line in (f"(see ARCHITECTURE{md})", f"/work/plan{md}", f"../{shared}x", "The seed's UNet ablation"):
        assert OUTSIDE.search(line), line
    assert not OUTSIDE.search("the seed is at most 2^31 - 1; a changed seed's old value")
