"""Every code block of README.md and docs/*.md runs as written, or says why not.

A block's fence names its language: ``sh`` and ``python`` blocks run, ``toml`` blocks parse,
``text`` blocks (printed output, listings) are read only. A runnable block may be preceded by

- ``<!-- not run: REASON -->``: it is not run, for the reason given (at least four words);
- ``<!-- run with: "OLD" -> "NEW"; ... -->``: it runs with each OLD replaced by NEW (each must
  occur), to keep long commands short: a few seconds of recording, few inducing points.

The blocks run in one folder, in page order (README.md, docs/guide.md, then the other pages by
name), so that a page's commands find the files written by those before them; a shell command
already run there, word for word, is not run again. Shell commands run in bash with the
installed ``fmu-greybox`` first on the PATH; Python blocks with this interpreter.
"""

from __future__ import annotations

import os
import re
import subprocess
import sys
import time
import tomllib
from dataclasses import dataclass
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
LANGUAGES = {"sh", "python", "toml", "text"}
RUNNABLE = {"sh", "python"}
MIN_REASON_WORDS = 4
OPENING = re.compile(r"^(?P<indent>\s*)```(?P<language>\S*)\s*$")
CLOSING = re.compile(r"^\s*```\s*$")
DIRECTIVE = re.compile(r"^\s*<!--\s*(?P<kind>not run|run with):\s*(?P<text>.*?)\s*-->\s*$")
REPLACEMENT = re.compile(r'^"(?P<old>[^"]+)"\s*->\s*"(?P<new>[^"]*)"$')


@dataclass(frozen=True)
class Block:
    """One fenced code block of a page."""

    page: str
    line: int
    language: str
    code: str
    directive: str = ""  # "not run" or "run with"
    argument: str = ""

    @property
    def where(self) -> str:
        return f"{self.page}:{self.line}"

    def replacements(self) -> list[tuple[str, str]]:
        """The (old, new) pairs of a ``run with`` directive."""
        if self.directive != "run with":
            return []
        pairs = []
        for item in self.argument.split(";"):
            match = REPLACEMENT.match(item.strip())
            assert match, f'{self.where}: "{item.strip()}" is not "OLD" -> "NEW"'
            pairs.append((match["old"], match["new"]))
        return pairs

    def runnable_code(self) -> str:
        """The code as run: each replacement applied once it is found."""
        code = self.code
        for old, new in self.replacements():
            assert old in code, f"{self.where}: run with: {old!r} is not in the block"
            code = code.replace(old, new)
        return code


def pages() -> list[Path]:
    """README.md, the guide, then the other pages of docs/ by name."""
    guide = ROOT / "docs" / "guide.md"
    others = sorted(p for p in (ROOT / "docs").glob("*.md") if p != guide)
    return [ROOT / "README.md", guide, *others]


def blocks_of(path: Path) -> list[Block]:
    """The fenced code blocks of a page, each with the directive on the line before it."""
    lines = path.read_text(encoding="utf-8").splitlines()
    name = str(path.relative_to(ROOT))
    blocks, i = [], 0
    while i < len(lines):
        opening = OPENING.match(lines[i])
        if not opening:
            i += 1
            continue
        end = next(j for j in range(i + 1, len(lines)) if CLOSING.match(lines[j]))
        indent = len(opening["indent"])
        code = "\n".join(line[indent:] for line in lines[i + 1 : end]) + "\n"
        previous = next((lines[j] for j in range(i - 1, -1, -1) if lines[j].strip()), "")
        directive = DIRECTIVE.match(previous)
        blocks.append(
            Block(
                name,
                i + 1,
                opening["language"],
                code,
                directive["kind"] if directive else "",
                directive["text"] if directive else "",
            )
        )
        i = end + 1
    return blocks


def all_blocks() -> list[Block]:
    return [block for page in pages() for block in blocks_of(page)]


def shell_commands(code: str) -> list[str]:
    """A shell block's commands: continuation lines joined, comments and blank lines left out;
    a block with a loop or a background job is one command."""
    if re.search(r"\b(for|while|do|done)\b|&\s*$|<<", code, flags=re.M):
        return [code]
    joined = re.sub(r"\\\n\s*", " ", code)
    return [line.strip() for line in joined.splitlines() if line.strip() and line[0] != "#"]


def test_every_block_names_its_language_and_every_skip_its_reason() -> None:
    blocks = all_blocks()
    assert len(blocks) > 50
    for block in blocks:
        assert block.language in LANGUAGES, f"{block.where}: language {block.language!r}"
        if block.directive:
            assert block.language in RUNNABLE, f"{block.where}: a directive on a {block.language}"
        if block.directive == "not run":
            words = block.argument.split()
            assert len(words) >= MIN_REASON_WORDS, f"{block.where}: not run needs its reason"
        block.runnable_code()  # each replacement is found


def test_the_directives_are_read() -> None:
    """The guide's first recording is shortened, and its demo is not run, with its reason."""
    guide = blocks_of(ROOT / "docs" / "guide.md")
    (synth,) = [b for b in guide if "fmu-greybox synth" in b.code and b.language == "sh"]
    assert "--duration 4 --out rec.csv" in synth.runnable_code()
    (demo,) = [b for b in guide if b.code.startswith("fmu-greybox demo")]
    assert demo.directive == "not run" and "tests/test_demo.py" in demo.argument


def test_every_toml_block_parses() -> None:
    for block in all_blocks():
        if block.language == "toml":
            try:
                tomllib.loads(block.code)
            except tomllib.TOMLDecodeError as error:
                pytest.fail(f"{block.where}: {error}")


def run(block: Block, command: str, folder: Path, env: dict[str, str]) -> None:
    """Run one command of a block in ``folder``; fail naming the block and its output."""
    if block.language == "python":
        script = folder / "snippet.py"
        script.write_text(command, encoding="utf-8")
        argv = [sys.executable, str(script)]
    else:
        argv = ["bash", "-euo", "pipefail", "-c", command]
    done = subprocess.run(
        argv, cwd=folder, env=env, capture_output=True, text=True, timeout=600, check=False
    )
    if done.returncode != 0:
        pytest.fail(
            f"{block.where} failed (exit {done.returncode}): {command}\n"
            f"{done.stdout[-2000:]}\n{done.stderr[-3000:]}"
        )


def test_every_runnable_block_runs(tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    """Run every sh and python block not marked ``not run``, in page order, in one folder."""
    env = dict(os.environ)
    env["PATH"] = f"{Path(sys.executable).parent}{os.pathsep}{env.get('PATH', '')}"
    env["OPENBLAS_NUM_THREADS"] = "1"
    started, ran, already = time.monotonic(), [], set()
    for block in all_blocks():
        if block.language not in RUNNABLE or block.directive == "not run":
            continue
        code = block.runnable_code()
        commands = [code] if block.language == "python" else shell_commands(code)
        took = time.monotonic()
        for command in commands:
            if block.language == "sh" and command in already:
                continue
            run(block, command, tmp_path, env)
            already.add(command)
        ran.append(f"{block.where} {time.monotonic() - took:.0f} s")
    with capsys.disabled():
        print(f"\nran {len(ran)} blocks in {time.monotonic() - started:.0f} s: {', '.join(ran)}")
    assert {"README.md", "docs/guide.md", "docs/api.md"} <= {w.split(":")[0] for w in ran}
    assert "docs/guide.md" in {w.split(":")[0] for w in ran}
    assert (tmp_path / "greybox.fmu").is_file() and (tmp_path / "val" / "report.html").is_file()
