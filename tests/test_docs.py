"""The README and the documentation site say what the code does: the README is short, every page
is in the site's navigation, links and anchors resolve, the Python examples run (doctest), the
shell blocks marked ``<!-- test: run -->`` run, and every dotted ``mbus_framework`` name a page
mentions exists."""
from __future__ import annotations

import doctest
import importlib
import os
import re
import shlex
import subprocess
import sys
import unicodedata
from pathlib import Path

import pytest
import yaml

REPO = Path(__file__).resolve().parents[1]
DOCS = REPO / "docs"
PAGES = sorted(DOCS.glob("*.md"))
MARKDOWN = [REPO / "README.md", *PAGES]
RUN_MARKER = "<!-- test: run -->"
FENCE = re.compile(r"^```(\w*)\s*$")


def blocks(path: Path) -> list[tuple[str, str, bool]]:
    """(language, text, marked runnable) of every fenced code block."""
    out, lines, i = [], path.read_text(encoding="utf-8").splitlines(), 0
    while i < len(lines):
        m = FENCE.match(lines[i].strip())
        if m and lines[i].strip() != "```" or (m and m.group(1) == ""):
            marked = i > 0 and lines[i - 1].strip() == RUN_MARKER
            j = i + 1
            while j < len(lines) and lines[j].strip() != "```":
                j += 1
            out.append((m.group(1), "\n".join(lines[i + 1:j]), marked))
            i = j + 1
        else:
            i += 1
    return out


def slug(text: str) -> str:
    """Python-Markdown's toc slug (what mkdocs uses for heading anchors)."""
    text = re.sub(r"`|\*\*|\[([^\]]*)\]\([^)]*\)", r"\1", text)
    text = unicodedata.normalize("NFKD", text).encode("ascii", "ignore").decode("ascii")
    text = re.sub(r"[^\w\s-]", "", text).strip().lower()
    return re.sub(r"[-\s]+", "-", text)


def anchors(path: Path) -> set[str]:
    text = path.read_text(encoding="utf-8")
    text = re.sub(r"```.*?```", "", text, flags=re.S)
    return {slug(m.group(1)) for m in re.finditer(r"^#{1,6}\s+(.+?)\s*$", text, flags=re.M)}


def nav_pages(node) -> list[str]:
    if isinstance(node, str):
        return [node]
    if isinstance(node, list):
        return [p for item in node for p in nav_pages(item)]
    if isinstance(node, dict):
        return [p for v in node.values() for p in nav_pages(v)]
    return []


@pytest.fixture
def sandbox(tmp_path, monkeypatch) -> Path:
    """A working directory that sees the repository's configs and examples (runs/ lands here)."""
    for name in ("configs", "examples"):
        (tmp_path / name).symlink_to(REPO / name)
    monkeypatch.chdir(tmp_path)
    monkeypatch.setenv("MPLBACKEND", "Agg")
    monkeypatch.setenv("PATH", os.path.dirname(sys.executable) + os.pathsep + os.environ.get("PATH", ""))
    return tmp_path


# ---------------------------------------------------------------------------------------
# Structure
# ---------------------------------------------------------------------------------------
def test_readme_fits_in_a_head():
    lines = (REPO / "README.md").read_text(encoding="utf-8").splitlines()
    assert len(lines) < 250, len(lines)
    first_screen = "\n".join(lines[:45])
    assert "two CSV files from my oscilloscope" in first_screen and "mbus-run" in first_screen
    assert 'pip install -e ".[test]"' in first_screen
    assert "python -m pytest" in "\n".join(lines)


def test_every_page_is_in_the_navigation_and_every_nav_entry_exists():
    config = yaml.safe_load((REPO / "mkdocs.yml").read_text(encoding="utf-8"))
    listed = nav_pages(config["nav"])
    assert len(listed) == len(set(listed))
    assert sorted(listed) == sorted(p.name for p in PAGES)
    assert config["theme"]["name"] == "material" and config["strict"] is True
    assert "estimation.md" in listed  # the page the estimator's documentation grows in


@pytest.mark.parametrize("path", MARKDOWN, ids=lambda p: p.name)
def test_relative_links_and_anchors_resolve(path):
    text = re.sub(r"```.*?```", "", path.read_text(encoding="utf-8"), flags=re.S)
    for target in re.findall(r"\]\(([^)\s]+)\)", text):
        if re.match(r"[a-z]+:", target):
            continue
        file, _, anchor = target.partition("#")
        dest = (path.parent / file).resolve() if file else path
        assert dest.exists(), f"{path.name}: link to missing {target}"
        if anchor and dest.suffix == ".md":
            assert anchor in anchors(dest), f"{path.name}: no heading for #{anchor} in {dest.name}"


def test_dotted_names_in_the_docs_exist():
    names = set()
    for path in MARKDOWN:
        names |= set(re.findall(r"mbus_framework(?:\.[A-Za-z_]\w*)+", path.read_text(encoding="utf-8")))
    missing = []
    for name in sorted(names):
        parts = name.split(".")
        for i in range(len(parts), 0, -1):
            try:
                obj = importlib.import_module(".".join(parts[:i]))
            except ImportError:
                continue
            try:
                for attr in parts[i:]:
                    obj = getattr(obj, attr)
            except AttributeError:
                missing.append(name)
            break
    assert not missing, missing


