"""The documentation: the site builds with warnings as errors, every example on every page of
docs/ and in README.md runs as written, and the reference's single sources agree with the code.

Examples (the conventions every page follows):

* a ```python block runs in a fresh Python process of its own;
* a ```bash, ```console or ```shell block runs with ``bash -euo pipefail``; a leading ``$ ``
  prompt is stripped; in a console block, lines not starting with ``$ `` are expected output
  and not run (a command ending in ``\\`` continues on the next line);
* ``<!-- file: NAME -->`` on the last non-blank line before a fenced block (of any language)
  writes the block to NAME in the page's directory instead of running it;
* ``<!-- snippet: continues -->`` joins a python block to the python block before it;
* ``<!-- snippet: not run: REASON -->`` skips a block; skipped blocks are counted (at most
  :data:`MAX_SKIPPED` in all), and the README's ``<!-- main-command -->`` and
  ``<!-- test-command -->`` blocks (they install into a fresh virtual environment; CI runs the
  test command itself) count among them;
* ```toml, ```text, ```json and other blocks without a file marker are not run;
* a file a page offers for download (MyST's ``{download}`text <path>``` role, the path relative
  to the page) is copied into the page's directory under its own name before its blocks run,
  as a reader saves it beside their work.

Each page runs in one fresh temporary directory, its blocks in order (a later block may use the
files an earlier one wrote), with no PYTHONPATH (the files a page offers are what a reader has), MPLBACKEND=Agg, the session's
design cache (TWIN_CACHE_DIR) and this interpreter's ``twin`` first on PATH. A failure names the
page, the block's line and the tail of its stderr.

The build needs the ``docs`` extra (Sphinx, MyST, numpydoc, furo); without it it skips, unless
TWIN_REQUIRE_DOCS=1 (CI), where a missing extra fails. The examples need no extra and always run.
The build and the pages run side by side (:data:`WORKERS` at a time).
"""
from __future__ import annotations

import importlib.util
import os
import re
import shutil
import subprocess
import sys
import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
DOCS = ROOT / "docs"
README = ROOT / "README.md"
GENERATED = DOCS / "_generated"

MAX_SKIPPED = 6            # blocks not run, over every page and the README
BLOCK_TIMEOUT_S = 240      # one block
BUILD_TIMEOUT_S = 300
STDERR_TAIL_LINES = 40
README_MAX_LINES = 260     # "at most about 250"
DOCS_PACKAGES = ("sphinx", "myst_parser", "numpydoc", "furo")

RUN_LANGS = {"python", "bash", "console", "shell", "sh"}
# the README's blocks that CI extracts (.ci/run) and that install into a fresh virtual environment
INSTALL_MARKERS = {"main-command": "installs into a fresh virtual environment (the quickstart)",
                   "test-command": "installs into a fresh virtual environment; CI runs it itself (.ci/run)"}

_FENCE_OPEN = re.compile(r"^(\s*)(`{3,}|~{3,})\s*\{?([\w+-]*)\}?.*$")
_MARKER = re.compile(r"^\s*<!--\s*(snippet|file):\s*(.*?)\s*-->\s*$")
_PLAIN_MARKER = re.compile(r"^\s*<!--\s*([\w-]+)\s*-->\s*$")


def _require_docs() -> bool:
    return os.environ.get("TWIN_REQUIRE_DOCS", "") not in ("", "0")


def _missing_packages() -> list[str]:
    return [p for p in DOCS_PACKAGES if importlib.util.find_spec(p) is None]


def needs_docs():
    missing = _missing_packages()
    if missing:
        if _require_docs():
            pytest.fail(f"TWIN_REQUIRE_DOCS=1 but the docs extra is not installed (missing {', '.join(missing)}): "
                        "pip install '.[docs]'")
        pytest.skip(f"the docs extra is not installed (missing {', '.join(missing)}): pip install '.[docs]'")


# ---- extraction ---------------------------------------------------------------------------------

