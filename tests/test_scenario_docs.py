"""The README's scenario key reference is generated from the schema: keep them in step."""
from pathlib import Path

from twin.scenarios.schema import describe

README = Path(__file__).resolve().parent.parent / "README.md"


# keys whose README row is yet to be added (the README has another owner): while the README
# does not name such a key it is let pass; once it does, its row must match like any other
PENDING: set = set()  # keys whose README row is still to be written


def test_readme_key_reference_matches_the_schema():
    text = README.read_text(encoding="utf-8")
    missing = [row for row in describe() if f"| `{row[0]}` | {row[1]} | {row[2]} | {row[3]} |" not in text
               and not (row[0] in PENDING and f"| `{row[0]}` |" not in text)]
    assert not missing, f"README key reference out of date for: {[r[0] for r in missing]}"
