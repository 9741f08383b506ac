"""Frame lists typed by people: '5, 10, 20-24'."""
from __future__ import annotations

from .model import SkinkitError

#: The public API (what tests/fuzz/api_fuzz.py calls with hostile arguments); the rest are helpers.
__all__ = ["parse_frame_list"]


MAX_FRAMES = 1_000_000  # a list longer than this is a typing mistake, not an animation


def parse_frame_list(text: str) -> list[int]:
    """'5, 10, 20-24' -> [5, 10, 20, 21, 22, 23, 24]; an empty text is no frames. Frames may be negative
    ('-5', '-10--2'); a range that runs backwards or a list of more than MAX_FRAMES frames is refused."""
    if text is not None and not isinstance(text, str):
        raise SkinkitError(f"frames: expected text such as '5, 10, 20-24', got {type(text).__name__}")
    frames = []
    for part in filter(None, (p.strip() for p in (text or "").split(","))):
        first, separator, last = part[1:].partition("-")
        first, last = part[0] + first, last if separator else part[0] + first
        try:
            start, stop = int(first), int(last)
        except ValueError:
            raise SkinkitError(f"frames {text!r}: expected numbers and ranges such as '5, 10, 20-24'") from None
        if stop < start:
            raise SkinkitError(f"frames {text!r}: the range {part} runs backwards (write {stop}-{start})")
        if len(frames) + stop - start + 1 > MAX_FRAMES:
            raise SkinkitError(f"frames {text!r}: more than {MAX_FRAMES} frames")
        frames.extend(range(start, stop + 1))
    return frames