@dataclass
class Block:
    page: str                  # path relative to the repository
    line: int                  # 1-based line of the opening fence
    lang: str
    code: str
    action: str                # "python", "shell", "file", "skip", "none"
    target: str = ""           # file NAME, or the reason of a skip
    lines: tuple = field(default_factory=tuple)

    @property
    def where(self) -> str:
        return f"{self.page} line " + ", ".join(str(n) for n in (self.lines or (self.line,)))


def extract(text: str, page: str = "page") -> list[Block]:
    """Every fenced block of ``text`` in order, classified by the conventions above (python
    continuations joined to the python block before them)."""
    lines = text.split("\n")
    blocks: list[Block] = []
    last_python: Block | None = None
    i = 0
    while i < len(lines):
        m = _FENCE_OPEN.match(lines[i])
        if not m:
            i += 1
            continue
        indent, fence, lang = m.group(1), m.group(2), m.group(3).lower()
        start = i + 1
        close = re.compile(r"^\s*" + re.escape(fence[0]) + "{" + str(len(fence)) + r",}\s*$")
        j = i + 1
        while j < len(lines) and not close.match(lines[j]):
            j += 1
        if j == len(lines):
            raise AssertionError(f"{page} line {start}: fence never closed")
        body = "\n".join(ln[len(indent):] if ln.startswith(indent) else ln.lstrip() for ln in lines[i + 1:j]) + "\n"
        k = i - 1
        while k >= 0 and not lines[k].strip():
            k -= 1
        prev = lines[k] if k >= 0 else ""
        marker, plain = _MARKER.match(prev), _PLAIN_MARKER.match(prev)
        action = "python" if lang == "python" else "shell" if lang in RUN_LANGS else "none"
        block = Block(page, start, lang, body, action, lines=(start,))
        if marker and marker.group(1) == "file":
            name = marker.group(2)
            if not name or name.startswith("/") or ".." in Path(name).parts:
                raise AssertionError(f"{page} line {k + 1}: `file:` needs a relative file name, got {name!r}")
            block.action, block.target = "file", name
        elif marker:
            what = marker.group(2)
            if what == "continues":
                if lang != "python" or last_python is None:
                    raise AssertionError(f"{page} line {start}: `snippet: continues` needs a python block after "
                                         f"a runnable python block")
                last_python.code += "\n" + body
                last_python.lines += (start,)
                i = j + 1
                continue
            if what.startswith("not run"):
                reason = what[len("not run"):].lstrip(" :—-").strip()
                if not reason:
                    raise AssertionError(f"{page} line {start}: `snippet: not run` gives no reason "
                                         f"(write `<!-- snippet: not run: WHY -->`)")
                block.action, block.target = "skip", reason
            else:
                raise AssertionError(f"{page} line {k + 1}: unknown snippet marker {what!r} "
                                     f"(`continues` or `not run: REASON`)")
        elif plain and plain.group(1) in INSTALL_MARKERS and action != "none":
            block.action, block.target = "skip", INSTALL_MARKERS[plain.group(1)]
        if block.action == "python":
            last_python = block
        elif block.action in ("skip", "shell") or (block.action == "file" and lang == "python"):
            last_python = None
        blocks.append(block)
        i = j + 1
    return blocks


def shell_script(block: Block) -> str:
    """The commands of a bash/console/shell block: prompts stripped; in a console block, only
    the ``$ `` lines (and their ``\\`` continuations) run."""
    out, continuing = [], False
    for ln in block.code.splitlines():
        if continuing:
            out.append(ln)
            continuing = ln.rstrip().endswith("\\")
            continue
        if ln.startswith("$ ") or ln.rstrip() == "$":
            out.append(ln[2:])
            continuing = ln.rstrip().endswith("\\")
        elif block.lang != "console":
            out.append(ln)
            continuing = ln.rstrip().endswith("\\")
    return "\n".join(out) + "\n"


