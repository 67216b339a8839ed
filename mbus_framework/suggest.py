"""'Did you mean' suggestions for unknown names."""
from __future__ import annotations

import difflib
from typing import Iterable


def did_you_mean(word: str, choices: Iterable[str]) -> str:
    """Return ``"; did you mean 'x'?"`` for the closest choice, or an empty string."""
    close = difflib.get_close_matches(str(word), [str(c) for c in choices], n=1, cutoff=0.6)
    return f"; did you mean '{close[0]}'?" if close else ""


def choices_text(choices: Iterable[str]) -> str:
    """Comma-separated, sorted list of choices."""
    return ", ".join(sorted(str(c) for c in choices)) or "(none registered)"
