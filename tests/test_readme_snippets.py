"""Every public entry point the README documents still works as written: each fenced
```python block of README.md runs, unchanged, in a fresh Python process of its own (cwd a
temporary directory, ``examples/`` on the path for ``my_plugins``, matplotlib on Agg).

A block may be preceded (last non-blank line before its fence) by a visible marker:

``<!-- snippet: continues -->``
    a fragment continuing the block before it: run as one program with that block;
``<!-- snippet: not run: REASON -->``
    deliberately not runnable (pseudo-code, …); skipped, and counted below.

A failure names the block's line in README.md and ends with the tail of its stderr."""

import os
import re
import subprocess
import sys
from dataclasses import dataclass
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
README = ROOT / "README.md"
EXAMPLES = ROOT / "examples"

MAX_SKIPPED = 2           # more than this many blocks not run: the README's examples are not tested
TIMEOUT_S = 120           # one block; the whole file runs in well under a minute
STDERR_TAIL_LINES = 40

_FENCE_OPEN = re.compile(r"^(\s*)```(\w*)\s*$")
_FENCE_CLOSE = re.compile(r"^\s*```\s*$")
_MARKER = re.compile(r"^\s*<!--\s*snippet:\s*(.*?)\s*-->\s*$")


@dataclass
class Snippet:
    line: int                 # README line of the opening fence (1-based)
    code: str
    lines: tuple = ()         # every block's opening line, when continuations were joined
    skip_reason: str | None = None


def extract(text: str) -> tuple[list[Snippet], list[Snippet]]:
    """The ```python blocks of ``text`` in order, continuations joined to the block before:
    (blocks to run, blocks not run)."""
    lines = text.split("\n")
    run: list[Snippet] = []
    skipped: list[Snippet] = []
    last_python: Snippet | None = None   # the block a continuation joins (None after a skip)
    i = 0
    while i < len(lines):
        m = _FENCE_OPEN.match(lines[i])
        if not m:
            i += 1
            continue
        indent, lang = m.group(1), m.group(2)
        start = i + 1                       # 1-based line of the fence
        j = i + 1
        while j < len(lines) and not _FENCE_CLOSE.match(lines[j]):
            j += 1
        if j == len(lines):
            raise AssertionError(f"README.md line {start}: fence never closed")
        if lang == "python":
            body = "\n".join(ln[len(indent):] if ln.startswith(indent) else ln for ln in lines[i + 1:j]) + "\n"
            k = i - 1
            while k >= 0 and not lines[k].strip():
                k -= 1
            marker = _MARKER.match(lines[k]) if k >= 0 else None
            if marker is None:
                last_python = Snippet(start, body, (start,))
                run.append(last_python)
            else:
                what = marker.group(1)
                if what == "continues":
                    if last_python is None:
                        raise AssertionError(f"README.md line {start}: `snippet: continues` with no runnable "
                                             f"python block before it")
                    last_python.code += "\n" + body
                    last_python.lines += (start,)
                elif what.startswith("not run"):
                    reason = what[len("not run"):].lstrip(" :—-").strip()
                    if not reason:
                        raise AssertionError(f"README.md line {start}: `snippet: not run` gives no reason "
                                             f"(write `<!-- snippet: not run: WHY -->`)")
                    skipped.append(Snippet(start, body, (start,), reason))
                    last_python = None
                else:
                    raise AssertionError(f"README.md line {k + 1}: unknown snippet marker {what!r} "
                                         f"(`continues` or `not run: REASON`)")
        i = j + 1
    return run, skipped


RUN, SKIPPED = extract(README.read_text(encoding="utf-8"))


def test_the_readme_has_python_snippets_and_few_are_skipped():
    assert RUN, "no ```python block found in README.md"
    assert len(SKIPPED) <= MAX_SKIPPED, (
        f"{len(SKIPPED)} README python blocks are marked `not run` (at most {MAX_SKIPPED}): "
        + ", ".join(f"line {s.line} ({s.skip_reason})" for s in SKIPPED))
    assert all(s.skip_reason for s in SKIPPED)


def test_the_extraction_follows_the_markers():
    text = "\n".join([
        "intro", "```python", "a = 1", "```",
        "<!-- snippet: continues -->", "", "```python", "print(a)", "```",
        "```bash", "twin run x", "```",
        "<!-- snippet: not run: pseudo-code -->", "```python", "do(something)", "```",
        "- a list item:", "  ```python", "  b = 2", "  ```",
    ])
    run, skipped = extract(text)
    assert [(s.line, s.lines, s.code) for s in run] == [(2, (2, 7), "a = 1\n\nprint(a)\n"), (18, (18,), "b = 2\n")]
    assert [(s.line, s.skip_reason) for s in skipped] == [(14, "pseudo-code")]
    with pytest.raises(AssertionError, match="gives no reason"):
        extract("<!-- snippet: not run -->\n```python\nx\n```\n")
    with pytest.raises(AssertionError, match="unknown snippet marker"):
        extract("<!-- snippet: maybe -->\n```python\nx\n```\n")


@pytest.mark.parametrize("snippet", RUN, ids=[f"README-line-{s.line}" for s in RUN])
def test_readme_snippet_runs_as_written(snippet, tmp_path):
    script = tmp_path / f"readme_line_{snippet.line}.py"
    script.write_text(snippet.code, encoding="utf-8")
    env = dict(os.environ)   # TWIN_CACHE_DIR: the session's private design cache (conftest)
    env["MPLBACKEND"] = "Agg"
    env["PYTHONPATH"] = os.pathsep.join(p for p in (str(EXAMPLES), env.get("PYTHONPATH", "")) if p)
    where = "README.md line " + ", ".join(str(n) for n in snippet.lines)
    try:
        proc = subprocess.run([sys.executable, str(script)], cwd=tmp_path, env=env, capture_output=True,
                              text=True, timeout=TIMEOUT_S)
    except subprocess.TimeoutExpired as exc:
        tail = "\n".join((exc.stderr or b"").decode(errors="replace").splitlines()[-STDERR_TAIL_LINES:])
        pytest.fail(f"{where}: the python snippet ran longer than {TIMEOUT_S} s\n--- stderr (tail) ---\n{tail}")
    if proc.returncode != 0:
        tail = "\n".join(proc.stderr.splitlines()[-STDERR_TAIL_LINES:])
        pytest.fail(f"{where}: the python snippet exited with status {proc.returncode}\n"
                    f"--- stderr (tail) ---\n{tail}")