def pages() -> list[Path]:
    found = [p for p in sorted(DOCS.rglob("*.md"))
             if not ({"_build", "_auto", "_generated", "investigations"} & set(p.relative_to(DOCS).parts))]
    return [README, *found]


def _rel(p: Path) -> str:
    return str(p.relative_to(ROOT))


PAGES = pages()
BLOCKS = {_rel(p): extract(p.read_text(encoding="utf-8"), _rel(p)) for p in PAGES}
_DOWNLOAD = re.compile(r"\{download\}`[^`<]*<([^>`]+)>`|\{download\}`([^`<]+)`")


def downloads(page: Path) -> list[Path]:
    """The files ``page`` offers with the ``{download}`` role (each must exist)."""
    found = []
    for m in _DOWNLOAD.finditer(page.read_text(encoding="utf-8")):
        path = (page.parent / (m.group(1) or m.group(2)).strip()).resolve()
        if not path.is_file():
            raise AssertionError(f"{_rel(page)}: the download {path.name!r} is not a file beside the page")
        found.append(path)
    return found


# ---- the extraction itself ----------------------------------------------------------------------

def test_the_extraction_follows_the_conventions():
    text = "\n".join([
        "intro", "```python", "a = 1", "```",                                     # 2
        "<!-- snippet: continues -->", "", "```python", "print(a)", "```",        # 7
        "```bash", "twin run x", "```",                                           # 10
        "<!-- file: sub/mine.toml -->", "```toml", "[run]", "```",                # 14
        "```toml", "not = 'run'", "```",                                          # 17
        "<!-- snippet: not run: a ten-minute sweep -->", "```console", "$ twin sweep x", "```",  # 21
        "```console", "$ twin run a \\", "  --no-video", "output line", "$ ls", "```",           # 24
        "- a list item:", "  ```python", "  b = 2", "  ```",                      # 31
        "<!-- test-command -->", "```bash", "pip install .", "```",               # 35
    ])
    blocks = extract(text, "p.md")
    assert [(b.line, b.action, b.target) for b in blocks] == [
        (2, "python", ""), (10, "shell", ""), (14, "file", "sub/mine.toml"), (17, "none", ""),
        (21, "skip", "a ten-minute sweep"), (24, "shell", ""), (31, "python", ""),
        (35, "skip", INSTALL_MARKERS["test-command"])]
    assert blocks[0].code == "a = 1\n\nprint(a)\n" and blocks[0].lines == (2, 7)
    assert blocks[6].code == "b = 2\n"
    assert shell_script(blocks[5]) == "twin run a \\\n  --no-video\nls\n"
    assert shell_script(Block("p", 1, "bash", "$ echo hi\necho there\n", "shell")) == "echo hi\necho there\n"
    with pytest.raises(AssertionError, match="gives no reason"):
        extract("<!-- snippet: not run -->\n```python\nx\n```\n")
    with pytest.raises(AssertionError, match="unknown snippet marker"):
        extract("<!-- snippet: maybe -->\n```python\nx\n```\n")
    with pytest.raises(AssertionError, match="continues"):
        extract("```bash\nls\n```\n<!-- snippet: continues -->\n```python\nx\n```\n")
    with pytest.raises(AssertionError, match="relative file name"):
        extract("<!-- file: ../x.py -->\n```python\nx\n```\n")
    with pytest.raises(AssertionError, match="never closed"):
        extract("```python\nx\n")


def test_few_examples_are_skipped_and_each_says_why():
    skipped = [b for bs in BLOCKS.values() for b in bs if b.action == "skip"]
    assert len(skipped) <= MAX_SKIPPED, (
        f"{len(skipped)} examples are not run (at most {MAX_SKIPPED}): "
        + "; ".join(f"{b.where} ({b.target})" for b in skipped))
    assert all(b.target for b in skipped)
    assert any(b.action in ("python", "shell") for bs in BLOCKS.values() for b in bs), "no runnable example found"


# ---- running a page's examples ------------------------------------------------------------------

