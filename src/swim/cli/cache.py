"""``swim cache``: list swim's disk caches, or clear them (a thin layer over :mod:`swim.compilation.cache_budget`).

Register it on the main app with ``app.command()(cache)`` (``swim/cli/main.py``).
"""

from __future__ import annotations

from typing import List, Optional

import typer
from rich.console import Console
from rich.markup import escape
from rich.table import Table

from ..errors import SwimInputError

console = Console(stderr=True)


def cache(
    clear: bool = typer.Option(False, "--clear", help="Remove the caches' files (the next render builds and compiles "
                               "them again)."),
    kind: Optional[List[str]] = typer.Option(None, "--kind", help="Only this cache: gas, surface, colour, jax, "
                                             "jax-export or numba (repeatable; default: all)."),
):
    """List swim's disk caches (folder, files, size, budget), or clear them with --clear.

    The gas, surface, colour, JAX and JAX export caches each stay below SWIM_CACHE_MAX_MB megabytes (default 1024),
    least recently used entries removed first; numba keeps the machine code of the last three versions of swim's
    kernels.
    """
    from ..compilation.cache_budget import CODE_VERSIONS, KINDS, cache_usage, clear_caches

    kinds = tuple(kind) if kind else KINDS
    try:
        if clear:
            removed = clear_caches(kinds)
            console.print(f"removed {removed / 2**20:.1f} MB from the {', '.join(kinds)} cache(s)")
            return
        table = Table("cache", "folder", "files", "size [MB]", "budget [MB]")
        for usage in cache_usage(kinds):
            budget = f"{CODE_VERSIONS} code versions" if usage.max_bytes is None else f"{usage.max_bytes / 2**20:.0f}"
            table.add_row(usage.kind, escape(str(usage.path)), str(usage.files), f"{usage.size_bytes / 2**20:.1f}",
                          budget)
        Console().print(table)
    except SwimInputError as exc:
        console.print(f"[red]error:[/red] {escape(str(exc))}", soft_wrap=True)  # one line, however long
        raise typer.Exit(code=2) from None
