"""The README's scenario key reference is generated from the schema: keep them in step."""
from pathlib import Path

from twin.scenarios.schema import describe

README = Path(__file__).resolve().parent.parent / "README.md"


def test_readme_key_reference_matches_the_schema():
    text = README.read_text(encoding="utf-8")
    missing = [row for row in describe() if f"| `{row[0]}` | {row[1]} | {row[2]} | {row[3]} |" not in text]
    assert not missing, f"README key reference out of date for: {[r[0] for r in missing]}"