# ---------------------------------------------------------------------------------------
# The examples run
# ---------------------------------------------------------------------------------------
PYCON = [p for p in MARKDOWN if any(lang == "pycon" for lang, _, _ in blocks(p))]


@pytest.mark.parametrize("path", PYCON, ids=lambda p: p.name)
def test_python_examples_run(path, sandbox):
    text = "\n\n".join(body for lang, body, _ in blocks(path) if lang == "pycon")
    test = doctest.DocTestParser().get_doctest(text, {}, path.name, str(path), 0)
    runner = doctest.DocTestRunner(optionflags=doctest.ELLIPSIS | doctest.NORMALIZE_WHITESPACE)
    runner.run(test)
    assert runner.failures == 0 and runner.tries > 0, f"{path.name}: {runner.failures} of {runner.tries} failed"


@pytest.mark.parametrize("module", ["mbus_framework", "mbus_framework.api", "mbus_framework.pipeline.html"])
def test_module_docstring_examples_run(module, monkeypatch):
    monkeypatch.chdir(REPO)
    result = doctest.testmod(importlib.import_module(module), optionflags=doctest.ELLIPSIS)
    assert result.failed == 0 and result.attempted > 0


def shell_commands() -> list[str]:
    """Commands of the blocks marked runnable, each once; config runs get --no-plots (speed)."""
    seen: list[str] = []
    for path in MARKDOWN:
        for lang, body, marked in blocks(path):
            if not (marked and lang == "bash"):
                continue
            for line in body.splitlines():
                command = line.split("  #")[0].strip()
                if command and not command.startswith("#") and command not in seen:
                    seen.append(command)
    return seen


@pytest.mark.parametrize("command", shell_commands())
def test_marked_shell_commands_run(command, sandbox):
    argv = shlex.split(command)
    if argv[0] == "mbus-run" and not argv[1].startswith("--"):
        argv.append("--no-plots")
    out = subprocess.run(argv, capture_output=True, text=True, timeout=300)
    assert out.returncode == 0, out.stderr[-2000:]
    if argv[0] == "mbus-run" and "--list-plugins" not in argv:
        named = " Pa " if "configs/real/" in command else "E_sigma"  # substitution runs: a law's moduli [Pa]
        assert "property" in out.stdout and named in out.stdout
        assert list(sandbox.glob("runs/*/report.html"))


def test_readme_and_pages_mark_the_quick_start_commands():
    commands = shell_commands()
    for command in ("mbus-run configs/recorded_gds2062.yaml", "mbus-run configs/recorded.yaml",
                    "mbus-run configs/potato.yaml"):
        assert command in commands


@pytest.mark.skipif(importlib.util.find_spec("mkdocs") is None, reason='needs pip install -e ".[docs]"')
def test_mkdocs_builds_strictly(tmp_path):
    out = subprocess.run([sys.executable, "-m", "mkdocs", "build", "--strict", "-q", "-d", str(tmp_path / "site")],
                         cwd=REPO, capture_output=True, text=True, timeout=300,
                         env=dict(os.environ, NO_MKDOCS_2_WARNING="1"))
    assert out.returncode == 0, out.stderr[-3000:]
    assert (tmp_path / "site" / "index.html").is_file()
    assert (tmp_path / "site" / "python-api" / "index.html").is_file()


def test_every_strategy_option_is_documented():
    """The scipy_lm table of docs/configuration.md names every field of StrategyOptions."""
    from mbus_framework.estimation.strategy import StrategyOptions

    text = (DOCS / "configuration.md").read_text(encoding="utf-8")
    missing = [n for n in StrategyOptions.model_fields if f"`strategy.{n}`" not in text]
    assert not missing, f"undocumented strategy options: {missing}"


def documented_commands() -> list[tuple[str, str]]:
    """(page, command) for every mbus-run, mbus-analyze and `python benchmarks/...` line of
    every bash block (marked runnable or not); backslash continuations joined."""
    out: list[tuple[str, str]] = []
    for path in MARKDOWN:
        for lang, body, _ in blocks(path):
            if lang != "bash":
                continue
            for line in body.replace("\\\n", " ").splitlines():
                command = line.split("  #")[0].split(" # ")[0].strip()
                if command.startswith(("mbus-run", "mbus-analyze", "python benchmarks/")):
                    out.append((path.name, command))
    return out


SHIPPED = ("configs/", "examples/", "benchmarks/", "tests/")


@pytest.mark.parametrize("page,command", documented_commands())
def test_documented_commands_parse_and_name_shipped_files(page, command):
    """Each documented command is accepted by its command-line parser (not run), and every
    file of the repository it names exists."""
    from mbus_framework.analysis import cli as analyze_cli
    from mbus_framework import cli as run_cli

    argv = shlex.split(command)
    for arg in argv[1:]:
        value = arg.split("=", 1)[-1]
        if value.startswith(SHIPPED) and not any(ch in value for ch in "<>*"):
            assert (REPO / value).exists(), f"{page}: {command}: {value} does not exist"
    if argv[0] == "python":
        return
    parser = run_cli._parser() if argv[0] == "mbus-run" else analyze_cli._parser()
    try:
        parser.parse_args(argv[1:])
    except SystemExit as exc:
        assert exc.code == 0, f"{page}: {command}: rejected by {argv[0]}'s parser"
