"""The shared layer: the memory probe and the size checks every stage uses before it allocates."""

from __future__ import annotations

import sys

import numpy as np

from ._errors import InputError


def available_memory() -> int | None:
    """Bytes of memory available to this process now (`MemAvailable` of /proc/meminfo), or
    `None` where the system does not say."""
    try:
        with open("/proc/meminfo") as fh:
            for line in fh:
                if line.startswith("MemAvailable:"):
                    return int(line.split()[1]) * 1024
    except (OSError, ValueError, IndexError):
        return None
    return None


def size_text(nbytes: float) -> str:
    """`nbytes` in the largest binary unit that keeps it at least 1 (e.g. '21.8 TiB')."""
    value = float(nbytes)
    for unit in ("bytes", "KiB", "MiB", "GiB", "TiB", "PiB"):
        if value < 1024 or unit == "PiB":
            return f"{value:,.0f} {unit}" if unit == "bytes" else f"{value:.1f} {unit}"
        value /= 1024
    return f"{value:.1f} PiB"  # pragma: no cover (the loop returns)


def check_memory(need: float, what: str, fix: str, avail: int | None = None) -> None:
    """Refuse, before anything is allocated, work that needs more memory than is available.

    **Arguments:**
    - `need`: the bytes the work needs (an estimate of its peak).
    - `what`: the work in the user's terms, e.g. "a 100000-sample grid" (starts the message).
    - `fix`: what to change, e.g. "lower --resolution".
    - `avail`: the bytes available (default: `available_memory()`).

    **Raises:** `InputError` "`what` needs about X but only Y of memory is available; `fix`".
    """
    avail = available_memory() if avail is None else avail
    if avail is not None and need > avail:
        raise InputError(
            f"{what} needs about {size_text(need)} of memory but {size_text(avail)} is "
            f"available; {fix}"
        )


def log(msg: str) -> None:
    """One line of progress or a note on stderr, prefixed `jaxrbf: `."""
    print(f"jaxrbf: {msg}", file=sys.stderr, flush=True)


#: Coordinates beyond this magnitude overflow float64 once squared (distances, kernels).
MAX_COORDINATE = 1e150
#: An extent below this underflows float64 once squared.
MIN_EXTENT = 1e-150
#: An extent below this fraction of the coordinates' magnitude is lost to float64 rounding.
MIN_RELATIVE_EXTENT = 1e-12


def check_scale(a: np.ndarray, what: str) -> None:
    """Refuse finite (n, d) coordinates that float64 cannot work with: so large that their squares
    overflow, spanning so little that squared distances underflow, or spanning so little next
    to their magnitude that rounding erases their differences. `what` names them in the
    message (e.g. "'cloud.xyz'" or "`points`")."""
    if a.size == 0:
        return
    lo, hi = a.min(axis=0), a.max(axis=0)
    big = float(max(np.abs(lo).max(), np.abs(hi).max()))
    if big > MAX_COORDINATE:
        raise InputError(
            f"{what} has coordinates as large as {big:.3g}: too large for float64 arithmetic "
            f"(squared distances overflow for coordinates beyond {MAX_COORDINATE:.0e}); rescale "
            "the input "
            "(e.g. change its unit) first"
        )
    extent = float((hi - lo).max())
    if 0 < extent < MIN_EXTENT:
        raise InputError(
            f"{what} spans only {extent:.3g}: too small for float64 arithmetic (squared "
            f"distances underflow for extents below {MIN_EXTENT:.0e}); rescale the input (e.g. change its "
            "unit) first"
        )
    if 0 < extent < MIN_RELATIVE_EXTENT * big:
        raise InputError(
            f"{what} spans only {extent:.3g} at coordinates as large as {big:.3g}: float64 "
            "cannot resolve such small differences; subtract a point near the data (recentre "
            "it) first"
        )
