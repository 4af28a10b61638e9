"""The scenario keys and command-line options the documentation names exist.

The scenario schema's reference page (docs/reference/scenario-schema.md) is generated from
``twin.scenarios.schema.describe()`` at build time (docs/_ext/twin_reference.py); these tests keep
the generator whole (every key with its type, default and meaning) and check the hand-written
pages and the README against the code: every ``--set KEY=VALUE`` names a scenario key, and every
``--option`` of a ``twin COMMAND`` written in them is an option of that command."""
from __future__ import annotations

import re
import shlex
import sys
from pathlib import Path

import click
import pytest

from twin.cli import main
from twin.scenarios.schema import describe

ROOT = Path(__file__).resolve().parent.parent
DOCS = ROOT / "docs"
PAGES = [ROOT / "README.md"] + [p for p in sorted(DOCS.rglob("*.md"))
                                if not ({"_build", "_auto", "_generated", "investigations"}
                                        & set(p.relative_to(DOCS).parts))]


def _reference():
    sys.path.insert(0, str(DOCS / "_ext"))
    try:
        import twin_reference
    finally:
        sys.path.remove(str(DOCS / "_ext"))
    return twin_reference


def test_the_reference_page_includes_the_generated_key_table():
    page = (DOCS / "reference" / "scenario-schema.md").read_text(encoding="utf-8")
    assert "_auto/scenario-keys.md" in page


def test_the_generated_key_table_has_every_key_with_type_default_and_meaning():
    ref = _reference()
    text = ref.scenario_markdown()
    rows = describe()
    assert len(rows) > 50
    missing = [r[0] for r in rows
               if f"| {ref.code(r[0])} | {ref.cell(r[1])} | {ref.code(r[2])} | {ref.cell(r[3])} |" not in text]
    assert not missing, f"keys missing or out of date in the generated reference: {missing}"
    assert text.count("\n| `") == len(rows)  # nothing else, nothing twice


# ---- what the pages name ------------------------------------------------------------------------

def _schema_keys() -> tuple[set, set]:
    """(every dotted key, the keys that hold free-form tables: plugin parameters, maps, bounds)."""
    keys, open_tables = set(), set()
    for key, kind, _default, _doc in describe():
        k = key.strip("[]").replace("[]", "")
        keys.add(k)
        if kind.startswith(("map", "table")):
            open_tables.add(k)
    return keys, open_tables


def key_exists(key: str) -> bool:
    """Whether ``--set KEY=…`` names a scenario key: a key, a table given whole, or a key inside
    a free-form table (a plugin's parameters, ``plant.scale.m_b``, ``expect.it2.fell``)."""
    keys, open_tables = _schema_keys()
    parts = re.findall(r'"[^"]*"|\'[^\']*\'|[^.]+', key)
    plain = ".".join(p.strip("\"'") for p in parts)
    if plain in keys or any(k.startswith(plain + ".") for k in keys):
        return True
    return any(".".join(p.strip("\"'") for p in parts[:i]) in open_tables for i in range(1, len(parts)))


def test_key_exists_tells_keys_from_non_keys():
    assert key_exists("plant.scale.m_b") and key_exists("plant.scale") and key_exists("sensors.sensing")
    assert key_exists('controller.params."mylab.ctrl:CascadePID".sign') and key_exists("pushes")
    assert key_exists("limits") and key_exists("expect.it2.fell")
    assert not key_exists("sensors.ideal_sensing") and not key_exists("plant.mass") and not key_exists("video.fps2")


def _spans(text: str) -> list[str]:
    """Inline code spans and the lines of fenced blocks: where commands are written."""
    out = re.findall(r"(?<!`)`([^`\n]+)`(?!`)", text)
    for block in re.findall(r"^\s*```[^\n]*\n(.*?)^\s*```", text, re.M | re.S):
        out += [ln[2:] if ln.startswith("$ ") else ln for ln in block.splitlines()]
    return out


def _commands(text: str):
    """(command words, arguments) of each ``twin …`` written in ``text``."""
    group_names = set(main.list_commands(click.Context(main)))
    for span in _spans(text):
        for m in re.finditer(r"(?:^|[\s;&|(])(?:\S*/)?twin\s+([a-z][\w-]*)((?:[^;&|`\n])*)", span):
            if m.group(1) not in group_names:
                continue
            try:
                args = shlex.split(m.group(2).replace("\\", " "))
            except ValueError:
                args = m.group(2).split()
            yield m.group(1), args


def _options(name: str) -> set:
    ctx = click.Context(main)
    cmd = main.get_command(ctx, name)
    opts = {o for p in cmd.params for o in (*getattr(p, "opts", ()), *getattr(p, "secondary_opts", ()))}
    if isinstance(cmd, click.Group):
        for sub in cmd.list_commands(ctx):
            c = cmd.get_command(ctx, sub)
            opts |= {o for p in c.params for o in (*getattr(p, "opts", ()), *getattr(p, "secondary_opts", ()))}
    return opts | {"--help", "-h"}


@pytest.mark.parametrize("page", PAGES, ids=[str(p.relative_to(ROOT)) for p in PAGES])
def test_every_option_and_key_a_page_names_exists(page):
    text = page.read_text(encoding="utf-8")
    bad = []
    for name, args in _commands(text):
        opts = _options(name)
        for i, a in enumerate(args):
            if a.startswith("--") and a.split("=", 1)[0] not in opts and a != "--":
                bad.append(f"twin {name}: no option {a.split('=', 1)[0]}")
            if a == "--set" and i + 1 < len(args) and "=" in args[i + 1]:
                key = args[i + 1].split("=", 1)[0]
                if not key_exists(key):
                    bad.append(f"twin {name} --set: no scenario key {key!r}")
    assert not bad, f"{page.relative_to(ROOT)} names what does not exist: {sorted(set(bad))}"


def test_the_check_finds_a_nonexistent_option():
    found = list(_commands("Run `twin run paper-exp1 --ideal-sensing --set sensors.ideal=true`."))
    assert found == [("run", ["paper-exp1", "--ideal-sensing", "--set", "sensors.ideal=true"])]
    assert "--ideal-sensing" not in _options("run") and not key_exists("sensors.ideal")
