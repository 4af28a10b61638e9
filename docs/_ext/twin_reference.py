"""Sphinx extension: the reference pages' tables, generated from the code at build time.

On ``builder-inited`` it writes Markdown into ``docs/reference/_auto/`` (ignored by git, excluded
from the sources: the reference pages include it):

``cli.md``
    every ``twin`` command, from the click commands of :mod:`twin.cli` (their ``--help``);
``scenario-keys.md``
    every scenario key, from :func:`twin.scenarios.schema.describe`;
``metrics.md`` and ``replay-metrics.md``
    every metric with its unit (:data:`twin.scenarios.expectations.METRICS`,
    :data:`~twin.scenarios.expectations.REPLAY_METRICS`) and definition
    (:data:`twin.outputs.metrics.METRIC_DEFINITIONS`, ``REPLAY_METRIC_DEFINITIONS``).

It also escapes, in the docstrings autodoc reads, the ``|x|`` of absolute values (reST would take
them for substitutions), so that the code's docstrings need no reST-only spelling.
"""
from __future__ import annotations

import re
from pathlib import Path

AUTO = Path(__file__).resolve().parents[1] / "reference" / "_auto"


def cell(text) -> str:
    """Text for one Markdown table cell: pipes escaped, newlines folded."""
    return " ".join(str(text).split()).replace("|", "\\|")


def code(text) -> str:
    """Inline code for a table cell (backticks inside widened by spaces, pipes escaped)."""
    text = " ".join(str(text).split())
    fence = "``" if "`" in text else "`"
    pad = " " if "`" in text else ""
    return f"{fence}{pad}{text}{pad}{fence}".replace("|", "\\|")


def unit_text(unit: str) -> str:
    return {"1": "– (a count or ratio)", "true/false": "true/false"}.get(unit, unit)


# ---- the command line -------------------------------------------------------------------------

def cli_markdown() -> str:
    import click

    from twin.cli import main

    out: list[str] = []
    rows: list[tuple[str, str]] = []

    def walk(cmd: click.Command, path: list[str], parent: click.Context | None, depth: int) -> None:
        ctx = click.Context(cmd, info_name=path[-1], parent=parent, terminal_width=100, max_content_width=100)
        name = " ".join(path)
        if depth > 0:
            rows.append((name, cmd.get_short_help_str(limit=120)))
            out.append(f"{'#' * min(depth + 1, 4)} `{name}`\n")
            out.append("```text\n" + cmd.get_help(ctx).rstrip() + "\n```\n")
        if isinstance(cmd, click.Group):
            for sub in cmd.list_commands(ctx):
                child = cmd.get_command(ctx, sub)
                if child is not None and not getattr(child, "hidden", False):
                    walk(child, [*path, sub], ctx, depth + 1)

    ctx0 = click.Context(main, info_name="twin", terminal_width=100, max_content_width=100)
    head = ["## `twin`\n", "```text\n" + main.get_help(ctx0).rstrip() + "\n```\n"]
    walk(main, ["twin"], None, 0)
    table = ["| command | what it does |", "|---|---|"] + [f"| [{code(n)}](#{anchor(n)}) | {cell(h)} |"
                                                            for n, h in rows]
    return "\n".join(table) + "\n\n" + "\n".join(head + out)


def anchor(name: str) -> str:
    """MyST's heading anchor (``myst_heading_anchors``) of the heading `` `name` ``."""
    return re.sub(r"[^\w\- ]", "", name.lower()).strip().replace(" ", "-")


# ---- the scenario schema ------------------------------------------------------------------------

def scenario_markdown() -> str:
    from twin.scenarios.schema import describe

    groups: dict[str, list] = {}
    for key, kind, default, doc in describe():
        top = key.strip("[]").split(".")[0].split("[")[0]
        table = key.startswith("[[") or "." in key or kind.startswith("table")
        title = f"`[[{top}]]`" if key.startswith("[[") or "[]." in key else f"`[{top}]`" if table else "Top-level keys"
        groups.setdefault(title, []).append((key, kind, default, doc))
    out = []
    for title, rows in sorted(groups.items(), key=lambda g: g[0] != "Top-level keys"):
        out.append(f"## {title}\n")
        out.append("| key | type and range | default | meaning |")
        out.append("|---|---|---|---|")
        out += [f"| {code(k)} | {cell(t)} | {code(d)} | {cell(doc)} |" for k, t, d, doc in rows]
        out.append("")
    return "\n".join(out)