def _env() -> dict:
    env = dict(os.environ)  # TWIN_CACHE_DIR: the session's private design cache (conftest)
    env["MPLBACKEND"] = "Agg"
    env.pop("PYTHONPATH", None)  # a user's environment: the installed package, and what the page gives to save
    env["PATH"] = os.pathsep.join([str(Path(sys.executable).parent), env.get("PATH", "")])
    env.pop("TWIN_REQUIRE_DOCS", None)
    return env


def _tail(text) -> str:
    if isinstance(text, bytes):
        text = text.decode(errors="replace")
    return "\n".join((text or "").splitlines()[-STDERR_TAIL_LINES:])


def run_page(page: str, blocks: list[Block], cwd: Path) -> list[str]:
    """Run ``blocks`` in order in ``cwd``; the failures as messages (empty: all ran)."""
    env = _env()
    for n, b in enumerate(blocks):
        if b.action == "file":
            path = cwd / b.target
            path.parent.mkdir(parents=True, exist_ok=True)
            path.write_text(b.code, encoding="utf-8")
            continue
        if b.action == "python":
            script = cwd / f".block_{n}_line_{b.line}.py"
            script.write_text(b.code, encoding="utf-8")
            cmd = [sys.executable, str(script)]
        elif b.action == "shell":
            cmd = ["bash", "-euo", "pipefail", "-c", shell_script(b)]
        else:
            continue
        try:
            proc = subprocess.run(cmd, cwd=cwd, env=env, capture_output=True, text=True, timeout=BLOCK_TIMEOUT_S)
        except subprocess.TimeoutExpired as exc:
            return [f"{b.where}: the {b.lang} example ran longer than {BLOCK_TIMEOUT_S} s\n"
                    f"--- stderr (tail) ---\n{_tail(exc.stderr)}"]
        if proc.returncode != 0:
            # later blocks may need what this one should have made: stop at the first failure
            return [f"{b.where}: the {b.lang} example exited with status {proc.returncode}\n"
                    f"--- stderr (tail) ---\n{_tail(proc.stderr)}\n--- stdout (tail) ---\n{_tail(proc.stdout)}"]
    return []


RUNNABLE = [p for p, bs in BLOCKS.items() if any(b.action in ("python", "shell") for b in bs)]
WORKERS = max(2, min(4, os.cpu_count() or 2))  # the pages (and the build) run side by side


def _build(out: Path) -> tuple[int, str, float]:
    """Build the site into ``out`` with warnings as errors: (status, stderr, seconds)."""
    t0 = time.perf_counter()
    proc = subprocess.run([sys.executable, "-m", "sphinx", "-W", "--keep-going", "-q", "-b", "html",
                           "-d", str(out / "doctrees"), str(DOCS), str(out / "html")],
                          cwd=ROOT, env=_env(), capture_output=True, text=True, timeout=BUILD_TIMEOUT_S)
    return proc.returncode, proc.stderr, time.perf_counter() - t0


@pytest.fixture(scope="module")
def jobs(tmp_path_factory):
    """The build (where the docs extra is installed) and every page's examples, started together
    on :data:`WORKERS` threads (each runs subprocesses); a test waits for its own."""
    base = tmp_path_factory.mktemp("docs")
    with ThreadPoolExecutor(max_workers=WORKERS) as pool:
        futures = {}
        if not _missing_packages():
            futures["build"] = pool.submit(_build, base / "site")
        for i, page in enumerate(RUNNABLE):
            cwd = base / f"page{i}"
            cwd.mkdir()
            for f in downloads(ROOT / page):
                shutil.copyfile(f, cwd / f.name)
            futures[page] = pool.submit(run_page, page, BLOCKS[page], cwd)
        yield futures, base
        for f in futures.values():
            f.cancel()


@pytest.mark.parametrize("page", RUNNABLE)
def test_the_examples_of_a_page_run_as_written(page, jobs):
    failures = jobs[0][page].result()
    if failures:
        pytest.fail("\n\n".join(failures), pytrace=False)


