"""``twin pil``: an export on an emulated Cortex-M4F (QEMU), over the readings of a run of the twin:
flash, RAM, stack, instructions per step, and its duties against the host build's
(:mod:`twin.workflows.pil`)."""
from __future__ import annotations

import json
from pathlib import Path

import click

from twin.commands.common import Once
from twin.workflows.pil import run_pil


def _fmt_bytes(n: int) -> str:
    return f"{n} B" if n < 10_000 else f"{n / 1024:.1f} kB"


@click.command("pil", cls=Once)
@click.argument("directory", metavar="DIR", type=click.Path(file_okay=False, path_type=Path))
@click.option("--seconds", type=float, default=3.0, show_default=True,
              help="How much of the export's scenario's run (its readings, its targets) to feed the microcontroller.")
@click.option("--json", "json_out", type=click.Path(dir_okay=False, path_type=Path), default=None, metavar="FILE",
              help="Also write every figure as JSON.")
def pil_command(directory, seconds, json_out):
    """Run an export on an emulated Cortex-M4F: processor in the loop.

    DIR is a directory 'twin export' wrote (float32 for a Cortex-M4F's single-precision FPU).
    Its library is cross-compiled with arm-none-eabi-gcc (hard float, -O2) for QEMU's
    netduinoplus2 board (an STM32F405 at 168 MHz), run under qemu-system-arm with semihosting
    over the readings of its scenario's run of the twin, and built for the host too: the two
    output streams are compared value by value. QEMU counts the instructions of each step
    (-icount); the time at 168 MHz assumes one cycle per instruction (a lower bound). Needs
    arm-none-eabi-gcc, libnewlib-arm-none-eabi and qemu-system-arm (Debian/Ubuntu packages).

    \b
    Examples:
      twin export --precision float32 --out fw32
      twin pil fw32
    """
    r = run_pil(directory, seconds)
    b, q, c = r["build"], r["qemu"], r["compare"]
    click.echo(f"{r['controller']} with {r['estimator']}, {r['precision']} ({r['arithmetic']}), on {b['board']} (Cortex-M4F), "
               f"{r['steps']} steps of {r['scenario']}")
    click.echo(f"  flash   {_fmt_bytes(b['library_flash'])} (the library; the whole test image "
               f"{_fmt_bytes(b['image_flash'])}), target <= 64 kB")
    click.echo(f"  RAM     {_fmt_bytes(b['ram_bytes'])}: state {b['state_bytes']} B + stack {b['stack_bytes']} B "
               f"(worst path) + static {b['library_ram']} B, target <= 8 kB")
    click.echo(f"  time    {q['instructions_mean']:.0f} instructions per step on average, {q['instructions_max']} at "
               f"most: {q['us_max']:.1f} µs at 168 MHz, {100 * q['period_share']:.2f} % of the control period "
               f"(target <= 10 %)")
    if c["identical"]:
        click.echo("  outputs the same bits as the host build's, every step")
    else:
        parts = [f"{name} on {f['steps']} steps (at most {f['max_ulp']} ulp, {f['max_abs']:.3g})"
                 for name, f in c["fields"].items()]
        click.echo("  outputs differ from the host build's: " + "; ".join(parts) +
                   " (newlib's float maths functions against glibc's: one ulp on some arguments)")
    if json_out is not None:
        json_out.parent.mkdir(parents=True, exist_ok=True)
        json_out.write_text(json.dumps(r, indent=2, default=str) + "\n", encoding="utf-8")
        click.echo(f"wrote {json_out}")


__all__ = ["pil_command"]