def robot_markdown() -> str:
    from twin.robots.robot import ROBOT_KEYS

    out = []
    for section, keys in ROBOT_KEYS.items():
        out.append(f"## {'Top-level keys' if not section else f'`[{section}]`'}\n")
        out.append("| key | unit | range | paper's robot | meaning |")
        out.append("|---|---|---|---|---|")
        for name, k in keys.items():
            if k.kind in ("number", "integer", "vector3"):
                span = f"{'(' if k.lo_open else '['}{k.lo:g}, {k.hi:g}]" + (" each" if k.kind == "vector3" else "")
            elif k.kind == "choice":
                span = ", ".join(k.choices)
            else:
                span = {"bool": "true/false", "text": "text"}.get(k.kind, "")
            default = "derived" if k.default is None else (
                "[" + ", ".join(f"{v:g}" for v in k.default) + "]" if isinstance(k.default, tuple) else
                str(k.default).lower() if isinstance(k.default, bool) else
                f"{k.default:g}" if isinstance(k.default, (int, float)) else k.default)
            out.append(f"| {code(name)} | {cell(unit_text(k.unit) if k.unit else '')} | {cell(span)} | "
                       f"{code(default) if default != '' else ''} | {cell(k.doc)} |")
        out.append("")
    return "\n".join(out)


# ---- the metrics --------------------------------------------------------------------------------

def metrics_markdown(replay: bool = False) -> str:
    from twin.outputs.metrics import METRIC_DEFINITIONS, REPLAY_METRIC_DEFINITIONS
    from twin.scenarios.expectations import METRICS, REPLAY_METRICS

    units, defs = (REPLAY_METRICS, REPLAY_METRIC_DEFINITIONS) if replay else (METRICS, METRIC_DEFINITIONS)
    missing = set(units) ^ set(defs)
    if missing:
        raise RuntimeError(f"metrics without a unit or a definition: {sorted(missing)}")
    rows = ["| metric | unit | definition |", "|---|---|---|"]
    rows += [f"| {code(k)} | {cell(unit_text(units[k]))} | {cell(defs[k])} |" for k in units]
    return "\n".join(rows) + "\n"


PAGES = {"cli.md": cli_markdown, "scenario-keys.md": scenario_markdown, "robot-keys.md": robot_markdown,
         "metrics.md": metrics_markdown,
         "replay-metrics.md": lambda: metrics_markdown(replay=True)}


def generate(directory: Path = AUTO) -> list[Path]:
    """Write every generated page into ``directory`` (only files whose text changed)."""
    directory.mkdir(parents=True, exist_ok=True)
    ignore = directory / ".gitignore"
    if not ignore.exists():
        ignore.write_text("# written by docs/_ext/twin_reference.py at every build\n*\n", encoding="utf-8")
    written = []
    for name, make in PAGES.items():
        text = "<!-- generated by docs/_ext/twin_reference.py: do not edit -->\n\n" + make()
        path = directory / name
        if not path.exists() or path.read_text(encoding="utf-8") != text:
            tmp = path.with_suffix(f".tmp{id(text)}")
            tmp.write_text(text, encoding="utf-8")
            tmp.replace(path)
        written.append(path)
    return written


# ---- docstrings: |x| is an absolute value, not a reST substitution --------------------------------

_LITERAL = re.compile(r"(``.+?``|`[^`]+`_?|:\w+:`[^`]+`)")


def escape_bars(line: str) -> str:
    """``line`` with each ``|`` outside inline literals and roles escaped; a line that is a reST
    table row or line block (starting with ``|`` or ``+-``) is left alone."""
    if line.lstrip().startswith(("| ", "+-", "+=")) and line.rstrip().endswith(("|", "+")):
        return line
    parts = _LITERAL.split(line)
    return "".join(p if i % 2 else re.sub(r"(?<!\\)\|", r"\\|", p) for i, p in enumerate(parts))