def test_a_failing_example_names_its_page_and_line(tmp_path):
    blocks = extract("text\n\n<!-- file: data.txt -->\n```text\nhello\n```\n\n```bash\ncat data.txt\n```\n\n"
                     "```python\nimport sys\nsys.exit('broken on purpose')\n```\n", "docs/x.md")
    failures = run_page("docs/x.md", blocks, tmp_path)
    assert (tmp_path / "data.txt").read_text() == "hello\n"
    assert len(failures) == 1 and failures[0].startswith("docs/x.md line 12: the python example exited with status 1")
    assert "broken on purpose" in failures[0]


# ---- the site ---------------------------------------------------------------------------------

def test_the_site_builds_with_warnings_as_errors(jobs):
    needs_docs()
    futures, base = jobs
    status, stderr, seconds = futures["build"].result()
    assert status == 0, f"sphinx -W failed (status {status}) after {seconds:.0f} s:\n{_tail(stderr)}"
    html = base / "site" / "html"
    for page in ("index", "reference/cli", "reference/scenario-schema", "reference/metrics", "reference/api",
                 "reference/api/running"):
        assert (html / f"{page}.html").is_file(), page
    cli = (html / "reference" / "cli.html").read_text(encoding="utf-8")
    assert "twin run" in cli and "--set" in cli
    # a dataclass's signature with its long defaults shortened (RunSpec's ran to about 20 lines)
    from html import unescape

    running = unescape(re.sub(r"<[^>]+>", "", (html / "reference" / "api" / "running.html").read_text(encoding="utf-8")))
    sig = re.search(r"class twin\.sim\.spec\.RunSpec\((.*?)\)¶", running, re.S)
    assert sig and len(sig.group(1)) < 400 and "estimator=Plugin(…)" in sig.group(1), sig and sig.group(1)[:300]
    for page in ("reference/envs/balance-v0", "reference/envs/track-v0"):
        assert (html / f"{page}.html").is_file(), page
    # commands in prose as typed (no smart quotes): a copied command must run
    assert "twin run --log-sensors" in cli and "–log-sensors" not in cli and "‘twin" not in cli
    # no development history in the user's documentation (the changelog page excepted)
    history = {}
    for f in html.rglob("*.html"):
        if f.name in ("changelog.html", "genindex.html", "search.html"):
            continue
        hit = re.search(r"\bissues? \d+", re.sub(r"<[^>]+>", "", f.read_text(encoding="utf-8")), re.I)
        if hit:
            history[str(f.relative_to(html))] = hit.group(0)
    assert not history, f"issue numbers on pages of the site: {history}"


# ---- the reference's single sources -------------------------------------------------------------

from test_scenario_docs import _reference  # noqa: E402  (the reference extension, imported from docs/_ext)


def test_every_metric_has_a_unit_and_a_definition():
    from twin.outputs.metrics import METRIC_DEFINITIONS, REPLAY_METRIC_DEFINITIONS
    from twin.scenarios.expectations import METRICS, REPLAY_METRICS

    assert set(METRIC_DEFINITIONS) == set(METRICS)
    assert set(REPLAY_METRIC_DEFINITIONS) == set(REPLAY_METRICS)
    assert all(len(d) > 20 and d.endswith(".") for d in [*METRIC_DEFINITIONS.values(),
                                                         *REPLAY_METRIC_DEFINITIONS.values()])


