"""The README is a newcomer's door: short, and its examples run outside a developer checkout."""

from __future__ import annotations

import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def test_the_readme_is_short_and_its_examples_need_no_developer_checkout() -> None:
    text = (ROOT / "README.md").read_text(encoding="utf-8")
    assert len(text.splitlines()) <= 250
    blocks = "\n".join(re.findall(r"```bash\n(.*?)```", text, re.DOTALL))
    assert blocks
    assert "../shared" not in blocks  # an example path only a developer checkout has
    for page in re.findall(r"`(docs/[\w/.-]+\.(?:md|png))`", text):  # every page it names exists
        assert (ROOT / page).is_file(), page
    for page in re.findall(r"\]\((docs/[\w/.-]+)\)", text):
        assert (ROOT / page).is_file(), page
