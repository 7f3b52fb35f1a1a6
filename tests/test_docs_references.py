"""The repository stands alone: every document a tracked file names is a tracked file of it, and no
file cites documents that live outside it (design notes, planning files, a shared folder)."""

from __future__ import annotations

import argparse
import ast
import importlib
import json
import re
import shlex
import subprocess
from pathlib import Path, PurePosixPath

import pytest

REPO = Path(__file__).resolve().parents[1]
THIS = PurePosixPath("tests") / Path(__file__).name
# Markdown files the code writes into its outputs (`dotsim eval` writes OUT/eval.md, bench.gpu_check
# OUT/gpu_check.md): not documents.
OUTPUT_FILES = {"eval.md", "gpu_check.md"}
# A name like docs/FORMAT.md or GEOMETRY.md, not part of a longer path or URL.
MD_REFERENCE = re.compile(r"(?<![\w./-])((?:[\w.-]+/)*[\w-]+\.md)\b")
# A source file named by its path in the repository (tests/dotsim/rig/test_geometry.py), so that moving or
# renaming a module or a test leaves no reference behind.
PY_REFERENCE = re.compile(r"(?<![\w./-])((?:[\w.-]+/)+[\w-]+\.py)\b")
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


def test_named_source_files_exist():
    files = tracked_text_files()
    tracked = set(files)
    missing = [f"{name}:{text.count(chr(10), 0, m.start()) + 1}: {m.group(1)}"
               for name, text in files.items() if name != THIS
               for m in PY_REFERENCE.finditer(text) if not resolves(m.group(1), name, tracked)]
    assert not missing, "source files named but not in the repository:\n" + "\n".join(missing)


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
    line = "(tests/dotsim/test_rig.py) and config.py, python -m bench.run_all, https://x.org/tests/y.py"
    assert [m.group(1) for m in PY_REFERENCE.finditer(line)] == ["tests/dotsim/test_rig.py"]
    # built from parts, so that this file does not itself name the documents it bans
    md, shared = ".md", "shared/"
    for line in (f"(see ARCHITECTURE{md})", f"/work/plan{md}", f"../{shared}x", "The seed's UNet ablation"):
        assert OUTSIDE.search(line), line
    assert not OUTSIDE.search("the seed is at most 2^31 - 1; a changed seed's old value")


# ----------------------------------------------------------------------------- documented examples
# Every example the documents give is read here, so that the docs cannot rot: each `dotsim` command
# line names real subcommands and options (and parses, where it has no placeholders), each `python -m
# bench.X` names a real module and options it defines, each `make X` a real target, each config
# file named exists and loads, each rig file, JSON and Python example reads.

DOCUMENTS = ["README.md", *sorted(str(p.relative_to(REPO)) for p in (REPO / "docs").glob("*.md"))]
CODE_SPAN = re.compile(r"`([^`\n]+)`")
PLACEHOLDER = re.compile(r"^[A-Z][A-Z0-9_]*(\.\w+)?$|\.\.\.|[\[\]|<>*]")


def example_lines(name: str) -> list[tuple[str, str, bool]]:
    """(where, line, whole) of each line of a code block (fenced or indented by 4; whole: a command
    as one would type it) and each inline code span of a document (often a command's name alone),
    with backslash continuations joined and shell comments dropped."""
    lines, fenced, found = (REPO / name).read_text().splitlines(), False, []
    number, pending = 0, ""
    while number < len(lines):
        line = lines[number]
        number += 1
        if line.lstrip().startswith("```"):
            fenced = not fenced
            continue
        if fenced or line.startswith("    ") or re.match(r"^ {3}\s{4}", line):
            text = pending + line.strip()
            if text.endswith("\\"):
                pending = text[:-1] + " "
                continue
            pending = ""
            found.append((f"{name}:{number}", re.sub(r"\s+#.*$", "", text), True))
        else:
            found += [(f"{name}:{number}", span, False) for span in CODE_SPAN.findall(line)]
    return found


def commands(prefix: str) -> list[tuple[str, list[str], bool]]:
    """(where, tokens after `prefix`, whole) of every documented command line starting with it."""
    found = []
    for name in DOCUMENTS:
        for where, line, whole in example_lines(name):
            for part in re.split(r"\s*(?:&&|;|\|(?=\s))\s*", line):
                if part.startswith(prefix + " "):
                    try:
                        tokens = shlex.split(part)
                    except ValueError:
                        tokens = part.split()
                    found.append((where, tokens[len(prefix.split()):], whole))
    return found


def _subparsers(parser) -> dict:
    return next((a.choices for a in parser._actions if isinstance(a, argparse._SubParsersAction)), {})


def _option_names(parser) -> set[str]:
    return {s for action in parser._actions for s in action.option_strings}