def test_the_generated_reference_covers_every_key_metric_and_command(tmp_path):
    import click

    from twin.cli import main
    from twin.scenarios.schema import describe
    from twin.scenarios.expectations import METRICS

    ref = _reference()
    ref.generate(tmp_path)
    keys = (tmp_path / "scenario-keys.md").read_text(encoding="utf-8")
    missing = [k for k, *_ in describe() if ref.code(k) not in keys]
    assert not missing, f"scenario keys missing from the generated reference: {missing}"
    metrics = (tmp_path / "metrics.md").read_text(encoding="utf-8")
    assert [m for m in METRICS if f"| `{m}` |" not in metrics] == []
    cli = (tmp_path / "cli.md").read_text(encoding="utf-8")
    ctx = click.Context(main, info_name="twin")
    for name in main.list_commands(ctx):
        cmd = main.get_command(ctx, name)
        if cmd is None or cmd.hidden:
            continue
        assert f"`twin {name}`" in cli, name
        for p in cmd.params:
            for opt in getattr(p, "opts", []):
                if opt.startswith("--") and not getattr(p, "hidden", False):
                    assert opt in cli, (name, opt)


def test_absolute_value_bars_in_docstrings_are_escaped_outside_literals():
    ref = _reference()
    assert ref.escape_bars("max |θ| over ``a|b`` and :func:`x|y`") == "max \\|θ\\| over ``a|b`` and :func:`x|y`"
    assert ref.escape_bars("| a | b |") == "| a | b |"
    doc = ["the |x| here::", "", "    a = '|x|'", "", "and |y|", ">>> abs(-1) | 0"]
    assert ref.escape_docstring(doc) == ["the \\|x\\| here::", "", "    a = '|x|'", "", "and \\|y\\|",
                                         ">>> abs(-1) | 0"]


def test_a_section_numpydoc_does_not_know_is_kept_as_a_rubric():
    ref = _reference()
    known = ["Summary.", "", "Parameters", "----------", "x : float", "    metres"]
    assert ref.headings_to_rubrics(known) == known
    doc = known + ["", "Optional hooks", "--------------", "f() -> None", "    called last"]
    assert ref.headings_to_rubrics(doc) == ["Summary.", "", ".. rubric:: Parameters", "", "x : float", "    metres",
                                            "", ".. rubric:: Optional hooks", "", "f() -> None", "    called last"]


# ---- the README as a landing page ---------------------------------------------------------------

def test_the_readme_is_a_landing_page():
    text = README.read_text(encoding="utf-8")
    n = len(text.splitlines())
    assert n <= README_MAX_LINES, f"README.md has {n} lines (a landing page: at most about 250)"
    assert not re.search(r"\bissues? \d+|#\d+\b", text, re.I), re.search(r"\bissues? \d+|#\d+\b", text, re.I)
    for marker in ("<!-- main-command -->", "<!-- test-command -->"):
        assert text.count(marker) == 1, marker
    assert "'.[test,ray,gym,docs]'" in text
    # relative links (to pages and images) resolve
    broken = [t for t in re.findall(r"\]\(([^)#\s]+)(?:#[^)]*)?\)", text)
              if "://" not in t and not t.startswith("mailto:") and not (ROOT / t).exists()]
    assert not broken, f"README links that resolve to nothing: {broken}"


def test_the_readme_headline_table_is_the_generated_one():
    """A table copied from docs/_generated into the README must equal the generated file's table."""
    text = README.read_text(encoding="utf-8")
    copied = re.findall(r"<!-- generated: (\S+) -->\n(.*?)\n<!-- end generated -->", text, re.S)
    assert copied, "the README's headline results are no copy of a docs/_generated table"
    for name, body in copied:
        source = (ROOT / name).read_text(encoding="utf-8")
        assert body.strip() in source, f"README's copy of {name} differs from it: copy it again"


def test_the_generated_tables_name_command_machine_date_and_commit():
    files = sorted(GENERATED.glob("*.md"))
    assert files, "no generated table in docs/_generated"
    for f in files:
        first = f.read_text(encoding="utf-8").splitlines()[0]
        assert re.match(r"^\*Generated by `python benchmarks/\S+\.py[^`]*` on .+ \(\d+ logical CPUs, Python [\d.]+, "
                        r"\w+\), \d{4}-\d\d-\d\d, commit [0-9a-f]{7,}", first), (f.name, first)
