"""``twin cache``: the design cache's directory and size, and clearing it."""
from __future__ import annotations

import click

from twin.controllers import design_cache


@click.group()
def cache():
    """The design cache: LMI designs stored by their inputs, so that a run need not solve them.

    Where: $TWIN_CACHE_DIR, else $XDG_CACHE_HOME/mtwip-twin, else ~/.cache/mtwip-twin.

    \b
    Examples:
      twin cache info
      twin cache clear
    """


@cache.command("info")
def cache_info():
    """Print the design cache's directory and how many designs it holds."""
    d = design_cache.cache_dir()
    n = len(list(d.glob("lmi-*.json"))) if d.is_dir() else 0
    click.echo(f"{d}: {n} cached design{'s' * (n != 1)}")


@cache.command("clear")
def cache_clear():
    """Delete every cached design (only the cache's own files)."""
    d, n = design_cache.clear()
    click.echo(f"removed {n} file{'s' * (n != 1)} from {d}")
