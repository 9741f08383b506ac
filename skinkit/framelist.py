"""Frame lists typed by people: '5, 10, 20-24'."""
from __future__ import annotations

from .model import SkinkitError


def parse_frame_list(text: str) -> list[int]:
    """'5, 10, 20-24' -> [5, 10, 20, 21, 22, 23, 24]; an empty text is no frames."""
    frames = []
    for part in filter(None, (p.strip() for p in (text or "").split(","))):
        first, _, last = part.partition("-") if not part.startswith("-") else (part, "", "")
        try:
            frames.extend(range(int(first), int(last or first) + 1))
        except ValueError:
            raise SkinkitError(f"frames {text!r}: expected numbers and ranges such as '5, 10, 20-24'") from None
    return frames