NUMPYDOC_SECTIONS = {"Parameters", "Returns", "Yields", "Receives", "Raises", "Warns", "Other Parameters",
                     "Attributes", "Methods", "See Also", "Notes", "Warnings", "References", "Examples",
                     "Summary", "Extended Summary"}


def headings_to_rubrics(lines: list[str]) -> list[str]:
    """If a docstring has a section numpydoc does not know (it would drop it, e.g. "Optional
    hooks (the loop calls them only if they exist)"), every section heading becomes a rubric
    over its content (a definition list), so that nothing is lost; else ``lines`` unchanged."""
    def is_rule(i):
        return i < len(lines) and len(lines[i].strip()) >= 3 and set(lines[i].strip()) == {"-"}

    heads = [i for i in range(len(lines) - 1) if lines[i].strip() and is_rule(i + 1)]
    if all(lines[i].strip() in NUMPYDOC_SECTIONS for i in heads):
        return lines
    out, skip = [], set()
    for i, ln in enumerate(lines):
        if i in skip:
            continue
        if i in heads:
            indent = ln[:len(ln) - len(ln.lstrip())]
            out += [f"{indent}.. rubric:: {ln.strip()}", ""]
            skip.add(i + 1)
        else:
            out.append(ln)
    return out


def escape_docstring(lines: list[str]) -> list[str]:
    """:func:`escape_bars` on every line but those of literal blocks (after a ``::``, indented
    deeper) and doctests (``>>>``)."""
    out, literal_indent = [], None

    def indent(ln):
        return len(ln) - len(ln.lstrip())

    for i, ln in enumerate(lines):
        if literal_indent is not None:
            if not ln.strip() or indent(ln) > literal_indent:
                out.append(ln)
                continue
            literal_indent = None
        if ln.lstrip().startswith((">>>", "...")):
            out.append(ln)
            continue
        out.append(escape_bars(ln))
        if ln.rstrip().endswith("::"):
            literal_indent = indent(ln)
    return out


def _process_docstring(app, what, name, obj, options, lines):
    lines[:] = headings_to_rubrics(escape_docstring(lines))


def _builder_inited(app):
    generate()


LONG_DEFAULT = 30  # characters: a default's repr beyond this is shown as its type, Name(…)


def short_signature(signature: str) -> str:
    """``signature`` ("(a, b=Plugin(kind='ekf', params=None), ...)") with every default whose repr
    is longer than :data:`LONG_DEFAULT` shortened to ``Name(…)``: a dataclass's generated
    signature spells out nested defaults in full (RunSpec's ran to about 20 lines)."""
    if not signature or not signature.startswith("("):
        return signature
    body, tail = signature[1:], ""
    depth, parts, cur = 0, [], ""
    for i, ch in enumerate(body):
        if ch in "([{":
            depth += 1
        elif ch in ")]}":
            if depth == 0:  # the closing parenthesis of the signature
                tail = body[i:]
                break
            depth -= 1
        if ch == "," and depth == 0:
            parts.append(cur)
            cur = ""
        else:
            cur += ch
    parts.append(cur)
    out = []
    for part in parts:
        name, eq, default = part.partition("=")
        if eq and len(default) > LONG_DEFAULT:
            head = default.strip().split("(", 1)[0]
            default = f"{head}(…)" if head and head.replace(".", "").isidentifier() else "…"
        out.append(name + eq + default)
    return "(" + ",".join(out) + tail


def _process_signature(app, what, name, obj, options, signature, return_annotation):
    if signature and len(signature) > 200:
        return short_signature(signature), return_annotation
    return None


def setup(app):
    app.connect("builder-inited", _builder_inited)
    app.connect("autodoc-process-signature", _process_signature)
    app.connect("autodoc-process-docstring", _process_docstring, priority=400)
    return {"version": "1", "parallel_read_safe": True, "parallel_write_safe": True}
