"""Plain fixed-width text tables for the command line and the paper studies (no extra dependency)."""

from __future__ import annotations


def format_table(rows: list[list], header: list[str], floatfmt: str = "{:.4g}") -> str:
    """A plain fixed-width text table (no extra dependency)."""
    cells = [[(floatfmt.format(c) if isinstance(c, float) else str(c)) for c in r] for r in rows]
    widths = [max(len(h), *(len(r[i]) for r in cells)) if cells else len(h) for i, h in enumerate(header)]
    line = "  ".join(h.rjust(w) for h, w in zip(header, widths))
    sep = "  ".join("-" * w for w in widths)
    body = ["  ".join(c.rjust(w) for c, w in zip(r, widths)) for r in cells]
    return "\n".join([line, sep, *body])