def test_documented_dotsim_commands_are_real():
    from commands.cli import build_parser

    top = build_parser()
    problems, checked = [], 0
    for where, tokens, whole in commands("dotsim"):
        parser, path = top, []
        for token in tokens:  # the subcommand path: `dotsim capture record ...`
            choices = _subparsers(parser)
            if not choices or token.startswith("-"):
                break
            if token not in choices:
                if not PLACEHOLDER.search(token):
                    problems.append(f"{where}: dotsim {' '.join(path + [token])}: no such command")
                parser = None
                break
            parser, path = choices[token], path + [token]
        if parser is None or not path:
            continue
        checked += 1
        known = _option_names(parser)
        for token in tokens:
            option = token.strip("[],").split("=")[0]
            if option.startswith("-") and option not in ("-", "--") and not option[1:2].isdigit() \
                    and option not in known:
                problems.append(f"{where}: dotsim {' '.join(path)}: no option {option}")
        if whole and not any(PLACEHOLDER.search(t) for t in tokens):
            try:
                top.parse_args(tokens)
            except SystemExit:
                problems.append(f"{where}: `dotsim {' '.join(tokens)}` does not parse")
    assert checked > 30, checked
    assert not problems, "\n".join(problems)


def test_documented_bench_modules_make_targets_and_configs_are_real():
    problems = []
    for prefix in ("python -m", "python3 -m"):
        for where, tokens, _ in commands(prefix):
            if not tokens or not tokens[0].startswith("bench."):
                continue
            module = REPO / (tokens[0].replace(".", "/") + ".py")
            if not module.is_file():
                problems.append(f"{where}: no module {tokens[0]}")
                continue
            source = module.read_text()
            # options a bench declares with a helper of another bench module (add_side_by_side_options)
            for imported in re.findall(r"^from (bench\.\w+) import", source, re.MULTILINE):
                source += (REPO / (imported.replace(".", "/") + ".py")).read_text()
            for token in tokens[1:]:
                option = token.strip("[],").split("=")[0]
                if option.startswith("--") and f'"{option}"' not in source:
                    problems.append(f"{where}: {tokens[0]} has no option {option}")
    targets = set(re.findall(r"^([\w-]+):", (REPO / "Makefile").read_text(), re.MULTILINE))
    for where, tokens, _ in commands("make"):
        problems += [f"{where}: no make target {t}" for t in tokens if not t.startswith("-") and "=" not in t
                     and not PLACEHOLDER.search(t) and t not in targets]
    for name in DOCUMENTS:
        named = re.findall(r"(?<![\w/])(?:dotsim/)?configs/[\w.-]+\.toml", (REPO / name).read_text())
        for config in sorted(set(named)):
            if not (REPO / config).is_file():
                problems.append(f"{name}: {config} does not exist")
    assert not problems, "\n".join(problems)


def test_every_shipped_config_loads():
    from dotsim.config_schema import ConfigError
    from generator.config import load_config as generator_config
    from trainer.config import load_config as trainer_config

    paths = sorted((REPO / "dotsim" / "configs").glob("*.toml"))
    assert paths, "no built-in configs found in dotsim/configs/"
    for path in paths:
        try:
            (trainer_config if path.name.startswith("train") else generator_config)(path)
        except ConfigError as error:  # every key checked; only the asset cache (`make assets`) is not built
            assert "[assets] cache_dir" in str(error) and "directory not found" in str(error), error


def fenced_blocks(language: str) -> list[tuple[str, str]]:
    """(where, text) of every ```language block of the documents."""
    found = []
    for name in DOCUMENTS:
        text = (REPO / name).read_text()
        for m in re.finditer(rf"^```{language}\n(.*?)^```", text, re.MULTILINE | re.DOTALL):
            found.append((f"{name}:{text.count(chr(10), 0, m.start()) + 1}", m.group(1)))
    return found


def test_documented_json_and_python_examples_read():
    problems = []
    for where, block in fenced_blocks("json"):
        if "..." in re.sub(r'"[^"]*"', '""', block):
            continue  # an abridged example (`...` outside strings) is no document to parse
        try:
            json.loads(block)
        except ValueError as error:
            problems.append(f"{where}: not JSON: {error}")
    for where, block in fenced_blocks("python"):
        tree = ast.parse(block)  # a syntax error fails the test, naming the block
        for node in ast.walk(tree):
            if isinstance(node, ast.ImportFrom) and node.module and node.module.split(".")[0] != "bpy":
                module = importlib.import_module(node.module)
                problems += [f"{where}: {node.module} has no {a.name}" for a in node.names
                             if not hasattr(module, a.name)]
    assert not problems, "\n".join(problems)


def test_the_rig_file_example_reads_as_written(tmp_path):
    """docs/GEOMETRY.md's OpenCV rig YAML, copied verbatim: its integer literals are read as the
    numbers they are (fx 600 and 1200, a 5 cm baseline), not refused."""
    from dotsim.rig.files import load_rig_file

    text = (REPO / "docs" / "GEOMETRY.md").read_text()
    block = re.search(r"^( +)%YAML:1\.0\n(?:\1.*\n)+", text, re.MULTILINE)
    assert block, "docs/GEOMETRY.md has no %YAML:1.0 rig example"
    indent = len(block.group(1))
    (tmp_path / "calibration.yaml").write_text("".join(line[indent:] + "\n"
                                                       for line in block.group(0).splitlines()))
    rig = load_rig_file(tmp_path / "calibration.yaml").rig
    sizes = (rig.camera.width, rig.camera.height, rig.projector.width, rig.projector.height)
    assert sizes == (640, 480, 1600, 1200)
    assert (rig.camera.fx, rig.camera.cx, rig.projector.fx, rig.projector.cy) == (600, 319.5, 1200, 599.5)
    assert abs(rig.baseline - 0.05) < 1e-12
